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
    evaluate_fixed(blocks, a, &[])
}

/// As [`evaluate`], with the parameters `fixed` (indices into β) held at their all-block
/// values in the held-out fits: parameters only one block can identify (a constant bias is
/// told from the bias walk by the walk's known start, in the first block) are not
/// extrapolated from the blocks that cannot see them, where their estimate is arbitrary
/// and its prediction of the held-out block can be off by orders of magnitude.
pub fn evaluate_fixed(blocks: &[BlockStats], a: &DMatrix<f64>, fixed: &[usize]) -> Fit {
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
        let beta_b = if p == 0 { DVector::zeros(0) } else { fold_fit(&g, &(&g - &gb), &(&x - &xb), &beta, fixed) };
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
/// given them; so are the parameters the caller lists in `fixed`.
fn fold_fit(g: &DMatrix<f64>, gf: &DMatrix<f64>, xf: &DVector<f64>, beta: &DVector<f64>, fixed: &[usize]) -> DVector<f64> {
    let p = g.nrows();
    let weak: Vec<usize> = (0..p).filter(|&i| fixed.contains(&i) || gf[(i, i)] < MIN_FOLD_INFORMATION * g[(i, i)]).collect();
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Two blocks; parameter 0 is seen only by block 0. Held-out, block 0 is predicted with
    /// parameter 0 extrapolated from block 1 (where it is nearly unidentified and the
    /// estimate is far off) unless it is fixed at its all-block value.
    #[test]
    fn fixed_parameter_is_not_extrapolated_from_blocks_that_cannot_see_it() {
        // Atoms: a0 (only in block 0), a1 (in both); truth θ = (2, 1).
        let mk = |g: [[f64; 2]; 2], truth: [f64; 2], noise: [f64; 2]| {
            let gram = DMatrix::from_row_slice(2, 2, &[g[0][0], g[0][1], g[1][0], g[1][1]]);
            let xy = &gram * DVector::from_row_slice(&truth) + DVector::from_row_slice(&noise);
            BlockStats { yy: 100.0, xy, gram, log_s: 0.0, n: 100.0 }
        };
        // Block 1 sees a0 only through a tiny, noisy correlation.
        let b0 = mk([[100.0, 10.0], [10.0, 100.0]], [2.0, 1.0], [0.0, 0.0]);
        let b1 = mk([[1e-6, 1e-4], [1e-4, 100.0]], [2.0, 1.0], [0.5, 0.0]);
        let a = DMatrix::identity(2, 2);
        // Block 1 alone extrapolates parameter 0 wildly: what a held-out fit of block 0 used.
        assert!(solve(&b1.gram, &b1.xy).0[0].abs() > 1e3);
        // Held at its all-block value, by the caller's list and by the information rule alike.
        let fixed = evaluate_fixed(&[b0.clone(), b1.clone()], &a, &[0]);
        let auto = evaluate(&[b0.clone(), b1.clone()], &a);
        for fit in [&fixed, &auto] {
            assert!((fit.beta_folds[0][0] - fit.beta[0]).abs() < 1e-12);
            assert!((fit.beta[0] - 2.0).abs() < 0.1, "all-block estimate {}", fit.beta[0]);
        }
        // A parameter block 1 does see (above the information share) is refitted unless listed.
        let b1_sees = mk([[50.0, 10.0], [10.0, 100.0]], [2.0, 1.0], [5.0, 0.0]);
        let refit = evaluate(&[b0.clone(), b1_sees.clone()], &a);
        let held = evaluate_fixed(&[b0, b1_sees], &a, &[0]);
        assert!((refit.beta_folds[0][0] - refit.beta[0]).abs() > 1e-3);
        assert!((held.beta_folds[0][0] - held.beta[0]).abs() < 1e-12);
    }
}
