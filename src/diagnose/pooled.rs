//! Several recordings of one IMU against their references, pooled: what lasts (the gyro's
//! scale and cross-axis error, the same at every power-on) from what each power-on brings (its
//! turn-on bias). Each recording's plain calibration ([`PlainCalibration`]) gives every
//! parameter with its σ whether or not that recording resolves it; per entry the recordings are
//! pooled by inverse variance and tested for agreeing (χ² of their spread about the pooled
//! value). A quantity is a lasting error when the recordings agree on it and the pooled value
//! stands out of zero at 95 % family-wise over the nine judged ([`Z_FAMILY`]), and, on the
//! diagonal, beyond the regression dilution the reference's own errors could cause (A pulled
//! toward zero by at most residual² / reference² of an axis).
//! The off-diagonal is split as physics splits it: its antisymmetric part is a small rotation
//! between the reference's frame and the IMU's (the reference's hand-eye calibration or the
//! mount, not the sensor), its symmetric part the sensor's own non-orthogonality.

use nalgebra::{Matrix3, Vector3};

use super::plain_calibration::{inverse_variance_mean, rows, PlainCalibration, Z_95};

/// z of the one-sided 99 % point of a normal: the agreement test's level.
const Z_99: f64 = 2.326;

/// z of a two-sided 95 % test over the nine quantities judged at once (three scales, three
/// rotations, three non-orthogonalities; Bonferroni): what a pooled value must pass to be
/// lasting, so that nine chances do not make one.
pub const Z_FAMILY: f64 = 2.77;

/// The χ² quantile at 99 % for `dof` degrees of freedom (Wilson–Hilferty; within 1 % of the
/// exact value from 2 degrees of freedom on).
fn chi2_99(dof: f64) -> f64 {
    let a = 2.0 / (9.0 * dof);
    dof * (1.0 - a + Z_99 * a.sqrt()).powi(3)
}

/// One parameter over the recordings: the pooled value, its 1 σ, and the spread's χ².
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PooledEntry {
    pub value: f64,
    pub sigma: f64,
    pub chi2: f64,
    /// The recordings agree on it (χ² below its 99 % point for n − 1 degrees of freedom).
    pub agree: bool,
}

impl PooledEntry {
    /// Values with their 1 σ pooled by inverse variance, and tested for agreeing.
    fn pool(values: &[(f64, f64)]) -> Self {
        let (value, sigma) = inverse_variance_mean(values);
        let chi2: f64 = values.iter().map(|(v, s)| ((v - value) / s.max(1e-300)).powi(2)).sum();
        PooledEntry { value, sigma, chi2, agree: chi2 <= chi2_99((values.len() - 1) as f64) }
    }

    /// Agreed on and beyond zero by more than `floor` plus [`Z_FAMILY`] σ.
    fn lasting(&self, floor: f64) -> bool {
        self.agree && self.value.abs() - Z_FAMILY * self.sigma > floor
    }
}

/// Several recordings of one IMU pooled.
#[derive(Debug, Clone, PartialEq)]
pub struct Pooled {
    pub recordings: Vec<String>,
    /// A − I per entry (row: IMU axis, column: reference axis).
    pub lasting: [[PooledEntry; 3]; 3],
    /// The largest regression dilution a recording's reference could cause per axis (a
    /// fraction: A's diagonal pulled toward zero by up to this).
    pub dilution: Vector3<f64>,
    /// A − I's antisymmetric part: the rotation about x, y, z between the reference's frame and
    /// the IMU's, rad.
    pub rotation: [PooledEntry; 3],
    /// Its symmetric part: the sensor's non-orthogonality, for the axis pairs xy, xz, yz.
    pub non_orthogonality: [PooledEntry; 3],
    /// The bias per axis pooled, and whether the recordings agree on it (a turn-on bias that
    /// repeats) or not (each power-on's own).
    pub bias: [PooledEntry; 3],
    pub bias_each: Vec<Vector3<f64>>,
}

impl Pooled {
    /// Pools `fits` (one per recording, named by `recordings`); `None` for fewer than two.
    pub fn of(recordings: Vec<String>, fits: &[PlainCalibration]) -> Option<Self> {
        if fits.len() < 2 || recordings.len() != fits.len() {
            return None;
        }
        let lasting = std::array::from_fn(|r| {
            std::array::from_fn(|c| {
                let truth = if r == c { 1.0 } else { 0.0 };
                PooledEntry::pool(&fits.iter().map(|f| (f.matrix[(r, c)] - truth, f.matrix_sigma[(r, c)])).collect::<Vec<_>>())
            })
        });
        let dilution =
            Vector3::from_fn(|k, _| fits.iter().map(|f| (f.residual_rms[k] / f.reference_rms[k].max(1e-300)).powi(2)).fold(0.0, f64::max));
        let bias = std::array::from_fn(|k| PooledEntry::pool(&fits.iter().map(|f| (f.bias[k], f.bias_sigma[k])).collect::<Vec<_>>()));
        // Rows are fitted one IMU axis at a time: entries of two rows are taken as independent.
        let half = |f: &PlainCalibration, (r, c): (usize, usize), sign: f64| {
            let value = 0.5 * (f.matrix[(r, c)] + sign * f.matrix[(c, r)]);
            (value, 0.5 * f.matrix_sigma[(r, c)].hypot(f.matrix_sigma[(c, r)]))
        };
        // θ about x is A[2][1] − A[1][2] halved, about y A[0][2] − A[2][0], about z A[1][0] − A[0][1].
        let rotation = [(2, 1), (0, 2), (1, 0)].map(|rc| PooledEntry::pool(&fits.iter().map(|f| half(f, rc, -1.0)).collect::<Vec<_>>()));
        let non_orthogonality =
            [(0, 1), (0, 2), (1, 2)].map(|rc| PooledEntry::pool(&fits.iter().map(|f| half(f, rc, 1.0)).collect::<Vec<_>>()));
        Some(Pooled { recordings, lasting, dilution, rotation, non_orthogonality, bias, bias_each: fits.iter().map(|f| f.bias).collect() })
    }

    /// The lasting gyro scale per axis, where one is found (A's diagonal less 1).
    pub fn lasting_scale(&self) -> [Option<f64>; 3] {
        std::array::from_fn(|k| {
            let e = &self.lasting[k][k];
            e.lasting(self.dilution[k]).then_some(e.value)
        })
    }

    /// The lasting rotation between the reference's frame and the IMU's about x, y, z, rad.
    pub fn lasting_rotation(&self) -> [Option<f64>; 3] {
        self.rotation.map(|e| e.lasting(0.0).then_some(e.value))
    }

    /// The sensor's lasting non-orthogonality for the pairs xy, xz, yz.
    pub fn lasting_non_orthogonality(&self) -> [Option<f64>; 3] {
        self.non_orthogonality.map(|e| e.lasting(0.0).then_some(e.value))
    }

    /// The axes whose bias the recordings disagree on: each power-on's own.
    pub fn bias_per_power_on(&self) -> [bool; 3] {
        std::array::from_fn(|k| !self.bias[k].agree)
    }

    /// One line for the terminal.
    pub fn summary(&self) -> String {
        let axes = ["x", "y", "z"];
        let scale: Vec<String> = self
            .lasting_scale()
            .iter()
            .enumerate()
            .filter_map(|(k, s)| s.map(|v| format!("{} {:+.2} ± {:.2} %", axes[k], 100.0 * v, 100.0 * Z_95 * self.lasting[k][k].sigma)))
            .collect();
        let said = |found: [Option<f64>; 3], entries: &[PooledEntry; 3], names: [&str; 3], k: f64, unit: &str| -> Vec<String> {
            (0..3)
                .filter_map(|i| found[i].map(|v| format!("{} {:+.2} ± {:.2} {unit}", names[i], k * v, k * Z_95 * entries[i].sigma)))
                .collect()
        };
        let rotation = said(self.lasting_rotation(), &self.rotation, axes, 1e3, "mrad");
        let skew = said(self.lasting_non_orthogonality(), &self.non_orthogonality, ["xy", "xz", "yz"], 100.0, "%");
        let disagree: Vec<&str> = (0..3).filter(|&k| !self.lasting[k][k].agree).map(|k| axes[k]).collect();
        let per_power_on: Vec<&str> = (0..3).filter(|&k| self.bias_per_power_on()[k]).map(|k| axes[k]).collect();
        let none = |v: &[String]| if v.is_empty() { "none".to_string() } else { v.join(", ") };
        format!(
            "pooled over {} recordings of one IMU (pooled.json): lasting gyro scale {}; the sensor's non-orthogonality {}; a rotation between the reference's frame and the IMU's (the reference's or the mount's, not the sensor's) {}; scale differing between recordings on {}; bias each power-on's own on {}",
            self.recordings.len(),
            none(&scale),
            none(&skew),
            none(&rotation),
            if disagree.is_empty() { "none".into() } else { disagree.join(", ") },
            if per_power_on.is_empty() { "none (it repeats)".into() } else { per_power_on.join(", ") },
        )
    }

    /// `pooled.json`.
    pub fn json(&self) -> serde_json::Value {
        let value = Matrix3::from_fn(|r, c| self.lasting[r][c].value);
        let sigma = Matrix3::from_fn(|r, c| self.lasting[r][c].sigma);
        let chi2 = Matrix3::from_fn(|r, c| self.lasting[r][c].chi2);
        let agree: Vec<Vec<bool>> = self.lasting.iter().map(|row| row.iter().map(|e| e.agree).collect()).collect();
        serde_json::json!({
            "rule": "each recording's plain calibration (plain_calibration.json); per entry of A − I the recordings pooled by inverse variance; they agree when the χ² of their spread about the pooled value is below its 99 % point (n − 1 degrees of freedom); a quantity (a scale, the off-diagonal's antisymmetric part: a rotation between the reference's frame and the IMU's, its symmetric part: the sensor's non-orthogonality) is lasting when they agree on it and it stands out of zero by 2.77 sigma (95 % family-wise over the nine) plus, for a scale, the regression dilution the references could cause (residual² / reference² of the axis, the largest over the recordings); the ± given are 95 % per quantity",
            "recordings": self.recordings,
            "lasting_error": rows(&value),
            "lasting_error_sigma": rows(&sigma),
            "chi2": rows(&chi2),
            "chi2_99": chi2_99((self.recordings.len() - 1) as f64),
            "agree": agree,
            "dilution": self.dilution.as_slice(),
            "lasting_scale": self.lasting_scale(),
            "rotation_rad": self.rotation,
            "lasting_rotation_rad": self.lasting_rotation(),
            "non_orthogonality": self.non_orthogonality,
            "lasting_non_orthogonality": self.lasting_non_orthogonality(),
            "bias_pooled_rad_s": self.bias.iter().map(|e| e.value).collect::<Vec<_>>(),
            "bias_pooled_sigma_rad_s": self.bias.iter().map(|e| e.sigma).collect::<Vec<_>>(),
            "bias_chi2": self.bias.iter().map(|e| e.chi2).collect::<Vec<_>>(),
            "bias_each_rad_s": self.bias_each.iter().map(|b| b.as_slice().to_vec()).collect::<Vec<_>>(),
            "bias_per_power_on": self.bias_per_power_on(),
        })
    }

    /// `pooled.md`: the table per entry, and which catalogue terms each recording's diagnosis
    /// found (`found`: recording name → term names).
    pub fn markdown(&self, found: &[(String, Vec<String>)]) -> String {
        let axes = ["x", "y", "z"];
        let mut md = format!(
            "# Pooled over {} recordings of one IMU\n\nEach recording's plain calibration pooled per entry by inverse variance; the recordings agree on an entry when the χ² of their spread is below {:.1} (99 %, {} degrees of freedom). Lasting: agreed on, and beyond zero by {:.2} σ (95 % family-wise over the nine quantities judged; a scale also beyond the regression dilution the references could cause). ± is 95 % per entry.\n\n| entry | pooled (%) | ± 95 % | χ² | agree | lasting |\n|---|---|---|---|---|---|\n",
            self.recordings.len(),
            chi2_99((self.recordings.len() - 1) as f64),
            self.recordings.len() - 1,
            Z_FAMILY
        );
        for r in 0..3 {
            for c in 0..3 {
                let e = &self.lasting[r][c];
                let lasting = match (r == c, e.lasting(self.dilution[r])) {
                    (false, _) => "judged split, below",
                    (true, true) => "**yes**",
                    (true, false) => "no",
                };
                let name = if r == c { format!("scale {}", axes[r]) } else { format!("cross-axis {}{}", axes[r], axes[c]) };
                md += &format!(
                    "| {name} | {:+.3} | {:.3} | {:.1} | {} | {} |\n",
                    100.0 * e.value,
                    100.0 * Z_95 * e.sigma,
                    e.chi2,
                    if e.agree { "yes" } else { "no" },
                    lasting
                );
            }
        }
        md += "\nThe off-diagonal split: its antisymmetric part a rotation between the reference's frame and the IMU's (the reference's hand-eye calibration or the mount, not the sensor), its symmetric part the sensor's non-orthogonality.\n\n| part | pooled | ± 95 % | χ² | agree | lasting |\n|---|---|---|---|---|---|\n";
        let rotation =
            ["rotation about x", "rotation about y", "rotation about z"].into_iter().zip(&self.rotation).map(|(n, e)| (n, e, 1e3, "mrad"));
        let skew = ["non-orthogonality xy", "non-orthogonality xz", "non-orthogonality yz"].into_iter().zip(&self.non_orthogonality);
        let parts = rotation.chain(skew.map(|(n, e)| (n, e, 100.0, "%")));
        for (name, e, k, unit) in parts {
            md += &format!(
                "| {name} | {:+.3} {unit} | {:.3} | {:.1} | {} | {} |\n",
                k * e.value,
                k * Z_95 * e.sigma,
                e.chi2,
                if e.agree { "yes" } else { "no" },
                if e.lasting(0.0) { "**yes**" } else { "no" }
            );
        }
        md += &format!(
            "\nRegression dilution the references could cause, x / y / z: {:.3} / {:.3} / {:.3} %.\n\n| axis | bias pooled (mrad/s) | ± 95 % | χ² | |\n|---|---|---|---|---|\n",
            100.0 * self.dilution.x,
            100.0 * self.dilution.y,
            100.0 * self.dilution.z
        );
        for (k, e) in self.bias.iter().enumerate() {
            let each: Vec<String> = self.bias_each.iter().map(|b| format!("{:+.1}", 1e3 * b[k])).collect();
            let what = if e.agree { "repeats across the power-ons" } else { "each power-on's own" };
            md += &format!(
                "| {} | {:+.2} | {:.2} | {:.1} | {what} (each: {}) |\n",
                axes[k],
                1e3 * e.value,
                1e3 * Z_95 * e.sigma,
                e.chi2,
                each.join(", ")
            );
        }
        md += "\n| recording | terms its diagnosis found |\n|---|---|\n";
        for (name, terms) in found {
            md += &format!("| {name} | {} |\n", if terms.is_empty() { "none".to_string() } else { terms.join(", ") });
        }
        md
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fit(scale_x: f64, sigma: f64, bias_x: f64) -> PlainCalibration {
        let mut matrix = Matrix3::identity();
        matrix[(0, 0)] += scale_x;
        PlainCalibration {
            matrix,
            bias: Vector3::new(bias_x, 0.0, 0.0),
            matrix_sigma: Matrix3::repeat(sigma),
            bias_sigma: Vector3::repeat(1e-4),
            windows: 500,
            residual_rms: Vector3::repeat(0.01),
            reference_rms: Vector3::repeat(1.0),
        }
    }

    #[test]
    fn the_chi2_quantile_is_near_the_table() {
        // χ²₀.₉₉: 1 dof 6.63, 5 dof 15.09, 10 dof 23.21.
        for (dof, table) in [(5.0, 15.086), (10.0, 23.209)] {
            assert!((chi2_99(dof) / table - 1.0).abs() < 0.01, "{dof}: {}", chi2_99(dof));
        }
    }

    /// A scale the recordings share is lasting; one that a single recording carries is not; a
    /// bias that changes between power-ons is said to; one below the dilution is not claimed.
    #[test]
    fn what_the_recordings_share_is_lasting_and_what_one_carries_is_not() {
        let names = |n: usize| (0..n).map(|k| format!("r{k}")).collect::<Vec<_>>();
        let shared = Pooled::of(names(3), &[fit(-0.002, 0.0005, 0.01), fit(-0.0021, 0.0005, -0.02), fit(-0.0019, 0.0005, 0.03)]).unwrap();
        assert!(shared.lasting_scale()[0].is_some_and(|v| (v + 0.002).abs() < 1e-4), "{shared:?}");
        assert_eq!(shared.lasting_scale()[1], None);
        assert!(shared.bias_per_power_on()[0] && !shared.bias_per_power_on()[1]);

        let one = Pooled::of(names(3), &[fit(0.03, 0.0005, 0.0), fit(0.0, 0.0005, 0.0), fit(0.0, 0.0005, 0.0)]).unwrap();
        assert!(!one.lasting[0][0].agree && one.lasting_scale()[0].is_none(), "{one:?}");

        let diluted = Pooled::of(names(2), &[fit(-0.00005, 0.00001, 0.0), fit(-0.00005, 0.00001, 0.0)]).unwrap();
        assert!(diluted.dilution.x > 5e-5 && diluted.lasting_scale()[0].is_none(), "{diluted:?}");
        assert!(Pooled::of(names(1), &[fit(0.0, 0.001, 0.0)]).is_none());
    }
}
