//! The odometer's prior: the relative pose the filter predicts between two times, with its
//! uncertainty, under which the odometer matches planes and solves.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use super::Eskf;
use crate::filter::history::Pose;
use crate::filter::relative_pose::{
    RelativePoseMeasurement, RelativeRotation, RelativeTranslation,
};
use crate::filter::state::{GYRO_BIAS, VEL};
use crate::filter::update::Observability;

/// Relative pose predicted by the filter between two times (the odometer's prior).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PosePrior {
    /// `C_t^t_ref`: rotates body-at-t vectors into body at t_ref.
    pub rotation: UnitQuaternion<f64>,
    /// Body origin at t in body-at-t_ref coordinates, m.
    pub translation: Vector3<f64>,
    /// Covariance of the rotation vector, rad^2.
    pub rotation_covariance: Matrix3<f64>,
    /// Covariance of the translation, m^2.
    pub translation_covariance: Matrix3<f64>,
}

impl Eskf {
    /// The relative pose from `t_ref` to `t` predicted by the filter, as the odometer's prior.
    /// Its covariance is exact (from the augmented covariance) when `t_ref` is the open
    /// clone's time and `t` the filter time; otherwise it is the IMU error growth over the
    /// interval: velocity and gyro-bias uncertainty times the interval plus the white noise.
    pub fn relative_pose(&self, t_ref: f64, t: f64) -> Option<PosePrior> {
        let reference = self.history.pose_at(t_ref)?;
        let current = self.pose_or_ahead(t)?;
        let (rotation, translation) = RelativePoseMeasurement::predict(&reference, &current);
        let exact = self.clone.filter(|c| {
            self.bridgeable(t_ref, c.t) && self.t.is_some_and(|now| self.bridgeable(t, now))
        });
        let (rotation_covariance, translation_covariance) = match exact {
            Some(clone) => self.clone_relative_covariance(&clone, t),
            None => self.growth_covariance(&reference, t - t_ref),
        };
        Some(PosePrior {
            rotation,
            translation,
            rotation_covariance,
            translation_covariance,
        })
    }

    fn clone_relative_covariance(&self, clone: &Pose, t: f64) -> (Matrix3<f64>, Matrix3<f64>) {
        let full = RelativeRotation {
            rotation_vector: Vector3::zeros(),
            covariance: Matrix3::zeros(),
            observability: Observability::full(),
        };
        let probe = RelativePoseMeasurement {
            t_ref: clone.t,
            t,
            rotation: Some(full),
            translation: Some(RelativeTranslation {
                displacement: Vector3::zeros(),
                covariance: Matrix3::zeros(),
                observability: Observability::full(),
            }),
            shared: None,
        };
        let rows = probe.cloned_rows(clone, &self.state, None, &self.covariance);
        let s = rows.innovation_covariance(&self.covariance);
        // The probe's noise is zero, so the covariance is H P H^T.
        (
            s.fixed_view::<3, 3>(0, 0).into(),
            s.fixed_view::<3, 3>(3, 3).into(),
        )
    }

    fn growth_covariance(&self, reference: &Pose, interval: f64) -> (Matrix3<f64>, Matrix3<f64>) {
        let dt = interval.abs();
        let m = self.imu_to_body.to_rotation_matrix().into_inner();
        let bias = m * self.covariance.fixed_view::<3, 3>(GYRO_BIAS, GYRO_BIAS) * m.transpose();
        let rotation =
            bias * dt * dt + Matrix3::identity() * self.config.gyro_noise_density.powi(2) * dt;
        let r_t = reference.q.to_rotation_matrix().into_inner().transpose();
        let velocity = r_t * self.covariance.fixed_view::<3, 3>(VEL, VEL) * r_t.transpose();
        let translation = velocity * dt * dt
            + Matrix3::identity() * self.config.accel_noise_density.powi(2) * dt.powi(3) / 3.0;
        (rotation, translation)
    }
}
