//! Deskew (paper section 2): every valid reading of a scan becomes a point in the body frame at
//! the epoch's reference time, using the body's motion between the beam's time and that time.
//! Invalid readings are counted by reason and never reach a fit.

use crate::sensors::{Mount, Scan, ScannerGeometry};
use nalgebra::{Isometry3, Matrix2x3, Matrix3x2, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Body pose at a beam's time relative to the body at the epoch's reference time:
/// `p_ref = pose_at(t) * p_body(t)`. Identity for a stationary body.
pub(crate) type PoseAt<'a> = &'a dyn Fn(f64) -> Isometry3<f64>;

/// One valid reading, ready for line extraction (2-D) and plane fitting (3-D).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Beam {
    /// The deskewed point in the scanner's own plane (x front, y right), i.e. `body` seen from
    /// the scanner's mount: the line extractor segments here, where straight 3-D lines stay
    /// straight whatever the motion during the scan.
    pub planar: Vector2<f64>,
    /// Point in the body frame at the reference time (deskewed).
    pub body: Vector3<f64>,
    /// Unit beam direction in the body frame; its angle to a plane's normal scales how much of
    /// the ranging noise moves the point off the plane.
    pub direction: Vector3<f64>,
    /// Beam azimuth in the scanner frame, radians.
    pub azimuth: f64,
    /// Measured range, metres.
    pub range: f64,
    /// When it was measured, host seconds: a velocity error moves the deskewed point by itself
    /// times this less the reference time.
    pub time: f64,
}

/// Readings dropped from one scan, by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DroppedReadings {
    /// NaN readings.
    pub not_a_number: u32,
    /// Exactly zero: no echo.
    pub zero: u32,
    /// Below DMIN (or negative): a device error code, not a distance.
    pub error_code: u32,
    /// Above DMAX (including +infinity).
    pub out_of_range: u32,
}

impl DroppedReadings {
    #[cfg(test)]
    pub(crate) fn total(&self) -> u32 {
        self.not_a_number + self.zero + self.error_code + self.out_of_range
    }

    /// Counts a reading as dropped if it is not a measurement; returns whether it was kept.
    fn admit(&mut self, range_m: f64, geometry: &ScannerGeometry) -> bool {
        let counter = if range_m.is_nan() {
            &mut self.not_a_number
        } else if range_m == 0.0 {
            &mut self.zero
        } else if range_m < geometry.dmin_m {
            &mut self.error_code
        } else if range_m > geometry.dmax_m {
            &mut self.out_of_range
        } else {
            return true;
        };
        *counter += 1;
        false
    }
}

/// The body pose function is sampled every this many readings (0.7 ms on a UTM-30LX) and the
/// scanner-to-reference map interpolated linearly between samples: over such an interval the
/// motion is linear far below the ranging noise (1e-8 rad of curvature at 1 rad/s), and
/// evaluating an IMU-driven pose function per beam would dominate the epoch.
pub(crate) const POSE_SAMPLE_READINGS: usize = 16;

/// Beam geometry of one reading, fixed for a scanner, its mount and the scan's step layout.
#[derive(Debug, Clone, Copy)]
struct BeamGeometry {
    azimuth: f64,
    in_scanner: Vector2<f64>,
    direction: Vector3<f64>,
}

/// Deskews scans, keeping the per-step beam directions between calls.
#[derive(Debug, Clone, Default)]
pub struct Deskewer {
    layout: Option<(ScannerGeometry, Mount, u32, u32)>,
    table: Vec<BeamGeometry>,
    /// First two rows of the inverse mount rotation: body directions to scanner-plane x, y.
    to_scanner_plane: Matrix2x3<f64>,
}

impl Deskewer {
    /// Fills `out` (cleared first) with the valid beams of `scan`, deskewed to the reference
    /// time of `pose_at`.
    pub fn deskew(
        &mut self,
        scan: &Scan,
        geometry: &ScannerGeometry,
        mount: &Mount,
        pose_at: PoseAt<'_>,
        out: &mut Vec<Beam>,
    ) -> DroppedReadings {
        self.prepare(scan, geometry, mount);
        out.clear();
        let mut dropped = DroppedReadings::default();
        let mut motion = Interpolator::default();
        for (index, &range) in scan.ranges_m.iter().enumerate() {
            if !dropped.admit(range, geometry) {
                continue;
            }
            let beam = self.table[index];
            let measured = beam.in_scanner * range;
            let body = motion.map_to_reference(index, &measured, scan, geometry, mount, pose_at);
            out.push(Beam {
                planar: self.to_scanner_plane * (body - mount.translation),
                body,
                direction: beam.direction,
                azimuth: beam.azimuth,
                range,
                time: scan.time_of(index, geometry),
            });
        }
        dropped
    }

    fn prepare(&mut self, scan: &Scan, geometry: &ScannerGeometry, mount: &Mount) {
        let layout = Some((*geometry, *mount, scan.first_step, scan.cluster));
        if self.layout == layout && self.table.len() >= scan.ranges_m.len() {
            return;
        }
        self.layout = layout;
        let inverse = mount.rotation.inverse().to_rotation_matrix();
        self.to_scanner_plane = inverse.matrix().fixed_rows::<2>(0).into_owned();
        self.table.clear();
        self.table.extend((0..scan.ranges_m.len()).map(|index| {
            let step = scan.step_of(index);
            let in_scanner = geometry.step_direction(step);
            BeamGeometry {
                azimuth: geometry.step_azimuth(step),
                in_scanner: in_scanner.xy(),
                direction: mount.rotation * in_scanner,
            }
        }));
    }
}

/// The affine map from the scanner plane to the reference body frame, `p = M q + t`.
#[derive(Debug, Clone, Copy, Default)]
struct PlaneMap {
    m: Matrix3x2<f64>,
    t: Vector3<f64>,
}

impl PlaneMap {
    fn at(pose: &Isometry3<f64>, mount: &Mount) -> Self {
        let rotation = (pose.rotation * mount.rotation).to_rotation_matrix();
        Self {
            m: rotation.matrix().fixed_columns::<2>(0).into_owned(),
            t: pose
                .transform_point(&Point3::from(mount.translation))
                .coords,
        }
    }

    fn apply(&self, q: &Vector2<f64>) -> Vector3<f64> {
        self.m * q + self.t
    }
}

/// Samples the pose function at every `POSE_SAMPLE_READINGS`-th reading and interpolates the
/// scanner-to-reference map linearly in between.
#[derive(Default)]
struct Interpolator {
    knot: Option<usize>,
    first: usize,
    span: f64,
    start: PlaneMap,
    change: PlaneMap,
}

impl Interpolator {
    fn map_to_reference(
        &mut self,
        index: usize,
        planar: &Vector2<f64>,
        scan: &Scan,
        geometry: &ScannerGeometry,
        mount: &Mount,
        pose_at: PoseAt<'_>,
    ) -> Vector3<f64> {
        let knot = index / POSE_SAMPLE_READINGS;
        if self.knot != Some(knot) {
            let first = knot * POSE_SAMPLE_READINGS;
            let last = (first + POSE_SAMPLE_READINGS).min(scan.ranges_m.len() - 1);
            let map_at = |i: usize| PlaneMap::at(&pose_at(scan.time_of(i, geometry)), mount);
            let (start, end) = (map_at(first), map_at(last));
            self.knot = Some(knot);
            self.first = first;
            self.span = (last - first) as f64;
            self.start = start;
            self.change = PlaneMap {
                m: end.m - start.m,
                t: end.t - start.t,
            };
        }
        let f = if self.span > 0.0 {
            (index - self.first) as f64 / self.span
        } else {
            0.0
        };
        self.start.apply(planar) + self.change.apply(planar) * f
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn scan(ranges_m: Vec<f64>) -> Scan {
        Scan {
            sensor: 0,
            t0: 10.0,
            first_step: 0,
            cluster: 1,
            ranges_m,
        }
    }

    #[test]
    fn invalid_readings_are_dropped_and_counted_by_reason() {
        let g = ScannerGeometry::UTM_30LX;
        let ranges = vec![
            f64::NAN,
            0.0,
            0.005,
            -1.0,
            61.0,
            f64::INFINITY,
            2.0,
            g.dmin_m,
            g.dmax_m,
        ];
        let mut beams = Vec::new();
        let dropped = Deskewer::default().deskew(
            &scan(ranges),
            &g,
            &Mount::identity(),
            &|_| Isometry3::identity(),
            &mut beams,
        );
        assert_eq!(
            dropped,
            DroppedReadings {
                not_a_number: 1,
                zero: 1,
                error_code: 2,
                out_of_range: 2
            }
        );
        assert_eq!(dropped.total(), 6);
        assert_eq!(beams.len(), 3);
        assert!(beams.iter().all(|b| b.body.iter().all(|c| c.is_finite())));
    }

    #[test]
    fn mount_places_the_beam_and_motion_moves_it_to_the_reference_time() {
        let g = ScannerGeometry::UTM_30LX;
        let mount = Mount::from_rpy_deg([0.0, 0.0, 90.0], [0.1, 0.0, -0.2]);
        let mut ranges = vec![0.0; 541];
        ranges[540] = 3.0; // front step
        let s = scan(ranges);
        let t_beam = s.time_of(540, &g);
        let velocity = Vector3::new(1.0, -2.0, 0.5);
        // Body moved by velocity * (t - t_ref) since the reference time t_ref = 10.
        let pose_at = |t: f64| {
            Isometry3::from_parts(
                Translation3::from(velocity * (t - 10.0)),
                UnitQuaternion::identity(),
            )
        };
        let mut beams = Vec::new();
        Deskewer::default().deskew(&s, &g, &mount, &pose_at, &mut beams);
        assert_eq!(beams.len(), 1);
        let expected = Vector3::new(0.1, 3.0, -0.2) + velocity * (t_beam - 10.0);
        assert!((beams[0].body - expected).norm() < 1e-12);
        let seen_from_mount = mount.rotation.inverse() * (expected - mount.translation);
        assert!((beams[0].planar - seen_from_mount.xy()).norm() < 1e-12);
        assert!((beams[0].direction - Vector3::y()).norm() < 1e-12);
    }
}
