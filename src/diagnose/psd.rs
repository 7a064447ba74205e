//! Spectra: a radix-2 FFT, Welch's power spectral density, and the periodogram peak search
//! behind the `vibration` candidate.

use std::f64::consts::TAU;

/// In-place radix-2 FFT of (re, im); the length must be a power of two.
pub fn fft(re: &mut [f64], im: &mut [f64]) {
    let n = re.len();
    debug_assert!(n.is_power_of_two() && im.len() == n);
    let mut j = 0;
    for i in 1..n {
        let mut bit = n >> 1;
        while j & bit != 0 {
            j ^= bit;
            bit >>= 1;
        }
        j |= bit;
        if i < j {
            re.swap(i, j);
            im.swap(i, j);
        }
    }
    let mut len = 2;
    while len <= n {
        let ang = -TAU / len as f64;
        let (wr, wi) = (ang.cos(), ang.sin());
        for start in (0..n).step_by(len) {
            let (mut cr, mut ci) = (1.0, 0.0);
            for k in 0..len / 2 {
                let (a, b) = (start + k, start + k + len / 2);
                let (tr, ti) = (re[b] * cr - im[b] * ci, re[b] * ci + im[b] * cr);
                re[b] = re[a] - tr;
                im[b] = im[a] - ti;
                re[a] += tr;
                im[a] += ti;
                let ncr = cr * wr - ci * wi;
                ci = cr * wi + ci * wr;
                cr = ncr;
            }
        }
        len <<= 1;
    }
}

/// One-sided Welch PSD (units²/Hz) with Hann windows of `seg` samples (power of two), 50 %
/// overlap, each segment's mean removed. Returns (frequencies Hz, PSD).
pub fn welch(x: &[f64], dt: f64, seg: usize) -> (Vec<f64>, Vec<f64>) {
    let seg = seg.min(x.len().next_power_of_two() / 2).max(8);
    let win: Vec<f64> = (0..seg).map(|i| 0.5 - 0.5 * (TAU * i as f64 / seg as f64).cos()).collect();
    let u: f64 = win.iter().map(|w| w * w).sum();
    let mut acc = vec![0.0; seg / 2 + 1];
    let mut count = 0;
    let mut start = 0;
    while start + seg <= x.len() {
        let s = &x[start..start + seg];
        let mean = s.iter().sum::<f64>() / seg as f64;
        let mut re: Vec<f64> = s.iter().zip(&win).map(|(v, w)| (v - mean) * w).collect();
        let mut im = vec![0.0; seg];
        fft(&mut re, &mut im);
        for (k, a) in acc.iter_mut().enumerate() {
            let p = re[k] * re[k] + im[k] * im[k];
            *a += if k == 0 || k == seg / 2 { p } else { 2.0 * p };
        }
        count += 1;
        start += seg / 2;
    }
    let scale = dt / (u * count.max(1) as f64);
    let f = (0..=seg / 2).map(|k| k as f64 / (seg as f64 * dt)).collect();
    (f, acc.into_iter().map(|a| a * scale).collect())
}

/// Σ over channels of |Σ x_k e^{−iωk dt}|² / n at one frequency (direct DFT).
pub fn line_power(chans: &[Vec<f64>], dt: f64, f: f64) -> f64 {
    let w = TAU * f * dt;
    chans
        .iter()
        .map(|x| {
            let (c, s) =
                x.iter().enumerate().fold((0.0, 0.0), |(c, s), (k, v)| (c + v * (w * k as f64).cos(), s + v * (w * k as f64).sin()));
            (c * c + s * s) / x.len() as f64
        })
        .sum()
}

/// The frequency of a significant spectral line in whitened channels (i.i.d. N(0, 1) under
/// the null), if any: the largest periodogram value summed over the channels is compared
/// with its null distribution, Gamma(channels, 1) per bin, Bonferroni-corrected over the
/// bins; the frequency is then refined between the neighbouring bins by golden section.
pub fn periodogram_peak(chans: &[Vec<f64>], dt: f64, alpha: f64) -> Option<f64> {
    let n = chans.first()?.len();
    if n < 64 {
        return None;
    }
    let m = n.next_power_of_two();
    let mut total = vec![0.0; m / 2];
    for x in chans {
        let mut re = vec![0.0; m];
        re[..n].copy_from_slice(x);
        let mut im = vec![0.0; m];
        fft(&mut re, &mut im);
        for (k, t) in total.iter_mut().enumerate() {
            *t += (re[k] * re[k] + im[k] * im[k]) / n as f64;
        }
    }
    // Skip the lowest bins (drift territory, < 0.5 Hz).
    let k0 = ((0.5 * m as f64 * dt).ceil() as usize).max(1);
    let (k, peak) = total.iter().enumerate().skip(k0).fold((0, 0.0), |b, (k, v)| if *v > b.1 { (k, *v) } else { b });
    let dof = chans.len() as f64;
    // P(Gamma(d, 1) > x) = e^{−x} Σ_{j<d} x^j / j!
    let tail = |x: f64| (-x).exp() * (0..dof as usize).fold((0.0, 1.0), |(s, t), j| (s + t, t * x / (j as f64 + 1.0))).0;
    let bins = (n / 2) as f64;
    if tail(peak) * bins > alpha {
        return None;
    }
    let df = 1.0 / (m as f64 * dt);
    let f0 = k as f64 * df;
    let (f, _) = super::select::golden(f0 - df, f0 + df, 30, |f| line_power(chans, dt, f));
    Some(f)
}
