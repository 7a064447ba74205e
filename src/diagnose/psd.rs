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

/// P(Gamma(d, 1) > x) = e^{−x} Σ_{j<d} x^j / j!, for integer d.
fn gamma_tail(d: usize, x: f64) -> f64 {
    (-x).exp() * (0..d).fold((0.0, 1.0), |(s, t), j| (s + t, t * x / (j as f64 + 1.0))).0
}

/// The spectral lines a recording's motion carries, for telling a residual line that is a
/// misfit of the motion (a gait harmonic) from an added one. Per sensor, the three channels'
/// 4-term Blackman–Harris tapered periodograms (weighted mean removed) are summed; a line at
/// f is a local maximum within ± 2 padded bins of f's bin (not the flank of a line further
/// away, whose tapered main lobe spans ± 4 record bins) that stands out of the local continuum: the bins 8–40 record-bins away on each side,
/// whose median scales the Gamma(3, 1) null (median 2.674) of a locally flat spectrum. The
/// taper's side lobes (−92 dB) keep a strong line or the low-frequency motion from leaking
/// into its neighbours; a broadband motion (random impacts) is a continuum, not a line.
#[derive(Debug, Clone)]
pub struct MotionLines {
    spectra: Vec<Vec<f64>>,
    /// Bins per 1 / (record length).
    pad: usize,
    bin_hz: f64,
    alpha: f64,
}

impl MotionLines {
    /// `sensors`: each a sensor's three channels; `alpha`: the false-alarm probability per test.
    pub fn new(sensors: &[&[Vec<f64>]], dt: f64, alpha: f64) -> Self {
        let n = sensors.first().and_then(|s| s.first()).map_or(0, Vec::len);
        let m = n.max(2).next_power_of_two();
        let a = [0.35875, 0.48829, 0.14128, 0.01168];
        let w: Vec<f64> = (0..n)
            .map(|k| {
                let x = TAU * k as f64 / (n.max(2) - 1) as f64;
                a[0] - a[1] * x.cos() + a[2] * (2.0 * x).cos() - a[3] * (3.0 * x).cos()
            })
            .collect();
        let sw: f64 = w.iter().sum();
        let spectra = sensors
            .iter()
            .map(|chans| {
                let mut total = vec![0.0; m / 2];
                for x in chans.iter() {
                    let mean = x.iter().zip(&w).map(|(v, w)| v * w).sum::<f64>() / sw.max(1e-300);
                    let mut re = vec![0.0; m];
                    for (r, (v, wk)) in re.iter_mut().zip(x.iter().zip(&w)) {
                        *r = (v - mean) * wk;
                    }
                    let mut im = vec![0.0; m];
                    fft(&mut re, &mut im);
                    for (k, t) in total.iter_mut().enumerate() {
                        *t += re[k] * re[k] + im[k] * im[k];
                    }
                }
                total
            })
            .collect();
        MotionLines { spectra, pad: (m / n.max(1)).max(1), bin_hz: 1.0 / (m as f64 * dt), alpha }
    }

    /// Does the motion carry a line at `f` (any sensor)?
    pub fn carries(&self, f: f64) -> bool {
        let k = (f / self.bin_hz).round() as i64;
        let lobe = 2 * self.pad as i64;
        let (near, far) = (8 * self.pad as i64, 40 * self.pad as i64);
        self.spectra.iter().any(|p| {
            let len = p.len() as i64;
            let at = |j: i64| (0..len).contains(&j).then(|| p[j as usize]);
            // The sim's own peak must sit within the window: the flank of a line a few bins
            // away (the taper's main lobe is ±4 record bins wide) is not a line at f.
            let Some(j) = (k - lobe..=k + lobe).filter(|j| at(*j).is_some()).max_by(|a, b| p[*a as usize].total_cmp(&p[*b as usize]))
            else {
                return false;
            };
            let peak = p[j as usize];
            if at(j - 1).is_some_and(|v| v > peak) || at(j + 1).is_some_and(|v| v > peak) || j == k - lobe || j == k + lobe {
                return false;
            }
            let mut around: Vec<f64> = (k - far..=k - near).chain(k + near..=k + far).filter_map(at).collect();
            if around.len() < 16 {
                return false;
            }
            around.sort_by(f64::total_cmp);
            let median = around[around.len() / 2];
            if median <= 0.0 {
                return peak > 0.0;
            }
            let tests = (2 * lobe + 1) as f64 / self.pad as f64;
            let line = gamma_tail(3, peak / (median / 2.674)) * tests < self.alpha;
            tracing::trace!("motion line test at {f:.4} Hz: peak / continuum median {:.3e}, line {line}", peak / median);
            line
        })
    }
}

/// How many significant residual lines [`periodogram_peak`] tries against `excluded`.
const MAX_LINES_TRIED: usize = 64;

/// The frequency of the strongest significant spectral line in whitened channels (i.i.d.
/// N(0, 1) under the null) that `excluded` does not reject, if any: a periodogram bin is
/// significant when its value summed over the channels exceeds its null distribution,
/// Gamma(channels, 1) per bin, Bonferroni-corrected over the bins. The local maxima among
/// them are tried strongest first; the first one not excluded (tested at its bin's
/// frequency) is refined between the neighbouring bins by golden section.
pub fn periodogram_peak(chans: &[Vec<f64>], dt: f64, alpha: f64, excluded: impl Fn(f64) -> bool) -> Option<f64> {
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
    let bins = (n / 2) as f64;
    let significant = |v: f64| gamma_tail(chans.len(), v) * bins <= alpha;
    let mut peaks: Vec<usize> = (k0..total.len())
        .filter(|&k| significant(total[k]) && total[k] >= total[k - 1] && total.get(k + 1).is_none_or(|v| total[k] >= *v))
        .collect();
    peaks.sort_by(|a, b| total[*b].total_cmp(&total[*a]));
    peaks.truncate(MAX_LINES_TRIED);
    let df = 1.0 / (m as f64 * dt);
    let k = peaks.into_iter().find(|&k| !excluded(k as f64 * df))?;
    let f0 = k as f64 * df;
    let (f, _) = super::golden::golden(f0 - df, f0 + df, 30, |f| line_power(chans, dt, f));
    Some(f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, StandardNormal};

    /// 100 s at 100 Hz of three channels: `pulse(t)` summed over the given impact times, plus
    /// white noise of σ 0.01.
    fn channels(impacts: &[f64], seed: u64) -> Vec<Vec<f64>> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let (n, dt) = (10_000, 0.01);
        let gain = [1.0, 0.5, -0.8];
        (0..3)
            .map(|c| {
                let mut x: Vec<f64> = (0..n).map(|_| 0.01 * Distribution::<f64>::sample(&StandardNormal, &mut rng)).collect();
                for &t0 in impacts {
                    let k0 = (t0 / dt).ceil() as usize;
                    for (k, v) in x.iter_mut().enumerate().skip(k0).take(12) {
                        let t = k as f64 * dt - t0;
                        *v += gain[c] * 3.0 * (-t / 0.02).exp();
                    }
                }
                x
            })
            .collect()
    }

    #[test]
    fn motion_lines_are_told_from_a_continuum_and_from_noise() {
        let dt = 0.01;
        // A trot: one impact every 0.5 s (lines at multiples of 2 Hz).
        let periodic: Vec<f64> = (0..200).map(|k| 0.5 * k as f64 + 0.013).collect();
        // Impacts at random times: a continuum.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let random: Vec<f64> = (0..200).map(|_| rng.gen_range(0.0..99.9)).collect();
        let lines = channels(&periodic, 1);
        let continuum = channels(&random, 2);
        let noise = channels(&[], 4);
        let m = |c: &Vec<Vec<f64>>| MotionLines::new(&[c.as_slice()], dt, 1e-4);
        let (ml, mc, mn) = (m(&lines), m(&continuum), m(&noise));
        for f in [2.0, 10.0, 26.0, 38.0] {
            assert!(ml.carries(f), "periodic impacts carry a line at {f} Hz");
        }
        for f in [3.0, 11.1, 26.9, 37.3] {
            assert!(!ml.carries(f), "no line between the harmonics at {f} Hz");
        }
        // Half a record bin (0.01 Hz) off a harmonic is on it; four bins off is on the flank
        // of its tapered main lobe, not a line.
        assert!(ml.carries(10.005) && ml.carries(25.995));
        assert!(!ml.carries(10.04) && !ml.carries(25.96));
        for f in [2.0, 10.0, 13.7, 26.0, 41.3] {
            assert!(!mc.carries(f), "random impacts are a continuum, no line at {f} Hz");
            assert!(!mn.carries(f), "white noise carries no line at {f} Hz");
        }
    }

    #[test]
    fn an_excluded_line_gives_way_to_the_next() {
        let (n, dt) = (8000, 0.005);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let chans: Vec<Vec<f64>> = (0..3)
            .map(|_| {
                (0..n)
                    .map(|k| {
                        let t = k as f64 * dt;
                        Distribution::<f64>::sample(&StandardNormal, &mut rng)
                            + 0.5 * (TAU * 10.0 * t).sin()
                            + 0.2 * (TAU * 23.3 * t + 1.0).sin()
                    })
                    .collect()
            })
            .collect();
        let strongest = periodogram_peak(&chans, dt, 1e-4, |_| false).unwrap();
        assert!((strongest - 10.0).abs() < 0.01, "{strongest}");
        let next = periodogram_peak(&chans, dt, 1e-4, |f| (f - 10.0).abs() < 0.1).unwrap();
        assert!((next - 23.3).abs() < 0.01, "{next}");
        assert!(periodogram_peak(&chans, dt, 1e-4, |_| true).is_none());
    }
}
