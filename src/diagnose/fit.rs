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
    let free: Vec<usize> = (0..p).filter(|i| !fixed.contains(i)).collect();
    let mut loglik_blocks = Vec::with_capacity(blocks.len());
    let mut beta_folds = Vec::with_capacity(blocks.len());
    for b in blocks {
        let (gb, xb) = project(b, a);
        let beta_b = if p == 0 {
            DVector::zeros(0)
        } else if free.len() == p {
            solve(&(&g - &gb), &(&x - &xb)).0
        } else {
            // Normal equations of the free parameters with the fixed ones moved to the
            // right-hand side: G_ff β_f = x_f − G_fx β_x.
            let (go, xo) = (&g - &gb, &x - &xb);
            let gff = DMatrix::from_fn(free.len(), free.len(), |i, j| go[(free[i], free[j])]);
            let xf = DVector::from_fn(free.len(), |i, _| xo[free[i]] - fixed.iter().map(|&k| go[(free[i], k)] * beta[k]).sum::<f64>());
            let (bf, _) = solve(&gff, &xf);
            let mut out = beta.clone();
            for (i, &f) in free.iter().enumerate() {
                out[f] = bf[i];
            }
            out
        };
        loglik_blocks.push(b.loglik(&(a * &beta_b)));
        beta_folds.push(beta_b);
    }
    Fit { beta, cov, loglik, loglik_cv: loglik_blocks.iter().sum(), loglik_blocks, beta_folds }
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
        let free = evaluate(&[b0.clone(), b1.clone()], &a);
        let fixed = evaluate_fixed(&[b0, b1], &a, &[0]);
        assert!(free.beta_folds[0][0].abs() > 1e3, "free fold estimate {}", free.beta_folds[0][0]);
        assert!((fixed.beta_folds[0][0] - fixed.beta[0]).abs() < 1e-12);
        assert!((fixed.beta[0] - 2.0).abs() < 0.1, "all-block estimate {}", fixed.beta[0]);
        assert!(fixed.loglik_blocks[0] > free.loglik_blocks[0] + 1e3);
    }
}
