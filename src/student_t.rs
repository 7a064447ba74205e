//! Quantiles of Student's t, for the bounds the pipeline decides on (an adaptation's carry-over
//! over judged recordings, a power-on's bias predicted from earlier ones). Tabulated to df 10;
//! beyond, each range takes its smallest df's value, so a bound is never narrower than the
//! exact one.

/// One-sided 95 % (the 0.95 quantile) with `df` degrees of freedom (∞ for 0).
pub fn one_sided_95(df: usize) -> f64 {
    const TABLE: [f64; 10] = [6.314, 2.920, 2.353, 2.132, 2.015, 1.943, 1.895, 1.860, 1.833, 1.812];
    match df {
        0 => f64::INFINITY,
        1..=10 => TABLE[df - 1],
        11..=15 => 1.796,
        16..=20 => 1.746,
        21..=30 => 1.721,
        31..=60 => 1.696,
        _ => 1.671,
    }
}

/// Two-sided 95 % (the 0.975 quantile) with `df` degrees of freedom (∞ for 0).
pub fn two_sided_95(df: usize) -> f64 {
    const TABLE: [f64; 10] = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228];
    match df {
        0 => f64::INFINITY,
        1..=10 => TABLE[df - 1],
        11..=15 => 2.201,
        16..=20 => 2.120,
        21..=30 => 2.080,
        31..=60 => 2.040,
        _ => 2.000,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_quantiles_fall_with_the_degrees_of_freedom_and_stay_above_the_normals() {
        for q in [one_sided_95 as fn(usize) -> f64, two_sided_95] {
            let values: Vec<f64> = (0..200).map(q).collect();
            assert!(values.windows(2).all(|w| w[1] <= w[0]), "{values:?}");
        }
        assert!(one_sided_95(1000) > 1.645 && two_sided_95(1000) > 1.960);
    }
}
