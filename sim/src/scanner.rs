//! Simulated Hokuyo scanners: per-beam timing, pose at each beam's time, range noise, device
//! error codes and 1 mm quantisation, as the device would report them.

use super::scene::CastScene;
use super::trajectory::Trajectory;
use ladar_sensors::{Mount, Scan, ScannerGeometry};
use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ScannerModel {
    #[serde(rename = "urg-04lx")]
    Urg04lx,
    #[serde(rename = "utm-30lx")]
    Utm30lx,
    #[serde(rename = "ust-20lx")]
    Ust20lx,
    /// Geometry from the scanner's `geometry` key; error codes as the UTM-30LX.
    Custom,
}

impl ScannerModel {
    pub fn geometry(self) -> Option<ScannerGeometry> {
        match self {
            Self::Urg04lx => Some(ScannerGeometry::URG_04LX),
            Self::Utm30lx => Some(ScannerGeometry::UTM_30LX),
            Self::Ust20lx => Some(ScannerGeometry::UST_20LX),
            Self::Custom => None,
        }
    }

    /// What the device reports when nothing is within range (metres = raw mm / 1000):
    /// URG-04LX code 0, UTM/UST code 1 ("no object in range").
    pub fn no_return_m(self) -> f64 {
        match self {
            Self::Urg04lx => 0.0,
            _ => 0.001,
        }
    }

    /// What a dropped-out beam reports: URG-04LX code 6 ("others"), UTM/UST code 5 ("other").
    pub fn dropout_m(self) -> f64 {
        match self {
            Self::Urg04lx => 0.006,
            _ => 0.005,
        }
    }

    /// What a target closer than DMIN gives: URG-04LX code 0, UTM/UST code 2 ("too near").
    pub fn too_near_m(self) -> f64 {
        match self {
            Self::Urg04lx => 0.0,
            _ => 0.002,
        }
    }
}

/// Longest time between two exactly evaluated body poses within a scan. Linear interpolation
/// over 0.5 ms errs by at most a * (0.5 ms)^2 / 8, 0.1 um at 3 m/s^2: far below the 1 mm
/// resolution, and it makes a moving 1081-beam scan as cheap as a still one.
pub const POSE_KNOT_SPACING_S: f64 = 5e-4;

/// Body poses along a scan: exact every `stride` beams, interpolated in between.
struct PoseKnots<'a> {
    trajectory: &'a Trajectory,
    t_first: f64,
    knot_period: f64,
    stride: usize,
    knot: usize,
    left: (Vector3<f64>, UnitQuaternion<f64>),
    right: (Vector3<f64>, UnitQuaternion<f64>),
}

impl<'a> PoseKnots<'a> {
    fn new(trajectory: &'a Trajectory, t_first: f64, step_period: f64) -> Self {
        // Steps get a knot per beam: a jump must land on the beam where it happens, and a ramped
        // step (paper-sim) keeps the exact poses, so the paper's figures do not depend on it.
        let stride = match trajectory {
            Trajectory::Stationary { .. } => usize::MAX,
            Trajectory::Step { .. } => 1,
            _ => ((POSE_KNOT_SPACING_S / step_period) as usize).max(1),
        };
        let knot_period = step_period * stride.min(1 << 20) as f64;
        let left = trajectory.pose(t_first);
        let right = trajectory.pose(t_first + knot_period);
        Self {
            trajectory,
            t_first,
            knot_period,
            stride,
            knot: 0,
            left,
            right,
        }
    }

    /// Pose at beam `i`; beams must be asked for in increasing order.
    fn at(&mut self, i: usize) -> (Vector3<f64>, UnitQuaternion<f64>) {
        if self.stride == usize::MAX {
            return self.left;
        }
        let knot = i / self.stride;
        while self.knot < knot {
            self.knot += 1;
            self.left = self.right;
            let t_next = self.t_first + (self.knot + 1) as f64 * self.knot_period;
            self.right = self.trajectory.pose(t_next);
        }
        let within = i - knot * self.stride;
        if within == 0 {
            return self.left;
        }
        let fraction = within as f64 / self.stride as f64;
        (
            self.left.0.lerp(&self.right.0, fraction),
            self.left.1.nlerp(&self.right.1, fraction),
        )
    }
}

/// One scanner as configured. Scans run back to back from `phase_s`; with `skip = n` only every
/// (n+1)-th revolution is reported (SCIP `MD` scan interval).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScannerConfig {
    pub name: String,
    pub model: ScannerModel,
    /// Required for `custom`, overrides the model's geometry otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<ScannerGeometry>,
    /// `[roll, pitch, yaw]` of the scanner frame in the body frame (docs/design.md, "Frames").
    pub mount_rpy_deg: [f64; 3],
    #[serde(default)]
    pub mount_translation_m: [f64; 3],
    /// Gaussian range noise, 1 sigma.
    pub range_sigma_m: f64,
    /// Probability that a beam returns an error code instead of a range.
    #[serde(default)]
    pub dropout_probability: f64,
    /// Reported steps; default AMIN..=AMAX.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steps: Option<[u32; 2]>,
    #[serde(default)]
    pub skip: u32,
    /// Time of step 0 of the first revolution.
    #[serde(default)]
    pub phase_s: f64,
}

impl ScannerConfig {
    pub fn new(name: &str, model: ScannerModel, mount_rpy_deg: [f64; 3], sigma: f64) -> Self {
        Self {
            name: name.to_string(),
            model,
            geometry: None,
            mount_rpy_deg,
            mount_translation_m: [0.0; 3],
            range_sigma_m: sigma,
            dropout_probability: 0.0,
            steps: None,
            skip: 0,
            phase_s: 0.0,
        }
    }

    /// The geometry in force; `None` only for a `custom` model without `geometry`.
    pub fn resolved_geometry(&self) -> Option<ScannerGeometry> {
        self.geometry.or(self.model.geometry())
    }

    pub fn mount(&self) -> Mount {
        Mount::from_rpy_deg(self.mount_rpy_deg, self.mount_translation_m)
    }

    /// Time between two reported scans.
    pub fn report_period(&self, geometry: &ScannerGeometry) -> f64 {
        geometry.scan_period() * f64::from(self.skip + 1)
    }

    /// Why this scanner cannot be simulated, if it cannot.
    pub fn problem(&self) -> Option<String> {
        let Some(g) = self.resolved_geometry() else {
            return Some(format!(
                "scanner \"{}\": model custom needs a [scanners.geometry] table",
                self.name
            ));
        };
        let [first, last] = self.steps.unwrap_or([g.amin, g.amax]);
        let bad = if g.ares == 0 || g.rpm == 0 {
            "geometry ares and rpm must be positive"
        } else if first > last || last >= g.ares {
            "steps must satisfy first <= last < ares"
        } else if self.range_sigma_m.is_nan() || self.range_sigma_m < 0.0 {
            "range_sigma_m must be zero or positive"
        } else if !(0.0..=1.0).contains(&self.dropout_probability) {
            "dropout_probability must be within 0..1"
        } else if self.skip > 9 {
            "skip must be 0..=9 (the SCIP scan interval)"
        } else if !self.phase_s.is_finite() {
            "phase_s must be a finite number of seconds"
        } else {
            return None;
        };
        Some(format!("scanner \"{}\": {bad}", self.name))
    }
}

/// A validated scanner ready to cast.
#[derive(Debug, Clone)]
/// Read-only: its beam directions are derived from the mount once, at construction.
pub struct SimScanner {
    config: ScannerConfig,
    geometry: ScannerGeometry,
    mount: Mount,
    first_step: u32,
    /// Beam direction of each reported step in the body frame.
    directions_body: Vec<Vector3<f64>>,
}

impl SimScanner {
    /// `config` must have passed [`ScannerConfig::problem`].
    pub(crate) fn new(config: &ScannerConfig) -> Self {
        let geometry = config
            .resolved_geometry()
            .expect("validated scanner has a geometry");
        let [first, last] = config.steps.unwrap_or([geometry.amin, geometry.amax]);
        let mount = config.mount();
        let directions_body = (first..=last)
            .map(|k| mount.rotation * geometry.step_direction(f64::from(k)))
            .collect();
        Self {
            config: config.clone(),
            geometry,
            mount,
            first_step: first,
            directions_body,
        }
    }

    pub fn config(&self) -> &ScannerConfig {
        &self.config
    }

    pub fn geometry(&self) -> &ScannerGeometry {
        &self.geometry
    }

    pub fn mount(&self) -> &Mount {
        &self.mount
    }

    pub fn range_sigma_m(&self) -> f64 {
        self.config.range_sigma_m
    }

    /// Casts one revolution starting (step 0) at `t0`, appending to `hits`, if given, the index
    /// of the patch each beam hit. Each beam leaves from the body pose at its own time; the pose
    /// is exact at knots at most [`POSE_KNOT_SPACING_S`] apart and interpolated between them.
    pub(crate) fn cast(
        &self,
        sensor: usize,
        t0: f64,
        trajectory: &Trajectory,
        cast_scene: &mut CastScene,
        rng: &mut ChaCha8Rng,
        mut hits: Option<&mut Vec<Option<usize>>>,
    ) -> Scan {
        let step_period = self.geometry.step_period();
        let t_first = t0 + f64::from(self.first_step) * step_period;
        let mut poses = PoseKnots::new(trajectory, t_first, step_period);
        let mut ranges = Vec::with_capacity(self.directions_body.len());
        let mut hint = None;
        for (i, dir_body) in self.directions_body.iter().enumerate() {
            let t = t_first + i as f64 * step_period;
            let (p, q) = poses.at(i);
            let origin = p + q * self.mount.translation;
            let dir = q * dir_body;
            let hit = cast_scene.cast(t, &origin, &dir, &mut hint);
            if let Some(hits) = hits.as_deref_mut() {
                hits.push(hit.map(|(_, patch)| patch));
            }
            ranges.push(self.report(hit.map(|(range, _)| range), rng));
        }
        Scan {
            sensor,
            t0,
            first_step: self.first_step,
            cluster: 1,
            ranges_m: ranges,
        }
    }

    /// The value the device would send for a true range (metres, 1 mm resolution).
    fn report(&self, true_range: Option<f64>, rng: &mut ChaCha8Rng) -> f64 {
        let model = self.config.model;
        if self.config.dropout_probability > 0.0
            && rng.gen::<f64>() < self.config.dropout_probability
        {
            return model.dropout_m();
        }
        let Some(range) = true_range else {
            return model.no_return_m();
        };
        let noise: f64 = if self.config.range_sigma_m > 0.0 {
            let unit: f64 = StandardNormal.sample(rng);
            self.config.range_sigma_m * unit
        } else {
            0.0
        };
        let measured = ((range + noise) * 1000.0).round() / 1000.0;
        if measured > self.geometry.dmax_m {
            model.no_return_m()
        } else if measured < self.geometry.dmin_m {
            model.too_near_m()
        } else {
            measured
        }
    }
}
