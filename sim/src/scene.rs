//! The world: bounded rectangular patches in NED, some of them moving (doors, boards), and the
//! ray cast that finds the nearest patch along a beam at the beam's own time.

use nalgebra::{Unit, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// A scalar that changes with time: a door angle in degrees or a board displacement in metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Profile {
    /// `cycles` raised-cosine swings 0 -> `amplitude` -> 0, each `period_s` long, from
    /// `start_s`; exactly 0 outside them and exactly `amplitude` at each half period.
    Swing {
        start_s: f64,
        period_s: f64,
        cycles: u32,
        amplitude: f64,
    },
    /// 0 before `at_s`, `amount` from then on (the paper's one-epoch bias experiments).
    Step { at_s: f64, amount: f64 },
}

impl Motion {
    pub fn is_static(&self) -> bool {
        matches!(self, Self::Static)
    }
}

impl Profile {
    pub fn value(&self, t: f64) -> f64 {
        match *self {
            Self::Swing {
                start_s,
                period_s,
                cycles,
                amplitude,
            } => {
                let elapsed = t - start_s;
                let end = period_s * f64::from(cycles);
                if period_s <= 0.0 || elapsed <= 0.0 || elapsed >= end {
                    return 0.0;
                }
                amplitude * 0.5 * (1.0 - (TAU * elapsed / period_s).cos())
            }
            Self::Step { at_s, amount } => {
                if t >= at_s {
                    amount
                } else {
                    0.0
                }
            }
        }
    }
}

/// How a patch moves. Static patches are never re-evaluated per beam.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Motion {
    #[default]
    Static,
    /// Rotation by `angle_deg(t)` about the line through `pivot_m` along `axis` (right-handed;
    /// for a door on a vertical hinge the axis is [0, 0, 1] or [0, 0, -1]).
    Rotate {
        pivot_m: [f64; 3],
        axis: [f64; 3],
        angle_deg: Profile,
    },
    /// Translation by `distance_m(t)` along the unit `direction`.
    Translate {
        direction: [f64; 3],
        distance_m: Profile,
    },
}

/// A rectangle: `centre + a * axis_u + b * axis_v` with `|a| <= half_extents_m[0]` and
/// `|b| <= half_extents_m[1]`, at its rest position (motion displaces it from there). Its normal
/// is `axis_u x axis_v`; which side faces the sensor does not matter to the ray cast.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Patch {
    pub name: String,
    pub centre_m: [f64; 3],
    pub axis_u: [f64; 3],
    pub axis_v: [f64; 3],
    pub half_extents_m: [f64; 2],
    #[serde(default, skip_serializing_if = "Motion::is_static")]
    pub motion: Motion,
}

/// A patch placed at one instant, with orthonormal axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlacedPatch {
    pub centre: Vector3<f64>,
    pub u: Vector3<f64>,
    pub v: Vector3<f64>,
    pub normal: Vector3<f64>,
    pub half_u: f64,
    pub half_v: f64,
}

impl PlacedPatch {
    /// Distance along the unit `dir` from `origin` to the patch, if the beam hits it.
    pub fn intersect(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<f64> {
        self.intersect_before(origin, dir, f64::INFINITY)
    }

    /// Like [`Self::intersect`], but only hits nearer than `limit` (cheap rejection first).
    fn intersect_before(
        &self,
        origin: &Vector3<f64>,
        dir: &Vector3<f64>,
        limit: f64,
    ) -> Option<f64> {
        let denom = self.normal.dot(dir);
        if denom.abs() < 1e-12 {
            return None;
        }
        let to_centre = self.centre - origin;
        let s = self.normal.dot(&to_centre) / denom;
        if s <= 0.0 || s >= limit {
            return None;
        }
        let offset = dir * s - to_centre;
        (offset.dot(&self.u).abs() <= self.half_u && offset.dot(&self.v).abs() <= self.half_v)
            .then_some(s)
    }
}

impl Patch {
    /// Axis-aligned-or-not rectangle from its centre, two in-plane directions (need not be unit
    /// or exactly orthogonal: `axis_v` is orthogonalised against `axis_u`) and half extents.
    pub fn new(
        name: &str,
        centre_m: [f64; 3],
        axis_u: [f64; 3],
        axis_v: [f64; 3],
        half_extents_m: [f64; 2],
    ) -> Self {
        Self {
            name: name.to_string(),
            centre_m,
            axis_u,
            axis_v,
            half_extents_m,
            motion: Motion::Static,
        }
    }

    pub fn with_motion(mut self, motion: Motion) -> Self {
        self.motion = motion;
        self
    }

    /// Why this patch cannot be used, if it cannot.
    pub fn problem(&self) -> Option<String> {
        let u = Vector3::from(self.axis_u);
        let v = Vector3::from(self.axis_v);
        if u.norm() < 1e-9 || v.norm() < 1e-9 || u.normalize().cross(&v.normalize()).norm() < 1e-6 {
            return Some(format!(
                "patch \"{}\": axis_u and axis_v must be non-zero and not parallel",
                self.name
            ));
        }
        if !(self
            .half_extents_m
            .iter()
            .all(|h| *h > 0.0 && h.is_finite()))
        {
            return Some(format!(
                "patch \"{}\": half_extents_m must be positive",
                self.name
            ));
        }
        let direction = match self.motion {
            Motion::Static => None,
            Motion::Rotate { axis, .. } => Some(("axis", axis)),
            Motion::Translate { direction, .. } => Some(("direction", direction)),
        };
        match direction {
            Some((key, d)) if Vector3::from(d).norm() < 1e-9 => Some(format!(
                "patch \"{}\": motion {key} must be non-zero",
                self.name
            )),
            _ => None,
        }
    }

    /// The patch at rest, with orthonormal axes.
    pub fn rest(&self) -> PlacedPatch {
        let u = Vector3::from(self.axis_u).normalize();
        let v_raw = Vector3::from(self.axis_v);
        let v = (v_raw - u * u.dot(&v_raw)).normalize();
        PlacedPatch {
            centre: Vector3::from(self.centre_m),
            u,
            v,
            normal: u.cross(&v),
            half_u: self.half_extents_m[0],
            half_v: self.half_extents_m[1],
        }
    }

    pub fn is_static(&self) -> bool {
        self.motion.is_static()
    }

    /// The patch where its motion has taken it at time `t`.
    pub fn at(&self, t: f64) -> PlacedPatch {
        place(&self.rest(), &self.motion, t)
    }
}

fn place(rest: &PlacedPatch, motion: &Motion, t: f64) -> PlacedPatch {
    match *motion {
        Motion::Static => *rest,
        Motion::Rotate {
            pivot_m,
            axis,
            angle_deg,
        } => {
            let rotation = UnitQuaternion::from_axis_angle(
                &Unit::new_normalize(Vector3::from(axis)),
                angle_deg.value(t).to_radians(),
            );
            let pivot = Vector3::from(pivot_m);
            PlacedPatch {
                centre: pivot + rotation * (rest.centre - pivot),
                u: rotation * rest.u,
                v: rotation * rest.v,
                normal: rotation * rest.normal,
                ..*rest
            }
        }
        Motion::Translate {
            direction,
            distance_m,
        } => PlacedPatch {
            centre: rest.centre + Vector3::from(direction).normalize() * distance_m.value(t),
            ..*rest
        },
    }
}

/// A plane in Hesse form in some frame: points x on it satisfy `normal . x = distance`, with
/// `distance >= 0` (the normal points from the frame origin towards the plane).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruePlane {
    /// Index of the patch in `Scene::patches`.
    pub patch: usize,
    pub normal: Vector3<f64>,
    pub distance: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    pub patches: Vec<Patch>,
}

impl Scene {
    /// The six faces of a box resting on `centre_m` with `half_size_m` along its own axes, turned
    /// `yaw_deg` about NED down; all faces share `motion`. Face names are `name.+x`, `name.-x`, ...
    pub fn add_box(
        &mut self,
        name: &str,
        centre_m: [f64; 3],
        half_size_m: [f64; 3],
        yaw_deg: f64,
        motion: Motion,
    ) {
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians());
        let axes = [
            turn * Vector3::x(),
            turn * Vector3::y(),
            turn * Vector3::z(),
        ];
        let centre = Vector3::from(centre_m);
        for (face, label) in [(0usize, "x"), (1, "y"), (2, "z")] {
            let (a, b) = ((face + 1) % 3, (face + 2) % 3);
            for sign in [1.0, -1.0] {
                let face_centre = centre + axes[face] * (sign * half_size_m[face]);
                let patch = Patch::new(
                    &format!("{name}.{}{label}", if sign > 0.0 { '+' } else { '-' }),
                    round_nanometre(face_centre.into()),
                    round_nanometre(axes[a].into()),
                    round_nanometre(axes[b].into()),
                    [half_size_m[a], half_size_m[b]],
                )
                .with_motion(motion);
                self.patches.push(patch);
            }
        }
    }

    /// Every patch as a Hesse plane in the body frame of the pose (`p`, `q`: body -> NED) at `t`.
    pub fn planes_in_body(
        &self,
        t: f64,
        p: &Vector3<f64>,
        q: &UnitQuaternion<f64>,
    ) -> Vec<TruePlane> {
        self.patches
            .iter()
            .enumerate()
            .map(|(index, patch)| {
                let placed = patch.at(t);
                let normal_body = q.inverse_transform_vector(&placed.normal);
                let centre_body = q.inverse_transform_vector(&(placed.centre - p));
                let distance = normal_body.dot(&centre_body);
                let sign = if distance < 0.0 { -1.0 } else { 1.0 };
                TruePlane {
                    patch: index,
                    normal: normal_body * sign,
                    distance: distance * sign,
                }
            })
            .collect()
    }
}

/// Drops binary noise (1.2000000000000002, 6e-17) so scenario files read cleanly.
fn round_nanometre(values: [f64; 3]) -> [f64; 3] {
    values.map(|v| (v * 1e9).round() / 1e9)
}

/// A moving patch with its placement cached by the value of its motion profile, so patches at
/// rest (a closed door, a parked board) cost no more than static ones.
struct MovingPatch {
    index: usize,
    rest: PlacedPatch,
    motion: Motion,
    cached_value: f64,
    placed: PlacedPatch,
}

impl MovingPatch {
    fn at(&mut self, t: f64) -> &PlacedPatch {
        let value = match self.motion {
            Motion::Static => 0.0,
            Motion::Rotate { angle_deg, .. } => angle_deg.value(t),
            Motion::Translate { distance_m, .. } => distance_m.value(t),
        };
        if value != self.cached_value {
            self.cached_value = value;
            self.placed = place(&self.rest, &self.motion, t);
        }
        &self.placed
    }
}

/// Scene prepared for many casts: static patches placed once, moving ones placed per beam.
pub(crate) struct CastScene {
    static_patches: Vec<(usize, PlacedPatch)>,
    moving: Vec<MovingPatch>,
}

impl CastScene {
    pub(crate) fn new(scene: &Scene) -> Self {
        let mut static_patches = Vec::new();
        let mut moving = Vec::new();
        for (index, patch) in scene.patches.iter().enumerate() {
            let rest = patch.rest();
            if patch.is_static() {
                static_patches.push((index, rest));
            } else {
                moving.push(MovingPatch {
                    index,
                    rest,
                    motion: patch.motion,
                    cached_value: 0.0,
                    placed: rest,
                });
            }
        }
        Self {
            static_patches,
            moving,
        }
    }

    /// Nearest hit along the beam at time `t`: (range, patch index). `hint` carries the static
    /// patch the previous beam hit from one call to the next: trying it first makes every
    /// other patch fail the cheap "farther than the nearest hit" test.
    pub(crate) fn cast(
        &mut self,
        t: f64,
        origin: &Vector3<f64>,
        dir: &Vector3<f64>,
        hint: &mut Option<usize>,
    ) -> Option<(f64, usize)> {
        let mut nearest: Option<(f64, usize)> = None;
        let mut nearest_static = None;
        let mut limit = f64::INFINITY;
        let order = hint.iter().copied().chain(0..self.static_patches.len());
        for (position, slot) in order.enumerate() {
            if position > 0 && Some(slot) == *hint {
                continue;
            }
            let (index, placed) = &self.static_patches[slot];
            if let Some(range) = placed.intersect_before(origin, dir, limit) {
                limit = range;
                nearest = Some((range, *index));
                nearest_static = Some(slot);
            }
        }
        for moving in &mut self.moving {
            let index = moving.index;
            if let Some(range) = moving.at(t).intersect_before(origin, dir, limit) {
                limit = range;
                nearest = Some((range, index));
                nearest_static = None;
            }
        }
        *hint = nearest_static.or(*hint);
        nearest
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn swing_reaches_zero_and_full_amplitude() {
        let door = Profile::Swing {
            start_s: 2.0,
            period_s: 8.0,
            cycles: 3,
            amplitude: 90.0,
        };
        assert_eq!(door.value(0.0), 0.0);
        assert_eq!(door.value(2.0), 0.0);
        for cycle in 0..3 {
            let peak = 2.0 + 4.0 + 8.0 * f64::from(cycle);
            assert!((door.value(peak) - 90.0).abs() < 1e-12);
            assert!(door.value(peak + 4.0).abs() < 1e-12);
        }
        assert_eq!(door.value(26.5), 0.0, "closed after the last cycle");
        let max = (0..3000)
            .map(|i| door.value(f64::from(i) * 0.01))
            .fold(f64::MIN, f64::max);
        assert!(max <= 90.0 && max > 89.99);
    }

    #[test]
    fn hinged_door_swings_about_its_hinge() {
        // Door in the plane y = 1, hinge at x = 0, opening towards -y about NED down.
        let door = Patch::new(
            "door",
            [0.45, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.45, 1.0],
        )
        .with_motion(Motion::Rotate {
            pivot_m: [0.0, 1.0, 0.0],
            axis: [0.0, 0.0, -1.0],
            angle_deg: Profile::Step {
                at_s: 1.0,
                amount: 90.0,
            },
        });
        let open = door.at(1.0);
        assert!((open.centre - Vector3::new(0.0, 0.55, 0.0)).norm() < 1e-12);
        assert!((open.normal.abs() - Vector3::x()).norm() < 1e-12);
        assert_eq!(door.at(0.5), door.rest());
    }

    #[test]
    fn ray_hits_inside_and_misses_outside_the_rectangle() {
        let wall = Patch::new(
            "wall",
            [3.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 1.0],
        )
        .rest();
        let origin = Vector3::zeros();
        let s = wall.intersect(&origin, &Vector3::x()).unwrap();
        assert!((s - 3.0).abs() < 1e-12);
        let slanted = Vector3::new(3.0, 0.9, 0.0).normalize();
        assert!((wall.intersect(&origin, &slanted).unwrap() - 3.0f64.hypot(0.9)).abs() < 1e-12);
        assert!(wall
            .intersect(&origin, &Vector3::new(3.0, 1.1, 0.0).normalize())
            .is_none());
        assert!(
            wall.intersect(&origin, &-Vector3::x()).is_none(),
            "behind the beam"
        );
    }

    #[test]
    fn nearest_patch_wins() {
        let mut scene = Scene::default();
        scene.patches.push(Patch::new(
            "far",
            [5.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [2.0, 2.0],
        ));
        scene.patches.push(Patch::new(
            "near",
            [2.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.2, 0.2],
        ));
        let mut cast = CastScene::new(&scene);
        // A hint at the far patch must not stop the near one from winning.
        let mut hint = Some(0);
        let hit = cast.cast(0.0, &Vector3::zeros(), &Vector3::x(), &mut hint);
        assert_eq!(hit.unwrap().1, 1);
        assert_eq!(hint, Some(1));
        let beside = Vector3::new(5.0, 1.0, 0.0).normalize();
        assert_eq!(
            cast.cast(0.0, &Vector3::zeros(), &beside, &mut Some(1))
                .unwrap()
                .1,
            0
        );
    }

    #[test]
    fn box_faces_enclose_the_box() {
        let mut scene = Scene::default();
        scene.add_box(
            "crate",
            [4.0, 0.0, 0.5],
            [0.5, 0.3, 0.5],
            0.0,
            Motion::Static,
        );
        assert_eq!(scene.patches.len(), 6);
        let planes = scene.planes_in_body(0.0, &Vector3::zeros(), &UnitQuaternion::identity());
        let distances: Vec<f64> = planes.iter().map(|p| p.distance).collect();
        let expected = [4.5, 3.5, 0.3, 0.3, 1.0, 0.0];
        for (d, e) in distances.iter().zip(expected) {
            assert!((d - e).abs() < 1e-12, "{distances:?}");
        }
    }
}
