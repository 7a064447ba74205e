//! Latency histograms: fixed bins, no allocation per sample; split into idle and adapting.

use std::time::Duration;

/// Latency histogram in fixed bins, 10 µs up to 100 ms by default (no allocation per sample).
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    bins: Vec<u64>,
    bin_us: f64,
    count: u64,
    max_us: f64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        LatencyHistogram { bins: vec![0; 10_001], bin_us: 10.0, count: 0, max_us: 0.0 }
    }
}

impl LatencyHistogram {
    /// 1 µs bins up to 10 ms: for the stages of a sample's path, which take microseconds.
    pub fn fine() -> Self {
        LatencyHistogram { bins: vec![0; 10_001], bin_us: 1.0, count: 0, max_us: 0.0 }
    }

    pub fn record(&mut self, d: Duration) {
        let us = d.as_secs_f64() * 1e6;
        let i = ((us / self.bin_us) as usize).min(self.bins.len() - 1);
        self.bins[i] += 1;
        self.count += 1;
        self.max_us = self.max_us.max(us);
    }
    /// Quantile in µs (upper edge of the bin), 0 when empty.
    pub fn quantile_us(&self, q: f64) -> f64 {
        if self.count == 0 {
            return 0.0;
        }
        let target = (q * self.count as f64).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (i, b) in self.bins.iter().enumerate() {
            seen += b;
            if seen >= target {
                return ((i + 1) as f64 * self.bin_us).min(self.max_us.max(self.bin_us));
            }
        }
        self.max_us
    }
    pub fn count(&self) -> u64 {
        self.count
    }
    /// Largest value recorded, µs (exact, not binned).
    pub fn max_us(&self) -> f64 {
        self.max_us
    }
    /// p50 / p99 / max / count as JSON (the node's `--stats-json`, benchmarks).
    pub fn summary_json(&self) -> serde_json::Value {
        serde_json::json!({"p50_us": self.quantile_us(0.5), "p99_us": self.quantile_us(0.99), "max_us": self.max_us, "count": self.count})
    }
}

/// A sample's time in the node taken apart by stage (each a fine histogram): where the
/// in-node latency goes. DDS receive is the input's DDS source timestamp (the writer's clock,
/// the same host) to the node taking it from the subscription: the peer's write, delivery on
/// loopback, RustDDS's receive thread, the CDR decode and the wake of the node's task.
#[derive(Debug, Clone)]
pub struct StageLatency {
    pub dds_receive: LatencyHistogram,
    /// `Pipeline::push`: checks, power-on bias, the model, the attitude.
    pub correct: LatencyHistogram,
    /// `fill_denoised`, CDR encode and the send of `/imu/denoised`.
    pub publish_denoised: LatencyHistogram,
    /// The same for `/imu/gyro_correction`.
    pub publish_correction: LatencyHistogram,
}

impl Default for StageLatency {
    fn default() -> Self {
        StageLatency {
            dds_receive: LatencyHistogram::fine(),
            correct: LatencyHistogram::fine(),
            publish_denoised: LatencyHistogram::fine(),
            publish_correction: LatencyHistogram::fine(),
        }
    }
}

impl StageLatency {
    pub fn summary_json(&self) -> serde_json::Value {
        serde_json::json!({
            "dds_receive": self.dds_receive.summary_json(), "correct": self.correct.summary_json(),
            "publish_denoised": self.publish_denoised.summary_json(), "publish_correction": self.publish_correction.summary_json(),
        })
    }
}

/// Per-sample latencies split by whether an adaptation was running when the sample was
/// processed (index 0: idle, 1: adapting), to check the adaptation does not starve the
/// real-time path.
#[derive(Debug, Clone, Default)]
pub struct SplitLatency {
    /// In the node: input taken from the subscription → outputs published.
    pub in_node: [LatencyHistogram; 2],
    /// Writer to publish: the input's DDS source timestamp (the sender's clock; same host)
    /// → outputs published. Includes DDS delivery and any wait for a tokio worker.
    pub write_to_publish: [LatencyHistogram; 2],
}

impl SplitLatency {
    pub fn summary_json(&self) -> serde_json::Value {
        let side = |i: usize| serde_json::json!({"in_node": self.in_node[i].summary_json(), "write_to_publish": self.write_to_publish[i].summary_json()});
        serde_json::json!({"idle": side(0), "adapting": side(1)})
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latency_quantiles() {
        let mut h = LatencyHistogram::default();
        for us in 1..=100 {
            h.record(Duration::from_micros(us * 10));
        }
        assert!((h.quantile_us(0.5) - 500.0).abs() <= 10.0, "{}", h.quantile_us(0.5));
        assert!((h.quantile_us(0.99) - 990.0).abs() <= 10.0);
        let mut fine = LatencyHistogram::fine();
        for us in 1..=100 {
            fine.record(Duration::from_nanos(us * 1000 + 300));
        }
        assert_eq!((fine.quantile_us(0.5), fine.quantile_us(0.99)), (51.0, 100.0));
        fine.record(Duration::from_millis(50));
        assert_eq!(fine.max_us(), 50_000.0);
    }
}
