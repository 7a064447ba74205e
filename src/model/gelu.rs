//! GELU, the Embedding's and Generator's activation: exact in f64 (the reference, as torch's
//! `gelu(approximate="none")`), and a fast f32 form for the node's per-sample path whose error
//! is bounded against the exact one (unit test `the_fast_gelu_is_within_its_bound`).

/// Exact GELU, `x Φ(x) = ½ x (1 + erf(x/√2))`, as torch's `gelu(approximate="none")`.
pub fn gelu(x: f64) -> f64 {
    let z = x * std::f64::consts::FRAC_1_SQRT_2;
    if z >= 0.0 {
        0.5 * x * (2.0 - erfc_pos(z))
    } else {
        0.5 * x * erfc_pos(-z)
    }
}

/// The error function, to about 1e-15 absolute.
pub fn erf(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 - erfc_pos(x)
    } else {
        erfc_pos(-x) - 1.0
    }
}

/// erfc(z) for z ≥ 0: a positive-term series for z < 2 (no cancellation inside the sum), the
/// continued fraction beyond (relative accuracy where erfc is tiny, which GELU needs for x ≪ 0).
const ERFC_SWITCH: f64 = 2.0;
const ERFC_CF_TERMS: usize = 100;

fn erfc_pos(z: f64) -> f64 {
    const FRAC_2_SQRT_PI: f64 = std::f64::consts::FRAC_2_SQRT_PI;
    if z.is_nan() {
        return f64::NAN;
    }
    if z < ERFC_SWITCH {
        // erf(z) = 2/√π e^{−z²} Σ_n 2ⁿ z^{2n+1} / (1·3·…·(2n+1)).
        let z2 = z * z;
        let mut term = z;
        let mut sum = z;
        let mut n = 0.0;
        while term > sum * 1e-17 {
            n += 1.0;
            term *= 2.0 * z2 / (2.0 * n + 1.0);
            sum += term;
        }
        1.0 - FRAC_2_SQRT_PI * (-z2).exp() * sum
    } else if z < 27.0 {
        // erfc(z) = e^{−z²}/√π · 1/(z + (1/2)/(z + 1/(z + (3/2)/(z + …)))).
        let mut f = z;
        for k in (1..=ERFC_CF_TERMS).rev() {
            f = z + 0.5 * k as f64 / f;
        }
        (-z * z).exp() / (f * std::f64::consts::PI.sqrt())
    } else {
        0.0
    }
}

/// The fast f32 GELU's bound against the exact one: |error| ≤ `FAST_GELU_MAX_ERROR` · max(1, |x|).
pub const FAST_GELU_MAX_ERROR: f64 = 3e-7;

/// GELU in f32: erf from Abramowitz & Stegun 7.1.26 (|error| ≤ 1.5e-7 in exact arithmetic),
/// `erf(z) ≈ 1 − t (a₁ + t (a₂ + t (a₃ + t (a₄ + t a₅)))) e^{−z²}`, `t = 1 / (1 + p z)`.
/// Arithmetic, bit operations and selects only (no call): a layer's activations vectorise.
#[inline(always)]
pub fn gelu_f32(x: f32) -> f32 {
    const P: f32 = 0.327_591_1;
    const A: [f32; 5] = [0.254_829_6, -0.284_496_74, 1.421_413_7, -1.453_152, 1.061_405_4];
    let z = x.abs() * std::f32::consts::FRAC_1_SQRT_2;
    let t = 1.0 / (1.0 + P * z);
    let poly = t * (A[0] + t * (A[1] + t * (A[2] + t * (A[3] + t * A[4]))));
    // erfc(z) for z ≥ 0; Φ(x) = 1 − erfc/2 for x ≥ 0, erfc/2 below.
    let half_erfc = 0.5 * poly * exp_non_positive(-z * z);
    let phi = if x >= 0.0 { 1.0 - half_erfc } else { half_erfc };
    x * phi
}

/// `e^x` for x ≤ 0 in f32, to a relative 2e-7: `2ⁿ · e^r`, n = round(x / ln 2) (by the
/// 1.5 · 2²³ rounding trick: no SSE4.1 needed), |r| ≤ ln 2 / 2, `e^r` by its Taylor series to
/// r⁷ (the next term is < 3e-8 relative). Below −87 (where e^x underflows f32's normals) 0.
#[inline(always)]
fn exp_non_positive(x: f32) -> f32 {
    const ROUND: f32 = 12_582_912.0;
    // ln 2 in two parts: r = x − n·ln2 without losing r's bits.
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    let x = x.max(-87.0);
    let n = (x * std::f32::consts::LOG2_E + ROUND) - ROUND;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let p = 1.0 + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    // 2ⁿ from its exponent bits; n ≥ −126 here, a normal number.
    let two_n = f32::from_bits(((n as i32 + 127) as u32) << 23);
    p * two_n
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Tensor;

    #[test]
    fn gelu_matches_torch() {
        let xs: Vec<f64> = (-4000..=4000).map(|i| i as f64 * 0.005).chain([-40.0, -12.0, -8.5, 8.5, 40.0]).collect();
        let t = Tensor::from_slice(&xs).gelu("none");
        let reference = Vec::<f64>::try_from(&t).unwrap();
        let mine: Vec<f64> = xs.iter().map(|&x| gelu(x)).collect();
        for ((x, a), b) in xs.iter().zip(&mine).zip(&reference) {
            assert!((a - b).abs() <= 4e-16 * (1.0 + b.abs()) || (a - b).abs() <= 1e-13 * b.abs(), "gelu({x}): {a} vs torch {b}");
        }
        let zs: Vec<f64> = (0..=600).map(|i| i as f64 * 0.01).collect();
        let reference = Vec::<f64>::try_from(&Tensor::from_slice(&zs).erfc()).unwrap();
        let worst = zs.iter().zip(&reference).map(|(&z, r)| ((erfc_pos(z) - r) / r).abs()).fold(0.0, f64::max);
        println!("erfc: worst relative error {worst:.1e} on [0, 6]");
        assert!(worst < 1e-12);
    }

    #[test]
    fn the_fast_exp_is_within_its_bound() {
        let worst = (0..=870_000)
            .map(|i| -(i as f32) * 1e-4)
            .map(|x| ((exp_non_positive(x) as f64 - (x as f64).exp()) / (x as f64).exp()).abs())
            .fold(0.0, f64::max);
        println!("fast exp: worst relative error {worst:.2e} on [−87, 0]");
        assert!(worst < 2e-7, "{worst:e}");
        assert_eq!(exp_non_positive(-1000.0), exp_non_positive(-87.0));
    }

    #[test]
    fn the_fast_gelu_is_within_its_bound() {
        let xs: Vec<f64> = (-200_000..=200_000).map(|i| i as f64 * 1e-4).chain([-40.0, -12.0, 12.0, 40.0]).collect();
        let worst = xs
            .iter()
            .map(|&x| {
                let x32 = x as f32;
                ((gelu_f32(x32) as f64 - gelu(x32 as f64)).abs() / (x32 as f64).abs().max(1.0), x)
            })
            .fold((0.0, 0.0), |a, b| if b.0 > a.0 { b } else { a });
        println!("fast GELU: worst error {:.2e} · max(1, |x|) at x = {}", worst.0, worst.1);
        assert!(worst.0 <= FAST_GELU_MAX_ERROR, "{worst:?}");
        assert_eq!(gelu_f32(0.0), 0.0);
        assert!(gelu_f32(f32::NAN).is_nan());
    }
}
