//! What one odometry epoch did, for epochs.jsonl: the planes, the matches, the integrity
//! evidence, the relative pose that was fused and the filter's verdict on it.

use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

use super::witnesses::epochs_per_baseline;
use crate::estimate::IntegrityStatus;
use crate::filter::{surprises_one_of, UpdateReport};
use crate::integrity::{EpochReport, SolveKind};
use crate::odometry::deskew::DroppedReadings;
use crate::odometry::planes::Plane;

pub use super::witnesses::Check;

/// How an epoch ended.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum EpochOutcome {
    /// The epoch only became the reference of the next one: it is the first, the filter was not
    /// aligned yet, or the previous epoch fell out of the pose history (IMU gap, stale scanner).
    Reference,
    /// Integrity cleared at least one of rotation and displacement and the filter fused it.
    Fused,
    /// The filter's innovation gate refused the relative pose.
    RejectedByGate,
    /// Nothing was fit to fuse: see `integrity` (fault not isolable, too few planes).
    NotFused,
    /// The filter could not take the measurement (e.g. the scans arrived too late).
    UpdateFailed { reason: String },
}

/// A three-vector with its covariance, as fused.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WithCovariance {
    pub value: [f64; 3],
    pub covariance: [[f64; 3]; 3],
}

impl WithCovariance {
    pub(crate) fn new(value: &Vector3<f64>, covariance: &Matrix3<f64>) -> Self {
        Self {
            value: (*value).into(),
            covariance: (*covariance).into(),
        }
    }
}

/// The filter's verdict on an epoch's relative pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct UpdateSummary {
    /// Normalised innovation squared over the observable rows.
    pub nis: f64,
    /// Observable rows fused.
    pub dof: usize,
    /// Gate threshold on the NIS.
    pub threshold: f64,
    pub accepted: bool,
}

impl UpdateSummary {
    /// Whether its NIS surprises one of the updates of the paper's second at epochs
    /// `interval_s` apart (`filter::surprises_one_of`): what it fused then vouches for nothing
    /// held in doubt (`witnesses::Provisional`).
    pub(crate) fn surprising(&self, interval_s: f64) -> bool {
        surprises_one_of(self.nis, self.dof, epochs_per_baseline(interval_s))
    }
}

impl From<&UpdateReport> for UpdateSummary {
    fn from(report: &UpdateReport) -> Self {
        Self {
            nis: report.nis,
            dof: report.dof,
            threshold: report.threshold,
            accepted: report.accepted,
        }
    }
}

/// A direction of one solve that a single plane alone faced.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LoneDirection {
    pub solve: SolveKind,
    pub direction: [f64; 3],
    pub check: Check,
}

/// A plane as `normal . p = rho` in its epoch's body axes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PlaneGeometry {
    pub normal: [f64; 3],
    pub rho: f64,
}

impl From<&Plane> for PlaneGeometry {
    fn from(plane: &Plane) -> Self {
        Self {
            normal: plane.normal.into(),
            rho: plane.rho,
        }
    }
}

/// One line of epochs.jsonl.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EpochRecord {
    /// Reference time of this epoch (mid-scan time of scanner 0), host seconds.
    pub t: f64,
    /// Reference time of the epoch it was matched against.
    pub t_previous: Option<f64>,
    #[serde(flatten)]
    pub outcome: EpochOutcome,
    /// Valid readings per scanner.
    pub readings: [usize; 2],
    /// Readings dropped per scanner, by reason.
    pub dropped: [DroppedReadings; 2],
    /// Lines extracted per scanner.
    pub lines: [usize; 2],
    /// The ranging sigma each scanner's lines were weighed with, m: `range_sigma_m`, or what
    /// the lines showed if the scanner ranged worse (`odometry/ranging_noise.rs`).
    pub range_sigma_m: [f64; 2],
    /// Planes built with a line of each scanner (a plane may count for both).
    pub planes_per_scanner: [usize; 2],
    pub planes: usize,
    /// Each plane's unit normal (body i axes) and distance, by id: enough to draw the epoch.
    pub plane_geometry: Vec<PlaneGeometry>,
    /// Plane pairs matched with the previous epoch.
    pub matched: usize,
    /// Matches in the fused solves (after exclusion).
    pub used: usize,
    /// Ids (in this epoch's planes) of the planes integrity excluded.
    pub excluded_planes: Vec<usize>,
    /// Ids of the level planes left out because their height wandered against the other level
    /// planes' (`fusion/level_drift.rs`): a line on a low face taken for a floor.
    pub wandering_level_planes: Vec<usize>,
    /// Planes left out for want of confirmation (`fusion.plane_confirmation_s`): candidates
    /// no plane of the epoch that far back agrees with, whose lines went to other pairs; and,
    /// while the filter's poses do not reach that far back yet, every plane (none is matched).
    pub unconfirmed_planes: usize,
    /// Directions (body i) no matched plane constrained: anchored to the filter's prior for
    /// the solve and left out of the fused displacement.
    pub unobservable_displacement: Vec<[f64; 3]>,
    /// Directions (body i) one plane alone faced, not taken for a wall or a floor, with what the
    /// filter's prediction made of each (`fusion/witnesses.rs`).
    pub lone_directions: Vec<LoneDirection>,
    /// Directions fused on a lone plane's word that still wait for a check after this epoch:
    /// while any does, the estimate is not converged.
    pub provisional_directions: usize,
    /// Verdict of the integrity monitor, when the epoch was solved.
    pub status: Option<IntegrityStatus>,
    /// Test statistics, thresholds, minimum detectable biases and protection levels.
    pub integrity: Option<EpochReport>,
    /// Rotation vector of `C_j^i` (body j -> body i), rad, with the covariance given to the
    /// filter (right perturbation, body-j axes).
    pub rotation: Option<WithCovariance>,
    /// Body j's origin in body-i axes, m, with its covariance.
    pub displacement: Option<WithCovariance>,
    pub update: Option<UpdateSummary>,
    /// The filter's verdict on each floor or ceiling fused as the vertical, when it had lost
    /// it (`fusion/building_vertical.rs`).
    pub level_surfaces: Vec<UpdateSummary>,
    /// What the plane map did (`odometry.method = "map"`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub map: Option<super::map_epoch::MapEpoch>,
}
