//! The gravity-aided attitude run again at the first standstill: until the power-on bias is
//! measured, the gyro carries it and the attitude integrates it (a heading error that stays
//! for the whole run). The samples since the filter started are kept (bounded); each still
//! window of the first standstill runs the filter again from its start with the bias now
//! known, and the attitude published from then on is that run's. What was published before
//! stays as it was. docs/node.md, "The first standstill in hindsight".

use nalgebra::Vector3;

use super::gravity_aided::GravityAided;

/// One sample the filter saw: its stamp, the gyro before the power-on bias removed then, the
/// specific force.
#[derive(Debug, Clone, Copy)]
struct Seen {
    stamp_ns: i64,
    gyro_with_bias: Vector3<f64>,
    accel: Vector3<f64>,
}

/// The filter's start and the samples since, until the first standstill has ended.
pub(super) struct Hindsight {
    /// The filter as it started, and the bias removed upstream then.
    start: Option<(GravityAided, Vector3<f64>)>,
    seen: Vec<Seen>,
    capacity: usize,
    /// The longest span kept, ns.
    span_ns: i64,
    /// Nothing more to do: the first standstill ended, the span outgrew the buffer, a gap or
    /// a model's output came in, or it is off.
    closed: bool,
    /// The span of the last run again, s (from the filter's start to the sample before the
    /// standstill's window that set it).
    pub(super) last_span_s: Option<f64>,
}

impl Hindsight {
    /// Keeps up to `seconds` of samples, at most `seconds × rate_hz` of them (0 s: off).
    pub(super) fn new(seconds: f64, rate_hz: f64) -> Self {
        let capacity = (seconds * rate_hz.max(1.0)).ceil() as usize;
        let span_ns = (seconds * 1e9) as i64;
        Hindsight { start: None, seen: Vec::new(), capacity, span_ns, closed: capacity == 0, last_span_s: None }
    }

    /// The filter has just started (`removed`: the power-on bias removed from its gyro).
    pub(super) fn start(&mut self, filter: &GravityAided, removed: Vector3<f64>) {
        if !self.closed && self.start.is_none() {
            self.start = Some((filter.clone(), removed));
            self.seen = Vec::with_capacity(self.capacity);
        }
    }

    /// A sample the filter saw, its gyro with `removed` taken off; `runs_model`: a model's
    /// output (not run again: its output on the debiased gyro is not known).
    pub(super) fn record(&mut self, stamp_ns: i64, gyro: &Vector3<f64>, accel: &Vector3<f64>, removed: Vector3<f64>, runs_model: bool) {
        if self.closed || self.start.is_none() {
            return;
        }
        let too_long = self.seen.first().is_some_and(|f| stamp_ns - f.stamp_ns > self.span_ns);
        if runs_model || too_long || self.seen.len() == self.capacity {
            self.close();
            return;
        }
        self.seen.push(Seen { stamp_ns, gyro_with_bias: gyro + removed, accel: *accel });
    }

    /// Stops for good (the first standstill is over, or something the run cannot redo).
    pub(super) fn close(&mut self) {
        self.closed = true;
        self.start = None;
        self.seen = Vec::new();
    }

    /// The filter run again from its start over the samples seen, with `removed` taken off
    /// their gyro and the residual bias set to 0 within `measured` (variance per axis); `None`
    /// when there is nothing to run again.
    pub(super) fn rerun(&mut self, removed: Vector3<f64>, measured: Vector3<f64>) -> Option<GravityAided> {
        if self.closed {
            return None;
        }
        let (start, removed_then) = self.start.as_ref()?;
        let mut filter = start.clone();
        filter.rebase_bias(removed - removed_then, Some(measured));
        for s in &self.seen {
            filter.push(s.stamp_ns, &(s.gyro_with_bias - removed), &s.accel);
        }
        if let (Some(first), Some(last)) = (self.seen.first(), self.seen.last()) {
            self.last_span_s = Some((last.stamp_ns - first.stamp_ns) as f64 * 1e-9);
        }
        Some(filter)
    }
}
