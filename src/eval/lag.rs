//! Ground truth misaligned in time: the lag between the gyro and the ground truth's rate
//! found by correlation ([`ground_truth_lag`]), coarse then fine.

use crate::core::Recording;
use crate::so3::{log, slerp_at};

use super::EvalOptions;

/// How far the ground truth's clock is from the IMU's, from the rotation rates.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GroundTruthLag {
    /// Seconds the ground truth lags the IMU (negative: it leads): a motion the IMU stamps at
    /// t, the ground truth stamps at t + lag.
    pub lag_s: f64,
    /// Correlation of the two rate norms at that lag (1: the same shape).
    pub correlation: f64,
}

/// Largest lag of the ground truth behind the IMU (or lead) that training and adaptation
/// accept, s. The 17 EuRoC and TUM-VI recordings measure within ±1.2 ms. An IMU's own low-pass
/// filter delays its gyro too (a first-order 40 Hz filter: 4 ms; a 10 Hz one: 16 ms): that is
/// the sensor, and stays below this. Beyond it the stamps are off, and at 1 rad/s every 20 ms
/// is 1.1° of orientation error that training would learn as gyro error.
pub const GROUND_TRUTH_LAG_TOLERANCE_S: f64 = 0.020;
/// A lag estimate is trusted from this correlation on; below it there is too little motion,
/// or too different a motion, to tell.
pub const GROUND_TRUTH_LAG_MIN_CORRELATION: f64 = 0.5;
/// Lags searched either way, s.
pub const GROUND_TRUTH_LAG_SEARCH_S: f64 = 1.0;

impl GroundTruthLag {
    /// Measurably beyond [`GROUND_TRUTH_LAG_TOLERANCE_S`].
    pub fn is_misaligned(&self) -> bool {
        self.correlation >= GROUND_TRUTH_LAG_MIN_CORRELATION && self.lag_s.abs() > GROUND_TRUTH_LAG_TOLERANCE_S
    }
}

/// The ground truth's lag when it is measurably beyond [`GROUND_TRUTH_LAG_TOLERANCE_S`].
pub fn misaligned_ground_truth(rec: &Recording, opts: &EvalOptions) -> Option<GroundTruthLag> {
    ground_truth_lag(rec, opts, GROUND_TRUTH_LAG_SEARCH_S).filter(GroundTruthLag::is_misaligned)
}

/// Sample pairs a lag is judged on at least: fewer say nothing.
const MIN_LAG_PAIRS: usize = 200;

/// The ground truth's lag behind the IMU, from the cross-correlation of the gyro's norm with the
/// ground truth's rotation-rate norm, both at the IMU stamps and averaged over 5 samples, for
/// lags up to `max_lag_s` either way and around the best peak up to 30 s away found on 0.05-s
/// block means (the peak refined by a parabola). Norms need no
/// IMU-to-body rotation, and a gyro bias shifts them far less than the motion does. `None`
/// without enough covered samples or motion. A clock offset between the IMU and the ground
/// truth reads as drift to every metric and as a wrong correction to training and adaptation.
pub fn ground_truth_lag(rec: &Recording, opts: &EvalOptions, max_lag_s: f64) -> Option<GroundTruthLag> {
    const HALF: usize = 2;
    let n = rec.imu.len();
    if n < 2 * HALF + 2 || max_lag_s.is_nan() || max_lag_s <= 0.0 {
        return None;
    }
    let gt = slerp_at(&rec.ground_truth, rec.imu.iter().map(|s| s.stamp_ns), opts.max_gap_ns);
    let mut gyro_mean = vec![None; n];
    let mut gt_rate_vec = vec![None; n];
    for k in HALF..n - HALF {
        // Centred on t_k like the ground truth's rate, each sample taken as the rate at its
        // stamp: so EuRoC, TUM-VI and the simulator measure within ±1.2 ms. (The 4 samples a
        // forward integration uses, ω_n over [t_n, t_n+1], would put all of them at −2.5 ms.)
        let span = &rec.imu[k - HALF..=k + HALF];
        gyro_mean[k] = Some(span.iter().map(|s| s.gyro).sum::<nalgebra::Vector3<f64>>() / span.len() as f64);
        if let (Some(a), Some(b)) = (gt[k - HALF], gt[k + HALF]) {
            let dt = (rec.imu[k + HALF].stamp_ns - rec.imu[k - HALF].stamp_ns) as f64 * 1e-9;
            if dt > 0.0 {
                gt_rate_vec[k] = Some(log(&(a.inverse() * b)) / dt);
            }
        }
    }
    let period = rec.imu_seconds() / (n - 1) as f64;
    let max_lag = ((max_lag_s / period).round() as usize).min(n / 2) as i64;
    // The bias is measured with the two streams paired as they are; when that finds an offset,
    // again paired at it (with the ground truth seconds off, the streams' means are of other
    // motion, and a robot that turns one way skews the bias and with it the peak).
    // And the raw norms too, the better correlation winning: a bias measured against ground
    // truth that is not this gyro's rotation (inverted quaternions, another frame; said by the
    // rotation checks) is no bias, and taking it off would invent a lag.
    let better = |a: Option<GroundTruthLag>, b: Option<GroundTruthLag>| match (a, b) {
        (Some(a), Some(b)) => Some(if b.correlation > a.correlation { b } else { a }),
        (a, b) => a.or(b),
    };
    let raw = lag_search(&gyro_mean, &gt_rate_vec, None, period, max_lag);
    let first = lag_search(&gyro_mean, &gt_rate_vec, Some(0), period, max_lag);
    let again = first
        .filter(|f| f.lag_s.abs() > GROUND_TRUTH_LAG_TOLERANCE_S)
        .and_then(|f| lag_search(&gyro_mean, &gt_rate_vec, Some((f.lag_s / period).round() as i64), period, max_lag));
    better(better(raw, first), again)
}

/// [`ground_truth_lag`]'s search on the centred gyro means and ground-truth rates, the gyro's
/// bias measured with the ground truth paired `bias_lag` samples later (`None`: not taken off).
fn lag_search(
    gyro_mean: &[Option<nalgebra::Vector3<f64>>],
    gt_rate_vec: &[Option<nalgebra::Vector3<f64>>],
    bias_lag: Option<i64>,
    period: f64,
    max_lag: i64,
) -> Option<GroundTruthLag> {
    // A gyro bias comparable to the motion (a consumer IMU on a slowly turning car) skews the
    // norm's peak by tens of ms: the mean difference of the rates (paired at `bias_lag`) is taken
    // off first. A frame mix-up only leaves the mean rotation rate's share in it.
    let (mut diff, mut count) = (nalgebra::Vector3::zeros(), 0usize);
    for (k, g) in gyro_mean.iter().enumerate().filter(|_| bias_lag.is_some()) {
        let r = usize::try_from(k as i64 + bias_lag.unwrap_or(0)).ok().and_then(|j| gt_rate_vec.get(j)).copied().flatten();
        if let (Some(g), Some(r)) = (g, r) {
            diff += g - r;
            count += 1;
        }
    }
    let bias = if count > 0 { diff / count as f64 } else { nalgebra::Vector3::zeros() };
    let gyro_norm: Vec<f64> = gyro_mean.iter().map(|g| g.map_or(f64::NAN, |g| (g - bias).norm())).collect();
    let gt_rate: Vec<f64> = gt_rate_vec.iter().map(|r| r.map_or(f64::NAN, |r| r.norm())).collect();
    // A clock offset beyond the search would otherwise go unsaid (the best lag inside it is
    // then at its edge, or too weak to trust): a coarse search over 0.05-s block means first,
    // and the fine search also covers its peak when that lies outside.
    let block = ((COARSE_BLOCK_S / period).round() as usize).max(1);
    let (coarse_gyro, coarse_gt) = (block_means(&gyro_norm, block), block_means(&gt_rate, block));
    let coarse_max = ((COARSE_LAG_SEARCH_S / (block as f64 * period)).round() as usize).min(coarse_gyro.len() / 2) as i64;
    let coarse_min_pairs = (MIN_LAG_PAIRS / block).max(20);
    let coarse: Vec<(i64, Option<f64>)> =
        (-coarse_max..=coarse_max).map(|l| (l * block as i64, lag_correlation(&coarse_gyro, &coarse_gt, l, coarse_min_pairs))).collect();
    // The coarse search's best peaks (a periodic gait has one a step period from the true one,
    // almost as high on block means), and zero lag.
    let mut peaks: Vec<(i64, f64)> = (0..coarse.len())
        .filter_map(|i| {
            let (l, c) = (coarse[i].0, coarse[i].1?);
            let left = i.checked_sub(1).and_then(|j| coarse[j].1).unwrap_or(f64::NEG_INFINITY);
            let right = coarse.get(i + 1).and_then(|x| x.1).unwrap_or(f64::NEG_INFINITY);
            let candidate = l.abs() <= max_lag || c >= GROUND_TRUTH_LAG_MIN_CORRELATION;
            (candidate && c >= left && c >= right).then_some((l, c))
        })
        .collect();
    peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
    // Of peaks that tie with the best (exactly periodic motion), the nearest to zero either
    // side are visited too: the pick below prefers them.
    let top = peaks.first().map_or(f64::NAN, |p| p.1);
    let ties = |positive: bool| {
        peaks.iter().filter(|p| (p.0 > 0) == positive && p.0 != 0 && ties_with(p.1, top)).min_by_key(|p| p.0.abs()).copied()
    };
    let nearest = [ties(true), ties(false)];
    peaks.truncate(COARSE_PEAKS);
    peaks.extend(nearest.into_iter().flatten());
    peaks.push((0, f64::NAN));
    peaks.sort_by_key(|p| p.0);
    // The fine search, at every sample, covers two blocks either side of each (within ±1 s
    // only, inside the reach; anywhere beyond it); the best fine correlation decides.
    let mut lags: Vec<i64> = Vec::new();
    for &(l, c) in &peaks {
        tracing::trace!("clock-lag coarse peak at {:.3} s (r {c:.3})", l as f64 * period);
        let range = (l - 2 * block as i64..=l + 2 * block as i64).filter(|x| l.abs() > max_lag || x.abs() <= max_lag);
        for x in range {
            match lags.last() {
                Some(&last) if last != i64::MIN && x <= last => {}
                // Kept apart from the other ranges by a gap: their ends are not neighbours in the peak fit.
                Some(&last) if last != i64::MIN && x > last + 1 => {
                    lags.push(i64::MIN);
                    lags.push(x);
                }
                _ => lags.push(x),
            }
        }
    }
    let corr: Vec<Option<f64>> =
        lags.iter().map(|&l| if l == i64::MIN { None } else { lag_correlation(&gyro_norm, &gt_rate, l, MIN_LAG_PAIRS) }).collect();
    let (_, top) = corr.iter().enumerate().filter_map(|(i, c)| c.map(|c| (i, c))).max_by(|a, b| a.1.total_cmp(&b.1))?;
    // Peaks as high as the best within what the data can tell (exactly periodic motion: a gait
    // on a treadmill), the one nearest zero: clocks are far more often aligned than a whole
    // number of periods apart (a query span picked 20 s from peaks at 0, 10 and 20 s, r 0.998).
    let is_peak = |i: usize| {
        let c = corr[i].unwrap_or(f64::NEG_INFINITY);
        let side = |j: Option<usize>| j.and_then(|j| corr.get(j).copied().flatten()).unwrap_or(f64::NEG_INFINITY);
        c >= side(i.checked_sub(1)) && c >= side(Some(i + 1))
    };
    let (best, c) = (0..corr.len())
        .filter(|&i| corr[i].is_some_and(|c| ties_with(c, top)) && is_peak(i))
        .map(|i| (i, corr[i].unwrap_or(top)))
        .min_by_key(|&(i, _)| lags[i].unsigned_abs())?;
    // Sub-sample peak: the parabola through the best lag and its neighbours.
    let shift = match (best.checked_sub(1).and_then(|i| corr[i]), corr.get(best + 1).copied().flatten()) {
        (Some(l), Some(r)) if l - 2.0 * c + r < 0.0 => (0.5 * (l - r) / (l - 2.0 * c + r)).clamp(-0.5, 0.5),
        _ => 0.0,
    };
    Some(GroundTruthLag { lag_s: (lags[best] as f64 + shift) * period, correlation: c })
}

/// A correlation `c` ties with the best one `top` ([`lag_search`]) when it is below it by at
/// most 1e-4: exactly periodic motion, whose peaks differ only by the edges of the overlap.
/// Noisy data never ties this closely (a tolerance scaled by 1 − r took a noisy trot's true
/// 2-s lag for 0).
fn ties_with(c: f64, top: f64) -> bool {
    top - c <= 1e-4
}

/// Block length (s) and reach (s, either way) of [`ground_truth_lag`]'s coarse search.
const COARSE_BLOCK_S: f64 = 0.05;
const COARSE_LAG_SEARCH_S: f64 = 30.0;
/// Coarse peaks the fine search visits (besides zero lag).
const COARSE_PEAKS: usize = 3;

/// Means of consecutive blocks of `len` values, over the finite ones (NaN where none is).
fn block_means(x: &[f64], len: usize) -> Vec<f64> {
    x.chunks(len)
        .map(|b| {
            let (sum, count) = b.iter().filter(|v| v.is_finite()).fold((0.0, 0usize), |(s, c), v| (s + v, c + 1));
            if count > 0 {
                sum / count as f64
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// Pearson correlation of `a[k]` with `b[k + lag]` over the pairs where both are finite;
/// `None` with fewer than `min_pairs` of them or no variance.
fn lag_correlation(a: &[f64], b: &[f64], lag: i64, min_pairs: usize) -> Option<f64> {
    let skip = lag.unsigned_abs() as usize;
    if skip >= a.len().min(b.len()) {
        return None;
    }
    let (a, b) = if lag >= 0 { (a, &b[skip..]) } else { (&a[skip..], b) };
    let (mut m, mut sa, mut sb, mut saa, mut sbb, mut sab) = (0usize, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (&x, &y) in a.iter().zip(b) {
        if x.is_finite() && y.is_finite() {
            m += 1;
            sa += x;
            sb += y;
            saa += x * x;
            sbb += y * y;
            sab += x * y;
        }
    }
    if m < min_pairs {
        return None;
    }
    let m = m as f64;
    let (va, vb) = (saa - sa * sa / m, sbb - sb * sb / m);
    (va > 0.0 && vb > 0.0).then(|| (sab - sa * sb / m) / (va * vb).sqrt())
}
