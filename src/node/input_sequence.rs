//! What DDS lost of the input, read from each writer's sequence numbers: a sample that never
//! reached the node leaves a gap that no counter in the pipeline can see.
//!
//! Two different losses: samples a writer published before its first one reached the node
//! (the node started later, or matched the writer late: RustDDS can miss a Fast DDS writer's
//! first discovery heartbeat and match it only a second later, docs/interop.md), and gaps
//! after it (best-effort samples lost on the way, or pushed out of a full `queue_depth`).

use ros2_client::Gid;

/// Writers tracked; a topic with more (a misconfigured graph) counts the rest together.
const MAX_WRITERS: usize = 16;

/// Per-writer last sequence number, and the losses they show.
#[derive(Debug, Default, Clone)]
pub struct InputSequences {
    writers: Vec<(Gid, i64)>,
    /// Samples the writers published before their first one reached the node.
    pub before_first: u64,
    /// Samples missing between two that arrived (lost on the way, or out of a full history).
    pub lost: u64,
    /// Samples that arrived with a sequence number at or below one already seen.
    pub out_of_order: u64,
    /// Samples of writers beyond the first [`MAX_WRITERS`] (not followed).
    pub untracked: u64,
}

impl InputSequences {
    /// Notes one sample of `writer` with sequence number `seq` (the first a writer sends is 1).
    pub fn observe(&mut self, writer: Gid, seq: i64) {
        let full = self.writers.len() >= MAX_WRITERS;
        match self.writers.iter_mut().find(|(w, _)| *w == writer) {
            Some((_, last)) if seq > *last => {
                self.lost += (seq - *last - 1) as u64;
                *last = seq;
            }
            Some(_) => self.out_of_order += 1,
            None if !full => {
                self.before_first += (seq - 1).max(0) as u64;
                self.writers.push((writer, seq));
            }
            None => self.untracked += 1,
        }
    }

    /// Writers whose samples are followed.
    pub fn writers(&self) -> usize {
        self.writers.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gid(n: u8) -> Gid {
        Gid::from([n; 16])
    }

    #[test]
    fn a_late_match_and_a_gap_are_told_apart() {
        let mut s = InputSequences::default();
        // Matched at the writer's 151st sample; then 160 and 161 lost on the way.
        for seq in (151..=159).chain(162..=170) {
            s.observe(gid(1), seq);
        }
        assert_eq!((s.writers(), s.before_first, s.lost, s.out_of_order), (1, 150, 2, 0));
        // A second writer from its first sample; a repeat counts as out of order.
        s.observe(gid(2), 1);
        s.observe(gid(2), 2);
        s.observe(gid(2), 2);
        assert_eq!((s.writers(), s.before_first, s.lost, s.out_of_order), (2, 150, 2, 1));
    }

    #[test]
    fn writers_beyond_the_bound_are_counted_not_followed() {
        let mut s = InputSequences::default();
        for seq in 1..=3 {
            for n in 0..20u8 {
                s.observe(gid(n), seq);
            }
        }
        assert_eq!(s.writers(), MAX_WRITERS);
        assert_eq!((s.before_first, s.lost, s.untracked), (0, 0, 3 * (20 - MAX_WRITERS as u64)));
    }
}
