//! Analytic body trajectories. Every coordinate is a closed-form function of time with exact first
//! and second derivatives, so the IMU derived from it agrees with the truth to rounding.

use super::GRAVITY;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::f64::consts::{PI, TAU};

/// A scalar function of time with its first and second derivatives at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Jet {
    value: f64,
    rate: f64,
    accel: f64,
}

impl Jet {
    fn constant(value: f64) -> Self {
        Self {
            value,
            ..Self::default()
        }
    }

    fn add(self, other: Self) -> Self {
        Self {
            value: self.value + other.value,
            rate: self.rate + other.rate,
            accel: self.accel + other.accel,
        }
    }

    fn scale(self, k: f64) -> Self {
        Self {
            value: k * self.value,
            rate: k * self.rate,
            accel: k * self.accel,
        }
    }

    fn mul(self, other: Self) -> Self {
        Self {
            value: self.value * other.value,
            rate: self.rate * other.value + self.value * other.rate,
            accel: self.accel * other.value
                + 2.0 * self.rate * other.rate
                + self.value * other.accel,
        }
    }

    /// `amplitude * sin(2 pi t / period)`; a zero amplitude or period gives zero.
    fn sine(t: f64, amplitude: f64, period: f64) -> Self {
        if amplitude == 0.0 || period <= 0.0 {
            return Self::default();
        }
        let w = TAU / period;
        let (s, c) = (w * t).sin_cos();
        Self {
            value: amplitude * s,
            rate: amplitude * w * c,
            accel: -amplitude * w * w * s,
        }
    }

    /// Minimum-jerk step from 0 to 1 over `[start, start + duration]`: zero velocity and zero
    /// acceleration at both ends, so pieces join without jumps in specific force.
    fn smooth_step(t: f64, start: f64, duration: f64) -> Self {
        if duration <= 0.0 {
            return Self::constant(if t >= start { 1.0 } else { 0.0 });
        }
        let u = (t - start) / duration;
        if u <= 0.0 {
            return Self::default();
        }
        if u >= 1.0 {
            return Self::constant(1.0);
        }
        let (u2, u3) = (u * u, u * u * u);
        Self {
            value: u3 * (10.0 - 15.0 * u + 6.0 * u2),
            rate: 30.0 * u2 * (1.0 - u) * (1.0 - u) / duration,
            accel: 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u) / (duration * duration),
        }
    }

    /// The integral of [`Self::smooth_step`]: 0 before `start`, then a rate rising smoothly
    /// from 0 to 1 over `duration`, then `t - start - duration / 2`. Scaled by a speed, it is
    /// the distance covered when setting off from rest to a constant speed.
    fn smooth_ramp(t: f64, start: f64, duration: f64) -> Self {
        let elapsed = t - start;
        if elapsed <= 0.0 {
            return Self::default();
        }
        if elapsed >= duration {
            return Self {
                value: elapsed - duration / 2.0,
                rate: 1.0,
                accel: 0.0,
            };
        }
        let u = elapsed / duration;
        let step = Self::smooth_step(t, start, duration);
        Self {
            value: duration * u.powi(4) * (2.5 - 3.0 * u + u * u),
            rate: step.value,
            accel: step.rate,
        }
    }
}

/// Small hover motions: per-axis sinusoids in position (NED) and attitude (roll, pitch, yaw),
/// faded in from `start_s` over `ramp_s` so the body is exactly still before (for ZUPT).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct Oscillation {
    pub position_amplitude_m: [f64; 3],
    pub position_period_s: [f64; 3],
    pub attitude_amplitude_deg: [f64; 3],
    pub attitude_period_s: [f64; 3],
    pub start_s: f64,
    pub ramp_s: f64,
}

impl Oscillation {
    fn envelope(&self, t: f64) -> Jet {
        Jet::smooth_step(t, self.start_s, self.ramp_s)
    }

    fn position(&self, t: f64, axis: usize) -> Jet {
        let local = t - self.start_s;
        let wave = Jet::sine(
            local,
            self.position_amplitude_m[axis],
            self.position_period_s[axis],
        );
        self.envelope(t).mul(wave)
    }

    fn attitude(&self, t: f64, axis: usize) -> Jet {
        let local = t - self.start_s;
        let wave = Jet::sine(
            local,
            self.attitude_amplitude_deg[axis].to_radians(),
            self.attitude_period_s[axis],
        );
        self.envelope(t).mul(wave)
    }
}

/// Motion of the body origin and attitude in NED. Positions in metres, angles in degrees
/// (`rpy_deg = [roll, pitch, yaw]`, aerospace ZYX).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Trajectory {
    /// Fixed pose.
    Stationary {
        position_m: [f64; 3],
        rpy_deg: [f64; 3],
    },
    /// Fixed pose plus small sinusoidal motions.
    Hover {
        position_m: [f64; 3],
        rpy_deg: [f64; 3],
        #[serde(default)]
        oscillation: Oscillation,
    },
    /// Flight along the initial heading: wait until `start_s`, fly `leg_length_m` in
    /// `leg_duration_s` (minimum-jerk speed profile, peak 1.875 x mean speed), then optionally
    /// turn 180 deg in yaw over `turn_duration_s` and fly back. Hover motions are superposed.
    Flight {
        position_m: [f64; 3],
        rpy_deg: [f64; 3],
        start_s: f64,
        leg_length_m: f64,
        leg_duration_s: f64,
        #[serde(default)]
        return_leg: bool,
        #[serde(default)]
        turn_duration_s: f64,
        #[serde(default)]
        oscillation: Oscillation,
    },
    /// Flight from rest at `position_m` through `waypoints_m` (NED, m) at `speed_mps`, from
    /// `start_s`: constant speed along each leg, and every change of velocity (setting off, each
    /// corner, the stop) a minimum-jerk blend over `blend_s`, so corners are cut and the body
    /// stops exactly at the last waypoint. The yaw turns with the horizontal track over the same
    /// blends (the body keeps the angle to the track it starts with). Hover motions are
    /// superposed.
    Waypoints {
        position_m: [f64; 3],
        rpy_deg: [f64; 3],
        start_s: f64,
        waypoints_m: Vec<[f64; 3]>,
        speed_mps: f64,
        blend_s: f64,
        #[serde(default)]
        oscillation: Oscillation,
    },
    /// Pose jumps at `at_s` (the paper's two compensated epochs), or with `ramp_s > 0` moves
    /// over the `ramp_s` before `at_s` (minimum-jerk profile), which an IMU can follow.
    Step {
        position_m: [f64; 3],
        rpy_deg: [f64; 3],
        at_s: f64,
        position_after_m: [f64; 3],
        rpy_after_deg: [f64; 3],
        #[serde(default, skip_serializing_if = "is_zero")]
        ramp_s: f64,
    },
}

/// Full kinematic state of the body at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kinematics {
    pub t: f64,
    /// Position of the body origin, NED, m.
    pub p: Vector3<f64>,
    /// Attitude, body -> NED.
    pub q: UnitQuaternion<f64>,
    /// Velocity, NED, m/s.
    pub v: Vector3<f64>,
    /// Acceleration, NED, m/s^2.
    pub a: Vector3<f64>,
    /// Angular rate of the body relative to NED, in body axes, rad/s.
    pub omega_body: Vector3<f64>,
    /// Specific force (acceleration minus gravity) in body axes, m/s^2.
    pub specific_force_body: Vector3<f64>,
}

impl Trajectory {
    /// Whether the motion has continuous acceleration, which an IMU needs.
    pub fn is_smooth(&self) -> bool {
        !matches!(self, Self::Step { ramp_s, .. } if *ramp_s <= 0.0)
    }

    /// What is wrong with the trajectory's own values, if anything.
    pub fn problem(&self) -> Option<String> {
        match self {
            Self::Step { ramp_s, .. } if !(ramp_s.is_finite() && *ramp_s >= 0.0) => Some(format!(
                "trajectory ramp_s = {ramp_s} is invalid: set a duration in seconds, 0 or more"
            )),
            Self::Waypoints {
                start_s,
                waypoints_m,
                speed_mps,
                blend_s,
                ..
            } => {
                let positive = |v: f64| v.is_finite() && v > 0.0;
                if !(positive(*speed_mps) && positive(*blend_s) && start_s.is_finite()) {
                    Some(format!(
                        "trajectory speed_mps = {speed_mps}, blend_s = {blend_s}, start_s = {start_s}: speed and blend must be positive, start_s finite"
                    ))
                } else if waypoints_m.is_empty()
                    || waypoints_m.iter().flatten().any(|c| !c.is_finite())
                {
                    Some("trajectory waypoints_m must list at least one finite position".into())
                } else {
                    None
                }
            }
            _ => None,
        }
    }

    /// Position and attitude only (cheaper than [`Self::kinematics`]; used per beam).
    pub fn pose(&self, t: f64) -> (Vector3<f64>, UnitQuaternion<f64>) {
        let (p, e) = self.coordinates(t);
        (
            Vector3::new(p[0].value, p[1].value, p[2].value),
            euler_to_quaternion(e[0].value, e[1].value, e[2].value),
        )
    }

    pub fn kinematics(&self, t: f64) -> Kinematics {
        let (p, e) = self.coordinates(t);
        let q = euler_to_quaternion(e[0].value, e[1].value, e[2].value);
        let a = Vector3::new(p[0].accel, p[1].accel, p[2].accel);
        let gravity = Vector3::new(0.0, 0.0, GRAVITY);
        Kinematics {
            t,
            p: Vector3::new(p[0].value, p[1].value, p[2].value),
            q,
            v: Vector3::new(p[0].rate, p[1].rate, p[2].rate),
            a,
            omega_body: euler_rates_to_body(&e),
            specific_force_body: q.inverse_transform_vector(&(a - gravity)),
        }
    }

    /// Each NED position coordinate and each Euler angle (rad) as a jet.
    fn coordinates(&self, t: f64) -> ([Jet; 3], [Jet; 3]) {
        match self {
            Self::Stationary {
                position_m,
                rpy_deg,
            } => (
                position_m.map(Jet::constant),
                rpy_deg.map(|a| Jet::constant(a.to_radians())),
            ),
            Self::Hover {
                position_m,
                rpy_deg,
                oscillation,
            } => hover_coordinates(t, position_m, rpy_deg, oscillation),
            Self::Flight {
                position_m,
                rpy_deg,
                start_s,
                leg_length_m,
                leg_duration_s,
                return_leg,
                turn_duration_s,
                oscillation,
            } => {
                let (mut p, mut e) = hover_coordinates(t, position_m, rpy_deg, oscillation);
                let outbound = Jet::smooth_step(t, *start_s, *leg_duration_s);
                let (along, turn) = if *return_leg {
                    let turn_start = start_s + leg_duration_s;
                    let back_start = turn_start + turn_duration_s;
                    let back = Jet::smooth_step(t, back_start, *leg_duration_s);
                    (
                        outbound.add(back.scale(-1.0)),
                        Jet::smooth_step(t, turn_start, *turn_duration_s).scale(PI),
                    )
                } else {
                    (outbound, Jet::default())
                };
                let heading = rpy_deg[2].to_radians();
                let along = along.scale(*leg_length_m);
                p[0] = p[0].add(along.scale(heading.cos()));
                p[1] = p[1].add(along.scale(heading.sin()));
                e[2] = e[2].add(turn);
                (p, e)
            }
            Self::Waypoints {
                position_m,
                rpy_deg,
                start_s,
                waypoints_m,
                speed_mps,
                blend_s,
                oscillation,
            } => {
                let (mut p, mut e) = hover_coordinates(t, position_m, rpy_deg, oscillation);
                let (travel, turn) =
                    waypoint_legs(t, position_m, *start_s, waypoints_m, *speed_mps, *blend_s);
                for (coordinate, leg) in p.iter_mut().zip(travel) {
                    *coordinate = coordinate.add(leg);
                }
                e[2] = e[2].add(turn);
                (p, e)
            }
            Self::Step {
                position_m,
                rpy_deg,
                at_s,
                position_after_m,
                rpy_after_deg,
                ramp_s,
            } => {
                let start = at_s - ramp_s;
                let constant = |p: &[f64; 3], e: &[f64; 3]| {
                    (
                        p.map(Jet::constant),
                        e.map(|a| Jet::constant(a.to_radians())),
                    )
                };
                // Outside the ramp the poses are the end poses exactly, not blends that round:
                // the paper's scans and its faults (placed at `at_s`) are taken there.
                if t >= *at_s {
                    constant(position_after_m, rpy_after_deg)
                } else if t < start {
                    constant(position_m, rpy_deg)
                } else {
                    let s = Jet::smooth_step(t, start, *ramp_s);
                    let blend = |from: f64, to: f64| Jet::constant(from).add(s.scale(to - from));
                    (
                        std::array::from_fn(|i| blend(position_m[i], position_after_m[i])),
                        std::array::from_fn(|i| {
                            blend(rpy_deg[i].to_radians(), rpy_after_deg[i].to_radians())
                        }),
                    )
                }
            }
        }
    }
}

fn is_zero(value: &f64) -> bool {
    *value == 0.0
}

fn hover_coordinates(
    t: f64,
    position_m: &[f64; 3],
    rpy_deg: &[f64; 3],
    oscillation: &Oscillation,
) -> ([Jet; 3], [Jet; 3]) {
    let p = std::array::from_fn(|i| Jet::constant(position_m[i]).add(oscillation.position(t, i)));
    let e = std::array::from_fn(|i| {
        Jet::constant(rpy_deg[i].to_radians()).add(oscillation.attitude(t, i))
    });
    (p, e)
}

/// The displacement (NED) and the yaw turn of a waypoint flight at `t`. Leg k's velocity rises
/// from 0 to its constant value as leg k - 1's falls to 0, over the same blend, so their sum
/// turns the corner smoothly; each leg covers exactly its length, whatever the blends.
fn waypoint_legs(
    t: f64,
    position_m: &[f64; 3],
    start_s: f64,
    waypoints_m: &[[f64; 3]],
    speed_mps: f64,
    blend_s: f64,
) -> ([Jet; 3], Jet) {
    let mut travel = [Jet::default(); 3];
    let mut yaw = Jet::default();
    let mut from = Vector3::from(*position_m);
    let mut leg_start = start_s;
    let mut heading: Option<f64> = None;
    for to in waypoints_m.iter().map(|w| Vector3::from(*w)) {
        let leg = to - from;
        let duration = leg.norm() / speed_mps;
        if duration == 0.0 {
            continue;
        }
        let covered = Jet::smooth_ramp(t, leg_start, blend_s)
            .add(Jet::smooth_ramp(t, leg_start + duration, blend_s).scale(-1.0));
        for (axis, coordinate) in travel.iter_mut().enumerate() {
            *coordinate = coordinate.add(covered.scale(leg[axis] / duration));
        }
        // A vertical leg has no track heading: the yaw holds.
        if leg.xy().norm() > 1e-9 {
            let leg_heading = leg.y.atan2(leg.x);
            if let Some(previous) = heading {
                let turn = (leg_heading - previous + PI).rem_euclid(TAU) - PI;
                yaw = yaw.add(Jet::smooth_step(t, leg_start, blend_s).scale(turn));
            }
            heading = Some(leg_heading);
        }
        from = to;
        leg_start += duration;
    }
    (travel, yaw)
}

/// Rz(yaw) Ry(pitch) Rx(roll), the same composition as `Mount::from_rpy_deg`.
pub fn euler_to_quaternion(roll: f64, pitch: f64, yaw: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
        * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), pitch)
        * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), roll)
}

/// Body angular rate from ZYX Euler angles and their rates.
fn euler_rates_to_body(e: &[Jet; 3]) -> Vector3<f64> {
    let (roll, pitch) = (e[0].value, e[1].value);
    let (droll, dpitch, dyaw) = (e[0].rate, e[1].rate, e[2].rate);
    let (sr, cr) = roll.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    Vector3::new(
        droll - dyaw * sp,
        dpitch * cr + dyaw * sr * cp,
        -dpitch * sr + dyaw * cr * cp,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn busy_flight() -> Trajectory {
        Trajectory::Flight {
            position_m: [1.0, -0.5, -1.2],
            rpy_deg: [2.0, -10.0, 30.0],
            start_s: 0.5,
            leg_length_m: 4.0,
            leg_duration_s: 3.0,
            return_leg: true,
            turn_duration_s: 2.0,
            oscillation: busy_oscillation(),
        }
    }

    fn busy_oscillation() -> Oscillation {
        Oscillation {
            position_amplitude_m: [0.03, 0.02, 0.04],
            position_period_s: [2.1, 3.3, 1.7],
            attitude_amplitude_deg: [3.0, 2.0, 4.0],
            attitude_period_s: [1.9, 2.7, 3.1],
            start_s: 0.2,
            ramp_s: 1.0,
        }
    }

    /// North, then east sinking 0.2 m (a right turn), a 1 m climb shorter than the blend (three
    /// legs blend at once) and a diagonal leg back to the start: turns of 90 then 135 deg.
    fn waypoint_walk(oscillation: Oscillation) -> Trajectory {
        Trajectory::Waypoints {
            position_m: [1.0, -0.5, -1.2],
            rpy_deg: [2.0, -10.0, 30.0],
            start_s: 0.5,
            waypoints_m: vec![
                [3.0, -0.5, -1.2],
                [3.0, 1.5, -1.0],
                [3.0, 1.5, -2.0],
                [1.0, -0.5, -1.2],
            ],
            speed_mps: 0.8,
            blend_s: 1.5,
            oscillation,
        }
    }

    #[test]
    fn derivatives_match_central_differences() {
        let flight_times = [0.1, 0.7, 1.3, 2.9, 3.6, 4.4, 6.0, 8.9];
        let walk_times = [
            0.4, 0.9, 2.5, 3.3, 4.0, 5.6, 6.5, 7.1, 8.4, 10.2, 12.0, 14.0,
        ];
        for (traj, times) in [
            (busy_flight(), &flight_times[..]),
            (waypoint_walk(busy_oscillation()), &walk_times[..]),
        ] {
            assert_derivatives_match(&traj, times);
        }
    }

    fn assert_derivatives_match(traj: &Trajectory, times: &[f64]) {
        let h = 1e-5;
        for &t in times {
            let k = traj.kinematics(t);
            let (before, after) = (traj.kinematics(t - h), traj.kinematics(t + h));
            let v_fd = (after.p - before.p) / (2.0 * h);
            let a_fd = (after.v - before.v) / (2.0 * h);
            assert!((v_fd - k.v).norm() < 1e-8, "velocity at {t}");
            assert!((a_fd - k.a).norm() < 1e-7, "acceleration at {t}");
            let dq = before.q.inverse() * after.q;
            let omega_fd = dq.scaled_axis() / (2.0 * h);
            assert!((omega_fd - k.omega_body).norm() < 1e-8, "rate at {t}");
        }
    }

    #[test]
    fn stationary_body_feels_gravity_upward() {
        let traj = Trajectory::Stationary {
            position_m: [0.0; 3],
            rpy_deg: [0.0; 3],
        };
        let k = traj.kinematics(3.0);
        assert!((k.specific_force_body - Vector3::new(0.0, 0.0, -GRAVITY)).norm() < 1e-12);
        assert_eq!(k.omega_body, Vector3::zeros());
    }

    #[test]
    fn oscillation_is_exactly_still_before_its_start() {
        let traj = Trajectory::Hover {
            position_m: [0.0; 3],
            rpy_deg: [0.0, -10.0, 0.0],
            oscillation: Oscillation {
                position_amplitude_m: [0.05; 3],
                position_period_s: [3.0; 3],
                attitude_amplitude_deg: [1.0; 3],
                attitude_period_s: [4.0; 3],
                start_s: 40.0,
                ramp_s: 10.0,
            },
        };
        let k = traj.kinematics(39.9);
        assert_eq!(k.v, Vector3::zeros());
        assert_eq!(k.omega_body, Vector3::zeros());
        assert!(traj.kinematics(45.0).v.norm() > 1e-3);
    }

    #[test]
    fn flight_returns_to_start_facing_back() {
        let traj = busy_flight();
        let Trajectory::Flight { rpy_deg, .. } = &traj else {
            unreachable!()
        };
        let mut still = traj.clone();
        if let Trajectory::Flight { oscillation, .. } = &mut still {
            *oscillation = Oscillation::default();
        }
        let (p_start, _) = still.pose(0.0);
        let (p_mid, _) = still.pose(3.5);
        let (p_end, q_end) = still.pose(20.0);
        assert!(((p_mid - p_start).norm() - 4.0).abs() < 1e-12);
        assert!((p_end - p_start).norm() < 1e-12);
        let yaw_end = q_end.euler_angles().2.to_degrees();
        let expected = rpy_deg[2] + 180.0 - 360.0;
        assert!((yaw_end - expected).abs() < 1e-9, "{yaw_end}");
    }

    #[test]
    fn waypoints_cruise_at_the_speed_turn_with_the_track_and_stop_at_the_last() {
        let walk = waypoint_walk(Oscillation::default());
        // Leg 1 sets off at 0.5 s and starts blending into leg 2 at 3 s.
        let cruise = walk.kinematics(2.5);
        assert!((cruise.v - Vector3::new(0.8, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(cruise.a, Vector3::zeros());
        assert!((cruise.q.euler_angles().2.to_degrees() - 30.0).abs() < 1e-9);
        // Leg 2 (2.01 m) cruises from 4.5 s; its track heads east, 90 deg right of leg 1's.
        let second = walk.kinematics(5.0);
        assert!((second.v.norm() - 0.8).abs() < 1e-12);
        assert!((second.q.euler_angles().2.to_degrees() - 120.0).abs() < 1e-9);
        let end = walk.kinematics(30.0);
        assert!((end.p - Vector3::new(1.0, -0.5, -1.2)).norm() < 1e-12);
        assert_eq!((end.v, end.a), (Vector3::zeros(), Vector3::zeros()));
        // The vertical leg holds the yaw; from east to south-west is 135 deg right.
        let yaw_end = end.q.euler_angles().2.to_degrees();
        assert!(
            (yaw_end - (30.0 + 90.0 + 135.0 - 360.0)).abs() < 1e-9,
            "{yaw_end}"
        );
        assert_eq!(
            walk.kinematics(0.5).v,
            Vector3::zeros(),
            "at rest until start_s"
        );
        let fastest = (0..3000)
            .map(|i| walk.kinematics(f64::from(i) * 0.01).v.norm())
            .fold(0.0, f64::max);
        assert!(
            fastest <= 0.8 + 1e-9,
            "corners are cut, never rushed: {fastest}"
        );
    }

    #[test]
    fn waypoints_need_a_speed_a_blend_and_somewhere_to_go() {
        assert_eq!(waypoint_walk(Oscillation::default()).problem(), None);
        let edit = |change: fn(&mut f64, &mut f64, &mut Vec<[f64; 3]>)| {
            let mut walk = waypoint_walk(Oscillation::default());
            let Trajectory::Waypoints {
                speed_mps,
                blend_s,
                waypoints_m,
                ..
            } = &mut walk
            else {
                unreachable!()
            };
            change(speed_mps, blend_s, waypoints_m);
            walk.problem()
        };
        assert!(edit(|speed, _, _| *speed = 0.0)
            .unwrap()
            .contains("speed_mps = 0"));
        assert!(edit(|_, blend, _| *blend = -1.0)
            .unwrap()
            .contains("blend_s = -1"));
        assert!(edit(|_, _, points| points.clear())
            .unwrap()
            .contains("waypoints_m"));
    }
}
