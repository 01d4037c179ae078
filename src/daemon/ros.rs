//! ROS messages as this project's measurements (docs/ros-data.md): a `LaserScan` becomes the
//! [`ScannerGeometry`] and [`Scan`] a Hokuyo would have reported, an `Imu` an
//! [`ImuSample::Rate`]. Everything after that is the code a raw-byte replay runs.
//!
//! Frames: ROS scanners and IMUs are FLU (x forward, y left, z up) and measure scan angles
//! counter-clockwise about z; this project's are FRD (docs/design.md, "Frames"). FLU to FRD is
//! a half turn about x, `(x, y, z) -> (x, -y, -z)`, so a ROS angle `theta` is the azimuth
//! `-theta` of the FRD scanner frame: exactly how SCIP steps count, later steps to the left.

use super::readings::SensorEvent;
use crate::sensors::{ImuSample, Scan, ScannerGeometry};
use nalgebra::Vector3;
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
}
