//! ROS messages as this project's measurements (docs/ros-data.md): a `LaserScan` becomes the
//! [`ScannerGeometry`] and [`Scan`] a Hokuyo would have reported, an `Imu` an
//! [`ImuSample::Rate`]. Everything after that is the code a raw-byte replay runs.
//!
//! Frames: ROS scanners and IMUs are FLU (x forward, y left, z up) and measure scan angles
//! counter-clockwise about z; this project's are FRD (docs/design.md, "Frames"). FLU to FRD is
//! a half turn about x, `(x, y, z) -> (x, -y, -z)`, so a ROS angle `theta` is the azimuth
//! `-theta` of the FRD scanner frame: exactly how SCIP steps count, later steps to the left.

use super::readings::SensorEvent;
use crate::sensors::{ImuSample, Mount, Scan, ScannerGeometry};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rosmsg::{Echoes, ScanInfo};
use std::f64::consts::TAU;

/// Ranges below this are no returns whatever `range_min` says: 0 is the code this project
/// gives a no return (as SCIP's error codes, it sits below the shortest valid range).
const SHORTEST_RANGE_M: f64 = 1e-3;
const NO_RETURN_M: f64 = 0.0;
/// A revolution in more steps than this is not a scanner's: an `angle_increment` gone wrong.
const MAX_STEPS_PER_REVOLUTION: f64 = 1e6;

/// The geometry a scan's description gives, and the step of its first beam; `None` when the
/// description cannot be a planar scanner's (no increment, more than a revolution, no beams).
///
/// Angles become steps of `2 pi / ares`, `ares` the nearest whole number of increments per
/// revolution: exact for Hokuyo and SICK scanners, whose increments divide a revolution. The
/// first beam is step 0 whenever it is at or right of the front (`angle_min <= 0`, as every
/// ROS scanner driver starts), so the scan starts at its stamp, as a SCIP scan starts at its
/// step 0; a scan that starts left of the front has the front at step 0. A beam's time is `time_increment` after the one before (`scan_time` per
/// revolution when the driver gives no `time_increment`); a scan with neither is taken whole
/// at its stamp.
pub(crate) fn geometry(info: &ScanInfo, beams: usize) -> Option<(ScannerGeometry, u32)> {
    let increment = f64::from(info.angle_increment);
    let steps = (TAU / increment).round();
    if !(1.0..=MAX_STEPS_PER_REVOLUTION).contains(&steps) || beams == 0 {
        return None;
    }
    let ares = steps as u32;
    // The first beam's step counted from the front, positive to the left.
    let from_front = (f64::from(info.angle_min) / increment).round();
    let front = (-from_front).max(0.0);
    let first = from_front + front;
    let last = first + beams as f64 - 1.0;
    if !from_front.is_finite() || front > steps || last - first >= steps {
        return None;
    }
    let revolution_s = match (info.time_increment, info.scan_time) {
        (dt, _) if dt > 0.0 => f64::from(dt) * steps,
        (_, period) if period > 0.0 => f64::from(period),
        _ => 0.0,
    };
    let rpm = if revolution_s > 0.0 {
        (60.0 / revolution_s)
            .round()
            .clamp(1.0, f64::from(u32::MAX))
    } else {
        f64::from(u32::MAX)
    };
    let geometry = ScannerGeometry {
        ares,
        amin: first as u32,
        amax: last as u32,
        afrt: front as u32,
        rpm: rpm as u32,
        dmin_m: f64::from(info.range_min).max(SHORTEST_RANGE_M),
        dmax_m: f64::from(info.range_max),
    };
    Some((geometry, first as u32))
}

/// A range as metres, or the no-return code when the scanner says it is out of its limits.
fn range_m(range: f32, info: &ScanInfo) -> f64 {
    if range.is_finite() && range >= info.range_min && range <= info.range_max {
        f64::from(range)
    } else {
        NO_RETURN_M
    }
}

/// The scan of scanner `sensor` whose first beam was measured at `stamp_s`, ranges as
/// [`range_m`] keeps them.
fn scan(
    sensor: usize,
    stamp_s: f64,
    geometry: &ScannerGeometry,
    first_step: u32,
    ranges: impl Iterator<Item = f64>,
) -> Scan {
    Scan {
        sensor,
        t0: stamp_s - f64::from(first_step) * geometry.step_period(),
        first_step,
        cluster: 1,
        ranges_m: ranges.collect(),
    }
}

/// A planar scan's ranges, whichever message carried them.
pub(crate) enum Ranges<'a> {
    Single(&'a [f32]),
    /// `MultiEchoLaserScan`: the first echo of each beam, the nearest surface, as cartographer
    /// reads it too; a beam without echoes is a no return.
    FirstEcho(&'a Echoes),
}

impl Ranges<'_> {
    fn beams(&self) -> usize {
        match self {
            Self::Single(ranges) => ranges.len(),
            Self::FirstEcho(echoes) => echoes.beams(),
        }
    }

    fn first(&self, beam: usize) -> f32 {
        match self {
            Self::Single(ranges) => ranges[beam],
            Self::FirstEcho(echoes) => echoes.beam(beam).first().copied().unwrap_or(f32::NAN),
        }
    }
}

/// Turns one scanner's ROS scans into geometries (when they change) and scans.
#[derive(Debug, Default)]
pub(crate) struct ScanConverter {
    geometry: Option<ScannerGeometry>,
}

impl ScanConverter {
    /// Appends the scan, after its geometry if that is new; false if the description is not a
    /// planar scanner's ([`geometry`]), and nothing is appended.
    pub(crate) fn take(
        &mut self,
        sensor: usize,
        stamp_s: f64,
        info: &ScanInfo,
        ranges: Ranges<'_>,
        out: &mut Vec<SensorEvent>,
    ) -> bool {
        let Some((geometry, first_step)) = geometry(info, ranges.beams()) else {
            return false;
        };
        if self.geometry != Some(geometry) {
            self.geometry = Some(geometry);
            out.push(SensorEvent::Geometry { sensor, geometry });
        }
        let metres = (0..ranges.beams()).map(|beam| range_m(ranges.first(beam), info));
        out.push(SensorEvent::Scan(scan(
            sensor, stamp_s, &geometry, first_step, metres,
        )));
        true
    }
}

/// FLU to FRD (and ENU to NED): a half turn about x.
fn flu_to_frd(v: &rosmsg::Vector3) -> Vector3<f64> {
    Vector3::new(v.x, -v.y, -v.z)
}

/// A ROS frame's name as tf2 compares it: ROS 1 names may start with a `/` that tf2 drops.
fn frame_name(frame: &str) -> &str {
    frame.trim_start_matches('/')
}

/// Where `frame` sits in the root of its tree, in FLU, by the chain of `transforms` (each
/// child has one parent, as in tf2), and that root's name.
fn to_root<'a>(
    frame: &'a str,
    transforms: &'a [rosmsg::TransformStamped],
) -> (&'a str, Isometry3<f64>) {
    let mut pose = Isometry3::identity();
    let mut at = frame_name(frame);
    // A chain visits each transform at most once; a longer one is a loop in the recording.
    for _ in 0..transforms.len() {
        let Some(link) = transforms
            .iter()
            .find(|t| frame_name(&t.child_frame_id) == at)
        else {
            break;
        };
        let (t, q) = (&link.translation, &link.rotation);
        let rotation = UnitQuaternion::from_quaternion(Quaternion::new(q.w, q.x, q.y, q.z));
        pose = Isometry3::from_parts(Translation3::new(t.x, t.y, t.z), rotation) * pose;
        at = frame_name(&link.header.frame_id);
    }
    (at, pose)
}

/// The mount of the sensor whose messages are in `sensor_frame` on the body `body_frame`, in
/// this project's FRD frames, from the static transforms of a recording; the error says which
/// link is missing. Both frames are walked up to the root of their tree, so a chain through
/// any common parent (`odom`, `map`) composes as tf2 would.
pub(crate) fn mount_from_tf(
    body_frame: &str,
    sensor_frame: &str,
    transforms: &[rosmsg::TransformStamped],
) -> Result<Mount, String> {
    let (body_root, body) = to_root(body_frame, transforms);
    let (sensor_root, sensor) = to_root(sensor_frame, transforms);
    if body_root != sensor_root {
        return Err(format!(
            "/tf_static links no chain from `{}` to `{}` (it ends at `{body_root}` and `{sensor_root}`)",
            frame_name(body_frame),
            frame_name(sensor_frame)
        ));
    }
    let flu = body.inverse() * sensor;
    // The half turn about x on both sides, F R F, keeps a quaternion's w and turns its vector
    // part as any vector: the same map as the IMU's samples.
    let q = flu.rotation.quaternion();
    let axis = flu_to_frd(&rosmsg::Vector3 {
        x: q.i,
        y: q.j,
        z: q.k,
    });
    let t = flu.translation.vector;
    Ok(Mount {
        rotation: UnitQuaternion::from_quaternion(Quaternion::from_parts(q.w, axis)),
        translation: flu_to_frd(&rosmsg::Vector3 {
            x: t.x,
            y: t.y,
            z: t.z,
        }),
    })
}

/// Rate of turn and specific force of an `Imu` message, in the IMU's FRD frame. The
/// orientation it may carry is the device's own filter's, which this odometer does not take.
pub(crate) fn imu_sample(imu: &rosmsg::Imu) -> ImuSample {
    ImuSample::Rate {
        t: imu.header.stamp.as_secs_f64(),
        gyro: flu_to_frd(&imu.angular_velocity),
        accel: flu_to_frd(&imu.linear_acceleration),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A UTM-30LX as its ROS driver describes it: 270 deg in quarter degrees at 40 Hz.
    fn utm_30lx() -> ScanInfo {
        ScanInfo {
            angle_min: (-135f32).to_radians(),
            angle_max: 135f32.to_radians(),
            angle_increment: 0.25f32.to_radians(),
            time_increment: 1.0 / (40.0 * 1440.0),
            scan_time: 0.025,
            range_min: 0.023,
            range_max: 60.0,
        }
    }

    #[test]
    fn a_utm_30lx_scan_has_the_geometry_of_its_pp_reply_turned_to_the_same_angles() {
        let (geometry, first) = geometry(&utm_30lx(), 1081).unwrap();
        let pp = ScannerGeometry::UTM_30LX;
        assert_eq!((geometry.ares, geometry.rpm), (pp.ares, pp.rpm));
        assert_eq!(
            (geometry.amin, geometry.amax, geometry.afrt),
            (pp.amin, pp.amax, pp.afrt)
        );
        assert_eq!(first, 0);
        for k in [0, 540, 1080] {
            let ours = geometry.step_azimuth(f64::from(first + k));
            let hokuyo = pp.step_azimuth(f64::from(pp.amin + k));
            assert!(
                (ours - hokuyo).abs() < 1e-12,
                "beam {k}: {ours} vs {hokuyo}"
            );
        }
        // The first beam is to the right (ROS -135 deg), so +135 deg azimuth in FRD.
        assert!((geometry.step_azimuth(f64::from(first)) - 135f64.to_radians()).abs() < 1e-12);
        assert!((geometry.step_period() - 1.0 / (40.0 * 1440.0)).abs() < 1e-12);
    }

    #[test]
    fn without_time_increment_the_scan_time_times_the_beams_and_without_both_none_does() {
        let info = ScanInfo {
            time_increment: 0.0,
            ..utm_30lx()
        };
        assert_eq!(geometry(&info, 1081).unwrap().0.rpm, 2400);
        let untimed = ScanInfo {
            scan_time: 0.0,
            ..info
        };
        let (g, _) = geometry(&untimed, 1081).unwrap();
        assert!(g.step_period() * 1081.0 < 1e-6, "{}", g.step_period());
    }

    #[test]
    fn impossible_descriptions_give_no_geometry() {
        for info in [
            ScanInfo {
                angle_increment: 0.0,
                ..utm_30lx()
            },
            ScanInfo {
                angle_increment: f32::NAN,
                ..utm_30lx()
            },
            ScanInfo {
                angle_increment: -0.1,
                ..utm_30lx()
            },
            ScanInfo {
                angle_min: -10.0,
                ..utm_30lx()
            },
            ScanInfo {
                angle_min: f32::NAN,
                ..utm_30lx()
            },
        ] {
            assert_eq!(geometry(&info, 1081), None, "{info:?}");
        }
        assert_eq!(geometry(&utm_30lx(), 0), None);
        assert_eq!(geometry(&utm_30lx(), 1441), None, "more than a revolution");
        let left_of_front = ScanInfo {
            angle_min: 0.5,
            ..utm_30lx()
        };
        let (g, first) = geometry(&left_of_front, 100).unwrap();
        assert_eq!((g.afrt, first), (0, 115));
        // To the nearest step: within half an increment.
        assert!((g.step_azimuth(f64::from(first)) + 0.5).abs() < 0.125f64.to_radians());
    }

    #[test]
    fn out_of_limit_and_non_finite_ranges_are_no_returns_the_geometry_drops() {
        let info = utm_30lx();
        let mut converter = ScanConverter::default();
        let mut out = Vec::new();
        let ranges = [1.5, 0.01, 61.0, f32::NAN, f32::INFINITY, 0.023];
        assert!(converter.take(1, 100.0, &info, Ranges::Single(&ranges), &mut out));
        let [SensorEvent::Geometry {
            sensor: 1,
            geometry,
        }, SensorEvent::Scan(scan)] = &out[..]
        else {
            panic!("a geometry, then the scan: {out:?}");
        };
        assert_eq!(scan.ranges_m[..5], [1.5, 0.0, 0.0, 0.0, 0.0]);
        assert!((scan.ranges_m[5] - 0.023).abs() < 1e-9);
        let valid: Vec<bool> = scan
            .ranges_m
            .iter()
            .map(|&r| geometry.is_valid_range(r))
            .collect();
        assert_eq!(valid, [true, false, false, false, false, true]);
        assert!((scan.time_of(0, geometry) - 100.0).abs() < 1e-9);
        assert!((scan.time_of(4, geometry) - 100.0 - 4.0 / 57_600.0).abs() < 1e-9);

        out.clear();
        assert!(converter.take(1, 100.025, &info, Ranges::Single(&ranges), &mut out));
        assert!(
            matches!(out[..], [SensorEvent::Scan(_)]),
            "the same geometry is not given again"
        );
    }

    #[test]
    fn a_multi_echo_scan_keeps_the_first_echo() {
        let echoes = Echoes::from_beams([&[2.0f32, 3.0][..], &[], &[4.0]]);
        let mut out = Vec::new();
        let taken = ScanConverter::default().take(
            0,
            1.0,
            &utm_30lx(),
            Ranges::FirstEcho(&echoes),
            &mut out,
        );
        assert!(taken);
        let SensorEvent::Scan(scan) = &out[1] else {
            panic!("{out:?}");
        };
        assert_eq!(scan.ranges_m, [2.0, 0.0, 4.0]);
    }

    #[test]
    fn a_ros_imu_turning_left_at_rest_is_a_negative_yaw_rate_and_minus_g_down_in_frd() {
        let imu = rosmsg::Imu {
            header: rosmsg::Header {
                stamp: rosmsg::Time {
                    sec: 12,
                    nanosec: 500_000_000,
                },
                ..Default::default()
            },
            // Level, turning left (counter-clockwise seen from above) at 0.3 rad/s, rolling
            // right wing down at 0.1 rad/s; at rest the specific force points up, +z in FLU.
            angular_velocity: rosmsg::Vector3 {
                x: 0.1,
                y: 0.2,
                z: 0.3,
            },
            linear_acceleration: rosmsg::Vector3 {
                x: 0.5,
                y: 1.0,
                z: 9.81,
            },
            ..Default::default()
        };
        let ImuSample::Rate { t, gyro, accel } = imu_sample(&imu) else {
            panic!("rates");
        };
        assert_eq!(t, 12.5);
        // Each motion keeps its meaning with the axes turned: the roll rate about forward is
        // unchanged, the pitch and yaw rates change sign with y and z.
        assert_eq!(gyro, Vector3::new(0.1, -0.2, -0.3));
        // At rest a NED IMU reads -g along down, as the filter expects.
        assert_eq!(accel, Vector3::new(0.5, -1.0, -9.81));
        // The same rotation seen as a rotation matrix: a turn left by the yaw rate over 1 s,
        // applied to the forward axis, points left, which is -y in FRD.
        let turn = nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, gyro.z));
        assert!((turn * Vector3::x()).y < 0.0);
    }

    fn link(parent: &str, child: &str, xyz: [f64; 3], rpy: [f64; 3]) -> rosmsg::TransformStamped {
        let q = UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]);
        rosmsg::TransformStamped {
            header: rosmsg::Header {
                frame_id: parent.into(),
                ..Default::default()
            },
            child_frame_id: child.into(),
            translation: rosmsg::Vector3 {
                x: xyz[0],
                y: xyz[1],
                z: xyz[2],
            },
            rotation: rosmsg::Quaternion {
                x: q.i,
                y: q.j,
                z: q.k,
                w: q.w,
            },
        }
    }

    fn close(a: &Mount, b: &Mount) -> bool {
        a.rotation.angle_to(&b.rotation) < 1e-12 && (a.translation - b.translation).norm() < 1e-12
    }

    #[test]
    fn a_scanner_pitched_plus_30_deg_about_ros_y_is_pitched_down_30_deg_in_frd() {
        // +30 deg about y (left) turns x towards -z, down in FLU: a scan plane tilted down.
        let tf = [link(
            "base_link",
            "laser",
            [0.2, 0.1, 0.3],
            [0.0, 30f64.to_radians(), 0.0],
        )];
        let mount = mount_from_tf("base_link", "laser", &tf).unwrap();
        let expected = Mount::from_rpy_deg([0.0, -30.0, 0.0], [0.2, -0.1, -0.3]);
        assert!(close(&mount, &expected), "{mount:?}");
        // Down in FRD is +z: the front of the plane points down.
        assert!(((mount.rotation * Vector3::x()).z - 0.5).abs() < 1e-12);
    }

    #[test]
    // The URDF writes 3.14, not pi.
    #[allow(clippy::approx_constant)]
    fn the_conversion_is_the_half_turn_the_docs_apply_by_hand_to_a_urdf() {
        // The backpack's vertical scanner: URDF rpy 0 -1.57 3.14, as its configuration writes it.
        let rpy = [0.0f64, -1.57, 3.14];
        let tf = [link(
            "base_link",
            "vertical",
            [0.1251, 0.0937, 0.17772],
            rpy,
        )];
        let mount = mount_from_tf("base_link", "vertical", &tf).unwrap();
        let [r, p, y] = rpy.map(f64::to_degrees);
        let by_hand = Mount::from_rpy_deg([r, -p, -y], [0.1251, -0.0937, -0.17772]);
        assert!(close(&mount, &by_hand), "{mount:?} vs {by_hand:?}");
    }

    #[test]
    fn a_two_link_chain_composes_and_a_leading_slash_names_the_same_frame() {
        let tf = [
            link(
                "/base_link",
                "/mast",
                [0.0, 0.0, 0.5],
                [0.0, 0.0, 90f64.to_radians()],
            ),
            link("mast", "laser", [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
            link("odom", "base_link", [5.0, 5.0, 0.0], [0.0, 0.0, 1.0]),
        ];
        let mount = mount_from_tf("base_link", "laser", &tf).unwrap();
        // One metre along the mast's x, which is the body's left (ROS y), at 0.5 m up:
        // FRD (0, -1, -0.5), turned a quarter turn left (-90 deg yaw in FRD).
        let expected = Mount::from_rpy_deg([0.0, 0.0, -90.0], [0.0, -1.0, -0.5]);
        assert!(close(&mount, &expected), "{mount:?}");
        // From the sensor up to the body too: the inverse.
        let inverse = mount_from_tf("laser", "base_link", &tf).unwrap();
        assert!(close(
            &inverse,
            &Mount {
                rotation: expected.rotation.inverse(),
                translation: -(expected.rotation.inverse() * expected.translation),
            }
        ));
        // A frame is its own mount.
        assert!(close(
            &mount_from_tf("imu_link", "imu_link", &[]).unwrap(),
            &Mount::identity()
        ));
    }

    #[test]
    fn a_missing_link_names_both_ends_of_the_chain() {
        let tf = [link("mast", "laser", [1.0, 0.0, 0.0], [0.0; 3])];
        let error = mount_from_tf("base_link", "laser", &tf).unwrap_err();
        assert_eq!(
            error,
            "/tf_static links no chain from `base_link` to `laser` (it ends at `base_link` and `mast`)"
        );
        // A loop ends rather than spins.
        let looped = [
            link("a", "b", [0.0; 3], [0.0; 3]),
            link("b", "a", [0.0; 3], [0.0; 3]),
        ];
        assert!(mount_from_tf("base_link", "a", &looped).is_err());
    }
}
