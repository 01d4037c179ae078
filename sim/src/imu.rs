//! Simulated strapdown IMU (MTi-G-7x0 class by default). The truth signals come from the analytic
//! trajectory; increments (DeltaQ/DeltaV) are exact, not integrated, so they carry every coning
//! and sculling term.

use super::trajectory::{euler_to_quaternion, Trajectory};
use super::GRAVITY;
use ladar_sensors::ImuSample;
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

const DEG: f64 = std::f64::consts::PI / 180.0;
/// 1 ug in m/s^2, written out so the scenario files show round numbers.
const MICRO_G: f64 = 9.80665e-6;

/// Error model of one triad. Units: gyro rad/s, accelerometer m/s^2.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriadErrors {
    /// White noise density, unit/sqrt(Hz) (gyro: angle random walk).
    pub noise_density: f64,
    /// Bias random walk, unit/sqrt(s): the bias drifts by this times sqrt(elapsed seconds).
    pub bias_random_walk: f64,
    /// Constant bias from switch-on, unit.
    pub turn_on_bias: [f64; 3],
    /// Scale-factor error per axis (0.001 = 1000 ppm).
    pub scale_factor: [f64; 3],
}

impl TriadErrors {
    pub const NONE: Self = Self {
        noise_density: 0.0,
        bias_random_walk: 0.0,
        turn_on_bias: [0.0; 3],
        scale_factor: [0.0; 3],
    };

    /// docs/protocols.md, 2.5 "Noise figures": 0.01 deg/s/sqrt(Hz); the 10 deg/h in-run bias is
    /// reached after 100 s of random walk; turn-on bias and scale factor of a calibrated MEMS unit.
    pub fn mti_gyro() -> Self {
        Self {
            noise_density: 0.01 * DEG,
            bias_random_walk: 10.0 * DEG / 3600.0 / 10.0,
            turn_on_bias: [0.05 * DEG, -0.03 * DEG, 0.04 * DEG],
            scale_factor: [500e-6, -300e-6, 200e-6],
        }
    }

    /// docs/protocols.md, 2.5 "Noise figures": 60 ug/sqrt(Hz); the 15 ug in-run bias is reached
    /// after 100 s.
    pub fn mti_accel() -> Self {
        Self {
            noise_density: 60.0 * MICRO_G,
            bias_random_walk: 1.5 * MICRO_G,
            turn_on_bias: [0.02, -0.015, 0.01],
            scale_factor: [300e-6, -200e-6, 100e-6],
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ImuOutput {
    /// Rate of turn and acceleration at each sample time.
    Rate,
    /// DeltaQ and DeltaV over each sample interval.
    Delta,
}

/// IMU configuration. The IMU sits at the body origin (no lever arm); `mount_rpy_deg` rotates the
/// IMU frame into body FRD like a scanner mount. Samples are at `k / rate_hz`, k >= 1.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuConfig {
    pub rate_hz: f64,
    pub output: ImuOutput,
    #[serde(default)]
    pub mount_rpy_deg: [f64; 3],
    pub gyro: TriadErrors,
    pub accel: TriadErrors,
}

impl Default for ImuConfig {
    fn default() -> Self {
        Self {
            rate_hz: 400.0,
            output: ImuOutput::Delta,
            mount_rpy_deg: [0.0; 3],
            gyro: TriadErrors::mti_gyro(),
            accel: TriadErrors::mti_accel(),
        }
    }
}

/// One-sigma spread of the errors an IMU of a type may switch on with, per axis: what a
/// Monte Carlo study draws so that each run flies a different unit, as a filter's priors claim.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSpread {
    /// Gyro turn-on bias, rad/s.
    pub gyro_bias: f64,
    /// Accelerometer turn-on bias, m/s^2.
    pub accel_bias: f64,
    /// Gyro scale-factor error (0.001 = 1000 ppm).
    pub gyro_scale_factor: f64,
    /// Accelerometer scale-factor error.
    pub accel_scale_factor: f64,
}

impl ImuConfig {
    /// The same IMU with its turn-on biases and scale factors drawn from `spread` (zero-mean
    /// normal, independent per axis), seeded by `seed`.
    pub fn with_drawn_errors(mut self, spread: &ImuSpread, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut draw = |sigma: f64| -> [f64; 3] {
            std::array::from_fn(|_| {
                let z: f64 = StandardNormal.sample(&mut rng);
                sigma * z
            })
        };
        self.gyro.turn_on_bias = draw(spread.gyro_bias);
        self.accel.turn_on_bias = draw(spread.accel_bias);
        self.gyro.scale_factor = draw(spread.gyro_scale_factor);
        self.accel.scale_factor = draw(spread.accel_scale_factor);
        self
    }

    pub fn period(&self) -> f64 {
        1.0 / self.rate_hz
    }

    /// IMU frame -> body.
    pub fn mount_rotation(&self) -> UnitQuaternion<f64> {
        let [r, p, y] = self.mount_rpy_deg.map(f64::to_radians);
        euler_to_quaternion(r, p, y)
    }

    pub fn problem(&self) -> Option<String> {
        let triads = [self.gyro, self.accel];
        if !(self.rate_hz > 0.0 && self.rate_hz.is_finite()) {
            Some("imu: rate_hz must be positive".into())
        } else if triads
            .iter()
            .any(|e| !(e.noise_density >= 0.0 && e.bias_random_walk >= 0.0))
        {
            Some("imu: noise_density and bias_random_walk must be zero or positive".into())
        } else {
            None
        }
    }
}

/// Stateful IMU: owns the drifting biases, so samples must be drawn in time order.
#[derive(Debug, Clone)]
pub(crate) struct ImuGenerator {
    config: ImuConfig,
    mount: UnitQuaternion<f64>,
    gyro_drift: Vector3<f64>,
    accel_drift: Vector3<f64>,
}

impl ImuGenerator {
    pub(crate) fn new(config: &ImuConfig) -> Self {
        Self {
            config: config.clone(),
            mount: config.mount_rotation(),
            gyro_drift: Vector3::zeros(),
            accel_drift: Vector3::zeros(),
        }
    }

    /// Sample number `k` (time `k / rate_hz`).
    pub(crate) fn sample(
        &mut self,
        k: u64,
        trajectory: &Trajectory,
        rng: &mut ChaCha8Rng,
    ) -> ImuSample {
        let dt = self.config.period();
        let t = k as f64 * dt;
        self.gyro_drift += gaussian3(rng) * (self.config.gyro.bias_random_walk * dt.sqrt());
        self.accel_drift += gaussian3(rng) * (self.config.accel.bias_random_walk * dt.sqrt());
        let gyro_bias = Vector3::from(self.config.gyro.turn_on_bias) + self.gyro_drift;
        let accel_bias = Vector3::from(self.config.accel.turn_on_bias) + self.accel_drift;
        match self.config.output {
            ImuOutput::Rate => {
                let truth = trajectory.kinematics(t);
                let white = 1.0 / dt.sqrt();
                ImuSample::Rate {
                    t,
                    gyro: corrupt(
                        self.mount.inverse_transform_vector(&truth.omega_body),
                        &self.config.gyro,
                        gyro_bias,
                        self.config.gyro.noise_density * white,
                        rng,
                    ),
                    accel: corrupt(
                        self.mount
                            .inverse_transform_vector(&truth.specific_force_body),
                        &self.config.accel,
                        accel_bias,
                        self.config.accel.noise_density * white,
                        rng,
                    ),
                }
            }
            ImuOutput::Delta => {
                let (dq, dv) = self.true_increments(trajectory, t - dt, t);
                let integrated = dt.sqrt();
                let angle = corrupt(
                    dq.scaled_axis(),
                    &self.config.gyro,
                    gyro_bias * dt,
                    self.config.gyro.noise_density * integrated,
                    rng,
                );
                ImuSample::Delta {
                    t,
                    dt,
                    dq: UnitQuaternion::from_scaled_axis(angle),
                    dv: corrupt(
                        dv,
                        &self.config.accel,
                        accel_bias * dt,
                        self.config.accel.noise_density * integrated,
                        rng,
                    ),
                }
            }
        }
    }

    /// Exact increments in the IMU frame over `(t0, t1]`: `dq = q(t0)^-1 q(t1)` and `dv` such that
    /// `v(t1) = v(t0) + C(t0) dv + g (t1 - t0)`, i.e. the specific force integrated in the IMU
    /// frame frozen at `t0` (what a strapdown integrator with perfect coning/sculling gives).
    pub(crate) fn true_increments(
        &self,
        trajectory: &Trajectory,
        t0: f64,
        t1: f64,
    ) -> (UnitQuaternion<f64>, Vector3<f64>) {
        let (before, after) = (trajectory.kinematics(t0), trajectory.kinematics(t1));
        let q0 = before.q * self.mount;
        let q1 = after.q * self.mount;
        let gravity = Vector3::new(0.0, 0.0, GRAVITY);
        let dv = q0.inverse_transform_vector(&(after.v - before.v - gravity * (t1 - t0)));
        (q0.inverse() * q1, dv)
    }
}

fn gaussian3(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    Vector3::from_fn(|_, _| StandardNormal.sample(rng))
}

/// `(1 + scale) * truth + bias + sigma * white noise`, per axis. Noise is drawn even when sigma
/// is zero so the random stream does not depend on which errors are switched on.
fn corrupt(
    truth: Vector3<f64>,
    errors: &TriadErrors,
    bias: Vector3<f64>,
    sigma: f64,
    rng: &mut ChaCha8Rng,
) -> Vector3<f64> {
    let scale = Vector3::from(errors.scale_factor).add_scalar(1.0);
    truth.component_mul(&scale) + bias + gaussian3(rng) * sigma
}
