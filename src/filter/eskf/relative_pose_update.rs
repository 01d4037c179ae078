//! The odometry epoch's update: the relative pose, bridged to the clone and the current pose,
//! fused against the clone (`Cloned`) or as a mean velocity and rate (`Velocity`).

use super::{Eskf, FilterPhase, ResetReason, UpdateError, UpdateKind, UpdateReport};
use crate::filter::config::{RelativePoseUpdate, PAPER_EPOCH_S};
use crate::filter::consistency::surprises;
use crate::filter::history::Pose;
use crate::filter::relative_pose::RelativePoseMeasurement;

impl Eskf {
    /// Fuses one odometry epoch in the configured mode; the clone is consumed either way.
    pub fn update_relative_pose(
        &mut self,
        measurement: &RelativePoseMeasurement,
    ) -> Result<UpdateReport, UpdateError> {
        // The carried noise is shared only with the very next relative pose: once this one is
        // tried, fused or not, the pose after it shares nothing with the carried one.
        let carried = self.carried.take();
        let now = self.aligned_time()?;
        if !measurement.is_finite() {
            return Err(UpdateError::NonFinite);
        }
        if !self.bridgeable(measurement.t, now) {
            return Err(UpdateError::TimeMismatch {
                t: measurement.t,
                filter_t: now,
            });
        }
        if self.phase == FilterPhase::StationaryStart && self.shows_motion(measurement) {
            self.leave_stationary_start(measurement);
        }
        let current = Pose {
            t: now,
            p: self.state.p,
            q: self.state.q,
        };
        let at_ref =
            self.history
                .pose_at(measurement.t_ref)
                .ok_or(UpdateError::OutsideHistory {
                    t_ref: measurement.t_ref,
                })?;
        let at_t = self.pose_or_ahead(measurement.t).unwrap_or(current);
        let (rows, kind) = match self.config.relative_pose_update {
            RelativePoseUpdate::Cloned => {
                let clone = self
                    .clone
                    .take()
                    .filter(|c| self.bridgeable(measurement.t_ref, c.t))
                    .ok_or(UpdateError::NoClone {
                        t_ref: measurement.t_ref,
                    })?;
                // Bridge from the history's pose at the clone time, not from the clone: an
                // update while the clone was open (the stationary start's zero-velocity
                // updates) moved the history rigidly and the clone by its correlations, and
                // the bridge must be motion alone.
                let clone_in_history = self.history.pose_at(clone.t).unwrap_or(clone);
                let bridged = measurement.bridged(&clone_in_history, &at_ref, &at_t, &current);
                (
                    bridged.cloned_rows(&clone, &self.state, carried.as_ref(), &self.covariance),
                    UpdateKind::RelativePoseCloned,
                )
            }
            RelativePoseUpdate::Velocity => {
                let bridged = measurement.bridged(&at_ref, &at_ref, &at_t, &current);
                (
                    bridged.velocity_rows(
                        &at_ref,
                        &self.state,
                        &self.imu_to_body,
                        self.config.gyro_noise_density,
                    ),
                    UpdateKind::RelativePoseVelocity,
                )
            }
        };
        let report = self.fuse(&rows, kind, now)?;
        self.after_odometry_update(&report, [measurement.t_ref, measurement.t], now);
        Ok(report)
    }

    /// What an odometry update (a relative pose, or the map's lines) tells the filter about
    /// itself: the last fused time, a dispute, convergence since the last (re)start, and the
    /// divergence guard's verdict. `span` is when the update's epochs begin and end (a relative
    /// pose's two epochs; the map's one, twice).
    pub(super) fn after_odometry_update(
        &mut self,
        report: &UpdateReport,
        span: [f64; 2],
        now: f64,
    ) {
        if report.accepted && report.dof > 0 {
            self.last_fused = Some(now);
            self.degraded = None;
        }
        if report.dof > 0 {
            self.disputed = !report.accepted;
        }
        if !self.converged && surprised(report) {
            self.fused_since_start = 0;
            self.first_fused_ref = None;
        } else if report.accepted && report.dof > 0 {
            self.fused_since_start += 1;
            let first = *self.first_fused_ref.get_or_insert(span[0]);
            let epochs = self.config.converged_after_epochs;
            // Faster epochs must span as long (from the first one's reference to the last one's
            // end, the span of the epochs but the first), since what the first epochs leave
            // unsettled (a guessed velocity and tilt, the biases they imply) settles with time,
            // not with the count: at 10 Hz three epochs took 0.3 s, and in random room 131 the
            // start in motion counted as converged 1 s in with a gyro bias 7 mrad/s off.
            let span_s = f64::from(epochs.saturating_sub(1)) * PAPER_EPOCH_S;
            self.converged |= self.fused_since_start >= epochs && span[1] - first >= span_s;
        }
        if let Some(divergence) =
            self.guard
                .after_update(now, report.nis, report.dof, report.accepted, self.converged)
        {
            self.reinitialise(ResetReason::Diverged(divergence));
        }
    }
}

/// Whether the update surprised the filter (`consistency::surprises`) or the gate refused it.
/// Until the estimate has converged such an update starts the count again: the filter's
/// prediction disagreed with the odometry, so its covariance is not yet to be believed. In
/// `random-room-99` at 10 Hz a start in motion counted as converged on three epochs after two
/// refusals and NIS of 7.5 and 6.7 on 2 degrees of freedom, its tilt off and its velocity
/// 0.7 m/s off at a sigma of 0.09 m/s, and growing.
fn surprised(report: &UpdateReport) -> bool {
    report.dof > 0 && (!report.accepted || surprises(report.nis, report.dof))
}
