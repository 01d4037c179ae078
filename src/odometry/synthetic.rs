//! Exact ray casting in a convex room of planes, for tests, benchmarks and Monte Carlo runs
//! that need scans with known geometry without the full simulator.

use crate::sensors::{Mount, Scan, ScannerGeometry};
use nalgebra::{Isometry3, Point3, Vector3};

/// A plane of the room in world coordinates: `normal . x = rho`, normal pointing out of the room.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldPlane {
    pub normal: Vector3<f64>,
    pub rho: f64,
}

impl WorldPlane {
    pub(crate) fn new(normal: [f64; 3], rho: f64) -> Self {
        Self {
            normal: Vector3::from(normal).normalize(),
            rho,
        }
    }
}

/// A hallway-like convex room in NED around the origin: 4 m wide, 2.6 m high (origin 1.3 m above
/// the floor), end walls 5 m ahead and 3 m behind, and all four corners cut at 45 degrees.
pub fn hallway() -> Vec<WorldPlane> {
    let diagonal = std::f64::consts::FRAC_1_SQRT_2;
    vec![
        WorldPlane::new([1.0, 0.0, 0.0], 5.0),
        WorldPlane::new([-1.0, 0.0, 0.0], 3.0),
        WorldPlane::new([0.0, 1.0, 0.0], 2.0),
        WorldPlane::new([0.0, -1.0, 0.0], 2.0),
        WorldPlane::new([0.0, 0.0, 1.0], 1.3),
        WorldPlane::new([0.0, 0.0, -1.0], 1.3),
        WorldPlane::new([1.0, 1.0, 0.0], 5.5 * diagonal),
        WorldPlane::new([1.0, -1.0, 0.0], 5.5 * diagonal),
        WorldPlane::new([-1.0, 1.0, 0.0], 3.5 * diagonal),
        WorldPlane::new([-1.0, -1.0, 0.0], 3.5 * diagonal),
    ]
}

/// Two scanners crossed in roll and pitch (not mirror images, whose lines on the floor and the
/// ceiling would all be parallel), so that both draw lines on six planes of `hallway()`.
pub fn crossed_mounts() -> [Mount; 2] {
    [
        Mount::from_rpy_deg([30.0, 30.0, 0.0], [0.1, 0.0, 0.0]),
        Mount::from_rpy_deg([-30.0, -20.0, 0.0], [-0.1, 0.0, 0.0]),
    ]
}

/// One exact scan of `room` from every step AMIN..=AMAX; `body_pose(t)` maps body to world at
/// time t. A beam that leaves the room (it cannot from inside a closed convex room) reads 0.
pub fn cast_scan(
    room: &[WorldPlane],
    geometry: &ScannerGeometry,
    mount: &Mount,
    body_pose: &dyn Fn(f64) -> Isometry3<f64>,
    t0: f64,
) -> Scan {
    let mut scan = Scan {
        sensor: 0,
        t0,
        first_step: geometry.amin,
        cluster: 1,
        ranges_m: Vec::with_capacity((geometry.amax - geometry.amin + 1) as usize),
    };
    for index in 0..=(geometry.amax - geometry.amin) as usize {
        let step = scan.step_of(index);
        let pose = body_pose(scan.time_of(index, geometry));
        let origin = pose
            .transform_point(&Point3::from(mount.translation))
            .coords;
        let direction = pose.rotation * (mount.rotation * geometry.step_direction(step));
        scan.ranges_m
            .push(first_hit(room, &origin, &direction).unwrap_or(0.0));
    }
    scan
}

fn first_hit(room: &[WorldPlane], origin: &Vector3<f64>, direction: &Vector3<f64>) -> Option<f64> {
    room.iter()
        .filter(|p| p.normal.dot(direction) > 1e-12)
        .map(|p| (p.rho - p.normal.dot(origin)) / p.normal.dot(direction))
        .filter(|t| *t > 0.0)
        .min_by(f64::total_cmp)
}
