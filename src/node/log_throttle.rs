//! At most one log line a second for what can repeat at the rate a peer sends it (an input of
//! the wrong type, a flood of `~/adapt` calls): the first is said at once, the others are
//! counted and their number said with the next line. The counters on /diagnostics count every
//! one.

use std::time::{Duration, Instant};

/// The least time between two lines of one throttle.
pub(super) const LOG_EVERY: Duration = Duration::from_secs(1);

#[derive(Debug)]
pub(super) struct LogThrottle {
    every: Duration,
    last: Option<Instant>,
    unsaid: u64,
}

impl LogThrottle {
    pub(super) fn new(every: Duration) -> Self {
        LogThrottle { every, last: None, unsaid: 0 }
    }

    /// `Some(n)`: log now, `n` occurrences were left unsaid since the last line; `None`: this one
    /// is counted and left unsaid.
    pub(super) fn admit(&mut self, now: Instant) -> Option<u64> {
        match self.last {
            Some(t) if now.saturating_duration_since(t) < self.every => {
                self.unsaid += 1;
                None
            }
            _ => {
                self.last = Some(now);
                Some(std::mem::take(&mut self.unsaid))
            }
        }
    }
}

/// " (N more since the last line)" where some were left unsaid, else "".
pub(super) fn unsaid(n: u64) -> String {
    match n {
        0 => String::new(),
        n => format!(" ({n} more since the last line)"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flood_is_one_line_a_second_with_the_count_of_the_rest() {
        let mut t = LogThrottle::new(LOG_EVERY);
        let t0 = Instant::now();
        // 1000 a second for 3 s.
        let said: Vec<(u64, u64)> = (0..3000u64).filter_map(|k| t.admit(t0 + Duration::from_millis(k)).map(|n| (k, n))).collect();
        assert_eq!(said, vec![(0, 0), (1000, 999), (2000, 999)]);
        assert_eq!(unsaid(999), " (999 more since the last line)");
        assert_eq!(unsaid(0), "");
        // Rare events are all said.
        let mut t = LogThrottle::new(LOG_EVERY);
        assert!((0..5u64).all(|k| t.admit(t0 + Duration::from_secs(2 * k)) == Some(0)));
    }
}
