//! The replay's comparison of estimates with a simulated recording's `/truth`, in the figures
//! the lab's `evaluate` reports on the same scenario: per-axis NED velocity and roll/pitch/yaw
//! errors, after the filter's stationary start (alignment is not accuracy), and how far the
//! position drifted from the truth's since then (what `trajectory.tum` shows).

use super::mavlink_out::QualityPolicy;
use crate::estimate::Estimate;
use crate::sensors::TruthSample;
use nalgebra::{UnitQuaternion, Vector3};

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
    /// The position's travel since the first estimate compared, less the truth's (NED, m):
    /// its RMS over the estimates and its value at the last.
    pub position_drift_rms_m: [f64; 3],
    pub position_drift_end_m: [f64; 3],
    /// How far the truth travelled meanwhile, m.
    pub distance_travelled_m: f64,
}

/// Errors of the `estimates` from `from_s` on, each against the truth sample nearest in time.
pub(crate) fn truth_errors(
    estimates: &[Estimate],
    truth: &[TruthSample],
    from_s: f64,
) -> Option<TruthErrors> {
    let mut errors = ErrorSeries::default();
    for estimate in estimates.iter().filter(|e| e.t >= from_s) {
        let nearest = nearest(truth, estimate.t)?;
        errors.push(
            &estimate.velocity,
            &estimate.attitude,
            &estimate.position,
            nearest,
        );
    }
    if errors.is_empty() {
        return None;
    }
    Some(TruthErrors {
        position_drift_rms_m: errors.drift_rms(),
        position_drift_end_m: errors.drift_end(),
        distance_travelled_m: errors.travelled_m(),
        samples: errors.len(),
        from_s,
        velocity_std_ned: errors.velocity_std(),
        velocity_rms_ned: errors.velocity_rms(),
        attitude_std_mrad: errors.attitude_std_mrad(),
        attitude_rms_mrad: errors.attitude_rms_mrad(),
    })
}

/// What the autopilot was told, judged against `/truth`: the body-frame velocity and its
/// covariance as ODOMETRY carries them, for the estimates whose quality says "use me". Body
/// axes do not depend on where the filter put its origin and north, so this holds for a replay
/// started anywhere in a recording.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AutopilotView {
    pub estimates: usize,
    /// Estimates with quality >= 1.
    pub valid: usize,
    /// Seconds from the first estimate to the first valid one.
    pub first_valid_after_s: Option<f64>,
    /// Per body axis: the share of valid estimates whose error is within 3 reported sigmas.
    pub inside_3_sigma: [f64; 3],
    /// Per body axis: the mean squared error over the reported variance (1 when honest).
    pub mean_nees: [f64; 3],
    /// Largest body-velocity error of a valid estimate, m/s.
    pub worst_valid_error_mps: f64,
    /// Times `reset_counter` moved.
    pub resets: usize,
}

/// The autopilot's view of `estimates` (in time order), with `policy`'s quality.
pub(crate) fn autopilot_view(
    estimates: &[Estimate],
    truth: &[TruthSample],
    policy: &QualityPolicy,
) -> Option<AutopilotView> {
    let first = estimates.first()?;
    let mut view = AutopilotView {
        estimates: estimates.len(),
        valid: 0,
        first_valid_after_s: None,
        inside_3_sigma: [0.0; 3],
        mean_nees: [0.0; 3],
        worst_valid_error_mps: 0.0,
        resets: estimates
            .windows(2)
            .filter(|pair| pair[0].reset_counter != pair[1].reset_counter)
            .count(),
    };
    for estimate in estimates.iter().filter(|e| policy.quality(e) >= 1) {
        let truth = nearest(truth, estimate.t)?;
        let error = estimate.body_velocity() - truth.q.inverse_transform_vector(&truth.v);
        let variance = estimate.body_velocity_covariance().diagonal();
        view.first_valid_after_s.get_or_insert(estimate.t - first.t);
        view.valid += 1;
        view.worst_valid_error_mps = view.worst_valid_error_mps.max(error.amax());
        for axis in 0..3 {
            let squared = error[axis] * error[axis] / variance[axis];
            view.inside_3_sigma[axis] += f64::from(u8::from(squared <= 9.0));
            view.mean_nees[axis] += squared;
        }
    }
    let valid = view.valid.max(1) as f64;
    view.inside_3_sigma = view.inside_3_sigma.map(|n| n / valid);
    view.mean_nees = view.mean_nees.map(|n| n / valid);
    Some(view)
}

fn nearest(truth: &[TruthSample], t: f64) -> Option<&TruthSample> {
    nearest_in_time(truth, t, |sample| sample.t)
}

/// The item of a time-ordered slice whose time is nearest `t`.
pub(crate) fn nearest_in_time<T>(items: &[T], t: f64, time: impl Fn(&T) -> f64) -> Option<&T> {
    let after = items.partition_point(|item| time(item) < t);
    [after.checked_sub(1), Some(after)]
        .into_iter()
        .flatten()
        .filter_map(|i| items.get(i))
        .min_by(|a, b| (time(a) - t).abs().total_cmp(&(time(b) - t).abs()))
}

/// Velocity (NED, m/s) and roll/pitch/yaw (Euler angle, mrad) errors against truth, per axis,
/// the position's drift (its travel since the first sample less the truth's, m) and the
/// distance the truth travelled: the figures both the replay summary and the lab's scenario
/// evaluation report.
#[derive(Debug, Default, Clone)]
pub struct ErrorSeries {
    velocity: Vec<Vector3<f64>>,
    attitude: Vec<Vector3<f64>>,
    drift: Vec<Vector3<f64>>,
    /// The estimate's and the truth's positions at the first sample.
    first_positions: Option<(Vector3<f64>, Vector3<f64>)>,
    last_truth_position: Option<Vector3<f64>>,
    travelled_m: f64,
}

impl ErrorSeries {
    pub fn push(
        &mut self,
        velocity: &Vector3<f64>,
        attitude: &UnitQuaternion<f64>,
        position: &Vector3<f64>,
        truth: &TruthSample,
    ) {
        self.velocity.push(velocity - truth.v);
        let (r, p, y) = attitude.euler_angles();
        let (tr, tp, ty) = truth.q.euler_angles();
        self.attitude
            .push(Vector3::new(wrap(r - tr), wrap(p - tp), wrap(y - ty)) * 1e3);
        let (position_0, truth_0) = *self.first_positions.get_or_insert((*position, truth.p));
        self.drift
            .push((position - position_0) - (truth.p - truth_0));
        if let Some(last) = self.last_truth_position.replace(truth.p) {
            self.travelled_m += (truth.p - last).norm();
        }
    }

    pub fn drift_rms(&self) -> [f64; 3] {
        rms(&self.drift)
    }

    pub fn drift_end(&self) -> [f64; 3] {
        self.drift.last().copied().unwrap_or_default().into()
    }

    /// How far the truth travelled from the first sample to the last, m.
    pub fn travelled_m(&self) -> f64 {
        self.travelled_m
    }

    pub(crate) fn len(&self) -> usize {
        self.velocity.len()
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.velocity.is_empty()
    }

    pub fn velocity_std(&self) -> [f64; 3] {
        std_dev(&self.velocity)
    }

    pub fn velocity_rms(&self) -> [f64; 3] {
        rms(&self.velocity)
    }

    pub fn attitude_std_mrad(&self) -> [f64; 3] {
        std_dev(&self.attitude)
    }

    pub fn attitude_rms_mrad(&self) -> [f64; 3] {
        rms(&self.attitude)
    }
}

fn wrap(angle: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    angle - tau * (angle / tau).round()
}

fn mean(values: &[Vector3<f64>]) -> Vector3<f64> {
    values.iter().sum::<Vector3<f64>>() / values.len().max(1) as f64
}

fn std_dev(values: &[Vector3<f64>]) -> [f64; 3] {
    let mean = mean(values);
    let n = values.len().max(2) as f64 - 1.0;
    let sum = values
        .iter()
        .map(|v| (v - mean).component_mul(&(v - mean)))
        .sum::<Vector3<f64>>();
    (sum / n).map(f64::sqrt).into()
}

fn rms(values: &[Vector3<f64>]) -> [f64; 3] {
    let sum = values
        .iter()
        .map(|v| v.component_mul(v))
        .sum::<Vector3<f64>>();
    (sum / values.len().max(1) as f64).map(f64::sqrt).into()
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
            last_reset: None,
            integrity: None,
            since_last_fused: 0.0,
            degraded: false,
            converged: true,
        }
    }

    #[test]
    fn the_autopilot_view_judges_valid_estimates_in_body_axes_against_their_sigmas() {
        let truth: Vec<_> = (0..100).map(|k| truth(k as f64 * 0.1)).collect();
        let mut estimates = vec![
            estimate(0.5, 5.0, 0.0),
            estimate(2.0, 1.1, 0.0),
            estimate(3.0, 4.0, 0.0),
        ];
        for estimate in &mut estimates {
            estimate.integrity = Some(crate::estimate::IntegrityStatus::Ok);
            estimate.velocity_covariance = Matrix3::identity() * 0.16;
            // The attitude exact, so that the body velocity's sigma is the velocity's own
            // (a radian of doubt at 4 m/s would make every estimate unusable).
            estimate.attitude_covariance = Matrix3::zeros();
        }
        estimates[0].converged = false;
        estimates[2].reset_counter = 1;
        let view = autopilot_view(&estimates, &truth, &QualityPolicy::default()).unwrap();
        assert_eq!((view.estimates, view.valid, view.resets), (3, 2, 1));
        assert_eq!(view.first_valid_after_s, Some(1.5));
        // Errors 0.1 and 3 m/s against a sigma of 0.4: one inside, NEES (0.0625 + 56.25) / 2.
        assert_eq!(view.inside_3_sigma[0], 0.5);
        assert!((view.mean_nees[0] - 28.15625).abs() < 1e-9);
        assert!((view.worst_valid_error_mps - 3.0).abs() < 1e-9);
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

    #[test]
    fn drift_is_the_travel_since_the_first_sample_less_the_truths() {
        // The truth walks 1 m/s along x; the estimate starts 5 m off (an origin is not
        // drift) and walks 1.1 m/s.
        let walking = |t: f64| TruthSample {
            p: Vector3::new(t, 0.0, 0.0),
            ..truth(t)
        };
        let truth: Vec<_> = (0..=100).map(|k| walking(k as f64 * 0.1)).collect();
        let estimates: Vec<_> = [2.0, 4.0, 6.0]
            .map(|t| Estimate {
                position: Vector3::new(5.0 + 1.1 * t, 0.0, 0.0),
                ..estimate(t, 1.1, 0.0)
            })
            .to_vec();
        let errors = truth_errors(&estimates, &truth, 1.0).unwrap();
        assert!((errors.position_drift_end_m[0] - 0.4).abs() < 1e-9);
        let rms = ((0.0 + 0.04 + 0.16) / 3.0f64).sqrt();
        assert!((errors.position_drift_rms_m[0] - rms).abs() < 1e-9);
        assert!((errors.distance_travelled_m - 4.0).abs() < 1e-9);
        assert!(truth_errors(&estimates, &[], 0.0).is_none());
    }
}
