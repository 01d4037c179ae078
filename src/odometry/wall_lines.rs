//! Plumb planes from a single line, in a building. With the paper's rig in a room the level
//! scanner alone sees the walls ahead and behind, and the pitched one only the floor in front:
//! no pair ever makes the end walls' planes, and the motion along the room goes unobserved.
//! A wall is plumb, so one line on it places it: the plane through the line whose normal is
//! level and square to the line.
//!
//! A line that slopes against the building's level cannot lie on a floor or a ceiling, so in a
//! building it lies on a wall. A level line could lie on a floor as well: it is taken for a
//! wall only when every beam of the other scanner in its bearing ends further from the body's level
//! (below a line under the body, above one over it) and no further out, which a floor (the
//! lowest surface there is) or a ceiling never shows, and only when it is longer than a table is
//! deep. What still passes wrongly (the edge of a long shelf's top) moves against the
//! other planes as the platform bobs, and integrity, or the filter's prediction, says so.
//!
//! Such a plane's normal comes from the filter's vertical and the line, not from a measurement:
//! it tells the displacement along the normal and nothing about the rotation
//! (`Plane::normal_assumed`).

use nalgebra::Vector3;

use super::lines::Segment;
use super::planes::{Building, LineRef, Plane, ScanLines};
use super::uncertainty::PlaneUncertainty;

/// How a single line becomes a plumb plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct WallLineParameters {
    pub building: Building,
    /// Lines steeper than this against the level, radians, are left out: the level normal
    /// square to them is ill-defined.
    pub max_slope_rad: f64,
    /// A level line must be at least this long (m) to be taken for a wall.
    pub min_level_length_m: f64,
    /// The other scanner's beams in a level line's bearing must end further from the body's
    /// level than it by three sigmas of this (m) and of the filter's vertical over the line's
    /// reach, and no further out than this beyond it: a beam's ranging and the floor's
    /// unevenness.
    pub margin_m: f64,
    /// The filter's tilt sigma, rad.
    pub vertical_sigma_rad: f64,
    /// Half-width of the bearing the other scanner's beams are looked for in, radians.
    pub bearing_half_width_rad: f64,
    /// How far from plumb a building's walls and the filter's vertical are together, rad.
    pub tilt_sigma_rad: f64,
}

/// Appends to `out` a plumb plane for each line not in `used` that a wall must carry; `admit`
/// may refuse it (the keyframe's confirmation). Marks the lines it takes in `used`.
pub(crate) fn wall_planes(
    scans: &[ScanLines; 2],
    used: &mut [Vec<bool>; 2],
    parameters: &WallLineParameters,
    admit: &mut dyn FnMut(&Plane) -> bool,
    out: &mut Vec<Plane>,
) {
    let measured = out.len();
    for (scanner, scan) in scans.iter().enumerate() {
        for segment in 0..scan.segments.len() {
            if used[scanner].get(segment).copied().unwrap_or(true) {
                continue;
            }
            let line = &scan.segments[segment];
            if out[..measured].iter().any(|plane| carries(plane, line)) {
                continue;
            }
            let Some(mut plane) = wall_plane(scans, scanner, segment, parameters) else {
                continue;
            };
            plane.id = out.len();
            if admit(&plane) {
                used[scanner][segment] = true;
                out.push(plane);
            }
        }
    }
}

/// Whether a plane of the epoch already holds `line`: a surface that a pair measured gains
/// little from an assumed plane through another of its lines, and the two share the surface's
/// unevenness and the scan's deskew, which their sigmas would count twice.
fn carries(plane: &Plane, line: &Segment) -> bool {
    !plane.normal_assumed
        && plane.normal.dot(&line.direction).abs() <= CARRIED_LINE_MAX_TILT_RAD.sin()
        && (plane.normal.dot(&line.centroid) - plane.rho).abs() <= CARRIED_LINE_MAX_OFFSET_M
}

/// A line within this of a plane's direction (rad) and of its distance (m) lies on it: a
/// few of a plane's sigmas, well short of what tells two walls apart.
const CARRIED_LINE_MAX_TILT_RAD: f64 = 0.03;
const CARRIED_LINE_MAX_OFFSET_M: f64 = 0.05;

fn wall_plane(
    scans: &[ScanLines; 2],
    scanner: usize,
    segment: usize,
    parameters: &WallLineParameters,
) -> Option<Plane> {
    let down = parameters.building.down;
    let line = &scans[scanner].segments[segment];
    if line.points() < 2 {
        return None;
    }
    let slope = line.direction.dot(&down).abs();
    if slope > parameters.max_slope_rad.sin() {
        return None;
    }
    let square = line.direction.cross(&down);
    let mut normal = square.normalize();
    let mut rho = normal.dot(&line.centroid);
    if rho < 0.0 {
        normal = -normal;
        rho = -rho;
    }
    let level = slope <= parameters.building.max_tilt_rad.sin();
    if level && !stands_clear_of_the_other_scan(scans, scanner, segment, &normal, rho, parameters) {
        return None;
    }
    // Two errors turn the plane about its centroid, each moving its distance by the turn times
    // the centroid's offset across the turn: the wall off plumb (or the filter's vertical off)
    // tilts it about the line, and the line's own direction, off within the scan, turns it
    // about the vertical.
    let range_sigma = scans[scanner].range_sigma;
    let level_share = square.norm();
    let heading_sigma = range_sigma / line.abscissa_spread.sqrt() / level_share;
    let tilt = line.direction.cross(&normal);
    let heading = down.cross(&normal);
    let tilt_sigma = parameters.tilt_sigma_rad;
    let sigma_rho = ((range_sigma * range_sigma) / line.points() as f64
        + (tilt.dot(&line.centroid) * tilt_sigma).powi(2)
        + (heading.dot(&line.centroid) * heading_sigma).powi(2))
    .sqrt();
    let normal_covariance = tilt * tilt.transpose() * tilt_sigma.powi(2)
        + heading * heading.transpose() * heading_sigma.powi(2);
    let uncertainty = PlaneUncertainty {
        normal_covariance,
        sigma_normal: normal_covariance.trace().sqrt(),
        sigma_rho,
    };
    Some(Plane::through_one_line(
        LineRef { scanner, segment },
        normal,
        rho,
        uncertainty,
        line.length,
    ))
}

/// Whether a level line is long enough for a wall and every beam of the other scanner in its
/// bearing (there must be one) ends beyond it vertically, away from the body's level, by
/// `margin_m`, and no further out than the wall it would lie on (`normal . p = rho`, as
/// `wall_plane` places it): below a line under the body,
/// nothing but the floor's own line can end at its depth; above one over the body, the
/// ceiling's. How far out a beam ends is measured along that wall's normal, not as its level
/// range: a beam ten degrees off the bearing meets the same wall 1.5 % further away, 7 cm at
/// 4.4 m, and a back wall seen again higher up would have counted as passing behind the line.
fn stands_clear_of_the_other_scan(
    scans: &[ScanLines; 2],
    scanner: usize,
    segment: usize,
    normal: &Vector3<f64>,
    rho: f64,
    parameters: &WallLineParameters,
) -> bool {
    let down = parameters.building.down;
    let line = &scans[scanner].segments[segment];
    if line.length < parameters.min_level_length_m {
        return false;
    }
    let depth = line.centroid.dot(&down);
    let horizontal = line.centroid - down * depth;
    let reach = horizontal.norm();
    if reach <= f64::EPSILON {
        return false;
    }
    let clearance = 3.0
        * parameters
            .margin_m
            .hypot(reach * parameters.vertical_sigma_rad);
    let mut seen = false;
    for (level, beam_depth) in scans[1 - scanner].beams_in_bearing(
        down,
        horizontal / reach,
        parameters.bearing_half_width_rad,
    ) {
        let beyond = (beam_depth - depth) * depth.signum();
        // A plumb wall's offset is the same at every height, up to its tilt over the rise.
        let out_tolerance = 3.0
            * parameters
                .margin_m
                .hypot((beam_depth - depth) * parameters.tilt_sigma_rad);
        if normal.dot(&level) > rho + out_tolerance || beyond < clearance {
            return false;
        }
        seen = true;
    }
    seen
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::odometry::deskew::Beam;
    use crate::odometry::lines::Segment;
    use crate::odometry::single_line_fixtures::{beam, line};
    use nalgebra::{Matrix3, Vector3};

    /// Scanner 0 lays `seen` (down is +z); scanner 1's beams end at `other_end` straight ahead.
    fn planes(seen: Segment, other_end: Option<Vector3<f64>>) -> Vec<Plane> {
        planes_beside(Vec::new(), seen, other_end)
    }

    /// As `planes`, with `measured` the planes the epoch's pairs made; returns the new ones.
    fn planes_beside(
        measured: Vec<Plane>,
        seen: Segment,
        other_end: Option<Vector3<f64>>,
    ) -> Vec<Plane> {
        let segments = [vec![seen], Vec::new()];
        let fan: Vec<Beam> = other_end
            .into_iter()
            .flat_map(|end| (-5..=5).map(move |k| beam(end + Vector3::y() * 0.05 * f64::from(k))))
            .collect();
        let beams = [Vec::new(), fan];
        let scans = [0, 1].map(|k| ScanLines {
            segments: &segments[k],
            beams: &beams[k],
            range_sigma: 0.01,
        });
        let mut used = [vec![false; 1], Vec::new()];
        let parameters = WallLineParameters {
            building: Building {
                down: Vector3::z(),
                max_tilt_rad: 3f64.to_radians(),
            },
            max_slope_rad: 60f64.to_radians(),
            min_level_length_m: 1.0,
            margin_m: 0.1,
            vertical_sigma_rad: 0.001,
            bearing_half_width_rad: 10f64.to_radians(),
            tilt_sigma_rad: 0.003,
        };
        let mut out = measured;
        let before = out.len();
        wall_planes(&scans, &mut used, &parameters, &mut |_| true, &mut out);
        assert_eq!(used[0][0], out.len() > before);
        out.split_off(before)
    }

    /// A pair's plane: normal y at `rho`.
    fn measured_wall(rho: f64) -> Plane {
        let uncertainty = PlaneUncertainty {
            normal_covariance: Matrix3::identity() * 1e-6,
            sigma_normal: 1e-3,
            sigma_rho: 1e-3,
        };
        let line = LineRef {
            scanner: 1,
            segment: 0,
        };
        Plane {
            normal_assumed: false,
            ..Plane::through_one_line(line, Vector3::y(), rho, uncertainty, 2.0)
        }
    }

    #[test]
    fn a_line_on_a_surface_a_pair_measured_makes_no_second_plane() {
        let slope = Vector3::new(1.0, 0.0, 10f64.to_radians().tan());
        let side_wall = || line(Vector3::new(1.0, 3.0, 0.2), slope, 2.0);
        assert!(planes_beside(vec![measured_wall(3.02)], side_wall(), None).is_empty());
        assert_eq!(
            planes_beside(vec![measured_wall(5.0)], side_wall(), None).len(),
            1
        );
    }

    #[test]
    fn a_sloping_line_is_a_plumb_plane_square_to_it() {
        // A side wall 3 m to the right, met by a scan plane pitched 10 degrees down.
        let slope = Vector3::new(1.0, 0.0, 10f64.to_radians().tan());
        let found = planes(line(Vector3::new(1.0, 3.0, 0.2), slope, 2.0), None);
        assert_eq!(found.len(), 1);
        let wall = &found[0];
        assert!((wall.normal - Vector3::y()).norm() < 1e-12);
        assert!((wall.rho - 3.0).abs() < 1e-12);
        assert!(wall.normal_assumed);
        // The line's direction, off within the scan (0.01 m over a spread of 10 m^2), turns the
        // wall about the vertical through the centroid, which lies 1 m along the wall from the
        // foot of the normal. Turning it about the line by the 3 mrad tilt moves it by 3 mrad
        // over the centroid's 2.3 cm offset across the line, and the centroid's own noise adds
        // 0.01 m over 40 points.
        let heading_sigma = 0.01 / 10f64.sqrt() / slope.normalize().x;
        let tilt = slope.normalize().cross(&Vector3::y());
        let tilt_lever = tilt.dot(&Vector3::new(1.0, 3.0, 0.2));
        let expected =
            (0.01f64.powi(2) / 40.0 + heading_sigma.powi(2) + (tilt_lever * 0.003).powi(2)).sqrt();
        assert!((wall.uncertainty.sigma_rho - expected).abs() < 1e-9);
        // The normal turns about the vertical (along x) by the heading sigma, and about the
        // sloping line by the tilt (mostly along z).
        let along_x = heading_sigma.powi(2) + (tilt.x * 0.003).powi(2);
        assert!((wall.uncertainty.normal_covariance[(0, 0)] - along_x).abs() < 1e-12);
    }

    #[test]
    fn a_level_line_above_where_the_other_scanner_ends_is_a_wall() {
        let wall_line = line(Vector3::new(5.0, 0.0, 0.9), Vector3::y(), 3.0);
        let found = planes(wall_line, Some(Vector3::new(1.8, 0.0, 1.5)));
        assert_eq!(found.len(), 1);
        assert!((found[0].normal - Vector3::x()).norm() < 1e-12);
        assert!((found[0].rho - 5.0).abs() < 1e-12);
    }

    #[test]
    fn a_wall_the_other_scanner_meets_higher_up_off_the_bearing_is_a_wall() {
        // A back wall 8 m away, its line 0.5 m over the body; the other scanner meets it 1.1 m
        // higher, seven to ten degrees off the line's bearing, so its beams end up to 12 cm
        // further away on the level (more than the fixture's 0.1 m margin) on the same wall.
        let back_wall = line(Vector3::new(8.0, 0.0, -0.5), Vector3::y(), 3.0);
        let found = planes(back_wall, Some(Vector3::new(8.0, 1.2, -1.6)));
        assert_eq!(found.len(), 1);
        assert!((found[0].normal - Vector3::x()).norm() < 1e-12);
    }

    #[test]
    fn a_level_line_the_other_scanner_meets_as_high_or_passes_or_misses_stays_out() {
        let on_the_floor = line(Vector3::new(5.0, 0.0, 1.5), Vector3::y(), 3.0);
        assert!(planes(on_the_floor, Some(Vector3::new(1.8, 0.0, 1.5))).is_empty());
        let overshot = line(Vector3::new(5.0, 0.0, 0.9), Vector3::y(), 3.0);
        assert!(planes(overshot, Some(Vector3::new(7.0, 0.0, 1.5))).is_empty());
        let unseen = line(Vector3::new(5.0, 0.0, 0.9), Vector3::y(), 3.0);
        assert!(planes(unseen, None).is_empty());
        let table_deep = line(Vector3::new(5.0, 0.0, 0.9), Vector3::y(), 0.8);
        assert!(planes(table_deep, Some(Vector3::new(1.8, 0.0, 1.5))).is_empty());
    }

    #[test]
    fn a_steep_line_stays_out() {
        let steep = Vector3::new(0.3, 0.0, 1.0);
        assert!(planes(line(Vector3::new(1.0, 3.0, 0.2), steep, 2.0), None).is_empty());
    }
}
