//! What the recording could have shown: for each catalogue term the selection left out, the
//! smallest value of each of its parameters it would have taken in.
//!
//! With the chosen terms in the model, a candidate's parameter k has the GLS variance C_kk
//! (the whitened Gram of the chosen atoms and the candidate's, inverted: what the other
//! terms explain as well is not information about it). Its estimate is θ̂ = θ + z √C_kk, z
//! standard normal; it adds ½ θ̂²/C_kk to the in-sample log-likelihood and, held out, p/2
//! less on average (p the candidate's parameters); the selection takes a term in once that
//! held-out gain exceeds `need = threshold + per_param·p`. So |θ̂| must pass
//! √(2 (need + p/2) C_kk), and a true value passes it 19 times in 20 from
//! θ_min = (√(2 (need + p/2)) + 1.645) √C_kk on, the other parameters zero. Below it the
//! recording may miss it (at a third of it, nearly always).
//! The drift terms (biases, the temperature coefficient) are judged against the bias walk in
//! sample, and the terms with a nonlinear parameter (vibration, low-pass) by their own search:
//! no limit is stated for them.

use nalgebra::DMatrix;

use super::catalogue::Map;
use super::residual::{block_stats, blocks, BlockStats, Column};
use super::select::{design, Chosen, SelectOptions, Selection};

/// The smallest value of each parameter of a term the recording shows 19 times in 20.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DetectionLimit {
    pub term: &'static str,
    /// Per parameter (the catalogue's atom labels, `gyro_g_sensitivity.matrix[0][1]`), in its
    /// own units; infinite where the chosen terms explain the same (nothing is left to see it).
    pub smallest_found: Vec<(String, f64)>,
}

impl DetectionLimit {
    /// How far a value is above the limit: √Σ (θ_k / θ_min,k)², ≥ 1 where this recording would
    /// show it (its parameters' correlations aside).
    pub fn margin(&self, values: &[f64]) -> f64 {
        self.smallest_found.iter().zip(values).map(|((_, lim), v)| (v / lim).powi(2)).sum::<f64>().sqrt()
    }
}

/// Terms whose limit is not stated (judged otherwise than by the held-out gain of a linear fit).
const NO_LIMIT: [&str; 5] = ["gyro_bias", "accel_bias", "gyro_bias_temperature", "vibration", "earth_rotation"];

/// The limits of every linear candidate not chosen, under the selection's final noise model;
/// each σ widened by `widen` (√(χ²/n) of the residual after the fit, as the findings' are).
pub fn detection_limits(sel: &Selection, mask: &[bool], opts: &SelectOptions, widen: f64) -> Vec<DetectionLimit> {
    let cat = &sel.catalogue;
    let cols: Vec<&Column> = cat.atoms.iter().map(|a| &a.column).collect();
    let mut total = BlockStats::zeros(cols.len());
    block_stats(&sel.y, &cols, &sel.noise, mask, &blocks(sel.y[0].len(), opts.folds)).iter().for_each(|b| total.add(b));
    let mut out = Vec::new();
    for (ci, cand) in cat.candidates.iter().enumerate() {
        if NO_LIMIT.contains(&cand.name) || cand.map != Map::Direct || sel.chosen.iter().any(|c| c.cand == ci) {
            continue;
        }
        let mut with = sel.chosen.clone();
        with.push(Chosen { cand: ci, nonlinear: 0.0 });
        let a = design(cat, &with);
        let gram = a.transpose() * &total.gram * &a;
        let first = a.ncols() - cand.params;
        let need = opts.threshold + (opts.per_param + 0.5) * cand.params as f64;
        // z at 95 % one-sided: the value found 19 times in 20.
        let z = (2.0 * need).sqrt() + 1.645;
        let variances = conditional_variances(&gram, first);
        out.push(DetectionLimit {
            term: cand.name,
            smallest_found: cand
                .atoms
                .iter()
                .zip(variances)
                .map(|(&atom, var)| (cat.atoms[atom].label.clone(), z * var.sqrt() * widen))
                .collect(),
        });
    }
    out
}

/// The diagonal of the inverse of `gram` from index `first` on: each parameter's variance with
/// every other one free. Infinite where the matrix is singular along it.
fn conditional_variances(gram: &DMatrix<f64>, first: usize) -> Vec<f64> {
    let p = gram.nrows();
    // Scaled to a unit diagonal so that the parameters' units do not decide the conditioning.
    let d: Vec<f64> = (0..p).map(|i| if gram[(i, i)] > 0.0 { 1.0 / gram[(i, i)].sqrt() } else { 0.0 }).collect();
    let scaled = DMatrix::from_fn(p, p, |i, j| gram[(i, j)] * d[i] * d[j]);
    let eig = nalgebra::SymmetricEigen::new(scaled);
    (first..p)
        .map(|k| {
            if d[k] == 0.0 {
                return f64::INFINITY;
            }
            // (S⁻¹)_kk = Σ_i v_ki² / λ_i; a direction the data do not determine (λ ≈ 0) that
            // involves parameter k leaves it undetermined.
            let mut s = 0.0;
            for (i, &lambda) in eig.eigenvalues.iter().enumerate() {
                let v = eig.eigenvectors[(k, i)];
                if v * v < 1e-12 {
                    continue;
                }
                if lambda <= 1e-10 {
                    return f64::INFINITY;
                }
                s += v * v / lambda;
            }
            s * d[k] * d[k]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parameter_the_others_explain_as_well_has_no_limit() {
        // Parameters 0 and 1 see the same atom; 2 is independent with information 4.
        let g = DMatrix::from_row_slice(3, 3, &[1.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 4.0]);
        let v = conditional_variances(&g, 1);
        assert!(v[0].is_infinite());
        assert!((v[1] - 0.25).abs() < 1e-12);
    }

    #[test]
    fn correlation_with_a_chosen_term_raises_the_limit() {
        // Information 1 each, correlated 0.9: conditional variance 1 / (1 − 0.81).
        let g = DMatrix::from_row_slice(2, 2, &[1.0, 0.9, 0.9, 1.0]);
        let v = conditional_variances(&g, 1);
        assert!((v[0] - 1.0 / 0.19).abs() < 1e-9, "{v:?}");
        let alone = conditional_variances(&DMatrix::from_row_slice(1, 1, &[1.0]), 0);
        assert!((alone[0] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_margin_is_one_at_the_limit() {
        let l = DetectionLimit { term: "gyro_scale", smallest_found: vec![("a".into(), 2.0), ("b".into(), 4.0)] };
        assert!((l.margin(&[2.0, 0.0]) - 1.0).abs() < 1e-12);
        assert!((l.margin(&[0.0, -4.0]) - 1.0).abs() < 1e-12);
        assert!(l.margin(&[1.0, 1.0]) < 1.0);
    }
}
