//! One Monte Carlo trial: two epochs captured with fresh noise (a fault staged between them or
//! not), solved with truth association, and checked by the integrity monitor.

use super::harness::{Fault, LabelledEpoch, PlaneLabel, Rig};
use crate::estimate::IntegrityStatus;
use crate::integrity::{EpochReport, IntegrityMonitor, SolveKind, SolveTest};
use crate::odometry::{OdometryEpoch, RelativePose};
use nalgebra::Vector3;

pub struct PairOutcome {
    pub previous: LabelledEpoch,
    pub current: LabelledEpoch,
    /// The solves with every matched plane.
    pub epoch: OdometryEpoch,
    pub report: EpochReport,
    pub truth: RelativePose,
    pub fault: Option<Fault>,
}

impl PairOutcome {
    /// Labels of each match's previous-epoch plane, by match index.
    pub fn match_label(&self, k: usize) -> PlaneLabel {
        self.previous.labels[self.epoch.matches[k].previous]
    }

    /// Whether the faulty patch is in some matched plane.
    pub fn fault_in_solve(&self) -> bool {
        self.fault.is_some_and(|fault| {
            (0..self.epoch.matches.len())
                .any(|k| self.match_label(k).contains(&Some(fault.patch())))
        })
    }

    /// A test fired (whether or not the culprit could be excluded).
    pub fn detected(&self) -> bool {
        matches!(
            self.report.status,
            IntegrityStatus::Excluded { .. } | IntegrityStatus::DetectedNotIsolable
        )
    }

    /// The exclusion removed planes, all of them touching the faulty patch.
    pub fn excluded_the_fault(&self) -> bool {
        let Some(fault) = self.fault else {
            return false;
        };
        matches!(self.report.status, IntegrityStatus::Excluded { .. })
            && self
                .report
                .excluded
                .iter()
                .all(|&k| self.match_label(k).contains(&Some(fault.patch())))
    }

    /// Each solve tested on its own with the whole false-alarm budget, before any exclusion.
    pub fn solo_tests(&self, monitor: &IntegrityMonitor) -> [Option<SolveTest>; 2] {
        let test = |kind, solved: &Result<crate::least_squares::Solution, _>| {
            solved
                .as_ref()
                .ok()
                .and_then(|s| monitor.test(kind, &s.system).ok())
        };
        [
            test(SolveKind::Rotation, &self.epoch.rotation),
            test(SolveKind::Displacement, &self.epoch.displacement),
        ]
    }

    /// Rotation (rotation vector of C_est C_true^-1, rad) and displacement (m) errors of the
    /// solves with every plane, when both solved.
    pub fn errors_all_planes(&self) -> Option<[Vector3<f64>; 2]> {
        let rotation = self.epoch.rotation.as_ref().ok()?;
        let displacement = self.epoch.displacement.as_ref().ok()?;
        Some(self.errors(&rotation.x, &displacement.x))
    }

    /// The same after integrity's exclusions, when the epoch is usable.
    pub fn errors_after_integrity(&self) -> Option<[Vector3<f64>; 2]> {
        if !self.report.status.usable() {
            return None;
        }
        let rotation = self.report.rotation.solution.as_ref()?;
        let displacement = self.report.displacement.solution.as_ref()?;
        Some(self.errors(&rotation.x, &displacement.x))
    }

    fn errors(&self, rotation: &Vector3<f64>, displacement: &Vector3<f64>) -> [Vector3<f64>; 2] {
        let estimated = nalgebra::UnitQuaternion::from_scaled_axis(*rotation);
        [
            (estimated * self.truth.rotation.inverse()).scaled_axis(),
            displacement - self.truth.translation,
        ]
    }
}

/// Captures epochs at the rig's two times with `fault` staged, solves and checks them.
pub fn run_pair(rig: &mut Rig, monitor: &IntegrityMonitor, fault: Option<Fault>) -> PairOutcome {
    rig.stage(fault);
    let [ti, tj] = rig.epoch_times;
    let previous = rig.capture(ti);
    let current = rig.capture(tj);
    check_pair(rig, monitor, previous, current, fault)
}

/// Solves and checks two captured epochs.
pub fn check_pair(
    rig: &Rig,
    monitor: &IntegrityMonitor,
    previous: LabelledEpoch,
    current: LabelledEpoch,
    fault: Option<Fault>,
) -> PairOutcome {
    let epoch = rig.solve(&previous, &current);
    let odometer = &rig.odometer;
    let resolve =
        |excluded: &[usize]| odometer.resolve(&previous.planes, &current.planes, &epoch, excluded);
    let report = monitor.check_epoch(
        epoch.rotation.clone(),
        epoch.displacement.clone(),
        &mut |excluded| resolve(excluded).rotation,
        &mut |excluded| resolve(excluded).displacement,
    );
    let truth = rig.true_relative_pose(&previous, &current);
    PairOutcome {
        previous,
        current,
        epoch,
        report,
        truth,
        fault,
    }
}
