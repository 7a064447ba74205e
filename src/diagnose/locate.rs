//! Where the residual differs beyond the simulator's noise model: per axis, per time
//! segment, per frequency band, each claim with its statistic.
//!
//! All statistics are on the whitened residual under the no-term model (white noise from the
//! sim bag's covariance fields, bias walk estimated): i.i.d. N(0, 1) when nothing is left out.
//! - axis: χ² = Σ ν̃² over the recording, z = (χ² − n)/√(2n);
//! - segment: the same over windows of [`SEGMENT_S`], per sensor (three axes pooled),
//!   reported when Bonferroni-significant;
//! - band: Welch PSD of the whitened residual against its flat null level, per octave band;
//!   the band-power ratio with its z-score (Welch bins of K segments ≈ χ²_{2K}/2K; the Hann
//!   window correlates neighbouring bins and the 50 % overlap neighbouring segments, so the
//!   band's degrees of freedom are fewer than 2K per bin, see [`band_dof`]).
//!
//! z-scores are the Wilson–Hilferty normal equivalents of the χ² tails: a band of a few bins
//! has few degrees of freedom, where the plain normal approximation of χ² understates the tail
//! (false claims at α = 1e-3 were common on null recordings).

use serde::Serialize;

use super::psd::welch;
use super::residual::CHANNELS;

/// Length of the time segments tested, s.
pub const SEGMENT_S: f64 = 10.0;
/// Significance level (family-wise, Bonferroni) of a located claim.
pub const ALPHA: f64 = 1e-3;

/// One located mismatch.
#[derive(Debug, Clone, Serialize)]
pub struct Located {
    /// `axis`, `segment` or `band`.
    pub kind: String,
    /// Channel (`gyro_x` …) or sensor (`gyro`, `accel`).
    pub channel: String,
    /// Seconds since the first sample (segments), Hz (bands).
    pub from: f64,
    pub to: f64,
    /// Name of the statistic and its value.
    pub statistic: String,
    pub value: f64,
    /// Excess as a z-score, and its one-sided p-value.
    pub z: f64,
    pub p_value: f64,
    /// Excess power over the noise model, as a share of the model's (χ²/n − 1, band power
    /// ratio − 1).
    pub excess: f64,
}

/// Normal equivalent of a χ² with `dof` degrees of freedom observed at `chi2`
/// (Wilson–Hilferty: (χ²/k)^{1/3} is nearly normal, mean 1 − 2/9k, variance 2/9k).
pub fn chi2_z(chi2: f64, dof: f64) -> f64 {
    let v = 2.0 / (9.0 * dof);
    ((chi2 / dof).max(0.0).cbrt() - (1.0 - v)) / v.sqrt()
}

/// Equivalent degrees of freedom of the sum of `bins` adjacent Welch bins over `segments`
/// Hann segments with 50 % overlap, on white noise. Each bin of one segment is χ²₂; the Hann
/// window makes adjacent bins' powers correlate by (2/3)² = 4/9 and bins two apart by
/// (1/6)² = 1/36, and 50 % overlapping segments by (1/6)² (Welch 1967), which inflates the
/// variance of the sum over independent bins by those covariances.
pub fn band_dof(bins: usize, segments: usize) -> f64 {
    let b = bins as f64;
    let var_bins = b + 2.0 * (b - 1.0).max(0.0) * 4.0 / 9.0 + 2.0 * (b - 2.0).max(0.0) / 36.0;
    let k = segments as f64;
    let var_segments = k + 2.0 * (k - 1.0).max(0.0) / 36.0;
    2.0 * b * b * k * k / (var_bins * var_segments)
}

/// Complementary error function (Numerical Recipes erfcc, relative error < 1.2e-7).
pub fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07 + t * (-1.135_203_98 + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

/// One-sided normal tail P(Z > z).
pub fn normal_tail(z: f64) -> f64 {
    0.5 * erfc(z / std::f64::consts::SQRT_2)
}

fn chi2_claim(kind: &str, channel: &str, from: f64, to: f64, w: &[&[f64]]) -> Located {
    let n: f64 = w.iter().map(|x| x.len() as f64).sum();
    let chi2: f64 = w.iter().flat_map(|x| x.iter()).map(|v| v * v).sum();
    let z = chi2_z(chi2, n);
    Located {
        kind: kind.into(),
        channel: channel.into(),
        from,
        to,
        statistic: format!("chi2 (dof {n})"),
        value: chi2,
        z,
        p_value: normal_tail(z),
        excess: chi2 / n - 1.0,
    }
}

/// Locate the mismatch in whitened residual channels.
pub fn locate(w: &[Vec<f64>; 6], dt: f64) -> Vec<Located> {
    let n = w[0].len();
    let mut out = Vec::new();
    let duration = n as f64 * dt;
    for (c, name) in CHANNELS.iter().enumerate() {
        let l = chi2_claim("axis", name, 0.0, duration, &[&w[c]]);
        if l.p_value < ALPHA / 6.0 {
            out.push(l);
        }
    }
    // At least 16 samples a segment; a recording shorter than that has none (n < 16 would
    // make the bounds cross).
    let seg = ((SEGMENT_S / dt).round() as usize).max(16).min(n.max(16));
    let nseg = n / seg;
    for (s, sensor) in ["gyro", "accel"].iter().enumerate() {
        for k in 0..nseg {
            let r = k * seg..(k + 1) * seg;
            let parts: Vec<&[f64]> = (0..3).map(|a| &w[3 * s + a][r.clone()]).collect();
            let l = chi2_claim("segment", sensor, r.start as f64 * dt, r.end as f64 * dt, &parts);
            if l.p_value < ALPHA / (2 * nseg.max(1)) as f64 {
                out.push(l);
            }
        }
    }
    // Octave bands from 0.05 Hz to Nyquist.
    let segn = ((20.0 / dt) as usize).next_power_of_two().min(n.next_power_of_two() / 2).max(64);
    let k_segments = (2 * n / segn).saturating_sub(1).max(1);
    for (c, name) in CHANNELS.iter().enumerate() {
        let (f, p) = welch(&w[c], dt, segn);
        let level = 2.0 * dt; // one-sided PSD of unit-variance white noise
        let nyq = 0.5 / dt;
        let mut lo = 0.05;
        let nb = ((nyq / lo).log2().ceil() as usize).max(1);
        while lo < nyq {
            let hi = (2.0 * lo).min(nyq);
            let bins: Vec<f64> = f.iter().zip(&p).filter(|(fr, _)| **fr >= lo && **fr < hi).map(|(_, v)| *v).collect();
            if !bins.is_empty() {
                let ratio = bins.iter().sum::<f64>() / (bins.len() as f64 * level);
                let dof = band_dof(bins.len(), k_segments);
                let z = chi2_z(ratio * dof, dof);
                let pv = normal_tail(z);
                if pv < ALPHA / (6 * nb) as f64 {
                    out.push(Located {
                        kind: "band".into(),
                        channel: name.to_string(),
                        from: lo,
                        to: hi,
                        statistic: "band power ratio".into(),
                        value: ratio,
                        z,
                        p_value: pv,
                        excess: ratio - 1.0,
                    });
                }
            }
            lo = hi;
        }
    }
    out
}
