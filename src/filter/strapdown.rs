//! Strapdown mechanisation in local NED at IMU rate.
//!
//! Both IMU outputs are reduced to one increment per interval, `(dtheta, dv)`, expressed in the
//! body frame at the START of the interval, and integrated by the same code:
//! `q+ = q Exp(dtheta)`, `v+ = v + R dv + g dt`, `p+ = p + (v + v+) dt / 2`.
//! The position rule's error per step is `O(da dt^2)` and telescopes instead of accumulating.
//!
//! - `Delta` samples (Xsens DeltaQ / DeltaV) already are such increments: the MTi integrates
//!   at its internal rate with coning and sculling compensation on board (strapdown
//!   integration, SDI), so `dq` is used as the exact rotation over the interval.
//! - `Rate` samples are paired with the previous sample and both rate and specific force are
//!   taken as linear over the interval. The rotation gets the two-sample coning term
//!   `(w0 x w1) dt^2 / 12`; the velocity increment integrates `(I + [alpha(t)]x) f(t)` exactly
//!   for linear inputs (sculling and rotation terms) plus the second-order rotation term
//!   `alpha x (alpha x f) dt / 6`.
//!
//! Gravity is `[0, 0, g]` in NED with a constant configured magnitude; Earth rotation and
//! transport rate are neglected (local non-rotating frame, minutes-long indoor flights): the
//! Earth rate measured during the stationary start is absorbed in the gyro bias.

use nalgebra::{UnitQuaternion, Vector3};

use super::state::NominalState;
use crate::sensors::ImuSample;

/// Angle and velocity increments over `(t - dt, t]` in the IMU frame at the start of the
/// interval, before bias and scale-factor correction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ImuIncrement {
    pub t: f64,
    pub dt: f64,
    pub dtheta: Vector3<f64>,
    pub dv: Vector3<f64>,
}

impl ImuIncrement {
    /// The increment ending at `current`, using `previous` for `Rate` samples. `None` for a
    /// first `Rate` sample (nothing to pair with).
    pub(crate) fn from_samples(previous: Option<&ImuSample>, current: &ImuSample) -> Option<Self> {
        match *current {
            ImuSample::Delta { t, dt, dq, dv } => Some(Self {
                t,
                dt,
                dtheta: dq.scaled_axis(),
                dv,
            }),
            ImuSample::Rate { t, gyro, accel } => {
                let (t0, w0, f0) = match previous? {
                    ImuSample::Rate { t, gyro, accel } => (*t, *gyro, *accel),
                    ImuSample::Delta { t, dt, dq, dv } => (*t, dq.scaled_axis() / *dt, *dv / *dt),
                };
                Some(Self::from_linear_rates(t0, w0, f0, t, gyro, accel))
            }
        }
    }

    fn from_linear_rates(
        t0: f64,
        w0: Vector3<f64>,
        f0: Vector3<f64>,
        t1: f64,
        w1: Vector3<f64>,
        f1: Vector3<f64>,
    ) -> Self {
        let dt = t1 - t0;
        let dt2 = dt * dt;
        let dw = w1 - w0;
        let df = f1 - f0;
        let dtheta = (w0 + w1) * (dt / 2.0) + w0.cross(&w1) * (dt2 / 12.0);
        let first_order_rotation = w0.cross(&f0) * (dt2 / 2.0)
            + w0.cross(&df) * (dt2 / 3.0)
            + dw.cross(&f0) * (dt2 / 6.0)
            + dw.cross(&df) * (dt2 / 8.0);
        let mean_f = (f0 + f1) / 2.0;
        let second_order_rotation = dtheta.cross(&dtheta.cross(&mean_f)) * (dt / 6.0);
        let dv = mean_f * dt + first_order_rotation + second_order_rotation;
        Self {
            t: t1,
            dt,
            dtheta,
            dv,
        }
    }

    /// Removes bias and scale factor and rotates into the body frame.
    pub(crate) fn corrected(
        &self,
        state: &NominalState,
        imu_to_body: &UnitQuaternion<f64>,
    ) -> Corrected {
        let dtheta_imu = (self.dtheta - state.gyro_bias * self.dt)
            .component_div(&state.gyro_scale.add_scalar(1.0));
        let dv_imu = (self.dv - state.accel_bias * self.dt)
            .component_div(&state.accel_scale.add_scalar(1.0));
        Corrected {
            dt: self.dt,
            dtheta_imu,
            dv_imu,
            dtheta: imu_to_body * dtheta_imu,
            dv: imu_to_body * dv_imu,
        }
    }
}

/// A bias- and scale-corrected increment, in the IMU frame (for the Jacobians) and the body
/// frame (for the mechanisation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Corrected {
    pub dt: f64,
    pub dtheta_imu: Vector3<f64>,
    pub dv_imu: Vector3<f64>,
    pub dtheta: Vector3<f64>,
    pub dv: Vector3<f64>,
}

/// Integrates one corrected increment; biases and scale factors are constant here.
pub(crate) fn mechanise(
    state: &NominalState,
    inc: &Corrected,
    gravity: &Vector3<f64>,
) -> NominalState {
    let v_next = state.v + state.q * inc.dv + gravity * inc.dt;
    NominalState {
        p: state.p + (state.v + v_next) * (inc.dt / 2.0),
        v: v_next,
        q: state.q * UnitQuaternion::from_scaled_axis(inc.dtheta),
        ..*state
    }
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{Circle, Trajectory};
    use super::*;

    fn run(samples: &[ImuSample], start: NominalState) -> NominalState {
        let gravity = Vector3::new(0.0, 0.0, 9.80665);
        let identity = UnitQuaternion::identity();
        let mut state = start;
        let mut previous = None;
        for sample in samples {
            if let Some(inc) = ImuIncrement::from_samples(previous.as_ref(), sample) {
                state = mechanise(&state, &inc.corrected(&state, &identity), &gravity);
            }
            previous = Some(*sample);
        }
        state
    }

    fn check_tracks_truth(delta: bool) {
        let trajectory = Circle::default();
        let (rate, t_end) = (400.0, 10.0);
        let samples = trajectory.imu_samples(0.0, t_end, rate, delta);
        let truth0 = trajectory.truth(0.0);
        let start = NominalState {
            p: truth0.p,
            v: truth0.v,
            ..NominalState::at_rest(truth0.q, Vector3::zeros())
        };
        let end = run(&samples, start);
        let truth = trajectory.truth(t_end);
        let position_error = (end.p - truth.p).norm();
        let attitude_error = (end.q.inverse() * truth.q).angle();
        assert!(position_error < 1e-3, "position error {position_error} m");
        assert!(attitude_error < 1e-6, "attitude error {attitude_error} rad");
        assert!((end.v - truth.v).norm() < 1e-3);
    }

    #[test]
    fn noise_free_rate_samples_track_a_tumbling_circle_to_a_millimetre() {
        check_tracks_truth(false);
    }

    #[test]
    fn noise_free_delta_samples_track_a_tumbling_circle_to_a_millimetre() {
        check_tracks_truth(true);
    }

    #[test]
    fn coning_term_matters_for_rate_samples() {
        // Two samples with perpendicular rates: the coning term is the only difference from
        // a plain trapezoid and is the size Ignagni's formula gives.
        let a = ImuSample::Rate {
            t: 0.0,
            gyro: Vector3::x(),
            accel: Vector3::zeros(),
        };
        let b = ImuSample::Rate {
            t: 0.1,
            gyro: Vector3::y(),
            accel: Vector3::zeros(),
        };
        let inc = ImuIncrement::from_samples(Some(&a), &b).unwrap();
        let coning = inc.dtheta - Vector3::new(0.05, 0.05, 0.0);
        assert!((coning - Vector3::z() * 0.01 / 12.0).norm() < 1e-15);
    }
}
