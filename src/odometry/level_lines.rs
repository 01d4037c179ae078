//! Level planes from a single line, in a building. With the paper's rig the pitched scanner
//! alone sees the floor within a few metres, and the level one sees the walls: no floor plane
//! is ever built from a pair, and the vertical goes unobserved with the motion along the room.
//! A floor is level, so one level line on it is enough to place it: the plane through the line
//! whose normal is the building's vertical (`Building::down`).
//!
//! A level line alone could as well lie on a wall facing the platform (both scan planes meet a
//! wall ahead along a level line). A wall reaches up past every scanner, so the scanner whose
//! beams look higher would meet it at the same horizontal distance or nearer; a level line that
//! every other scanner's beams overshoot in its bearing lies on a floor, a table top or a low
//! shelf, all level, or on the face of something lower than the other beams (then it moves
//! against the other planes, and integrity, or the filter's prediction, says so).
//!
//! Such a plane's normal is the filter's vertical, not a measurement: it tells the displacement
//! along the vertical and nothing about the rotation (`Plane::normal_assumed`).

use nalgebra::{Matrix3, Vector3};

use super::planes::{Building, LineRef, Plane, ScanLines};
use super::uncertainty::PlaneUncertainty;

/// How a level line becomes a plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LevelLineParameters {
    pub building: Building,
    /// A line this close to the body origin's level (m) may be anything.
    pub min_depth_m: f64,
    /// What the other scanner's beams must do for the line not to be on a wall.
    pub overshoot: Overshoot,
    /// How far from level a building's floors are taken to be, rad: the plane's normal sigma.
    pub tilt_sigma_rad: f64,
}

/// Appends to `out` a level plane for each line not in `used` that is level, below or above
/// the body origin by `min_depth_m` or more, and overshot by every other scanner's beams in its
/// bearing; `admit` may refuse it (the keyframe's confirmation). Marks the lines it takes in
/// `used`.
pub(crate) fn level_planes(
    scans: &[ScanLines; 2],
    used: &mut [Vec<bool>; 2],
    parameters: &LevelLineParameters,
    admit: &mut dyn FnMut(&Plane) -> bool,
    out: &mut Vec<Plane>,
) {
    for (scanner, scan) in scans.iter().enumerate() {
        for (segment, line) in scan.segments.iter().enumerate() {
            if used[scanner].get(segment).copied().unwrap_or(true) {
                continue;
            }
            let Some(mut plane) = level_plane(scans, scanner, segment, parameters) else {
                continue;
            };
            plane.id = out.len();
            if line.points() >= 2 && admit(&plane) {
                used[scanner][segment] = true;
                out.push(plane);
            }
        }
    }
}

fn level_plane(
    scans: &[ScanLines; 2],
    scanner: usize,
    segment: usize,
    parameters: &LevelLineParameters,
) -> Option<Plane> {
    let building = &parameters.building;
    let down = building.down;
    let line = &scans[scanner].segments[segment];
    if line.direction.dot(&down).abs() > building.max_tilt_rad.sin() {
        return None;
    }
    let depth = line.centroid.dot(&down);
    if depth.abs() < parameters.min_depth_m {
        return None;
    }
    let reach = (line.centroid - down * depth).norm();
    if !parameters
        .overshoot
        .passes(&scans[1 - scanner], &down, &line.centroid)
    {
        return None;
    }
    let normal = down * depth.signum();
    let range_sigma = scans[scanner].range_sigma;
    // The centroid's noise along the vertical, and the filter's vertical off by the tilt sigma
    // over the line's horizontal reach.
    let sigma_rho = ((range_sigma * range_sigma) / line.points() as f64
        + (reach * parameters.tilt_sigma_rad).powi(2))
    .sqrt();
    let tangent = Matrix3::identity() - normal * normal.transpose();
    let uncertainty = PlaneUncertainty {
        normal_covariance: tangent * parameters.tilt_sigma_rad.powi(2),
        sigma_normal: parameters.tilt_sigma_rad * std::f64::consts::SQRT_2,
        sigma_rho,
    };
    Some(Plane::through_one_line(
        LineRef { scanner, segment },
        normal,
        depth.abs(),
        uncertainty,
        line.length,
    ))
}

/// How the other scanner's beams show that a level line lies on a level surface (module
/// doc): each of them in the line's bearing reaches past it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Overshoot {
    /// How much further out (m, horizontally) each beam must reach.
    pub margin_m: f64,
    /// Half-width of the bearing the beams are looked for in, radians.
    pub bearing_half_width_rad: f64,
}

impl Overshoot {
    /// Whether `scan` has beams in the bearing of `point` (body axes, seen from the body
    /// origin along the level) and every one of them reaches `margin_m` beyond it.
    pub(crate) fn passes(
        &self,
        scan: &ScanLines,
        down: &Vector3<f64>,
        point: &Vector3<f64>,
    ) -> bool {
        let horizontal = point - down * point.dot(down);
        let reach = horizontal.norm();
        if reach <= f64::EPSILON {
            return false;
        }
        let mut seen = false;
        for (level, _) in
            scan.beams_in_bearing(*down, horizontal / reach, self.bearing_half_width_rad)
        {
            if level.norm() < reach + self.margin_m {
                return false;
            }
            seen = true;
        }
        seen
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::odometry::deskew::Beam;
    use crate::odometry::lines::Segment;
    use crate::odometry::single_line_fixtures::{beam, line};

    /// A level floor line 1.5 m below the body origin and 1.8 m ahead, along body y (the
    /// pitched scanner's, scanner 1); scanner 0's beams reach `ahead_m` straight ahead.
    struct Scene {
        segments: [Vec<Segment>; 2],
        beams: [Vec<Beam>; 2],
    }

    impl Scene {
        fn new(floor_direction: Vector3<f64>, ahead_m: f64) -> Self {
            let floor = line(Vector3::new(1.8, 0.0, 1.5), floor_direction, 2.0);
            let fan = (-5..=5)
                .map(|k| beam(Vector3::new(ahead_m, 0.05 * f64::from(k), 0.2)))
                .collect();
            Self {
                segments: [Vec::new(), vec![floor]],
                beams: [fan, Vec::new()],
            }
        }

        fn planes(&self) -> Vec<Plane> {
            let scans = [0, 1].map(|k| ScanLines {
                segments: &self.segments[k],
                beams: &self.beams[k],
                range_sigma: 0.01,
            });
            let mut used = [vec![false; 0], vec![false; 1]];
            let parameters = LevelLineParameters {
                building: Building {
                    down: Vector3::z(),
                    max_tilt_rad: 3f64.to_radians(),
                },
                min_depth_m: 0.3,
                overshoot: Overshoot {
                    margin_m: 0.3,
                    bearing_half_width_rad: 10f64.to_radians(),
                },
                tilt_sigma_rad: 0.003,
            };
            let mut out = Vec::new();
            level_planes(&scans, &mut used, &parameters, &mut |_| true, &mut out);
            out
        }
    }

    #[test]
    fn a_level_line_the_other_scanner_overshoots_is_a_level_plane_with_an_assumed_normal() {
        let planes = Scene::new(Vector3::y(), 5.0).planes();
        assert_eq!(planes.len(), 1);
        let floor = &planes[0];
        assert_eq!(floor.normal, Vector3::z());
        assert!((floor.rho - 1.5).abs() < 1e-12);
        assert!(floor.normal_assumed && !floor.crossing);
        // The vertical off by the tilt sigma over the line's 1.8 m reach dominates.
        assert!((floor.uncertainty.sigma_rho - 1.8 * 0.003).abs() < 1e-3);
    }

    #[test]
    fn a_level_line_the_other_scanner_meets_as_near_may_be_a_wall_and_is_left_out() {
        assert!(Scene::new(Vector3::y(), 1.9).planes().is_empty());
    }

    #[test]
    fn a_sloping_line_or_one_nothing_else_looks_past_is_left_out() {
        assert!(Scene::new(Vector3::new(0.0, 1.0, 0.2), 5.0)
            .planes()
            .is_empty());
        let mut unseen = Scene::new(Vector3::y(), 5.0);
        unseen.beams[0].clear();
        assert!(unseen.planes().is_empty());
    }
}
