//! The diagnosis' PNGs, written beside `report.md` and linked from it:
//! - `psd.png`: Welch PSD of the residual per channel, before and after the fitted terms, with
//!   the located frequency bands shaded;
//! - `allan.png`: Allan deviation before / after, and what the fitted noise model predicts;
//! - `residual.png`: residual block means over time per sensor, before and after, with the
//!   located time segments shaded.

use std::path::{Path, PathBuf};

use super::residual::CHANNELS;
use super::Diagnosis;
use crate::plot::{color, line_figure, Figure, Legend, Panel, PlotError, Series};

const BEFORE: plotters::style::RGBColor = plotters::style::RGBColor(214, 39, 40);
const AFTER: plotters::style::RGBColor = plotters::style::RGBColor(31, 119, 180);

fn unit(c: usize) -> &'static str {
    if c < 3 {
        "rad/s"
    } else {
        "m/s²"
    }
}

/// Average of the PSD over 1/20-decade frequency bins: a readable curve, the level kept.
fn log_binned(rows: &[(f64, f64, f64)]) -> Vec<(f64, f64, f64)> {
    let mut out: Vec<(f64, f64, f64)> = Vec::new();
    let mut cur: Option<(i64, f64, f64, f64, usize)> = None;
    for &(f, b, a) in rows.iter().filter(|r| r.0 > 0.0) {
        let k = (f.log10() * 20.0).floor() as i64;
        match &mut cur {
            Some((kk, sf, sb, sa, n)) if *kk == k => {
                *sf += f;
                *sb += b;
                *sa += a;
                *n += 1;
            }
            _ => {
                if let Some((_, sf, sb, sa, n)) = cur.take() {
                    out.push((sf / n as f64, sb / n as f64, sa / n as f64));
                }
                cur = Some((k, f, b, a, 1));
            }
        }
    }
    if let Some((_, sf, sb, sa, n)) = cur {
        out.push((sf / n as f64, sb / n as f64, sa / n as f64));
    }
    out
}

/// Write the three PNGs into `dir`; returns their paths.
pub fn write_figures(dir: &Path, d: &Diagnosis) -> Result<Vec<PathBuf>, PlotError> {
    let mut written = Vec::new();

    let psd = psd_panels(d);
    let p = dir.join("psd.png");
    line_figure(
        &p,
        &Figure { title: "Residual PSD (Welch, 1/20-decade bins)".into(), width: 1200, height: 700, rows: 2, cols: 3, panels: psd },
    )?;
    written.push(p);

    let allan = allan_panels(d);
    let p = dir.join("allan.png");
    line_figure(&p, &Figure { title: "Residual Allan deviation".into(), width: 1200, height: 700, rows: 2, cols: 3, panels: allan })?;
    written.push(p);

    let t = &d.curves.residual_t;
    let res = residual_panels(d);
    let block = if t.len() > 1 { t[1] - t[0] } else { 0.0 };
    let p = dir.join("residual.png");
    line_figure(
        &p,
        &Figure {
            title: format!("Residual over time ({block:.2} s block means)"),
            width: 1200,
            height: 800,
            rows: 2,
            cols: 2,
            panels: res,
        },
    )?;
    written.push(p);
    Ok(written)
}

/// Per channel: the residual's PSD before and after the fit, the located bands shaded.
fn psd_panels(d: &Diagnosis) -> Vec<Panel> {
    (0..6)
        .map(|c| {
            let rows = log_binned(d.curves.psd.get(c).map_or(&[][..], Vec::as_slice));
            Panel {
                title: CHANNELS[c].into(),
                x_label: "frequency [Hz]".into(),
                y_label: format!("PSD [({})²/Hz]", unit(c)),
                series: vec![
                    Series::new("before (real − sim)", rows.iter().map(|r| (r.0, r.1)).collect(), BEFORE),
                    Series::new("after (fitted terms removed)", rows.iter().map(|r| (r.0, r.2)).collect(), AFTER),
                ],
                log_x: true,
                log_y: true,
                shade: d.located.iter().filter(|l| l.kind == "band" && l.channel == CHANNELS[c]).map(|l| (l.from, l.to)).collect(),
                shade_label: "located band".into(),
                legend: if c == 0 { Legend::LowerLeft } else { Legend::None },
                ..Default::default()
            }
        })
        .collect()
}

/// Per channel: the residual's Allan deviation before and after, beside the noise model's.
fn allan_panels(d: &Diagnosis) -> Vec<Panel> {
    (0..6)
        .map(|c| {
            let rows = d.curves.allan.get(c).map_or(&[][..], Vec::as_slice);
            let model = d.curves.allan_model.get(c).map_or(&[][..], Vec::as_slice);
            Panel {
                title: CHANNELS[c].into(),
                x_label: "τ [s]".into(),
                y_label: format!("Allan deviation [{}]", unit(c)),
                series: vec![
                    Series::new("before", rows.iter().map(|r| (r.0, r.1)).collect(), BEFORE),
                    Series::new("after", rows.iter().map(|r| (r.0, r.2)).collect(), AFTER),
                    Series::new("noise model (after)", model.to_vec(), plotters::style::BLACK).dashed().width(1),
                ],
                log_x: true,
                log_y: true,
                legend: if c == 0 { Legend::LowerLeft } else { Legend::None },
                ..Default::default()
            }
        })
        .collect()
}

/// Per sensor: the residual's block means over time before (located segments shaded) and
/// after the held-out fit, on one scale.
fn residual_panels(d: &Diagnosis) -> Vec<Panel> {
    let t = &d.curves.residual_t;
    let mut res = Vec::new();
    for (s, sensor) in ["gyro", "accel"].iter().enumerate() {
        let shade: Vec<(f64, f64)> =
            d.located.iter().filter(|l| l.kind == "segment" && l.channel == *sensor).map(|l| (l.from, l.to)).collect();
        // One scale for before and after, so the improvement shows.
        let (lo, hi) = [&d.curves.residual_before, &d.curves.residual_after]
            .iter()
            .flat_map(|r| r[3 * s..3 * s + 3].iter().flatten())
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(*v), b.max(*v)));
        let pad = ((hi - lo) * 0.05).max(1e-12);
        for (after, curves) in [(false, &d.curves.residual_before), (true, &d.curves.residual_after)] {
            let series = (0..3)
                .map(|a| {
                    let c = 3 * s + a;
                    Series::new(CHANNELS[c], t.iter().zip(&curves[c]).map(|(t, v)| (*t, *v)).collect(), color(a))
                })
                .collect();
            res.push(Panel {
                title: format!("{sensor} residual {}", if after { "after (held-out fit removed)" } else { "before (real − sim)" }),
                x_label: "time [s]".into(),
                y_label: format!("block mean [{}]", unit(3 * s)),
                series,
                shade: if after { Vec::new() } else { shade.clone() },
                shade_label: if after { String::new() } else { "located segment".into() },
                legend: Legend::UpperLeft,
                y_limits: lo.is_finite().then_some((lo - pad, hi + pad)),
                ..Default::default()
            });
        }
    }
    res
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_bins_average_and_skip_dc() {
        let rows: Vec<(f64, f64, f64)> = (0..1000).map(|k| (k as f64 * 0.1, 2.0, 1.0)).collect();
        let b = log_binned(&rows);
        assert!(b.len() < 100 && b.len() > 30, "{}", b.len());
        assert!(b.iter().all(|r| r.0 > 0.0 && r.1 == 2.0 && r.2 == 1.0));
        assert!(b.windows(2).all(|w| w[0].0 < w[1].0));
    }
}
