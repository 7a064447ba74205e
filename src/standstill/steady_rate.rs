//! A body still but for a steady rate above `max_bias`: windows refused only as turning (their
//! block means held, their specific force is gravity) that follow one another at one rate. Had
//! the body turned across gravity at that rate, gravity would have turned in the body; where it
//! did not, the rate across gravity is this IMU's bias beyond `max_bias` (some parts' zero-rate
//! offset reaches ±20 °/s, 0.35 rad/s). About gravity, one IMU cannot tell a turn in place from
//! such a bias. Said (the node's /diagnostics, eval's note), never removed: `max_bias` is the
//! user's to raise.

use nalgebra::Vector3;

/// The least run said, s (four windows of the default 0.5 s).
const MIN_SECONDS: f64 = 2.0;

/// Gravity shows the rate across it is no turn when a turn at that rate would have turned it
/// this many times as far as it turned (and as `max_tilt_change`).
const TURN_EVIDENCE: f64 = 10.0;

/// A steady rate above `max_bias` on an otherwise still body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateAboveMaxBias {
    pub start_ns: i64,
    pub seconds: f64,
    /// Its mean, rad/s (IMU axes).
    pub rate: Vector3<f64>,
    /// Its part across the mean gravity and about it, rad/s.
    pub across_gravity: f64,
    pub about_gravity: f64,
    /// How far gravity turned in the body over the run, rad.
    pub tilt: f64,
    /// The settings it was judged by: `max_bias` (rad/s) and `max_tilt_change` (rad).
    pub max_bias: f64,
    pub max_tilt_change: f64,
}

impl RateAboveMaxBias {
    /// True when the rate across gravity cannot have been a turn: it is this IMU's bias.
    pub fn across_is_bias(&self) -> bool {
        self.across_gravity * self.seconds > TURN_EVIDENCE * self.tilt.max(self.max_tilt_change)
    }

    /// What it is, for /diagnostics and a note.
    pub fn says(&self) -> String {
        let r = self.rate;
        let what = if self.across_is_bias() {
            format!(
                "gravity turned {:.3} rad where a turn would have turned it {:.2} rad, so the {:.3} rad/s across it is this IMU's bias",
                self.tilt,
                self.across_gravity * self.seconds,
                self.across_gravity
            )
        } else {
            format!("{:.3} rad/s about gravity: a turn in place, or a bias beyond max_bias (one IMU cannot tell)", self.about_gravity)
        };
        format!(
            "{:.1} s still but for a steady [{:.4}, {:.4}, {:.4}] rad/s, above standstill.max_bias {}: {what}; \
             raise max_bias above {:.2} if the platform stood still",
            self.seconds,
            r.x,
            r.y,
            r.z,
            self.max_bias,
            r.amax()
        )
    }
}

/// The run of such windows in progress.
#[derive(Debug, Clone, Copy)]
pub(super) struct SteadyRate {
    start_ns: i64,
    seconds: f64,
    /// ∫ rate dt and ∫ specific force dt over its windows.
    turn: Vector3<f64>,
    force: Vector3<f64>,
    first_gravity: Vector3<f64>,
    tilt: f64,
}

impl SteadyRate {
    /// A run opened by one window (`seconds` long, at `rate`, specific force `gravity`).
    pub(super) fn start(start_ns: i64, seconds: f64, rate: Vector3<f64>, gravity: Vector3<f64>) -> Self {
        SteadyRate { start_ns, seconds, turn: rate * seconds, force: gravity * seconds, first_gravity: gravity, tilt: 0.0 }
    }

    /// Adds the next window; false (the run unchanged) when its rate is off the run's by
    /// `tolerance` or more on an axis.
    pub(super) fn extend(&mut self, seconds: f64, rate: Vector3<f64>, gravity: Vector3<f64>, tolerance: f64) -> bool {
        if (rate - self.turn / self.seconds).amax() >= tolerance {
            return false;
        }
        self.seconds += seconds;
        self.turn += rate * seconds;
        self.force += gravity * seconds;
        self.tilt = self.tilt.max(self.first_gravity.angle(&gravity));
        true
    }

    /// The run, once long enough to say, judged by `max_bias` and `max_tilt_change`.
    pub(super) fn said(&self, max_bias: f64, max_tilt_change: f64) -> Option<RateAboveMaxBias> {
        if self.seconds < MIN_SECONDS {
            return None;
        }
        let rate = self.turn / self.seconds;
        let up = self.force.try_normalize(1e-9).unwrap_or_else(Vector3::z);
        let about = rate.dot(&up);
        Some(RateAboveMaxBias {
            start_ns: self.start_ns,
            seconds: self.seconds,
            rate,
            across_gravity: (rate - up * about).norm(),
            about_gravity: about.abs(),
            tilt: self.tilt,
            max_bias,
            max_tilt_change,
        })
    }
}
