//! End to end through the geometry core on simulated scenarios: scans from the simulator,
//! deskewed with the true motion, planes extracted, matched by the core's own matcher under a
//! prior centred on the truth, and both solves compared with the true relative pose. No filter,
//! no integrity: this checks that the core's covariances are honest on realistic scenes.

use ladar_odometer::integrity::{IntegrityConfig, IntegrityMonitor};
use ladar_odometer::integrity_check::Rig;
use ladar_odometer::odometry::{OdometryConfig, RelativePose};
use ladar_sim::Scenario;
use nalgebra::{Matrix6, UnitQuaternion, Vector6};

/// chi-square with 6 degrees of freedom: 99.9 % point.
const NEES_999: f64 = 22.458;

#[derive(Debug, Default)]
struct Summary {
    pairs: usize,
    under_determined: usize,
    solved: usize,
    mean_nees: f64,
    beyond_999: usize,
    max_rotation_mrad: f64,
    max_displacement_mm: f64,
    mean_planes: f64,
    /// Solved pairs the integrity monitor (default settings) lets through as usable, and of
    /// those the ones beyond the 99.9 % point: what would reach a filter.
    usable: usize,
    usable_beyond_999: usize,
}

/// Consecutive scan epochs of a scenario in `[from_s, to_s)`, each pair solved and scored.
fn consecutive(name: &str, from_s: f64, to_s: f64, config: OdometryConfig) -> Summary {
    let scenario = Scenario::builtin(name).unwrap();
    let mut rig = Rig::new(&scenario, scenario.seed, config).unwrap();
    let period = rig.epoch_times[1] - rig.epoch_times[0];
    let epochs = ((to_s - from_s) / period).floor() as usize;
    let times: Vec<[f64; 2]> = (1..epochs)
        .map(|k| [k - 1, k].map(|e| from_s + e as f64 * period))
        .collect();
    score(&format!("{name} {from_s}-{to_s} s"), &mut rig, &times)
}

/// Solves the pair of epochs starting at each `[t_i, t_j]` (fresh noise every capture).
fn score(label: &str, rig: &mut Rig, times: &[[f64; 2]]) -> Summary {
    let monitor = IntegrityMonitor::new(IntegrityConfig::default()).unwrap();
    let mut summary = Summary::default();
    let mut nees_sum = 0.0;
    let mut planes = 0;
    for &[ti, tj] in times {
        let previous = rig.capture(ti);
        let current = rig.capture(tj);
        let truth = rig.true_relative_pose(&previous, &current);
        let prior = RelativePose {
            rotation: truth.rotation,
            translation: truth.translation,
            ..RelativePose::stationary(0.01, 0.05)
        };
        let epoch = rig
            .odometer
            .solve(&previous.planes, &current.planes, &prior);
        summary.pairs += 1;
        planes += current.planes.planes.len();
        match (&epoch.rotation, &epoch.displacement) {
            (Ok(rotation), Ok(displacement)) => {
                let rotation_error = (UnitQuaternion::from_scaled_axis(rotation.x)
                    * truth.rotation.inverse())
                .scaled_axis();
                let displacement_error = displacement.x - truth.translation;
                let error = Vector6::from_iterator(
                    rotation_error
                        .iter()
                        .chain(displacement_error.iter())
                        .copied(),
                );
                let mut covariance = Matrix6::zeros();
                covariance
                    .fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&rotation.covariance);
                covariance
                    .fixed_view_mut::<3, 3>(3, 3)
                    .copy_from(&displacement.covariance);
                let nees = error.dot(&(covariance.try_inverse().unwrap() * error));
                summary.solved += 1;
                nees_sum += nees;
                summary.beyond_999 += usize::from(nees > NEES_999);
                let odometer = &rig.odometer;
                let resolve = |excluded: &[usize]| {
                    odometer.resolve(&previous.planes, &current.planes, &epoch, excluded)
                };
                let report = monitor.check_epoch(
                    epoch.rotation.clone(),
                    epoch.displacement.clone(),
                    &mut |excluded| resolve(excluded).rotation,
                    &mut |excluded| resolve(excluded).displacement,
                );
                if report.status.usable() && report.excluded.is_empty() {
                    summary.usable += 1;
                    summary.usable_beyond_999 += usize::from(nees > NEES_999);
                }
                summary.max_rotation_mrad =
                    summary.max_rotation_mrad.max(rotation_error.norm() * 1e3);
                summary.max_displacement_mm = summary
                    .max_displacement_mm
                    .max(displacement_error.norm() * 1e3);
            }
            _ => summary.under_determined += 1,
        }
    }
    summary.mean_nees = nees_sum / summary.solved.max(1) as f64;
    summary.mean_planes = planes as f64 / summary.pairs.max(1) as f64;
    println!("{label}: {summary:?}");
    summary
}

fn assert_honest(summary: &Summary, max_under_determined_share: f64) {
    let pairs = summary.pairs as f64;
    assert!(
        (summary.under_determined as f64) <= max_under_determined_share * pairs,
        "{summary:?}"
    );
    // Mean NEES of a consistent 6-DOF estimate is 6; allow the spread of a modest sample and
    // mildly pessimistic covariances, never optimistic ones.
    assert!((2.0..=9.0).contains(&summary.mean_nees), "{summary:?}");
    assert!(
        summary.beyond_999 as f64 <= 0.01 * summary.solved as f64 + 1.0,
        "{summary:?}"
    );
}

/// Paper-sim's two epochs (a 0.72 m step between them), solved with the core's own matcher
/// many times with fresh noise: every pair solves and the errors match the covariances.
#[test]
fn paper_sim_pairs_solve_with_honest_covariances() {
    let scenario = Scenario::paper_sim(ladar_sim::PaperBias::None);
    let mut rig = Rig::new(
        &scenario,
        21,
        ladar_odometer::integrity_check::paper_config(),
    )
    .unwrap();
    let times = vec![rig.epoch_times; 300];
    let summary = score("paper-sim", &mut rig, &times);
    assert_eq!(summary.solved, summary.pairs, "{summary:?}");
    assert_honest(&summary, 0.0);
}

/// The hallway scenarios end to end through the core alone. Known to fail (docs/figures.md
/// section 5): flight pairs leave the motion along the hallway unobserved (the fusion anchors
/// it with the filter's prior), and some hover pairs that integrity passes are 4-8 sigma off
/// in roll, from moving or fictitious planes the tests do not flag.
#[test]
#[ignore = "fails on the core alone: unobserved along-hallway motion, unflagged hover roll bias; docs/figures.md section 5"]
fn hallway_scenarios_solve_with_honest_covariances() {
    let config = OdometryConfig::default;
    let still = consecutive("hallway-hover", 0.0, 40.0, config());
    let hover = consecutive("hallway-hover", 100.0, 120.0, config());
    let flight = consecutive("hallway-flight", 0.0, 43.0, config());
    for summary in [&still, &hover, &flight] {
        assert_honest(summary, 0.2);
    }
}

/// The two hallway scanners' lines on the left wall cross near their centres (both scan
/// planes contain the body's y axis), where eq 8 degenerates; the plane is then fitted to both
/// lines, and its predicted sigmas must stay honest (0.8x to 3x the Monte Carlo scatter).
#[test]
fn a_side_wall_seen_by_crossing_lines_is_found_with_honest_sigmas() {
    let scenario = Scenario::builtin("hallway-hover").unwrap();
    let runs = 300;
    let table =
        ladar_lab::sigma::plane_sigma_table(&scenario, &OdometryConfig::default(), 0.0, runs, 5)
            .unwrap();
    println!("{table}");
    let wall = table.rows.iter().find(|r| r.plane == "left-wall").unwrap();
    assert!(wall.found * 10 >= runs * 9, "{table}");
    // Three standard errors of a standard deviation from `runs` samples below 0.8.
    let lowest = 0.8 * (1.0 - 3.0 / (2.0 * runs as f64).sqrt());
    for ratio in wall.ratios() {
        assert!((lowest..=3.0).contains(&ratio), "{table}");
    }
}

/// docs/accuracy.md, "Plane sigmas on the hallway": mid-hover, every surface's predicted sigmas
/// match its scatter, the cabinet's small faces as well as the floor and the long wall. They did
/// not while split points wandered past corners and fits regressed on noisy abscissae: the
/// cabinet's faces then erred 1.2 to 1.6 times more than predicted, with a 1-2 mm distance bias
/// and 3 % of its planes beyond 6 sigma.
#[test]
#[ignore = "release-mode study, about 1 s: run with --ignored --nocapture"]
fn hallway_planes_mid_hover_have_honest_sigmas_and_no_distance_bias() {
    let mut scenario = Scenario::builtin("hallway-hover").unwrap();
    for patch in &mut scenario.scene.patches {
        patch.motion = Default::default();
    }
    for t in [45.0, 60.0] {
        let table =
            ladar_lab::sigma::plane_sigma_table(&scenario, &OdometryConfig::default(), t, 1000, 1)
                .unwrap();
        println!("{table}");
        for surface in ["floor", "left-wall", "cabinet.-x", "cabinet.+y"] {
            let row = table.rows.iter().find(|r| r.plane == surface).unwrap();
            assert!(
                row.found >= 990 && row.gross_errors * 100 < row.found,
                "{surface}: {table}"
            );
            for ratio in row.ratios() {
                assert!((0.9..1.15).contains(&ratio), "{surface}: {table}");
            }
            // Four standard errors of the mean.
            let bias_limit = 4.0 * row.measured_rho_mm / (row.found as f64).sqrt();
            assert!(
                row.mean_rho_error_mm.abs() < bias_limit,
                "{surface}: {table}"
            );
        }
    }
}
