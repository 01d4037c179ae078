//! Accuracy and consistency of the fusion on a simulated run: drives `Simulator::events()`
//! through `Fusion` and compares the estimates with the trajectory's truth after the
//! stationary start.

use nalgebra::{DMatrix, DVector, SVector, UnitQuaternion, Vector3};
use serde::Serialize;

use ladar_odometer::daemon::truth::ErrorSeries;
use ladar_odometer::estimate::{Estimate, IntegrityStatus};
use ladar_odometer::filter::state::{Covariance, ATT, POS, VEL};
use ladar_odometer::filter::{mean_nees_interval, Eskf};
use ladar_odometer::fusion::record::{EpochOutcome, EpochRecord};
use ladar_odometer::fusion::{Fusion, FusionError, FusionSettings};
use ladar_odometer::sensors::TruthSample;
use ladar_sim::{Scenario, ScenarioError, SimEvent, Simulator};

/// Estimates are compared with truth every this many IMU samples (10 Hz at 400 Hz).
const COMPARE_EVERY: u64 = 40;

/// Epochs by how they ended.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct EpochCounts {
    pub total: u64,
    /// Reference only (first epoch, before alignment, chain restarted).
    pub reference: u64,
    /// Integrity `Ok` and fused.
    pub ok: u64,
    /// Planes excluded, the rest fused.
    pub excluded: u64,
    pub not_isolable: u64,
    pub under_determined: u64,
    /// Refused by the filter's innovation gate.
    pub rejected_by_gate: u64,
    pub update_failed: u64,
    /// Fused (accepted by the gate), whatever the integrity verdict.
    pub fused: u64,
    /// Epochs that left at least one matched plane out for want of confirmation.
    pub with_unconfirmed: u64,
}

impl EpochCounts {
    fn add(&mut self, record: &EpochRecord) {
        self.total += 1;
        match &record.status {
            None => self.reference += 1,
            Some(IntegrityStatus::Ok) => self.ok += 1,
            Some(IntegrityStatus::Excluded { .. }) => self.excluded += 1,
            Some(IntegrityStatus::DetectedNotIsolable) => self.not_isolable += 1,
            Some(IntegrityStatus::UnderDetermined) => self.under_determined += 1,
        }
        match record.outcome {
            EpochOutcome::Fused => self.fused += 1,
            EpochOutcome::RejectedByGate => self.rejected_by_gate += 1,
            EpochOutcome::UpdateFailed { .. } => self.update_failed += 1,
            _ => {}
        }
        if record.unconfirmed_planes > 0 {
            self.with_unconfirmed += 1;
        }
    }
}

/// Figures of one simulated run, after the stationary start.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AccuracyReport {
    pub scenario: String,
    /// Start of the comparison (end of the filter's stationary start), s.
    pub from_s: f64,
    pub to_s: f64,
    /// Standard deviation of the NED velocity error per axis, m/s.
    pub velocity_error_std_ned: [f64; 3],
    /// Root mean square of the NED velocity error per axis, m/s.
    pub velocity_error_rms_ned: [f64; 3],
    /// Standard deviation of the roll, pitch and yaw (Euler angle) errors, mrad.
    pub attitude_error_std_mrad: [f64; 3],
    pub attitude_error_rms_mrad: [f64; 3],
    /// Horizontal position error at the end, m.
    pub horizontal_error_end_m: f64,
    /// Position error at the end, NED, m.
    pub position_error_end_m: [f64; 3],
    /// Path length of the truth over the compared span, m.
    pub distance_travelled_m: f64,
    /// Final horizontal error in % of the distance travelled (infinite when hovering).
    pub drift_percent: f64,
    /// Average 9-dof NEES (position, velocity, attitude), sampled once a second.
    pub nees_mean: f64,
    /// 95 % interval of that average for a consistent filter, as if the samples were
    /// independent (they are not quite: a narrow yardstick).
    pub nees_interval: [f64; 2],
    pub nees_samples: usize,
    /// Average NEES of the states the odometry observes: velocity and tilt (the north and
    /// east components of the attitude error), 5 dof. Absolute position and yaw are only
    /// dead-reckoned, so their covariance grows while their error need not; this one is the
    /// yardstick of the filter's consistency.
    pub observable_nees_mean: f64,
    pub observable_nees_interval: [f64; 2],
    /// Average squared normalised error per block (position, velocity, attitude), each the
    /// block's own 3-dof NEES: which block makes the 9-dof figure low or high.
    pub nees_block_means: [f64; 3],
    /// Average NIS per degree of freedom of the relative-pose updates (1 when consistent).
    pub nis_per_dof_mean: f64,
    pub epochs: EpochCounts,
}

#[derive(Debug, thiserror::Error)]
pub enum EvaluationError {
    #[error("{0}")]
    Scenario(#[from] ScenarioError),
    #[error("{0}")]
    Fusion(#[from] FusionError),
    #[error("scenario {0} has no IMU: the fusion needs one")]
    NoImu(String),
    #[error("scenario {0} needs two scanners, it has {1}")]
    ScannerCount(String, usize),
}

/// A consistency yardstick: a subset of the position, velocity and attitude errors, normalised
/// by its own marginal covariance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NeesPart {
    /// Position, velocity and attitude: 9 dof.
    Full,
    /// Velocity and tilt, the states the odometry and gravity observe: 5 dof.
    Observable,
    Position,
    Velocity,
    Attitude,
    /// The north and east components of the global attitude error: 2 dof.
    Tilt,
    /// The down component of the global attitude error: 1 dof.
    Yaw,
}

impl NeesPart {
    pub const ALL: [NeesPart; 7] = [
        NeesPart::Full,
        NeesPart::Observable,
        NeesPart::Position,
        NeesPart::Velocity,
        NeesPart::Attitude,
        NeesPart::Tilt,
        NeesPart::Yaw,
    ];

    /// Indices into the 9 states position, velocity, attitude.
    fn indices(self) -> &'static [usize] {
        match self {
            NeesPart::Full => &[0, 1, 2, 3, 4, 5, 6, 7, 8],
            NeesPart::Observable => &[3, 4, 5, 6, 7],
            NeesPart::Position => &[0, 1, 2],
            NeesPart::Velocity => &[3, 4, 5],
            NeesPart::Attitude => &[6, 7, 8],
            NeesPart::Tilt => &[6, 7],
            NeesPart::Yaw => &[8],
        }
    }

    pub fn dof(self) -> usize {
        self.indices().len()
    }
}

/// Every `NeesPart` at one comparison time, in `NeesPart::ALL` order.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NeesSample {
    pub t: f64,
    pub values: [f64; NeesPart::ALL.len()],
}

impl NeesSample {
    pub fn get(&self, part: NeesPart) -> f64 {
        self.values[part as usize]
    }
}

/// One run's figures and its NEES once a second after the stationary start.
#[derive(Debug, Clone)]
pub struct RecordedRun {
    pub report: AccuracyReport,
    pub nees: Vec<NeesSample>,
}

/// Runs the scenario through the fusion with `settings` (whose IMU mount is taken from the
/// scenario) and measures the accuracy.
pub fn run_scenario(
    scenario: &Scenario,
    settings: &FusionSettings,
) -> Result<AccuracyReport, EvaluationError> {
    run_scenario_with(scenario, settings, &mut |_, _| {})
}

/// As `run_scenario`, handing every epoch record to `on_epoch` with the estimate just after it.
pub fn run_scenario_with(
    scenario: &Scenario,
    settings: &FusionSettings,
    on_epoch: &mut dyn FnMut(&EpochRecord, &Estimate),
) -> Result<AccuracyReport, EvaluationError> {
    Ok(run_scenario_recorded(scenario, settings, on_epoch)?.report)
}

/// As `run_scenario_with`, keeping the NEES time series (for Monte Carlo averages over runs).
pub fn run_scenario_recorded(
    scenario: &Scenario,
    settings: &FusionSettings,
    on_epoch: &mut dyn FnMut(&EpochRecord, &Estimate),
) -> Result<RecordedRun, EvaluationError> {
    let mut simulator = Simulator::new(scenario)?;
    let imu = simulator
        .imu()
        .ok_or_else(|| EvaluationError::NoImu(scenario.name.clone()))?;
    let mut settings = settings.clone();
    settings.filter.imu_mount_rpy_deg = imu.mount_rpy_deg;
    let setups = simulator.scanner_setups().ok_or_else(|| {
        EvaluationError::ScannerCount(scenario.name.clone(), simulator.scanners().len())
    })?;
    let from_s = settings.filter.stationary_start_s;
    let mut fusion = Fusion::new(settings, setups)?;
    let trajectory = scenario.trajectory.clone();
    let truth = |t: f64| {
        let k = trajectory.kinematics(t);
        TruthSample {
            t,
            p: k.p,
            q: k.q,
            v: k.v,
        }
    };
    let mut errors = Errors::default();
    let mut epochs = EpochCounts::default();
    let mut nis = (0.0, 0usize);
    let mut samples = 0u64;
    let mut next_nees = from_s;
    for event in simulator.events() {
        match event {
            SimEvent::Imu(sample) => {
                fusion.push_imu(sample);
                samples += 1;
                let Some(t) = fusion.filter().time() else {
                    continue;
                };
                if t < from_s || !samples.is_multiple_of(COMPARE_EVERY) {
                    continue;
                }
                let truth = truth(t);
                let estimate = fusion.estimate();
                errors.add(
                    &estimate.velocity,
                    &estimate.attitude,
                    &estimate.position,
                    &truth,
                );
                if t >= next_nees {
                    next_nees += 1.0;
                    errors.nees.extend(nees_sample(fusion.filter(), &truth));
                }
            }
            SimEvent::Scan { scan, .. } => {
                if let Some(record) = fusion.push_scan(scan) {
                    epochs.add(&record);
                    if let Some(update) = record.update.filter(|u| u.dof > 0) {
                        nis.0 += update.nis / update.dof as f64;
                        nis.1 += 1;
                    }
                    on_epoch(&record, &fusion.estimate());
                }
            }
            SimEvent::Truth(_) => {}
        }
    }
    let nees = errors.nees.clone();
    let report = errors.report(
        scenario.name.clone(),
        from_s,
        epochs,
        nis.0 / nis.1.max(1) as f64,
    );
    Ok(RecordedRun { report, nees })
}

#[derive(Debug, Default)]
struct Errors {
    series: ErrorSeries,
    last_position: Option<(f64, Vector3<f64>)>,
    nees: Vec<NeesSample>,
}

impl Errors {
    fn add(
        &mut self,
        velocity: &Vector3<f64>,
        attitude: &UnitQuaternion<f64>,
        position: &Vector3<f64>,
        truth: &TruthSample,
    ) {
        self.series.push(velocity, attitude, position, truth);
        self.last_position = Some((truth.t, position - truth.p));
    }

    fn report(
        self,
        scenario: String,
        from_s: f64,
        epochs: EpochCounts,
        nis: f64,
    ) -> AccuracyReport {
        let (to_s, end) = self.last_position.unwrap_or((from_s, Vector3::zeros()));
        let horizontal = end.xy().norm();
        let n = self.nees.len().max(1);
        let part_mean =
            |part: NeesPart| self.nees.iter().map(|s| s.get(part)).sum::<f64>() / n as f64;
        let interval = |part: NeesPart| mean_nees_interval(part.dof(), n);
        AccuracyReport {
            scenario,
            from_s,
            to_s,
            velocity_error_std_ned: self.series.velocity_std(),
            velocity_error_rms_ned: self.series.velocity_rms(),
            attitude_error_std_mrad: self.series.attitude_std_mrad(),
            attitude_error_rms_mrad: self.series.attitude_rms_mrad(),
            horizontal_error_end_m: horizontal,
            position_error_end_m: end.into(),
            distance_travelled_m: self.series.travelled_m(),
            drift_percent: 100.0 * horizontal / self.series.travelled_m(),
            nees_mean: part_mean(NeesPart::Full),
            nees_interval: interval(NeesPart::Full),
            nees_samples: self.nees.len(),
            observable_nees_mean: part_mean(NeesPart::Observable),
            observable_nees_interval: interval(NeesPart::Observable),
            nees_block_means: [
                part_mean(NeesPart::Position),
                part_mean(NeesPart::Velocity),
                part_mean(NeesPart::Attitude),
            ],
            nis_per_dof_mean: nis,
            epochs,
        }
    }
}

/// Every `NeesPart` against its marginal covariance; `None` if one is not positive definite.
fn nees_sample(filter: &Eskf, truth: &TruthSample) -> Option<NeesSample> {
    let state = filter.state();
    let covariance = filter.covariance();
    let mut error = SVector::<f64, 9>::zeros();
    error.fixed_rows_mut::<3>(0).copy_from(&(truth.p - state.p));
    error.fixed_rows_mut::<3>(3).copy_from(&(truth.v - state.v));
    error
        .fixed_rows_mut::<3>(6)
        .copy_from(&(truth.q * state.q.inverse()).scaled_axis());
    let mut values = [0.0; NeesPart::ALL.len()];
    for (value, part) in values.iter_mut().zip(NeesPart::ALL) {
        *value = normalised(&error, &covariance, part.indices())?;
    }
    Some(NeesSample { t: truth.t, values })
}

/// `e_S^T P_SS^-1 e_S` over the indices `S` of the 9 states position, velocity, attitude.
fn normalised(error: &SVector<f64, 9>, covariance: &Covariance, indices: &[usize]) -> Option<f64> {
    // The 9 states are the first of the covariance, in the same order.
    const _: () = assert!(POS == 0 && VEL == 3 && ATT == 6);
    let n = indices.len();
    let sub = DMatrix::from_fn(n, n, |i, j| covariance[(indices[i], indices[j])]);
    let e = DVector::from_fn(n, |i, _| error[indices[i]]);
    Some(sub.cholesky()?.solve(&e).dot(&e))
}
