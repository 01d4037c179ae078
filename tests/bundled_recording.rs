//! The recording shipped in the repository (`data/hallway-hover.mcap`, made from
//! data/scenarios/bundled-hallway-hover.toml) replays through the real fusion to the accuracy
//! the fusion reaches on that scenario. It is part of the repository, so it must exist.

use ladar_odometer::daemon::fusion_estimator::FusionEstimator;
use ladar_odometer::daemon::pipeline::Outcome;
use ladar_odometer::daemon::replay::{self, ReplayOptions, BUNDLED_RECORDING};
use std::path::Path;

/// The repository's budget for the bundled file.
const MAX_BYTES: u64 = 10 * 1024 * 1024;

#[test]
fn bundled_recording_replays_within_the_hover_accuracy() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(BUNDLED_RECORDING);
    let size = std::fs::metadata(&path)
        .unwrap_or_else(|e| panic!("{} is part of the repository: {e}", path.display()))
        .len();
    assert!(size <= MAX_BYTES, "{} is {size} bytes", path.display());

    let options = ReplayOptions {
        recording: path,
        ..ReplayOptions::default()
    };
    let (summary, estimator) =
        replay::replay(&options, |config, _| FusionEstimator::new(config)).unwrap();
    println!("{summary}");
    assert!(summary.loss.is_none());
    assert!(summary.duration_s > 60.0, "{summary}");
    assert!(estimator.fusion().is_some());
    for (name, counts) in &summary.sensors {
        assert_eq!(counts.decode_errors, 0, "{name}");
    }
    // One epoch a second, every one after the first with planes from both scanners.
    assert!(summary.outputs.epochs >= 70, "{summary}");
    assert_eq!(
        summary.outputs.outcomes.total(),
        summary.outputs.epochs,
        "{summary}"
    );
    assert!(
        summary.outputs.outcomes.get(Outcome::Fused) >= 50,
        "most epochs after the stationary start are fused: {summary}"
    );
    assert!(
        summary.to_string().contains("\n  epochs: ") && summary.to_string().contains(" fused"),
        "{summary}"
    );
    assert!(
        summary.outputs.planes as f64 / summary.outputs.epochs as f64 >= 4.0,
        "{summary}"
    );

    let truth = summary
        .truth
        .expect("the simulated recording carries /truth");
    assert_eq!(
        truth.from_s, 20.0,
        "the rig config sets the stationary start"
    );
    assert!(truth.samples >= 1000, "{summary}");
    // tests/hallway.rs reaches about [0.006 0.003 0.001] m/s and 1-3 mrad on this geometry.
    for axis in 0..3 {
        assert!(truth.velocity_std_ned[axis] < 0.015, "{summary}");
        assert!(truth.attitude_std_mrad[axis] < 4.0, "{summary}");
        assert!(truth.attitude_rms_mrad[axis] < 10.0, "{summary}");
        // A hover among walls: centimetres, where a velocity 0.015 m/s off would give 0.8 m.
        assert!(truth.position_drift_rms_m[axis] < 0.05, "{summary}");
    }
}

/// `replay --start 30 --duration 30`: the fusion starts while the rig hovers, as a daemon
/// restarted in flight would. It is usable within 10 s, honest in body axes, and the summary
/// leaves out the NED comparison, whose origin and north are not the recording's.
#[test]
fn a_replay_started_in_the_hover_is_usable_within_10_s_and_honest() {
    let options = ReplayOptions {
        recording: Path::new(env!("CARGO_MANIFEST_DIR")).join(BUNDLED_RECORDING),
        start_s: 30.0,
        duration_s: Some(30.0),
        ..ReplayOptions::default()
    };
    let (summary, _) = replay::replay(&options, |config, _| FusionEstimator::new(config)).unwrap();
    println!("{summary}");
    assert!(summary.truth.is_none(), "{summary}");
    assert!(
        (summary.duration_s - 60.0).abs() < 0.5,
        "read up to 60 s: {summary}"
    );
    let view = summary.autopilot.expect("the recording carries /truth");
    assert!(
        view.first_valid_after_s.is_some_and(|s| s <= 10.0),
        "{summary}"
    );
    for axis in 0..3 {
        assert!(view.inside_3_sigma[axis] >= 0.97, "{summary}");
        assert!(view.mean_nees[axis] <= 1.5, "{summary}");
    }
}

/// Replay is how a flight is examined afterwards, so the real fusion must give the same bytes
/// every time: estimates, epochs and MAVLink frames.
#[test]
fn replaying_twice_with_the_real_fusion_writes_the_same_bytes() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(BUNDLED_RECORDING);
    let scratch = std::env::temp_dir().join(format!("ladar-bundled-{}", std::process::id()));
    let outputs: Vec<_> = ["first", "second"]
        .iter()
        .map(|run| {
            let out = scratch.join(run);
            let options = ReplayOptions {
                recording: path.clone(),
                out: Some(out.clone()),
                ..ReplayOptions::default()
            };
            replay::replay(&options, |config, _| FusionEstimator::new(config)).unwrap();
            ["trajectory.tum", "epochs.jsonl", "mavlink.tlog"]
                .map(|file| std::fs::read(out.join(file)).unwrap())
        })
        .collect();
    std::fs::remove_dir_all(&scratch).unwrap();
    for (first, second) in outputs[0].iter().zip(&outputs[1]) {
        assert!(first.len() > 10_000);
        assert!(first == second, "the two replays differ");
    }
}

/// `replay` logs through RUST_LOG like `run`: what it replays at info, each epoch at debug.
#[test]
fn replay_honours_rust_log() {
    let replay = |rust_log: Option<&str>| {
        let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_ladar-odometer"));
        command
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .args(["replay", "--duration", "4"])
            .env_remove("RUST_LOG");
        if let Some(filter) = rust_log {
            command.env("RUST_LOG", filter);
        }
        let output = command.output().unwrap();
        assert!(output.status.success(), "{output:?}");
        String::from_utf8(output.stderr).unwrap()
    };
    let debug = replay(Some("debug"));
    assert!(debug.contains("replaying"), "{debug}");
    assert!(debug.contains(" epoch "), "{debug}");
    let quiet = replay(Some("warn"));
    assert!(!quiet.contains("replaying"), "{quiet}");
    let default = replay(None);
    assert!(
        default.contains("replaying") && !default.contains(" epoch "),
        "{default}"
    );
}

/// `replay --method map` measures on the plane map whatever the recording configured: its
/// epochs.jsonl carries the map, with lines fused on surfaces, and the summary's velocity
/// against truth is as good as the hover's.
#[test]
fn replay_method_map_measures_on_the_plane_map() {
    let out = std::env::temp_dir().join(format!("ladar-method-map-{}", std::process::id()));
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_ladar-odometer"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["replay", "--method", "map", "--out"])
        .arg(&out)
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert!(output.status.success(), "{output:?}");
    let epochs = std::fs::read_to_string(out.join("epochs.jsonl")).unwrap();
    std::fs::remove_dir_all(&out).unwrap();
    let fused_on_the_map = epochs
        .lines()
        .map(|line| serde_json::from_str::<serde_json::Value>(line).unwrap())
        .filter(|epoch| epoch["map"]["fused"].as_u64().is_some_and(|n| n >= 4))
        .count();
    assert!(
        fused_on_the_map >= 40,
        "{fused_on_the_map} epochs fused on the map"
    );
    let summary = String::from_utf8(output.stdout).unwrap();
    let std_line = summary
        .lines()
        .find(|l| l.contains("velocity error NED  std"))
        .unwrap_or_else(|| panic!("{summary}"));
    let numbers: Vec<f64> = std_line
        .split(['[', ']'])
        .nth(1)
        .unwrap()
        .split_whitespace()
        .map(|n| n.parse().unwrap())
        .collect();
    assert!(numbers.iter().all(|&v| v < 0.015), "{std_line}");
}
