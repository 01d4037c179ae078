//! The replay's comparison of estimates with a simulated recording's `/truth`, in the figures
//! `fusion::evaluate` reports on the same scenario: per-axis NED velocity and roll/pitch/yaw
//! errors, after the filter's stationary start (alignment is not accuracy).

use crate::estimate::Estimate;
use crate::fusion::evaluate::ErrorSeries;
use crate::sensors::TruthSample;

/// Velocity and attitude errors of the estimates against `/truth`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthErrors {
    /// Estimates compared: those from `from_s` on.
    pub samples: usize,
    pub from_s: f64,
    pub velocity_std_ned: [f64; 3],
    pub velocity_rms_ned: [f64; 3],
    /// Roll, pitch and yaw (Euler angle) errors, mrad.
    pub attitude_std_mrad: [f64; 3],
    pub attitude_rms_mrad: [f64; 3],
}

/// Errors of the `estimates` from `from_s` on, each against the truth sample nearest in time.
pub fn truth_errors(
    estimates: &[Estimate],
    truth: &[TruthSample],
    from_s: f64,
) -> Option<TruthErrors> {
    let mut errors = ErrorSeries::default();
    for estimate in estimates.iter().filter(|e| e.t >= from_s) {
        let nearest = nearest(truth, estimate.t)?;
        errors.push(&estimate.velocity, &estimate.attitude, nearest);
    }
    if errors.is_empty() {
        return None;
    }
    Some(TruthErrors {
        samples: errors.len(),
        from_s,
        velocity_std_ned: errors.velocity_std(),
        velocity_rms_ned: errors.velocity_rms(),
        attitude_std_mrad: errors.attitude_std_mrad(),
        attitude_rms_mrad: errors.attitude_rms_mrad(),
    })
}

fn nearest(truth: &[TruthSample], t: f64) -> Option<&TruthSample> {
    let after = truth.partition_point(|s| s.t < t);
    [after.checked_sub(1), Some(after)]
        .into_iter()
        .flatten()
        .filter_map(|i| truth.get(i))
        .min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, UnitQuaternion, Vector3};

    fn truth(t: f64) -> TruthSample {
        TruthSample {
            t,
            p: Vector3::zeros(),
            q: UnitQuaternion::identity(),
            v: Vector3::new(1.0, 0.0, 0.0),
        }
    }

    fn estimate(t: f64, vx: f64, roll: f64) -> Estimate {
        Estimate {
            t,
            position: Vector3::zeros(),
            velocity: Vector3::new(vx, 0.0, 0.0),
            attitude: UnitQuaternion::from_euler_angles(roll, 0.0, 0.0),
            angular_rate: Vector3::zeros(),
            position_covariance: Matrix3::identity(),
            velocity_covariance: Matrix3::identity(),
            velocity_attitude_covariance: Matrix3::zeros(),
            attitude_covariance: Matrix3::identity(),
            gyro_bias: Vector3::zeros(),
            accel_bias: Vector3::zeros(),
            reset_counter: 0,
            integrity: None,
            since_last_fused: 0.0,
            degraded: false,
            converged: true,
        }
    }

    #[test]
    fn errors_skip_the_stationary_start_and_split_bias_from_spread() {
        let truth: Vec<_> = (0..100).map(|k| truth(k as f64 * 0.1)).collect();
        let estimates = [
            estimate(0.5, 5.0, 0.5),
            estimate(2.0, 1.1, 0.001),
            estimate(3.0, 1.3, 0.003),
        ];
        let errors = truth_errors(&estimates, &truth, 1.0).unwrap();
        assert_eq!(errors.samples, 2);
        assert!((errors.velocity_std_ned[0] - 0.2f64.hypot(0.0) / 2f64.sqrt()).abs() < 1e-9);
        assert!((errors.velocity_rms_ned[0] - ((0.01 + 0.09) / 2.0f64).sqrt()).abs() < 1e-9);
        assert!((errors.attitude_rms_mrad[0] - ((1.0 + 9.0) / 2.0f64).sqrt()).abs() < 1e-6);
        assert!(truth_errors(&estimates, &truth, 10.0).is_none());
        assert!(truth_errors(&estimates, &[], 0.0).is_none());
    }
}
