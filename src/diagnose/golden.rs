//! Golden-section search: the one-dimensional maximiser the noise fits (`select`) and the
//! periodogram's peak refinement (`psd`) share.

/// Golden-section maximisation of f on [lo, hi] (`iters` steps): the argument and the value.
pub fn golden(mut lo: f64, mut hi: f64, iters: usize, mut f: impl FnMut(f64) -> f64) -> (f64, f64) {
    let r = (5f64.sqrt() - 1.0) / 2.0;
    let (mut x1, mut x2) = (hi - r * (hi - lo), lo + r * (hi - lo));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..iters {
        if f1 > f2 {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - r * (hi - lo);
            f1 = f(x1);
        } else {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + r * (hi - lo);
            f2 = f(x2);
        }
    }
    if f1 > f2 {
        (x1, f1)
    } else {
        (x2, f2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_peak_of_a_parabola_is_found() {
        let (x, y) = golden(-3.0, 5.0, 40, |x| 2.0 - (x - 1.25).powi(2));
        assert!((x - 1.25).abs() < 1e-6 && (y - 2.0).abs() < 1e-12, "{x} {y}");
    }
}
