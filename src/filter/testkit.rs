//! Analytic trajectories and the exact IMU outputs they produce, for the filter's tests.

use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::sensors::{ImuSample, TruthSample};

pub(crate) const G: f64 = 9.80665;

pub(crate) fn gravity() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, G)
}

pub(crate) trait Trajectory {
    fn truth(&self, t: f64) -> TruthSample;
    /// Body angular rate, FRD, rad/s.
    fn body_rate(&self, t: f64) -> Vector3<f64>;
    /// Acceleration in NED, m/s^2.
    fn accel_ned(&self, t: f64) -> Vector3<f64>;

    fn specific_force(&self, t: f64) -> Vector3<f64> {
        self.truth(t)
            .q
            .inverse_transform_vector(&(self.accel_ned(t) - gravity()))
    }

    /// Noise-free IMU output (IMU frame = body frame) at `rate_hz`: `Rate` samples at the
    /// instants of `[t0, t1]`, or exact `Delta` increments (start-of-interval body frame)
    /// covering `(t0, t1]`.
    fn imu_samples(&self, t0: f64, t1: f64, rate_hz: f64, delta: bool) -> Vec<ImuSample> {
        let dt = 1.0 / rate_hz;
        let n = ((t1 - t0) * rate_hz).round() as usize;
        (usize::from(delta)..=n)
            .map(|k| {
                let t = t0 + k as f64 * dt;
                if delta {
                    let (a, b) = (self.truth(t - dt), self.truth(t));
                    ImuSample::Delta {
                        t,
                        dt,
                        dq: a.q.inverse() * b.q,
                        dv: a.q.inverse_transform_vector(&(b.v - a.v - gravity() * dt)),
                    }
                } else {
                    ImuSample::Rate {
                        t,
                        gyro: self.body_rate(t),
                        accel: self.specific_force(t),
                    }
                }
            })
            .collect()
    }
}

/// A circle in the horizontal plane, heading along the track, rolling and pitching sinusoidally.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Circle {
    pub radius: f64,
    pub omega: f64,
    pub roll_amplitude: f64,
    pub pitch_amplitude: f64,
    pub wobble: f64,
}

impl Default for Circle {
    fn default() -> Self {
        Self {
            radius: 5.0,
            omega: 0.5,
            roll_amplitude: 0.2,
            pitch_amplitude: 0.1,
            wobble: 1.3,
        }
    }
}

impl Circle {
    fn euler(&self, t: f64) -> ([f64; 3], [f64; 3]) {
        let (w, a, b, s) = (
            self.omega,
            self.roll_amplitude,
            self.pitch_amplitude,
            self.wobble,
        );
        let angles = [
            a * (s * t).sin(),
            b * (0.7 * s * t).sin(),
            w * t + std::f64::consts::FRAC_PI_2,
        ];
        let rates = [a * s * (s * t).cos(), 0.7 * b * s * (0.7 * s * t).cos(), w];
        (angles, rates)
    }
}

impl Trajectory for Circle {
    fn truth(&self, t: f64) -> TruthSample {
        let (r, w) = (self.radius, self.omega);
        let ([roll, pitch, yaw], _) = self.euler(t);
        TruthSample {
            t,
            p: Vector3::new(r * (w * t).cos(), r * (w * t).sin(), 0.0),
            q: UnitQuaternion::from_euler_angles(roll, pitch, yaw),
            v: Vector3::new(-r * w * (w * t).sin(), r * w * (w * t).cos(), 0.0),
        }
    }

    fn body_rate(&self, t: f64) -> Vector3<f64> {
        let ([roll, pitch, _], [droll, dpitch, dyaw]) = self.euler(t);
        Vector3::new(
            droll - dyaw * pitch.sin(),
            dpitch * roll.cos() + dyaw * pitch.cos() * roll.sin(),
            -dpitch * roll.sin() + dyaw * pitch.cos() * roll.cos(),
        )
    }

    fn accel_ned(&self, t: f64) -> Vector3<f64> {
        let (r, w) = (self.radius, self.omega);
        -Vector3::new((w * t).cos(), (w * t).sin(), 0.0) * r * w * w
    }
}

/// At rest at the origin with a fixed attitude.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Stationary {
    pub q: UnitQuaternion<f64>,
}

impl Trajectory for Stationary {
    fn truth(&self, t: f64) -> TruthSample {
        TruthSample {
            t,
            p: Vector3::zeros(),
            q: self.q,
            v: Vector3::zeros(),
        }
    }
    fn body_rate(&self, _t: f64) -> Vector3<f64> {
        Vector3::zeros()
    }
    fn accel_ned(&self, _t: f64) -> Vector3<f64> {
        Vector3::zeros()
    }
}

/// Constant velocity with a constant body rate (spinning while drifting).
#[derive(Debug, Clone, Copy)]
pub(crate) struct ConstantRotation {
    pub q0: UnitQuaternion<f64>,
    pub rate: Vector3<f64>,
    pub velocity: Vector3<f64>,
}

impl Trajectory for ConstantRotation {
    fn truth(&self, t: f64) -> TruthSample {
        TruthSample {
            t,
            p: self.velocity * t,
            q: self.q0 * UnitQuaternion::from_scaled_axis(self.rate * t),
            v: self.velocity,
        }
    }
    fn body_rate(&self, _t: f64) -> Vector3<f64> {
        self.rate
    }
    fn accel_ned(&self, _t: f64) -> Vector3<f64> {
        Vector3::zeros()
    }
}

/// Sensor errors added to noise-free `Rate` samples.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ImuErrors {
    pub gyro_bias: Vector3<f64>,
    pub accel_bias: Vector3<f64>,
    pub gyro_noise_density: f64,
    pub accel_noise_density: f64,
}

impl ImuErrors {
    pub(crate) fn corrupt(&self, samples: &mut [ImuSample], rate_hz: f64, rng: &mut ChaCha8Rng) {
        let mut white = |density: f64| -> Vector3<f64> {
            Vector3::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal)) * density * rate_hz.sqrt()
        };
        for sample in samples {
            if let ImuSample::Rate { gyro, accel, .. } = sample {
                *gyro += self.gyro_bias + white(self.gyro_noise_density);
                *accel += self.accel_bias + white(self.accel_noise_density);
            }
        }
    }
}
