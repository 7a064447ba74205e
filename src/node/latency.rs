//! Latency histograms: fixed bins, no allocation per sample; split into idle and adapting.

use std::time::Duration;

/// Latency histogram in fixed 10 µs bins up to 100 ms (no allocation per sample).
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    bins: Vec<u64>,
    count: u64,
    max_us: f64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        LatencyHistogram { bins: vec![0; 10_001], count: 0, max_us: 0.0 }
    }
}

impl LatencyHistogram {
    const BIN_US: f64 = 10.0;
    pub fn record(&mut self, d: Duration) {
        let us = d.as_secs_f64() * 1e6;
        let i = ((us / Self::BIN_US) as usize).min(self.bins.len() - 1);
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
                return ((i + 1) as f64 * Self::BIN_US).min(self.max_us.max(Self::BIN_US));
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
    }
}
