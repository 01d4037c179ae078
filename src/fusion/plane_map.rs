//! The plane map's bookkeeping (docs/design.md, 4.11 "Plane map"): which of an epoch's lines
//! lie on which mapped surface, which surfaces the epoch's planes add, and which surfaces leave.
//! The surfaces' parameters and uncertainty are states of the filter (`filter::map_states`);
//! this keeps what the filter does not need: where on its plane each surface has been seen, how
//! often, and since when.

use nalgebra::{Matrix3, Matrix3x2, Vector2, Vector3};
use serde::Serialize;

use crate::filter::map_states::Surface;
use crate::filter::{Eskf, MapLine, Pose, SurfaceAllowance, SurfacePlacement};
use crate::odometry::planes::Plane;
use crate::odometry::{tangent_basis, MapConfig};

/// A line that lies on a mapped surface by the association test, or why none.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Association {
    On(u64),
    /// On no surface: free to place a new one.
    Free,
    /// Two surfaces that are not one fit it equally well: left out.
    Ambiguous,
}

/// Where on its plane a surface has been seen: a box in two fixed directions of the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Extent {
    axes: Matrix3x2<f64>,
    low: Vector2<f64>,
    high: Vector2<f64>,
}

impl Extent {
    fn of_segment(axes: Matrix3x2<f64>, ends: [Vector3<f64>; 2]) -> Self {
        let [a, b] = ends.map(|end| axes.transpose() * end);
        Self {
            axes,
            low: a.inf(&b),
            high: a.sup(&b),
        }
    }

    fn grow(&mut self, ends: [Vector3<f64>; 2]) {
        for end in ends {
            let at = self.axes.transpose() * end;
            self.low = self.low.inf(&at);
            self.high = self.high.sup(&at);
        }
    }

    /// Whether the segment `ends` comes within `margin` of the box on both axes, widened by
    /// three sigmas of the position along each: where the body may be, the segment may be.
    fn near(&self, ends: [Vector3<f64>; 2], margin: f64, position: &Matrix3<f64>) -> bool {
        let [a, b] = ends.map(|end| self.axes.transpose() * end);
        (0..2).all(|k| {
            let axis = self.axes.column(k);
            let reach = margin + 3.0 * axis.dot(&(position * axis)).max(0.0).sqrt();
            a[k].min(b[k]) <= self.high[k] + reach && a[k].max(b[k]) >= self.low[k] - reach
        })
    }

    /// The normal of the plane the box lies in (as placed).
    fn normal(&self) -> Vector3<f64> {
        self.axes.column(0).cross(&self.axes.column(1))
    }

    /// How far the box reaches up and down, m.
    fn vertical_spread(&self) -> f64 {
        let heights = [
            self.low,
            self.high,
            Vector2::new(self.low.x, self.high.y),
            Vector2::new(self.high.x, self.low.y),
        ]
        .map(|corner| (self.axes * corner).z);
        let (low, high) = heights
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), z| {
                (l.min(*z), h.max(*z))
            });
        high - low
    }

    /// Distance from `point` (in the plane's coordinates) to the box.
    fn distance_to(&self, point: &Vector3<f64>) -> f64 {
        let at = self.axes.transpose() * point;
        let outside = (self.low - at)
            .sup(&(at - self.high))
            .sup(&Vector2::zeros());
        outside.norm()
    }
}

/// What placed a surface.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SurfaceOrigin {
    /// A plane of two lines seen at once.
    Pair,
    /// One line a building's floor, ceiling or wall must carry (`level_lines`, `wall_lines`).
    OneLine,
}

/// What the map keeps of a surface beside its states in the filter.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Mapped {
    id: u64,
    origin: SurfaceOrigin,
    placed_s: f64,
    last_seen_s: f64,
    /// Lines fused on it after the ones that placed it: the constraints it gave.
    lines_fused: u64,
    extent: Extent,
    /// What it must show before it may alone face a direction (`Standing`).
    standing: Standing,
    /// The nearest and furthest the body has seen it from, along its normal, m.
    seen_across: [f64; 2],
}

/// What a surface must show before its lines may alone tell the filter a direction
/// (`fusion/witnesses.rs` argues the same for the pairs' planes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Standing {
    /// Static by its kind: two crossing lines show they lie on one surface, and a wide one (a
    /// wall, not a door, a person or a carried board) or, in a building, a level one stands
    /// still.
    Static,
    /// Believed alone where the prediction knows its offset well enough to see it move: a
    /// narrow surface, one of parallel lines, or a floor from one level line.
    Checked,
    /// Believed only beside another surface facing the same way: a wall from one line. Its
    /// normal is assumed, and a floor or ceiling line taken for a wall makes a plane that moves
    /// with the body, which no prediction tells from a wall while the body creeps along it.
    Corroborated,
}

/// How a new surface's standing is judged.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Trust {
    pub min_extent_m: f64,
    pub building: Option<crate::odometry::planes::Building>,
}

impl Trust {
    pub(crate) fn standing(&self, plane: &Plane) -> Standing {
        let level = self.building.is_some_and(|b| b.is_level(&plane.normal));
        match (plane.normal_assumed, plane.crossing) {
            (true, _) if !level => Standing::Corroborated,
            (false, true) if plane.extent_m >= self.min_extent_m || level => Standing::Static,
            _ => Standing::Checked,
        }
    }
}

/// A mapped surface as epochs.jsonl shows it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SurfaceRecord {
    pub id: u64,
    pub origin: SurfaceOrigin,
    /// What it must show to face a direction alone, as it stands now.
    pub standing: Standing,
    /// Unit normal and distance (`normal . x = distance`, x NED).
    pub normal: [f64; 3],
    pub distance: f64,
    /// Sigmas of its normal (rad, the larger turn) and distance (m).
    pub sigma_normal_rad: f64,
    pub sigma_distance_m: f64,
    pub lines_fused: u64,
    /// The corners of where it has been seen (NED), for drawing.
    pub seen_from: [f64; 3],
    pub seen_to: [f64; 3],
}

/// How far up its height a wall from one line must be seen before it may be checked by the
/// prediction alone (`Standing`), m.
const CORROBORATING_SPREAD_M: f64 = 0.3;

/// A line that leaves a surface's plane by more than this (the sine of about 11 degrees) is
/// not tried on it: beyond any attitude doubt the gate would accept, and most of an epoch's
/// lines against most surfaces (a floor line against a wall) end there, before the chi-square.
const MAX_TILT_OUT_OF_PLANE: f64 = 0.2;

/// Surfaces agreeing this closely where a line lies are one surface placed twice.
const DUPLICATE_COSINE: f64 = 0.9994; // 2 degrees
const DUPLICATE_DISTANCE_M: f64 = 0.05;
/// A line fits one surface clearly better than another when its chi-square is lower by this.
const CLEARLY_BETTER_CHI2: f64 = 9.0;

/// The plane map's bookkeeping.
#[derive(Debug, Clone, Default)]
pub(crate) struct PlaneMap {
    config: MapConfig,
    surfaces: Vec<Mapped>,
    /// What the last association dropped (`seen_from_its_side`).
    seen_from_behind: Vec<u64>,
}

impl PlaneMap {
    pub(crate) fn new(config: MapConfig) -> Self {
        Self {
            config,
            surfaces: Vec::new(),
            seen_from_behind: Vec::new(),
        }
    }

    pub(crate) fn allowance(&self) -> SurfaceAllowance {
        self.config.allowance()
    }

    /// Forgets what the filter no longer holds (it restarted, or dropped them).
    pub(crate) fn sync(&mut self, held: &[Surface]) {
        self.surfaces
            .retain(|mapped| held.iter().any(|surface| surface.id == mapped.id));
    }

    /// Which surface each line lies on, by the chi-square of its offset and tilt under the
    /// prediction, among the surfaces seen near it. A surface placed twice (two fit a line
    /// equally, and agree) is merged: the younger leaves the map.
    pub(crate) fn associate(
        &mut self,
        filter: &mut Eskf,
        lines: &[MapLine],
        pose: &Pose,
        t_ref: f64,
    ) -> Vec<Association> {
        let allowance = self.allowance();
        let Some(epoch) = filter.map_epoch(t_ref) else {
            return vec![Association::Free; lines.len()];
        };
        let position = filter.position_covariance();
        let near = |m: &&Mapped, ends| m.extent.near(ends, self.config.extent_margin_m, &position);
        let mut duplicates = Vec::new();
        let mut behind = Vec::new();
        let associations = lines
            .iter()
            .map(|line| {
                let ends = ends_in_navigation(line, pose);
                let along = pose.q.transform_vector(&line.direction);
                let toward = pose.q.transform_vector(&line.centroid);
                let (mut fits, from_behind): (Vec<Fit>, Vec<Fit>) = self
                    .surfaces
                    .iter()
                    .filter(|m| m.extent.normal().dot(&along).abs() <= MAX_TILT_OUT_OF_PLANE)
                    .filter(|m| near(m, ends))
                    .filter_map(|m| {
                        let (y, s) = filter.line_fit(line, m.id, &epoch, &allowance)?;
                        let chi2 = s.cholesky()?.solve(&y).dot(&y);
                        (chi2 <= self.config.association_gate_chi2).then_some((chi2, m.id))
                    })
                    .partition(|&(_, id)| seen_from_its_side(filter.surfaces(), id, &toward));
                behind.extend(from_behind.into_iter().map(|(_, id)| id));
                fits.sort_by(|a, b| a.0.total_cmp(&b.0));
                match fits.as_slice() {
                    [] => Association::Free,
                    [(_, only)] => Association::On(*only),
                    [(best, a), (second, _), ..] if second - best >= CLEARLY_BETTER_CHI2 => {
                        Association::On(*a)
                    }
                    [(_, a), (_, b), ..] => {
                        if same_surface(filter.surfaces(), *a, *b, &ends[0]) {
                            let (older, younger) = (a.min(b), a.max(b));
                            duplicates.push(*younger);
                            Association::On(*older)
                        } else {
                            Association::Ambiguous
                        }
                    }
                }
            })
            .collect();
        for id in duplicates {
            self.remove(filter, id);
        }
        behind.sort_unstable();
        behind.dedup();
        for &id in &behind {
            self.remove(filter, id);
        }
        self.seen_from_behind = behind;
        associations
    }

    /// The surfaces the last `associate` dropped because a line fitted them from behind.
    pub(crate) fn seen_from_behind(&self) -> &[u64] {
        &self.seen_from_behind
    }

    /// Notes that `lines` were seen on `id` from `pose` (and whether they were fused, the
    /// constraints it gave). A wall from one line that has now been seen `CORROBORATING_SPREAD_M`
    /// up its height, or from body positions that far apart along its normal, is a wall: a
    /// floor or ceiling line taken for one stays at one height, and moves with the body, so
    /// that the prediction stops putting it on the plane once the body has moved.
    pub(crate) fn seen(&mut self, id: u64, lines: &[MapLine], pose: &Pose, fused: bool) {
        let Some(mapped) = self.surfaces.iter_mut().find(|m| m.id == id) else {
            return;
        };
        mapped.last_seen_s = pose.t;
        if fused {
            mapped.lines_fused += lines.len() as u64;
        }
        for line in lines {
            mapped.extent.grow(ends_in_navigation(line, pose));
        }
        let reach = mapped.extent.normal().dot(&pose.p);
        let [near, far] = &mut mapped.seen_across;
        (*near, *far) = (near.min(reach), far.max(reach));
        let corroborated = mapped.extent.vertical_spread() >= CORROBORATING_SPREAD_M
            || *far - *near >= CORROBORATING_SPREAD_M;
        if mapped.standing == Standing::Corroborated && corroborated {
            mapped.standing = Standing::Checked;
        }
    }

    /// Places a surface for `plane` (its lines `lines`, body axes at `pose`), fitted to its
    /// lines. Returns its id, or `None` when the lines do not lie on one surface.
    pub(crate) fn place(
        &mut self,
        filter: &mut Eskf,
        plane: &Plane,
        lines: &[MapLine],
        pose: &Pose,
        trust: &Trust,
    ) -> Option<u64> {
        let placement = self.placement(plane, lines, pose);
        let id = filter
            .add_surface(&placement, lines, pose.t, &self.allowance())
            .ok()
            .flatten()?;
        let axes = tangent_basis(&placement.normal);
        let mut extent = Extent::of_segment(axes, ends_in_navigation(&lines[0], pose));
        for line in &lines[1..] {
            extent.grow(ends_in_navigation(line, pose));
        }
        self.surfaces.push(Mapped {
            id,
            origin: if plane.normal_assumed {
                SurfaceOrigin::OneLine
            } else {
                SurfaceOrigin::Pair
            },
            placed_s: pose.t,
            last_seen_s: pose.t,
            lines_fused: 0,
            extent,
            standing: trust.standing(plane),
            seen_across: [extent.normal().dot(&pose.p); 2],
        });
        Some(id)
    }

    /// A new surface through `plane`, turning about its lines' centroid, vague about what its
    /// lines will measure so that they decide it. A plane through one line cannot measure its
    /// turn about the line; that turn is the building's assumption, level or plumb to
    /// `building_sigma_deg` in the navigation frame.
    fn placement(&self, plane: &Plane, lines: &[MapLine], pose: &Pose) -> SurfacePlacement {
        let normal = pose.q.transform_vector(&plane.normal);
        let distance = plane.rho + normal.dot(&pose.p);
        let centroid = lines.iter().map(|l| l.centroid).sum::<Vector3<f64>>() / lines.len() as f64;
        let anchor = pose.q.transform_vector(&centroid) + pose.p;
        let anchor = anchor - normal * (normal.dot(&anchor) - distance);
        let vague = self.config.new_surface_sigma_deg.to_radians();
        let (basis, follows, turns) = if plane.normal_assumed {
            let along = pose.q.transform_vector(&lines[0].direction);
            let along = (along - normal * normal.dot(&along)).normalize();
            let building = self.config.building_sigma_deg.to_radians();
            (
                Matrix3x2::from_columns(&[along, normal.cross(&along)]),
                [true, false],
                [vague, building],
            )
        } else {
            (tangent_basis(&normal), [true, true], [vague, vague])
        };
        SurfacePlacement {
            normal,
            distance,
            basis,
            anchor,
            turns_follow_body: follows,
            own_covariance: Matrix3::from_diagonal(&Vector3::new(
                turns[0].powi(2),
                turns[1].powi(2),
                self.config.new_surface_sigma_m.powi(2),
            )),
        }
    }

    /// Drops surfaces unseen for `forget_after_s`, further than `max_range_m` from `position`,
    /// and beyond `max_surfaces` the ones unseen longest. Returns their ids.
    pub(crate) fn forget(
        &mut self,
        filter: &mut Eskf,
        position: &Vector3<f64>,
        t: f64,
    ) -> Vec<u64> {
        let stale = |m: &Mapped| {
            t - m.last_seen_s > self.config.forget_after_s
                || m.extent.distance_to(position) > self.config.max_range_m
        };
        let mut gone: Vec<u64> = self
            .surfaces
            .iter()
            .filter(|m| stale(m))
            .map(|m| m.id)
            .collect();
        let mut by_age: Vec<&Mapped> = self.surfaces.iter().filter(|m| !stale(m)).collect();
        by_age.sort_by(|a, b| b.last_seen_s.total_cmp(&a.last_seen_s));
        gone.extend(by_age.iter().skip(self.config.max_surfaces).map(|m| m.id));
        for &id in &gone {
            self.remove(filter, id);
        }
        gone
    }

    /// What surface `id` must show to face a direction alone.
    pub(crate) fn standing(&self, id: u64) -> Option<Standing> {
        self.surfaces
            .iter()
            .find(|m| m.id == id)
            .map(|m| m.standing)
    }

    /// Whether surface `id` shows by its own lines that it is a surface where it was placed, so
    /// that it may teach the filter a direction before the prediction can check it: placed from
    /// two lines seen at once, or seen `CORROBORATING_SPREAD_M` up its height. Seen from places
    /// apart along its normal is not enough: where nothing else faces that way the body's place
    /// along it is the prediction's, and a ceiling line taken for a wall, which moves with the
    /// body, stays where a prediction that has not seen the body move puts it (`bare-corridor`,
    /// rolled rig, seed 217: corroborated so at 67 s, and fused, it held the walk still).
    pub(crate) fn shows_itself(&self, id: u64) -> bool {
        self.surfaces.iter().find(|m| m.id == id).is_some_and(|m| {
            m.origin == SurfaceOrigin::Pair || m.extent.vertical_spread() >= CORROBORATING_SPREAD_M
        })
    }

    /// How long before `t` surface `id` was placed, s.
    pub(crate) fn age_s(&self, id: u64, t: f64) -> Option<f64> {
        self.surfaces
            .iter()
            .find(|m| m.id == id)
            .map(|m| t - m.placed_s)
    }

    pub(crate) fn remove(&mut self, filter: &mut Eskf, id: u64) {
        filter.remove_surface(id);
        self.surfaces.retain(|m| m.id != id);
    }

    /// Every mapped surface, as epochs.jsonl shows it.
    pub(crate) fn records(&self, filter: &Eskf) -> Vec<SurfaceRecord> {
        // The surfaces lie in the map's frame; the records, like the trajectory, in the
        // navigation frame.
        let origin = filter.map_origin();
        self.surfaces
            .iter()
            .filter_map(|m| {
                let surface = filter.surfaces().iter().find(|s| s.id == m.id)?;
                let sigmas = filter.surface_sigmas(m.id)?;
                let from = m.extent.axes * m.extent.low;
                let to = m.extent.axes * m.extent.high;
                let offset = surface.normal * surface.distance + origin;
                Some(SurfaceRecord {
                    id: m.id,
                    origin: m.origin,
                    standing: m.standing,
                    normal: surface.normal.into(),
                    distance: surface.distance + surface.normal.dot(&origin),
                    sigma_normal_rad: sigmas.x.max(sigmas.y),
                    sigma_distance_m: sigmas.z,
                    lines_fused: m.lines_fused,
                    seen_from: (from + offset).into(),
                    seen_to: (to + offset).into(),
                })
            })
            .collect()
    }
}

/// A surface a line fits within the association gate: the chi-square, and the surface's id.
type Fit = (f64, u64);

/// Whether a line seen `toward` (from the body to the line, navigation axes) can lie on
/// surface `id`: a surface is placed with its normal pointing away from the body, and a face
/// of anything solid is seen from its own side only. A surface a line fits from its other side
/// leaves the map: either it moved past the body (a carried board, a door) or the line is on
/// the far face of what it is a face of, a box's depth away, and neither is to be trusted.
/// Looking back down the hallway after a turn, the cabinet's far face fitted its near face's
/// surface within the prediction's 0.24 m along the hallway and set the body 0.6 m off at a
/// sigma of 6 mm (`hallway-flight` on the map). Only left out of the association, a carried
/// board's surfaces stayed in the map once it had passed the body, and one of them later
/// taught the corridor's length 0.23 m/s off (`board-corridor` at 10 Hz, seed 109).
fn seen_from_its_side(surfaces: &[Surface], id: u64, toward: &Vector3<f64>) -> bool {
    surfaces
        .iter()
        .find(|s| s.id == id)
        .is_some_and(|s| s.normal.dot(toward) > 0.0)
}

/// Whether surfaces `a` and `b` are one surface where `point` (NED) lies.
fn same_surface(surfaces: &[Surface], a: u64, b: u64, point: &Vector3<f64>) -> bool {
    let find = |id: u64| surfaces.iter().find(|s| s.id == id);
    let (Some(a), Some(b)) = (find(a), find(b)) else {
        return false;
    };
    let offset = |s: &Surface| s.normal.dot(point) - s.distance;
    a.normal.dot(&b.normal) >= DUPLICATE_COSINE
        && (offset(a) - offset(b)).abs() <= DUPLICATE_DISTANCE_M
}

/// The two ends of a line in navigation axes.
fn ends_in_navigation(line: &MapLine, pose: &Pose) -> [Vector3<f64>; 2] {
    let half = line.direction * (0.5 * line.length_m);
    [line.centroid - half, line.centroid + half].map(|end| pose.q.transform_vector(&end) + pose.p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::odometry::planes::{Building, LineRef};
    use crate::odometry::uncertainty::PlaneUncertainty;

    fn plane(normal: Vector3<f64>, crossing: bool, extent_m: f64, assumed: bool) -> Plane {
        Plane {
            id: 0,
            normal,
            rho: 2.0,
            uncertainty: PlaneUncertainty {
                normal_covariance: Matrix3::identity() * 1e-6,
                sigma_normal: 1e-3,
                sigma_rho: 3e-3,
            },
            lines: [LineRef {
                scanner: 0,
                segment: 0,
            }; 2],
            crossing,
            confirmed: false,
            extent_m,
            normal_assumed: assumed,
        }
    }

    #[test]
    fn only_crossing_wide_or_level_surfaces_stand_alone_and_one_line_walls_need_a_fellow() {
        let trust = Trust {
            min_extent_m: 1.5,
            building: Some(Building {
                down: Vector3::z(),
                max_tilt_rad: 0.05,
            }),
        };
        let outdoors = Trust {
            building: None,
            ..trust
        };
        let (wall, floor) = (Vector3::x(), Vector3::z());
        // (judged by, normal, crossing, extent, normal assumed, standing)
        let cases = [
            (trust, wall, true, 3.0, false, Standing::Static),
            (trust, floor, true, 0.5, false, Standing::Static),
            // A door, a person or a board: narrow. Parallel lines may join two surfaces.
            (trust, wall, true, 0.8, false, Standing::Checked),
            (trust, wall, false, 3.0, false, Standing::Checked),
            // One line: a floor is level by the line's kind; a wall might be a floor line.
            (trust, floor, false, 3.0, true, Standing::Checked),
            (trust, wall, false, 3.0, true, Standing::Corroborated),
            (outdoors, floor, true, 0.5, false, Standing::Checked),
        ];
        for (k, (judge, normal, crossing, extent, assumed, standing)) in
            cases.into_iter().enumerate()
        {
            let plane = plane(normal, crossing, extent, assumed);
            assert_eq!(judge.standing(&plane), standing, "case {k}");
        }
    }

    #[test]
    fn a_segment_is_near_a_surface_where_the_body_may_be() {
        let axes = tangent_basis(&Vector3::x());
        let wall = Extent::of_segment(
            axes,
            [Vector3::new(5.0, -1.0, 0.0), Vector3::new(5.0, 1.0, 0.0)],
        );
        let beyond = [Vector3::new(5.0, 2.0, 0.0), Vector3::new(5.0, 4.0, 0.0)];
        let certain = Matrix3::identity() * 1e-6;
        assert!(!wall.near(beyond, 0.5, &certain));
        assert!(wall.near(beyond, 1.2, &certain));
        // Unsure by a metre along the wall, the body may have seen the same stretch.
        let unsure_along = Matrix3::from_diagonal(&Vector3::new(1e-6, 0.25, 1e-6));
        assert!(wall.near(beyond, 0.5, &unsure_along));
    }

    #[test]
    fn a_box_reaches_up_as_far_as_its_corners() {
        let axes = tangent_basis(&Vector3::x());
        let level_line = [Vector3::new(5.0, -1.0, 0.2), Vector3::new(5.0, 1.0, 0.2)];
        let mut wall = Extent::of_segment(axes, level_line);
        assert!(wall.vertical_spread() < 1e-9);
        wall.grow([Vector3::new(5.0, 0.0, -0.3), Vector3::new(5.0, 0.5, -0.3)]);
        assert!((wall.vertical_spread() - 0.5).abs() < 1e-9);
    }
}
