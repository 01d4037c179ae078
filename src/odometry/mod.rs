//! The geometry core of the paper, one stage per file (sections 2 to 3.2): `deskew` -> `lines`
//! -> `planes` (+ `uncertainty`) -> `matching` -> `rotation` and `displacement`.
//!
//! Conventions (contract with integrity and the filter): epoch i is the reference (earlier) and
//! epoch j the current one. The relative pose is `(C, dR)`: `C = C_j^i` rotates body-j vectors
//! into body i (`C n_j = n_i`, eq 3) and `dR` is body j's origin in body-i axes, so that
//! `rho_i - rho_j = n_i . dR` (eq 1). Rotation solutions report `x` as the rotation vector
//! (scaled axis) of C, with covariance of a left perturbation in body-i axes.
//!
//! An [`Odometer`] holds every buffer the stages need, so that in steady state extraction and
//! matching allocate nothing; only the returned solutions (and match list) are new each epoch.

pub mod deskew;
pub(crate) mod displacement;
pub(crate) mod level_lines;
pub mod lines;
pub mod map_config;
pub(crate) mod map_lines;
pub(crate) mod matching;
pub mod planes;
mod ranging_noise;
pub(crate) mod rotation;
#[cfg(test)]
mod single_line_fixtures;
pub mod synthetic;
pub(crate) mod uncertainty;
pub(crate) mod wall_lines;

use crate::config::ConfigErrors;
use crate::least_squares::{Solution, SolveError};
use crate::sensors::{Scan, ScannerSetup};
use deskew::{Beam, Deskewer, DroppedReadings, PoseAt};
use level_lines::{level_planes, LevelLineParameters, Overshoot};
use lines::{LineExtractor, LineParameters, Segment};
pub use map_config::{MapConfig, OdometryMethod};
use map_lines::ScanOfLines;
use matching::{MatchGates, Matcher, PlaneMatch};
use nalgebra::{Matrix3, Matrix3x2, UnitQuaternion, Vector3};
use planes::{Building, Plane, PlaneExtractor, PlaneParameters, ScanLines, Surfaces};
use ranging_noise::RangingNoise;
use rotation::{solve_rotation, RotationParameters};
use serde::{Deserialize, Serialize};
use wall_lines::{wall_planes, WallLineParameters};

/// Settings of the geometry core. Every key has a default; unknown keys are refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OdometryConfig {
    /// How an epoch measures the motion: `"pairs"`, the paper's planes of two lines seen at
    /// once matched scan to scan, or `"map"`, every line on a local map of surfaces
    /// (`[odometry.map]`; docs/design.md, 4.11).
    pub method: OdometryMethod,
    pub map: MapConfig,
    /// Ranging noise (1 sigma, metres) used for scanners whose setup gives none. 0.01 m: the
    /// paper's simulation and the UTM-30LX's +-30 mm read as 3 sigma.
    pub range_sigma_m: f64,
    /// Borges-Aldon breakpoint angle lambda, degrees: consecutive points further apart than a
    /// surface seen at this incidence could put them start a new segment.
    pub breakpoint_lambda_deg: f64,
    /// Noise allowance added to the breakpoint distance, in ranging sigmas.
    pub breakpoint_noise_sigmas: f64,
    /// A segment is split where a point lies further than this from its chord, metres.
    pub split_distance_m: f64,
    /// Fewest points a line may have.
    pub min_line_points: usize,
    /// Shortest line kept, metres.
    pub min_line_length_m: f64,
    /// Smallest distance of the second line's centre from the first line, metres; closer pairs
    /// give an ill-defined normal (eq 25's denominator).
    pub min_line_separation_m: f64,
    /// A second line counts as coplanar if it tilts out of the plane by at most this many
    /// predicted sigmas.
    pub coplanarity_gate_sigmas: f64,
    /// Keep only planes confirmed by a third line (fictitious planes, paper Fig. 3).
    pub require_third_line: bool,
    /// Also build planes from two (nearly) parallel lines, as the paper does. Parallel lines
    /// are always coplanar, so their coplanarity proves nothing: a floor line and a parallel
    /// ceiling line make a fictitious plane (Fig. 3). Off by default; turn on for scanners whose
    /// planes are parallel by construction (e.g. two scanners pitched about the same axis facing
    /// a wall square on). Crossing pairs are still preferred when lines compete.
    pub accept_parallel_lines: bool,
    /// A building's floors are level and its walls plumb within this, degrees, judged by the
    /// filter's attitude (widened by three of its tilt sigmas and of the plane's normal sigma).
    /// A plane from two lines is kept only if it is one or the other: two lines that meet are
    /// coplanar whatever surfaces they lie on (a wall line and a line on a box face meet where
    /// the face meets the wall), and parallel lines always are, so the fictitious planes they
    /// make in a building lean between the surfaces they join (`accept_parallel_lines` keeps
    /// every one, as the paper does). And a level plane may be the only one facing a direction
    /// (`[integrity] lone_plane_*`): floors do not walk. A measured floor or ceiling gives a
    /// filter that lost its vertical its tilt back (`fusion/building_vertical.rs`). 90 says the
    /// scene is not a building.
    pub building_max_tilt_deg: f64,
    /// In a building, a level line that the other scanner's beams overshoot in its bearing
    /// also makes a plane, level through the line (a floor, a table top), which observes the
    /// vertical where only one scanner sees the floor (`level_lines.rs`). Not with
    /// `accept_parallel_lines`, which keeps the paper's planes only.
    pub level_lines: bool,
    /// In a building, a line that no pair took and that a wall must carry (it slopes, or it is
    /// level and stands above where the other scanner's beams end in its bearing) also makes a
    /// plane, plumb through the line, which observes the motion toward the walls only one
    /// scanner sees (`wall_lines.rs`). Not with `accept_parallel_lines`.
    pub wall_lines: bool,
    /// Planes whose normal sigma exceeds this, degrees, are dropped: they add little and their
    /// error is no longer linear in the noise (predicted sigmas turn optimistic).
    pub max_sigma_normal_deg: f64,
    /// Chi-square gate (3 degrees of freedom) on a plane match's normal and distance under the
    /// prior; 30.66 is the 1 - 1e-6 point. It only associates: a static plane it refuses is
    /// refused because the predicted distance (the filter's velocity) is off, and when that
    /// plane alone sees an axis the filter then dead-reckons along it on exactly its worst
    /// velocities. A gate at the 99.9 % point made the 1 Hz hover's along-track position
    /// optimistic by that selection (docs/accuracy.md, "The match gate", has the study).
    pub match_gate_chi2: f64,
    /// Chi-square gate (2 degrees of freedom) on the normal alone; 13.82 is the 99.9 % point.
    /// The normal is predicted with the gyro's rotation, so this one stays a real test: it
    /// keeps a turning door's plane from being matched at all.
    pub match_normal_gate_chi2: f64,
    /// Most Gauss-Newton steps of the rotation solve.
    pub rotation_max_iterations: usize,
    /// The rotation solve stops once a correction is below this, radians.
    pub rotation_tolerance_rad: f64,
}

impl Default for OdometryConfig {
    fn default() -> Self {
        Self {
            method: OdometryMethod::Map,
            map: MapConfig::default(),
            range_sigma_m: 0.01,
            breakpoint_lambda_deg: 10.0,
            breakpoint_noise_sigmas: 3.0,
            split_distance_m: 0.05,
            min_line_points: 10,
            min_line_length_m: 0.3,
            min_line_separation_m: 0.15,
            coplanarity_gate_sigmas: 5.0,
            require_third_line: false,
            accept_parallel_lines: false,
            building_max_tilt_deg: 3.0,
            level_lines: true,
            wall_lines: true,
            max_sigma_normal_deg: 0.5,
            match_gate_chi2: 30.66,
            match_normal_gate_chi2: 13.82,
            rotation_max_iterations: 10,
            rotation_tolerance_rad: 1e-10,
        }
    }
}

impl OdometryConfig {
    /// The two match gates, as the matcher takes them.
    pub(crate) fn match_gates(&self) -> MatchGates {
        MatchGates {
            total_chi2: self.match_gate_chi2,
            normal_chi2: self.match_normal_gate_chi2,
        }
    }

    /// Adds every problem of the table to `errors`.
    pub(crate) fn check(&self, errors: &mut ConfigErrors) {
        self.map.check(errors);
        let mut odometry = errors.table("odometry");
        let positive = "set it to a finite number above 0";
        let checks = [
            (
                "range_sigma_m",
                self.range_sigma_m,
                self.range_sigma_m > 0.0,
                positive,
            ),
            (
                "breakpoint_lambda_deg",
                self.breakpoint_lambda_deg,
                self.breakpoint_lambda_deg > 0.0 && self.breakpoint_lambda_deg < 90.0,
                "set it between 0 and 90 degrees",
            ),
            (
                "breakpoint_noise_sigmas",
                self.breakpoint_noise_sigmas,
                self.breakpoint_noise_sigmas >= 0.0,
                "set it to 0 or more",
            ),
            (
                "split_distance_m",
                self.split_distance_m,
                self.split_distance_m > 0.0,
                positive,
            ),
            (
                "min_line_length_m",
                self.min_line_length_m,
                self.min_line_length_m > 0.0,
                positive,
            ),
            (
                "min_line_separation_m",
                self.min_line_separation_m,
                self.min_line_separation_m > 0.0,
                positive,
            ),
            (
                "coplanarity_gate_sigmas",
                self.coplanarity_gate_sigmas,
                self.coplanarity_gate_sigmas > 0.0,
                positive,
            ),
            (
                "building_max_tilt_deg",
                self.building_max_tilt_deg,
                self.building_max_tilt_deg > 0.0 && self.building_max_tilt_deg <= 90.0,
                "set it above 0 and at most 90 degrees (90: the scene is not a building)",
            ),
            (
                "max_sigma_normal_deg",
                self.max_sigma_normal_deg,
                self.max_sigma_normal_deg > 0.0,
                positive,
            ),
            (
                "match_gate_chi2",
                self.match_gate_chi2,
                self.match_gate_chi2 > 0.0,
                positive,
            ),
            (
                "match_normal_gate_chi2",
                self.match_normal_gate_chi2,
                self.match_normal_gate_chi2 > 0.0,
                positive,
            ),
            (
                "rotation_tolerance_rad",
                self.rotation_tolerance_rad,
                self.rotation_tolerance_rad > 0.0,
                positive,
            ),
        ];
        for (key, value, ok, fix) in checks {
            odometry.check(ok && value.is_finite(), key, value, fix);
        }
        odometry.check(
            self.min_line_points >= 3,
            "min_line_points",
            self.min_line_points,
            "set it to 3 or more",
        );
        odometry.check(
            self.rotation_max_iterations >= 1,
            "rotation_max_iterations",
            self.rotation_max_iterations,
            "set it to 1 or more",
        );
    }

    /// Line-extraction parameters for a scanner with this ranging sigma.
    pub(crate) fn line_parameters(&self, range_sigma_m: f64) -> LineParameters {
        LineParameters {
            breakpoint_lambda_rad: self.breakpoint_lambda_deg.to_radians(),
            breakpoint_noise_m: self.breakpoint_noise_sigmas * range_sigma_m,
            split_distance_m: self.split_distance_m,
            min_points: self.min_line_points,
            min_length_m: self.min_line_length_m,
        }
    }

    /// The building's vertical in body axes, if the scene is a building and the filter knows
    /// its attitude (`down`, the downward vertical).
    pub(crate) fn building(&self, down: Option<Vector3<f64>>) -> Option<Building> {
        let max_tilt_rad = self.building_max_tilt_deg.to_radians();
        down.filter(|_| self.building_max_tilt_deg < 90.0)
            .map(|down| Building { down, max_tilt_rad })
    }

    /// The building single lines of a kind (`enabled`) may make planes in, with the filter's
    /// tilt sigma: only while the filter knows its vertical to `max_vertical_sigma_rad`, since
    /// their normals are set by it, and never with `accept_parallel_lines`, which keeps the
    /// paper's planes only.
    fn single_line_building(
        &self,
        enabled: bool,
        vertical: Option<Vertical>,
        max_vertical_sigma_rad: f64,
    ) -> Option<(Building, f64)> {
        let known = vertical
            .filter(|v| v.sigma_rad <= max_vertical_sigma_rad)
            .filter(|_| enabled && !self.accept_parallel_lines)?;
        self.building(Some(known.down))
            .map(|building| (building, known.sigma_rad))
    }

    /// How level lines become planes, when they do.
    pub(crate) fn level_line_parameters(
        &self,
        vertical: Option<Vertical>,
    ) -> Option<LevelLineParameters> {
        let (building, _) = self.single_line_building(
            self.level_lines,
            vertical,
            SINGLE_LINE_MAX_VERTICAL_SIGMA_RAD,
        )?;
        Some(LevelLineParameters {
            building,
            min_depth_m: LEVEL_LINE_MIN_DEPTH_M,
            overshoot: LEVEL_SURFACE_OVERSHOOT,
            tilt_sigma_rad: SINGLE_LINE_TILT_SIGMA_RAD,
        })
    }

    /// How single lines become plumb planes, when they do.
    pub(crate) fn wall_line_parameters(
        &self,
        vertical: Option<Vertical>,
    ) -> Option<WallLineParameters> {
        let (building, vertical_sigma_rad) =
            self.single_line_building(self.wall_lines, vertical, WALL_LINE_MAX_VERTICAL_SIGMA_RAD)?;
        Some(WallLineParameters {
            building: building.judged_by(vertical_sigma_rad),
            max_slope_rad: WALL_LINE_MAX_SLOPE_DEG.to_radians(),
            min_level_length_m: WALL_LINE_MIN_LEVEL_LENGTH_M,
            margin_m: WALL_LINE_MARGIN_M,
            vertical_sigma_rad,
            bearing_half_width_rad: SINGLE_LINE_BEARING_HALF_WIDTH_DEG.to_radians(),
            tilt_sigma_rad: SINGLE_LINE_TILT_SIGMA_RAD.hypot(vertical_sigma_rad),
        })
    }

    /// Plane-extraction parameters, given the downward vertical in body axes when the filter
    /// knows it.
    pub(crate) fn plane_parameters(&self, vertical: Option<Vertical>) -> PlaneParameters {
        let building = vertical.and_then(|v| Some((self.building(Some(v.down))?, v.sigma_rad)));
        let surfaces = match building {
            _ if self.accept_parallel_lines => Surfaces::All,
            Some((building, vertical_sigma_rad)) => Surfaces::Building {
                building,
                vertical_sigma_rad,
                level_overshoot: LEVEL_SURFACE_OVERSHOOT,
            },
            None => Surfaces::Crossing,
        };
        PlaneParameters {
            min_separation_m: self.min_line_separation_m,
            coplanarity_gate_sigmas: self.coplanarity_gate_sigmas,
            require_third_line: self.require_third_line,
            surfaces,
            max_sigma_normal_rad: self.max_sigma_normal_deg.to_radians(),
        }
    }

    pub(crate) fn rotation_parameters(&self) -> RotationParameters {
        RotationParameters {
            max_iterations: self.rotation_max_iterations,
            tolerance_rad: self.rotation_tolerance_rad,
        }
    }
}

/// Relative pose between epochs i and j with its uncertainty: a prior (from the IMU) or a result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativePose {
    /// C = C_j^i, rotating body-j vectors into body i.
    pub rotation: UnitQuaternion<f64>,
    /// dR: body j's origin in body-i axes, metres.
    pub translation: Vector3<f64>,
    /// Covariance of a left rotation perturbation in body-i axes, rad^2.
    pub rotation_covariance: Matrix3<f64>,
    /// Covariance of dR, m^2.
    pub translation_covariance: Matrix3<f64>,
}

impl RelativePose {
    /// No motion, known to the given 1-sigma angle and distance.
    pub fn stationary(sigma_rad: f64, sigma_m: f64) -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
            rotation_covariance: Matrix3::identity() * sigma_rad.powi(2),
            translation_covariance: Matrix3::identity() * sigma_m.powi(2),
        }
    }
}

/// The planes of one epoch in the body frame at its reference time.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EpochPlanes {
    /// Reference time of the epoch, seconds.
    pub t_ref: f64,
    pub planes: Vec<Plane>,
    /// Readings dropped per scanner, by reason.
    pub dropped: [DroppedReadings; 2],
    /// Valid readings per scanner.
    pub readings: [usize; 2],
    /// Lines found per scanner.
    pub lines: [usize; 2],
    /// The ranging sigma each scanner's lines were weighed with, m: the configured one, or
    /// what the lines showed if worse.
    pub range_sigma_m: [f64; 2],
    /// The planes the lines make without the admission test of
    /// `Odometer::extract_admitted_into`, when it refused any (empty otherwise: they are
    /// `planes`). With `planes`, what a later epoch's planes are confirmed against.
    pub unscreened: Vec<Plane>,
    /// Candidates `admit` refused whose lines were still free: left out for want of
    /// confirmation, their lines given to other pairs.
    pub refused: usize,
    /// The downward vertical in these body axes, when the filter knew its attitude.
    pub down: Option<Vector3<f64>>,
}

/// Keeps the planes through one line that `admit` refused among the epoch's unscreened
/// planes, so that later epochs can be confirmed against them. Without them a floor refused
/// once (the keyframe's prior off for a moment) was refused in every later epoch: no keyframe
/// held it any more, as a level line's plane has no pair to be found again without the test.
fn remember_unscreened_single_lines(out: &mut EpochPlanes, from_pairs: usize, refused: &[Plane]) {
    out.refused += refused.len();
    if refused.is_empty() {
        return;
    }
    if out.unscreened.is_empty() {
        out.unscreened.extend_from_slice(&out.planes[..from_pairs]);
    }
    out.unscreened.extend_from_slice(&out.planes[from_pairs..]);
    out.unscreened.extend_from_slice(refused);
}

/// The outcome of one epoch pair: matches and both solves, re-solvable with exclusions.
#[derive(Debug, Clone, PartialEq)]
pub struct OdometryEpoch {
    pub matches: Vec<PlaneMatch>,
    pub prior: RelativePose,
    /// Indices into `matches` left out of both solves.
    pub excluded: Vec<usize>,
    /// `x` = rotation vector of C_j^i; see `rotation`.
    pub rotation: Result<Solution, SolveError>,
    /// `x` = dR; see `displacement`.
    pub displacement: Result<Solution, SolveError>,
}

impl OdometryEpoch {
    /// `excluded` and the matches this epoch already left out of its solves.
    pub(crate) fn excluding(&self, excluded: &[usize]) -> Vec<usize> {
        let mut all = self.excluded.clone();
        all.extend_from_slice(excluded);
        all
    }

    /// The solved relative pose, when both solves succeeded.
    pub fn relative_pose(&self) -> Option<RelativePose> {
        let rotation = self.rotation.as_ref().ok()?;
        let displacement = self.displacement.as_ref().ok()?;
        Some(RelativePose {
            rotation: UnitQuaternion::from_scaled_axis(rotation.x),
            translation: displacement.x,
            rotation_covariance: rotation.covariance,
            translation_covariance: displacement.covariance,
        })
    }
}

/// A level line nearer the body origin's level than this (m) may be anything.
const LEVEL_LINE_MIN_DEPTH_M: f64 = 0.3;
/// The bearing in which the other scanner's beams are looked for, half-width in degrees.
const SINGLE_LINE_BEARING_HALF_WIDTH_DEG: f64 = 10.0;
/// What shows a level line to lie on a level surface rather than on a wall: the other
/// scanner's beams in its bearing pass it by 0.3 m, a few times the ranging noise and a wall's
/// skirting.
const LEVEL_SURFACE_OVERSHOOT: Overshoot = Overshoot {
    margin_m: 0.3,
    bearing_half_width_rad: SINGLE_LINE_BEARING_HALF_WIDTH_DEG * std::f64::consts::PI / 180.0,
};
/// How far the filter's vertical and a building's floor or wall may be from level or plumb
/// together, rad: a single-line plane's tilt sigma about its line (a converged tilt is good to
/// a milliradian or two, a floor or a wall to a few over the few metres seen).
const SINGLE_LINE_TILT_SIGMA_RAD: f64 = 0.003;
/// Level lines make planes only while the filter's tilt sigma is at most this, rad: just after
/// a start in motion the vertical is known to degrees, and each correction would move a level
/// plane's distance by the line's reach times the turn.
const SINGLE_LINE_MAX_VERTICAL_SIGMA_RAD: f64 = 0.01;

/// Wall lines make planes while the filter's tilt sigma is at most this, rad: a start in
/// motion's (3 degrees). A plumb plane's normal is level and square to its line, so the
/// vertical's error only tips it about the line, which moves the distance by the line's height
/// over the body times the error: its covariance carries that, and the level test that tells a
/// wall's level line from a sloping one is widened by three sigmas of it. Held to 10 mrad like
/// level lines, the open room and the corridor started in motion had no plane along them
/// until the tilt converged, and the tilt converged only through that motion.
const WALL_LINE_MAX_VERTICAL_SIGMA_RAD: f64 = 0.06;

/// Single lines steeper than this, degrees from level, make no plumb plane.
const WALL_LINE_MAX_SLOPE_DEG: f64 = 60.0;
/// A level single line is taken for a wall only from this length (m): deeper than a table.
const WALL_LINE_MIN_LEVEL_LENGTH_M: f64 = 1.2;
/// The sigma (m) of where a beam of the other scanner ends against a level line, for the
/// test that the line stands clear of what those beams meet (`WallLineParameters::margin_m`):
/// ranging, and a floor's or a ceiling's unevenness.
const WALL_LINE_MARGIN_M: f64 = 0.02;

/// The filter's downward vertical in body axes at an epoch, with its tilt sigma (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vertical {
    pub down: Vector3<f64>,
    pub sigma_rad: f64,
}

/// The geometry core with its reusable buffers.
#[derive(Debug, Clone)]
pub struct Odometer {
    config: OdometryConfig,
    scanners: [ScannerSetup; 2],
    deskewers: [Deskewer; 2],
    beams: [Vec<Beam>; 2],
    segments: [Vec<Segment>; 2],
    lines: LineExtractor,
    planes: PlaneExtractor,
    /// Which lines the pairs took, for the level lines.
    paired: [Vec<bool>; 2],
    /// Planes through one line that the admission test refused, reused between epochs.
    refused_single_line: Vec<Plane>,
    matcher: Matcher,
    /// What each scanner's lines show of its ranging noise (`ranging_noise`).
    ranging_noise: [RangingNoise; 2],
}

impl Odometer {
    pub fn new(scanners: [ScannerSetup; 2], config: OdometryConfig) -> Result<Self, ConfigErrors> {
        ConfigErrors::collect(|errors| {
            config.check(errors);
            for (k, scanner) in scanners.iter().enumerate() {
                if let Some(sigma) = scanner.range_sigma_m {
                    errors.table(&format!("scanner[{k}]")).check(
                        sigma > 0.0 && sigma.is_finite(),
                        "range_sigma_m",
                        sigma,
                        "set it to a finite number above 0",
                    );
                }
            }
        })?;
        Ok(Self {
            config,
            scanners,
            deskewers: Default::default(),
            beams: Default::default(),
            segments: Default::default(),
            lines: LineExtractor::default(),
            planes: PlaneExtractor::default(),
            paired: [Vec::new(), Vec::new()],
            refused_single_line: Vec::new(),
            matcher: Matcher::default(),
            ranging_noise: Default::default(),
        })
    }

    pub(crate) fn config(&self) -> &OdometryConfig {
        &self.config
    }

    /// Lines of scanner `k` from the latest extraction, indexing `beams(k)`.
    pub fn lines(&self, k: usize) -> &[Segment] {
        &self.segments[k]
    }

    /// Scanner `k`'s lines from the latest extraction, as the plane map measures with them.
    pub(crate) fn scan_of_lines(&self, k: usize) -> ScanOfLines<'_> {
        ScanOfLines {
            segments: &self.segments[k],
            beams: &self.beams[k],
            range_sigma_m: self.range_sigma(k),
            scan_normal: self.scanners[k].mount.rotation * Vector3::z(),
        }
    }

    /// Scanner `scanner`'s ranging sigma: as configured, or what its lines show if worse.
    fn range_sigma(&self, scanner: usize) -> f64 {
        let configured = self.scanners[scanner]
            .range_sigma_m
            .unwrap_or(self.config.range_sigma_m);
        self.ranging_noise[scanner].sigma_at_least(configured)
    }

    /// Planes of one epoch: `scans[k]` is scanner k's scan; `pose_at(t)` is the body pose at
    /// time t relative to the body at `t_ref` (identity when stationary).
    pub(crate) fn extract(
        &mut self,
        scans: [&Scan; 2],
        t_ref: f64,
        pose_at: PoseAt<'_>,
    ) -> EpochPlanes {
        let mut out = EpochPlanes::default();
        self.extract_into(scans, t_ref, pose_at, &mut out);
        out
    }

    /// As `extract`, reusing `out`'s storage (no allocation once it has grown).
    pub fn extract_into(
        &mut self,
        scans: [&Scan; 2],
        t_ref: f64,
        pose_at: PoseAt<'_>,
        out: &mut EpochPlanes,
    ) {
        self.extract_admitted_into(scans, t_ref, pose_at, None, &mut |_| true, out);
    }

    /// `extract_into` with the filter's vertical known, as the fusion extracts once aligned:
    /// in a building single lines make planes too (`level_lines`, `wall_lines`).
    pub fn extract_with_vertical_into(
        &mut self,
        scans: [&Scan; 2],
        t_ref: f64,
        pose_at: PoseAt<'_>,
        vertical: Vertical,
        out: &mut EpochPlanes,
    ) {
        self.extract_admitted_into(scans, t_ref, pose_at, Some(vertical), &mut |_| true, out);
    }

    /// As `extract_into`, keeping only the planes `admit` accepts: a refused candidate does
    /// not take its lines, which stay free for the next pair. `down`, the downward vertical in
    /// body axes at `t_ref` when the filter knows it, lets a building's level and plumb planes
    /// from parallel lines in (`building_max_tilt_deg`).
    pub(crate) fn extract_admitted_into(
        &mut self,
        scans: [&Scan; 2],
        t_ref: f64,
        pose_at: PoseAt<'_>,
        vertical: Option<Vertical>,
        admit: &mut dyn FnMut(&Plane) -> bool,
        out: &mut EpochPlanes,
    ) {
        let down = vertical.map(|v| v.down);
        out.t_ref = t_ref;
        out.down = down;
        for (k, scan) in scans.into_iter().enumerate() {
            let setup = &self.scanners[k];
            out.dropped[k] = self.deskewers[k].deskew(
                scan,
                &setup.geometry,
                &setup.mount,
                pose_at,
                &mut self.beams[k],
            );
            out.readings[k] = self.beams[k].len();
            let parameters = self.config.line_parameters(self.range_sigma(k));
            self.lines
                .extract(&self.beams[k], &parameters, &mut self.segments[k]);
            self.ranging_noise[k].observe(&self.segments[k]);
            out.lines[k] = self.segments[k].len();
        }
        let sigmas = [self.range_sigma(0), self.range_sigma(1)];
        out.range_sigma_m = sigmas;
        let scan_lines = [0, 1].map(|k| ScanLines {
            segments: &self.segments[k],
            beams: &self.beams[k],
            range_sigma: sigmas[k],
        });
        out.refused = self.planes.extract(
            scan_lines,
            &self.config.plane_parameters(vertical),
            admit,
            &mut out.planes,
            &mut out.unscreened,
        );
        let level = self.config.level_line_parameters(vertical);
        let walls = self.config.wall_line_parameters(vertical);
        if level.is_none() && walls.is_none() {
            return;
        }
        for (paired, segments) in self.paired.iter_mut().zip(&self.segments) {
            paired.clear();
            paired.resize(segments.len(), false);
        }
        for line in out.planes.iter().flat_map(|plane| plane.lines) {
            self.paired[line.scanner][line.segment] = true;
        }
        let from_pairs = out.planes.len();
        let mut refused = std::mem::take(&mut self.refused_single_line);
        refused.clear();
        let mut screen = |plane: &Plane| {
            let admitted = admit(plane);
            if !admitted {
                refused.push(*plane);
            }
            admitted
        };
        if let Some(parameters) = level {
            level_planes(
                &scan_lines,
                &mut self.paired,
                &parameters,
                &mut screen,
                &mut out.planes,
            );
        }
        if let Some(parameters) = walls {
            wall_planes(
                &scan_lines,
                &mut self.paired,
                &parameters,
                &mut screen,
                &mut out.planes,
            );
        }
        remember_unscreened_single_lines(out, from_pairs, &refused);
        self.refused_single_line = refused;
    }

    /// Matches `current` (epoch j) to `previous` (epoch i) under `prior` and solves both.
    pub fn solve(
        &mut self,
        previous: &EpochPlanes,
        current: &EpochPlanes,
        prior: &RelativePose,
    ) -> OdometryEpoch {
        self.solve_doubting_under(previous, current, prior, prior)
    }

    /// As `solve`, a pairing in doubt under `doubt_prior`: a prior vaguer along directions
    /// where `prior` is only a doubtful plane's word (`fusion::witnesses`).
    pub fn solve_doubting_under(
        &mut self,
        previous: &EpochPlanes,
        current: &EpochPlanes,
        prior: &RelativePose,
        doubt_prior: &RelativePose,
    ) -> OdometryEpoch {
        let mut matches = Vec::new();
        self.matcher.match_planes(
            &previous.planes,
            &current.planes,
            [prior, doubt_prior],
            &self.config.match_gates(),
            &mut matches,
        );
        self.solve_matched(previous, current, matches, prior, &[])
    }

    /// Solves `epoch`'s matches again without the matches listed in `excluded`, nor those
    /// `epoch` already left out.
    pub fn resolve(
        &self,
        previous: &EpochPlanes,
        current: &EpochPlanes,
        epoch: &OdometryEpoch,
        excluded: &[usize],
    ) -> OdometryEpoch {
        self.solve_matched(
            previous,
            current,
            epoch.matches.clone(),
            &epoch.prior,
            &epoch.excluding(excluded),
        )
    }

    fn solve_matched(
        &self,
        previous: &EpochPlanes,
        current: &EpochPlanes,
        matches: Vec<PlaneMatch>,
        prior: &RelativePose,
        excluded: &[usize],
    ) -> OdometryEpoch {
        let (i, j) = (&previous.planes, &current.planes);
        let rotation = solve_rotation(
            i,
            j,
            &matches,
            &prior.rotation,
            excluded,
            &self.config.rotation_parameters(),
        );
        let solved_rotation = rotation
            .as_ref()
            .ok()
            .map(|s| UnitQuaternion::from_scaled_axis(s.x));
        let displacement = displacement::solve_displacement(
            i,
            j,
            &matches,
            solved_rotation.as_ref(),
            &prior.translation,
            &prior.translation_covariance,
            excluded,
        );
        OdometryEpoch {
            matches,
            prior: *prior,
            excluded: excluded.to_vec(),
            rotation,
            displacement,
        }
    }
}

/// Readings whose beam meets a surface at a smaller cosine are not slid onto it: along a
/// grazing beam the slide would move them further than their noise.
const MIN_SLIDE_COSINE: f64 = 0.1;

/// A reading `height` off a plane of normal `normal`, slid along its beam onto that plane.
/// Ranging noise moves a reading along its beam, so where the beam meets the surface carries
/// none of it, while the reading's own position along the surface does at oblique incidence,
/// correlated with its offset: fits that regress offsets on it tilt towards the beams (errors
/// in variables).
fn slid_along_beam(beam: &Beam, height: f64, normal: &Vector3<f64>) -> Vector3<f64> {
    let cosine = normal.dot(&beam.direction);
    if cosine.abs() < MIN_SLIDE_COSINE {
        beam.body
    } else {
        beam.body - beam.direction * (height / cosine)
    }
}

/// Orthonormal basis (3x2) of the plane perpendicular to the unit vector `n`.
pub(crate) fn tangent_basis(n: &Vector3<f64>) -> Matrix3x2<f64> {
    let helper = if n.x.abs() < 0.6 {
        Vector3::x()
    } else if n.y.abs() < 0.6 {
        Vector3::y()
    } else {
        Vector3::z()
    };
    let first = n.cross(&helper).normalize();
    Matrix3x2::from_columns(&[first, n.cross(&first)])
}

#[cfg(test)]
mod tests;
