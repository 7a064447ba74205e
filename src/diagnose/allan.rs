//! Overlapping Allan deviation, and what the residual's noise model predicts for it.

/// Overlapping Allan deviation of `x` (sample interval `dt`) at octave-spaced cluster sizes.
/// Returns (τ s, σ(τ)).
pub fn allan_deviation(x: &[f64], dt: f64) -> Vec<(f64, f64)> {
    let n = x.len();
    let mut cum = Vec::with_capacity(n + 1);
    cum.push(0.0);
    for v in x {
        cum.push(cum.last().copied().unwrap_or(0.0) + v);
    }
    let mut out = Vec::new();
    let mut m = 1usize;
    while 2 * m < n / 4 {
        let mut acc = 0.0;
        let count = n - 2 * m + 1;
        for k in 0..count {
            let a = (cum[k + m] - cum[k]) / m as f64;
            let b = (cum[k + 2 * m] - cum[k + m]) / m as f64;
            acc += (b - a) * (b - a);
        }
        out.push((m as f64 * dt, (acc / (2.0 * count as f64)).sqrt()));
        m *= 2;
    }
    out
}

/// Allan deviation of white noise of per-sample variance `white` plus a random walk of
/// per-step variance `walk`: σ²(τ) = white·dt/τ + walk·τ/(3 dt).
pub fn model_allan(white: f64, walk: f64, dt: f64, tau: f64) -> f64 {
    (white * dt / tau + walk * tau / (3.0 * dt)).sqrt()
}
