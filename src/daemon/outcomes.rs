//! How the epochs turned out, for the replay summary and `run`'s log: counts per outcome with
//! its reason, and warnings when epochs fail or are under-determined, at most one per outcome
//! every [`WARN_EVERY_S`] of sensor time, so that a rig in a bare corridor does not flood the
//! journal at the epoch rate.

use super::pipeline::{EpochCounts, Outcome};
use std::fmt;

/// A warning about one outcome repeats at most this often, s.
pub(crate) const WARN_EVERY_S: f64 = 10.0;

/// Epochs per outcome.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct OutcomeCounts {
    counts: [u64; Outcome::ALL.len()],
    last_failure: Option<String>,
}

impl OutcomeCounts {
    pub(crate) fn add(&mut self, epoch: &EpochCounts) {
        self.counts[index(epoch.outcome)] += 1;
        if let Some(reason) = &epoch.failure {
            self.last_failure = Some(reason.clone());
        }
    }

    pub fn get(&self, outcome: Outcome) -> u64 {
        self.counts[index(outcome)]
    }

    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }
}

fn index(outcome: Outcome) -> usize {
    Outcome::ALL
        .iter()
        .position(|&o| o == outcome)
        .expect("ALL lists every outcome")
}

impl fmt::Display for OutcomeCounts {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.total() == 0 {
            return f.write_str("no epochs");
        }
        let mut first = true;
        for outcome in Outcome::ALL {
            let n = self.get(outcome);
            if n == 0 {
                continue;
            }
            if !first {
                f.write_str(", ")?;
            }
            first = false;
            write!(f, "{n} {}", outcome.describe())?;
            if let (Outcome::Failed, Some(reason)) = (outcome, &self.last_failure) {
                write!(f, " (the last: {reason})")?;
            }
        }
        Ok(())
    }
}

/// Decides the warnings about failed and under-determined epochs.
#[derive(Debug, Default)]
pub(crate) struct OutcomeWarnings {
    /// Per warned outcome: when it was last warned of, and the epochs since.
    warned: [(Option<f64>, u64); Outcome::ALL.len()],
}

impl OutcomeWarnings {
    /// The warning an epoch ending at sensor time `now_s` calls for, if any.
    pub(crate) fn observe(&mut self, epoch: &EpochCounts, now_s: f64) -> Option<String> {
        if !matches!(epoch.outcome, Outcome::Failed | Outcome::UnderDetermined) {
            return None;
        }
        let (last, since) = &mut self.warned[index(epoch.outcome)];
        *since += 1;
        let reason = epoch
            .failure
            .as_ref()
            .map_or_else(String::new, |reason| format!(": {reason}"));
        let message = match *last {
            None => format!(
                "epoch {}{reason} (repeats are logged at most every {WARN_EVERY_S:.0} s)",
                epoch.outcome.describe()
            ),
            // Written so that a clock going back does not silence the warnings for good.
            Some(at) if (now_s - at).abs() < WARN_EVERY_S => return None,
            Some(at) => format!(
                "{since} epochs {} in the last {:.0} s{reason}",
                epoch.outcome.describe(),
                now_s - at
            ),
        };
        *last = Some(now_s);
        *since = 0;
        Some(message)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn epoch(outcome: Outcome) -> EpochCounts {
        EpochCounts {
            outcome,
            failure: (outcome == Outcome::Failed).then(|| "scans arrived too late".to_string()),
            ..EpochCounts::default()
        }
    }

    #[test]
    fn counts_name_each_outcome_with_its_reason() {
        let mut counts = OutcomeCounts::default();
        assert_eq!(counts.to_string(), "no epochs");
        for outcome in [Outcome::Fused, Outcome::Fused, Outcome::UnderDetermined] {
            counts.add(&epoch(outcome));
        }
        counts.add(&epoch(Outcome::Failed));
        assert_eq!(counts.total(), 4);
        assert_eq!(counts.get(Outcome::Fused), 2);
        let line = counts.to_string();
        assert!(line.starts_with("2 fused, 1 under-determined"), "{line}");
        assert!(
            line.ends_with("1 failed in the filter (the last: scans arrived too late)"),
            "{line}"
        );
        assert!(!line.contains("gate"), "{line}");
    }

    #[test]
    fn warnings_come_at_most_every_10_s_per_outcome_with_a_count() {
        let mut warnings = OutcomeWarnings::default();
        assert_eq!(warnings.observe(&epoch(Outcome::Fused), 0.0), None);
        let first = warnings
            .observe(&epoch(Outcome::UnderDetermined), 1.0)
            .unwrap();
        assert!(first.starts_with("epoch under-determined"), "{first}");
        // A failure is its own reason to warn, whatever the other outcome did.
        let failed = warnings.observe(&epoch(Outcome::Failed), 1.5).unwrap();
        assert!(failed.contains("scans arrived too late"), "{failed}");
        for t in 2..11 {
            assert_eq!(
                warnings.observe(&epoch(Outcome::UnderDetermined), f64::from(t)),
                None
            );
        }
        let repeat = warnings
            .observe(&epoch(Outcome::UnderDetermined), 11.0)
            .unwrap();
        assert!(
            repeat.starts_with("10 epochs under-determined") && repeat.contains("last 10 s"),
            "{repeat}"
        );
        assert_eq!(
            warnings.observe(&epoch(Outcome::UnderDetermined), 12.0),
            None
        );
    }
}
