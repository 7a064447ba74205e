//! What the pipeline saw and did, by reason: the counters /diagnostics publishes.

/// Why an input sample was not used. Every drop is counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dropped {
    NonFinite,
    /// Beyond what an IMU measures ([`ImuSample::is_plausible`]): a corrupt value, which would
    /// poison the model's window and jump the integrated attitude.
    Implausible,
    DuplicateStamp,
    BackwardsStamp,
}

/// Counters of everything the pipeline saw and did, by reason (published on /diagnostics).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Counters {
    pub received: u64,
    pub processed: u64,
    pub dropped_non_finite: u64,
    pub dropped_implausible: u64,
    pub dropped_duplicate_stamp: u64,
    pub dropped_backwards_stamp: u64,
    pub gaps: u64,
    /// Times the source's clock went back and was followed ([`CLOCK_JUMP_SAMPLES`]).
    pub clock_jumps: u64,
    pub rate_changes: u64,
    pub resets: u64,
    pub warmup_samples: u64,
    /// Samples missing from holes shorter than a gap, estimated from the stamps of a regular
    /// stream (best-effort DDS dropping a burst, a driver's buffer overrun): bridged, not reset.
    pub missed_samples: u64,
    /// Samples with an axis held at the sensor's range ([`ClipDetector`]): used as recorded,
    /// their true values were larger.
    pub saturated_samples: u64,
    /// Times the model started or stopped being fed the input's periods ([`crate::resample`]).
    pub resampling_switches: u64,
}

impl Counters {
    /// Every input dropped, whatever the reason.
    pub fn dropped(&self) -> u64 {
        self.dropped_non_finite + self.dropped_implausible + self.dropped_duplicate_stamp + self.dropped_backwards_stamp
    }
}
