//! The stationary start's zero-motion updates, and how it ends: motion seen by the IMU or by
//! the odometry. Also the zero-velocity update on demand.

use nalgebra::{Matrix3, Vector3};

use super::{Eskf, FilterPhase, UpdateKind};
use crate::filter::alignment::zero_motion_rows;
use crate::filter::chi_square_quantile;
use crate::filter::relative_pose::RelativePoseMeasurement;
use crate::filter::state::{ACCEL_BIAS, ATT, GYRO_BIAS, VEL};
use crate::sensors::ImuSample;

impl Eskf {
    /// Zero-motion updates once per window; motion ends the stationary start early rather than
    /// letting a false zero velocity into the state. A window whose mean specific force or
    /// rate departs from the alignment's is motion, however gentle (a hover, the first
    /// instants of a take-off), which a per-sample test cannot see.
    pub(super) fn stationary_updates(&mut self, t: f64, sample: &ImuSample, interval: f64) {
        if !self.looks_stationary(sample) {
            self.end_stationary_start();
            return;
        }
        if let Some(window) = self.completed_window(t, sample, interval) {
            if self.departs(&window, &self.means) {
                self.end_stationary_start();
                return;
            }
            let rows = zero_motion_rows(
                &self.state,
                &window.mean_rate(),
                window.weight(),
                self.config.zupt_velocity_sigma_mps,
                self.config.gyro_noise_density,
            );
            // A rejected or failed zero-motion update only skips one window.
            let _ = self.fuse(&rows, UpdateKind::ZeroMotion, t);
        }
        let start = self.t_start.unwrap_or(t);
        if t - start >= self.config.stationary_start_s {
            self.phase = FilterPhase::Navigating;
        }
    }

    /// Motion ends the start. It may have begun before the IMU or the odometry could see it, and
    /// the zero-motion updates since then took its rate for gyro bias, its acceleration for
    /// accelerometer bias, and held the velocity it built at zero: they get back the
    /// uncertainty of such an unseen motion (`FilterConfig::still_sway_rate_sigma`,
    /// `unseen_start_force_sigma`, and `zupt_velocity_sigma_mps` unless that force is 0; added,
    /// which keeps every correlation valid). A start that runs its full length saw no motion
    /// and keeps what it learnt.
    fn end_stationary_start(&mut self) {
        let force = self.config.unseen_start_force_sigma();
        let velocity = if force > 0.0 {
            self.config.zupt_velocity_sigma_mps
        } else {
            0.0
        };
        let sways = [
            (GYRO_BIAS, self.config.still_sway_rate_sigma),
            (ACCEL_BIAS, force),
            (VEL, velocity),
        ];
        for (at, sway) in sways {
            for k in 0..3 {
                self.covariance[(at + k, at + k)] += sway * sway;
            }
        }
        self.counters.motion_during_start += 1;
        self.zero_motion = None;
        self.phase = FilterPhase::Navigating;
    }

    /// Whether a relative pose contradicts the stationary start: a rotation or displacement
    /// beyond what a body at rest shows (gyro noise, `zupt_velocity_sigma_mps` of sway) with
    /// the odometer's own noise, at 1 - 1e-6.
    pub(super) fn shows_motion(&self, measurement: &RelativePoseMeasurement) -> bool {
        let interval = (measurement.t - measurement.t_ref).abs();
        let threshold = chi_square_quantile(1.0 - 1e-6, 3);
        let beyond = |value: &Vector3<f64>, covariance: &Matrix3<f64>, rest_variance: f64| {
            let total = covariance + Matrix3::identity() * rest_variance;
            total
                .cholesky()
                .is_some_and(|c| value.dot(&c.solve(value)) > threshold)
        };
        let turned = measurement.rotation.is_some_and(|r| {
            let rest = self.config.gyro_noise_density.powi(2) * interval;
            beyond(&r.rotation_vector, &r.covariance, rest)
        });
        let moved = measurement.translation.is_some_and(|d| {
            let rest = (self.config.zupt_velocity_sigma_mps * interval).powi(2);
            beyond(&d.displacement, &d.covariance, rest)
        });
        turned || moved
    }

    /// The odometry saw motion while the zero-motion updates held the filter still: those
    /// updates were false for as long as the platform has moved, so the velocity, tilt and
    /// accelerometer bias get back the uncertainty of a start in motion (added, which keeps
    /// every correlation with the open clone valid) and the estimate converges again.
    pub(super) fn leave_stationary_start(&mut self, measurement: &RelativePoseMeasurement) {
        self.end_stationary_start();
        self.converged = false;
        self.fused_since_start = 0;
        self.first_fused_ref = None;
        // The zero-motion updates were wrong by at most the velocity the odometry saw (twice
        // its mean, for margin), and that error came from a tilt and an accelerometer bias
        // that turned it into velocity over the epoch.
        let interval = (measurement.t - measurement.t_ref).abs().max(1e-3);
        let seen = measurement
            .translation
            .map_or(0.0, |d| d.displacement.norm() / interval);
        let velocity = (2.0 * seen + self.config.zupt_velocity_sigma_mps)
            .min(self.config.moving_start_sigma_velocity_mps);
        let tilt = (velocity / (self.config.gravity_mps2 * interval))
            .min(self.config.moving_start_sigma_tilt_deg.to_radians());
        let added = [
            (VEL, velocity),
            (
                ACCEL_BIAS,
                (velocity / interval).min(self.config.initial_sigma_accel_bias),
            ),
        ];
        for (at, sigma) in added {
            for k in 0..3 {
                self.covariance[(at + k, at + k)] += sigma * sigma;
            }
        }
        for k in 0..2 {
            self.covariance[(ATT + k, ATT + k)] += tilt * tilt;
        }
    }

    /// Zero-velocity update on demand: how the tests pin the velocity between two clones.
    #[cfg(test)]
    pub(crate) fn update_zero_velocity(
        &mut self,
        sigma_mps: f64,
    ) -> Result<super::UpdateReport, super::UpdateError> {
        use crate::filter::update::{Jacobian3, Observability, Stacked};
        let t = self.aligned_time()?;
        let mut rows = Stacked::default();
        let mut h = Jacobian3::zeros();
        h.fixed_view_mut::<3, 3>(0, VEL)
            .copy_from(&Matrix3::identity());
        rows.push(
            &-self.state.v,
            &h,
            &(Matrix3::identity() * sigma_mps * sigma_mps),
            &Observability::full(),
        );
        self.fuse(&rows, UpdateKind::ZeroMotion, t)
    }
}
