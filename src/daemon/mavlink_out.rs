//! MAVLink messages for the autopilot, built from [`Estimate`]s. Pure: no I/O, no clock; the
//! caller passes `now` and sends what comes back (docs/protocols.md and docs/design.md, "MAVLink").
//!
//! Quality (ODOMETRY `quality`, int8) and confidence (VISION_POSITION_DELTA `confidence`,
//! 0-100 %) come from the same mapping, [`QualityPolicy::quality`]:
//!
//! | situation                                                         | quality            |
//! |-------------------------------------------------------------------|--------------------|
//! | estimate degraded (stale scanner, IMU gap) or covariance not finite | -1 (failed)       |
//! | no odometry epoch fused yet, or none for more than `stale_after_s` | -1 (failed)        |
//! | not converged since the start or a restart                         | 0 (do not use)     |
//! | worst-direction velocity sigma above `unusable_sigma_mps` (unobserved) | 0 (do not use) |
//! | latest epoch `DetectedNotIsolable` or `UnderDetermined`            | `low` (10)         |
//! | latest epoch `Ok`                                                  | 1-100 from sigma_v |
//! | latest epoch `Excluded`                                            | as Ok, capped at `excluded_cap` (75) |
//!
//! "From sigma_v" is `100 * reference_sigma_mps / sigma_v` clamped to 1..=100, where sigma_v is
//! the standard deviation of the body velocity sent along its worst direction. -1 is what both autopilots treat as "do not use":
//! PX4 with `EKF2_EV_QMIN >= 1`, ArduPilot with `VISO_QUAL_MIN >= 0` (its default); quality 0
//! ("not to be used": not converged, or an axis unobserved) needs `VISO_QUAL_MIN = 1`. The
//! confidence of VISION_POSITION_DELTA is the same number with -1 mapped to 0; ArduPilot turns it
//! into `velErr = VERR_MIN + (VERR_MAX - VERR_MIN) (1 - conf/100)`, so with
//! `EK3_VIS_VERR_MAX >= 1` a confidence of 0 keeps EKF3 from starting body-odometry aiding.
//!
//! Without IMU data there is no estimate and so no message: a -1 would carry a frozen velocity,
//! which PX4 at its default `EKF2_EV_QMIN = 0` fuses (docs/autopilot.md, "Sensor outages"); the
//! MAVLink task's HEARTBEAT says CRITICAL instead.

use crate::estimate::{Estimate, IntegrityStatus};
use crate::filter::ResetReason;
use mavlink::dialects::ardupilotmega::{
    self as apm, MavAutopilot, MavEstimatorType, MavFrame, MavMessage, MavModeFlag, MavSeverity,
    MavState, MavType,
};
use mavlink::MavHeader;
use nalgebra::{Matrix3, UnitQuaternion};
use serde::Deserialize;
use std::fmt;
use std::str::FromStr;

/// MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY: the component id autopilots expect from an odometer.
pub(crate) const DEFAULT_COMPONENT_ID: u8 = 197;
pub(crate) const HEARTBEAT_RATE_HZ: f64 = 1.0;

/// Which messages the autopilot gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Profile {
    /// PX4 EKF2: ODOMETRY LOCAL_FRD/BODY_FRD with pose, body velocity and covariances.
    Px4,
    /// ArduPilot EKF3 body-frame odometry: VISION_POSITION_DELTA (VISO_TYPE=1).
    Ardupilot,
    /// ArduPilot external navigation: ODOMETRY LOCAL_FRD/BODY_FRD (VISO_TYPE=3).
    ArdupilotOdometry,
}

impl Profile {
    /// Rates the autopilot fuses well: PX4 drops EV below ~30 Hz; EKF3 drops body odometry
    /// samples closer than 50 ms; AP_VisualOdom needs at least 4 Hz.
    pub(crate) fn rate_range_hz(self) -> (f64, f64) {
        match self {
            Self::Px4 => (30.0, 50.0),
            Self::Ardupilot => (10.0, 20.0),
            Self::ArdupilotOdometry => (4.0, 50.0),
        }
    }

    /// Closest spacing, in estimate time, at which an odometry epoch's message may follow the
    /// previous message, or `None` where epochs wait for the steady rate. PX4's EKF2 drops an
    /// EV sample closer to the previous one than its observation-buffer interval ("EV data too
    /// fast"; the fusion horizon over the buffer length, 7-10 ms with default delays), so 10 ms.
    /// ArduPilot's EKF3 spaces external navigation samples by `extNavIntervalMin_ms` = 20 ms.
    /// A VISION_POSITION_DELTA sent early would cover a shorter interval that still holds the
    /// whole jump of the epoch's correction, which EKF3 turns into a velocity spike of
    /// correction / interval: the delta profile keeps its steady rate, and its next slot
    /// carries the epoch.
    pub(crate) fn epoch_spacing_s(self) -> Option<f64> {
        match self {
            Self::Px4 => Some(0.010),
            Self::ArdupilotOdometry => Some(0.020),
            Self::Ardupilot => None,
        }
    }

    pub(crate) fn default_rate_hz(self) -> f64 {
        match self {
            Self::Px4 => 30.0,
            Self::Ardupilot => 15.0,
            Self::ArdupilotOdometry => 20.0,
        }
    }
}

impl fmt::Display for Profile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Px4 => "px4",
            Self::Ardupilot => "ardupilot",
            Self::ArdupilotOdometry => "ardupilot-odometry",
        })
    }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown MAVLink profile `{0}`: use one of px4, ardupilot, ardupilot-odometry")]
pub struct UnknownProfile(pub String);

impl FromStr for Profile {
    type Err = UnknownProfile;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "px4" => Ok(Self::Px4),
            "ardupilot" => Ok(Self::Ardupilot),
            "ardupilot-odometry" => Ok(Self::ArdupilotOdometry),
            other => Err(UnknownProfile(other.to_string())),
        }
    }
}

/// Who we are on the MAVLink network.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Identity {
    pub system_id: u8,
    pub component_id: u8,
}

impl Identity {
    /// The header to send with; the link fills in the sequence number.
    pub(crate) fn header(&self) -> MavHeader {
        MavHeader {
            system_id: u32::from(self.system_id),
            component_id: self.component_id,
            sequence: 0,
        }
    }
}

/// Thresholds of the quality mapping documented at the top of this module.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QualityPolicy {
    /// Without a fused odometry epoch for this long the estimate is IMU dead-reckoning.
    pub stale_after_s: f64,
    /// Velocity sigma (m/s) that earns quality 100.
    pub reference_sigma_mps: f64,
    /// Velocity sigma (m/s) above which the estimate is not to be used at all: an axis the
    /// surfaces have left unobserved for long. Beyond it the filter's linearisation is no
    /// longer to be trusted either (an unknown velocity of a metre per second turns every
    /// attitude error into a velocity error the covariance describes only to first order), so
    /// even PX4, which weighs each axis by its variance, must not use the message.
    pub unusable_sigma_mps: f64,
    /// Quality while the latest epoch was not fused but an earlier one is recent.
    pub low: i8,
    /// Highest quality while planes are being excluded.
    pub excluded_cap: i8,
}

impl Default for QualityPolicy {
    fn default() -> Self {
        Self {
            stale_after_s: 1.0,
            reference_sigma_mps: 0.05,
            unusable_sigma_mps: 0.5,
            low: 10,
            excluded_cap: 75,
        }
    }
}

impl QualityPolicy {
    /// ODOMETRY quality: -1 failed, 1 worst .. 100 best.
    pub fn quality(&self, estimate: &Estimate) -> i8 {
        let Some(sigma_v) = largest_sigma(&estimate.body_velocity_covariance()) else {
            return -1;
        };
        // Written so that a NaN age also counts as stale.
        let fresh = estimate.since_last_fused <= self.stale_after_s;
        if estimate.degraded || !fresh {
            return -1;
        }
        if !estimate.converged || sigma_v > self.unusable_sigma_mps {
            return 0;
        }
        let from_covariance = (100.0 * self.reference_sigma_mps / sigma_v).clamp(1.0, 100.0) as i8;
        match &estimate.integrity {
            None => -1,
            Some(IntegrityStatus::Ok) => from_covariance,
            Some(IntegrityStatus::Excluded { .. }) => from_covariance.min(self.excluded_cap),
            Some(IntegrityStatus::DetectedNotIsolable | IntegrityStatus::UnderDetermined) => {
                self.low.min(from_covariance)
            }
        }
    }

    /// VISION_POSITION_DELTA confidence in percent: 0 whenever quality says "failed".
    pub(crate) fn confidence(&self, estimate: &Estimate) -> f32 {
        f32::from(self.quality(estimate).max(0))
    }
}

/// The sigma along the covariance's worst direction, not its worst axis: a direction nothing
/// observes, held by the speed prior at 0.53 m/s, lay 45 degrees off both level axes while
/// `hallway-flight` turned, and its axes' sigmas of 0.38 m/s sent a velocity 0.86 m/s off with
/// quality 10. Taken of the body-velocity covariance the autopilot is sent.
fn largest_sigma(covariance: &Matrix3<f64>) -> Option<f64> {
    let sane =
        covariance.iter().all(|v| v.is_finite()) && covariance.diagonal().iter().all(|v| *v >= 0.0);
    sane.then(|| {
        let largest = covariance.symmetric_eigenvalues().max();
        largest.max(0.0).sqrt().max(f64::MIN_POSITIVE)
    })
}

/// HEARTBEAT of an onboard odometer (MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID).
pub(crate) fn heartbeat(system_status: MavState) -> MavMessage {
    MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status,
        mavlink_version: 3,
    })
}

/// What the HEARTBEAT says of the estimate: CALIBRATING before there is one and until it has
/// converged after the start or a restart (quality 0), CRITICAL while it is failed (quality -1:
/// a stale sensor, no odometry fused for too long), ACTIVE while it may be used.
pub(crate) fn system_state(estimate: Option<&Estimate>, policy: &QualityPolicy) -> MavState {
    match estimate.map(|e| policy.quality(e)) {
        None | Some(0) => MavState::MAV_STATE_CALIBRATING,
        Some(quality) if quality < 0 => MavState::MAV_STATE_CRITICAL,
        Some(_) => MavState::MAV_STATE_ACTIVE,
    }
}

/// STATUSTEXT for the ground station and the autopilot's log, cut to the 50 bytes it holds.
pub(crate) fn statustext(severity: MavSeverity, text: &str) -> MavMessage {
    let mut end = text.len().min(STATUSTEXT_BYTES);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    MavMessage::STATUSTEXT(apm::STATUSTEXT_DATA {
        severity,
        text: text[..end].into(),
        id: 0,
        chunk_seq: 0,
    })
}

const STATUSTEXT_BYTES: usize = 50;

/// The STATUSTEXT telling the autopilot why `reset_counter` moved to `counter`. A position step
/// is a routine re-anchor (along a corridor nothing measures, every couple of seconds while the
/// estimate is at quality 0), so it is INFO, which ground stations log without announcing; a
/// restart of the filter is a WARNING.
fn reset_text(counter: u8, reason: Option<ResetReason>) -> MavMessage {
    let (severity, why) = match reason {
        Some(ResetReason::Diverged(_)) => {
            (MavSeverity::MAV_SEVERITY_WARNING, "diverged, restarted")
        }
        Some(ResetReason::ImuGap { .. }) => {
            (MavSeverity::MAV_SEVERITY_WARNING, "IMU gap, realigning")
        }
        Some(ResetReason::PositionStep { .. }) => (MavSeverity::MAV_SEVERITY_INFO, "position step"),
        Some(ResetReason::NonFinitePropagation | ResetReason::NonFiniteUpdate) => {
            (MavSeverity::MAV_SEVERITY_WARNING, "non-finite")
        }
        None => (MavSeverity::MAV_SEVERITY_WARNING, "reset"),
    };
    statustext(severity, &format!("LADAR odometry reset {counter}: {why}"))
}

/// The answer to a TIMESYNC request (`tc1 == 0`) from `requester`, stamped with our clock in
/// ns, which must be the clock of `time_usec` in the estimate messages. `None` for a reply
/// (`tc1 != 0`), which must not be answered or the two ends ping-pong forever.
pub(crate) fn timesync_reply(
    request: &apm::TIMESYNC_DATA,
    requester: &MavHeader,
    now_ns: i64,
) -> Option<MavMessage> {
    (request.tc1 == 0).then(|| {
        MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
            tc1: now_ns,
            ts1: request.ts1,
            target_system: u8::try_from(requester.system_id).unwrap_or(0),
            target_component: requester.component_id,
        })
    })
}

fn time_usec(t: f64) -> u64 {
    (t.max(0.0) * 1e6).round() as u64
}

/// Upper triangle (row-major) of a 6x6 whose diagonal blocks are `a` and `b`: autopilots read
/// the variances at indices 0, 6, 11 and 15, 18, 20.
pub(crate) fn upper_triangle_6x6(a: &Matrix3<f64>, b: &Matrix3<f64>) -> [f32; 21] {
    let mut out = [0.0f32; 21];
    let mut k = 0;
    for row in 0..6 {
        for col in row..6 {
            out[k] = match (row < 3, col < 3) {
                (true, true) => a[(row, col)] as f32,
                (false, false) => b[(row - 3, col - 3)] as f32,
                _ => 0.0,
            };
            k += 1;
        }
    }
    out
}

/// ODOMETRY in LOCAL_FRD (our NED, whose heading the autopilot treats as arbitrary) with child
/// frame BODY_FRD: pose, body velocity, body rates, covariances, reset counter and quality.
pub(crate) fn odometry(estimate: &Estimate, quality: i8) -> MavMessage {
    let p = estimate.position.map(|x| x as f32);
    let q = estimate.attitude.quaternion();
    let v = estimate.body_velocity().map(|x| x as f32);
    let w = estimate.angular_rate.map(|x| x as f32);
    let body_velocity_covariance = estimate.body_velocity_covariance();
    // The filter does not publish a rate covariance: NaN says "unknown" to a reader that looks.
    let unknown = Matrix3::from_element(f64::NAN);
    MavMessage::ODOMETRY(apm::ODOMETRY_DATA {
        time_usec: time_usec(estimate.t),
        frame_id: MavFrame::MAV_FRAME_LOCAL_FRD,
        child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
        x: p.x,
        y: p.y,
        z: p.z,
        q: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
        vx: v.x,
        vy: v.y,
        vz: v.z,
        rollspeed: w.x,
        pitchspeed: w.y,
        yawspeed: w.z,
        pose_covariance: upper_triangle_6x6(
            &estimate.position_covariance,
            &estimate.attitude_covariance,
        ),
        velocity_covariance: upper_triangle_6x6(&body_velocity_covariance, &unknown),
        reset_counter: estimate.reset_counter,
        estimator_type: MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
        quality,
    })
}

/// VISION_POSITION_DELTA from `previous` to `current`: the rotation vector of the body's turn
/// (previous body -> current body, in previous body axes, which is what integrated gyro rates
/// give) and the displacement in the current body frame. `None` when time does not advance or
/// the filter was reset in between (a delta across a jump would be fused as real motion).
pub(crate) fn position_delta(
    previous: &Estimate,
    current: &Estimate,
    confidence: f32,
) -> Option<MavMessage> {
    let dt = current.t - previous.t;
    let advances = dt > 0.0;
    if !advances || previous.reset_counter != current.reset_counter {
        return None;
    }
    let turn: UnitQuaternion<f64> = previous.attitude.inverse() * current.attitude;
    let angle = turn.scaled_axis().map(|x| x as f32);
    let displacement = current
        .attitude
        .inverse_transform_vector(&(current.position - previous.position))
        .map(|x| x as f32);
    Some(MavMessage::VISION_POSITION_DELTA(
        apm::VISION_POSITION_DELTA_DATA {
            time_usec: time_usec(current.t),
            time_delta_usec: (dt * 1e6).round() as u64,
            angle_delta: [angle.x, angle.y, angle.z],
            position_delta: [displacement.x, displacement.y, displacement.z],
            confidence,
        },
    ))
}

/// Fires at most once per period; a late call does not cause a burst of catch-up sends.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct RateLimiter {
    period_s: f64,
    next_s: Option<f64>,
}

impl RateLimiter {
    pub(crate) fn new(rate_hz: f64) -> Self {
        Self {
            period_s: 1.0 / rate_hz,
            next_s: None,
        }
    }

    /// A message went out at `now` outside the schedule: the next slot is `periods` periods
    /// later, so the out-of-slot message takes the place of a slot instead of adding to the rate.
    pub(crate) fn restart(&mut self, now: f64, periods: f64) {
        self.next_s = Some(now + periods * self.period_s);
    }

    pub(crate) fn ready(&mut self, now: f64) -> bool {
        match self.next_s {
            Some(next) if now < next => false,
            Some(next) => {
                // Keep the phase when on time, re-anchor after a stall.
                let stepped = next + self.period_s;
                self.next_s = Some(if stepped > now {
                    stepped
                } else {
                    now + self.period_s
                });
                true
            }
            None => {
                self.next_s = Some(now + self.period_s);
                true
            }
        }
    }
}

/// Where the steady schedule resumes after an epoch's message, in periods. Epochs come at a
/// fixed rate that usually divides the steady rate (1 Hz epochs, 30 Hz ODOMETRY): resuming one
/// period later would put a slot right where the next epoch falls, and the epoch would then
/// have to wait for the spacing. Half a period more puts the next epoch mid-way between two
/// slots, far enough from both, and keeps the average rate at the steady one (the epoch's
/// message stands for half a slot).
pub(crate) const EPOCH_RESTART_PERIODS: f64 = 1.5;

/// What to send for each estimate and when the heartbeat is due, for one profile. Decided on
/// estimate time alone, so a replay sends the messages the flight sent.
///
/// IMU-rate estimates go out at the steady rate. The estimate an odometry epoch publishes goes
/// out at once where the profile allows ([`Profile::epoch_spacing_s`]): if the previous message
/// is too recent, the first estimate far enough from it goes instead, out of its slot. Either
/// way the steady schedule restarts [`EPOCH_RESTART_PERIODS`] periods after that message.
#[derive(Debug, Clone)]
pub(crate) struct MavlinkStream {
    profile: Profile,
    policy: QualityPolicy,
    estimates: RateLimiter,
    heartbeats: RateLimiter,
    last_sent: Option<Estimate>,
    /// An epoch's estimate came too soon after the previous message and is still to be carried.
    epoch_waiting: bool,
    state: MavState,
    reset_counter: Option<u8>,
    /// A STATUSTEXT to send after the estimate that caused it.
    pending_text: Option<MavMessage>,
}

impl MavlinkStream {
    pub(crate) fn new(profile: Profile, rate_hz: f64, policy: QualityPolicy) -> Self {
        Self {
            profile,
            policy,
            estimates: RateLimiter::new(rate_hz),
            heartbeats: RateLimiter::new(HEARTBEAT_RATE_HZ),
            last_sent: None,
            epoch_waiting: false,
            state: system_state(None, &policy),
            reset_counter: None,
            pending_text: None,
        }
    }

    /// The HEARTBEAT state of the newest estimate.
    pub(crate) fn system_state(&self) -> MavState {
        self.state
    }

    /// A STATUSTEXT the newest estimates call for (a reset), once.
    pub(crate) fn take_statustext(&mut self) -> Option<MavMessage> {
        self.pending_text.take()
    }

    fn observe(&mut self, estimate: &Estimate) {
        self.state = system_state(Some(estimate), &self.policy);
        let previous = self.reset_counter.replace(estimate.reset_counter);
        if previous.is_some_and(|counter| counter != estimate.reset_counter) {
            self.pending_text = Some(reset_text(estimate.reset_counter, estimate.last_reset));
        }
    }

    pub(crate) fn policy(&self) -> QualityPolicy {
        self.policy
    }

    pub(crate) fn heartbeat_due(&mut self, now: f64) -> Option<MavMessage> {
        self.heartbeats.ready(now).then(|| heartbeat(self.state))
    }

    /// The message for this estimate if one is due at `now`. The ArduPilot delta profile sends
    /// nothing for the first estimate (and after a reset): it needs a previous one.
    pub(crate) fn on_estimate(&mut self, now: f64, estimate: &Estimate) -> Option<MavMessage> {
        self.observe(estimate);
        if self.epoch_waiting && self.spaced_from_last(estimate.t) {
            self.epoch_waiting = false;
            self.estimates.restart(now, EPOCH_RESTART_PERIODS);
        } else if !self.estimates.ready(now) {
            return None;
        }
        self.message(estimate)
    }

    /// The message for the estimate an odometry epoch published, if the profile sends epochs
    /// early and the previous message is not too recent; otherwise a later estimate carries it.
    pub(crate) fn on_epoch_estimate(&mut self, estimate: &Estimate) -> Option<MavMessage> {
        self.observe(estimate);
        self.profile.epoch_spacing_s()?;
        if !self.spaced_from_last(estimate.t) {
            self.epoch_waiting = true;
            return None;
        }
        self.epoch_waiting = false;
        self.estimates.restart(estimate.t, EPOCH_RESTART_PERIODS);
        self.message(estimate)
    }

    fn spaced_from_last(&self, t: f64) -> bool {
        // Message times are whole microseconds: half of one absorbs the rounding of sample times.
        const TOLERANCE_S: f64 = 0.5e-6;
        let spacing = self.profile.epoch_spacing_s().unwrap_or(f64::INFINITY);
        self.last_sent
            .as_ref()
            .is_none_or(|last| t - last.t >= spacing - TOLERANCE_S)
    }

    fn message(&mut self, estimate: &Estimate) -> Option<MavMessage> {
        let message = match self.profile {
            Profile::Px4 | Profile::ArdupilotOdometry => {
                Some(odometry(estimate, self.policy.quality(estimate)))
            }
            Profile::Ardupilot => self.last_sent.as_ref().and_then(|previous| {
                position_delta(previous, estimate, self.policy.confidence(estimate))
            }),
        };
        self.last_sent = Some(estimate.clone());
        message
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use std::f64::consts::FRAC_PI_2;

    fn encode(sequence: u8, message: &MavMessage) -> String {
        let header = MavHeader {
            system_id: 1,
            component_id: DEFAULT_COMPONENT_ID,
            sequence,
        };
        let mut bytes = Vec::new();
        mavlink::write_v2_msg(&mut bytes, header, message).unwrap();
        bytes.iter().map(|b| format!("{b:02x}")).collect()
    }

    fn estimate() -> Estimate {
        Estimate {
            t: 1.0,
            position: Vector3::new(1.0, 2.0, -3.0),
            velocity: Vector3::new(0.5, 0.0, 0.0),
            attitude: UnitQuaternion::identity(),
            angular_rate: Vector3::new(0.0, 0.0, 0.1),
            position_covariance: Matrix3::from_diagonal(&Vector3::new(0.01, 0.02, 0.03)),
            velocity_covariance: Matrix3::from_diagonal(&Vector3::new(0.0025, 0.0025, 0.0025)),
            velocity_attitude_covariance: Matrix3::zeros(),
            attitude_covariance: Matrix3::from_diagonal(&Vector3::new(1e-4, 2e-4, 3e-4)),
            gyro_bias: Vector3::zeros(),
            accel_bias: Vector3::zeros(),
            reset_counter: 0,
            last_reset: None,
            integrity: Some(IntegrityStatus::Ok),
            since_last_fused: 0.1,
            degraded: false,
            converged: true,
        }
    }

    #[test]
    fn heartbeat_matches_the_cross_validated_vector() {
        assert_eq!(
            encode(0, &heartbeat(MavState::MAV_STATE_ACTIVE)),
            "fd0900000001c50000000000000012080004031ee4"
        );
    }

    #[test]
    fn odometry_matches_the_cross_validated_vector() {
        let mut nan_first = [0.0f32; 21];
        nan_first[0] = f32::NAN;
        let message = MavMessage::ODOMETRY(apm::ODOMETRY_DATA {
            time_usec: 1_000_000,
            frame_id: MavFrame::MAV_FRAME_LOCAL_FRD,
            child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
            x: 1.0,
            y: 2.0,
            z: -3.0,
            q: [1.0, 0.0, 0.0, 0.0],
            vx: 0.5,
            yawspeed: 0.1,
            pose_covariance: nan_first,
            velocity_covariance: nan_first,
            reset_counter: 0,
            estimator_type: MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
            quality: 100,
            ..Default::default()
        });
        let zeros = "00".repeat(80);
        let expected = format!(
            "fde900000201c54b010040420f00000000000000803f00000040000040c00000803f00000000000000000000\
             00000000003f00000000000000000000000000000000cdcccc3d0000c07f{zeros}0000c07f{zeros}\
             140c000364567a"
        );
        assert_eq!(expected.len(), 2 * 245);
        assert_eq!(encode(2, &message), expected);
    }

    #[test]
    fn vision_position_delta_matches_the_cross_validated_vector() {
        let message = MavMessage::VISION_POSITION_DELTA(apm::VISION_POSITION_DELTA_DATA {
            time_usec: 1_000_000,
            time_delta_usec: 50_000,
            angle_delta: [0.0, 0.0, 0.01],
            position_delta: [0.05, 0.0, 0.0],
            confidence: 90.0,
        });
        assert_eq!(
            encode(3, &message),
            "fd2c00000301c5032b0040420f000000000050c300000000000000000000000000000ad7233ccdcc4c3d\
             00000000000000000000b442723e"
        );
    }

    #[test]
    fn timesync_request_is_answered_and_reply_ignored() {
        let requester = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 9,
        };
        let request = apm::TIMESYNC_DATA {
            tc1: 0,
            ts1: 123_456,
            ..Default::default()
        };
        let Some(MavMessage::TIMESYNC(reply)) = timesync_reply(&request, &requester, 42) else {
            panic!("a request must be answered");
        };
        assert_eq!((reply.tc1, reply.ts1), (42, 123_456));
        assert_eq!((reply.target_system, reply.target_component), (1, 1));
        let answer = apm::TIMESYNC_DATA { tc1: 7, ..request };
        assert!(timesync_reply(&answer, &requester, 42).is_none());
    }

    #[test]
    fn odometry_maps_pose_body_velocity_and_covariance_indices() {
        let mut e = estimate();
        e.attitude = UnitQuaternion::from_euler_angles(0.0, 0.0, FRAC_PI_2);
        e.velocity = Vector3::new(0.0, 2.0, 0.0); // east, i.e. straight ahead after a 90 deg yaw
        e.velocity_covariance = Matrix3::from_diagonal(&Vector3::new(0.01, 0.04, 0.09));
        let MavMessage::ODOMETRY(m) = odometry(&e, 55) else {
            panic!("expected ODOMETRY");
        };
        assert_eq!(m.frame_id, MavFrame::MAV_FRAME_LOCAL_FRD);
        assert_eq!(m.child_frame_id, MavFrame::MAV_FRAME_BODY_FRD);
        assert_eq!(m.time_usec, 1_000_000);
        assert_eq!([m.x, m.y, m.z], [1.0, 2.0, -3.0]);
        let q = e.attitude.quaternion();
        assert_eq!(m.q, [q.w as f32, q.i as f32, q.j as f32, q.k as f32]);
        assert!((m.vx - 2.0).abs() < 1e-6 && m.vy.abs() < 1e-6 && m.vz.abs() < 1e-6);
        assert_eq!(m.yawspeed, 0.1);
        assert_eq!(
            [
                m.pose_covariance[0],
                m.pose_covariance[6],
                m.pose_covariance[11]
            ],
            [0.01, 0.02, 0.03]
        );
        assert_eq!(
            [
                m.pose_covariance[15],
                m.pose_covariance[18],
                m.pose_covariance[20]
            ],
            [1e-4, 2e-4, 3e-4]
        );
        // NED north/east variances swap places in the body frame of a vehicle facing east, and
        // the attitude's sigmas turn the 2 m/s east into sideways (yaw, 3e-4 rad^2) and vertical
        // (roll about north, 1e-4 rad^2) uncertainty: 4 m^2/s^2 times each.
        let v = &m.velocity_covariance;
        assert!((v[0] - 0.04).abs() < 1e-7, "{}", v[0]);
        assert!((v[6] - (0.01 + 4.0 * 3e-4)).abs() < 1e-7, "{}", v[6]);
        assert!((v[11] - (0.09 + 4.0 * 1e-4)).abs() < 1e-7, "{}", v[11]);
        assert!(v[15].is_nan() && v[18].is_nan() && v[20].is_nan());
        assert_eq!(m.estimator_type, MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO);
        assert_eq!(m.quality, 55);
    }

    #[test]
    fn quality_follows_integrity_and_staleness() {
        let policy = QualityPolicy::default();
        let mut e = estimate();
        // At rest, so that the attitude's sigmas add nothing to the body velocity's.
        e.velocity = Vector3::zeros();
        assert_eq!(policy.quality(&e), 100, "sigma_v 0.05 earns the full score");
        e.velocity_covariance = Matrix3::identity() * 0.01; // sigma 0.1 m/s
        assert_eq!(policy.quality(&e), 50);
        e.integrity = Some(IntegrityStatus::Excluded { planes: vec![3] });
        e.velocity_covariance = Matrix3::identity() * 1e-4;
        assert_eq!(policy.quality(&e), 75);
        e.integrity = Some(IntegrityStatus::DetectedNotIsolable);
        assert_eq!(policy.quality(&e), 10);
        e.integrity = Some(IntegrityStatus::UnderDetermined);
        assert_eq!(policy.quality(&e), 10);
        e.integrity = Some(IntegrityStatus::Ok);
        e.since_last_fused = 1.5;
        assert_eq!(policy.quality(&e), -1, "no fused odometry for too long");
        e.since_last_fused = f64::INFINITY;
        assert_eq!(policy.quality(&e), -1);
        e.since_last_fused = 0.0;
        e.degraded = true;
        assert_eq!(policy.quality(&e), -1);
        assert_eq!(policy.confidence(&e), 0.0);
        e.degraded = false;
        e.integrity = None;
        assert_eq!(policy.quality(&e), -1, "before any odometry epoch");
        e.integrity = Some(IntegrityStatus::Ok);
        e.velocity_covariance[(0, 0)] = f64::NAN;
        assert_eq!(policy.quality(&e), -1);
        e.velocity_covariance = Matrix3::identity() * 0.16;
        assert_eq!(policy.quality(&e), 12, "sigma 0.4 m/s: usable, barely");
        e.velocity_covariance = Matrix3::identity() * 100.0;
        assert_eq!(
            policy.quality(&e),
            0,
            "huge but finite covariance: an unobserved axis, not to be used, not failed"
        );
        e.velocity_covariance = Matrix3::identity() * 1e-4;
        e.converged = false;
        assert_eq!(policy.quality(&e), 0, "not converged since the start");
    }

    #[test]
    fn a_direction_unobserved_between_the_axes_is_not_to_be_used() {
        let policy = QualityPolicy::default();
        let mut e = estimate();
        e.velocity = Vector3::zeros();
        // 0.55 m/s along north-east, 1 cm/s across and down: 0.39 m/s on each axis.
        let along = Vector3::new(1.0, 1.0, 0.0).normalize();
        e.velocity_covariance =
            along * along.transpose() * (0.55 * 0.55 - 1e-4) + Matrix3::identity() * 1e-4;
        assert_eq!(policy.quality(&e), 0, "{}", policy.quality(&e));
        // The same sigma along north alone has always been unusable.
        e.velocity_covariance = Matrix3::from_diagonal(&Vector3::new(0.3025, 1e-4, 1e-4));
        assert_eq!(policy.quality(&e), 0);
    }

    #[test]
    fn a_heading_in_doubt_at_speed_lowers_the_quality_as_the_sent_covariance_does() {
        let policy = QualityPolicy::default();
        let mut e = estimate();
        e.velocity = Vector3::new(2.0, 0.0, 0.0);
        e.velocity_covariance = Matrix3::identity() * 1e-4;
        e.attitude_covariance = Matrix3::from_diagonal(&Vector3::new(1e-6, 1e-6, 0.01));
        // 0.1 rad of heading at 2 m/s: 0.2 m/s sideways in the body frame.
        assert_eq!(policy.quality(&e), 24);
    }

    #[test]
    fn delta_of_a_yaw_turn_while_moving_forward() {
        let previous = estimate();
        let mut current = estimate();
        current.t = previous.t + 0.05;
        current.attitude = UnitQuaternion::from_euler_angles(0.0, 0.0, FRAC_PI_2);
        current.position = previous.position + Vector3::new(1.0, 0.0, 0.0); // 1 m north
        let Some(MavMessage::VISION_POSITION_DELTA(m)) = position_delta(&previous, &current, 80.0)
        else {
            panic!("expected VISION_POSITION_DELTA");
        };
        assert_eq!(m.time_delta_usec, 50_000);
        assert_eq!(m.time_usec, 1_050_000);
        assert!(m.angle_delta[0].abs() < 1e-6 && m.angle_delta[1].abs() < 1e-6);
        assert!((f64::from(m.angle_delta[2]) - FRAC_PI_2).abs() < 1e-6);
        // Facing east, north is on the left: -y in the current FRD body frame.
        assert!(m.position_delta[0].abs() < 1e-6);
        assert!((m.position_delta[1] + 1.0).abs() < 1e-6);
        assert!(m.position_delta[2].abs() < 1e-6);
        assert_eq!(m.confidence, 80.0);
    }

    #[test]
    fn delta_angle_is_in_previous_body_axes() {
        // Pitched up 30 deg, then yawing about the body z axis: the delta is about body z only.
        let mut previous = estimate();
        previous.attitude = UnitQuaternion::from_euler_angles(0.0, 0.5, 0.0);
        let mut current = previous.clone();
        current.t += 0.1;
        current.attitude = previous.attitude * UnitQuaternion::from_euler_angles(0.0, 0.0, 0.2);
        let Some(MavMessage::VISION_POSITION_DELTA(m)) = position_delta(&previous, &current, 50.0)
        else {
            panic!("expected VISION_POSITION_DELTA");
        };
        assert!(m.angle_delta[0].abs() < 1e-6 && m.angle_delta[1].abs() < 1e-6);
        assert!((m.angle_delta[2] - 0.2).abs() < 1e-6);
    }

    #[test]
    fn no_delta_across_a_reset_or_without_time_passing() {
        let previous = estimate();
        let mut current = estimate();
        assert!(position_delta(&previous, &current, 50.0).is_none());
        current.t += 0.1;
        current.reset_counter = 1;
        assert!(position_delta(&previous, &current, 50.0).is_none());
    }

    proptest::proptest! {
        #[test]
        fn delta_reconstructs_the_current_pose(
            rpy0 in proptest::array::uniform3(-1.5f64..1.5),
            turn in proptest::array::uniform3(-0.5f64..0.5),
            step in proptest::array::uniform3(-2.0f64..2.0),
        ) {
            let mut previous = estimate();
            previous.attitude = UnitQuaternion::from_euler_angles(rpy0[0], rpy0[1], rpy0[2]);
            let mut current = previous.clone();
            current.t += 0.05;
            current.attitude =
                previous.attitude * UnitQuaternion::from_scaled_axis(Vector3::from(turn));
            current.position += Vector3::from(step);
            let Some(MavMessage::VISION_POSITION_DELTA(m)) =
                position_delta(&previous, &current, 100.0)
            else {
                panic!("expected a delta");
            };
            let angle = Vector3::from(m.angle_delta.map(f64::from));
            let rebuilt = previous.attitude * UnitQuaternion::from_scaled_axis(angle);
            proptest::prop_assert!(rebuilt.angle_to(&current.attitude) < 1e-5);
            let displacement =
                current.attitude * Vector3::from(m.position_delta.map(f64::from));
            proptest::prop_assert!((displacement - Vector3::from(step)).norm() < 1e-5);
        }
    }

    #[test]
    fn rate_limiter_keeps_phase_and_does_not_burst() {
        let mut limiter = RateLimiter::new(10.0);
        let fired: Vec<bool> = [0.0, 0.05, 0.1, 0.15, 0.2]
            .iter()
            .map(|&t| limiter.ready(t))
            .collect();
        assert_eq!(fired, [true, false, true, false, true]);
        assert!(limiter.ready(5.0), "after a stall it fires once");
        assert!(!limiter.ready(5.01), "and does not catch up with a burst");
        assert!(limiter.ready(5.1));
    }

    #[test]
    fn stream_sends_per_profile_at_its_rate() {
        let mut px4 = MavlinkStream::new(Profile::Px4, 30.0, QualityPolicy::default());
        let mut ardupilot = MavlinkStream::new(Profile::Ardupilot, 10.0, QualityPolicy::default());
        let (mut odometry_count, mut delta_count, mut heartbeats) = (0, 0, 0);
        for i in 0..200 {
            let now = f64::from(i) * 0.01; // 100 Hz estimates for 2 s
            let mut e = estimate();
            e.t = now;
            if let Some(MavMessage::ODOMETRY(_)) = px4.on_estimate(now, &e) {
                odometry_count += 1;
            }
            if let Some(MavMessage::VISION_POSITION_DELTA(_)) = ardupilot.on_estimate(now, &e) {
                delta_count += 1;
            }
            heartbeats += usize::from(px4.heartbeat_due(now).is_some());
        }
        assert!((59..=61).contains(&odometry_count), "{odometry_count}");
        assert_eq!(
            delta_count, 19,
            "20 sends at 10 Hz, the first has no previous"
        );
        assert_eq!(heartbeats, 2);
    }

    #[test]
    fn a_reset_sends_one_statustext_and_the_heartbeat_follows_the_estimate() {
        let mut stream = MavlinkStream::new(Profile::Px4, 30.0, QualityPolicy::default());
        let heartbeat_state = |stream: &mut MavlinkStream, now: f64| match stream.heartbeat_due(now)
        {
            Some(MavMessage::HEARTBEAT(h)) => h.system_status,
            other => panic!("{other:?}"),
        };
        assert_eq!(
            heartbeat_state(&mut stream, 0.0),
            MavState::MAV_STATE_CALIBRATING,
            "no estimate yet"
        );
        stream.on_estimate(0.5, &at(0.5));
        assert_eq!(stream.take_statustext(), None);
        assert_eq!(
            heartbeat_state(&mut stream, 1.0),
            MavState::MAV_STATE_ACTIVE
        );
        // A (re)start that has not converged yet, with `reset_counter` moved to `counter`.
        let restart = |t: f64, counter: u8, reason: ResetReason| Estimate {
            reset_counter: counter,
            converged: false,
            last_reset: Some(reason),
            ..at(t)
        };
        let text_after = |stream: &mut MavlinkStream, estimate: &Estimate| {
            stream.on_estimate(estimate.t, estimate);
            match stream.take_statustext() {
                Some(MavMessage::STATUSTEXT(text)) => text,
                other => panic!("no STATUSTEXT for {estimate:?}: {other:?}"),
            }
        };
        let imu_gap = ResetReason::ImuGap { seconds: 3.0 };
        let text = text_after(&mut stream, &restart(1.5, 1, imu_gap));
        assert_eq!(text.severity, MavSeverity::MAV_SEVERITY_WARNING);
        assert_eq!(
            text.text.to_str().unwrap().trim_end_matches('\0'),
            "LADAR odometry reset 1: IMU gap, realigning"
        );
        assert_eq!(stream.take_statustext(), None, "once");
        let step = ResetReason::PositionStep { metres: 0.4 };
        let text = text_after(&mut stream, &restart(1.6, 2, step));
        assert_eq!(
            text.severity,
            MavSeverity::MAV_SEVERITY_INFO,
            "a routine re-anchor"
        );
        assert_eq!(
            heartbeat_state(&mut stream, 2.0),
            MavState::MAV_STATE_CALIBRATING
        );
        let degraded = Estimate {
            degraded: true,
            ..restart(2.5, 2, imu_gap)
        };
        stream.on_estimate(2.5, &degraded);
        assert_eq!(
            heartbeat_state(&mut stream, 3.0),
            MavState::MAV_STATE_CRITICAL
        );
    }

    #[test]
    fn a_statustext_is_cut_to_fifty_bytes_on_a_character_boundary() {
        let MavMessage::STATUSTEXT(text) =
            statustext(MavSeverity::MAV_SEVERITY_INFO, &"é".repeat(40))
        else {
            panic!()
        };
        assert_eq!(
            text.text.to_str().unwrap().trim_end_matches('\0'),
            "é".repeat(25)
        );
    }

    fn at(t: f64) -> Estimate {
        Estimate { t, ..estimate() }
    }

    fn odometry_time(message: Option<MavMessage>) -> Option<u64> {
        match message {
            Some(MavMessage::ODOMETRY(o)) => Some(o.time_usec),
            _ => None,
        }
    }

    #[test]
    fn an_epoch_goes_out_at_once_and_takes_the_place_of_the_next_slot() {
        // Binary-exact times: a 32 Hz schedule over estimates every 1/256 s.
        let t = |k: u32| 1.0 + f64::from(k) / 256.0;
        let mut px4 = MavlinkStream::new(Profile::Px4, 32.0, QualityPolicy::default());
        assert!(px4.on_estimate(t(0), &at(t(0))).is_some());
        assert!(px4.on_estimate(t(3), &at(t(3))).is_none());
        let epoch = px4.on_epoch_estimate(&at(t(3)));
        assert_eq!(
            odometry_time(epoch),
            Some(1_011_719),
            "11.7 ms after the slot"
        );
        // The slot due at t(8) moved to t(15): 1.5 periods after the epoch's message.
        let sent: Vec<u64> = (4..=24)
            .filter_map(|k| odometry_time(px4.on_estimate(t(k), &at(t(k)))))
            .collect();
        assert_eq!(sent, [1_058_594, 1_089_844]);
    }

    #[test]
    fn an_epoch_too_close_to_the_previous_message_rides_on_the_first_estimate_far_enough() {
        let mut px4 = MavlinkStream::new(Profile::Px4, 30.0, QualityPolicy::default());
        let times = [2.0, 2.0025, 2.005, 2.0075, 2.01, 2.0125];
        assert!(px4.on_estimate(times[0], &at(times[0])).is_some());
        assert!(px4.on_estimate(times[1], &at(times[1])).is_none());
        assert!(
            px4.on_epoch_estimate(&at(times[1])).is_none(),
            "2.5 ms after the previous message: EKF2 would drop it"
        );
        let sent: Vec<Option<u64>> = times[2..]
            .iter()
            .map(|&t| odometry_time(px4.on_estimate(t, &at(t))))
            .collect();
        assert_eq!(sent, [None, None, Some(2_010_000), None]);
    }

    #[test]
    fn the_delta_profile_keeps_its_steady_rate_through_epochs() {
        let steady = |with_epochs: bool| {
            let mut stream = MavlinkStream::new(Profile::Ardupilot, 10.0, QualityPolicy::default());
            let mut sent = Vec::new();
            for k in 0..100 {
                let t = f64::from(k) * 0.01;
                if let Some(MavMessage::VISION_POSITION_DELTA(d)) = stream.on_estimate(t, &at(t)) {
                    sent.push(d.time_usec);
                }
                if with_epochs && k % 7 == 3 {
                    assert!(stream.on_epoch_estimate(&at(t)).is_none());
                }
            }
            sent
        };
        assert_eq!(steady(true), steady(false));
        assert_eq!(steady(true).len(), 9);
    }

    #[test]
    fn profile_names_round_trip() {
        for p in [Profile::Px4, Profile::Ardupilot, Profile::ArdupilotOdometry] {
            assert_eq!(p.to_string().parse::<Profile>(), Ok(p));
            let (low, high) = p.rate_range_hz();
            assert!((low..=high).contains(&p.default_rate_hz()));
        }
        let err = "apm".parse::<Profile>().unwrap_err().to_string();
        assert!(err.contains("`apm`") && err.contains("px4"));
    }
}
