//! Nominal state and the layout of the 21 error states (Sola 2017, global attitude error):
//! `[dp, dv, dtheta, dbg, dba, dsg, dsa]`, followed in the covariance by the 6 cloned states
//! `[dp_i, dtheta_i]` of the reference epoch when a clone is active, and by the 6 states of the
//! noise the reference epoch's planes left in the last fused relative pose
//! `[rotation, displacement]`, which the next relative pose shares (`relative_pose::SharedNoise`).

use nalgebra::{SMatrix, SVector, UnitQuaternion, Vector3};

pub const POS: usize = 0;
pub const VEL: usize = 3;
pub const ATT: usize = 6;
pub(crate) const GYRO_BIAS: usize = 9;
pub(crate) const ACCEL_BIAS: usize = 12;
pub(crate) const GYRO_SCALE: usize = 15;
pub(crate) const ACCEL_SCALE: usize = 18;
/// Number of error states of the filter proper.
pub(crate) const ERROR_STATES: usize = 21;
pub(crate) const CLONE_POS: usize = 21;
pub(crate) const CLONE_ATT: usize = 24;
/// The carried noise of the reference epoch's planes: rotation (right perturbation, body axes
/// of the reference epoch), then displacement.
pub(crate) const CARRIED: usize = 27;
/// Error states, the clone of the reference pose and the carried noise.
pub(crate) const AUGMENTED: usize = 33;

pub type Covariance = SMatrix<f64, AUGMENTED, AUGMENTED>;
pub(crate) type ErrorState = SVector<f64, AUGMENTED>;

/// Nominal (large-signal) state. The IMU model, per axis in the IMU frame, is
/// `measured = (1 + scale) * true + bias + noise` for both the gyro and the accelerometer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NominalState {
    /// Position NED, m.
    pub p: Vector3<f64>,
    /// Velocity NED, m/s.
    pub v: Vector3<f64>,
    /// Attitude body FRD -> NED.
    pub q: UnitQuaternion<f64>,
    /// Gyro bias, IMU frame, rad/s.
    pub gyro_bias: Vector3<f64>,
    /// Accelerometer bias, IMU frame, m/s^2.
    pub accel_bias: Vector3<f64>,
    /// Gyro scale-factor error, IMU frame.
    pub gyro_scale: Vector3<f64>,
    /// Accelerometer scale-factor error, IMU frame.
    pub accel_scale: Vector3<f64>,
}

impl NominalState {
    pub fn at_rest(q: UnitQuaternion<f64>, gyro_bias: Vector3<f64>) -> Self {
        Self {
            p: Vector3::zeros(),
            v: Vector3::zeros(),
            q,
            gyro_bias,
            accel_bias: Vector3::zeros(),
            gyro_scale: Vector3::zeros(),
            accel_scale: Vector3::zeros(),
        }
    }

    /// Adds an error-state correction (true = nominal + error; attitude `q <- Exp(dtheta) q`).
    pub(crate) fn inject(&self, dx: &ErrorState) -> Self {
        let block = |at: usize| Vector3::new(dx[at], dx[at + 1], dx[at + 2]);
        Self {
            p: self.p + block(POS),
            v: self.v + block(VEL),
            q: UnitQuaternion::from_scaled_axis(block(ATT)) * self.q,
            gyro_bias: self.gyro_bias + block(GYRO_BIAS),
            accel_bias: self.accel_bias + block(ACCEL_BIAS),
            gyro_scale: self.gyro_scale + block(GYRO_SCALE),
            accel_scale: self.accel_scale + block(ACCEL_SCALE),
        }
    }

    pub(crate) fn is_finite(&self) -> bool {
        let vectors = [
            self.p,
            self.v,
            self.gyro_bias,
            self.accel_bias,
            self.gyro_scale,
            self.accel_scale,
        ];
        vectors.iter().all(|v| v.iter().all(|x| x.is_finite()))
            && self.q.coords.iter().all(|x| x.is_finite())
    }
}
