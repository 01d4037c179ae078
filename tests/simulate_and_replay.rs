//! `simulate` records a scenario through the drivers' emulators; replaying it must give back the
//! simulator's own scans and IMU samples (ranges to the millimetre, times through the clock
//! estimators), the truth, and the rig's configuration; and a damaged copy must fail cleanly.

#[allow(dead_code)]
mod support;

use ladar_odometer::daemon::pipeline::{EventTrace, Traced};
use ladar_odometer::daemon::recording::{
    ReadMode, Recording, CONFIG_METADATA_KEY, CONFIG_METADATA_NAME,
};
use ladar_odometer::daemon::replay::{self, ReplayError, ReplayOptions};
use ladar_odometer::daemon::simulate::{self, HANDSHAKE_S};
use ladar_odometer::sensors::{ImuSample, Scan};
use ladar_sim::{Scenario, SimEvent, Simulator, BUILTIN_NAMES};
use std::path::PathBuf;

fn scratch(name: &str) -> PathBuf {
    support::sweep_stale("sim");
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

/// The recording as Python's `mcap` writer (zstd, its default) or an lz4 writer would have
/// written it: the same channels, messages and configuration in compressed chunks.
fn rewritten_compressed(recording: &Recording, compression: mcap::Compression) -> Vec<u8> {
    use std::collections::{BTreeMap, HashMap};
    let mut out = std::io::Cursor::new(Vec::new());
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(compression))
        .create(&mut out)
        .unwrap();
    let config = recording.config_toml.clone().expect("simulate records it");
    writer
        .write_metadata(&mcap::records::Metadata {
            name: CONFIG_METADATA_NAME.into(),
            metadata: BTreeMap::from([(CONFIG_METADATA_KEY.to_string(), config)]),
        })
        .unwrap();
    let mut channels = HashMap::new();
    for (sequence, message) in recording.messages.iter().enumerate() {
        let topic = message.topic();
        let channel = *channels.entry(topic.clone()).or_insert_with(|| {
            writer
                .add_channel(0, &topic, message.encoding.as_str(), &BTreeMap::new())
                .unwrap()
        });
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: sequence as u32,
            log_time: message.log_time_ns,
            publish_time: message.log_time_ns,
        };
        writer
            .write_to_known_channel(&header, &message.data)
            .unwrap();
    }
    writer.finish().unwrap();
    drop(writer);
    out.into_inner()
}

#[test]
fn zstd_and_lz4_recordings_from_other_tools_replay_like_the_original() {
    let (_, scenario_path) = short_scenario("compressed.toml");
    let original = scratch("compressed-source.mcap");
    simulate::simulate(scenario_path.to_str().unwrap(), &original).unwrap();
    let replay_of = |recording: PathBuf| {
        let options = ReplayOptions {
            recording,
            ..ReplayOptions::default()
        };
        replay::replay(&options, |_, _| EventTrace::default()).unwrap()
    };
    let (want_summary, want) = replay_of(original.clone());
    assert!(!want.calls.is_empty());
    let recording = Recording::open(&original, ReadMode::Strict).unwrap();
    for compression in [mcap::Compression::Zstd, mcap::Compression::Lz4] {
        let file = scratch(&format!("compressed-{compression:?}.mcap"));
        std::fs::write(&file, rewritten_compressed(&recording, compression)).unwrap();
        let (summary, got) = replay_of(file);
        assert_eq!(
            (summary.chunks, summary.bytes, &summary.sensors),
            (
                want_summary.chunks,
                want_summary.bytes,
                &want_summary.sensors
            ),
            "{compression:?}"
        );
        assert!(got == want, "{compression:?}: the replay differs");
    }
}

#[test]
fn a_tolerant_replay_that_keeps_nothing_is_an_error_naming_the_file() {
    let (_, scenario_path) = short_scenario("nothing.toml");
    let out = scratch("nothing-source.mcap");
    simulate::simulate(scenario_path.to_str().unwrap(), &out).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    // The magic and part of the header record: no sensor message is complete.
    let cut = scratch("nothing.mcap");
    std::fs::write(&cut, &bytes[..12]).unwrap();
    let options = ReplayOptions {
        recording: cut.clone(),
        tolerant: true,
        ..ReplayOptions::default()
    };
    let error = replay::replay(&options, |_, _| EventTrace::default()).unwrap_err();
    assert!(
        matches!(error, ReplayError::NothingKept { .. }),
        "{error:?}"
    );
    let line = error.to_string();
    assert!(!line.contains('\n'), "{line}");
    assert!(
        line.contains(&cut.display().to_string()) && line.contains("mcap recover"),
        "{line}"
    );
}

/// Every built-in can be recorded, replayed and served (serve-emulators writes the rig
/// configuration `rig_config` gives): each has an IMU, and a trajectory it can follow. Two
/// random rooms stand for the rest, one of each rig.
#[test]
fn every_builtin_scenario_simulates_replays_and_has_a_rig_to_serve() {
    for name in BUILTIN_NAMES
        .into_iter()
        .chain(["random-room-3", "random-room-4"])
    {
        let mut scenario = Scenario::builtin(name).unwrap();
        scenario.duration_s = scenario.duration_s.min(3.0);
        assert!(
            simulate::rig_config(&scenario).is_ok(),
            "{name} cannot be served"
        );
        let path = scratch(&format!("builtin-{name}.toml"));
        std::fs::write(&path, scenario.to_toml().unwrap()).unwrap();
        let out = scratch(&format!("builtin-{name}.mcap"));
        let summary = simulate::simulate(path.to_str().unwrap(), &out)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(summary.imu_samples > 0 && summary.scans > 0, "{name}");
        let options = ReplayOptions {
            recording: out,
            ..ReplayOptions::default()
        };
        let (_, trace) = replay::replay(&options, |_, _| EventTrace::default()).unwrap();
        let imu = trace
            .calls
            .iter()
            .filter(|c| matches!(c, Traced::Imu(_)))
            .count();
        assert_eq!(imu as u64, summary.imu_samples, "{name}");
    }
}

#[test]
fn an_unknown_scenario_names_the_choices() {
    let error = simulate::simulate("no-such-scenario", &scratch("never.mcap")).unwrap_err();
    assert!(error.to_string().contains("hallway-hover"), "{error}");
}
