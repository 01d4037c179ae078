//! What the fusion hands to the outputs (MAVLink, files): the filter's state at one instant and
//! the integrity verdict of the latest odometry epoch.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::filter::ResetReason;
use serde::Serialize;

/// Integrity verdict of one odometry epoch (docs/design.md, 4.8 "Integrity").
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(tag = "status", rename_all = "snake_case")]
pub enum IntegrityStatus {
    /// Every test passed with all matched planes.
    Ok,
    /// The listed planes (ids of the current epoch) were excluded; the rest passed.
    Excluded { planes: Vec<usize> },
    /// A fault was detected but the redundancy did not allow isolating it: not fused.
    DetectedNotIsolable,
    /// Fewer than three non-parallel planes: the solve was not attempted or not fused.
    UnderDetermined,
}

impl IntegrityStatus {
    /// Whether the epoch's odometry may be fused.
    pub fn usable(&self) -> bool {
        matches!(self, Self::Ok | Self::Excluded { .. })
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Host monotonic time, seconds.
    pub t: f64,
    /// Position NED (origin at start), metres.
    pub position: Vector3<f64>,
    /// Velocity NED, m/s.
    pub velocity: Vector3<f64>,
    /// Attitude, body FRD to NED.
    pub attitude: UnitQuaternion<f64>,
    /// Body angular rate (FRD), bias-corrected, rad/s.
    pub angular_rate: Vector3<f64>,
    pub position_covariance: Matrix3<f64>,
    pub velocity_covariance: Matrix3<f64>,
    /// Covariance between the velocity and the attitude errors (rows velocity).
    pub velocity_attitude_covariance: Matrix3<f64>,
    /// Attitude error covariance in the NED tangent space (roll, pitch, yaw), rad^2.
    pub attitude_covariance: Matrix3<f64>,
    pub gyro_bias: Vector3<f64>,
    pub accel_bias: Vector3<f64>,
    /// Incremented whenever the published pose jumps: a restart (divergence, an IMU gap, a
    /// non-finite state) or a correction larger than `filter.max_position_step_m`.
    pub reset_counter: u8,
    /// Why `reset_counter` last moved.
    pub last_reset: Option<ResetReason>,
    /// Verdict of the most recent odometry epoch, if any has run.
    pub integrity: Option<IntegrityStatus>,
    /// Seconds since the last odometry epoch that was fused (infinite before the first).
    pub since_last_fused: f64,
    /// A sensor is stale or the IMU had a gap: the estimate is dead-reckoning or worse.
    pub degraded: bool,
    /// The filter has converged since its last start or restart, and its gate did not refuse
    /// the last relative pose; otherwise the autopilot must not use the estimate, whatever its
    /// covariance says.
    pub converged: bool,
}

impl Estimate {
    /// Velocity in the body frame, which is what PX4 and ArduPilot fuse.
    pub fn body_velocity(&self) -> Vector3<f64> {
        self.attitude.inverse_transform_vector(&self.velocity)
    }

    /// Covariance of [`Self::body_velocity`]: `v_b = R^T v` takes the velocity error and,
    /// through the attitude error `dtheta` (global), `R^T [v]x dtheta`, which at speed or with
    /// an uncertain heading is not negligible.
    pub fn body_velocity_covariance(&self) -> Matrix3<f64> {
        let to_body = self.attitude.to_rotation_matrix().into_inner().transpose();
        let lever = self.velocity.cross_matrix();
        let cross = self.velocity_attitude_covariance * lever.transpose();
        let nav = self.velocity_covariance
            + lever * self.attitude_covariance * lever.transpose()
            + cross
            + cross.transpose();
        to_body * nav * to_body.transpose()
    }
}
