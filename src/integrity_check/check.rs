//! `integrity-check`: for any scenario with at least four planes, the figures a user needs to
//! trust the integrity layer on their own mount: per plane predicted against measured sigma of
//! the displacement and rotation rows, thresholds and minimum detectable biases; the false-alarm
//! rate measured against the configured one; and detection against bias size for a plane that
//! moves (translation) or turns (rotation) between the two epochs.

use super::harness::{Fault, PlaneLabel, Rig};
use super::pairs::{run_pair, PairOutcome};
use super::{paper_config, StudyError};
use crate::integrity::{IntegrityConfig, IntegrityMonitor, SolveKind, SolveTest};
use crate::odometry::tangent_basis;
use ladar_sim::Scenario;
use serde::Serialize;
use std::fmt;

/// Translational biases tried, metres.
pub(crate) const TRANSLATION_BIASES_M: [f64; 5] = [0.02, 0.05, 0.1, 0.15, 0.2];
/// The translational bias whose test statistics are kept for the histogram (paper Fig. 7).
pub(crate) const HISTOGRAM_BIAS_M: f64 = 0.1;
/// Rotational biases tried, degrees.
pub(crate) const ROTATION_BIASES_DEG: [f64; 5] = [1.0, 2.0, 4.0, 6.0, 8.0];
/// A plane is studied when it is matched in at least this share of fault-free pairs.
const MIN_SEEN_SHARE: f64 = 0.5;

#[derive(Debug, Clone, PartialEq)]
pub struct IntegrityCheckArgs {
    /// A built-in scenario name or a scenario TOML file.
    pub scenario: String,
    /// Fault-free pairs, and pairs per bias size.
    pub runs: usize,
    pub seed: u64,
    /// Render as JSON rather than tables (see `IntegrityCheckReport::render`).
    pub json: bool,
    pub integrity: IntegrityConfig,
}

impl Default for IntegrityCheckArgs {
    fn default() -> Self {
        Self {
            scenario: "paper-sim".into(),
            runs: 1000,
            seed: 1,
            json: false,
            integrity: IntegrityConfig::default(),
        }
    }
}

/// Predicted against measured sigma of one solve's rows of a plane, with its test's figures.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct RowFigures {
    /// RMS over pairs of the rows' predicted sigma (m, or rad per tangent row).
    pub predicted_sigma: f64,
    /// RMS of the rows' actual errors against the true relative pose.
    pub measured_sigma: f64,
    /// Mean test threshold on the normalised residual (gamma, eq 39).
    pub gamma: f64,
    /// Mean threshold in row units: gamma times the residual's predicted sigma (eq 39's C_l).
    pub threshold: f64,
    /// Mean minimum detectable bias (eq 40), row units; infinite if untestable.
    pub mdb: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlaneFigures {
    /// Patch names of the plane's two lines ("a" or "a+b").
    pub plane: String,
    /// Share of fault-free pairs in which the plane was matched.
    pub seen: f64,
    /// Displacement rows: metres.
    pub displacement: RowFigures,
    /// Rotation rows: radians.
    pub rotation: RowFigures,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FalseAlarms {
    pub pairs: usize,
    /// Pairs that could not be tested (under-determined).
    pub untestable: usize,
    pub alarms: usize,
    pub rate: f64,
    pub configured: f64,
}

/// Detection of one moved plane at one bias size.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlaneDetection {
    pub plane: String,
    pub pairs: usize,
    pub detected: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DetectionRow {
    /// Bias size, metres or degrees.
    pub bias: f64,
    pub pairs: usize,
    /// Pairs in which the moved plane was not matched (it left the view or was not extracted).
    pub fault_not_in_solve: usize,
    pub detected: usize,
    /// Pairs where exactly the moved plane's matches were excluded and the rest passed.
    pub excluded_right_plane: usize,
    pub rate: f64,
    /// The same by the plane that moved.
    pub per_plane: Vec<PlaneDetection>,
}

/// The displacement test's statistic over its threshold, per pair, without a fault and with a
/// plane moved by `bias_m` (paper Figs. 6 and 7), for the report's histograms. Left out of the
/// JSON, which stays the figures.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TestStatistics {
    pub bias_m: f64,
    pub fault_free: Vec<f64>,
    pub biased: Vec<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IntegrityCheckReport {
    pub scenario: String,
    pub runs: usize,
    pub seed: u64,
    pub epoch_times_s: [f64; 2],
    pub false_alarm_probability: f64,
    pub missed_detection_probability: f64,
    pub planes: Vec<PlaneFigures>,
    pub false_alarms: FalseAlarms,
    pub translation: Vec<DetectionRow>,
    pub rotation: Vec<DetectionRow>,
    #[serde(skip)]
    pub statistics: TestStatistics,
}

impl IntegrityCheckReport {
    pub(crate) fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("the report holds only plain data")
    }

    /// JSON or tables.
    pub fn render(&self, json: bool) -> String {
        if json {
            self.to_json()
        } else {
            self.to_string()
        }
    }
}

/// Runs the check on the scenario named (or the TOML file given) in `args`.
pub fn integrity_check(args: &IntegrityCheckArgs) -> Result<IntegrityCheckReport, StudyError> {
    integrity_check_with_progress(args, &mut |_, _| {})
}

/// Pairs the check simulates: the fault-free ones, then as many per bias size.
pub fn pairs_to_run(args: &IntegrityCheckArgs) -> usize {
    args.runs * (1 + TRANSLATION_BIASES_M.len() + ROTATION_BIASES_DEG.len())
}

/// [`integrity_check`], calling `progress(done, total)` after each simulated pair.
pub fn integrity_check_with_progress(
    args: &IntegrityCheckArgs,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<IntegrityCheckReport, StudyError> {
    let total = pairs_to_run(args);
    let mut done = 0;
    let mut step = move || {
        done += 1;
        progress(done, total);
    };
    if args.runs < 10 {
        return Err(StudyError::TooFewRuns {
            runs: args.runs,
            minimum: 10,
        });
    }
    let scenario = Scenario::resolve(&args.scenario).map_err(StudyError::Scenario)?;
    let monitor = IntegrityMonitor::new(args.integrity.clone())
        .map_err(|e| StudyError::Config(e.to_string()))?;
    let mut rig = Rig::new(&scenario, args.seed, paper_config())?;
    let clean: Vec<PairOutcome> = (0..args.runs)
        .map(|_| {
            step();
            run_pair(&mut rig, &monitor, None)
        })
        .collect();
    let studied = studied_planes(&clean, args.runs);
    if studied.len() < 4 {
        return Err(StudyError::TooFewPlanes {
            scenario: scenario.name.clone(),
            planes: studied.len(),
        });
    }
    let planes = studied
        .iter()
        .map(|label| plane_figures(&rig, &clean, label, args.runs))
        .collect();
    // Faults go on patches that make a plane on their own, each in turn.
    let movable: Vec<usize> = studied
        .iter()
        .filter(|l| l[0] == l[1])
        .filter_map(|l| l[0])
        .collect();
    let names: Vec<(usize, String)> = movable
        .iter()
        .map(|&p| (p, label_name(&scenario, &[Some(p), Some(p)])))
        .collect();
    let mut biased = Vec::new();
    let mut detection = |rig: &mut Rig, make: &dyn Fn(usize, f64) -> Fault, bias: f64| {
        let outcomes: Vec<PairOutcome> = (0..args.runs)
            .map(|r| {
                step();
                let fault = make(movable[r % movable.len()], bias);
                run_pair(rig, &monitor, Some(fault))
            })
            .collect();
        if bias == HISTOGRAM_BIAS_M {
            biased = displacement_statistics(&monitor, &outcomes);
        }
        detection_row(bias, &outcomes, &names)
    };
    let translation = TRANSLATION_BIASES_M
        .iter()
        .map(|&b| {
            detection(
                &mut rig,
                &|patch, metres| Fault::Translate { patch, metres },
                b,
            )
        })
        .collect();
    let rotation = ROTATION_BIASES_DEG
        .iter()
        .map(|&b| {
            detection(
                &mut rig,
                &|patch, degrees| Fault::Rotate { patch, degrees },
                b,
            )
        })
        .collect();
    rig.stage(None);
    Ok(IntegrityCheckReport {
        scenario: scenario.name.clone(),
        runs: args.runs,
        seed: args.seed,
        epoch_times_s: rig.epoch_times,
        false_alarm_probability: args.integrity.false_alarm_probability,
        missed_detection_probability: args.integrity.missed_detection_probability,
        planes,
        false_alarms: false_alarms(&clean, args.integrity.false_alarm_probability),
        translation,
        rotation,
        statistics: TestStatistics {
            bias_m: HISTOGRAM_BIAS_M,
            fault_free: displacement_statistics(&monitor, &clean),
            biased,
        },
    })
}

/// Each pair's displacement test statistic over its threshold, with every matched plane (before
/// any exclusion): above 1 the test fires.
fn displacement_statistics(monitor: &IntegrityMonitor, outcomes: &[PairOutcome]) -> Vec<f64> {
    outcomes
        .iter()
        .filter_map(|o| o.epoch.displacement.as_ref().ok())
        .filter_map(|solution| monitor.test(SolveKind::Displacement, &solution.system).ok())
        .map(|test| test.chi_square / test.chi_square_threshold)
        .collect()
}

/// Labels of the planes matched in at least half of the pairs, most often seen first.
pub fn studied_planes(outcomes: &[PairOutcome], runs: usize) -> Vec<PlaneLabel> {
    let mut counts: Vec<(PlaneLabel, usize)> = Vec::new();
    for outcome in outcomes {
        for k in 0..outcome.epoch.matches.len() {
            let label = canonical(outcome.match_label(k));
            match counts.iter_mut().find(|(l, _)| *l == label) {
                Some((_, n)) => *n += 1,
                None => counts.push((label, 1)),
            }
        }
    }
    counts.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    counts
        .into_iter()
        .filter(|&(_, n)| n as f64 >= MIN_SEEN_SHARE * runs as f64)
        .map(|(l, _)| l)
        .collect()
}

pub(super) fn canonical(label: PlaneLabel) -> PlaneLabel {
    let [a, b] = label;
    [a.min(b), a.max(b)]
}

pub(crate) fn label_name(scenario: &Scenario, label: &PlaneLabel) -> String {
    let name = |p: Option<usize>| {
        p.and_then(|p| scenario.scene.patches.get(p))
            .map_or("?", |patch| patch.name.as_str())
    };
    if label[0] == label[1] {
        name(label[0]).to_string()
    } else {
        format!("{}+{}", name(label[0]), name(label[1]))
    }
}

#[derive(Default)]
struct RowSums {
    count: usize,
    predicted: f64,
    measured: f64,
    tested: usize,
    gamma: f64,
    threshold: f64,
    mdb: f64,
}

impl RowSums {
    fn figures(&self) -> RowFigures {
        let n = self.count.max(1) as f64;
        let t = self.tested.max(1) as f64;
        RowFigures {
            predicted_sigma: (self.predicted / n).sqrt(),
            measured_sigma: (self.measured / n).sqrt(),
            gamma: self.gamma / t,
            threshold: self.threshold / t,
            mdb: self.mdb / t,
        }
    }

    /// Adds the test of plane `k` in a solve whose system's rows are tagged by `plane_of_row`.
    fn add_test(&mut self, test: &SolveTest, plane_of_row: &[usize], k: usize) {
        let Some(plane) = test.plane(k) else { return };
        let sigmas: Vec<f64> = plane_of_row
            .iter()
            .zip(&test.residual_sigmas)
            .filter(|(&p, _)| p == k)
            .map(|(_, sigma)| sigma * sigma)
            .collect();
        let residual_sigma = (sigmas.iter().sum::<f64>() / sigmas.len().max(1) as f64).sqrt();
        self.tested += 1;
        self.gamma += plane.threshold;
        self.threshold += plane.threshold * residual_sigma;
        self.mdb += plane.mdb;
    }
}

/// Per-plane figures over the fault-free pairs in which the plane was matched and both solves
/// passed untouched.
pub fn plane_figures(
    rig: &Rig,
    outcomes: &[PairOutcome],
    label: &PlaneLabel,
    runs: usize,
) -> PlaneFigures {
    let mut displacement = RowSums::default();
    let mut rotation = RowSums::default();
    let mut seen = 0;
    for outcome in outcomes {
        let Some(k) =
            (0..outcome.epoch.matches.len()).find(|&k| canonical(outcome.match_label(k)) == *label)
        else {
            continue;
        };
        seen += 1;
        let m = outcome.epoch.matches[k];
        let plane_i = &outcome.previous.planes.planes[m.previous];
        let plane_j = &outcome.current.planes.planes[m.current];
        if let Ok(solution) = &outcome.epoch.displacement {
            let system = &solution.system;
            if let Some(row) = system.plane_of_row.iter().position(|&p| p == k) {
                let h = system.h.row(row).transpose();
                let error = system.y[row] - h.dot(&outcome.truth.translation);
                displacement.count += 1;
                displacement.predicted += system.r[(row, row)];
                displacement.measured += error * error;
            }
        }
        if let Ok(solution) = &outcome.epoch.rotation {
            let system = &solution.system;
            if let Some(row) = system.plane_of_row.iter().position(|&p| p == k) {
                let error = plane_i.normal - outcome.truth.rotation * plane_j.normal;
                let tangent = tangent_basis(&plane_i.normal).transpose() * error;
                rotation.count += 1;
                rotation.predicted += (system.r[(row, row)] + system.r[(row + 1, row + 1)]) / 2.0;
                rotation.measured += tangent.norm_squared() / 2.0;
            }
        }
        if !outcome.report.excluded.is_empty() {
            continue;
        }
        for (sums, solve) in [
            (&mut rotation, &outcome.report.rotation),
            (&mut displacement, &outcome.report.displacement),
        ] {
            if let (Some(test), Some(solution)) = (&solve.test, &solve.solution) {
                sums.add_test(test, &solution.system.plane_of_row, k);
            }
        }
    }
    PlaneFigures {
        plane: label_name(rig.scenario(), label),
        seen: seen as f64 / runs as f64,
        displacement: displacement.figures(),
        rotation: rotation.figures(),
    }
}

fn false_alarms(outcomes: &[PairOutcome], configured: f64) -> FalseAlarms {
    let untestable = outcomes
        .iter()
        .filter(|o| o.report.status == crate::estimate::IntegrityStatus::UnderDetermined)
        .count();
    let alarms = outcomes.iter().filter(|o| o.detected()).count();
    let tested = outcomes.len() - untestable;
    FalseAlarms {
        pairs: outcomes.len(),
        untestable,
        alarms,
        rate: alarms as f64 / tested.max(1) as f64,
        configured,
    }
}

fn detection_row(bias: f64, outcomes: &[PairOutcome], names: &[(usize, String)]) -> DetectionRow {
    let fault_not_in_solve = outcomes.iter().filter(|o| !o.fault_in_solve()).count();
    let detected = outcomes.iter().filter(|o| o.detected()).count();
    DetectionRow {
        bias,
        pairs: outcomes.len(),
        fault_not_in_solve,
        detected,
        excluded_right_plane: outcomes.iter().filter(|o| o.excluded_the_fault()).count(),
        rate: detected as f64 / outcomes.len().max(1) as f64,
        per_plane: names
            .iter()
            .map(|(patch, name)| {
                let moved: Vec<&PairOutcome> = outcomes
                    .iter()
                    .filter(|o| o.fault.is_some_and(|f| f.patch() == *patch))
                    .collect();
                PlaneDetection {
                    plane: name.clone(),
                    pairs: moved.len(),
                    detected: moved.iter().filter(|o| o.detected()).count(),
                }
            })
            .collect(),
    }
}

fn write_detection(f: &mut fmt::Formatter<'_>, unit: &str, rows: &[DetectionRow]) -> fmt::Result {
    write!(
        f,
        "{:>8} {:>7} {:>10} {:>9} {:>9} {:>9} | rate by moved plane:",
        format!("bias {unit}"),
        "pairs",
        "not in fit",
        "detected",
        "rate",
        "excl ok"
    )?;
    for plane in rows.first().map_or(&[][..], |r| &r.per_plane[..]) {
        write!(f, " {:>10}", plane.plane)?;
    }
    writeln!(f)?;
    for r in rows {
        write!(
            f,
            "{:>8} {:>7} {:>10} {:>9} {:>9.4} {:>9} |                     ",
            r.bias, r.pairs, r.fault_not_in_solve, r.detected, r.rate, r.excluded_right_plane
        )?;
        for plane in &r.per_plane {
            write!(
                f,
                " {:>10.4}",
                plane.detected as f64 / plane.pairs.max(1) as f64
            )?;
        }
        writeln!(f)?;
    }
    Ok(())
}

impl fmt::Display for IntegrityCheckReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "integrity-check {}: {} pairs per case (seed {}), epochs at {:.3} s and {:.3} s, Pfa {:e}, Pmd {:e}",
            self.scenario,
            self.runs,
            self.seed,
            self.epoch_times_s[0],
            self.epoch_times_s[1],
            self.false_alarm_probability,
            self.missed_detection_probability
        )?;
        writeln!(
            f,
            "per plane: predicted / measured row sigma, gamma, threshold, MDB"
        )?;
        writeln!(
            f,
            "{:<28} {:>5} | {:>8} {:>8} {:>5} {:>8} {:>8} | {:>8} {:>8} {:>5} {:>8} {:>8}",
            "plane",
            "seen",
            "disp mm",
            "meas mm",
            "gamma",
            "thr mm",
            "MDB m",
            "rot mrad",
            "meas",
            "gamma",
            "thr mrad",
            "MDB deg"
        )?;
        for p in &self.planes {
            let (d, r) = (&p.displacement, &p.rotation);
            writeln!(
                f,
                "{:<28} {:>5.2} | {:>8.2} {:>8.2} {:>5.2} {:>8.1} {:>8.3} | {:>8.2} {:>8.2} {:>5.2} {:>8.1} {:>8.2}",
                p.plane,
                p.seen,
                d.predicted_sigma * 1e3,
                d.measured_sigma * 1e3,
                d.gamma,
                d.threshold * 1e3,
                d.mdb,
                r.predicted_sigma * 1e3,
                r.measured_sigma * 1e3,
                r.gamma,
                r.threshold * 1e3,
                r.mdb.to_degrees()
            )?;
        }
        let untestable = self.planes.iter().any(|p| {
            [&p.displacement, &p.rotation]
                .iter()
                .any(|r| !(r.gamma.is_finite() && r.threshold.is_finite() && r.mdb.is_finite()))
        });
        if untestable {
            writeln!(
                f,
                "inf: in some pairs no other plane checked a direction of that plane (it alone \
                 observed an axis, or too few planes for the rotation), so no bias along it is \
                 detectable: no threshold, an unbounded MDB; the figures are means over pairs"
            )?;
        }
        let fa = &self.false_alarms;
        writeln!(
            f,
            "false alarms: {} in {} tested pairs ({} untestable): rate {:.2e}, configured {:.2e}",
            fa.alarms,
            fa.pairs - fa.untestable,
            fa.untestable,
            fa.rate,
            fa.configured
        )?;
        writeln!(f, "detection, one plane moved along its normal:")?;
        write_detection(f, "m", &self.translation)?;
        writeln!(f, "detection, one plane turned about the body:")?;
        write_detection(f, "deg", &self.rotation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_counts_every_pair_and_inf_cells_are_explained() {
        let args = IntegrityCheckArgs {
            runs: 10,
            ..IntegrityCheckArgs::default()
        };
        let mut seen = Vec::new();
        let mut report =
            integrity_check_with_progress(&args, &mut |done, total| seen.push((done, total)))
                .unwrap();
        let total = pairs_to_run(&args);
        assert_eq!(total, 110);
        assert_eq!(
            seen,
            (1..=total).map(|done| (done, total)).collect::<Vec<_>>()
        );
        let all_finite = report.to_string();
        assert!(!all_finite.contains("inf"), "{all_finite}");
        report.planes[0].displacement.mdb = f64::INFINITY;
        let text = report.to_string();
        let explained = text
            .lines()
            .find(|l| l.starts_with("inf: "))
            .unwrap_or_else(|| panic!("{text}"));
        assert!(
            explained.contains("no bias along it is detectable"),
            "{explained}"
        );
    }
}
