//! What the daemon says of itself besides MAVLink: the systemd status line (`systemctl status`)
//! and a WARN in the log whenever the estimate restarts or a sensor stalls, so that the
//! operator sees what the autopilot is told. Decided from the estimates and the pipeline's
//! staleness alone, on the chunks' times.

use crate::estimate::Estimate;
use crate::filter::ResetReason;

use super::mavlink_out::QualityPolicy;

/// A restart stays in the status line this long, s.
const RESTART_SHOWN_S: f64 = 30.0;

pub(crate) struct Health {
    /// Sensor names in pipeline order.
    names: Vec<String>,
    policy: QualityPolicy,
    line: String,
    reset_counter: Option<u8>,
    last_restart: Option<(f64, ResetReason)>,
    stale: Vec<bool>,
}

impl Health {
    pub(crate) fn new(names: Vec<String>) -> Self {
        Self {
            stale: vec![false; names.len()],
            names,
            policy: QualityPolicy::default(),
            line: String::new(),
            reset_counter: None,
            last_restart: None,
        }
    }

    /// Takes the newest estimate (if the chunk produced one) and each sensor's staleness at
    /// `now_s`; returns the status line when it changed.
    pub(crate) fn observe(
        &mut self,
        estimate: Option<&Estimate>,
        stale: &[bool],
        now_s: f64,
    ) -> Option<String> {
        self.log_stalls(stale);
        if let Some(estimate) = estimate {
            self.log_reset(estimate, now_s);
        }
        let line = self.line(estimate, now_s)?;
        (line != self.line).then(|| {
            self.line.clone_from(&line);
            line
        })
    }

    fn log_stalls(&mut self, stale: &[bool]) {
        for ((name, was), &is) in self.names.iter().zip(&mut self.stale).zip(stale) {
            match (*was, is) {
                (false, true) => tracing::warn!(
                    sensor = %name,
                    "sensor stalled: no bytes for a second or its link dropped; the estimate is not to be used until it is back"
                ),
                (true, false) => tracing::info!(sensor = %name, "sensor streaming again"),
                _ => {}
            }
            *was = is;
        }
    }

    fn log_reset(&mut self, estimate: &Estimate, now_s: f64) {
        let previous = self.reset_counter.replace(estimate.reset_counter);
        if previous.is_none_or(|counter| counter == estimate.reset_counter) {
            return;
        }
        match estimate.last_reset {
            Some(reason @ ResetReason::PositionStep { .. }) => {
                tracing::info!(reset_counter = estimate.reset_counter, "{reason}")
            }
            Some(reason) => {
                tracing::warn!(reset_counter = estimate.reset_counter, "{reason}");
                self.last_restart = Some((now_s, reason));
            }
            None => {}
        }
    }

    /// `None` until the first estimate: the start-up's own status stands until then.
    fn line(&self, estimate: Option<&Estimate>, now_s: f64) -> Option<String> {
        let stale: Vec<&str> = self
            .names
            .iter()
            .zip(&self.stale)
            .filter(|(_, &stale)| stale)
            .map(|(name, _)| name.as_str())
            .collect();
        let mut line = match estimate.map(|e| (e, self.policy.quality(e))) {
            None if stale.is_empty() => return None,
            None => "no estimate".to_string(),
            Some((e, quality)) if quality < 0 => format!("not usable (quality -1){}", why_not(e)),
            Some((_, 0)) => "not trusted yet (quality 0): converging or an axis unobserved".into(),
            Some(_) => "tracking".to_string(),
        };
        if !stale.is_empty() {
            line += &format!("; stalled: {}", stale.join(", "));
        }
        if let Some((at, reason)) = self.last_restart {
            if now_s - at <= RESTART_SHOWN_S {
                line += &format!("; restarted {:.0} s ago: {reason}", now_s - at);
            }
        }
        Some(line)
    }
}

fn why_not(estimate: &Estimate) -> &'static str {
    if estimate.degraded {
        ": a sensor is stale or the IMU had a gap"
    } else {
        ": no odometry fused for over a second"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::IntegrityStatus;
    use nalgebra::{Matrix3, UnitQuaternion, Vector3};

    fn estimate() -> Estimate {
        Estimate {
            t: 1.0,
            position: Vector3::zeros(),
            velocity: Vector3::zeros(),
            attitude: UnitQuaternion::identity(),
            angular_rate: Vector3::zeros(),
            position_covariance: Matrix3::identity() * 1e-4,
            velocity_covariance: Matrix3::identity() * 1e-4,
            velocity_attitude_covariance: Matrix3::zeros(),
            attitude_covariance: Matrix3::identity() * 1e-6,
            gyro_bias: Vector3::zeros(),
            accel_bias: Vector3::zeros(),
            reset_counter: 0,
            last_reset: None,
            integrity: Some(IntegrityStatus::Ok),
            since_last_fused: 0.0,
            degraded: false,
            converged: true,
        }
    }

    #[test]
    fn the_status_line_names_a_stalled_sensor_and_a_restart_and_changes_only_when_they_do() {
        let mut health = Health::new(vec!["front".into(), "imu".into()]);
        let mut e = estimate();
        assert_eq!(health.observe(None, &[false, false], 0.5), None);
        assert_eq!(
            health.observe(Some(&e), &[false, false], 1.0).as_deref(),
            Some("tracking")
        );
        assert_eq!(health.observe(Some(&e), &[false, false], 1.1), None);
        e.degraded = true;
        let line = health.observe(Some(&e), &[true, false], 2.0).unwrap();
        assert!(line.starts_with("not usable (quality -1)"), "{line}");
        assert!(line.ends_with("stalled: front"), "{line}");
        e.degraded = false;
        e.reset_counter = 1;
        e.converged = false;
        e.last_reset = Some(ResetReason::ImuGap { seconds: 3.0 });
        let line = health.observe(Some(&e), &[false, false], 3.0).unwrap();
        assert!(line.starts_with("not trusted yet (quality 0)"), "{line}");
        assert!(
            line.contains("restarted 0 s ago: no IMU data for 3.0 s"),
            "{line}"
        );
        e.converged = true;
        let later = health.observe(Some(&e), &[false, false], 40.0).unwrap();
        assert_eq!(later, "tracking", "a restart is shown for a while only");
    }
}
