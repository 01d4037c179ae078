//! Latencies of the live daemon, from the moment the chunk holding a scan's last byte was read
//! off the port (its host time) to a later moment on the same clock:
//! - scan to MAVLink: the bytes of the first MAVLink message carrying the epoch that scan
//!   closed have been written to the link (the figure the autopilot sees);
//! - scan to fused: the epoch has been fused and its outputs delivered to the MAVLink task.

use std::fmt;

/// Latencies kept for the distribution: a bounded buffer (one a second for a day is 86 400).
const KEPT: usize = 100_000;

#[derive(Debug)]
pub(crate) struct LatencyLog {
    /// What is measured, "scan-to-MAVLink" say: the log line's subject.
    what: &'static str,
    micros: Vec<u32>,
    total: u64,
}

/// The distribution at shutdown, microseconds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LatencySummary {
    pub what: &'static str,
    pub count: u64,
    pub median_us: u32,
    pub p90_us: u32,
    pub p99_us: u32,
    pub max_us: u32,
}

impl LatencyLog {
    pub(crate) fn new(what: &'static str) -> Self {
        Self {
            what,
            micros: Vec::new(),
            total: 0,
        }
    }

    pub(crate) fn add(&mut self, read_ns: u64, done_ns: u64) {
        let micros = u32::try_from(done_ns.saturating_sub(read_ns) / 1_000).unwrap_or(u32::MAX);
        tracing::debug!(latency_us = micros, "{} latency", self.what);
        self.total += 1;
        if self.micros.len() < KEPT {
            self.micros.push(micros);
        }
    }

    pub(crate) fn summary(&self) -> Option<LatencySummary> {
        let mut sorted = self.micros.clone();
        sorted.sort_unstable();
        let at = |q: f64| sorted[((sorted.len() - 1) as f64 * q).round() as usize];
        (!sorted.is_empty()).then(|| LatencySummary {
            what: self.what,
            count: self.total,
            median_us: at(0.5),
            p90_us: at(0.9),
            p99_us: at(0.99),
            max_us: at(1.0),
        })
    }
}

impl fmt::Display for LatencySummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} latency over {} epochs: median {} us, 90 % {} us, 99 % {} us, max {} us",
            self.what, self.count, self.median_us, self.p90_us, self.p99_us, self.max_us
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_of_a_known_spread() {
        let mut log = LatencyLog::new("scan-to-MAVLink");
        assert_eq!(log.summary(), None);
        for k in (1..=100u64).rev() {
            log.add(5_000_000, 5_000_000 + k * 1_000);
        }
        log.add(10, 5);
        let s = log.summary().unwrap();
        assert_eq!(s.count, 101);
        assert_eq!(
            (s.median_us, s.p90_us, s.p99_us, s.max_us),
            (50, 90, 99, 100)
        );
        assert!(s
            .to_string()
            .starts_with("scan-to-MAVLink latency over 101 epochs"));
    }
}
