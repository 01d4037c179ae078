//! The scenes the plane map of issue 18 is judged on (open-room, hall-walk, bare-corridor),
//! each with the paper's rig and with the rolled rig of `config/default.toml`: with the
//! scan-to-scan pairs odometer, how many planes an epoch has, how often the planes leave a
//! displacement axis unobserved, and what that costs in velocity, attitude and drift
//! (docs/accuracy.md, "Rooms and halls: the pairs baseline"); and the same scenes on the plane
//! map (`odometry.method = "map"`; docs/accuracy.md, "The plane map").
//!
//! The short runs are real tests; the baselines and the map's Monte Carlo study are
//! `#[ignore]`d, release-mode studies:
//! `cargo test --release -p ladar-lab --test plane_map_scenes -- --ignored --nocapture --test-threads 1`.

use ladar_lab::evaluate::{run_scenario_with, AccuracyReport};
use ladar_odometer::filter::Observability;
use ladar_odometer::fusion::record::{EpochOutcome, EpochRecord};
use ladar_odometer::fusion::{Fusion, FusionSettings};
use ladar_odometer::odometry::OdometryMethod;
use ladar_sim::{ImuSpread, Scenario, SimEvent, Simulator, Trajectory};
use nalgebra::Vector3;
use serde::Serialize;

/// Every scene stands still for its first 10 s: the filter's stationary start.
const STILL_S: f64 = 10.0;

/// Seeds of the baseline; the targets will need 20 runs.
const SEEDS: [u64; 5] = [100, 101, 102, 103, 104];

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Rig {
    /// The paper's: the UST-20LX pitched 30 deg down about the UTM-30LX's axis.
    Paper,
    /// `config/default.toml`'s: the UST-20LX also rolled 40 deg.
    Rolled,
}

/// `name` with `rig` and the scanners' scan interval for `epoch_rate_hz` (4 and 10 scans/s).
fn scenario(name: &str, rig: Rig, epoch_rate_hz: f64) -> Scenario {
    let mut scenario = Scenario::builtin(name).unwrap();
    if rig == Rig::Rolled {
        scenario = scenario.with_rolled_rig();
    }
    if epoch_rate_hz > 4.0 {
        for scanner in &mut scenario.scanners {
            scanner.skip = 3;
        }
    }
    scenario
}

/// The paper's odometer as the daemon replays a simulated recording (`simulate` writes the
/// still start into the rig's configuration); `map_settings` for the plane map.
fn settings(epoch_rate_hz: f64) -> FusionSettings {
    let mut settings = FusionSettings::default();
    settings.odometry.method = OdometryMethod::Pairs;
    settings.filter.stationary_start_s = STILL_S;
    settings.fusion.epoch_rate_hz = epoch_rate_hz;
    settings
}

/// Displacement axes the planes of an epoch leave unobserved: those the fusion anchored to the
/// filter's prior (`unobservable_displacement`), or all three when nothing was anchored and
/// there was no solve (too few planes, or none since the chain restarted). On the plane map,
/// those no fused surface faced, or all three when nothing was fused.
fn unobserved_axes(record: &EpochRecord) -> usize {
    if record.map.is_some() {
        // The map's epochs name the directions none of the surfaces fused faced.
        return match record.outcome {
            EpochOutcome::Fused => record.unobservable_displacement.len(),
            _ => 3,
        };
    }
    let solved = record
        .integrity
        .as_ref()
        .is_some_and(|report| report.displacement.solution.is_some());
    match record.unobservable_displacement.len() {
        0 if !solved => 3,
        anchored => anchored,
    }
}

/// Displacement axes the epoch gave the filter, as the fusion chooses them: none when
/// integrity did not clear the displacement (untestable for want of redundancy, or a fault not
/// isolable), else all but the unobserved ones and those a single plane alone observes
/// (integrity's unprotected directions).
fn fused_axes(record: &EpochRecord) -> usize {
    let (Some(_), Some(report)) = (&record.displacement, &record.integrity) else {
        return 0;
    };
    let unprotected = report
        .displacement
        .test
        .iter()
        .flat_map(|test| test.unprotected.iter());
    let left_out: Vec<Vector3<f64>> = record
        .unobservable_displacement
        .iter()
        .chain(unprotected)
        .map(|&u| Vector3::from(u))
        .collect();
    Observability::from_unobservable(&left_out).rank()
}

/// Why an epoch gave the filter no displacement axis.
#[derive(Debug, Clone, Copy)]
enum Unfused {
    /// The planes left an axis unobserved and the solve anchored it, but refused the anchored
    /// system: along an axis unobserved for a while the anchor's sigma reaches its 0.1 m cap,
    /// and the solve's own weighted test (`least_squares::PARALLEL_TOLERANCE`, 1e-3 of the
    /// strongest direction) then counts that axis unobserved again.
    AnchorRefused,
    /// Solved, but too few planes (or too ill-conditioned) for the parity test.
    Untestable,
    /// No solve: too few planes, or none since the chain restarted.
    NoSolve,
    /// A fault not isolable, or every observed direction unprotected.
    Other,
}

fn unfused_reason(record: &EpochRecord) -> Unfused {
    let solve = record.integrity.as_ref().map(|report| &report.displacement);
    let solved = solve.is_some_and(|solve| solve.solution.is_some());
    if record.displacement.is_some() {
        Unfused::Other
    } else if !solved && !record.unobservable_displacement.is_empty() {
        Unfused::AnchorRefused
    } else if !solved {
        Unfused::NoSolve
    } else if solve.is_some_and(|solve| solve.untestable.is_some()) {
        Unfused::Untestable
    } else {
        Unfused::Other
    }
}

/// One run's figures after the stationary start.
#[derive(Debug, Clone, Serialize)]
struct Baseline {
    epochs: usize,
    planes_per_epoch: f64,
    /// Epochs whose planes leave 0, 1, 2 and 3 displacement axes unobserved.
    unobserved_axes: [usize; 4],
    /// Share of the epochs whose planes leave at least one displacement axis unobserved.
    unobserved_share: f64,
    /// Epochs giving the filter 0, 1, 2 and 3 displacement axes.
    fused_axes: [usize; 4],
    /// Share of the epochs giving the filter fewer than three displacement axes.
    short_share: f64,
    /// Epochs giving it none, by `Unfused` reason in declaration order.
    unfused: [usize; 4],
    accuracy: AccuracyReport,
}

fn measure(scenario: &Scenario, settings: &FusionSettings) -> Baseline {
    let (mut epochs, mut planes) = (0, 0);
    let (mut unobserved, mut fused, mut unfused) = ([0; 4], [0; 4], [0; 4]);
    let accuracy = run_scenario_with(scenario, settings, &mut |record, _| {
        if record.t >= settings.filter.stationary_start_s {
            epochs += 1;
            planes += record.planes;
            unobserved[unobserved_axes(record)] += 1;
            let axes = fused_axes(record);
            fused[axes] += 1;
            if axes == 0 {
                unfused[unfused_reason(record) as usize] += 1;
            }
        }
    })
    .unwrap();
    let share = |count: usize| count as f64 / epochs.max(1) as f64;
    Baseline {
        epochs,
        planes_per_epoch: share(planes),
        unobserved_axes: unobserved,
        unobserved_share: share(epochs - unobserved[0]),
        fused_axes: fused,
        short_share: share(epochs - fused[3]),
        unfused,
        accuracy,
    }
}

/// Patches that at least `min_points` beams of scanner `sensor` hit in its scan from `t0`.
fn seen_by(sim: &mut Simulator, sensor: usize, t0: f64, min_points: usize) -> Vec<String> {
    let (_, hits) = sim.scan_labelled(sensor, t0);
    let mut counts = vec![0usize; sim.scene.patches.len()];
    for patch in hits.into_iter().flatten() {
        counts[patch] += 1;
    }
    (0..counts.len())
        .filter(|&p| counts[p] >= min_points)
        .map(|p| sim.scene.patches[p].name.clone())
        .collect()
}

/// The first `seconds` of `name` with either rig: after the still start every epoch has at
/// least `min_planes` planes, with `mean_planes` on average, and `mean_matched` of them on
/// average match a plane of the epoch before: the scene's surfaces are seen as planes, again
/// and again. Whether they fuse is the baseline's question, not this test's.
fn assert_sees_planes(
    name: &str,
    seconds: f64,
    min_planes: usize,
    mean_planes: f64,
    mean_matched: f64,
) {
    for rig in [Rig::Paper, Rig::Rolled] {
        let mut scenario = scenario(name, rig, 1.0);
        scenario.duration_s = seconds;
        let mut records = Vec::new();
        run_scenario_with(&scenario, &settings(1.0), &mut |record, _| {
            if record.t >= STILL_S {
                records.push(record.clone());
            }
        })
        .unwrap();
        let fewest = records.iter().map(|r| r.planes).min().unwrap_or(0);
        let per_epoch = |count: fn(&EpochRecord) -> usize| {
            records.iter().map(count).sum::<usize>() as f64 / records.len() as f64
        };
        let (planes, matched) = (per_epoch(|r| r.planes), per_epoch(|r| r.matched));
        println!(
            "{name} {rig:?}: {} epochs, {fewest} planes at least, {planes:.1} on average, {matched:.1} matched",
            records.len()
        );
        assert!(records.len() as f64 >= seconds - STILL_S - 1.0);
        assert!(
            fewest >= min_planes && planes >= mean_planes && matched >= mean_matched,
            "{name} {rig:?}"
        );
    }
}

#[test]
fn open_room_shows_its_door_person_and_furniture_and_the_odometer_planes() {
    let mut sim = Simulator::new(&Scenario::builtin("open-room").unwrap()).unwrap();
    let level = seen_by(&mut sim, 0, 0.5, 10);
    for surface in [
        "front-wall",
        "left-wall",
        "door",
        "pillar.-x",
        "bookshelf.+y",
    ] {
        assert!(level.iter().any(|s| s == surface), "{level:?}");
    }
    // The door open (t = 12.5 s) shows the corridor; at t = 31 s the person is 2.5 m away,
    // at the near end of the walk.
    assert!(seen_by(&mut sim, 0, 12.5, 10).contains(&"corridor-wall".into()));
    let pitched = seen_by(&mut sim, 1, 31.0, 10);
    assert!(pitched.iter().any(|s| s == "person"), "{pitched:?}");
    // Crossing the room: the body is at the far side, still, by 90 s.
    let end = sim.truth_at(90.0);
    assert!(
        (end.p.xy() - nalgebra::Vector2::new(5.0, 1.0)).norm() < 0.1,
        "{}",
        end.p
    );
    assert!((sim.truth_at(72.0).v.norm() - 0.25).abs() < 0.05);
    assert_sees_planes("open-room", 60.0, 2, 2.5, 1.5);
}

#[test]
fn hall_walk_loops_round_its_pillars_and_the_odometer_planes() {
    let mut sim = Simulator::new(&Scenario::builtin("hall-walk").unwrap()).unwrap();
    let level = seen_by(&mut sim, 0, 0.5, 10);
    for surface in [
        "left-wall",
        "right-wall",
        "back-wall",
        "pillar-1.-x",
        "counter.-y",
    ] {
        assert!(level.iter().any(|s| s == surface), "{level:?}");
    }
    // Halfway down the second long leg, facing back along the hall.
    let turned = sim.truth_at(60.5);
    assert!((turned.q.euler_angles().2.to_degrees().abs() - 180.0).abs() < 5.0);
    assert!((turned.v.norm() - 0.6).abs() < 0.05);
    assert!(seen_by(&mut sim, 0, 60.5, 10).contains(&"person".into()));
    // An epoch in a corner turn may see one plane only: the planes depend on the filter's
    // poses (deskew, confirmation), and which epoch that is moves with them.
    assert_sees_planes("hall-walk", 60.0, 1, 2.5, 1.5);
}

/// With the defaults (level and wall lines) the open room, with the paper's rig, observes all
/// three displacement axes in all but issue 18's 5 % of its epochs, where the pairs alone leave
/// one unobserved in every epoch (the baseline below), and the crossing ends within
/// centimetres where the pairs drift by metres (3.7-28.8 m over the baseline's seeds). Until
/// planes of parallel lines had to be level within a degree, a leaning one took the floor's
/// lines and left the vertical unobserved in 18 % of the epochs (docs/accuracy.md, "A floor of
/// two parallel lines that leaned").
#[test]
fn single_line_planes_keep_the_open_room_observed() {
    let run = measure(&scenario("open-room", Rig::Paper, 1.0), &settings(1.0));
    println!("{}", serde_json::to_string(&run).unwrap());
    assert!(run.unobserved_share < 0.05, "{}", run.unobserved_share);
    assert!(
        run.accuracy.horizontal_error_end_m < 0.1,
        "{}",
        run.accuracy.horizontal_error_end_m
    );
}

/// Three axes' figures for a table cell, `decimals` each.
fn axes(values: [f64; 3], decimals: usize) -> String {
    values.map(|v| format!("{v:.decimals$}")).join(", ")
}

/// Per axis, the mean over `runs` of a figure of their accuracy.
fn mean_axes(runs: &[Baseline], figure: fn(&AccuracyReport) -> [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|k| mean(runs.iter().map(|r| figure(&r.accuracy)[k])))
}

fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let values: Vec<f64> = values.collect();
    values.iter().sum::<f64>() / values.len() as f64
}

/// One row of the baseline: `SEEDS` runs of one scene with one rig at one epoch rate, averaged.
fn study(name: &str, rig: Rig, epoch_rate_hz: f64, single: SingleLines) {
    let scenario = scenario(name, rig, epoch_rate_hz);
    let mut settings = settings(epoch_rate_hz);
    settings.odometry.level_lines = single.level;
    settings.odometry.wall_lines = single.walls;
    let runs: Vec<Baseline> = SEEDS
        .iter()
        .map(|&seed| {
            let mut seeded = scenario.clone();
            seeded.seed = seed;
            let run = measure(&seeded, &settings);
            println!(
                "{} {epoch_rate_hz} Hz seed {seed}: {}",
                scenario.name,
                serde_json::to_string(&run).unwrap()
            );
            run
        })
        .collect();
    let velocity = mean_axes(&runs, |r| r.velocity_error_std_ned);
    let attitude = mean_axes(&runs, |r| r.attitude_error_std_mrad);
    let total = |f: fn(&Baseline) -> [usize; 4]| -> [usize; 4] {
        std::array::from_fn(|k| runs.iter().map(|r| f(r)[k]).sum())
    };
    let unobserved = total(|r| r.unobserved_axes);
    let fused = total(|r| r.fused_axes);
    let unfused = total(|r| r.unfused);
    let mut horizontal: Vec<f64> = runs
        .iter()
        .map(|r| r.accuracy.horizontal_error_end_m)
        .collect();
    horizontal.sort_by(f64::total_cmp);
    let share =
        |count: usize, of: [usize; 4]| 100.0 * count as f64 / of.iter().sum::<usize>() as f64;
    let run = &runs[0].accuracy;
    println!(
        "| {} | {epoch_rate_hz} Hz | {:.1} | {:.0} % | {:.0} / {:.0} / {:.0} % | {:.0} / {:.0} / {:.0} / {:.0} % | {} | {} | {:.1} ({:.1}-{:.1}) in {:.0} s |",
        scenario.name,
        mean(runs.iter().map(|r| r.planes_per_epoch)),
        share(unobserved[1] + unobserved[2] + unobserved[3], unobserved),
        share(fused[3], fused),
        share(fused[1] + fused[2], fused),
        share(fused[0], fused),
        share(unfused[0], fused),
        share(unfused[1], fused),
        share(unfused[2], fused),
        share(unfused[3], fused),
        axes(velocity, 3),
        axes(attitude, 2),
        horizontal[horizontal.len() / 2],
        horizontal[0],
        horizontal[horizontal.len() - 1],
        run.to_s - run.from_s,
    );
    // The premise of issue 18: with scan-to-scan pairs these scenes leave a displacement axis
    // unobserved in most epochs. When this fails, the scenes or the odometer changed and
    // docs/accuracy.md's baseline is stale. (Single-line planes observe more: not with them.)
    let unobserved_share = mean(runs.iter().map(|r| r.unobserved_share));
    assert!(
        single != PAIRS_ONLY || unobserved_share >= 0.8,
        "{}: {unobserved_share}",
        scenario.name
    );
}

/// Which single lines make planes besides the pairs.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SingleLines {
    level: bool,
    walls: bool,
}

const PAIRS_ONLY: SingleLines = SingleLines {
    level: false,
    walls: false,
};
const LEVEL: SingleLines = SingleLines {
    level: true,
    walls: false,
};
const LEVEL_AND_WALLS: SingleLines = SingleLines {
    level: true,
    walls: true,
};

fn study_scene(name: &str, single: SingleLines) {
    for rig in [Rig::Paper, Rig::Rolled] {
        for rate in [1.0, 10.0] {
            study(name, rig, rate, single);
        }
    }
}

#[test]
#[ignore]
fn baseline_open_room() {
    study_scene("open-room", PAIRS_ONLY);
}

/// The same with `odometry.level_lines` alone (docs/accuracy.md, "Level lines").
#[test]
#[ignore]
fn level_lines_open_room() {
    study_scene("open-room", LEVEL);
}

#[test]
#[ignore]
fn baseline_hall_walk() {
    study_scene("hall-walk", PAIRS_ONLY);
}

/// The same with `odometry.level_lines` alone (docs/accuracy.md, "Level lines").
#[test]
#[ignore]
fn level_lines_hall_walk() {
    study_scene("hall-walk", LEVEL);
}

#[test]
#[ignore]
fn baseline_bare_corridor() {
    study_scene("bare-corridor", PAIRS_ONLY);
}

/// The same with `odometry.level_lines` alone (docs/accuracy.md, "Level lines").
#[test]
#[ignore]
fn level_lines_bare_corridor() {
    study_scene("bare-corridor", LEVEL);
}

/// The same with `odometry.level_lines` and `odometry.wall_lines` (docs/accuracy.md, "Wall
/// lines").
#[test]
#[ignore]
fn building_lines_open_room() {
    study_scene("open-room", LEVEL_AND_WALLS);
}

/// The same with `odometry.level_lines` and `odometry.wall_lines` (docs/accuracy.md, "Wall
/// lines").
#[test]
#[ignore]
fn building_lines_hall_walk() {
    study_scene("hall-walk", LEVEL_AND_WALLS);
}

/// The same with `odometry.level_lines` and `odometry.wall_lines` (docs/accuracy.md, "Wall
/// lines").
#[test]
#[ignore]
fn building_lines_bare_corridor() {
    study_scene("bare-corridor", LEVEL_AND_WALLS);
}

/// The fusion on the plane map.
fn map_settings(epoch_rate_hz: f64) -> FusionSettings {
    let mut settings = settings(epoch_rate_hz);
    settings.odometry.method = OdometryMethod::Map;
    settings
}

/// Mean squared velocity error over its variance, per axis (1 if honest): the velocity block of
/// the 9-dof NEES, which is 3 when honest.
fn velocity_nees_per_axis(report: &AccuracyReport) -> f64 {
    report.nees_block_means[1] / 3.0
}

/// The first minute of the open room and of the hall walk on the plane map, with the paper's
/// rig: the velocity to millimetres a second, honest, and no drift.
#[test]
fn the_plane_map_measures_the_open_room_and_the_hall_walk() {
    for name in ["open-room", "hall-walk"] {
        let mut scenario = scenario(name, Rig::Paper, 1.0);
        scenario.duration_s = 60.0;
        let run = measure(&scenario, &map_settings(1.0));
        println!("{name}: {}", serde_json::to_string(&run).unwrap());
        let velocity = run.accuracy.velocity_error_std_ned;
        assert!(velocity.iter().all(|&v| v < 0.01), "{name}: {velocity:?}");
        let nees = velocity_nees_per_axis(&run.accuracy);
        assert!(nees < 1.5, "{name}: velocity NEES {nees} per axis");
        assert!(
            run.accuracy.horizontal_error_end_m < 0.05,
            "{name}: {run:?}"
        );
    }
}

/// The hall walk's first minute on the map at 1 Hz, with the paper's rig: the end wall, a wall
/// from one line, is the only surface facing along the hall until the walk brings a second
/// into view. The pairs observe the hall's length with it; had they handed over then, the map,
/// which lets no such wall face a direction alone (`Standing::Corroborated`), would leave that
/// length unfaced for twenty seconds: 46 % of the epochs, 12 % with the hand-over waiting
/// until the map keeps what the pairs observe.
#[test]
fn the_map_takes_over_only_what_its_surfaces_can_face() {
    let mut scenario = scenario("hall-walk", Rig::Paper, 1.0);
    scenario.duration_s = 60.0;
    let run = measure(&scenario, &map_settings(1.0));
    assert!(run.unobserved_share < 0.25, "{}", run.unobserved_share);
    let nees = velocity_nees_per_axis(&run.accuracy);
    assert!(nees < 1.5, "velocity NEES {nees} per axis");
}

/// The bare corridor on the map at 1 Hz, with the paper's rig: only the cabinet's faces face
/// along it, surfaces the prediction cannot check once the walk has left the velocity along
/// the corridor vague. Left out, they left the corridor's length unfaced in every epoch, and
/// the velocity along it 0.27 m/s off (standard deviation); fused on their own word and held
/// in doubt until later epochs check them, they measure the walk while in view: 74 % of the
/// epochs unfaced, 0.055 m/s.
#[test]
fn the_cabinet_alone_measures_the_walk_along_the_bare_corridor() {
    let scenario = scenario("bare-corridor", Rig::Paper, 1.0);
    let run = measure(&scenario, &map_settings(1.0));
    assert!(run.unobserved_share < 0.85, "{}", run.unobserved_share);
    let along = run.accuracy.velocity_error_std_ned[0];
    assert!(
        along < 0.12,
        "velocity error along the corridor {along} m/s"
    );
    let nees = velocity_nees_per_axis(&run.accuracy);
    assert!(nees < 1.5, "velocity NEES {nees} per axis");
}

/// The rolled rig in the bare corridor lays a level line on the ceiling that `wall_lines`
/// takes for a plumb wall across the corridor: a plane that moves with the body. While the
/// platform stood still it fitted, and as it walked off it told the filter that it stood still
/// along the corridor, 0.1 m/s off with a sigma of 3 mm/s (velocity NEES 138 per axis over the
/// first minute). A wall from one line now faces a direction alone only once it has been seen
/// up its height or from places apart along its normal (`Standing::Corroborated`).
#[test]
fn a_ceiling_line_taken_for_a_wall_never_holds_the_corridor_still() {
    let mut scenario = scenario("bare-corridor", Rig::Rolled, 10.0);
    scenario.duration_s = 60.0;
    let run = measure(&scenario, &map_settings(10.0));
    let nees = velocity_nees_per_axis(&run.accuracy);
    assert!(nees < 1.5, "velocity NEES {nees} per axis: {run:?}");
}

/// Along a bare corridor nothing faces the walk for minutes at a time, and the body's place
/// along it is given to the map's origin, so that the lines are linearised where the map
/// believes the body is (docs/design.md 4.11, "The body's place along an unfaced direction").
/// The origin keeps that place's error and its correlation with the velocity, so when the end
/// wall comes into view and measures the velocity, the place is corrected with it. Handed over
/// as a variance alone, it never was: this run ended 44 m off (sigma 36 m).
#[test]
fn the_walk_measured_again_corrects_the_place_along_the_bare_corridor() {
    let settings = map_settings(1.0);
    let scenario = study_run("bare-corridor", Rig::Paper, 1.0, 201, &settings);
    let trajectory = scenario.trajectory.clone();
    let mut last = None;
    run_scenario_with(&scenario, &settings, &mut |_, estimate| {
        last = Some((
            estimate.t,
            estimate.position.x,
            estimate.position_covariance[(0, 0)],
        ));
    })
    .unwrap();
    let (t, along, variance) = last.unwrap();
    let error = along - trajectory.kinematics(t).p.x;
    let sigma = variance.sqrt();
    assert!(
        error.abs() < 5.0 && error.abs() < 3.0 * sigma,
        "{error} m off along the corridor at a sigma of {sigma} m"
    );
}

/// Seeds of the map's Monte Carlo study.
const STUDY_SEEDS: std::ops::Range<u64> = 200..220;

/// `name` with `rig` at `epoch_rate_hz` on `seed`'s noise, with an IMU whose turn-on biases
/// and scale factors are drawn from the priors of `settings`' filter.
fn study_run(
    name: &str,
    rig: Rig,
    epoch_rate_hz: f64,
    seed: u64,
    settings: &FusionSettings,
) -> Scenario {
    let spread = ImuSpread {
        gyro_bias: settings.filter.initial_sigma_gyro_bias,
        accel_bias: settings.filter.initial_sigma_accel_bias,
        gyro_scale_factor: settings.filter.initial_sigma_gyro_scale,
        accel_scale_factor: settings.filter.initial_sigma_accel_scale,
    };
    let mut seeded = scenario(name, rig, epoch_rate_hz);
    seeded.seed = seed;
    seeded.imu = seeded.imu.map(|imu| imu.with_drawn_errors(&spread, seed));
    seeded
}

/// One row of the map's study: 20 runs of one scene with one rig at one epoch rate, each with
/// its own noise and an IMU drawn from the filter's priors, by `method`.
fn map_study(name: &str, rig: Rig, epoch_rate_hz: f64, method: OdometryMethod) {
    let mut settings = map_settings(epoch_rate_hz);
    settings.odometry.method = method;
    let runs: Vec<Baseline> = STUDY_SEEDS
        .map(|seed| {
            measure(
                &study_run(name, rig, epoch_rate_hz, seed, &settings),
                &settings,
            )
        })
        .collect();
    let velocity = mean_axes(&runs, |r| r.velocity_error_std_ned);
    let attitude = mean_axes(&runs, |r| r.attitude_error_std_mrad);
    let mut drift: Vec<f64> = runs
        .iter()
        .map(|r| 100.0 * r.accuracy.horizontal_error_end_m / (r.accuracy.to_s - r.accuracy.from_s))
        .collect();
    drift.sort_by(f64::total_cmp);
    let nees = mean(runs.iter().map(|r| r.accuracy.nees_mean));
    let interval = runs[0].accuracy.nees_interval;
    println!(
        "| {name} | {rig:?} | {epoch_rate_hz} Hz | {method:?} | {:.1} % | {} | {} | {:.2} ({:.2}) | {:.2} [{:.1}, {:.1}] | {:.2} |",
        100.0 * mean(runs.iter().map(|r| r.unobserved_share)),
        axes(velocity, 4),
        axes(attitude, 2),
        drift[drift.len() / 2],
        drift[drift.len() - 1],
        nees,
        interval[0],
        interval[1],
        mean(runs.iter().map(|r| velocity_nees_per_axis(&r.accuracy))),
    );
}

/// The map against the pairs on every scene, rig and rate, 20 runs each (docs/accuracy.md,
/// "The plane map").
#[test]
#[ignore]
fn study_plane_map_20_runs() {
    println!("| scene | rig | rate | method | epochs with an axis unobserved | velocity error std N, E, D (m/s) | attitude std (mrad) | drift per 100 s, median (worst), m | 9-dof NEES [95 % interval of one run] | velocity NEES per axis |");
    for name in ["open-room", "hall-walk", "bare-corridor"] {
        for rig in [Rig::Paper, Rig::Rolled] {
            for rate in [1.0, 10.0] {
                for method in [OdometryMethod::Pairs, OdometryMethod::Map] {
                    map_study(name, rig, rate, method);
                }
            }
        }
    }
}

/// Resident memory of this process, bytes (Linux).
fn resident_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4096)
}

/// An hour of the hall walk on the plane map at 10 Hz, lap after lap round its pillars: the
/// map forgets what it leaves behind (`max_surfaces`, `forget_after_s`), so memory stays flat.
/// The fusion is driven alone (the evaluation's error series would grow with the hour);
/// resident memory is sampled every simulated minute, and from the tenth minute on it may not
/// grow by more than 1 MB (`cargo test --release -p ladar-lab --test plane_map_scenes --
/// --ignored --nocapture memory`).
#[test]
#[ignore]
fn study_plane_map_memory_over_an_hour() {
    let mut scenario = scenario("hall-walk", Rig::Paper, 10.0);
    if let Trajectory::Waypoints { waypoints_m, .. } = &mut scenario.trajectory {
        let lap = waypoints_m.clone();
        for _ in 0..40 {
            waypoints_m.extend(lap.iter().copied());
        }
    }
    scenario.duration_s = 3600.0;
    let mut simulator = Simulator::new(&scenario).unwrap();
    let mut settings = map_settings(10.0);
    settings.filter.imu_mount_rpy_deg = simulator.imu().unwrap().mount_rpy_deg;
    let mut fusion = Fusion::new(settings, simulator.scanner_setups().unwrap()).unwrap();
    let mut samples: Vec<(f64, u64, usize)> = Vec::new();
    while let Some(event) = simulator.next_event() {
        match event {
            SimEvent::Imu(sample) => {
                fusion.push_imu(sample);
            }
            SimEvent::Scan { scan, t } => {
                fusion.push_scan(scan);
                if t >= samples.last().map_or(60.0, |(at, ..)| at + 60.0) {
                    let bytes = resident_bytes().unwrap_or(0);
                    samples.push((t, bytes, fusion.mapped_surfaces()));
                }
            }
            SimEvent::Truth(_) => {}
        }
    }
    for (t, bytes, held) in &samples {
        println!(
            "{t:.0} s: {:.2} MB resident, {held} surfaces",
            *bytes as f64 / 1e6
        );
    }
    let settled: Vec<u64> = samples.iter().skip(9).map(|(_, bytes, _)| *bytes).collect();
    let growth = settled.last().unwrap() - settled.iter().min().unwrap();
    assert!(samples.len() >= 55, "{} minutes", samples.len());
    assert!(
        growth <= 1_000_000,
        "grew by {growth} bytes after the tenth minute"
    );
}
