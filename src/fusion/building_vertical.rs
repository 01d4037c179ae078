//! A building's floors and ceilings are level, so a measured plane that is one tells the filter
//! where the vertical is. The relative poses only carry the vertical from one epoch to the next,
//! and a start in motion knows it to degrees from an accelerometer that also felt the motion:
//! until the velocity along every axis is observed nothing else pins it, gravity leaks the error
//! into the velocity, and single-line planes, whose normals the vertical sets, stay off
//! (`odometry/level_lines.rs`, `wall_lines.rs`).
//!
//! Only where the filter's tilt is less certain than `RELIABLE_TILT_SIGMA_RAD` does a floor
//! speak: its slope is the same error every epoch it is seen, and fused at every epoch it would
//! count as fresh evidence and make the tilt overconfident.
//!
//! A floor needs a second witness: another level surface that agrees, the walls it stands
//! square to, or a third line that confirms it (`is_corroborated`, `is_square_to_the_walls`).
//!
//! Walls are plumb too, but a wall tells one tilt axis, and the open room started still (the
//! paper's rig, seed 118 of the honest-velocity study) showed why that is not enough: with the
//! roll held by its walls and the pitch unobserved, the filter declared itself converged on a
//! pitch 26 mrad off and sent 0.24 m/s errors with sigmas of 0.08 m/s.

use nalgebra::Vector3;

use super::record::UpdateSummary;
use super::Fusion;
use crate::filter::LevelDirection;
use crate::odometry::planes::{Building, Plane};
use crate::odometry::tangent_basis;

/// How far a building's floors and ceilings are from level (rad, one sigma): a few millimetres
/// over a metre.
const LEVEL_SIGMA_RAD: f64 = 0.003;
/// The filter's tilt sigma about an axis (rad) above which a level surface measures it: the
/// surface then holds it to about its own level sigma.
const RELIABLE_TILT_SIGMA_RAD: f64 = 0.005;

impl Fusion {
    /// Fuses the level directions of the epoch's measured floors and ceilings along the tilt
    /// axes the filter has lost, if the scene is a building: one surface at a time, best first,
    /// so that the gate refuses one that is not level after all without its fellows.
    pub(super) fn level_from_building(&mut self, planes: &[Plane]) -> Vec<UpdateSummary> {
        if self.filter.largest_tilt_sigma() <= RELIABLE_TILT_SIGMA_RAD {
            return Vec::new();
        }
        let down = self
            .filter
            .state()
            .q
            .inverse_transform_vector(&Vector3::z());
        let Some(building) = self.odometer.config().building(Some(down)) else {
            return Vec::new();
        };
        let building = building.judged_by(self.filter.tilt_sigma());
        let measured = || {
            planes
                .iter()
                .filter(|plane| plane.crossing && !plane.normal_assumed)
        };
        let level: Vec<&Plane> = measured()
            .filter(|plane| building.is_level(&plane.normal))
            .collect();
        let walls: Vec<&Plane> = measured()
            .filter(|plane| building.is_plumb(&plane.normal))
            .collect();
        let mut surfaces: Vec<(bool, [LevelDirection; 2])> = level
            .iter()
            .filter(|plane| {
                plane.confirmed
                    || is_corroborated(plane, &level)
                    || is_square_to_the_walls(plane, &walls)
            })
            .filter_map(|plane| Some((plane.confirmed, level_directions(plane, &building)?)))
            .collect();
        // The first surface fused sets the tilt, and the rest only check it. Two lines that
        // cross lie in one plane whatever surfaces they are on: a front-wall line and a floor
        // line near the wall's foot made a "floor" 3 deg off level that a start in motion took
        // first (`random-room-57`), and the true floor, refused by the gate four epochs running,
        // then turned the tilt back at a rate the filter read as 11 mrad/s of gyro bias. A
        // third line lying in the plane shows it is one surface, so confirmed planes go first.
        surfaces.sort_by(|(confirmed_a, a), (confirmed_b, b)| {
            confirmed_b
                .cmp(confirmed_a)
                .then(best_variance(a).total_cmp(&best_variance(b)))
        });
        let mut updates = Vec::new();
        for (_, surface) in &surfaces {
            let lost: Vec<LevelDirection> = surface
                .iter()
                .filter(|d| self.filter.tilt_sigma_along(&d.body) > RELIABLE_TILT_SIGMA_RAD)
                .copied()
                .collect();
            if lost.is_empty() {
                continue;
            }
            match self.filter.update_level_directions(&lost) {
                Ok(report) => updates.push((&report).into()),
                Err(_) => break,
            }
        }
        updates
    }
}

/// The two body directions a level plane holds level, if the building takes it for a floor or
/// a ceiling, each with the variance of its sine against the true vertical: the plane's normal
/// error along it and the building's. They are the principal axes of the normal's error within
/// the plane, so that their noises are independent.
fn level_directions(plane: &Plane, building: &Building) -> Option<[LevelDirection; 2]> {
    if !building.is_level(&plane.normal) {
        return None;
    }
    let tangents = tangent_basis(&plane.normal);
    // A tilt of the normal along a tangent moves `tangent . down` by as much.
    let error =
        (tangents.transpose() * plane.uncertainty.normal_covariance * tangents).symmetric_eigen();
    Some([0, 1].map(|k| LevelDirection {
        body: tangents * error.eigenvectors.column(k),
        variance: error.eigenvalues[k].max(0.0) + LEVEL_SIGMA_RAD * LEVEL_SIGMA_RAD,
    }))
}

/// Whether another level surface of the epoch lies as `plane` does, within their normals'
/// sigmas and the building's unevenness. Two crossing lines lie in one plane whatever
/// surfaces they are on, and under a start in motion's tilt sigma (3 deg) the building takes a
/// plane several degrees off level for a floor: in `random-room-99` a "table top" 45 mrad off
/// level set the tilt 1.3 s after the start, and gravity ran the velocity off at 0.44 m/s^2
/// along the direction the walls left free. A floor beside a ceiling, or a table top beside
/// the floor, vouch for each other; a plane a third line confirms vouches for itself. Width
/// is no witness: the "table top" was wider than the 1.5 m that makes a lone plane static.
fn is_corroborated(plane: &Plane, level: &[&Plane]) -> bool {
    level.iter().any(|other| {
        let apart = plane.normal.dot(&other.normal).abs().min(1.0).acos();
        !std::ptr::eq(*other, plane) && apart <= CORROBORATION_SIGMAS * pair_sigma(plane, other)
    })
}

/// Whether the epoch has walls and `plane` stands square to each of them, within their
/// sigmas and the building's unevenness. A hallway's floor is often its only level surface,
/// and its walls check it about their normals; the "table top" of `random-room-99` leant 52
/// mrad off square to a wall beside it.
fn is_square_to_the_walls(plane: &Plane, walls: &[&Plane]) -> bool {
    !walls.is_empty()
        && walls.iter().all(|wall| {
            let off_square = plane.normal.dot(&wall.normal).abs().min(1.0).asin();
            off_square <= CORROBORATION_SIGMAS * pair_sigma(plane, wall)
        })
}

/// The sigma of the angle between two surfaces' normals that a building holds level or plumb.
fn pair_sigma(a: &Plane, b: &Plane) -> f64 {
    (a.uncertainty.sigma_normal.powi(2)
        + b.uncertainty.sigma_normal.powi(2)
        + 2.0 * LEVEL_SIGMA_RAD * LEVEL_SIGMA_RAD)
        .sqrt()
}

/// How many sigmas apart two surfaces may lie and still vouch for each other. Two, not three:
/// a floor refused costs an epoch, and the next offers it again; a leaning plane taken costs
/// the vertical (`random-room-103`: a plane 14-24 mrad off level beside the floor stood 10-15
/// mrad off square to its walls, within three sigmas).
const CORROBORATION_SIGMAS: f64 = 2.0;

fn best_variance(surface: &[LevelDirection; 2]) -> f64 {
    surface[0].variance.min(surface[1].variance)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::odometry::planes::LineRef;
    use crate::odometry::uncertainty::PlaneUncertainty;
    use nalgebra::{Matrix3, UnitQuaternion};

    fn crossing(normal: Vector3<f64>) -> Plane {
        let line = LineRef {
            scanner: 0,
            segment: 0,
        };
        let uncertainty = PlaneUncertainty {
            normal_covariance: Matrix3::zeros(),
            sigma_normal: 0.002,
            sigma_rho: 0.005,
        };
        Plane {
            crossing: true,
            ..Plane::through_one_line(line, normal, 2.0, uncertainty, 2.0)
        }
    }

    fn leaning(normal: Vector3<f64>, about: Vector3<f64>, rad: f64) -> Vector3<f64> {
        UnitQuaternion::from_scaled_axis(about * rad) * normal
    }

    #[test]
    fn a_level_surface_needs_a_second_witness() {
        let floor = crossing(Vector3::z());
        let walls = [crossing(Vector3::x()), crossing(Vector3::y())];
        let walls: Vec<&Plane> = walls.iter().collect();
        // A floor square to the walls, or beside a ceiling that agrees, is a floor.
        assert!(is_square_to_the_walls(&floor, &walls));
        let ceiling = crossing(-Vector3::z());
        assert!(is_corroborated(&floor, &[&floor, &ceiling]));
        // A "table top" leaning 45 mrad is disowned by the wall it leans towards and by the
        // ceiling, and is no witness of itself.
        let table_top = crossing(leaning(Vector3::z(), Vector3::x(), 0.045));
        assert!(!is_square_to_the_walls(&table_top, &walls));
        assert!(!is_corroborated(&table_top, &[&table_top, &ceiling]));
        assert!(!is_corroborated(&table_top, &[&table_top]));
        // With no wall in sight, nothing squares it.
        assert!(!is_square_to_the_walls(&floor, &[]));
    }
}
