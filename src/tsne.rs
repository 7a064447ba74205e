//! Exact t-SNE (van der Maaten & Hinton, JMLR 2008) for figures: a 2-D map of up to a few
//! thousand points, O(n²) time and memory, deterministic for a seed.
//!
//! 1. Per point i, the conditional affinities p_{j|i} ∝ exp(−β_i ‖x_i − x_j‖²) with β_i found
//!    by bisection so that the row's entropy equals ln(perplexity);
//! 2. P = (P_{j|i} + P_{i|j}) / 2n;
//! 3. gradient descent on KL(P‖Q) with Student-t Q, early exaggeration, momentum and the
//!    per-coordinate gains of the reference implementation.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

#[derive(Debug, thiserror::Error)]
pub enum TsneError {
    #[error("t-SNE needs at least 4 points, got {0}")]
    TooFewPoints(usize),
    #[error("point {index} has {got} coordinates, point 0 has {expected}")]
    Dimension { index: usize, got: usize, expected: usize },
    #[error("point {0} has a non-finite coordinate")]
    NonFinite(usize),
    #[error("invalid option: {0}")]
    Option(String),
}

/// Options of [`tsne`]. The defaults are the reference implementation's.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct TsneOptions {
    /// Effective number of neighbours; clamped to (n − 1) / 3 for small inputs.
    pub perplexity: f64,
    /// Gradient steps in all.
    pub iterations: usize,
    /// P is multiplied by this for the first `exaggeration_iterations` steps, so clusters
    /// form tight and far apart before the fine structure is laid out.
    pub early_exaggeration: f64,
    pub exaggeration_iterations: usize,
    /// Step size; `None`: max(n / early_exaggeration / 4, 50) (Belkina et al. 2019).
    pub learning_rate: Option<f64>,
    /// Seed of the initial layout N(0, 10⁻⁴ I).
    pub seed: u64,
}

impl Default for TsneOptions {
    fn default() -> Self {
        TsneOptions {
            perplexity: 30.0,
            iterations: 1000,
            early_exaggeration: 12.0,
            exaggeration_iterations: 250,
            learning_rate: None,
            seed: 0,
        }
    }
}

/// One calibrated row of conditional affinities.
#[derive(Debug, Clone)]
pub struct Calibrated {
    /// p_{j|i} for every j (0 at i itself); sums to 1.
    pub p: Vec<f64>,
    /// Precision β = 1 / 2σ².
    pub beta: f64,
    /// Shannon entropy of the row, nats.
    pub entropy: f64,
}

/// The conditional affinities of one point from its squared distances `d2` to all points
/// (`self_index` is excluded), with β bisected until the entropy is ln(perplexity) within
/// `tol` nats (or 200 halvings).
pub fn calibrate_row(d2: &[f64], self_index: usize, perplexity: f64, tol: f64) -> Calibrated {
    let target = perplexity.ln();
    let mut beta = 1.0;
    let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
    let mut p = vec![0.0; d2.len()];
    // Shift by the nearest distance so exp never underflows to all zeros.
    let d_min = d2.iter().enumerate().filter(|(j, _)| *j != self_index).map(|(_, d)| *d).fold(f64::INFINITY, f64::min);
    let d_min = if d_min.is_finite() { d_min } else { 0.0 };
    let mut entropy = 0.0;
    for _ in 0..200 {
        let mut sum = 0.0;
        let mut sum_dp = 0.0;
        for (j, (pj, d)) in p.iter_mut().zip(d2).enumerate() {
            *pj = if j == self_index { 0.0 } else { (-beta * (d - d_min)).exp() };
            sum += *pj;
            sum_dp += (d - d_min) * *pj;
        }
        // H = ln Σ + β Σ d p / Σ (with the shifted distances).
        entropy = sum.ln() + beta * sum_dp / sum;
        for pj in p.iter_mut() {
            *pj /= sum;
        }
        let diff = entropy - target;
        if diff.abs() < tol {
            break;
        }
        if diff > 0.0 {
            // Too flat: sharpen.
            lo = beta;
            beta = if hi.is_finite() { (beta + hi) / 2.0 } else { beta * 2.0 };
        } else {
            hi = beta;
            beta = (beta + lo) / 2.0;
        }
    }
    Calibrated { p, beta, entropy }
}

fn squared_distances(x: &[Vec<f64>]) -> Vec<f64> {
    let n = x.len();
    let mut d = vec![0.0; n * n];
    for i in 0..n {
        for j in i + 1..n {
            let v: f64 = x[i].iter().zip(&x[j]).map(|(a, b)| (a - b) * (a - b)).sum();
            d[i * n + j] = v;
            d[j * n + i] = v;
        }
    }
    d
}

/// The result of [`tsne`].
#[derive(Debug, Clone)]
pub struct Embedding2d {
    pub points: Vec<[f64; 2]>,
    /// KL(P‖Q) at the end.
    pub kl_divergence: f64,
    /// The perplexity used (after clamping).
    pub perplexity: f64,
}

impl TsneOptions {
    /// Names each option out of range (NaN included), so a caller can check before the work
    /// that produces the points.
    pub fn validate(&self) -> Result<(), TsneError> {
        let mut bad = Vec::new();
        if self.perplexity.is_nan() || self.perplexity <= 1.0 {
            bad.push(format!("perplexity {} must be > 1", self.perplexity));
        }
        if self.early_exaggeration.is_nan() || self.early_exaggeration < 1.0 {
            bad.push(format!("early_exaggeration {} must be ≥ 1", self.early_exaggeration));
        }
        if let Some(l) = self.learning_rate.filter(|l| l.is_nan() || *l <= 0.0) {
            bad.push(format!("learning_rate {l} must be > 0"));
        }
        if bad.is_empty() {
            Ok(())
        } else {
            Err(TsneError::Option(bad.join("; ")))
        }
    }
}

/// Every point of one dimension and finite.
fn check_points(x: &[Vec<f64>]) -> Result<(), TsneError> {
    let dim = x[0].len();
    for (i, p) in x.iter().enumerate() {
        if p.len() != dim {
            return Err(TsneError::Dimension { index: i, got: p.len(), expected: dim });
        }
        if p.iter().any(|v| !v.is_finite()) {
            return Err(TsneError::NonFinite(i));
        }
    }
    Ok(())
}

/// The joint probabilities P (n × n, row-major): each row's Gaussian calibrated to the
/// perplexity, symmetrised; the floor keeps log(P/Q) finite.
fn joint_probabilities(x: &[Vec<f64>], perplexity: f64) -> Vec<f64> {
    let n = x.len();
    let d2 = squared_distances(x);
    let mut p = vec![0.0; n * n];
    for i in 0..n {
        let row = calibrate_row(&d2[i * n..(i + 1) * n], i, perplexity, 1e-5);
        p[i * n..(i + 1) * n].copy_from_slice(&row.p);
    }
    let mut psym = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            psym[i * n + j] = ((p[i * n + j] + p[j * n + i]) / (2.0 * n as f64)).max(1e-12);
        }
        psym[i * n + i] = 0.0;
    }
    psym
}

/// KL(P‖Q) of the map `y` (`num` is scratch of n × n).
fn kl_divergence(psym: &[f64], y: &[[f64; 2]], num: &mut [f64]) -> f64 {
    let n = y.len();
    let mut z = 0.0;
    for i in 0..n {
        for j in 0..n {
            if i != j {
                let dx = y[i][0] - y[j][0];
                let dy = y[i][1] - y[j][1];
                num[i * n + j] = 1.0 / (1.0 + dx * dx + dy * dy);
                z += num[i * n + j];
            }
        }
    }
    let mut kl = 0.0;
    for i in 0..n {
        for j in 0..n {
            let pij = psym[i * n + j];
            if i != j && pij > 0.0 {
                kl += pij * (pij / (num[i * n + j] / z).max(1e-300)).ln();
            }
        }
    }
    kl
}

/// Embed `x` (n points of equal dimension) in 2-D.
pub fn tsne(x: &[Vec<f64>], opts: &TsneOptions) -> Result<Embedding2d, TsneError> {
    let n = x.len();
    if n < 4 {
        return Err(TsneError::TooFewPoints(n));
    }
    check_points(x)?;
    opts.validate()?;
    let perplexity = opts.perplexity.min((n - 1) as f64 / 3.0).max(1.5);
    if perplexity < opts.perplexity {
        tracing::warn!("t-SNE: perplexity {} clamped to {perplexity:.1} for {n} points", opts.perplexity);
    }

    let psym = joint_probabilities(x, perplexity);
    let lr = opts.learning_rate.unwrap_or_else(|| (n as f64 / opts.early_exaggeration / 4.0).max(50.0));
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let normal = Normal::new(0.0, 1e-2).map_err(|e| TsneError::Option(e.to_string()))?;
    let mut y: Vec<[f64; 2]> = (0..n).map(|_| [normal.sample(&mut rng), normal.sample(&mut rng)]).collect();
    let mut update = vec![[0.0f64; 2]; n];
    let mut gains = vec![[1.0f64; 2]; n];
    let mut num = vec![0.0; n * n];
    let mut grad = vec![[0.0f64; 2]; n];
    for it in 0..opts.iterations {
        let exaggeration = if it < opts.exaggeration_iterations { opts.early_exaggeration } else { 1.0 };
        let momentum = if it < opts.exaggeration_iterations { 0.5 } else { 0.8 };
        // Student-t kernel and its normaliser Z.
        let mut z = 0.0;
        for i in 0..n {
            for j in i + 1..n {
                let dx = y[i][0] - y[j][0];
                let dy = y[i][1] - y[j][1];
                let q = 1.0 / (1.0 + dx * dx + dy * dy);
                num[i * n + j] = q;
                num[j * n + i] = q;
                z += 2.0 * q;
            }
        }
        // dC/dy_i = 4 Σ_j (p_ij − q_ij) (y_i − y_j) / (1 + ‖y_i − y_j‖²).
        for i in 0..n {
            let mut g = [0.0; 2];
            for j in 0..n {
                if i == j {
                    continue;
                }
                let w = num[i * n + j];
                let f = (exaggeration * psym[i * n + j] - w / z) * w;
                g[0] += f * (y[i][0] - y[j][0]);
                g[1] += f * (y[i][1] - y[j][1]);
            }
            grad[i] = [4.0 * g[0], 4.0 * g[1]];
        }
        for i in 0..n {
            for k in 0..2 {
                // Gains grow where the gradient keeps pointing against the last step.
                gains[i][k] = if (grad[i][k] > 0.0) != (update[i][k] > 0.0) { gains[i][k] + 0.2 } else { (gains[i][k] * 0.8).max(0.01) };
                update[i][k] = momentum * update[i][k] - lr * gains[i][k] * grad[i][k];
                y[i][k] += update[i][k];
            }
        }
        // Keep the map centred (the cost is translation invariant).
        let (mx, my) = y.iter().fold((0.0, 0.0), |(a, b), p| (a + p[0], b + p[1]));
        for p in &mut y {
            p[0] -= mx / n as f64;
            p[1] -= my / n as f64;
        }
    }

    let kl = kl_divergence(&psym, &y, &mut num);
    Ok(Embedding2d { points: y, kl_divergence: kl, perplexity })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three isotropic Gaussian clusters in 10-D, far apart.
    fn clusters(per: usize, seed: u64) -> (Vec<Vec<f64>>, Vec<usize>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let mut x = Vec::new();
        let mut label = Vec::new();
        for c in 0..3 {
            for _ in 0..per {
                let mut p: Vec<f64> = (0..10).map(|_| normal.sample(&mut rng)).collect();
                p[c] += 20.0;
                x.push(p);
                label.push(c);
            }
        }
        (x, label)
    }

    #[test]
    fn calibration_hits_the_target_entropy() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let d2: Vec<f64> = (0..200).map(|_| normal.sample(&mut rng) * normal.sample(&mut rng) * 5.0).map(|v: f64| v * v).collect();
        for perp in [5.0, 30.0, 50.0] {
            let row = calibrate_row(&d2, 7, perp, 1e-6);
            let h: f64 = -row.p.iter().filter(|p| **p > 0.0).map(|p| p * p.ln()).sum::<f64>();
            assert!((h - perp.ln()).abs() < 1e-5, "perplexity {perp}: entropy {h} vs {}", perp.ln());
            assert!((row.entropy - h).abs() < 1e-8);
            assert_eq!(row.p[7], 0.0);
            assert!((row.p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn separated_clusters_stay_separated_and_runs_repeat() {
        let (x, label) = clusters(40, 1);
        let opts = TsneOptions { iterations: 500, seed: 5, ..Default::default() };
        let e = tsne(&x, &opts).unwrap();
        let centroid = |c: usize| {
            let pts: Vec<_> = e.points.iter().zip(&label).filter(|(_, l)| **l == c).map(|(p, _)| *p).collect();
            let m = pts.iter().fold([0.0, 0.0], |a, p| [a[0] + p[0], a[1] + p[1]]);
            let m = [m[0] / pts.len() as f64, m[1] / pts.len() as f64];
            let spread = pts.iter().map(|p| ((p[0] - m[0]).powi(2) + (p[1] - m[1]).powi(2)).sqrt()).fold(0.0, f64::max);
            (m, spread)
        };
        let cs: Vec<_> = (0..3).map(centroid).collect();
        for a in 0..3 {
            for b in a + 1..3 {
                let d = ((cs[a].0[0] - cs[b].0[0]).powi(2) + (cs[a].0[1] - cs[b].0[1]).powi(2)).sqrt();
                assert!(d > 1.5 * (cs[a].1 + cs[b].1), "clusters {a}, {b}: centroids {d:.2} apart, radii {:.2} {:.2}", cs[a].1, cs[b].1);
            }
        }
        // Every point's nearest neighbour in the map is of its own cluster.
        for i in 0..x.len() {
            let nn = (0..x.len())
                .filter(|j| *j != i)
                .min_by(|&a, &b| {
                    let d = |j: usize| (e.points[i][0] - e.points[j][0]).powi(2) + (e.points[i][1] - e.points[j][1]).powi(2);
                    d(a).total_cmp(&d(b))
                })
                .unwrap();
            assert_eq!(label[nn], label[i]);
        }
        let again = tsne(&x, &opts).unwrap();
        assert_eq!(e.points, again.points, "same seed, same map");
        let other = tsne(&x, &TsneOptions { seed: 6, ..opts }).unwrap();
        assert_ne!(e.points, other.points);
    }

    #[test]
    fn bad_input_is_an_error() {
        assert!(matches!(tsne(&vec![vec![0.0]; 3], &TsneOptions::default()), Err(TsneError::TooFewPoints(3))));
        let mut x = vec![vec![0.0, 1.0]; 5];
        x[2] = vec![1.0];
        assert!(matches!(tsne(&x, &TsneOptions::default()), Err(TsneError::Dimension { index: 2, .. })));
        x[2] = vec![f64::NAN, 0.0];
        assert!(matches!(tsne(&x, &TsneOptions::default()), Err(TsneError::NonFinite(2))));
        // Only the option out of range is named.
        let e = TsneOptions { perplexity: 0.0, ..Default::default() }.validate().unwrap_err().to_string();
        assert!(e.contains("perplexity 0") && !e.contains("early_exaggeration") && !e.contains("learning_rate"), "{e}");
        let e = TsneOptions { learning_rate: Some(f64::NAN), ..Default::default() }.validate().unwrap_err().to_string();
        assert!(e.contains("learning_rate NaN") && !e.contains("perplexity"), "{e}");
        // Identical points: no NaN in the map.
        let e = tsne(&vec![vec![1.0, 1.0]; 6], &TsneOptions { iterations: 50, ..Default::default() }).unwrap();
        assert!(e.points.iter().all(|p| p[0].is_finite() && p[1].is_finite()));
    }
}
