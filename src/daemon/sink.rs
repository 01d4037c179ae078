//! Where the fusion's outputs go, one way for `run` and `replay`: every estimate to
//! `trajectory.tum` and to the autopilot, every epoch to `epochs.jsonl` and to the tallies and
//! warnings of the summary and the log. What differs between the two is only how a MAVLink
//! message travels (`Autopilot`: over a channel to the link task live, serialised in line
//! with the replay) and what a failed write means (the caller's choice: `run` logs it and goes
//! on without files, `replay` stops).

use super::outcomes::{OutcomeCounts, OutcomeWarnings};
use super::outputs::{OutputError, Outputs};
use super::pipeline::{Estimator, Output};
use crate::estimate::Estimate;

/// How the estimates reach the autopilot.
pub(crate) trait Autopilot {
    type Error: From<OutputError>;
    /// An IMU-rate estimate; `files` takes the frames sent, for `mavlink.tlog`, when the sender
    /// writes them there.
    fn estimate(
        &mut self,
        estimate: &Estimate,
        files: Option<&mut Outputs>,
    ) -> Result<(), Self::Error>;
    /// The estimate right after an epoch closed by the chunk read at `read_ns`.
    fn epoch_estimate(
        &mut self,
        estimate: &Estimate,
        read_ns: u64,
        files: Option<&mut Outputs>,
    ) -> Result<(), Self::Error>;
}

/// No autopilot link (`run` without `[mavlink]`): the estimates go to the files only.
impl<A: Autopilot> Autopilot for Option<A> {
    type Error = A::Error;
    fn estimate(
        &mut self,
        estimate: &Estimate,
        files: Option<&mut Outputs>,
    ) -> Result<(), Self::Error> {
        self.as_mut()
            .map_or(Ok(()), |autopilot| autopilot.estimate(estimate, files))
    }
    fn epoch_estimate(
        &mut self,
        estimate: &Estimate,
        read_ns: u64,
        files: Option<&mut Outputs>,
    ) -> Result<(), Self::Error> {
        self.as_mut().map_or(Ok(()), |autopilot| {
            autopilot.epoch_estimate(estimate, read_ns, files)
        })
    }
}

/// What the outputs added up to.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Tally {
    pub estimates: u64,
    pub epochs: u64,
    pub planes: u64,
    pub detections: u64,
    pub exclusions: u64,
    pub outcomes: OutcomeCounts,
}

/// The one route of the fusion's outputs.
pub(crate) struct Sink<A> {
    autopilot: A,
    tally: Tally,
    warnings: OutcomeWarnings,
}

impl<A: Autopilot> Sink<A> {
    pub(crate) fn new(autopilot: A) -> Self {
        Self {
            autopilot,
            tally: Tally::default(),
            warnings: OutcomeWarnings::default(),
        }
    }

    /// Takes one output of the chunk read at `read_ns`, which is also the warnings' clock.
    pub(crate) fn output<E: Estimator>(
        &mut self,
        output: &Output<E::Epoch>,
        read_ns: u64,
        mut files: Option<&mut Outputs>,
    ) -> Result<(), A::Error> {
        match output {
            Output::Estimate(estimate) => {
                self.tally.estimates += 1;
                if let Some(files) = files.as_deref_mut() {
                    files.trajectory(estimate)?;
                }
                self.autopilot.estimate(estimate, files)?;
            }
            Output::EpochEstimate(estimate) => {
                self.autopilot.epoch_estimate(estimate, read_ns, files)?;
            }
            Output::Epoch(epoch) => {
                self.epoch::<E>(epoch, read_ns as f64 * 1e-9);
                if let Some(files) = files {
                    files.epoch(epoch)?;
                }
            }
        }
        Ok(())
    }

    fn epoch<E: Estimator>(&mut self, epoch: &E::Epoch, now_s: f64) {
        let counts = E::epoch_counts(epoch);
        self.tally.epochs += 1;
        self.tally.planes += counts.planes as u64;
        self.tally.detections += u64::from(counts.detected);
        self.tally.exclusions += counts.excluded as u64;
        tracing::debug!(
            outcome = counts.outcome.describe(),
            planes = counts.planes,
            excluded = counts.excluded,
            failure = counts.failure.as_deref(),
            "epoch"
        );
        if let Some(warning) = self.warnings.observe(&counts, now_s) {
            tracing::warn!("{warning}");
        }
        self.tally.outcomes.add(&counts);
    }

    pub(crate) fn tally(&self) -> &Tally {
        &self.tally
    }

    pub(crate) fn autopilot(&self) -> &A {
        &self.autopilot
    }

    pub(crate) fn into_parts(self) -> (A, Tally) {
        (self.autopilot, self.tally)
    }
}
