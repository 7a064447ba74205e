//! Generalised least squares on whitened block statistics, in-sample and cross-validated.
//!
//! A model is an affine map from its parameters β to the atoms' coefficients, θ = A β. With
//! the per-block statistics of the whitened atoms (Gram G_b, cross products x_b, ỹᵀỹ), the
//! fit on any set of blocks is β = (Aᵀ G A)⁻¹ Aᵀ x and the held-out log-likelihood of block
//! b is evaluated at the β fitted on all other blocks: cross-validation over time blocks
//! costs a few small solves, not a refit of the data.

use nalgebra::{DMatrix, DVector};

use super::residual::BlockStats;

/// A fitted model.
#[derive(Debug, Clone)]
pub struct Fit {
    /// Parameters.
    pub beta: DVector<f64>,
    /// Their covariance, (Aᵀ G A)⁻¹ (whitened units: already in parameter units²).
    pub cov: DMatrix<f64>,
    /// In-sample log-likelihood.
    pub loglik: f64,
    /// Held-out log-likelihood, summed over blocks.
    pub loglik_cv: f64,
    /// Held-out log-likelihood per block.
    pub loglik_blocks: Vec<f64>,
    /// β fitted without each block in turn (to predict that block).
    pub beta_folds: Vec<DVector<f64>>,
}

/// Solve the (possibly rank-deficient) normal equations; returns (β, pseudo-inverse).
pub fn solve(g: &DMatrix<f64>, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
    let p = g.nrows();
    if p == 0 {
        return (DVector::zeros(0), DMatrix::zeros(0, 0));
    }
    // Scale to unit diagonal for conditioning.
    let d: DVector<f64> = DVector::from_fn(p, |i, _| {
        let v = g[(i, i)];
        if v > 0.0 {
            1.0 / v.sqrt()
        } else {
            0.0
        }
    });
    let gs = DMatrix::from_fn(p, p, |i, j| g[(i, j)] * d[i] * d[j]);
    let inv = match gs.clone().cholesky() {
        Some(ch) if ch.l().diagonal().iter().all(|v| *v > 1e-7) => ch.inverse(),
        _ => gs.pseudo_inverse(1e-10).unwrap_or_else(|_| DMatrix::zeros(p, p)),
    };
    let inv = DMatrix::from_fn(p, p, |i, j| inv[(i, j)] * d[i] * d[j]);
    (&inv * x, inv)
}

/// Project block statistics through A.
fn project(s: &BlockStats, a: &DMatrix<f64>) -> (DMatrix<f64>, DVector<f64>) {
    (a.transpose() * &s.gram * a, a.transpose() * &s.xy)
}

/// Fit θ = A β on all blocks and cross-validate over them.
pub fn evaluate(blocks: &[BlockStats], a: &DMatrix<f64>) -> Fit {
    let p = a.ncols();
    let mut total = BlockStats::zeros(a.nrows());
    blocks.iter().for_each(|b| total.add(b));
    let (g, x) = project(&total, a);
    let (beta, cov) = solve(&g, &x);
    let theta = a * &beta;
    let loglik = total.loglik(&theta);
    let mut loglik_blocks = Vec::with_capacity(blocks.len());
    let mut beta_folds = Vec::with_capacity(blocks.len());
    for b in blocks {
        let (gb, xb) = project(b, a);
        let beta_b = if p == 0 { DVector::zeros(0) } else { fold_fit(&g, &(&g - &gb), &(&x - &xb), &beta) };
        loglik_blocks.push(b.loglik(&(a * &beta_b)));
        beta_folds.push(beta_b);
    }
    Fit { beta, cov, loglik, loglik_cv: loglik_blocks.iter().sum(), loglik_blocks, beta_folds }
}

/// Share of a parameter's information (diagonal of the Gram matrix) the other blocks must
/// carry for it to be cross-validated.
pub const MIN_FOLD_INFORMATION: f64 = 0.1;

/// β fitted on the blocks other than one (Gram `gf`, cross products `xf`). A parameter the
/// other blocks hardly determine (less than [`MIN_FOLD_INFORMATION`] of its information
/// outside the block) cannot be predicted from them — a constant bias against the bias walk
/// is one: it is told from the walk only by the walk's known start, i.e. by the first block.
/// Estimated from the other blocks it would be noise of variance 1/g_fold and its prediction
/// of the block meaningless (and it would make every later comparison of models that include
/// it meaningless too). Such parameters are held at their full-sample estimate `beta` (they
/// are judged in-sample, like the biases in the selection) and the others are refitted
/// given them.
fn fold_fit(g: &DMatrix<f64>, gf: &DMatrix<f64>, xf: &DVector<f64>, beta: &DVector<f64>) -> DVector<f64> {
    let p = g.nrows();
    let weak: Vec<usize> = (0..p).filter(|&i| gf[(i, i)] < MIN_FOLD_INFORMATION * g[(i, i)]).collect();
    if weak.is_empty() {
        return solve(gf, xf).0;
    }
    let free: Vec<usize> = (0..p).filter(|i| !weak.contains(i)).collect();
    let mut out = beta.clone();
    if free.is_empty() {
        return out;
    }
    let gr = DMatrix::from_fn(free.len(), free.len(), |r, c| gf[(free[r], free[c])]);
    let xr = DVector::from_fn(free.len(), |r, _| xf[free[r]] - weak.iter().map(|&w| gf[(free[r], w)] * beta[w]).sum::<f64>());
    let (br, _) = solve(&gr, &xr);
    for (k, &i) in free.iter().enumerate() {
        out[i] = br[k];
    }
    out
}
