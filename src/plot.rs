//! PNG figures (plotters, bitmap backend): line plots over time, log-log plots, 2-D scatter
//! with per-class colours, multi-panel figures. Used by `eval --plot-dir`, `embed` and
//! `diagnose`.
//!
//! Text is drawn with a TrueType font registered at run time (no system font library): by
//! default DejaVu Sans from Debian's `fonts-dejavu-core` (installed by `scripts/setup.sh`),
//! or the file named by `IMU_FSDA_FONT`. A missing font is a [`PlotError::Font`], never a
//! panic. Non-finite values (and non-positive ones on a log axis) are skipped: a line is
//! broken there, so NaN is also how a caller asks for a gap (e.g. at an angle wrap).

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle, RGBColor};

/// The font used when `IMU_FSDA_FONT` is not set.
pub const DEFAULT_FONT: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

#[derive(Debug, Clone, thiserror::Error)]
pub enum PlotError {
    #[error("font {path}: {why} (install Debian's fonts-dejavu-core, as scripts/setup.sh does, or set IMU_FSDA_FONT to a .ttf file)")]
    Font { path: PathBuf, why: String },
    #[error("{path}: {why}")]
    Draw { path: PathBuf, why: String },
    #[error("{0}: nothing to plot (no finite values)")]
    Empty(String),
    #[error("figure size {0}×{1} px is out of range (100–8000)")]
    Size(u32, u32),
    #[error("figure has {panels} panels for a {rows}×{cols} grid")]
    Layout { panels: usize, rows: usize, cols: usize },
}

/// Register the font once per process; later calls return the first outcome.
pub fn ensure_font() -> Result<(), PlotError> {
    static FONT: OnceLock<Result<(), PlotError>> = OnceLock::new();
    FONT.get_or_init(|| {
        let path = std::env::var_os("IMU_FSDA_FONT").map(PathBuf::from).unwrap_or_else(|| PathBuf::from(DEFAULT_FONT));
        let bytes = std::fs::read(&path).map_err(|e| PlotError::Font { path: path.clone(), why: e.to_string() })?;
        // plotters keeps a 'static reference: the font lives as long as the process.
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        register_font("sans-serif", FontStyle::Normal, bytes)
            .map_err(|_| PlotError::Font { path: path.clone(), why: "not a TrueType font".into() })?;
        tracing::debug!("plot font: {}", path.display());
        Ok(())
    })
    .clone()
}

/// A categorical palette (Tableau 10 then its light variants), readable on white.
pub const PALETTE: [RGBColor; 20] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
    RGBColor(174, 199, 232),
    RGBColor(255, 187, 120),
    RGBColor(152, 223, 138),
    RGBColor(255, 152, 150),
    RGBColor(197, 176, 213),
    RGBColor(196, 156, 148),
    RGBColor(247, 182, 210),
    RGBColor(199, 199, 199),
    RGBColor(219, 219, 141),
    RGBColor(158, 218, 229),
];

/// The `k`-th palette colour (cycling).
pub fn color(k: usize) -> RGBColor {
    PALETTE[k % PALETTE.len()]
}

/// One line.
#[derive(Debug, Clone)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub color: RGBColor,
    pub width: u32,
    pub dashed: bool,
}

impl Series {
    pub fn new(label: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor) -> Self {
        Series { label: label.into(), points, color, width: 2, dashed: false }
    }

    pub fn dashed(mut self) -> Self {
        self.dashed = true;
        self
    }

    pub fn width(mut self, w: u32) -> Self {
        self.width = w;
        self
    }
}

/// Where a panel's legend goes.
#[derive(Debug, Clone, Copy, Default)]
pub enum Legend {
    #[default]
    UpperRight,
    UpperLeft,
    LowerLeft,
    LowerRight,
    None,
}

/// One chart of a figure.
#[derive(Debug, Clone, Default)]
pub struct Panel {
    pub title: String,
    /// Axis descriptions, units included (`time [s]`).
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    pub log_x: bool,
    pub log_y: bool,
    /// X intervals drawn as light bands behind the lines (e.g. located segments).
    pub shade: Vec<(f64, f64)>,
    pub shade_label: String,
    pub legend: Legend,
    /// Fixed y range instead of the data's (e.g. the same scale on panels to compare).
    pub y_limits: Option<(f64, f64)>,
}

/// Panels on a `rows × cols` grid (row-major) under one title.
#[derive(Debug, Clone)]
pub struct Figure {
    pub title: String,
    pub width: u32,
    pub height: u32,
    pub rows: usize,
    pub cols: usize,
    pub panels: Vec<Panel>,
}

/// One class of a scatter plot.
#[derive(Debug, Clone)]
pub struct ScatterGroup {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub color: RGBColor,
    pub marker: Marker,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Marker {
    Circle,
    Triangle,
    Cross,
}

/// A 2-D scatter, one colour / marker per group.
#[derive(Debug, Clone)]
pub struct Scatter {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub width: u32,
    pub height: u32,
    pub groups: Vec<ScatterGroup>,
    pub marker_size: u32,
}

fn check_size(w: u32, h: u32) -> Result<(), PlotError> {
    if (100..=8000).contains(&w) && (100..=8000).contains(&h) {
        Ok(())
    } else {
        Err(PlotError::Size(w, h))
    }
}

fn usable(v: f64, log: bool) -> bool {
    v.is_finite() && (!log || v > 0.0)
}

/// Data range of the usable values, padded; log axes get whole decades' worth of margin.
fn axis_range(values: impl Iterator<Item = f64>, log: bool, what: &str) -> Result<Range<f64>, PlotError> {
    let (lo, hi) = values.filter(|v| usable(*v, log)).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if !lo.is_finite() {
        return Err(PlotError::Empty(what.into()));
    }
    if log {
        let (a, b) = (lo.log10(), hi.log10());
        let pad = ((b - a) * 0.05).max(0.1);
        Ok(10f64.powf(a - pad)..10f64.powf(b + pad))
    } else {
        let span = hi - lo;
        let pad = if span > 0.0 { span * 0.05 } else { lo.abs().max(1.0) * 0.1 };
        Ok(lo - pad..hi + pad)
    }
}

/// Compact tick labels: 3 significant digits, scientific outside [1e-3, 1e5); values below
/// 1e-9 of the axis span are rounding noise and print as 0. `span` is None for a log axis,
/// where only 1, 2 and 5 times a power of ten are labelled (the others crowd).
fn tick(v: &f64, span: Option<f64>) -> String {
    let a = v.abs();
    if span.is_none() && a > 0.0 {
        let m = a / 10f64.powf(a.log10().floor());
        if ![1.0, 2.0, 5.0].iter().any(|k| (m - k).abs() < 1e-6) {
            return String::new();
        }
    }
    if a == 0.0 || a < 1e-9 * span.unwrap_or(0.0) {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        let s = format!("{v:.0e}");
        s.replace("e-0", "e-").replace("e0", "")
    } else {
        let digits = (2 - a.log10().floor() as i32).max(0) as usize;
        let s = format!("{v:.digits$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    }
}

/// Runs of consecutive usable points; longer runs are reduced to the min and max of
/// `max_points / 2` buckets (what a line of that many pixels can show anyway).
fn runs(points: &[(f64, f64)], log_x: bool, log_y: bool, max_points: usize) -> Vec<Vec<(f64, f64)>> {
    let mut out: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut cur = Vec::new();
    for &(x, y) in points {
        if usable(x, log_x) && usable(y, log_y) {
            cur.push((x, y));
        } else if !cur.is_empty() {
            out.push(std::mem::take(&mut cur));
        }
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    let total: usize = out.iter().map(Vec::len).sum();
    if total <= max_points {
        return out;
    }
    let per_bucket = (2 * total).div_ceil(max_points).max(2);
    out.into_iter()
        .map(|run| {
            let mut r = Vec::with_capacity(2 * run.len() / per_bucket + 2);
            for chunk in run.chunks(per_bucket) {
                let (imin, imax) = chunk
                    .iter()
                    .enumerate()
                    .fold((0, 0), |(a, b), (k, p)| (if p.1 < chunk[a].1 { k } else { a }, if p.1 > chunk[b].1 { k } else { b }));
                let (first, second) = if imin <= imax { (imin, imax) } else { (imax, imin) };
                r.push(chunk[first]);
                if second != first {
                    r.push(chunk[second]);
                }
            }
            r
        })
        .collect()
}

fn draw_err(path: &Path) -> impl Fn(String) -> PlotError + '_ {
    move |why| PlotError::Draw { path: path.to_path_buf(), why }
}

fn legend_position(l: Legend) -> SeriesLabelPosition {
    match l {
        Legend::UpperRight | Legend::None => SeriesLabelPosition::UpperRight,
        Legend::UpperLeft => SeriesLabelPosition::UpperLeft,
        Legend::LowerLeft => SeriesLabelPosition::LowerLeft,
        Legend::LowerRight => SeriesLabelPosition::LowerRight,
    }
}

/// Draws one panel; a macro because the coordinate type differs with log/linear axes.
macro_rules! draw_panel {
    ($area:expr, $panel:expr, $xr:expr, $yr:expr, $spans:expr, $max_points:expr, $err:expr) => {{
        let panel: &Panel = $panel;
        let e = $err;
        let (xspan, yspan): (Option<f64>, Option<f64>) = $spans;
        let xf = move |v: &f64| tick(v, xspan);
        let yf = move |v: &f64| tick(v, yspan);
        let mut chart = ChartBuilder::on($area)
            .caption(&panel.title, ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(38)
            .y_label_area_size(62)
            .build_cartesian_2d($xr, $yr)
            .map_err(|x| e(x.to_string()))?;
        chart
            .configure_mesh()
            .x_desc(panel.x_label.as_str())
            .y_desc(panel.y_label.as_str())
            .x_label_formatter(&xf)
            .y_label_formatter(&yf)
            .label_style(("sans-serif", 13))
            .axis_desc_style(("sans-serif", 14))
            .max_light_lines(1)
            .light_line_style(RGBColor(240, 240, 240))
            .bold_line_style(RGBColor(215, 215, 215))
            .draw()
            .map_err(|x| e(x.to_string()))?;
        let (y0, y1) = {
            let r = chart.y_range();
            (r.start, r.end)
        };
        let band = RGBColor(255, 200, 60).mix(0.35);
        for (k, &(a, b)) in panel.shade.iter().enumerate() {
            let s = chart.draw_series(std::iter::once(Rectangle::new([(a, y0), (b, y1)], band.filled()))).map_err(|x| e(x.to_string()))?;
            if k == 0 && !panel.shade_label.is_empty() {
                s.label(panel.shade_label.as_str()).legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 18, y + 5)], band.filled()));
            }
        }
        let mut labelled = false;
        for s in &panel.series {
            let style = ShapeStyle { color: s.color.to_rgba(), filled: false, stroke_width: s.width };
            let mut first = true;
            for run in runs(&s.points, panel.log_x, panel.log_y, $max_points) {
                let ann = if s.dashed {
                    chart.draw_series(DashedLineSeries::new(run, 6, 4, style)).map_err(|x| e(x.to_string()))?
                } else {
                    chart.draw_series(LineSeries::new(run, style)).map_err(|x| e(x.to_string()))?
                };
                if first && !s.label.is_empty() {
                    labelled = true;
                    ann.label(s.label.as_str()).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
                }
                first = false;
            }
        }
        if (labelled || !panel.shade_label.is_empty()) && !matches!(panel.legend, Legend::None) {
            chart
                .configure_series_labels()
                .position(legend_position(panel.legend))
                .label_font(("sans-serif", 13))
                .background_style(WHITE.mix(0.85))
                .border_style(RGBColor(160, 160, 160))
                .draw()
                .map_err(|x| e(x.to_string()))?;
        }
    }};
}

fn panel_ranges(p: &Panel) -> Result<(Range<f64>, Range<f64>), PlotError> {
    let what = if p.title.is_empty() { p.y_label.clone() } else { p.title.clone() };
    let pts = || p.series.iter().flat_map(|s| s.points.iter()).filter(|(x, y)| usable(*x, p.log_x) && usable(*y, p.log_y));
    let x = axis_range(pts().map(|q| q.0), p.log_x, &what)?;
    let y = axis_range(pts().map(|q| q.1), p.log_y, &what)?;
    let y = match p.y_limits {
        Some((lo, hi)) if usable(lo, p.log_y) && usable(hi, p.log_y) && lo < hi => lo..hi,
        _ => y,
    };
    Ok((x, y))
}

fn draw_one(area: &DrawingArea<BitMapBackend<'_>, Shift>, p: &Panel, path: &Path, max_points: usize) -> Result<(), PlotError> {
    let (xr, yr) = panel_ranges(p)?;
    let err = draw_err(path);
    let span = |r: &Range<f64>, log: bool| (!log).then_some(r.end - r.start);
    let spans = (span(&xr, p.log_x), span(&yr, p.log_y));
    match (p.log_x, p.log_y) {
        (false, false) => draw_panel!(area, p, xr, yr, spans, max_points, &err),
        (true, false) => draw_panel!(area, p, xr.log_scale(), yr, spans, max_points, &err),
        (false, true) => draw_panel!(area, p, xr, yr.log_scale(), spans, max_points, &err),
        (true, true) => draw_panel!(area, p, xr.log_scale(), yr.log_scale(), spans, max_points, &err),
    }
    Ok(())
}

/// Write a (multi-panel) line figure as PNG. A panel without any usable value is an error.
pub fn line_figure(path: &Path, fig: &Figure) -> Result<(), PlotError> {
    ensure_font()?;
    check_size(fig.width, fig.height)?;
    if fig.rows * fig.cols < fig.panels.len() || fig.panels.is_empty() {
        return Err(PlotError::Layout { panels: fig.panels.len(), rows: fig.rows, cols: fig.cols });
    }
    // Check every panel before anything is written.
    for p in &fig.panels {
        panel_ranges(p)?;
    }
    let err = draw_err(path);
    let mut pixels = vec![255u8; fig.width as usize * fig.height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (fig.width, fig.height)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| err(x.to_string()))?;
        let body = if fig.title.is_empty() {
            root.clone()
        } else {
            root.titled(&fig.title, ("sans-serif", 22)).map_err(|x| err(x.to_string()))?
        };
        let areas = body.split_evenly((fig.rows, fig.cols));
        let max_points = 3 * (fig.width as usize / fig.cols.max(1));
        for (area, p) in areas.iter().zip(&fig.panels) {
            draw_one(area, p, path, max_points)?;
        }
        root.present().map_err(|x| err(x.to_string()))?;
    }
    write_png(path, &pixels, fig.width, fig.height)
}

/// Write a scatter plot as PNG. Points with a non-finite coordinate are skipped.
pub fn scatter(path: &Path, sc: &Scatter) -> Result<(), PlotError> {
    ensure_font()?;
    check_size(sc.width, sc.height)?;
    let pts = || sc.groups.iter().flat_map(|g| g.points.iter()).filter(|(x, y)| x.is_finite() && y.is_finite());
    let xr = axis_range(pts().map(|p| p.0), false, &sc.title)?;
    let yr = axis_range(pts().map(|p| p.1), false, &sc.title)?;
    // Room on the right for the legend.
    let xr = xr.start..xr.end + 0.3 * (xr.end - xr.start);
    let (xspan, yspan) = (Some(xr.end - xr.start), Some(yr.end - yr.start));
    let xf = move |v: &f64| tick(v, xspan);
    let yf = move |v: &f64| tick(v, yspan);
    let err = draw_err(path);
    let e = |x: DrawingAreaErrorKind<_>| err(x.to_string());
    let mut pixels = vec![255u8; sc.width as usize * sc.height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (sc.width, sc.height)).into_drawing_area();
        root.fill(&WHITE).map_err(e)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(&sc.title, ("sans-serif", 22))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(xr, yr)
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc(sc.x_label.as_str())
            .y_desc(sc.y_label.as_str())
            .x_label_formatter(&xf)
            .y_label_formatter(&yf)
            .label_style(("sans-serif", 13))
            .axis_desc_style(("sans-serif", 14))
            .max_light_lines(1)
            .light_line_style(RGBColor(240, 240, 240))
            .bold_line_style(RGBColor(220, 220, 220))
            .draw()
            .map_err(e)?;
        let size = sc.marker_size.max(1) as i32;
        for g in &sc.groups {
            let style = g.color.mix(0.75).filled();
            let stroke = ShapeStyle { color: g.color.to_rgba(), filled: false, stroke_width: 2 };
            let marker = g.marker;
            let points: Vec<(f64, f64)> = g.points.iter().copied().filter(|(x, y)| x.is_finite() && y.is_finite()).collect();
            if points.is_empty() {
                continue;
            }
            // One branch per marker: plotters takes concrete element types here.
            let (label, s) = (g.label.as_str(), size + 1);
            match marker {
                Marker::Circle => {
                    chart
                        .draw_series(points.into_iter().map(|c| Circle::new(c, size, style)))
                        .map_err(e)?
                        .label(label)
                        .legend(move |(x, y)| Circle::new((x + 6, y), s, style));
                }
                Marker::Triangle => {
                    chart
                        .draw_series(points.into_iter().map(|c| TriangleMarker::new(c, size + 1, style)))
                        .map_err(e)?
                        .label(label)
                        .legend(move |(x, y)| TriangleMarker::new((x + 6, y), s + 1, style));
                }
                Marker::Cross => {
                    chart
                        .draw_series(points.into_iter().map(|c| Cross::new(c, size, stroke)))
                        .map_err(e)?
                        .label(label)
                        .legend(move |(x, y)| Cross::new((x + 6, y), s, stroke));
                }
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font(("sans-serif", 13))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(160, 160, 160))
            .draw()
            .map_err(e)?;
        root.present().map_err(e)?;
    }
    write_png(path, &pixels, sc.width, sc.height)
}

/// Encode RGB pixels as PNG with the strongest compression (figures go into the
/// repository), through a temporary file so a reader never sees half a PNG.
fn write_png(path: &Path, rgb: &[u8], width: u32, height: u32) -> Result<(), PlotError> {
    let err = draw_err(path);
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let file = std::fs::File::create(&tmp).map_err(|x| err(x.to_string()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Best);
    enc.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
    let mut w = enc.write_header().map_err(|x| err(x.to_string()))?;
    w.write_image_data(rgb).map_err(|x| err(x.to_string()))?;
    w.finish().map_err(|x| err(x.to_string()))?;
    std::fs::rename(&tmp, path).map_err(|x| err(x.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Width and height from a PNG's IHDR, after checking the signature.
    pub(crate) fn png_size(path: &Path) -> (u32, u32) {
        let b = std::fs::read(path).unwrap();
        assert_eq!(&b[..8], b"\x89PNG\r\n\x1a\n", "not a PNG");
        assert_eq!(&b[12..16], b"IHDR");
        (u32::from_be_bytes(b[16..20].try_into().unwrap()), u32::from_be_bytes(b[20..24].try_into().unwrap()))
    }

    fn decode(path: &Path) -> (u32, u32, Vec<u8>) {
        let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size()];
        let info = r.next_frame(&mut buf).unwrap();
        buf.truncate(info.buffer_size());
        (info.width, info.height, buf)
    }

    fn sine(n: usize, f: f64) -> Vec<(f64, f64)> {
        (0..n).map(|k| (k as f64 * 0.01, (k as f64 * 0.01 * f).sin())).collect()
    }

    #[test]
    fn line_figure_writes_a_decodable_png_of_the_requested_size() {
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("lines.png");
        let mut gappy = sine(5000, 2.0);
        gappy[100].1 = f64::NAN;
        gappy[2000].1 = f64::INFINITY;
        let panel = |t: &str, log: bool| Panel {
            title: t.into(),
            x_label: "time [s]".into(),
            y_label: "angle [deg]".into(),
            series: vec![
                Series::new("a", gappy.iter().map(|&(x, y)| if log { (x + 0.01, y.abs() + 1e-3) } else { (x, y) }).collect(), color(0)),
                Series::new("b", sine(300, 5.0).into_iter().map(|(x, y)| (x + 0.01, y + 2.0)).collect(), color(1)).dashed(),
            ],
            log_x: log,
            log_y: log,
            shade: vec![(1.0, 2.0), (10.0, 12.0)],
            shade_label: "located".into(),
            ..Default::default()
        };
        let fig = Figure {
            title: "test".into(),
            width: 800,
            height: 600,
            rows: 3,
            cols: 1,
            panels: vec![panel("roll", false), panel("pitch", true), panel("yaw", false)],
        };
        line_figure(&path, &fig).unwrap();
        assert_eq!(png_size(&path), (800, 600));
        let (w, h, pixels) = decode(&path);
        assert_eq!((w, h), (800, 600));
        // Not blank: some pixels are not white.
        assert!(pixels.chunks(3).filter(|p| p != &[255, 255, 255]).count() > 1000);
    }

    #[test]
    fn scatter_writes_a_png() {
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("scatter.png");
        let groups = (0..3)
            .map(|g| ScatterGroup {
                label: format!("class {g}"),
                points: (0..50).map(|k| (g as f64 + (k as f64).sin(), (k as f64).cos())).chain([(f64::NAN, 0.0)]).collect(),
                color: color(g),
                marker: [Marker::Circle, Marker::Triangle, Marker::Cross][g],
            })
            .collect();
        let sc =
            Scatter { title: "t-SNE".into(), x_label: "x".into(), y_label: "y".into(), width: 640, height: 480, groups, marker_size: 3 };
        scatter(&path, &sc).unwrap();
        assert_eq!(decode(&path).0, 640);
        assert_eq!(png_size(&path), (640, 480));
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("x.png");
        let empty =
            Panel { title: "empty".into(), series: vec![Series::new("nan", vec![(0.0, f64::NAN)], color(0))], ..Default::default() };
        let fig = Figure { title: String::new(), width: 400, height: 300, rows: 1, cols: 1, panels: vec![empty.clone()] };
        assert!(matches!(line_figure(&path, &fig), Err(PlotError::Empty(_))));
        assert!(!path.exists());
        let log = Panel { log_y: true, series: vec![Series::new("neg", vec![(0.0, -1.0), (1.0, 0.0)], color(0))], ..empty };
        assert!(matches!(line_figure(&path, &Figure { panels: vec![log], ..fig.clone() }), Err(PlotError::Empty(_))));
        assert!(matches!(line_figure(&path, &Figure { width: 10, ..fig.clone() }), Err(PlotError::Size(10, 300))));
        assert!(matches!(line_figure(&path, &Figure { panels: vec![], ..fig }), Err(PlotError::Layout { .. })));
    }

    #[test]
    fn ticks_are_compact() {
        assert_eq!(tick(&0.0, Some(1.0)), "0");
        assert_eq!(tick(&-6e-17, Some(1.2)), "0");
        assert_eq!(tick(&1e-5, None), "1e-5");
        assert_eq!(tick(&1e-14, None), "1e-14");
        assert_eq!(tick(&5e-4, None), "5e-4");
        assert_eq!(tick(&7e-4, None), "");
        assert_eq!(tick(&0.25, Some(1.0)), "0.25");
        assert_eq!(tick(&120.0, Some(500.0)), "120");
        assert_eq!(tick(&-3.5, Some(10.0)), "-3.5");
    }

    #[test]
    fn runs_break_at_gaps_and_keep_extremes() {
        let mut p = sine(10_000, 3.0);
        p[5000].1 = f64::NAN;
        let r = runs(&p, false, false, 1000);
        assert_eq!(r.len(), 2);
        assert!(r.iter().map(Vec::len).sum::<usize>() <= 1100);
        let max = r.iter().flatten().map(|q| q.1).fold(f64::MIN, f64::max);
        assert!(max > 0.999);
    }
}
