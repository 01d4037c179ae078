use super::*;
use crate::odometry::OdometryMethod;
use crate::sensors::{Mount, ScannerGeometry};
use ladar_sim::{Scenario, SimEvent, Simulator};
use nalgebra::Vector3;

fn setups() -> [ScannerSetup; 2] {
    [0.0, -30.0].map(|pitch| ScannerSetup {
        geometry: ScannerGeometry::UTM_30LX,
        mount: Mount::from_rpy_deg([0.0, pitch, 0.0], [0.0; 3]),
        range_sigma_m: Some(0.01),
    })
}

fn blank_scan(sensor: usize, t0: f64) -> Scan {
    Scan {
        sensor,
        t0,
        first_step: 0,
        cluster: 1,
        ranges_m: vec![f64::NAN; 1081],
    }
}

fn fusion_at(rate_hz: f64) -> Fusion {
    let mut settings = FusionSettings::default();
    settings.fusion.epoch_rate_hz = rate_hz;
    Fusion::new(settings, setups()).unwrap()
}

/// The first seconds of hallway-hover, stationary: enough to align and run a few epochs.
fn short_hover(seconds: f64) -> (Scenario, FusionSettings) {
    let mut scenario = Scenario::builtin("hallway-hover").unwrap();
    scenario.duration_s = seconds;
    let mut settings = FusionSettings::default();
    settings.odometry.accept_parallel_lines = true;
    (scenario, settings)
}

#[test]
fn defaults_validate_and_bad_keys_name_themselves() {
    assert!(FusionSettings::default().validate().is_ok());
    let mut settings = FusionSettings::default();
    settings.fusion.epoch_rate_hz = 0.0;
    let error = Fusion::new(settings, setups()).err().unwrap().to_string();
    assert!(error.contains("fusion.epoch_rate_hz"), "{error}");
    let mut settings = FusionSettings::default();
    settings.fusion.epoch_rate_hz = 0.25;
    let error = settings.validate().unwrap_err().to_string();
    assert!(error.contains("filter.pose_history_s"), "{error}");
    assert!(!error.contains('\n'));
    let mut settings = FusionSettings::default();
    settings.fusion.plane_confirmation_s = -1.0;
    let error = settings.validate().unwrap_err().to_string();
    assert!(error.contains("fusion.plane_confirmation_s"), "{error}");
    settings.fusion.plane_confirmation_s = 1.9;
    let error = settings.validate().unwrap_err().to_string();
    assert!(
        error.contains("fusion.plane_confirmation_s = 1.9"),
        "{error}"
    );
}

#[test]
fn settings_parse_from_toml_and_refuse_unknown_keys() {
    let settings: FusionSettings =
        toml::from_str("[fusion]\nepoch_rate_hz = 10.0\nexclusion = false\n").unwrap();
    assert_eq!(settings.fusion.epoch_rate_hz, 10.0);
    assert!(!settings.fusion.exclusion);
    assert!(toml::from_str::<FusionSettings>("[fusion]\nepoch_rate = 1.0\n").is_err());
}

#[test]
fn the_plane_map_is_chosen_by_name_and_its_bad_keys_name_themselves() {
    let text = "[odometry]\nmethod = \"map\"\n[odometry.map]\nmax_surfaces = 40\n";
    let settings: FusionSettings = toml::from_str(text).unwrap();
    assert_eq!(settings.odometry.method, OdometryMethod::Map);
    assert_eq!(settings.odometry.map.max_surfaces, 40);
    assert!(settings.validate().is_ok());
    let unknown = "[odometry.map]\nmax_planes = 40\n";
    let error = toml::from_str::<FusionSettings>(unknown)
        .unwrap_err()
        .to_string();
    assert!(error.contains("max_planes"), "{error}");
    assert!(toml::from_str::<FusionSettings>("[odometry]\nmethod = \"icp\"\n").is_err());
    let mut settings = FusionSettings::default();
    settings.odometry.map.max_surfaces = 0;
    settings.odometry.map.roughness_m = f64::NAN;
    let error = settings.validate().unwrap_err().to_string();
    assert!(error.contains("odometry.map.max_surfaces"), "{error}");
    assert!(error.contains("odometry.map.roughness_m"), "{error}");
}

#[test]
fn scans_before_any_imu_make_a_reference_epoch_without_panicking() {
    let mut fusion = fusion_at(1.0);
    assert!(fusion.push_scan(blank_scan(0, 0.0)).is_none());
    let record = fusion.push_scan(blank_scan(1, 0.01)).unwrap();
    assert_eq!(record.outcome, EpochOutcome::Reference);
    assert_eq!(record.planes, 0);
    assert_eq!(record.dropped[0].not_a_number, 1081);
    assert!(fusion.estimate().degraded);
}

#[test]
fn pairs_need_both_scanners_within_the_skew_and_follow_the_epoch_rate() {
    let mut fusion = fusion_at(1.0);
    assert!(fusion.push_scan(blank_scan(0, 0.0)).is_none());
    // Too far from scanner 0's scan: dropped, and the older scan with it.
    assert!(fusion.push_scan(blank_scan(1, 0.2)).is_none());
    assert_eq!(fusion.counters().skewed_pairs, 1);
    assert!(fusion.push_scan(blank_scan(0, 0.21)).is_some());
    // 4 Hz pairs at 1 Hz epochs: the next three pairs are skipped.
    let epochs: Vec<bool> = (1..=8)
        .map(|k| {
            let t = 0.21 + 0.25 * f64::from(k);
            fusion.push_scan(blank_scan(1, t + 0.012));
            fusion.push_scan(blank_scan(0, t)).is_some()
        })
        .collect();
    assert_eq!(
        epochs,
        [false, false, false, true, false, false, false, true]
    );
    assert!(fusion.push_scan(blank_scan(2, 3.0)).is_none());
    assert_eq!(fusion.counters().unknown_scanner, 1);
}

#[test]
fn an_epoch_rate_equal_to_the_scan_rate_takes_every_pair() {
    let mut fusion = fusion_at(4.0);
    let taken = (0..6)
        .filter(|&k| {
            let t = 0.25 * f64::from(k);
            fusion.push_scan(blank_scan(0, t));
            fusion.push_scan(blank_scan(1, t + 0.012)).is_some()
        })
        .count();
    assert_eq!(taken, 6);
}

#[test]
fn set_scanner_checks_the_index() {
    let mut fusion = fusion_at(1.0);
    assert!(fusion.set_scanner(1, setups()[0]).is_ok());
    let error = fusion.set_scanner(2, setups()[0]).unwrap_err();
    assert_eq!(error, FusionError::NoSuchScanner(2));
}

/// Drives a short simulated run; returns the estimates, the records and the fusion.
fn drive(
    scenario: &Scenario,
    settings: &FusionSettings,
    mut before_scan: impl FnMut(&mut Fusion, &Scan),
) -> (Vec<Estimate>, Vec<EpochRecord>, Fusion) {
    let mut simulator = Simulator::new(scenario).unwrap();
    let mut fusion = Fusion::new(settings.clone(), simulator.scanner_setups().unwrap()).unwrap();
    let (mut estimates, mut records) = (Vec::new(), Vec::new());
    for event in simulator.events() {
        match event {
            SimEvent::Imu(sample) => estimates.extend(fusion.push_imu(sample)),
            SimEvent::Scan { scan, .. } => {
                before_scan(&mut fusion, &scan);
                records.extend(fusion.push_scan(scan));
            }
            SimEvent::Truth(_) => {}
        }
    }
    (estimates, records, fusion)
}

#[test]
fn the_same_inputs_give_identical_estimates_bit_for_bit() {
    let (scenario, mut settings) = short_hover(4.0);
    settings.fusion.estimate_decimation = 8;
    let (first, first_records, _) = drive(&scenario, &settings, |_, _| {});
    let (second, second_records, _) = drive(&scenario, &settings, |_, _| {});
    assert!(first.len() > 100);
    assert!(first_records
        .iter()
        .any(|r| r.outcome == EpochOutcome::Fused));
    let bits = |estimates: &[Estimate]| -> Vec<u64> {
        estimates
            .iter()
            .flat_map(|e| {
                e.position
                    .iter()
                    .chain(e.velocity.iter())
                    .chain(e.attitude.coords.iter())
                    .chain(e.position_covariance.iter())
                    .map(|x| x.to_bits())
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    assert_eq!(bits(&first), bits(&second));
    assert_eq!(first_records, second_records);
}

#[test]
fn a_stale_scanner_degrades_the_estimates_until_it_recovers() {
    let (scenario, settings) = short_hover(3.0);
    let (_, records, mut fusion) = drive(&scenario, &settings, |_, _| {});
    assert!(records.iter().any(|r| r.status.is_some()));
    assert!(!fusion.estimate().degraded);
    fusion.mark_stale(Sensor::Scanner(1), true);
    assert!(fusion.estimate().degraded);
    fusion.mark_stale(Sensor::Scanner(1), false);
    fusion.mark_stale(Sensor::Imu, true);
    assert!(fusion.estimate().degraded);
    fusion.mark_stale(Sensor::Imu, false);
    assert!(!fusion.estimate().degraded);
}

#[test]
fn a_silent_scanner_degrades_the_estimates() {
    let (scenario, mut settings) = short_hover(4.0);
    settings.fusion.scan_stale_s = 0.5;
    let mut simulator = Simulator::new(&scenario).unwrap();
    let mut fusion = Fusion::new(settings, simulator.scanner_setups().unwrap()).unwrap();
    let mut estimates = Vec::new();
    for event in simulator.events() {
        match event {
            SimEvent::Imu(sample) => estimates.extend(fusion.push_imu(sample)),
            // Scanner 1 goes quiet after 2 s.
            SimEvent::Scan { scan, .. } if scan.sensor == 0 || scan.t0 < 2.0 => {
                fusion.push_scan(scan);
            }
            _ => {}
        }
    }
    let degraded = |from: f64, to: f64| {
        estimates
            .iter()
            .filter(|e| e.t > from && e.t < to)
            .map(|e| e.degraded)
            .collect::<Vec<_>>()
    };
    assert!(degraded(1.5, 2.0).iter().all(|&d| !d));
    let late = degraded(2.7, 4.0);
    assert!(!late.is_empty() && late.iter().all(|&d| d));
}

#[test]
fn too_few_planes_fuse_nothing_and_say_why() {
    let (scenario, settings) = short_hover(4.0);
    // Blank out most of both scans: at most the walls beside the scanner remain.
    let mut simulator = Simulator::new(&scenario).unwrap();
    let mut fusion = Fusion::new(settings, simulator.scanner_setups().unwrap()).unwrap();
    let mut records = Vec::new();
    for event in simulator.events() {
        match event {
            SimEvent::Imu(sample) => {
                fusion.push_imu(sample);
            }
            SimEvent::Scan { mut scan, .. } => {
                for range in scan.ranges_m.iter_mut().skip(200) {
                    *range = f64::NAN;
                }
                records.extend(fusion.push_scan(scan));
            }
            SimEvent::Truth(_) => {}
        }
    }
    let solved: Vec<_> = records.iter().filter(|r| r.status.is_some()).collect();
    assert!(!solved.is_empty());
    for record in solved {
        assert_eq!(record.status, Some(IntegrityStatus::UnderDetermined));
        assert!(matches!(
            record.outcome,
            EpochOutcome::NotFused | EpochOutcome::Fused
        ));
        assert!(record.displacement.is_none() || record.rotation.is_none());
    }
}

/// A scan pair can be complete before the IMU sample that covers its reference time has been
/// read (a late IMU read, a sensor clock fit slightly ahead): the prior then extrapolates the
/// newest pose for those milliseconds instead of restarting the chain with a reference epoch.
#[test]
fn pairs_complete_before_the_imu_reaches_them_are_still_fused() {
    let (scenario, settings) = short_hover(6.0);
    let late_s = 0.03;
    let mut simulator = Simulator::new(&scenario).unwrap();
    let mut fusion = Fusion::new(settings, simulator.scanner_setups().unwrap()).unwrap();
    let mut held: std::collections::VecDeque<ImuSample> = Default::default();
    let (mut outcomes, mut ahead_of_imu) = (Vec::new(), 0);
    for event in simulator.events() {
        match event {
            SimEvent::Imu(sample) => held.push_back(sample),
            SimEvent::Scan { scan, .. } => {
                let last_beam = scan.time_of(scan.ranges_m.len() - 1, &setups()[0].geometry);
                while held.front().is_some_and(|s| s.time() <= last_beam - late_s) {
                    fusion.push_imu(held.pop_front().unwrap());
                }
                let newest_imu = fusion.filter().time();
                if let Some(record) = fusion.push_scan(scan) {
                    ahead_of_imu += usize::from(newest_imu.is_none_or(|t| t < record.t));
                    outcomes.push(record.outcome);
                }
            }
            SimEvent::Truth(_) => {}
        }
    }
    assert_eq!(
        ahead_of_imu,
        outcomes.len(),
        "every pair must be ahead of the IMU"
    );
    // The first epochs are references while the filter aligns; once one fuses, all do.
    let first_fused = outcomes.iter().position(|o| *o == EpochOutcome::Fused);
    let after = &outcomes[first_fused.unwrap_or(outcomes.len())..];
    assert!(after.len() >= 3, "{outcomes:?}");
    assert!(
        after.iter().all(|o| *o == EpochOutcome::Fused),
        "{outcomes:?}"
    );
}

/// Above 1 Hz a plane is used only once a plane of the epoch a baseline back agrees with it:
/// in a still scene, none in the first second after alignment (the filter has no pose that old
/// yet), nearly all after it. At 1 Hz the previous epoch is that far back already, and no plane
/// waits.
#[test]
fn planes_wait_for_confirmation_a_baseline_back_above_one_hertz() {
    let (mut scenario, mut settings) = short_hover(4.0);
    for scanner in &mut scenario.scanners {
        scanner.skip = 3;
    }
    settings.fusion.epoch_rate_hz = 10.0;
    let (_, records, _) = drive(&scenario, &settings, |_, _| {});
    let solvable = |r: &&EpochRecord| r.t_previous.is_some() || r.unconfirmed_planes > 0;
    let first = records
        .iter()
        .find(solvable)
        .expect("an epoch after alignment")
        .t;
    // The filter's first pose is an epoch before the first solved one.
    let early: Vec<_> = records
        .iter()
        .filter(|r| r.t >= first && r.t - first < 0.85)
        .collect();
    assert!(
        early.len() >= 5,
        "{} epochs in the first second",
        early.len()
    );
    for record in &early {
        assert!(record.planes >= 4, "at {}", record.t);
        assert_eq!(record.unconfirmed_planes, record.planes, "at {}", record.t);
        assert_eq!((record.matched, record.used), (0, 0), "at {}", record.t);
    }
    let later: Vec<_> = records.iter().filter(|r| r.t - first >= 1.05).collect();
    let planes: usize = later.iter().map(|r| r.planes).sum();
    let unconfirmed: usize = later.iter().map(|r| r.unconfirmed_planes).sum();
    assert!(later.len() >= 15, "{} epochs", later.len());
    assert!(
        unconfirmed * 20 < planes,
        "{unconfirmed} unconfirmed, {planes} planes"
    );
    assert!(later.iter().all(|r| r.used >= 4), "{later:?}");

    settings.fusion.epoch_rate_hz = 1.0;
    let (_, records, _) = drive(&short_hover(4.0).0, &settings, |_, _| {});
    assert!(records.iter().any(|r| r.used > 0));
    assert!(records.iter().all(|r| r.unconfirmed_planes == 0));
}

/// The fusion with the defaults on `name` (seed `seed`) from `start_s` for `seconds`, as the
/// daemon would run if started then: the records of its epochs.
fn run_from(
    name: &str,
    seed: u64,
    start_s: f64,
    seconds: f64,
) -> (Scenario, Fusion, Vec<EpochRecord>) {
    run_at_rate(name, seed, start_s, seconds, 1.0)
}

/// As `run_from`, with epochs at `epoch_rate_hz`; above 4 Hz the scanners send 10 scans a
/// second, as the lab's 10 Hz rows have them.
fn run_at_rate(
    name: &str,
    seed: u64,
    start_s: f64,
    seconds: f64,
    epoch_rate_hz: f64,
) -> (Scenario, Fusion, Vec<EpochRecord>) {
    run_judging(name, seed, start_s, seconds, epoch_rate_hz, |_, _, _| {})
}

/// As `run_at_rate`, handing `after_epoch` the fusion and its record after each epoch.
fn run_judging(
    name: &str,
    seed: u64,
    start_s: f64,
    seconds: f64,
    epoch_rate_hz: f64,
    mut after_epoch: impl FnMut(&Scenario, &Fusion, &EpochRecord),
) -> (Scenario, Fusion, Vec<EpochRecord>) {
    let mut scenario = Scenario::builtin(name).unwrap();
    scenario.duration_s = start_s + seconds;
    if epoch_rate_hz > 4.0 {
        for scanner in &mut scenario.scanners {
            scanner.skip = 3;
        }
    }
    let mut simulator = Simulator::with_seed(&scenario, seed).unwrap();
    // These regressions are the paper's odometer's; the map has its own.
    let mut settings = FusionSettings::default();
    settings.odometry.method = OdometryMethod::Pairs;
    settings.filter.imu_mount_rpy_deg = simulator.imu().unwrap().mount_rpy_deg;
    settings.fusion.epoch_rate_hz = epoch_rate_hz;
    let mut fusion = Fusion::new(settings, simulator.scanner_setups().unwrap()).unwrap();
    let mut records = Vec::new();
    while let Some(event) = simulator.next_event() {
        match event {
            SimEvent::Imu(sample) if sample.time() >= start_s => {
                fusion.push_imu(sample);
            }
            SimEvent::Scan { scan, .. } if scan.t0 >= start_s => {
                if let Some(record) = fusion.push_scan(scan) {
                    after_epoch(&scenario, &fusion, &record);
                    records.push(record);
                }
            }
            _ => {}
        }
    }
    (scenario, fusion, records)
}

/// Started 20.4 s into hallway-flight, in motion: the accelerometer's mean gives the tilt to
/// degrees (here 29 mrad off in pitch, and gravity would leak 0.3 m/s^2 into the velocity along
/// the hallway, which nothing observes). The floor, level in a
/// building, gives it back within the first epochs, to a few milliradians and honestly.
#[test]
fn a_start_in_motion_takes_its_tilt_from_the_floor() {
    let (scenario, fusion, records) = run_from("hallway-flight", 101, 20.4, 4.0);
    let level_surfaces: Vec<_> = records.iter().flat_map(|r| &r.level_surfaces).collect();
    assert!(
        level_surfaces.iter().any(|u| u.accepted && u.dof == 2),
        "{level_surfaces:?}"
    );
    let filter = fusion.filter();
    let truth = scenario.trajectory.kinematics(filter.time().unwrap());
    let error = (truth.q * filter.state().q.inverse()).scaled_axis();
    let tilt_error = error.xy().norm();
    assert!(tilt_error < 0.005, "tilt error {tilt_error} rad");
    assert!(
        tilt_error < 3.0 * filter.tilt_sigma() * std::f64::consts::SQRT_2,
        "tilt error {tilt_error} rad, sigma {}",
        filter.tilt_sigma()
    );
}

/// In `random-room-6` (the paper's rig, a box beside the start) a 0.67 m line on a box face and
/// a wall line 6 m away met on the line the scan planes share within their noise, 30 m from the
/// box line: as a crossing pair they made a plane 7.5 deg off level, which the still start's
/// loose tilt prior let in as a floor; fused, it tipped the vertical by 130 mrad and the
/// velocity ran to 4 m/s in 6 s with sigmas of 0.1-0.3 m/s. Such a pair no longer counts as
/// crossing (`planes::MAX_MEETING_SIGMA_M`).
#[test]
fn a_still_start_beside_a_box_keeps_its_vertical() {
    let (scenario, fusion, _) = run_from("random-room-6", 6, 0.0, 9.0);
    assert_velocity_honest(&scenario, &fusion, 0.01);
}

/// Started 27.1 s into random room 75 (the rolled rig, hovering beside a box near a wall): the
/// level scanner's wall line and the rolled scanner's line on the box's face meet where the
/// face meets the wall, so they made a plane 33 deg off level in every epoch. Its small turns
/// as the platform bobbed taught the start a gyro bias 15 sigmas off, and 20 s in the velocity
/// was 4.5 m/s wrong with a sigma of 0.35 m/s. In a building such a plane is refused.
#[test]
fn a_start_in_motion_beside_a_box_takes_no_plane_from_a_wall_and_the_box() {
    let (scenario, fusion, records) = run_from("random-room-75", 75, 27.1, 20.0);
    let vertical = |t: f64| {
        let truth = scenario.trajectory.kinematics(t);
        truth.q.inverse_transform_vector(&Vector3::z())
    };
    let sloping = records
        .iter()
        .flat_map(|r| r.plane_geometry.iter().map(move |p| (r.t, p)))
        .filter(|(t, p)| {
            let elevation = Vector3::from(p.normal).dot(&vertical(*t)).abs().asin();
            (0.1..1.47).contains(&elevation)
        })
        .count();
    assert_eq!(sloping, 0, "planes 6-84 deg off level");
    assert_velocity_honest(&scenario, &fusion, 0.05);
}

/// Started 20.7 s into random room 13 (paper's rig) under a prior of decimetres: the one box
/// top of the first epoch was paired with another box top 8 cm above the one it saw again, and
/// the filter learnt a vertical motion that was not there; 25 s later it sent a vertical
/// velocity 1 m/s off with a sigma of 1 cm/s. A match the prior cannot settle is left out.
#[test]
fn a_start_in_motion_does_not_swap_two_box_tops() {
    let (scenario, fusion, _) = run_from("random-room-13", 13, 20.7, 25.0);
    assert_velocity_honest(&scenario, &fusion, 0.05);
}

/// The fusion's last velocity is within `max_error_mps` of the truth and inside 3 of its sigmas
/// on each body axis.
fn assert_velocity_honest(scenario: &Scenario, fusion: &Fusion, max_error_mps: f64) {
    let (error, sigma) = velocity_error_and_sigma(scenario, fusion);
    assert!(error.norm() < max_error_mps, "velocity error {error:?} m/s");
    assert!(
        (0..3).all(|k| error[k].abs() <= 3.0 * sigma[k]),
        "error {error:?}, sigma {sigma:?}"
    );
}

/// Started 32.4 s into random room 35 (the rolled rig, walking along the room): the far wall
/// was the only plane along the room, and once the velocity had drifted (the floor unseen, the
/// tilt a little off) the filter's prediction contradicted it, so it was left out, and the
/// estimate stayed converged while its velocity along the room ran to 3.6 m/s off with a sigma
/// of 0.3 m/s. A surface that contradicts the filter leaves that direction in doubt: the
/// estimate is not to be used until a later epoch agrees. (Started 32.6 s in, as this test was
/// until the deskew's disagreement widened the planes, the wall is no longer contradicted.)
#[test]
fn a_wall_that_contradicts_the_filter_leaves_the_estimate_unusable() {
    let (scenario, fusion, records) = run_from("random-room-35", 35, 32.4, 15.0);
    let contradicted = records
        .iter()
        .flat_map(|r| &r.lone_directions)
        .any(|lone| lone.check == witnesses::Check::Contradicted);
    assert!(contradicted);
    assert_honest_or_unusable(&scenario, &fusion);
}

/// Started 30.8 s into random room 35 (the rolled rig, in motion): a table top at one epoch
/// and the floor at the next were matched, a lone direction fused unchecked and held. Four
/// epochs later the floor and the ceiling measured the vertical rightly, with a NIS of 11.8 on
/// 3 degrees of freedom, and released it; but the update had split its surprise between the
/// velocity and the accelerometer's bias and scale, and the estimate ended converged with a
/// vertical velocity 1.3 m/s off at a sigma of 2 cm/s. A surprised update releases nothing.
#[test]
fn a_surprised_update_does_not_release_a_direction_fused_unchecked() {
    let (scenario, fusion, _) = run_from("random-room-35", 35, 30.8, 15.0);
    assert_honest_or_unusable(&scenario, &fusion);
}

/// An estimate the autopilot may use has its velocity within three of its sigmas.
fn assert_honest_or_unusable(scenario: &Scenario, fusion: &Fusion) {
    let (error, sigma) = velocity_error_and_sigma(scenario, fusion);
    let honest = (0..3).all(|k| error[k].abs() <= 3.0 * sigma[k]);
    assert!(
        !fusion.estimate().converged || honest,
        "converged with error {error:?}, sigma {sigma:?}"
    );
}

/// Asserts that no epoch of a run as `run_at_rate` left the estimate usable (converged, every
/// velocity sigma within the autopilot profile's 0.5 m/s) with its velocity more than three
/// sigmas off on some axis; the failure lists those epochs (time, largest error).
fn assert_never_usable_and_wrong(
    name: &str,
    seed: u64,
    start_s: f64,
    seconds: f64,
    epoch_rate_hz: f64,
) {
    let mut wrong = Vec::new();
    run_judging(
        name,
        seed,
        start_s,
        seconds,
        epoch_rate_hz,
        |scenario, fusion, record| {
            let (error, sigma) = velocity_error_and_sigma(scenario, fusion);
            let usable = fusion.estimate().converged && sigma.max() <= 0.5;
            if usable && (0..3).any(|k| error[k].abs() > 3.0 * sigma[k]) {
                wrong.push((record.t, error.amax()));
            }
        },
    );
    assert!(wrong.is_empty(), "{name}: {wrong:?}");
}

/// The body-frame error of the fusion's last velocity against the truth, and its sigmas.
fn velocity_error_and_sigma(scenario: &Scenario, fusion: &Fusion) -> (Vector3<f64>, Vector3<f64>) {
    let estimate = fusion.estimate();
    let truth = scenario.trajectory.kinematics(estimate.t);
    let error = estimate.body_velocity() - truth.q.inverse_transform_vector(&truth.v);
    let sigma = estimate
        .body_velocity_covariance()
        .diagonal()
        .map(f64::sqrt);
    (error, sigma)
}

/// Started 24.6 s into random room 57 (the rolled rig): a front-wall line and a floor line near
/// the wall's foot made a plane 3 deg off level, which the start took for its floor ahead of
/// the true one; the true floor, refused four epochs running, then turned the tilt back at a
/// rate read as 11 mrad/s of gyro bias, and the velocity ran to 4.8 m/s off. A floor that a
/// third line confirms goes first.
#[test]
fn a_start_in_motion_takes_its_tilt_from_a_confirmed_floor_first() {
    let (scenario, fusion, _) = run_from("random-room-57", 57, 24.6, 12.0);
    assert_velocity_honest(&scenario, &fusion, 0.02);
}

/// The paper's rig in the open room, crossing it from 60 s: the floor, from the two scanners'
/// parallel lines, is the only plane to see the pitch, and its normal is a few mrad vague
/// beside the filter's tilt. The prediction could not check it (a 1 s epoch cannot show a plane
/// turning at 10 mrad/s through that), so the pitch was held in doubt and the estimate
/// unusable in every epoch from 60 s to the end of the run, its velocity good to a few mm/s.
/// So vague a plane cannot pull the estimate off unseen: no fault the check would miss moves it
/// by more than the prediction's own sigma.
#[test]
fn a_floor_far_vaguer_than_the_filter_does_not_hold_the_estimate_in_doubt() {
    let (scenario, fusion, records) = run_from("open-room", 105, 0.0, 75.0);
    let after = |t: f64| records.iter().filter(move |r| r.t >= t);
    let in_doubt = after(60.0).filter(|r| r.provisional_directions > 0).count();
    assert!(in_doubt <= 6, "{in_doubt} epochs in doubt after 60 s");
    let outweighed = after(50.0)
        .flat_map(|r| &r.lone_directions)
        .filter(|lone| lone.check == witnesses::Check::Outweighed)
        .count();
    assert!(outweighed > 0);
    assert!(fusion.estimate().converged);
    assert_velocity_honest(&scenario, &fusion, 0.05);
}

/// Random room 134 with the paper's rig, still start, the platform yawed square to a wall
/// behind it and a pillar in front of that wall: the two scanners' lines on both are level and
/// parallel, and at one height they made a ceiling 0.9 m up, confirmed by a third wall line,
/// in every epoch. Once the platform moved, the ceiling tilted as no surface does, the filter
/// learnt a gyro bias 3 mrad/s off from it, and 30 s in the velocity was 5.4 m/s off with a
/// sigma of 0.36 m/s. The level scanner's beams end on the pillar's face, where a ceiling's
/// would pass under the nearer line.
#[test]
fn a_still_start_takes_no_ceiling_from_a_wall_and_a_pillar_face_behind_it() {
    let (scenario, fusion, _) = run_from("random-room-134", 134, 0.0, 30.0);
    assert_velocity_honest(&scenario, &fusion, 0.05);
}

/// Random room 58 with the paper's rig, still start: the pitched scanner laid a level line on
/// the side of a low box square to it, and the level scanner's beams passed over the box, so
/// the face was taken for a table top. Moving along the room, its line climbed a centimetre an
/// epoch, below what the parity test sees beside the floor, and the filter averaged it into a
/// vertical velocity 5 mm/s off at a 1 mm/s sigma in 7 of the 20 epochs from 35 s. Against
/// the other level planes its height wanders, and it is left out.
#[test]
fn a_low_face_whose_level_line_climbs_against_the_floor_is_left_out() {
    let (mut judged, mut outside) = (0, 0);
    let (_, _, records) = run_judging(
        "random-room-58",
        58,
        0.0,
        55.0,
        1.0,
        |scenario, fusion, record| {
            if record.t >= 35.0 {
                let (error, sigma) = velocity_error_and_sigma(scenario, fusion);
                judged += 1;
                outside += usize::from(error.z.abs() > 3.0 * sigma.z);
            }
        },
    );
    let left_out = records
        .iter()
        .filter(|r| !r.wandering_level_planes.is_empty())
        .count();
    assert!(left_out > 0, "the face was never left out");
    assert!(judged >= 19, "{judged} epochs judged");
    assert!(
        outside <= 1,
        "{outside} of {judged} epochs 3 sigma off vertically"
    );
}

/// Started 33.2 s into random room 103 (the rolled rig, in motion) at 1 Hz: three epochs
/// fused, and the estimate counted as converged, while the odometry kept surprising the
/// filter (NIS past their 95 % points, a refusal by the gate); its tilt was off, and 18
/// epochs later it was still converged, its sigmas below 0.5 m/s, with its velocity from 0.09
/// to 2.9 m/s off. Until the estimate converges, a surprise starts the count again.
#[test]
fn a_start_that_keeps_surprising_the_filter_does_not_converge() {
    assert_never_usable_and_wrong("random-room-103", 103, 33.2, 40.0, 1.0);
}

/// Started 23.7 s into random room 99 (the rolled rig, in motion), an epoch for every scan
/// pair (4 a second): a crossing pair 0.44 m below made a "table top" 45 mrad off level, which
/// the start's 3 deg tilt sigma let in as a floor 1.3 s in; gravity then ran the velocity off
/// at 0.44 m/s^2 along the direction the walls left free, and 2 s later the estimate counted
/// as converged 1.3 m/s off at a sigma of 0.09 m/s. A level surface sets the vertical only
/// beside another that agrees, square to the walls, or confirmed by a third line.
#[test]
fn a_start_in_motion_takes_no_vertical_from_a_plane_the_walls_disown() {
    assert_never_usable_and_wrong("random-room-99", 99, 23.7, 10.0, 4.0);
}

/// Started 33.15 s into random room 103 (the rolled rig, in motion), an epoch for every scan
/// pair (4 a second): beside the floor the odometer also makes a plane 14-24 mrad off level, a
/// centimetre or two from it, which stands 10-15 mrad off square to the two parallel walls it
/// sees: within three sigmas of square, so it could set the vertical, and from 13 s on the
/// estimate was usable with velocity errors beyond three of its sigmas (at 10 scans/s the same
/// plane set the tilt 11 mrad off and the velocity ran off at 0.13 m/s^2, 0.6 m/s at worst).
/// Within two sigmas of square, the walls disown it.
#[test]
fn a_start_in_motion_takes_no_vertical_from_a_floor_leaning_off_its_walls() {
    assert_never_usable_and_wrong("random-room-103", 103, 33.15, 20.0, 4.0);
}

/// Random room 54 (the paper's rig, still start) at 10 Hz: when the platform moved off, a
/// rotation the filter learnt set its pitch-rate bias 3 mrad/s off, and the pitch it then held
/// in doubt was released by lone planes each far vaguer than one epoch's prediction; at ten
/// epochs a second their pulls add up. Judged per epoch, the estimate was usable 30 s in with
/// a velocity 4 m/s off; judged over the second, it stays in doubt.
#[test]
fn at_10_hz_a_vague_plane_is_outweighed_only_over_a_second_of_epochs() {
    let (scenario, fusion, _) = run_at_rate("random-room-54", 54, 0.0, 30.0, 10.0);
    assert_honest_or_unusable(&scenario, &fusion);
}
