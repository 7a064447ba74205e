//! The evaluation's figures (the paper's Figs. 3 and 4): attitude over time (ground truth and
//! each method's open-loop integration) and the per-axis error over time, from the paths
//! [`crate::eval::evaluate_with_path`] returns. Drawn with [`crate::plot`].

use std::path::{Path, PathBuf};

use nalgebra::UnitQuaternion;

use crate::core::Recording;
use crate::eval::OrientationPath;
use crate::plot::{color, line_figure, Figure, Legend, Panel, PlotError, Series};
use crate::so3::{euler_zyx, log, wrap_pi};

const AXES: [&str; 3] = ["roll", "pitch", "yaw"];

/// Colour of a method: the ground truth is black, raw grey, others from the palette.
fn method_color(k: usize, name: &str) -> plotters::style::RGBColor {
    match name {
        "raw" => plotters::style::RGBColor(150, 150, 150),
        _ => color([1, 0, 2, 3, 4, 5, 6, 8, 9][k % 9]),
    }
}

/// Degrees, with NaN inserted where consecutive values wrap by more than 180° so the line
/// breaks instead of crossing the plot.
fn with_breaks(points: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(points.len());
    let mut prev: Option<f64> = None;
    for (t, v) in points {
        if let (Some(p), true) = (prev, v.is_finite()) {
            if (v - p).abs() > 180.0 {
                out.push((t, f64::NAN));
            }
        }
        prev = v.is_finite().then_some(v).or(prev);
        out.push((t, v));
    }
    out
}

/// `DIR/<name>_orientation.png` and `DIR/<name>_error.png` for the methods' paths (all from
/// the same recording, so the same start and ground truth). Time is seconds since the start
/// of the integration.
pub fn orientation_figures(
    dir: &Path,
    name: &str,
    rec: &Recording,
    methods: &[(String, OrientationPath)],
) -> Result<[PathBuf; 2], PlotError> {
    let Some((_, first)) = methods.first() else { return Err(PlotError::Empty(format!("{name}: no method to plot"))) };
    let imu = &rec.imu[first.start..];
    let t0 = imu.first().map_or(0, |s| s.stamp_ns);
    let time: Vec<f64> = imu.iter().map(|s| (s.stamp_ns - t0) as f64 * 1e-9).collect();
    let euler = |q: &Option<UnitQuaternion<f64>>| q.map(|q| euler_zyx(&q).map(f64::to_degrees));

    let gt: Vec<_> = first.ground_truth.iter().map(euler).collect();
    let mut attitude: Vec<Panel> = (0..3)
        .map(|a| Panel {
            title: AXES[a].into(),
            x_label: "time since integration start [s]".into(),
            y_label: format!("{} [deg]", AXES[a]),
            series: vec![Series::new(
                "ground truth",
                with_breaks(time.iter().zip(&gt).map(|(t, e)| (*t, e.map_or(f64::NAN, |e| e[a]))).collect()),
                plotters::style::BLACK,
            )
            .width(3)],
            legend: if a == 0 { Legend::UpperLeft } else { Legend::None },
            ..Default::default()
        })
        .collect();
    let mut error: Vec<Panel> = (0..4)
        .map(|a| Panel {
            title: if a < 3 { format!("{} error", AXES[a]) } else { "attitude error (angle of R_gt⁻¹ R_est)".into() },
            x_label: "time since integration start [s]".into(),
            y_label: if a < 3 { format!("Δ{} [deg]", AXES[a]) } else { "angle [deg]".into() },
            legend: if a == 0 { Legend::UpperLeft } else { Legend::None },
            ..Default::default()
        })
        .collect();
    for (k, (method, path)) in methods.iter().enumerate() {
        let c = method_color(k, method);
        let est: Vec<_> = path.estimate.iter().map(|q| euler_zyx(q).map(f64::to_degrees)).collect();
        for a in 0..3 {
            attitude[a].series.push(Series::new(method.as_str(), with_breaks(time.iter().zip(&est).map(|(t, e)| (*t, e[a])).collect()), c));
        }
        let mut err: [Vec<(f64, f64)>; 4] = Default::default();
        for ((t, (r_hat, r_gt)), e) in time.iter().zip(path.estimate.iter().zip(&path.ground_truth)).zip(&est) {
            match (r_gt, euler(r_gt)) {
                (Some(r_gt), Some(g)) => {
                    for a in 0..3 {
                        err[a].push((*t, wrap_pi((e[a] - g[a]).to_radians()).to_degrees()));
                    }
                    err[3].push((*t, log(&(r_gt.inverse() * r_hat)).norm().to_degrees()));
                }
                _ => err.iter_mut().for_each(|s| s.push((*t, f64::NAN))),
            }
        }
        for (a, e) in err.into_iter().enumerate() {
            error[a].series.push(Series::new(method.as_str(), with_breaks(e), c));
        }
    }
    let o = dir.join(format!("{name}_orientation.png"));
    let e = dir.join(format!("{name}_error.png"));
    line_figure(
        &o,
        &Figure {
            title: format!("{name}: attitude (ZYX Euler angles of the IMU frame), open-loop integration"),
            width: 1000,
            height: 800,
            rows: 3,
            cols: 1,
            panels: attitude,
        },
    )?;
    line_figure(
        &e,
        &Figure {
            title: format!("{name}: attitude error of open-loop integration"),
            width: 1000,
            height: 900,
            rows: 4,
            cols: 1,
            panels: error,
        },
    )?;
    Ok([o, e])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wraps_break_the_line() {
        let p = with_breaks(vec![(0.0, 170.0), (1.0, 179.0), (2.0, -179.0), (3.0, f64::NAN), (4.0, -170.0)]);
        assert_eq!(p.len(), 6);
        assert!(p[2].1.is_nan() && p[3].1 == -179.0);
    }
}
