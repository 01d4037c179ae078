//! Stationary start: gravity alignment (roll and pitch from the mean specific force, gyro bias
//! from the mean rate, yaw 0 defining the local frame) and then zero-velocity plus zero-rate
//! updates (ZUPT / ZARU) until the configured end of the stationary period.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use super::state::{NominalState, GYRO_BIAS, VEL};
use super::update::{Jacobian3, Observability, Stacked};
use crate::sensors::ImuSample;

/// Whether one sample looks like a body at rest: slow rate and gravity-sized specific force.
pub(crate) fn looks_stationary(
    sample: &ImuSample,
    gravity: f64,
    max_rate: f64,
    max_force_error: f64,
) -> bool {
    let (rate, force) = rate_and_force(sample);
    rate.norm() <= max_rate && (force.norm() - gravity).abs() <= max_force_error
}

fn rate_and_force(sample: &ImuSample) -> (Vector3<f64>, Vector3<f64>) {
    match *sample {
        ImuSample::Rate { gyro, accel, .. } => (gyro, accel),
        ImuSample::Delta { dt, dq, dv, .. } => (dq.scaled_axis() / dt, dv / dt),
    }
}

/// Means of the IMU-frame specific force and rate over the alignment window.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct StationaryMeans {
    force: Vector3<f64>,
    rate: Vector3<f64>,
    weight: f64,
}

impl StationaryMeans {
    /// Adds one sample, weighted by the time it covers.
    pub(crate) fn add(&mut self, sample: &ImuSample, interval: f64) {
        let (rate, force) = rate_and_force(sample);
        self.force += force * interval;
        self.rate += rate * interval;
        self.weight += interval;
    }

    pub(crate) fn mean_rate(&self) -> Vector3<f64> {
        self.rate / self.weight
    }

    pub(crate) fn mean_force(&self) -> Vector3<f64> {
        self.force / self.weight
    }

    pub(crate) fn weight(&self) -> f64 {
        self.weight
    }

    /// Whether these means show motion against `reference` (both over a body at rest would
    /// agree to the sensor noise): the specific force turned or changed, or the rate changed.
    pub(crate) fn departs_from(
        &self,
        reference: &Self,
        max_force_change: f64,
        max_rate_change: f64,
    ) -> bool {
        (self.mean_force() - reference.mean_force()).norm() > max_force_change
            || (self.mean_rate() - reference.mean_rate()).norm() > max_rate_change
    }

    /// The state at rest: roll and pitch level the mean specific force (`f = -R^T g` at
    /// rest, and on average in a window without net acceleration), yaw is 0, and, when the
    /// window was `still`, the mean rate (which includes the Earth rate) is the gyro bias;
    /// in motion it is the motion, and the bias starts at 0.
    pub(crate) fn aligned_state(
        &self,
        imu_to_body: &UnitQuaternion<f64>,
        still: bool,
    ) -> NominalState {
        let f = imu_to_body * (self.force / self.weight);
        let roll = (-f.y).atan2(-f.z);
        let pitch = f.x.atan2((f.y * f.y + f.z * f.z).sqrt());
        NominalState::at_rest(
            UnitQuaternion::from_euler_angles(roll, pitch, 0.0),
            if still {
                self.mean_rate()
            } else {
                Vector3::zeros()
            },
        )
    }
}

/// The specific force in navigation axes, averaged over about the last `horizon` seconds
/// (exponentially): on average over a second or more a hovering or walking platform hardly
/// accelerates, so this mean is gravity as the filter's attitude sees it, and its lean is the
/// filter's tilt error. A restart after a divergence takes its tilt from it, as a start in
/// motion does from its window, rather than keeping the tilt that may have diverged.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct RecentForce {
    mean: Vector3<f64>,
    seconds: f64,
}

impl RecentForce {
    /// Adds the force `force` (navigation axes) held over `interval` seconds.
    pub(crate) fn add(&mut self, force: &Vector3<f64>, interval: f64, horizon: f64) {
        self.seconds += interval;
        let share = (interval / self.seconds.min(horizon)).min(1.0);
        self.mean += (force - self.mean) * share;
    }

    pub(crate) fn clear(&mut self) {
        *self = Self::default();
    }

    /// `attitude` turned about a level axis so that the mean force points straight up, once the
    /// mean spans `horizon` seconds: the heading moves only as much as a tilt of the body makes
    /// its Euler yaw move, and a restart keeps its own.
    pub(crate) fn levelled(
        &self,
        attitude: &UnitQuaternion<f64>,
        horizon: f64,
    ) -> Option<UnitQuaternion<f64>> {
        if self.seconds < horizon {
            return None;
        }
        // At rest the specific force is -g: up, which is -z in NED.
        let lean = UnitQuaternion::rotation_between(&self.mean, &-Vector3::z())?;
        Some(lean * attitude)
    }
}

/// Zero velocity and, from the mean gyro output over the interval, zero rate:
/// `0 - v = dv + n_v` and `mean(w_m) - b_g = db_g + n_w`, `n_w` of variance `N_g^2 / T`.
pub(crate) fn zero_motion_rows(
    state: &NominalState,
    mean_rate_imu: &Vector3<f64>,
    interval: f64,
    velocity_sigma: f64,
    gyro_noise_density: f64,
) -> Stacked {
    let mut rows = Stacked::default();
    let mut h = Jacobian3::zeros();
    h.fixed_view_mut::<3, 3>(0, VEL)
        .copy_from(&Matrix3::identity());
    rows.push(
        &-state.v,
        &h,
        &(Matrix3::identity() * velocity_sigma.powi(2)),
        &Observability::full(),
    );
    let mut h = Jacobian3::zeros();
    h.fixed_view_mut::<3, 3>(0, GYRO_BIAS)
        .copy_from(&Matrix3::identity());
    rows.push(
        &(mean_rate_imu - state.gyro_bias),
        &h,
        &(Matrix3::identity() * gyro_noise_density.powi(2) / interval),
        &Observability::full(),
    );
    rows
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recent_force_levels_a_tilted_attitude_about_a_level_axis() {
        let truth = UnitQuaternion::from_euler_angles(0.05, -0.17, 2.0);
        let tilt_error = UnitQuaternion::from_euler_angles(0.03, -0.11, 0.0);
        let estimate = tilt_error * truth;
        let gravity = Vector3::new(0.0, 0.0, 9.81);
        let mut recent = RecentForce::default();
        for k in 0..800 {
            // A hover's sway: accelerations that average out over the second.
            let sway = Vector3::new(0.3, -0.2, 0.1) * (f64::from(k) * 0.157).sin();
            let body_force = truth.inverse_transform_vector(&(sway - gravity));
            assert!(recent.levelled(&estimate, 1.0).is_none() || k > 399);
            recent.add(&(estimate * body_force), 0.0025, 1.0);
        }
        let levelled = recent.levelled(&estimate, 1.0).unwrap();
        let error = (levelled * truth.inverse()).scaled_axis();
        assert!(error.xy().norm() < 0.005, "{error:?}");
        let turn = (levelled * estimate.inverse()).scaled_axis();
        assert!(turn.z.abs() < 1e-12 && turn.norm() > 0.1, "{turn:?}");
        assert!(RecentForce::default().levelled(&estimate, 1.0).is_none());
    }

    #[test]
    fn gravity_alignment_recovers_roll_and_pitch() {
        let q = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0);
        let f = q.inverse_transform_vector(&Vector3::new(0.0, 0.0, -9.8));
        let mut means = StationaryMeans::default();
        means.add(
            &ImuSample::Rate {
                t: 0.0,
                gyro: Vector3::new(1e-3, 0.0, 0.0),
                accel: f,
            },
            0.01,
        );
        let state = means.aligned_state(&UnitQuaternion::identity(), true);
        let (roll, pitch, yaw) = state.q.euler_angles();
        assert!((roll - 0.3).abs() < 1e-12 && (pitch + 0.2).abs() < 1e-12);
        assert_eq!(yaw, 0.0);
        assert_eq!(state.gyro_bias, Vector3::new(1e-3, 0.0, 0.0));
    }
}
