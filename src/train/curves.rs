//! `<name>.curves.png`, written at the end of every run: the loss per epoch, and the
//! full-length AOE of the validation and monitor recordings (one line per dataset) at every
//! evaluation, with the exported epoch marked — where a run is easier to judge by eye than
//! from `<name>.train.json`.

use std::collections::BTreeMap;
use std::path::Path;

use super::config::first_path_component;
use super::report::{SequenceEvals, TrainSummary};
use crate::plot::{color, line_figure, Figure, Legend, Panel, PlotError, Series};

/// Mean AOE per dataset (first path component of the source) at each evaluated epoch.
pub fn aoe_per_dataset(evals: &[SequenceEvals]) -> BTreeMap<String, Vec<(f64, f64)>> {
    let mut sums: BTreeMap<String, BTreeMap<usize, (f64, usize)>> = BTreeMap::new();
    for s in evals {
        let per_epoch = sums.entry(first_path_component(&s.source).to_string()).or_default();
        for (epoch, e) in &s.evals {
            let slot = per_epoch.entry(*epoch).or_insert((0.0, 0));
            slot.0 += e.aoe_deg;
            slot.1 += 1;
        }
    }
    sums.into_iter().map(|(d, per_epoch)| (d, per_epoch.into_iter().map(|(ep, (sum, n))| (ep as f64, sum / n as f64)).collect())).collect()
}

/// Draws the run's curves to `path`. Needs the plot font (see `plot`); the caller decides
/// whether a failure matters (the trainer only warns: the model is already exported).
pub fn training_curves(summary: &TrainSummary, path: &Path) -> Result<(), PlotError> {
    let loss: Vec<(f64, f64)> = summary.history.iter().map(|r| (r.epoch as f64 + 1.0, r.loss)).collect();
    let mut loss_series = vec![Series::new("loss (query, adapted)", loss, color(0)).width(1)];
    let support: Vec<(f64, f64)> = summary.history.iter().filter_map(|r| r.support_loss.map(|s| (r.epoch as f64 + 1.0, s))).collect();
    if !support.is_empty() {
        loss_series.push(Series::new("support loss (unadapted)", support, color(1)).width(1));
    }
    let mut panels = vec![Panel {
        title: format!("{} ({:?}, seed {}): loss", summary.name, summary.mode, summary.seed),
        x_label: "epoch".into(),
        y_label: "loss".into(),
        series: loss_series,
        log_y: true,
        ..Default::default()
    }];
    let mut aoe = Vec::new();
    let mut k = 0;
    for (what, evals, dashed) in [("validation", &summary.validation, false), ("monitor", &summary.monitor, true)] {
        for (dataset, points) in aoe_per_dataset(evals) {
            let s = Series::new(format!("{what} {dataset}"), points, color(k));
            aoe.push(if dashed { s.dashed() } else { s });
            k += 1;
        }
    }
    if !aoe.is_empty() {
        let e = summary.exported_epoch as f64;
        // A band a few pixels wide whatever the run's length.
        let half = (summary.epochs as f64 / 150.0).max(0.3);
        let title = if summary.monitor.is_empty() {
            "full-length AOE per dataset".to_string()
        } else {
            "full-length AOE per dataset (monitor: recorded, never selected on)".to_string()
        };
        panels.push(Panel {
            title,
            x_label: "epoch".into(),
            y_label: "AOE [deg]".into(),
            series: aoe,
            log_y: true,
            shade: vec![(e - half, e + half)],
            shade_label: format!("exported (epoch {})", summary.exported_epoch),
            legend: Legend::UpperRight,
            ..Default::default()
        });
    }
    let rows = panels.len();
    line_figure(
        path,
        &Figure { title: format!("training run {}", summary.name), width: 1100, height: 380 * rows as u32, rows, cols: 1, panels },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::OrientationErrors;

    #[test]
    fn per_dataset_means_follow_the_epochs() {
        let seq = |source: &str, aoes: &[(usize, f64)]| SequenceEvals {
            name: source.into(),
            source: source.into(),
            raw: OrientationErrors::default(),
            evals: aoes.iter().map(|&(ep, a)| (ep, OrientationErrors { aoe_deg: a, ..Default::default() })).collect(),
        };
        let curves = aoe_per_dataset(&[
            seq("euroc/MH_01_easy", &[(10, 4.0), (20, 2.0)]),
            seq("euroc/V1_02_medium", &[(10, 6.0), (20, 4.0)]),
            seq("tumvi/dataset-room1_512_16", &[(10, 1.0), (20, 1.5)]),
        ]);
        assert_eq!(curves["euroc"], vec![(10.0, 5.0), (20.0, 3.0)]);
        assert_eq!(curves["tumvi"], vec![(10.0, 1.0), (20.0, 1.5)]);
        assert_eq!(curves.len(), 2);
    }
}
