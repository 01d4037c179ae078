//! The IMU's white noise as its own samples show it, so that the filter's process noise holds
//! when the unit is noisier than its configured densities: another unit of the type, a worse
//! grade, or a frame that shakes it. Between epochs the filter lives on its propagation, and
//! a tilt it believes to a tenth of a milliradian puts no room in the velocity for the
//! gravity a noisier gyro leaks into it. With the simulated IMU three times noisier than the
//! configuration said, the open room's cross-track NEES was 19.7 and the flight started in
//! motion had a fifth of its usable messages outside 3 sigma (docs/accuracy.md, "Noisier
//! sensors than configured"). The configuration stays the floor.
//!
//! A sample's rate of turn and specific force are the motion plus white noise of variance
//! `density^2 / dt`. The motion is smooth at hundreds of hertz, so the second difference of
//! three consecutive samples leaves the noise alone, with six times its variance. The median
//! of a second of squared differences (all axes) over that of a chi-square with one degree of
//! freedom is robust to the jolts of a landing or a bump, which a mean would take for noise.
//! Vibration that the samples resolve counts as noise: on a frame that shakes the unit the
//! measured density grows, and the velocity sigmas with it (docs/raspberry-pi.md, "Mounting
//! the IMU").

use crate::sensors::ImuSample;
use nalgebra::Vector3;

/// Samples per measurement (a second at 400 Hz).
const WINDOW_SAMPLES: usize = 400;
/// Median of a chi-square variable with one degree of freedom.
const CHI_SQUARE_1_MEDIAN: f64 = 0.454_936;
/// Variance of the second difference of white noise, in units of the noise's own variance.
const SECOND_DIFFERENCE_GAIN: f64 = 6.0;

/// White-noise densities: gyro, rad/s/sqrt(Hz); accelerometer, m/s^2/sqrt(Hz).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct WhiteNoise {
    pub gyro_density: f64,
    pub accel_density: f64,
}

/// Measures the IMU's white noise over consecutive windows of samples.
#[derive(Debug, Clone, Default)]
pub(crate) struct ImuNoiseMeter {
    /// The two latest samples' rate of turn and specific force.
    recent: Vec<(Vector3<f64>, Vector3<f64>)>,
    gyro_squares: Vec<f64>,
    accel_squares: Vec<f64>,
    interval_sum: f64,
}

impl ImuNoiseMeter {
    /// Takes one sample that came `interval` seconds after the previous one; returns the
    /// densities measured when it completes a window.
    pub(crate) fn observe(&mut self, sample: &ImuSample, interval: f64) -> Option<WhiteNoise> {
        let (rate, force) = rate_and_force(sample, interval)?;
        if self.recent.len() == 2 {
            let [(rate_1, force_1), (rate_2, force_2)] = [self.recent[0], self.recent[1]];
            self.recent.remove(0);
            let gyro = rate - 2.0 * rate_2 + rate_1;
            let accel = force - 2.0 * force_2 + force_1;
            self.gyro_squares.extend(gyro.iter().map(|d| d * d));
            self.accel_squares.extend(accel.iter().map(|d| d * d));
            self.interval_sum += interval;
        }
        self.recent.push((rate, force));
        (self.gyro_squares.len() >= 3 * WINDOW_SAMPLES).then(|| self.complete_window())
    }

    /// Forgets the latest samples: after a gap they are no neighbours of the next one.
    pub(crate) fn restart(&mut self) {
        self.recent.clear();
    }

    fn complete_window(&mut self) -> WhiteNoise {
        let mean_interval = self.interval_sum / WINDOW_SAMPLES as f64;
        let density = |squares: &mut Vec<f64>| {
            let middle = squares.len() / 2;
            let (_, median, _) = squares.select_nth_unstable_by(middle, f64::total_cmp);
            let variance = *median / CHI_SQUARE_1_MEDIAN / SECOND_DIFFERENCE_GAIN;
            squares.clear();
            (variance * mean_interval).sqrt()
        };
        let measured = WhiteNoise {
            gyro_density: density(&mut self.gyro_squares),
            accel_density: density(&mut self.accel_squares),
        };
        self.interval_sum = 0.0;
        measured
    }
}

/// A sample's mean rate of turn (rad/s) and specific force (m/s^2) over its interval.
fn rate_and_force(sample: &ImuSample, interval: f64) -> Option<(Vector3<f64>, Vector3<f64>)> {
    if interval.is_nan() || interval <= 0.0 {
        return None;
    }
    match sample {
        ImuSample::Rate { gyro, accel, .. } => Some((*gyro, *accel)),
        ImuSample::Delta { dt, dq, dv, .. } => Some((dq.scaled_axis() / *dt, dv / *dt)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    const DT: f64 = 0.0025;

    /// A window of increments of a turning, accelerating body with white noise of the given
    /// densities, as an Xsens sends them.
    fn measured(gyro_density: f64, accel_density: f64) -> WhiteNoise {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut noise = |density: f64| -> Vector3<f64> {
            Vector3::from_fn(|_, _| density / DT.sqrt() * rng.sample::<f64, _>(StandardNormal))
        };
        let mut meter = ImuNoiseMeter::default();
        (1..=WINDOW_SAMPLES + 2)
            .find_map(|k| {
                let t = k as f64 * DT;
                let rate = Vector3::new(0.3 * t.sin(), 0.5, -0.2 * (2.0 * t).cos());
                let force = Vector3::new(1.5 * (3.0 * t).sin(), 0.2, -9.81);
                let sample = ImuSample::Delta {
                    t,
                    dt: DT,
                    dq: UnitQuaternion::from_scaled_axis((rate + noise(gyro_density)) * DT),
                    dv: (force + noise(accel_density)) * DT,
                };
                meter.observe(&sample, DT)
            })
            .expect("a window completes")
    }

    #[test]
    fn the_samples_show_the_noise_the_unit_has_while_it_moves() {
        for scale in [1.0, 3.0] {
            let (gyro, accel) = (1.745e-4 * scale, 5.88e-4 * scale);
            let white = measured(gyro, accel);
            assert!(
                (white.gyro_density / gyro - 1.0).abs() < 0.15,
                "gyro {gyro} measured {white:?}"
            );
            assert!(
                (white.accel_density / accel - 1.0).abs() < 0.15,
                "accel {accel} measured {white:?}"
            );
        }
    }

    #[test]
    fn a_gap_starts_the_differences_again() {
        let mut meter = ImuNoiseMeter::default();
        let still = |t: f64| ImuSample::Rate {
            t,
            gyro: Vector3::zeros(),
            accel: Vector3::new(0.0, 0.0, -9.81),
        };
        meter.observe(&still(0.0), DT);
        meter.observe(&still(DT), DT);
        meter.restart();
        assert!(meter.observe(&still(1.0), DT).is_none());
        assert!(
            meter.gyro_squares.is_empty(),
            "no difference across the gap"
        );
    }
}
