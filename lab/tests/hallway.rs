//! Accuracy and consistency of the whole fusion on the hallway scenarios (docs/accuracy.md).
//!
//! The short seeded run is a real test; the full figures are `#[ignore]`d, release-mode runs:
//! `cargo test --release -p ladar-lab --test hallway -- --ignored --nocapture --test-threads 1`.
//!
//! The built-in hallway rig pitches the UST-20LX 30 deg down and rolls it 40 deg, so its lines
//! cross the level UTM-30LX's on the walls, the floor and the ceiling: every plane is built
//! from crossing lines and the odometry defaults (`accept_parallel_lines = false`, as the
//! daemon's replay uses them) apply. The "pitch-only" comparison sets the roll back to 0, the
//! rig before the change, where the floor and end-wall lines are parallel.

use ladar_lab::evaluate::{run_scenario, run_scenario_with, AccuracyReport, NeesPart};
use ladar_lab::monte_carlo::{run_monte_carlo, MonteCarloReport, MonteCarloSettings, UnitErrors};
use ladar_odometer::estimate::IntegrityStatus;
use ladar_odometer::filter::RelativePoseUpdate;
use ladar_odometer::fusion::FusionSettings;
use ladar_odometer::odometry::OdometryMethod;
use ladar_sim::{Scenario, Trajectory};

fn scenario(name: &str, duration_s: Option<f64>, skip: Option<u32>) -> Scenario {
    let mut scenario = Scenario::builtin(name).unwrap();
    if let Some(duration_s) = duration_s {
        scenario.duration_s = duration_s;
    }
    if let Some(skip) = skip {
        for scanner in &mut scenario.scanners {
            scanner.skip = skip;
        }
    }
    scenario
}

/// The rig before the roll: both scanners pitched about the body y axis only.
fn pitch_only(mut scenario: Scenario) -> Scenario {
    scenario.scanners[1].mount_rpy_deg[0] = 0.0;
    scenario
}

/// The named patches held still.
fn holding(mut scenario: Scenario, names: &[&str]) -> Scenario {
    for patch in &mut scenario.scene.patches {
        if names.contains(&patch.name.as_str()) {
            patch.motion = Default::default();
        }
    }
    scenario
}

/// The defaults, but for the stationary start (40 s on the hover, 10 s on the flight).
/// The paper's odometer (these studies are of its relative poses), after a stationary start
/// of `stationary_start_s`.
fn settings(stationary_start_s: f64) -> FusionSettings {
    let mut settings = FusionSettings::default();
    settings.odometry.method = OdometryMethod::Pairs;
    settings.filter.stationary_start_s = stationary_start_s;
    settings
}

fn at_10hz(mut settings: FusionSettings) -> FusionSettings {
    settings.fusion.epoch_rate_hz = 10.0;
    settings
}

/// Consecutive relative poses fused as independent, the conservative choice at 10 Hz.
fn independent_epochs(mut settings: FusionSettings) -> FusionSettings {
    settings.fusion.shared_plane_noise = false;
    settings
}

fn run(label: &str, scenario: &Scenario, settings: &FusionSettings) -> AccuracyReport {
    let report = run_scenario(scenario, settings).unwrap();
    println!("{label}: {}", serde_json::to_string(&report).unwrap());
    report
}

fn assert_within(report: &AccuracyReport, velocity: [f64; 3], attitude: [f64; 3], end_m: f64) {
    for axis in 0..3 {
        assert!(
            report.velocity_error_std_ned[axis] <= velocity[axis],
            "velocity std {:?} above {velocity:?}",
            report.velocity_error_std_ned
        );
        assert!(
            report.attitude_error_std_mrad[axis] <= attitude[axis],
            "attitude std {:?} above {attitude:?}",
            report.attitude_error_std_mrad
        );
    }
    assert!(
        report.horizontal_error_end_m <= end_m,
        "horizontal error {} m above {end_m} m",
        report.horizontal_error_end_m
    );
}

/// One run's time average is held to the spread it really has: its interval assumes
/// independent samples, but over seeds 100-139 of the 1 Hz hover the 9-dof average ranged
/// 6.7-16.6 (36 of 40 below 12, 7 inside [8.6, 9.4]) and the observable one 3.4-8.0 (one run
/// 13.5, the tilt of "What remains" in docs/accuracy.md). The Monte Carlo tests below are the
/// consistency test.
fn assert_honest(report: &AccuracyReport) {
    let bound = 12.0;
    assert!(
        report.nees_mean <= bound,
        "NEES {} above {bound} (interval {:?})",
        report.nees_mean,
        report.nees_interval
    );
    let observable_bound = 8.0;
    assert!(
        report.observable_nees_mean <= observable_bound,
        "observable NEES {} above {observable_bound} (interval {:?})",
        report.observable_nees_mean,
        report.observable_nees_interval
    );
}

/// The targets (paper: [0.058 0.026 0.032] m/s, [3 2 5] mrad, ~10 m).
fn assert_targets(report: &AccuracyReport) {
    assert_within(report, [0.03, 0.02, 0.02], [2.0, 2.0, 3.0], 2.0);
    assert_honest(report);
}

#[test]
fn short_hover_with_defaults_stays_accurate_and_never_fuses_a_detected_fault() {
    let scenario = scenario("hallway-hover", Some(70.0), None);
    let mut records = Vec::new();
    let report = run_scenario_with(&scenario, &settings(40.0), &mut |record, _| {
        records.push(record.clone())
    })
    .unwrap();
    println!("{}", serde_json::to_string(&report).unwrap());
    // The first 30 s of motion: pitch still settling.
    assert_within(&report, [0.015, 0.01, 0.005], [2.0, 3.0, 2.0], 0.1);
    assert!(report.epochs.fused >= 50, "{:?}", report.epochs);
    assert_honest(&report);
    for record in &records {
        if record.status == Some(IntegrityStatus::DetectedNotIsolable) {
            assert!(
                record.update.is_none(),
                "fused a detected fault at {}",
                record.t
            );
        }
        if let Some(IntegrityStatus::Excluded { .. }) = &record.status {
            assert!(!record.excluded_planes.is_empty());
            assert_eq!(record.used + record.excluded_planes.len(), record.matched);
        }
    }
}

#[test]
#[ignore]
fn hover_500s_1hz() {
    let report = run(
        "hallway-hover 1 Hz",
        &scenario("hallway-hover", None, None),
        &settings(40.0),
    );
    assert_targets(&report);
}

#[test]
#[ignore]
fn hover_500s_1hz_accepting_parallel_lines() {
    let mut settings = settings(40.0);
    settings.odometry.accept_parallel_lines = true;
    run(
        "hallway-hover 1 Hz, accept_parallel_lines",
        &scenario("hallway-hover", None, None),
        &settings,
    );
}

#[test]
#[ignore]
fn hover_500s_1hz_without_exclusion() {
    let mut settings = settings(40.0);
    settings.fusion.exclusion = false;
    run(
        "hallway-hover 1 Hz, no exclusion",
        &scenario("hallway-hover", None, None),
        &settings,
    );
}

#[test]
#[ignore]
fn hover_500s_1hz_velocity_update() {
    let mut settings = settings(40.0);
    settings.filter.relative_pose_update = RelativePoseUpdate::Velocity;
    run(
        "hallway-hover 1 Hz, velocity update",
        &scenario("hallway-hover", None, None),
        &settings,
    );
}

#[test]
#[ignore]
fn hover_500s_1hz_pitch_only() {
    let mut settings = settings(40.0);
    settings.odometry.accept_parallel_lines = true;
    run(
        "hallway-hover 1 Hz, pitch-only rig, accept_parallel_lines",
        &pitch_only(scenario("hallway-hover", None, None)),
        &settings,
    );
}

/// At 10 Hz the shared-noise model is optimistic on velocity while the door moves
/// (docs/accuracy.md, "Shared plane noise"): the accuracy targets hold, the honesty is bounded.
#[test]
#[ignore]
fn hover_500s_10hz() {
    let report = run(
        "hallway-hover 10 Hz",
        &scenario("hallway-hover", None, Some(3)),
        &at_10hz(settings(40.0)),
    );
    assert_within(&report, [0.03, 0.02, 0.02], [2.0, 2.0, 3.0], 2.0);
    assert!(report.nees_mean <= 1.4 * 9.0, "NEES {}", report.nees_mean);
}

/// With independent epochs, 10 Hz is honest but less accurate (yaw and along-track velocity).
#[test]
#[ignore]
fn hover_500s_10hz_independent_epochs() {
    let report = run(
        "hallway-hover 10 Hz, independent epochs",
        &scenario("hallway-hover", None, Some(3)),
        &independent_epochs(at_10hz(settings(40.0))),
    );
    assert_within(&report, [0.03, 0.02, 0.02], [2.0, 2.0, 5.0], 2.0);
    assert_honest(&report);
}

#[test]
#[ignore]
fn hover_500s_10hz_without_exclusion() {
    let mut settings = at_10hz(settings(40.0));
    settings.fusion.exclusion = false;
    run(
        "hallway-hover 10 Hz, no exclusion",
        &scenario("hallway-hover", None, Some(3)),
        &settings,
    );
}

#[test]
#[ignore]
fn hover_500s_10hz_velocity_update() {
    let mut settings = at_10hz(settings(40.0));
    settings.filter.relative_pose_update = RelativePoseUpdate::Velocity;
    run(
        "hallway-hover 10 Hz, velocity update",
        &scenario("hallway-hover", None, Some(3)),
        &settings,
    );
}

#[test]
#[ignore]
fn flight_1hz_and_10hz() {
    for (rate, skip) in [(1.0, None), (10.0, Some(3))] {
        let mut settings = settings(10.0);
        settings.fusion.epoch_rate_hz = rate;
        run(
            &format!("hallway-flight {rate} Hz"),
            &scenario("hallway-flight", None, skip),
            &settings,
        );
    }
}

/// Monte Carlo NEES (docs/accuracy.md, "NEES"): `runs` seeds of the hover from seed 100.
fn monte_carlo(
    label: &str,
    scenario: &Scenario,
    settings: &FusionSettings,
    runs: usize,
    unit_errors: UnitErrors,
) -> MonteCarloReport {
    let study = MonteCarloSettings {
        runs,
        first_seed: 100,
        unit_errors,
    };
    let report = run_monte_carlo(scenario, settings, &study).unwrap();
    println!("{label}: {}", serde_json::to_string(&report).unwrap());
    report
}

/// The run average lies inside its per-time 95 % interval at least `inside` of the time.
fn assert_consistent(report: &MonteCarloReport, part: NeesPart, inside: f64) {
    let statistic = report.part(part);
    assert!(
        statistic.fraction_inside >= inside,
        "{part:?} inside its interval {:.2} of the time, below {inside}: {statistic:?}",
        statistic.fraction_inside
    );
}

/// The run average is above its per-time interval at most `above` of the time.
fn assert_not_optimistic(report: &MonteCarloReport, part: NeesPart, above: f64) {
    let statistic = report.part(part);
    assert!(
        statistic.fraction_above <= above,
        "{part:?} above its interval {:.2} of the time: {statistic:?}",
        statistic.fraction_above
    );
}

/// The expected time-averaged NEES is the dof within the 95 % confidence interval the runs'
/// own time averages give (`NeesStatistic::between_runs_interval`): the test of the mean that
/// holds whatever the correlation between one run's times.
fn assert_mean_consistent(report: &MonteCarloReport, part: NeesPart) {
    let statistic = report.part(part);
    let [low, high] = statistic.between_runs_interval.expect("at least two runs");
    let dof = statistic.dof as f64;
    assert!(
        (low..=high).contains(&dof),
        "{part:?}: {dof} outside the between-runs interval [{low:.2}, {high:.2}] of mean {:.2}",
        statistic.mean
    );
}

/// The known optimism (docs/accuracy.md, "What remains"), bounded so it cannot grow unseen.
fn assert_mean_below(report: &MonteCarloReport, part: NeesPart, factor: f64) {
    let statistic = report.part(part);
    let bound = factor * statistic.dof as f64;
    assert!(
        statistic.mean <= bound,
        "{part:?} mean {} above {bound}",
        statistic.mean
    );
}

#[test]
#[ignore]
fn monte_carlo_nees_hover_1hz_scenario_unit() {
    let report = monte_carlo(
        "hallway-hover 1 Hz, Monte Carlo, scenario unit",
        &scenario("hallway-hover", None, None),
        &settings(40.0),
        40,
        UnitErrors::AsScenario,
    );
    for part in [
        NeesPart::Observable,
        NeesPart::Velocity,
        NeesPart::Attitude,
        NeesPart::Tilt,
        NeesPart::Yaw,
    ] {
        assert_consistent(&report, part, 0.85);
    }
    assert_consistent(&report, NeesPart::Position, 0.8);
    assert_consistent(&report, NeesPart::Full, 0.75);
    for part in [NeesPart::Velocity, NeesPart::Attitude, NeesPart::Yaw] {
        assert_not_optimistic(&report, part, 0.05);
    }
    for part in [
        NeesPart::Observable,
        NeesPart::Attitude,
        NeesPart::Tilt,
        NeesPart::Yaw,
    ] {
        assert_mean_consistent(&report, part);
    }
    // Position and tilt are a little optimistic (docs/accuracy.md, "What remains").
    assert_mean_below(&report, NeesPart::Full, 1.15);
    assert_mean_below(&report, NeesPart::Position, 1.2);
    assert_mean_below(&report, NeesPart::Tilt, 1.15);
    assert_mean_below(&report, NeesPart::Observable, 1.1);
}

#[test]
#[ignore]
fn monte_carlo_nees_hover_1hz_drawn_units() {
    let report = monte_carlo(
        "hallway-hover 1 Hz, Monte Carlo, drawn units",
        &scenario("hallway-hover", None, None),
        &settings(40.0),
        40,
        UnitErrors::DrawnFromFilterPrior,
    );
    assert_consistent(&report, NeesPart::Velocity, 0.85);
    assert_consistent(&report, NeesPart::Yaw, 0.85);
    for part in [NeesPart::Velocity, NeesPart::Yaw] {
        assert_not_optimistic(&report, part, 0.1);
    }
    assert_mean_below(&report, NeesPart::Full, 1.25);
    assert_mean_below(&report, NeesPart::Position, 1.2);
    assert_mean_below(&report, NeesPart::Tilt, 1.5);
}

#[test]
#[ignore]
fn monte_carlo_nees_hover_10hz_drawn_units() {
    let report = monte_carlo(
        "hallway-hover 10 Hz, Monte Carlo, drawn units",
        &scenario("hallway-hover", None, Some(3)),
        &at_10hz(settings(40.0)),
        20,
        UnitErrors::DrawnFromFilterPrior,
    );
    // Optimistic at 10 Hz: position and velocity while the door moves, and tilt
    // (docs/accuracy.md, "What remains"). Before plane confirmation: full 2.4, position 3.5.
    assert_mean_below(&report, NeesPart::Full, 1.5);
    assert_mean_below(&report, NeesPart::Position, 1.6);
    assert_mean_below(&report, NeesPart::Tilt, 1.7);
    assert_mean_below(&report, NeesPart::Velocity, 1.35);
    assert_mean_consistent(&report, NeesPart::Yaw);
}

#[test]
#[ignore]
fn monte_carlo_nees_hover_10hz_scenario_unit() {
    let report = monte_carlo(
        "hallway-hover 10 Hz, Monte Carlo, scenario unit",
        &scenario("hallway-hover", None, Some(3)),
        &at_10hz(settings(40.0)),
        20,
        UnitErrors::AsScenario,
    );
    assert_consistent(&report, NeesPart::Tilt, 0.8);
    // Yaw is judged by its mean only: its error hardly changes within a run, so the per-time
    // interval, which takes the 20 runs' times as independent, is no test of it. The mean moves
    // with the seeds (1.60, 1.23 and 0.81 from first seeds 100, 200 and 300) inside the
    // between-runs interval.
    for part in [NeesPart::Attitude, NeesPart::Tilt, NeesPart::Yaw] {
        assert_mean_consistent(&report, part);
    }
    // Optimistic at 10 Hz whatever the unit: position and velocity, while the door moves
    // (docs/accuracy.md, "Shared plane noise"). Before plane confirmation: full 2.35,
    // position 3.6, velocity 2.3.
    assert_mean_below(&report, NeesPart::Full, 1.4);
    assert_mean_below(&report, NeesPart::Position, 1.6);
    assert_mean_below(&report, NeesPart::Velocity, 1.35);
    assert_mean_below(&report, NeesPart::Tilt, 1.2);
}

/// The same study with independent epochs is never optimistic, door and board moving.
#[test]
#[ignore]
fn monte_carlo_nees_hover_10hz_independent_epochs() {
    let report = monte_carlo(
        "hallway-hover 10 Hz, Monte Carlo, scenario unit, independent epochs",
        &scenario("hallway-hover", None, Some(3)),
        &independent_epochs(at_10hz(settings(40.0))),
        20,
        UnitErrors::AsScenario,
    );
    for part in NeesPart::ALL {
        assert_not_optimistic(&report, part, 0.07);
        assert_mean_below(&report, part, 1.0);
    }
}

/// The 10 Hz study above, scenario unit, with the named patches held still.
fn monte_carlo_10hz_holding(label: &str, held: &[&str]) -> MonteCarloReport {
    monte_carlo(
        label,
        &holding(scenario("hallway-hover", None, Some(3)), held),
        &at_10hz(settings(40.0)),
        20,
        UnitErrors::AsScenario,
    )
}

/// The 10 Hz position and velocity optimism of the scenario-unit study is the door's: with it
/// still (and the board still or moving), position falls from 1.34 to under 1.1 times its dof
/// and velocity from 1.22 to under 1.1; yaw and tilt are consistent.
fn assert_door_still_10hz(report: &MonteCarloReport) {
    for part in [NeesPart::Full, NeesPart::Position, NeesPart::Velocity] {
        assert_mean_below(report, part, 1.1);
    }
    for part in [
        NeesPart::Full,
        NeesPart::Position,
        NeesPart::Yaw,
        NeesPart::Tilt,
    ] {
        assert_mean_consistent(report, part);
    }
    assert_consistent(report, NeesPart::Tilt, 0.9);
}

#[test]
#[ignore]
fn monte_carlo_nees_hover_10hz_door_and_board_still() {
    assert_door_still_10hz(&monte_carlo_10hz_holding(
        "hallway-hover 10 Hz, Monte Carlo, scenario unit, door and board still",
        &["door", "board"],
    ));
}

#[test]
#[ignore]
fn monte_carlo_nees_hover_10hz_door_still_board_moving() {
    assert_door_still_10hz(&monte_carlo_10hz_holding(
        "hallway-hover 10 Hz, Monte Carlo, scenario unit, door still, board moving",
        &["door"],
    ));
}

/// With the door taken out, its doorway opens on the room, and a line on the room's wall with a
/// line on the hallway ceiling makes a fictitious plane in a third of the epochs, moving with
/// the body by less in 0.1 s than integrity detects (docs/accuracy.md, "Plane confirmation").
/// Confirmed over a second, it is refused and the filter is consistent: without it position
/// was 3 times its dof.
#[test]
#[ignore]
fn monte_carlo_nees_hover_10hz_open_doorway() {
    let mut scenario = holding(scenario("hallway-hover", None, Some(3)), &["board"]);
    scenario.scene.patches.retain(|patch| patch.name != "door");
    let report = monte_carlo(
        "hallway-hover 10 Hz, Monte Carlo, scenario unit, open doorway, board still",
        &scenario,
        &at_10hz(settings(40.0)),
        20,
        UnitErrors::AsScenario,
    );
    for part in NeesPart::ALL {
        let position = part == NeesPart::Position;
        assert_mean_below(&report, part, if position { 1.3 } else { 1.1 });
    }
    // Yaw is a little conservative (0.73). Position is judged by the between-runs test alone:
    // it is a random walk, so 20 runs give about 20 samples of it and neither the per-time
    // interval nor a bound of 1.1 on the mean resolves it (mean 3.29 at stop 15, 3.71 now, both
    // inside their between-runs intervals, [2.2, 4.4] and [2.7, 4.7]).
    for part in [NeesPart::Full, NeesPart::Position, NeesPart::Attitude] {
        assert_mean_consistent(&report, part);
    }
}

/// The Monte Carlo study in small: three seeds of a short hover whose motion starts right
/// after a 5 s stationary start, each with its own IMU unit drawn from the filter's prior.
#[test]
fn short_monte_carlo_keeps_velocity_consistent_and_is_never_optimistic() {
    let report = short_monte_carlo(&settings(5.0));
    assert_consistent(&report, NeesPart::Velocity, 0.75);
    assert_consistent(&report, NeesPart::Observable, 0.75);
    for part in NeesPart::ALL {
        assert_not_optimistic(&report, part, 0.1);
    }
}

/// The same on the plane map: never optimistic. It is conservative by the allowance it makes
/// for real surfaces (roughness and waviness), which the simulator's planes do not have
/// (docs/accuracy.md, "The plane map"), so its NEES lies below the interval.
#[test]
fn on_the_plane_map_the_short_monte_carlo_is_never_optimistic() {
    let mut settings = settings(5.0);
    settings.odometry.method = OdometryMethod::Map;
    let report = short_monte_carlo(&settings);
    for part in NeesPart::ALL {
        assert_not_optimistic(&report, part, 0.1);
    }
}

/// Three seeds of a short hover whose motion starts right after a 5 s stationary start, each
/// with its own IMU unit drawn from the filter's prior.
fn short_monte_carlo(settings: &FusionSettings) -> MonteCarloReport {
    let mut scenario = scenario("hallway-hover", Some(17.0), None);
    if let Trajectory::Hover { oscillation, .. } = &mut scenario.trajectory {
        oscillation.start_s = 5.0;
        oscillation.ramp_s = 2.0;
    }
    let study = MonteCarloSettings {
        runs: 3,
        first_seed: 1,
        unit_errors: UnitErrors::DrawnFromFilterPrior,
    };
    let report = run_monte_carlo(&scenario, settings, &study).unwrap();
    println!("{}", serde_json::to_string(&report).unwrap());
    assert_eq!(report.times, 13);
    report
}

/// The flight on the plane map: after the turn at the hallway's end the level scanner looks
/// back at the cabinet's far face, parallel to the near face the map holds and 0.6 m behind
/// it. With the position 0.24 m unsure along the hallway the far face fitted the near face's
/// surface, and the body was set 0.6 m off at a sigma of 6 mm for the rest of the flight
/// (position NEES 822 over three axes). A face is seen from its own side only
/// (`plane_map::seen_from_its_side`).
#[test]
fn on_the_plane_map_a_face_seen_from_behind_never_moves_the_body() {
    let mut settings = settings(10.0);
    settings.odometry.method = OdometryMethod::Map;
    let report = run(
        "hallway-flight 1 Hz, map",
        &scenario("hallway-flight", None, None),
        &settings,
    );
    let position_nees = report.nees_block_means[0];
    assert!(
        position_nees < 9.0,
        "position NEES {position_nees} over 3 axes"
    );
    assert!(report.horizontal_error_end_m < 1.0, "{report:?}");
}
