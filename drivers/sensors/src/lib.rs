//! The sensor vocabulary: what a driver's output means in metres, seconds and frames (scanner
//! geometry, mounts, scans, IMU samples, ground truth). The daemon turns the drivers' readings
//! into these types and its geometry core and filter take them; the simulator makes them. Shared
//! by both, so that neither depends on the other.
//!
//! Frames and conventions follow docs/design.md, "Frames": body FRD, navigation NED, times in
//! seconds on the host monotonic clock.

use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Angular geometry of a Hokuyo scanner, as its `PP` reply gives it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ScannerGeometry {
    /// Steps per full revolution (ARES).
    pub ares: u32,
    /// First measurable step (AMIN).
    pub amin: u32,
    /// Last measurable step (AMAX).
    pub amax: u32,
    /// Step pointing straight ahead along the scanner x axis (AFRT).
    pub afrt: u32,
    /// Motor speed in revolutions per minute (SCAN).
    pub rpm: u32,
    /// Shortest valid range in metres (DMIN); smaller values are device error codes.
    pub dmin_m: f64,
    /// Longest valid range in metres (DMAX).
    pub dmax_m: f64,
}

impl ScannerGeometry {
    /// URG-04LX and URG-04LX-UG01 (SCIP 2.0 spec p.21).
    pub const URG_04LX: Self = Self {
        ares: 1024,
        amin: 44,
        amax: 725,
        afrt: 384,
        rpm: 600,
        dmin_m: 0.020,
        dmax_m: 5.6,
    };
    /// UTM-30LX (USB) and UTM-30LX-EW.
    pub const UTM_30LX: Self = Self {
        ares: 1440,
        amin: 0,
        amax: 1080,
        afrt: 540,
        rpm: 2400,
        dmin_m: 0.023,
        dmax_m: 60.0,
    };
    /// UST-20LX. Its PP reply was never seen; the daemon reads PP at run time.
    pub const UST_20LX: Self = Self {
        ares: 1440,
        amin: 0,
        amax: 1080,
        afrt: 540,
        rpm: 2400,
        dmin_m: 0.020,
        dmax_m: 20.0,
    };

    /// Beam azimuth of `step` in the scanner frame: psi = -(k - AFRT) * 2 pi / ARES.
    pub fn step_azimuth(&self, step: f64) -> f64 {
        -(step - f64::from(self.afrt)) * 2.0 * PI / f64::from(self.ares)
    }

    /// Unit beam direction of `step` in the scanner frame (x front, y right, z down).
    pub fn step_direction(&self, step: f64) -> Vector3<f64> {
        let psi = self.step_azimuth(step);
        Vector3::new(psi.cos(), psi.sin(), 0.0)
    }

    /// Time between two consecutive steps, in seconds.
    pub fn step_period(&self) -> f64 {
        60.0 / (f64::from(self.rpm) * f64::from(self.ares))
    }

    /// Time of one full revolution, in seconds.
    pub fn scan_period(&self) -> f64 {
        60.0 / f64::from(self.rpm)
    }

    /// Whether a range in metres is a measurement rather than an error code or junk.
    pub fn is_valid_range(&self, range_m: f64) -> bool {
        range_m.is_finite() && range_m >= self.dmin_m && range_m <= self.dmax_m
    }
}

/// Rigid mount of a sensor on the body: `p_body = rotation * p_sensor + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mount {
    pub rotation: UnitQuaternion<f64>,
    pub translation: Vector3<f64>,
}

impl Mount {
    /// `rpy_deg = [roll, pitch, yaw]`, composed as Rz(yaw) Ry(pitch) Rx(roll). With z down, a
    /// positive pitch raises the front of the scan plane.
    pub fn from_rpy_deg(rpy_deg: [f64; 3], translation: [f64; 3]) -> Self {
        let [roll, pitch, yaw] = rpy_deg.map(f64::to_radians);
        let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw)
            * Rotation3::from_axis_angle(&Vector3::y_axis(), pitch)
            * Rotation3::from_axis_angle(&Vector3::x_axis(), roll);
        Self {
            rotation: UnitQuaternion::from_rotation_matrix(&rotation),
            translation: Vector3::from(translation),
        }
    }

    pub fn identity() -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
        }
    }

    pub fn to_body(&self, p_sensor: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p_sensor + self.translation
    }
}

/// One scanner as the core needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScannerSetup {
    pub geometry: ScannerGeometry,
    pub mount: Mount,
    /// Ranging noise, 1 sigma, metres; `None` takes `OdometryConfig::range_sigma_m`.
    pub range_sigma_m: Option<f64>,
}

/// One revolution of one scanner, in metres, exactly as the device reported it: error codes,
/// zeros and NaN are kept here and dropped (with a count) by the geometry core.
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    /// Index of the scanner in the configuration.
    pub sensor: usize,
    /// Host time of step 0 (not of `first_step`), in seconds.
    pub t0: f64,
    /// Step of `ranges_m[0]`.
    pub first_step: u32,
    /// Steps merged into one reading (SCIP cluster count, at least 1).
    pub cluster: u32,
    pub ranges_m: Vec<f64>,
}

impl Scan {
    /// Step at the centre of reading `index`, which is where its beam points.
    pub fn step_of(&self, index: usize) -> f64 {
        let cluster = f64::from(self.cluster.max(1));
        f64::from(self.first_step) + index as f64 * cluster + (cluster - 1.0) / 2.0
    }

    /// Host time at which reading `index` was measured.
    pub fn time_of(&self, index: usize, geometry: &ScannerGeometry) -> f64 {
        self.t0 + self.step_of(index) * geometry.step_period()
    }
}

/// One IMU output in the IMU's own (NED-flagged) frame; the filter applies the IMU mount.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ImuSample {
    /// Acceleration (specific force, m/s^2) and rate of turn (rad/s) at time `t`.
    Rate {
        t: f64,
        gyro: Vector3<f64>,
        accel: Vector3<f64>,
    },
    /// Orientation and velocity increments over `(t - dt, t]` (Xsens DeltaQ / DeltaV).
    Delta {
        t: f64,
        dt: f64,
        dq: UnitQuaternion<f64>,
        dv: Vector3<f64>,
    },
}

impl ImuSample {
    pub fn time(&self) -> f64 {
        match self {
            Self::Rate { t, .. } | Self::Delta { t, .. } => *t,
        }
    }
}

/// Ground truth of the body at time `t`: position NED, attitude body->NED, velocity NED.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthSample {
    pub t: f64,
    pub p: Vector3<f64>,
    pub q: UnitQuaternion<f64>,
    pub v: Vector3<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn front_step_points_along_x_and_later_steps_turn_left() {
        let g = ScannerGeometry::UTM_30LX;
        assert!((g.step_direction(540.0) - Vector3::x()).norm() < 1e-12);
        // 90 deg later in step order is to the left of forward: -y in FRD.
        let left = g.step_direction(540.0 + 360.0);
        assert!((left - Vector3::new(0.0, -1.0, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn positive_pitch_raises_the_front_of_the_scan_plane() {
        let mount = Mount::from_rpy_deg([0.0, 10.0, 0.0], [0.0; 3]);
        let front = mount.to_body(&Vector3::x());
        assert!(
            front.z < 0.0,
            "z is down in FRD, so raised means negative z"
        );
        assert!((front.z + 10f64.to_radians().sin()).abs() < 1e-12);
    }

    #[test]
    fn cluster_centre_step() {
        let scan = Scan {
            sensor: 0,
            t0: 0.0,
            first_step: 44,
            cluster: 3,
            ranges_m: vec![1.0; 4],
        };
        assert_eq!(scan.step_of(0), 45.0);
        assert_eq!(scan.step_of(2), 51.0);
    }
}
