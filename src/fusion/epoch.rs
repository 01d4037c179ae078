//! One odometry epoch: deskew and extract the planes at the reference time, match and solve
//! against the previous epoch under the filter's prior, test integrity, and fuse what passed
//! against the clone of the previous epoch's pose; then clone the pose at this epoch.

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

use super::anchor::Anchored;
use super::deskew_basis::DeskewBasis;
use super::record::{EpochOutcome, EpochRecord, PlaneGeometry, UpdateSummary, WithCovariance};
use super::shared_noise::{NoiseMaps, PlaneNoiseMap};
use super::witnesses::{CheckedLone, LoneWitnesses};
use super::{Fusion, Reference};
use crate::estimate::IntegrityStatus;
use crate::filter::{
    Eskf, FilterPhase, Observability, Pose, RelativePoseMeasurement, RelativeRotation,
    RelativeTranslation,
};
use crate::integrity::EpochReport;
use crate::least_squares::Solution;
use crate::odometry::matching;
use crate::odometry::planes::Plane;
use crate::odometry::{EpochPlanes, OdometryEpoch, OdometryMethod, RelativePose, Vertical};
use crate::sensors::Scan;

/// How an epoch's planes are confirmed (`confirmation`).
// It lives on the stack for one call; boxing the prior would allocate every epoch.
#[allow(clippy::large_enum_variant)]
enum Confirmation {
    /// The test is off, or the previous epoch is already a baseline back.
    NotNeeded,
    /// No remembered epoch is a baseline back, or the filter cannot bridge it yet.
    Unavailable,
    /// Against the remembered epoch `keyframe`, under the filter's relative pose from it.
    Against {
        keyframe: usize,
        prior: RelativePose,
    },
}

/// What solving an epoch against the one before leaves for the next.
#[derive(Default)]
struct SolvedEpoch {
    /// How the epoch's planes entered the relative pose (`shared_noise`).
    noise_maps: Vec<PlaneNoiseMap>,
    /// The epoch's planes matched to the epoch before and kept by integrity.
    matched: Vec<usize>,
}

/// The solves integrity let through, with the matches they left out.
struct Cleared {
    rotation: Option<Solution>,
    displacement: Option<Solution>,
    /// Directions of the rotation (left perturbation, body-i axes) no test protects.
    rotation_unprotected: Vec<Vector3<f64>>,
    /// Observable directions of the displacement: all but the anchored ones and those no test
    /// protects.
    displacement_observability: Observability,
    excluded: Vec<usize>,
    /// The directions one plane alone observes, with the filter prediction's check.
    lone: CheckedLone,
}

impl Fusion {
    pub(super) fn run_epoch(&mut self, scans: &[Scan; 2], t_ref: f64) -> EpochRecord {
        self.forget_provisional_after_restart();
        let deskew = DeskewBasis::of(
            scans,
            scans
                .each_ref()
                .map(|scan| &self.scanners[scan.sensor].geometry),
            t_ref,
            self.filter.velocity_corrections(),
        );
        let mut current = std::mem::take(&mut self.current);
        let confirmed = self.extract(scans, t_ref, &mut current);
        let mut record = planes_record(&current);
        let mut reference = self.reference.take();
        if let Some(r) = &mut reference {
            r.deskew
                .widen(&deskew, &self.filter.state().q, &mut r.planes.planes);
        }
        let solvable = reference.as_ref().filter(|r| r.cloned);
        record.unconfirmed_planes = match (confirmed, solvable) {
            (true, _) => current.refused,
            (false, Some(_)) => current.planes.len(),
            (false, None) => 0,
        };
        let mut solved = SolvedEpoch::default();
        match solvable.filter(|_| confirmed) {
            Some(reference) => {
                record.t_previous = Some(reference.planes.t_ref);
                solved = self.solve_and_fuse(reference, &current, &mut record);
            }
            None => self.level_drift.forget(),
        }
        record.level_surfaces = self.level_from_building(&current.planes);
        if self.config.confirms_planes() {
            let (baseline, tolerance) = self.confirmation_baseline();
            self.recent.remember(&current, baseline, tolerance);
        }
        let cloned = self.filter.clone_pose().is_ok();
        self.reference = Some(Reference {
            planes: current,
            cloned,
            deskew,
            noise_maps: solved.noise_maps,
            matched: solved.matched,
        });
        self.current = reference.map(|r| r.planes).unwrap_or_default();
        record
    }

    /// Planes of the two scans in the body frame at `t_ref`, deskewed with the filter's poses
    /// (no motion assumed before the filter is aligned), each confirmed by the keyframe
    /// (`confirmation`) when the test applies. Returns false when it applies but there is no
    /// keyframe the filter can bridge yet: then no plane is confirmed.
    pub(super) fn extract(&mut self, scans: &[Scan; 2], t_ref: f64, out: &mut EpochPlanes) -> bool {
        let motion = MotionModel::new(&self.filter);
        let reference = motion.as_ref().map(|m| m.pose(t_ref));
        let pose_at = |t: f64| -> Isometry3<f64> {
            match (&motion, &reference) {
                (Some(motion), Some(reference)) => relative(reference, &motion.pose(t)),
                _ => Isometry3::identity(),
            }
        };
        let vertical = reference.map(|pose| Vertical {
            down: pose.q.inverse_transform_vector(&Vector3::z()),
            sigma_rad: self.filter.tilt_sigma(),
        });
        let scans = [&scans[0], &scans[1]];
        let (keyframe, prior) = match self.confirmation(t_ref) {
            Confirmation::Against { keyframe, prior } => (self.recent.at(keyframe), prior),
            unscreened => {
                self.odometer.extract_admitted_into(
                    scans,
                    t_ref,
                    &pose_at,
                    vertical,
                    &mut |_| true,
                    out,
                );
                return matches!(unscreened, Confirmation::NotNeeded);
            }
        };
        let gates = self.odometer.config().match_gates();
        // The keyframe's own screened planes may have been re-paired around a refused one, and
        // its unscreened ones (if it refused any) hold what a refusal there took out: a surface
        // is in one or both.
        let mut admit = |plane: &Plane| {
            [&keyframe.planes, &keyframe.unscreened]
                .iter()
                .any(|planes| matching::has_counterpart(planes, plane, &prior, &gates))
        };
        self.odometer
            .extract_admitted_into(scans, t_ref, &pose_at, vertical, &mut admit, out);
        true
    }

    /// What the planes of an epoch at `t_ref` are confirmed against.
    fn confirmation(&self, t_ref: f64) -> Confirmation {
        let (baseline, tolerance) = self.confirmation_baseline();
        let previous = self.reference.as_ref().map(|r| r.planes.t_ref);
        // A late epoch (after a gap) is itself a baseline back from the previous one.
        if !self.config.confirms_planes()
            || previous.is_some_and(|t| t_ref - t >= baseline - tolerance)
        {
            return Confirmation::NotNeeded;
        }
        let against = self
            .recent
            .keyframe_before(t_ref, baseline, tolerance)
            .and_then(|keyframe| {
                let prior = self.odometer_prior(self.recent.at(keyframe).t_ref, t_ref)?;
                Some(Confirmation::Against { keyframe, prior })
            });
        against.unwrap_or(Confirmation::Unavailable)
    }

    /// The confirmation's baseline and how early an epoch may come against it.
    fn confirmation_baseline(&self) -> (f64, f64) {
        (
            self.config.plane_confirmation_s,
            self.config.confirmation_tolerance_s(),
        )
    }

    /// The filter's relative pose from `t_ref` to `t` as the odometer's prior.
    fn odometer_prior(&self, t_ref: f64, t: f64) -> Option<RelativePose> {
        let prior = self.filter.relative_pose(t_ref, t)?;
        // The filter's rotation covariance is of a right perturbation (body j); the odometer
        // wants a left one (body i).
        let c = prior.rotation.to_rotation_matrix().into_inner();
        Some(RelativePose {
            rotation: prior.rotation,
            translation: prior.translation,
            rotation_covariance: c * prior.rotation_covariance * c.transpose(),
            translation_covariance: prior.translation_covariance,
        })
    }

    /// Returns how the current planes entered the fused relative pose.
    fn solve_and_fuse(
        &mut self,
        reference: &Reference,
        current: &EpochPlanes,
        record: &mut EpochRecord,
    ) -> SolvedEpoch {
        let previous = &reference.planes;
        let Some(prior) = self.odometer_prior(previous.t_ref, current.t_ref) else {
            self.level_drift.forget();
            record.outcome = EpochOutcome::Reference;
            return SolvedEpoch::default();
        };
        // The clone's axes before this epoch is fused. Pairings are doubted under the filter's
        // prior made vaguer along what it holds in doubt (`witnesses::Provisional::widened`).
        let to_navigation = self.navigation_axes_at(previous.t_ref);
        let doubt_prior =
            self.provisional
                .widened(&prior, &to_navigation, current.t_ref - previous.t_ref);
        let mut epoch = self
            .odometer
            .solve_doubting_under(previous, current, &prior, &doubt_prior);
        let buildings =
            [previous, current].map(|planes| self.odometer.config().building(planes.down));
        let wandering = self
            .level_drift
            .wandering(previous, current, &epoch.matches, buildings);
        if !wandering.is_empty() {
            epoch = self.odometer.resolve(previous, current, &epoch, &wandering);
        }
        let anchored = Anchored::new(previous, current, &epoch, &prior);
        let report = self.check_integrity(previous, current, &epoch, anchored.as_ref());
        let mut cleared = self.clear(
            [previous, current],
            &epoch,
            &doubt_prior,
            &report,
            anchored.as_ref(),
        );
        self.check_over_second(
            &mut cleared.lone,
            &to_navigation,
            [previous.t_ref, current.t_ref],
        );
        let scale = self.config.measurement_covariance_scale;
        let mut measurement = measurement(previous.t_ref, current.t_ref, &cleared, scale);
        let mut noise_maps = Vec::new();
        if self.config.shared_plane_noise {
            let maps = NoiseMaps::new(
                cleared.rotation.as_ref(),
                cleared.displacement.as_ref(),
                &epoch.matches,
                &previous.planes,
            );
            measurement.shared = Some(maps.shared_noise(
                &reference.noise_maps,
                &previous.planes,
                &current.planes,
                scale,
            ));
            noise_maps = maps.current;
        }
        self.integrity = Some(report.status.clone());
        describe_solve(record, current, &epoch, &cleared, anchored.as_ref(), report);
        record.rotation = measurement
            .rotation
            .map(|r| WithCovariance::new(&r.rotation_vector, &r.covariance));
        record.displacement = measurement
            .translation
            .map(|d| WithCovariance::new(&d.displacement, &d.covariance));
        (record.outcome, record.update) = self.fuse(&measurement);
        if record.outcome == EpochOutcome::Fused {
            let interval_s = current.t_ref - previous.t_ref;
            let surprised = record.update.is_some_and(|u| u.surprising(interval_s));
            self.settle_provisional(&cleared, [previous.t_ref, current.t_ref], surprised);
        }
        record.provisional_directions = self.provisional.len();
        let matched = epoch
            .matches
            .iter()
            .enumerate()
            .filter(|(k, _)| !cleared.excluded.contains(k))
            .map(|(_, m)| m.current)
            .collect();
        SolvedEpoch {
            noise_maps,
            matched,
        }
    }

    /// Hands the cleared relative pose to the filter, if anything was cleared.
    fn fuse(
        &mut self,
        measurement: &RelativePoseMeasurement,
    ) -> (EpochOutcome, Option<UpdateSummary>) {
        if measurement.rotation.is_none() && measurement.translation.is_none() {
            return (EpochOutcome::NotFused, None);
        }
        match self.filter.update_relative_pose(measurement) {
            Ok(update) if update.accepted => (EpochOutcome::Fused, Some((&update).into())),
            Ok(update) => (EpochOutcome::RejectedByGate, Some((&update).into())),
            Err(error) => (
                EpochOutcome::UpdateFailed {
                    reason: error.to_string(),
                },
                None,
            ),
        }
    }

    fn check_integrity(
        &self,
        previous: &EpochPlanes,
        current: &EpochPlanes,
        epoch: &OdometryEpoch,
        anchored: Option<&Anchored>,
    ) -> EpochReport {
        let odometer = &self.odometer;
        let mut rotation = |excluded: &[usize]| {
            odometer
                .resolve(previous, current, epoch, excluded)
                .rotation
        };
        let mut displacement = |excluded: &[usize]| match anchored {
            Some(anchored) => anchored.solve(excluded),
            None => {
                odometer
                    .resolve(previous, current, epoch, excluded)
                    .displacement
            }
        };
        let first = displacement(&[]);
        self.monitor.check_epoch(
            epoch.rotation.clone(),
            first,
            &mut rotation,
            &mut displacement,
        )
    }

    /// With exclusion: the solves integrity cleared (both, or the testable one of an
    /// under-determined epoch). Without: every solve that succeeded, with all planes.
    fn clear(
        &self,
        [previous, current]: [&EpochPlanes; 2],
        epoch: &OdometryEpoch,
        doubt_prior: &RelativePose,
        report: &EpochReport,
        anchored: Option<&Anchored>,
    ) -> Cleared {
        if !self.config.exclusion {
            return Cleared {
                rotation: epoch.rotation.as_ref().ok().cloned(),
                rotation_unprotected: Vec::new(),
                displacement_observability: anchored.map_or_else(Observability::full, |a| {
                    Observability::from_unobservable(&a.unobservable)
                }),
                displacement: match anchored {
                    Some(anchored) => anchored.solve(&[]).ok(),
                    None => epoch.displacement.as_ref().ok().cloned(),
                },
                excluded: Vec::new(),
                lone: CheckedLone::default(),
            };
        }
        let part = |solve: &crate::integrity::SolveReport| match (&report.status, &solve.status) {
            (IntegrityStatus::DetectedNotIsolable, _) => None,
            (_, status) if status.usable() => solve.solution.clone(),
            _ => None,
        };
        let (rotation, displacement) = (part(&report.rotation), part(&report.displacement));
        let lone = self.checked_lone_witnesses(
            [previous, current],
            (epoch, doubt_prior),
            &epoch.excluding(&report.excluded),
            [rotation.as_ref(), displacement.as_ref()],
        );
        let mut unobservable = anchored.map_or_else(Vec::new, |a| a.unobservable.clone());
        unobservable.extend(unprotected(&report.displacement));
        unobservable.extend(CheckedLone::contradicted(&lone.displacement));
        let mut rotation_unprotected = unprotected(&report.rotation);
        rotation_unprotected.extend(CheckedLone::contradicted(&lone.rotation));
        Cleared {
            rotation,
            rotation_unprotected,
            displacement,
            displacement_observability: Observability::from_unobservable(&unobservable),
            excluded: report.excluded.clone(),
            lone,
        }
    }

    /// The directions that one plane alone faces, each checked by the filter's prediction
    /// (`witnesses`), of the cleared `[rotation, displacement]`; whether a static surface's
    /// pairing is sure is judged under the prior the pairings were doubted under.
    fn checked_lone_witnesses(
        &self,
        [previous, current]: [&EpochPlanes; 2],
        (epoch, doubt_prior): (&OdometryEpoch, &RelativePose),
        excluded: &[usize],
        [rotation, displacement]: [Option<&Solution>; 2],
    ) -> CheckedLone {
        let limits = self.monitor.config();
        LoneWitnesses::of(
            previous,
            &epoch.matches,
            excluded,
            limits.lone_plane_min_extent_m,
            self.odometer.config().building(previous.down),
            doubt_prior,
        )
        .checked(
            rotation,
            displacement,
            &epoch.prior,
            current.t_ref - previous.t_ref,
            self.monitor.thresholds(),
            limits,
        )
    }

    /// On the plane map's odometer, checks each lone direction of the epoch spanning
    /// `interval` over the last second of epochs too (`checks_over_second`); `to_navigation`
    /// turns the epoch's body-i axes into navigation axes. The pairs alone keep
    /// the epoch's own check: their sideways sigma at 10 Hz is too small for what the second
    /// would release.
    fn check_over_second(
        &mut self,
        lone: &mut CheckedLone,
        to_navigation: &UnitQuaternion<f64>,
        interval: [f64; 2],
    ) {
        if self.odometer.config().method != OdometryMethod::Map {
            return;
        }
        self.checks_over_second
            .review(lone, to_navigation, interval, self.monitor.thresholds());
    }

    /// Holds the lone directions the filter just fused unchecked, and lets go of those it
    /// fused checked (`witnesses::Provisional`). A restart forgets them with the state.
    fn settle_provisional(
        &mut self,
        cleared: &Cleared,
        [t_previous, t]: [f64; 2],
        surprised: bool,
    ) {
        let to_navigation = self.navigation_axes_at(t_previous);
        let rotation = cleared
            .rotation
            .as_ref()
            .map(|_| Observability::from_unobservable(&cleared.rotation_unprotected));
        let displacement = cleared
            .displacement
            .as_ref()
            .map(|_| cleared.displacement_observability);
        self.provisional.after_fusion(
            &cleared.lone,
            [rotation, displacement],
            &to_navigation,
            surprised,
            t,
        );
    }

    /// The attitude that turns body axes at `t` into navigation axes.
    fn navigation_axes_at(&self, t: f64) -> UnitQuaternion<f64> {
        self.filter
            .pose_at_or_after(t)
            .map_or(self.filter.state().q, |pose| pose.q)
    }

    /// A filter that lost its convergence restarted: what it held provisional went with the
    /// state it restarted.
    fn forget_provisional_after_restart(&mut self) {
        let converged = self.filter.converged();
        if self.filter_converged && !converged {
            self.provisional.clear();
            self.checks_over_second.clear();
        }
        self.filter_converged = converged;
    }
}

/// The filter measurement from the cleared solves.
fn measurement(t_ref: f64, t: f64, cleared: &Cleared, scale: f64) -> RelativePoseMeasurement {
    let rotation = cleared.rotation.as_ref().map(|solution| {
        // The odometer's covariance is of a left perturbation in body-i axes; the filter's
        // residual is a right one, in body-j axes: Exp(a) C = C Exp(C^T a).
        let c = UnitQuaternion::from_scaled_axis(solution.x)
            .to_rotation_matrix()
            .into_inner();
        let unprotected: Vec<Vector3<f64>> = cleared
            .rotation_unprotected
            .iter()
            .map(|u| c.transpose() * u)
            .collect();
        RelativeRotation {
            rotation_vector: solution.x,
            covariance: symmetric(c.transpose() * solution.covariance * c) * scale,
            observability: Observability::from_unobservable(&unprotected),
        }
    });
    let translation = cleared
        .displacement
        .as_ref()
        .map(|solution| RelativeTranslation {
            displacement: solution.x,
            covariance: symmetric(solution.covariance) * scale,
            observability: cleared.displacement_observability,
        });
    RelativePoseMeasurement {
        t_ref,
        t,
        rotation,
        translation,
        shared: None,
    }
}

/// Matches, exclusions, anchored directions and the integrity evidence of a solved epoch.
fn describe_solve(
    record: &mut EpochRecord,
    current: &EpochPlanes,
    epoch: &OdometryEpoch,
    cleared: &Cleared,
    anchored: Option<&Anchored>,
    report: EpochReport,
) {
    record.matched = epoch.matches.len();
    record.excluded_planes = plane_ids(&cleared.excluded, epoch, current);
    record.wandering_level_planes = plane_ids(&epoch.excluded, epoch, current);
    record.used = record
        .matched
        .saturating_sub(record.excluded_planes.len() + record.wandering_level_planes.len());
    record.unobservable_displacement = anchored
        .map(|a| a.unobservable.iter().map(|&u| u.into()).collect())
        .unwrap_or_default();
    record.lone_directions = cleared.lone.described();
    record.status = Some(report.status.clone());
    record.integrity = Some(report);
}

/// The current epoch's ids of the planes in `matches` (indices into the epoch's matches).
fn plane_ids(matches: &[usize], epoch: &OdometryEpoch, current: &EpochPlanes) -> Vec<usize> {
    // Anchors sit after the real matches and have no plane id.
    matches
        .iter()
        .filter_map(|&k| epoch.matches.get(k))
        .map(|m| current.planes[m.current].id)
        .collect()
}

/// Directions of a solve's estimate that a fault on a plane alone in observing them could move
/// unseen (see `SolveTest::unprotected`).
fn unprotected(solve: &crate::integrity::SolveReport) -> Vec<Vector3<f64>> {
    solve.test.as_ref().map_or_else(Vec::new, |test| {
        test.unprotected.iter().map(|&u| Vector3::from(u)).collect()
    })
}

fn symmetric(m: Matrix3<f64>) -> Matrix3<f64> {
    (m + m.transpose()) * 0.5
}

pub(super) fn planes_record(planes: &EpochPlanes) -> EpochRecord {
    let on_scanner = |k: usize| {
        planes
            .planes
            .iter()
            .filter(|plane| plane.lines.iter().any(|line| line.scanner == k))
            .count()
    };
    EpochRecord {
        t: planes.t_ref,
        t_previous: None,
        outcome: EpochOutcome::Reference,
        readings: planes.readings,
        dropped: planes.dropped,
        lines: planes.lines,
        range_sigma_m: planes.range_sigma_m,
        planes_per_scanner: [on_scanner(0), on_scanner(1)],
        planes: planes.planes.len(),
        plane_geometry: planes.planes.iter().map(PlaneGeometry::from).collect(),
        matched: 0,
        used: 0,
        excluded_planes: Vec::new(),
        wandering_level_planes: Vec::new(),
        unconfirmed_planes: 0,
        unobservable_displacement: Vec::new(),
        lone_directions: Vec::new(),
        provisional_directions: 0,
        status: None,
        integrity: None,
        rotation: None,
        displacement: None,
        update: None,
        level_surfaces: Vec::new(),
        map: None,
    }
}

/// The filter's poses for deskewing: its history, extrapolated with the current velocity and
/// rate for beams after the newest IMU sample (`Eskf::pose_at_or_after`).
struct MotionModel<'a> {
    filter: &'a Eskf,
    newest: Pose,
}

impl<'a> MotionModel<'a> {
    fn new(filter: &'a Eskf) -> Option<Self> {
        if filter.phase() == FilterPhase::Aligning {
            return None;
        }
        let t = filter.time()?;
        let state = filter.state();
        Some(Self {
            filter,
            newest: Pose {
                t,
                p: state.p,
                q: state.q,
            },
        })
    }

    /// Before the history (older than pose_history_s) the oldest pose would do no better than
    /// the newest, and the epoch will restart the chain anyway.
    fn pose(&self, t: f64) -> Pose {
        self.filter
            .pose_at_or_after(t)
            .unwrap_or(Pose { t, ..self.newest })
    }
}

/// Body pose at `at` relative to the body at `reference`: `p_ref = T * p_at`.
fn relative(reference: &Pose, at: &Pose) -> Isometry3<f64> {
    let inverse = reference.q.inverse();
    Isometry3::from_parts(
        Translation3::from(inverse * (at.p - reference.p)),
        inverse * at.q,
    )
}
