//! `simulate` records a scenario through the drivers' emulators; replaying it must give back the
//! simulator's own scans and IMU samples (ranges to the millimetre, times through the clock
//! estimators), the truth, and the rig's configuration; and a damaged copy must fail cleanly.

use ladar_odometer::daemon::pipeline::{EventTrace, Traced};
use ladar_odometer::daemon::recording::{ReadMode, Recording};
use ladar_odometer::daemon::replay::{self, ReplayError, ReplayOptions};
use ladar_odometer::daemon::simulate::{self, HANDSHAKE_S};
use ladar_odometer::sensors::{ImuSample, Scan};
use ladar_odometer::sim::{Scenario, SimEvent, Simulator};
use std::path::PathBuf;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ladar-sim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// The hallway hover, cut to a few seconds so the test stays quick. Each test writes its own
/// file: tests run in parallel, and one reading while another rewrites sees a truncated file.
fn short_scenario(file: &str) -> (Scenario, PathBuf) {
    let mut scenario = Scenario::builtin("hallway-hover").unwrap();
    scenario.duration_s = 3.0;
    let path = scratch(file);
    std::fs::write(&path, scenario.to_toml().unwrap()).unwrap();
    (scenario, path)
}

fn simulated_events(scenario: &Scenario) -> (Vec<Scan>, Vec<ImuSample>, usize) {
    let mut simulator = Simulator::new(scenario).unwrap();
    let (mut scans, mut imu, mut truth) = (Vec::new(), Vec::new(), 0);
    for event in simulator.events() {
        match event {
            SimEvent::Scan { scan, .. } => scans.push(scan),
            SimEvent::Imu(sample) => imu.push(sample),
            SimEvent::Truth(_) => truth += 1,
        }
    }
    (scans, imu, truth)
}

#[test]
fn replay_of_a_simulation_gives_back_the_simulated_measurements() {
    let (scenario, scenario_path) = short_scenario("measurements.toml");
    let out = scratch("short.mcap");
    let summary = simulate::simulate(scenario_path.to_str().unwrap(), &out).unwrap();
    let (sim_scans, sim_imu, sim_truth) = simulated_events(&scenario);
    assert_eq!(summary.scans as usize, sim_scans.len());
    assert_eq!(summary.imu_samples as usize, sim_imu.len());

    let recording = Recording::open(&out, ReadMode::Strict).unwrap();
    assert_eq!(recording.truth.len(), sim_truth);
    let config = recording.config_toml.as_deref().unwrap();
    assert!(
        config.contains("[[scanner]]") && config.contains("[imu]"),
        "{config}"
    );

    let (replayed, trace) = replay::replay(
        &ReplayOptions {
            recording: out.clone(),
            ..ReplayOptions::default()
        },
        |config, specs| {
            assert!(config.is_some(), "the rig's configuration is in the file");
            assert_eq!(specs.len(), scenario.scanners.len() + 1);
            EventTrace::default()
        },
    )
    .unwrap();
    let scans: Vec<&Scan> = trace
        .calls
        .iter()
        .filter_map(|c| match c {
            Traced::Scan(s) => Some(s),
            _ => None,
        })
        .collect();
    let imu: Vec<&ImuSample> = trace
        .calls
        .iter()
        .filter_map(|c| match c {
            Traced::Imu(s) => Some(s),
            _ => None,
        })
        .collect();
    assert_eq!(scans.len(), sim_scans.len());
    assert_eq!(imu.len(), sim_imu.len());
    for sensor in 0..scenario.scanners.len() {
        let ours = scans.iter().filter(|s| s.sensor == sensor);
        let theirs = sim_scans.iter().filter(|s| s.sensor == sensor);
        for (got, want) in ours.zip(theirs) {
            assert_eq!(got.first_step, want.first_step);
            assert_eq!(got.ranges_m.len(), want.ranges_m.len());
            for (g, w) in got.ranges_m.iter().zip(&want.ranges_m) {
                assert!((g - w).abs() < 5e-4, "{g} vs {w}");
            }
            // Host time = simulated time + the handshake lead, through the SCIP clock fit.
            let error = got.t0 - (want.t0 + HANDSHAKE_S);
            assert!(error.abs() < 2e-3, "scan t0 off by {error} s");
        }
    }
    for (got, want) in imu.iter().zip(&sim_imu) {
        let error = got.time() - (want.time() + HANDSHAKE_S);
        assert!(error.abs() < 1e-3, "IMU time off by {error} s");
        if let (ImuSample::Delta { dv: a, .. }, ImuSample::Delta { dv: b, .. }) = (got, want) {
            assert!((a - b).norm() < 1e-5, "float32 on the wire: {a} vs {b}");
        }
    }
    for (_, counts) in &replayed.sensors {
        assert_eq!(counts.decode_errors, 0);
        assert_eq!(counts.lost_packets, 0);
    }
}

#[test]
fn a_cut_simulation_is_refused_in_one_line_and_kept_when_tolerant() {
    let (_, scenario_path) = short_scenario("cut.toml");
    let out = scratch("cut-source.mcap");
    simulate::simulate(scenario_path.to_str().unwrap(), &out).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    let cut = scratch("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let options = ReplayOptions {
        recording: cut,
        ..ReplayOptions::default()
    };
    let error = replay::replay(&options, |_, _| EventTrace::default()).unwrap_err();
    assert!(matches!(error, ReplayError::Recording(_)), "{error:?}");
    let line = error.to_string();
    assert!(
        !line.contains('\n') && line.contains("--tolerant"),
        "{line}"
    );
    let (summary, trace) = replay::replay(
        &ReplayOptions {
            tolerant: true,
            ..options
        },
        |_, _| EventTrace::default(),
    )
    .unwrap();
    assert!(summary.loss.is_some());
    assert!(!trace.calls.is_empty());
}

#[test]
fn an_unknown_scenario_names_the_choices() {
    let error = simulate::simulate("no-such-scenario", &scratch("never.mcap")).unwrap_err();
    assert!(error.to_string().contains("hallway-hover"), "{error}");
}
