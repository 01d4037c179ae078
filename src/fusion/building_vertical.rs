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
        let mut surfaces: Vec<(bool, [LevelDirection; 2])> = planes
            .iter()
            .filter(|plane| plane.crossing && !plane.normal_assumed)
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

fn best_variance(surface: &[LevelDirection; 2]) -> f64 {
    surface[0].variance.min(surface[1].variance)
}
