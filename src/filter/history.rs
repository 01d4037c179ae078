//! Ring buffer of the filter's propagated poses over the last few seconds, so a scan can be
//! deskewed with the pose at each beam's time and the odometer can be given a prior.

use std::collections::VecDeque;

use nalgebra::{UnitQuaternion, Vector3};

/// Pose of the body at time `t`: position NED and attitude body->NED.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Pose {
    pub t: f64,
    pub p: Vector3<f64>,
    pub q: UnitQuaternion<f64>,
}

#[derive(Debug, Clone)]
pub(crate) struct PoseHistory {
    poses: VecDeque<Pose>,
    capacity: usize,
}

impl PoseHistory {
    /// Allocates once; pushing never allocates afterwards.
    pub(crate) fn with_capacity(capacity: usize) -> Self {
        Self {
            poses: VecDeque::with_capacity(capacity),
            capacity,
        }
    }

    /// Appends a pose newer than every stored one, dropping the oldest when full.
    pub(crate) fn push(&mut self, pose: Pose) {
        if self.poses.len() == self.capacity {
            self.poses.pop_front();
        }
        self.poses.push_back(pose);
    }

    /// Removes the newest pose (replaced after a measurement update at the same time).
    pub(crate) fn pop_newest(&mut self) {
        self.poses.pop_back();
    }

    /// Applies a measurement update's correction to every stored pose: `rotation` (NED) turns
    /// each attitude and the positions about the newest pose, then `shift` moves them all, so
    /// the newest lands on the corrected state and relative motion is kept.
    pub(crate) fn correct(&mut self, shift: &Vector3<f64>, rotation: &UnitQuaternion<f64>) {
        let Some(anchor) = self.poses.back().map(|pose| pose.p) else {
            return;
        };
        for pose in &mut self.poses {
            pose.p = anchor + rotation * (pose.p - anchor) + shift;
            pose.q = rotation * pose.q;
        }
    }

    /// Time span covered, oldest to newest.
    pub(crate) fn span(&self) -> Option<(f64, f64)> {
        Some((self.poses.front()?.t, self.poses.back()?.t))
    }

    /// Pose at `t` by linear interpolation of position and slerp of attitude between the two
    /// stored poses around it; `None` outside the stored span (no extrapolation).
    pub(crate) fn pose_at(&self, t: f64) -> Option<Pose> {
        let (oldest, newest) = self.span()?;
        if !(t >= oldest && t <= newest) {
            return None;
        }
        let after = self.poses.partition_point(|pose| pose.t < t);
        let b = self.poses[after];
        if after == 0 || b.t == t {
            return Some(Pose { t, ..b });
        }
        let a = self.poses[after - 1];
        let s = (t - a.t) / (b.t - a.t);
        Some(Pose {
            t,
            p: a.p.lerp(&b.p, s),
            q: a.q.slerp(&b.q, s),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_inside_and_refuses_outside_and_forgets_the_oldest() {
        let mut history = PoseHistory::with_capacity(3);
        for k in 0..4 {
            let t = k as f64;
            history.push(Pose {
                t,
                p: Vector3::new(t, 0.0, 0.0),
                q: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.1 * t),
            });
        }
        assert_eq!(history.span(), Some((1.0, 3.0)));
        let pose = history.pose_at(2.25).unwrap();
        assert!((pose.p.x - 2.25).abs() < 1e-12);
        assert!((pose.q.euler_angles().2 - 0.225).abs() < 1e-12);
        assert_eq!(history.pose_at(3.0).unwrap().p.x, 3.0);
        assert!(history.pose_at(0.5).is_none());
        assert!(history.pose_at(3.1).is_none());
        assert!(history.pose_at(f64::NAN).is_none());
    }

    #[test]
    fn a_correction_moves_every_pose_and_keeps_the_relative_motion() {
        let mut history = PoseHistory::with_capacity(4);
        for k in 0..3 {
            let t = k as f64;
            history.push(Pose {
                t,
                p: Vector3::new(t, 0.5 * t, 0.0),
                q: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.1 * t),
            });
        }
        let relative = |h: &PoseHistory| {
            let (a, b) = (h.pose_at(0.5).unwrap(), h.pose_at(2.0).unwrap());
            (a.q.inverse() * b.q, a.q.inverse() * (b.p - a.p))
        };
        let before = relative(&history);
        let shift = Vector3::new(0.01, -0.02, 0.005);
        let turn = UnitQuaternion::from_euler_angles(0.001, -0.002, 0.003);
        let newest = history.pose_at(2.0).unwrap();
        history.correct(&shift, &turn);
        let corrected = history.pose_at(2.0).unwrap();
        assert!((corrected.p - (newest.p + shift)).norm() < 1e-12);
        assert!((corrected.q.angle_to(&(turn * newest.q))) < 1e-12);
        let after = relative(&history);
        assert!(before.0.angle_to(&after.0) < 1e-12);
        assert!((before.1 - after.1).norm() < 1e-12);
    }
}
