//! The residual r = real − sim and its noise model.
//!
//! Under the simulator's own noise model the residual of one channel is
//! r_k = W_k + z_k − n_k: the difference of two independent bias walks W (a random walk
//! from W_0 = 0 of per-step variance q, estimated), the real white noise z (variance σ_r²,
//! passed through a first-order low-pass of pole `pole` when the real sensor filters) and
//! the sim white noise n (variance σ_s², from the sim bag's covariance fields). A 2-state
//! Kalman filter for (W, z) turns the residual — and any regressor — into one-step-ahead
//! innovations ν_k with variances S_k: whitened, ν_k/√S_k i.i.d. N(0, 1) under the model.
//! Regressing whitened residual on whitened regressors is generalised least squares with
//! the bias walk as a nuisance, and Σ log S_k completes the Gaussian log-likelihood.
//!
//! The regressors themselves are built by the physics terms from the sim bag's signals,
//! smoothed first ([`base_signals`]): a local quadratic fit that leaves the centre sample
//! out, so the sim's own noise at sample k (which is in r_k with a minus sign) does not
//! correlate with the regressor at k and bias the fit.

use nalgebra::{DMatrix, DVector, Vector3};

use super::align::Aligned;
use crate::physics::ImuSignals;

/// Channel index → sensor (0 gyro, 1 accel).
pub fn sensor_of(channel: usize) -> usize {
    channel / 3
}

/// Names of the six channels.
pub const CHANNELS: [&str; 6] = ["gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"];

/// Weights of a leave-centre-out local quadratic fit over ±k samples, evaluated at the
/// centre (index 0 of the returned vec is offset −k; the centre weight is 0).
pub fn leave_out_weights(k: usize) -> Vec<f64> {
    leave_out_poly_weights(k, if k == 1 { 1 } else { 2 })
}

/// Weights of a leave-centre-out local polynomial fit of degree `deg` (lowered to what the
/// points allow) to the samples at `offsets` (none 0), evaluated at offset 0.
fn leave_out_fit_weights(offsets: &[i64], deg: usize) -> Vec<f64> {
    let scale = offsets.iter().map(|o| o.unsigned_abs()).max().unwrap_or(1).max(1) as f64;
    let deg = deg.min(offsets.len().saturating_sub(1));
    let v = DMatrix::from_fn(offsets.len(), deg + 1, |r, c| (offsets[r] as f64 / scale).powi(c as i32));
    let pinv = (v.transpose() * &v).try_inverse().unwrap_or_else(|| DMatrix::identity(deg + 1, deg + 1)) * v.transpose();
    (0..offsets.len()).map(|r| pinv[(0, r)]).collect()
}

/// Weights of a leave-centre-out local polynomial fit of degree `deg` over ±k samples,
/// evaluated at the centre (index 0 of the returned vec is offset −k; the centre weight is 0).
pub fn leave_out_poly_weights(k: usize, deg: usize) -> Vec<f64> {
    let offs: Vec<i64> = (-(k as i64)..=k as i64).filter(|&j| j != 0).collect();
    let fit = leave_out_fit_weights(&offs, deg);
    let mut w = vec![0.0; 2 * k + 1];
    for (o, f) in offs.iter().zip(fit) {
        w[(o + k as i64) as usize] = f;
    }
    w
}

/// Leave-centre-out smoothing of `x`: each sample replaced by the local polynomial (degree
/// `deg`) through its ±k neighbours, itself left out, so the sample's own noise is not in
/// its smoothed value. Within k samples of an end the window is cut at the end (a one-sided
/// fit, still without the sample itself), so no sample keeps its own noise.
pub fn smooth_leave_out(x: &[f64], k: usize, deg: usize) -> Vec<f64> {
    let n = x.len();
    let w = leave_out_poly_weights(k, deg);
    (0..n)
        .map(|i| {
            if i >= k && i + k < n {
                return w.iter().enumerate().map(|(j, wj)| wj * x[i + j - k]).sum();
            }
            let lo = -(i.min(k) as i64);
            let hi = (n - 1 - i).min(k) as i64;
            let offs: Vec<i64> = (lo..=hi).filter(|&j| j != 0).collect();
            if offs.is_empty() {
                return x[i];
            }
            let fw = leave_out_fit_weights(&offs, deg);
            offs.iter().zip(fw).map(|(o, f)| f * x[(i as i64 + o) as usize]).sum()
        })
        .collect()
}

/// The leave-centre-out smoother of one sensor's channels (half-width k, degree), chosen by
/// leave-one-out cross-validation: among local polynomials of degree 2 or 4 over ±k
/// samples, k·dt up to `max_half_s`, the one whose prediction of each sim sample from its
/// neighbours has the smallest mean squared error. That error is σ² + E(b − x)² (the
/// prediction does not use the sample's own noise), so the choice minimises the smoothed
/// signal's own error (distortion² + leftover noise), instead of a fixed window, which at
/// low rates (±1 sample at 100 Hz) distorts the motion's higher harmonics by (2πf·dt)²/2
/// and leaves a misfit of every term applied to it that other terms then mop up.
pub fn cv_smoother(x: &[Vec<f64>], dt: f64, max_half_s: f64) -> (usize, usize) {
    let k_max = ((max_half_s / dt).round() as usize).max(1);
    let mut best: Option<(f64, (usize, usize))> = None;
    for k in [1usize, 2, 3, 4, 6, 8, 11, 16, 22, 32, 45, 64].into_iter().filter(|&k| k <= k_max) {
        // A symmetric fit of even degree d needs k ≥ d/2 + 1 offsets per side; k = 1 is the
        // mean of the two neighbours.
        let degs: &[usize] = if k == 1 { &[1] } else { &[2, 4] };
        for &deg in degs.iter().filter(|&&d| k > d / 2) {
            let (sse, cnt) = x.iter().fold((0.0, 0usize), |(s, c), ch| {
                let b = smooth_leave_out(ch, k, deg);
                (s + ch.iter().zip(&b).map(|(v, b)| (v - b) * (v - b)).sum::<f64>(), c + ch.len())
            });
            let mse = sse / cnt.max(1) as f64;
            if best.is_none_or(|(m, _)| mse < m) {
                best = Some((mse, (k, deg)));
            }
        }
    }
    best.map_or((1, 1), |(_, kd)| kd)
}

/// Mean square of the leave-out error, against its noise-only level, above which the motion
/// is taken to be sharper than the smoother there: over 5 samples and 3 channels (15 degrees
/// of freedom) the noise alone exceeds 3 with probability ≈ 5·10⁻⁵.
const SHARP_MOTION_TRIGGER: f64 = 3.0;
/// Half-width (samples) of the window the leave-out error's mean square is taken over.
const SHARP_MOTION_HALF: usize = 2;

/// Puts back, in one sensor's smoothed channels, the motion the smoother rounded off.
///
/// Where the sim's motion is sharper than the smoother (a foot impact, a step), the smoothed
/// signal rounds it, and every term's regressor there misses the term's effect by θ times
/// the rounding — a structured misfit that other terms then partly absorb. The leave-out
/// error e = x − x̂ is the sim's white noise plus that rounding; its mean square ē² over
/// ±[`SHARP_MOTION_HALF`] samples and the three channels, against the noise-only level
/// σ²(1 + Σw²), tells the two apart. Where ē² exceeds [`SHARP_MOTION_TRIGGER`] times that
/// level, the rounding is restored shrunk by the noise's share, x̂ + (1 − σ²(1 + Σw²)/ē²)·e
/// (a positive-part James–Stein estimate); elsewhere x̂ stands. The sample's own noise
/// thus enters a regressor only where the motion dominates it, so its correlation with
/// the residual (−σ² per sample) is small beside the signal there. Returns the number of
/// samples restored.
pub fn restore_sharp_motion(x: &[Vec<f64>], smooth: &mut [Vec<f64>], k: usize, deg: usize, white_sim: f64) -> usize {
    let n = x.first().map_or(0, Vec::len);
    if n == 0 || white_sim.is_nan() || white_sim <= 0.0 {
        return 0;
    }
    let level = white_sim * (1.0 + leave_out_poly_weights(k, deg).iter().map(|w| w * w).sum::<f64>());
    let e2: Vec<f64> = (0..n).map(|i| x.iter().zip(smooth.iter()).map(|(xc, sc)| (xc[i] - sc[i]).powi(2)).sum::<f64>()).collect();
    let mut cum = vec![0.0; n + 1];
    for i in 0..n {
        cum[i + 1] = cum[i] + e2[i];
    }
    let mut restored = 0;
    for i in 0..n {
        let (lo, hi) = (i.saturating_sub(SHARP_MOTION_HALF), (i + SHARP_MOTION_HALF).min(n - 1));
        let mean = (cum[hi + 1] - cum[lo]) / ((hi + 1 - lo) * x.len()) as f64;
        if mean > SHARP_MOTION_TRIGGER * level {
            let w = 1.0 - level / mean;
            for (xc, sc) in x.iter().zip(smooth.iter_mut()) {
                sc[i] += w * (xc[i] - sc[i]);
            }
            restored += 1;
        }
    }
    restored
}

/// Half-width (samples) of the window over which the sim gyro's departure from the
/// ground-truth gyro is tested: 9 samples × 3 channels, so that noise alone (which the
/// derivative then amplifies by 1/dt) almost never passes the test.
const SHARP_ALPHA_HALF: usize = 4;

/// Half-widths (samples) of the derivative stencils [`sharp_angular_acceleration`] chooses from.
const ALPHA_STENCILS: [usize; 8] = [1, 2, 3, 4, 6, 8, 11, 16];

/// ω̇ for the regressors: the ground truth's, with the sharp motion it misses put back.
///
/// Ground-truth poses (100 Hz, or the IMU rate when lower) differentiated twice give a
/// noise-free ω̇ on smooth motion, but round off a foot impact of a few ms completely (on
/// the generated quadrupeds ω̇ from the poses is 40–50 % off in RMS), and the lever arm's
/// tangential atom ω̇ × r then misses its own effect there, which accelerometer terms absorb.
/// The sim gyro carries the impact (with its noise): d = gyro_sim − gyro_gt is noise where
/// the ground truth follows the motion and noise plus the impact where it does not. d is
/// kept, shrunk by the noise's share (positive-part James–Stein, as in
/// [`restore_sharp_motion`]), where its mean square over ±[`SHARP_ALPHA_HALF`] samples and
/// three channels exceeds [`SHARP_MOTION_TRIGGER`] × its noise level, and zeroed elsewhere;
/// its derivative is added to the ground truth's ω̇. The derivative's half-width k (slope
/// of a local line) is the one of least estimated risk on the kept samples: the mean square
/// of c_k − c_1 less its noise part, plus c_k's noise variance (a wider stencil is quieter
/// but rounds the impact; c_1, the central difference, is taken as unbiased). The gyro
/// noise in it is independent of the accelerometer residual the lever arm explains, so it
/// biases nothing there; only ω̇ of the smooth parts stays the ground truth's.
pub fn sharp_angular_acceleration(
    gt_alpha: &[Vector3<f64>],
    gt_gyro: &[Vector3<f64>],
    sim_gyro: &[Vec<f64>],
    white_sim: f64,
    dt: f64,
) -> (Vec<Vector3<f64>>, usize) {
    let n = gt_alpha.len();
    let mut alpha = gt_alpha.to_vec();
    if n == 0 || white_sim.is_nan() || white_sim <= 0.0 || gt_gyro.len() != n || sim_gyro.iter().any(|c| c.len() != n) {
        return (alpha, 0);
    }
    let d: Vec<Vector3<f64>> = (0..n).map(|i| Vector3::new(sim_gyro[0][i], sim_gyro[1][i], sim_gyro[2][i]) - gt_gyro[i]).collect();
    let mut cum = vec![0.0; n + 1];
    for i in 0..n {
        cum[i + 1] = cum[i] + d[i].norm_squared();
    }
    let mut kept = vec![Vector3::zeros(); n];
    let mut on = Vec::new();
    for i in 0..n {
        let (lo, hi) = (i.saturating_sub(SHARP_ALPHA_HALF), (i + SHARP_ALPHA_HALF).min(n - 1));
        let mean = (cum[hi + 1] - cum[lo]) / (3 * (hi + 1 - lo)) as f64;
        if mean > SHARP_MOTION_TRIGGER * white_sim {
            kept[i] = d[i] * (1.0 - white_sim / mean);
            on.push(i);
        }
    }
    if on.is_empty() {
        return (alpha, 0);
    }
    // Stencil of half-width k as weights over ±kmax (zero outside ±k).
    let kmax = ALPHA_STENCILS.iter().copied().filter(|&k| 2 * k < n).max().unwrap_or(1);
    let stencil = |k: usize| -> Vec<f64> {
        let mut w = vec![0.0; 2 * kmax + 1];
        for (j, v) in derivative_weights(k).into_iter().enumerate() {
            w[kmax - k + j] = v / dt;
        }
        w
    };
    let apply = |w: &[f64], i: usize| -> Vector3<f64> {
        if i < kmax || i + kmax >= n {
            return Vector3::zeros();
        }
        w.iter().enumerate().filter(|(_, v)| **v != 0.0).map(|(j, v)| kept[i + j - kmax] * *v).sum()
    };
    let w1 = stencil(1);
    let c1: Vec<Vector3<f64>> = on.iter().map(|&i| apply(&w1, i)).collect();
    let mut best = (f64::INFINITY, w1.clone());
    for k in ALPHA_STENCILS.into_iter().filter(|&k| k <= kmax) {
        let wk = stencil(k);
        let var_k = white_sim * wk.iter().map(|v| v * v).sum::<f64>();
        let var_diff = white_sim * wk.iter().zip(&w1).map(|(a, b)| (a - b) * (a - b)).sum::<f64>();
        let ms = on.iter().zip(&c1).map(|(&i, c)| (apply(&wk, i) - c).norm_squared() / 3.0).sum::<f64>() / on.len() as f64;
        let risk = ms - var_diff + var_k;
        if risk < best.0 {
            best = (risk, wk);
        }
    }
    // The derivative reaches kmax samples either side of a kept sample.
    let mut near = vec![false; n];
    for &i in &on {
        near[i.saturating_sub(kmax)..=(i + kmax).min(n - 1)].iter_mut().for_each(|v| *v = true);
    }
    for i in (0..n).filter(|&i| near[i]) {
        alpha[i] += apply(&best.1, i);
    }
    (alpha, on.len())
}

/// Savitzky–Golay first-derivative weights over ±k samples (per unit sample spacing).
pub fn derivative_weights(k: usize) -> Vec<f64> {
    let s: f64 = (1..=k).map(|j| 2.0 * (j * j) as f64).sum();
    (-(k as i64)..=k as i64).map(|j| j as f64 / s).collect()
}

/// Convolve with symmetric-window weights; the first and last `k` samples keep `edge`.
pub fn filter(x: &[f64], w: &[f64], edge: impl Fn(usize) -> f64) -> Vec<f64> {
    let k = w.len() / 2;
    (0..x.len())
        .map(|i| if i < k || i + k >= x.len() { edge(i) } else { w.iter().enumerate().map(|(j, wj)| wj * x[i + j - k]).sum() })
        .collect()
}

/// The signals the terms are applied to: the sim bag's gyro and accel smoothed (leave-out
/// local polynomial, window and degree per sensor by cross-validation, [`cv_smoother`],
/// up to ±`max_smoothing_s`; where the motion is sharper than that smoother the rounding is
/// put back, [`restore_sharp_motion`]), ω̇ by a Savitzky–Golay derivative of the sim gyro
/// over ±2·`half_window_s`, attitude from ground truth (identity when there is none) and
/// temperature (25 °C when there is none).
/// `gt_smoothing`: half-width of the local cubic the ground truth is smoothed by before ω̇ is
/// taken from it (a measured ground truth; `None` for a simulator's).
pub fn base_signals(a: &Aligned, half_window_s: f64, max_smoothing_s: f64, gt_smoothing: Option<f64>) -> ImuSignals {
    let dt = a.dt();
    let kd = ((2.0 * half_window_s / dt).round() as usize).max(1);
    let var = [a.sim_variance.0, a.sim_variance.1];
    let wd = derivative_weights(kd);
    // Window means: the sim's noise is divided by the window's length (its errors-in-variables
    // pull on a scale, −σ²/⟨ω²⟩, is then ~1e-6) while a smoother at the window rate would
    // round the motion itself, so the means are the regressors' signals as they are.
    let full_rate = a.samples_per_point == 1;
    let kdeg = if full_rate {
        [cv_smoother(&a.sim[..3], dt, max_smoothing_s), cv_smoother(&a.sim[3..], dt, max_smoothing_s)]
    } else {
        [(0, 0); 2]
    };
    let mut smooth: [Vec<f64>; 6] =
        std::array::from_fn(|c| if full_rate { smooth_leave_out(&a.sim[c], kdeg[c / 3].0, kdeg[c / 3].1) } else { a.sim[c].clone() });
    for s in (0..2).filter(|_| full_rate) {
        let r = restore_sharp_motion(&a.sim[3 * s..3 * s + 3], &mut smooth[3 * s..3 * s + 3], kdeg[s].0, kdeg[s].1, var[s]);
        tracing::debug!("sensor {s}: smoother (±{}, degree {}), sharp motion restored at {r} of {} samples", kdeg[s].0, kdeg[s].1, a.len());
    }
    let deriv: [Vec<f64>; 3] = std::array::from_fn(|c| {
        let x = &a.sim[c];
        let n = x.len();
        filter(x, &wd, |i| {
            let (l, r) = (i.saturating_sub(1), (i + 1).min(n - 1));
            (x[r] - x[l]) / ((r - l).max(1) as f64)
        })
        .into_iter()
        .map(|v| v / dt)
        .collect()
    });
    let n = a.len();
    let v3 = |ch: &[Vec<f64>], i: usize| Vector3::new(ch[0][i], ch[1][i], ch[2][i]);
    // ω̇ from the noise-free ground truth when there is one (a derivative of the noisy sim gyro
    // is noise-dominated on gentle motion), else from the sim gyro.
    let gt = &a.sim_recording.ground_truth;
    if !full_rate && gt.len() >= 4 {
        if let Some((alpha, _)) = super::bandwidth::window_mean_derivatives(a, gt_smoothing) {
            return ImuSignals {
                stamps_ns: a.stamps_ns.clone(),
                world_from_imu: a.world_from_imu.clone().unwrap_or_else(|| vec![nalgebra::UnitQuaternion::identity(); n]),
                alpha_in_imu: alpha,
                temperature_c: a.temperature_c.clone().unwrap_or_else(|| vec![25.0; n]),
                gyro: (0..n).map(|i| v3(&smooth[..3], i)).collect(),
                accel: (0..n).map(|i| v3(&smooth[3..], i)).collect(),
            };
        }
    }
    let alpha_in_imu = match (gt.len() >= 4, super::kinematics::ideal_from_poses_with(gt, &a.stamps_ns, gt_smoothing)) {
        (true, Ok(s)) => {
            let (alpha, kept) = sharp_angular_acceleration(&s.alpha_in_imu, &s.gyro, &a.sim[..3], var[0], dt);
            tracing::debug!("ω̇: ground truth's, sharp motion from the sim gyro at {kept} of {n} samples");
            alpha
        }
        _ => (0..n).map(|i| v3(&deriv, i)).collect(),
    };
    ImuSignals {
        stamps_ns: a.stamps_ns.clone(),
        world_from_imu: a.world_from_imu.clone().unwrap_or_else(|| vec![nalgebra::UnitQuaternion::identity(); n]),
        alpha_in_imu,
        temperature_c: a.temperature_c.clone().unwrap_or_else(|| vec![25.0; n]),
        gyro: (0..n).map(|i| v3(&smooth[..3], i)).collect(),
        accel: (0..n).map(|i| v3(&smooth[3..], i)).collect(),
    }
}

/// The noise model of one sensor's residual channels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelNoise {
    /// Sim white-noise variance per sample.
    pub white_sim: f64,
    /// Real white-noise variance per sample (before the real low-pass).
    pub white_real: f64,
    /// Pole of the real sensor's first-order low-pass, e^{−ω_c dt} (0: none).
    pub pole: f64,
    /// Per-step variance of the residual bias walk.
    pub walk: f64,
}

/// Noise model of both sensors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResidualNoise {
    pub sensors: [ChannelNoise; 2],
}

/// Kalman gains of one channel's noise model; whitening is then linear in the data.
#[derive(Debug, Clone)]
pub struct Whitener {
    gains: Vec<[f64; 2]>,
    inv_sqrt_s: Vec<f64>,
    pole: f64,
    /// Σ ln S_k over each sample.
    pub log_s: Vec<f64>,
}

impl Whitener {
    pub fn new(noise: &ChannelNoise, mask: &[bool]) -> Self {
        let n = mask.len();
        let a = noise.pole;
        let qz = (1.0 - a).powi(2) * noise.white_real;
        // P = [[p00, p01], [p01, p11]]; W_0 = 0 exactly up to one step of walk.
        let (mut p00, mut p01, mut p11) = (noise.walk, 0.0, noise.white_real);
        let mut gains = Vec::with_capacity(n);
        let mut inv_sqrt_s = Vec::with_capacity(n);
        let mut log_s = Vec::with_capacity(n);
        for &m in mask {
            if m {
                let s = p00 + 2.0 * p01 + p11 + noise.white_sim;
                let k0 = (p00 + p01) / s;
                let k1 = (p01 + p11) / s;
                // P − K S Kᵀ
                p00 -= k0 * k0 * s;
                p01 -= k0 * k1 * s;
                p11 -= k1 * k1 * s;
                gains.push([k0, k1]);
                inv_sqrt_s.push(1.0 / s.sqrt());
                log_s.push(s.ln());
            } else {
                gains.push([0.0, 0.0]);
                inv_sqrt_s.push(0.0);
                log_s.push(0.0);
            }
            // Predict: F = diag(1, a), Q = diag(q, (1−a)² σ_r²).
            p00 += noise.walk;
            p01 *= a;
            p11 = a * a * p11 + qz;
        }
        Whitener { gains, inv_sqrt_s, pole: a, log_s }
    }

    /// Whitened innovations of `x` (0 at masked samples).
    pub fn whiten(&self, x: &[f64]) -> Vec<f64> {
        let (mut w, mut z) = (0.0, 0.0);
        let mut out = Vec::with_capacity(x.len());
        for (k, &xk) in x.iter().enumerate() {
            let [k0, k1] = self.gains[k];
            let nu = xk - w - z;
            out.push(nu * self.inv_sqrt_s[k]);
            w += k0 * nu;
            z = self.pole * (z + k1 * nu);
        }
        out
    }
}

/// Sufficient statistics of a whitened regression over one time block.
#[derive(Debug, Clone)]
pub struct BlockStats {
    /// Σ x̃ x̃ᵀ over the regressors.
    pub gram: DMatrix<f64>,
    /// Σ x̃ ỹ.
    pub xy: DVector<f64>,
    /// Σ ỹ².
    pub yy: f64,
    /// Σ ln S.
    pub log_s: f64,
    /// Samples (per channel, summed over channels).
    pub n: f64,
}

impl BlockStats {
    pub fn zeros(p: usize) -> Self {
        BlockStats { gram: DMatrix::zeros(p, p), xy: DVector::zeros(p), yy: 0.0, log_s: 0.0, n: 0.0 }
    }

    pub fn add(&mut self, o: &BlockStats) {
        self.gram += &o.gram;
        self.xy += &o.xy;
        self.yy += o.yy;
        self.log_s += o.log_s;
        self.n += o.n;
    }

    /// Gaussian log-likelihood of the block at regression coefficients θ (with an offset
    /// already folded into the data), whitened units.
    pub fn loglik(&self, theta: &DVector<f64>) -> f64 {
        let ssr = self.yy - 2.0 * theta.dot(&self.xy) + (theta.transpose() * &self.gram * theta)[(0, 0)];
        -0.5 * (ssr + self.log_s + self.n * (2.0 * std::f64::consts::PI).ln())
    }
}

/// Regressor columns: per channel, `None` when the regressor is zero there.
pub type Column = [Option<Vec<f64>>; 6];

/// Whiten the residual and the columns under `noise` and sum the statistics per time block.
/// `blocks` are sample ranges covering the recording.
pub fn block_stats(
    y: &[Vec<f64>; 6],
    columns: &[&Column],
    noise: &ResidualNoise,
    mask: &[bool],
    blocks: &[std::ops::Range<usize>],
) -> Vec<BlockStats> {
    let p = columns.len();
    let mut out: Vec<BlockStats> = blocks.iter().map(|_| BlockStats::zeros(p)).collect();
    for c in 0..6 {
        let wh = Whitener::new(&noise.sensors[sensor_of(c)], mask);
        let yt = wh.whiten(&y[c]);
        let active: Vec<(usize, Vec<f64>)> =
            columns.iter().enumerate().filter_map(|(j, col)| col[c].as_ref().map(|x| (j, wh.whiten(x)))).collect();
        for (b, r) in blocks.iter().enumerate() {
            let s = &mut out[b];
            s.yy += yt[r.clone()].iter().map(|v| v * v).sum::<f64>();
            s.log_s += wh.log_s[r.clone()].iter().sum::<f64>();
            s.n += mask[r.clone()].iter().filter(|m| **m).count() as f64;
            for (ai, (j, xj)) in active.iter().enumerate() {
                s.xy[*j] += dot(&xj[r.clone()], &yt[r.clone()]);
                for (l, xl) in &active[ai..] {
                    let v = dot(&xj[r.clone()], &xl[r.clone()]);
                    s.gram[(*j, *l)] += v;
                    if l != j {
                        s.gram[(*l, *j)] += v;
                    }
                }
            }
        }
    }
    out
}

pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// `n` samples split into `k` contiguous blocks of (nearly) equal length.
pub fn blocks(n: usize, k: usize) -> Vec<std::ops::Range<usize>> {
    let k = k.clamp(1, n.max(1));
    (0..k).map(|b| b * n / k..(b + 1) * n / k).collect()
}

/// Whitened residual channels (innovations / √S) under a noise model.
pub fn whitened(y: &[Vec<f64>; 6], noise: &ResidualNoise, mask: &[bool]) -> [Vec<f64>; 6] {
    std::array::from_fn(|c| Whitener::new(&noise.sensors[sensor_of(c)], mask).whiten(&y[c]))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Deterministic uniform pseudo-noise in [0, 1) (an LCG), so the tests need no RNG crate.
    pub(crate) fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// Near-Gaussian pseudo-noise of variance 1: the sum of 12 uniforms, less 6.
    fn near_gaussian(seed: u64) -> impl FnMut() -> f64 {
        let mut u = uniform(seed);
        move || (0..12).map(|_| u()).sum::<f64>() - 6.0
    }

    /// The leave-out smoother reproduces polynomials up to its degree exactly, also within k
    /// samples of the ends (one-sided fits), and never uses the sample itself.
    #[test]
    fn leave_out_smoother_is_exact_on_polynomials_and_ignores_the_sample() {
        let n = 60;
        let x: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / 10.0;
                1.0 - 2.0 * t + 0.5 * t * t - 0.3 * t.powi(3) + 0.05 * t.powi(4)
            })
            .collect();
        // k ≥ deg + 1: enough points for the full degree also at the ends.
        for (k, deg) in [(5, 4), (8, 4), (3, 2)] {
            let quadratic_only = deg == 2;
            let xs: Vec<f64> =
                if quadratic_only { (0..n).map(|i| 1.0 + 0.1 * i as f64 - 0.01 * (i * i) as f64).collect() } else { x.clone() };
            let b = smooth_leave_out(&xs, k, deg);
            for i in 0..n {
                assert!((b[i] - xs[i]).abs() < 1e-7 * xs[i].abs().max(1.0), "k {k} deg {deg} i {i}: {} vs {}", b[i], xs[i]);
            }
            // A spike at sample i changes the smoothed value at i not at all.
            for i in [0, k / 2, n / 2, n - 1] {
                let mut y = xs.clone();
                y[i] += 100.0;
                assert!((smooth_leave_out(&y, k, deg)[i] - b[i]).abs() < 1e-9);
            }
        }
    }

    /// Cross-validation picks a wide window on a slow signal in noise and a narrow one on a
    /// fast signal with little noise.
    #[test]
    fn cv_smoother_widens_for_slow_signals_and_narrows_for_fast_ones() {
        let dt = 0.001;
        let n = 20_000;
        // Deterministic pseudo-noise, variance 1/12.
        let mut u = uniform(12345);
        let mut noise = || u() - 0.5;
        let slow: Vec<f64> = (0..n).map(|i| (std::f64::consts::TAU * 0.5 * i as f64 * dt).sin() + noise()).collect();
        let fast: Vec<f64> = (0..n).map(|i| (std::f64::consts::TAU * 60.0 * i as f64 * dt).sin() + 1e-4 * noise()).collect();
        let (k_slow, _) = cv_smoother(&[slow], dt, 0.05);
        let (k_fast, _) = cv_smoother(&[fast], dt, 0.05);
        assert!(k_slow >= 32, "slow: k {k_slow}");
        assert!(k_fast <= 4, "fast: k {k_fast}");
    }

    /// Where the ground truth follows the motion, its ω̇ is kept as it is (the sim gyro's
    /// noise alone does not trigger); where it misses short impacts the sim gyro carries,
    /// they are put back and ω̇ comes much closer to the truth.
    #[test]
    fn sharp_angular_acceleration_puts_back_what_the_ground_truth_misses() {
        let dt = 0.0025;
        let n = 40_000;
        let mut gauss = near_gaussian(4242);
        let sigma = 0.01;
        let t = |i: usize| i as f64 * dt;
        let tau = std::f64::consts::TAU;
        // Smooth part (in the ground truth) and 10 ms Gaussian-derivative impacts every 0.5 s (not in it).
        let smooth = |i: usize, c: usize| (tau * 0.7 * t(i) + c as f64).sin();
        let smooth_dot = |i: usize, c: usize| tau * 0.7 * (tau * 0.7 * t(i) + c as f64).cos();
        let (sw, amp) = (0.01, 2.0);
        let x = |i: usize| (t(i) % 0.5 - 0.25) / sw;
        let impact = |i: usize| amp * x(i) * (-0.5 * x(i) * x(i)).exp();
        let impact_dot = |i: usize| amp / sw * (1.0 - x(i) * x(i)) * (-0.5 * x(i) * x(i)).exp();
        let gt_gyro: Vec<Vector3<f64>> = (0..n).map(|i| Vector3::new(smooth(i, 0), smooth(i, 1), smooth(i, 2))).collect();
        let gt_alpha: Vec<Vector3<f64>> = (0..n).map(|i| Vector3::new(smooth_dot(i, 0), smooth_dot(i, 1), smooth_dot(i, 2))).collect();
        for sharp in [false, true] {
            let truth: Vec<Vector3<f64>> = (0..n)
                .map(|i| {
                    gt_alpha[i] + if sharp { Vector3::new(impact_dot(i), -impact_dot(i), 0.5 * impact_dot(i)) } else { Vector3::zeros() }
                })
                .collect();
            let sim: Vec<Vec<f64>> = (0..3)
                .map(|c| {
                    let k = [1.0, -1.0, 0.5][c];
                    (0..n).map(|i| gt_gyro[i][c] + if sharp { k * impact(i) } else { 0.0 } + sigma * gauss()).collect()
                })
                .collect();
            let (alpha, kept) = sharp_angular_acceleration(&gt_alpha, &gt_gyro, &sim, sigma * sigma, dt);
            let rel = |a: &[Vector3<f64>]| {
                let num: f64 = (0..n).map(|i| (a[i] - truth[i]).norm_squared()).sum();
                let den: f64 = truth.iter().map(|v| v.norm_squared()).sum();
                (num / den).sqrt()
            };
            if sharp {
                assert!(kept > n / 100, "impacts: only {kept} samples kept");
                assert!(rel(&alpha) < 0.3 * rel(&gt_alpha), "impacts: {} vs ground truth's {}", rel(&alpha), rel(&gt_alpha));
            } else {
                assert!(kept <= n / 5000, "smooth motion: {kept} samples kept");
                assert!(rel(&alpha) < 1e-3, "smooth motion: ω̇ moved by {}", rel(&alpha));
            }
        }
    }

    /// On smooth motion in white noise the smoothed signal is left alone (the noise alone
    /// almost never triggers); at impacts the rounding the smoother left is mostly put back,
    /// so the base signal is closer to the noise-free motion there.
    #[test]
    fn sharp_motion_is_restored_only_where_the_smoother_rounds_it() {
        let dt = 0.01;
        let n = 20_000;
        let mut gauss = near_gaussian(777);
        let sigma = 0.05;
        let t = |i: usize| i as f64 * dt;
        let smooth_truth: Vec<Vec<f64>> =
            (0..3).map(|c| (0..n).map(|i| (std::f64::consts::TAU * 0.7 * t(i) + c as f64).sin()).collect()).collect();
        // Impacts: a 30 ms half-sine of 8 units every 0.5 s on top.
        let impact = |i: usize| {
            let ph = t(i) % 0.5;
            if ph < 0.03 {
                8.0 * (std::f64::consts::PI * ph / 0.03).sin()
            } else {
                0.0
            }
        };
        let sharp_truth: Vec<Vec<f64>> =
            smooth_truth.iter().map(|ch| ch.iter().enumerate().map(|(i, v)| v + impact(i)).collect()).collect();
        for (truth, sharp) in [(&smooth_truth, false), (&sharp_truth, true)] {
            let x: Vec<Vec<f64>> = truth.iter().map(|ch| ch.iter().map(|v| v + sigma * gauss()).collect()).collect();
            let (k, deg) = cv_smoother(&x, dt, 0.05);
            let plain: Vec<Vec<f64>> = x.iter().map(|ch| smooth_leave_out(ch, k, deg)).collect();
            let mut restored = plain.clone();
            let count = restore_sharp_motion(&x, &mut restored, k, deg, sigma * sigma);
            let err = |b: &[Vec<f64>]| -> f64 {
                let idx: Vec<usize> = (0..n).filter(|&i| !sharp || impact(i) > 0.0 || (i > 0 && impact(i - 1) > 0.0)).collect();
                (idx.iter().map(|&i| (0..3).map(|c| (b[c][i] - truth[c][i]).powi(2)).sum::<f64>()).sum::<f64>() / idx.len() as f64).sqrt()
            };
            if sharp {
                assert!(count > n / 50, "impacts: only {count} samples restored");
                assert!(err(&restored) < 0.5 * err(&plain), "impacts: {} vs smoothed {}", err(&restored), err(&plain));
            } else {
                // Overlapping windows make a noise excursion trigger a few neighbours at once.
                assert!(count <= n / 1000, "smooth motion: {count} samples restored");
            }
        }
    }
}
