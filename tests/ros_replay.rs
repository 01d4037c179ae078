//! A simulated flight replayed from its raw bytes and from ROS 1 and ROS 2 recordings of the
//! same measurements gives the same trajectory, to within what ROS messages round; and a ROS
//! recording that no configured sensor can read is refused in one line naming its topics.

#[path = "support/ros_mcap.rs"]
mod ros_mcap;
#[allow(dead_code)]
mod support;

use ladar_odometer::daemon::config::Config;
use ladar_odometer::daemon::fusion_estimator::FusionEstimator;
use ladar_odometer::daemon::pipeline::{EpochCounts, Estimator, EventTrace, Traced};
use ladar_odometer::daemon::replay::{self, ReplayError, ReplayOptions, ReplaySummary};
use ladar_odometer::estimate::Estimate;
use ladar_odometer::sensors::{ImuSample, Mount, Scan, ScannerGeometry};
use ladar_sim::Scenario;
use ros_mcap::{RosRig, TOPICS};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

fn scratch(name: &str) -> PathBuf {
    support::sweep_stale("ros");
    let dir = std::env::temp_dir().join(format!("ladar-ros-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// The hallway flight, its first 6 s of motion after the 10 s stationary start, with an IMU
/// that outputs rates (ROS `Imu` messages carry rates, not increments); simulated once and
/// traced once for all the tests.
struct Flight {
    raw: PathBuf,
    calls: Vec<Traced>,
    /// The rig's configuration with the ROS topics of its sensors.
    ros_config: PathBuf,
}

fn flight() -> &'static Flight {
    static FLIGHT: OnceLock<Flight> = OnceLock::new();
    FLIGHT.get_or_init(|| {
        let mut scenario = Scenario::builtin("hallway-flight").unwrap();
        scenario.duration_s = 16.0;
        let raw = scratch("flight.mcap");
        let simulated = ros_mcap::simulate_with_topics(scenario, &raw);
        let ros_config = scratch("flight-ros.toml");
        std::fs::write(&ros_config, &simulated.ros_config).unwrap();
        Flight {
            raw,
            calls: simulated.calls,
            ros_config,
        }
    })
}

fn ros_recording(name: &str, encoding: rosmsg::Encoding, multi_echo: &[usize]) -> PathBuf {
    ros_recording_with_mounts(name, encoding, multi_echo, &[])
}

/// With `/tf_static` carrying `mounts` unless that is empty.
fn ros_recording_with_mounts(
    name: &str,
    encoding: rosmsg::Encoding,
    multi_echo: &[usize],
    mounts: &[Mount],
) -> PathBuf {
    let path = scratch(name);
    let rig = RosRig {
        topics: &TOPICS,
        multi_echo,
        mounts,
    };
    ros_mcap::write(&path, encoding, &flight().calls, &rig);
    path
}

/// A ROS recording has no `PP` reply: a scanner's geometry comes with its first scan, and the
/// fusion starts once both are known. This gives a raw replay's estimator the geometries at
/// that same moment, so that both replays fuse the same measurements from the same start.
struct GeometryWithFirstScan<E> {
    inner: E,
    held: [Option<ScannerGeometry>; 2],
}

impl<E: Estimator> Estimator for GeometryWithFirstScan<E> {
    type Epoch = E::Epoch;
    fn geometry(&mut self, scanner: usize, geometry: ScannerGeometry) {
        self.held[scanner] = Some(geometry);
    }
    fn imu(&mut self, sample: ImuSample) -> Option<Estimate> {
        self.inner.imu(sample)
    }
    fn scan(&mut self, scan: Scan) -> Option<E::Epoch> {
        if let Some(geometry) = self.held[scan.sensor].take() {
            self.inner.geometry(scan.sensor, geometry);
        }
        self.inner.scan(scan)
    }
    fn epoch_estimate(&self) -> Option<Estimate> {
        self.inner.epoch_estimate()
    }
    fn sensor_stale(&mut self, sensor: usize, stale: bool, t: f64) {
        self.inner.sensor_stale(sensor, stale, t);
    }
    fn epoch_counts(epoch: &E::Epoch) -> EpochCounts {
        E::epoch_counts(epoch)
    }
}

/// Replays into `out` and reads back `trajectory.tum`: time, position, quaternion.
fn trajectory(
    recording: &Path,
    config: Option<&Path>,
    out: &str,
) -> (ReplaySummary, Vec<[f64; 8]>) {
    let out = scratch(out);
    let options = ReplayOptions {
        recording: recording.to_path_buf(),
        config: config.map(Path::to_path_buf),
        out: Some(out.clone()),
        ..ReplayOptions::default()
    };
    let (summary, _) = replay::replay(&options, |config, _| GeometryWithFirstScan {
        inner: FusionEstimator::new(config),
        held: [None; 2],
    })
    .unwrap();
    let text = std::fs::read_to_string(out.join("trajectory.tum")).unwrap();
    let lines = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let values: Vec<f64> = l.split_whitespace().map(|v| v.parse().unwrap()).collect();
            values.try_into().unwrap()
        })
        .collect();
    (summary, lines)
}

/// The largest position (m) and attitude (rad) differences between two trajectories, over the
/// times both have; `b` may begin up to [`LATE_START_SAMPLES`] estimates after `a`.
fn largest_difference(a: &[[f64; 8]], b: &[[f64; 8]]) -> (f64, f64) {
    let late = a.len() - b.len();
    assert!(late <= LATE_START_SAMPLES, "{late} estimates fewer");
    let a = &a[late..];
    let mut worst = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        assert!(
            (x[0] - y[0]).abs() < 1e-6,
            "estimate times {} vs {}",
            x[0],
            y[0]
        );
        let position = (0..3)
            .map(|i| (x[1 + i] - y[1 + i]).powi(2))
            .sum::<f64>()
            .sqrt();
        let q = |v: &[f64; 8]| {
            nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                v[7], v[4], v[5], v[6],
            ))
        };
        worst.0 = worst.0.max(position);
        worst.1 = worst.1.max(q(x).angle_to(&q(y)));
    }
    worst
}

/// What a ROS message rounds: ranges to float32 (the raw ranges are whole millimetres below
/// 60 m, moved by at most 2 micrometres) and times to the nanosecond; IMU values are float64
/// in ROS and pass unchanged. The nanosecond matters once: the filter's alignment ends after a
/// fixed time, and a stamp rounded across that edge ends it one IMU sample (2.5 ms) later, so
/// the ROS replay may begin an estimate or two late. That start from one more gyro sample of
/// noise is what remains between the trajectories (0.2 mm and 0.2 mrad measured over the
/// 6 s of flight); the bounds below are a few times that, and a hundred times smaller than the
/// errors a wrong sign, frame, beam angle or beam time makes.
const LATE_START_SAMPLES: usize = 2;
const POSITION_TOLERANCE_M: f64 = 1e-3;
const ATTITUDE_TOLERANCE_RAD: f64 = 5e-4;

#[test]
fn ros1_and_ros2_recordings_of_a_flight_give_the_raw_replays_trajectory() {
    let flight = flight();
    let (raw_summary, raw) = trajectory(&flight.raw, None, "raw-out");
    assert!(raw_summary.outputs.epochs > 10, "{raw_summary}");
    let cases = [
        ("ros2.mcap", rosmsg::Encoding::Cdr, &[][..]),
        // As cartographer's backpack: the vertical scanner multi-echo.
        ("ros1.mcap", rosmsg::Encoding::Ros1, &[1][..]),
    ];
    for (name, encoding, multi_echo) in cases {
        let recording = ros_recording(name, encoding, multi_echo);
        let (summary, ros) =
            trajectory(&recording, Some(&flight.ros_config), &format!("{name}-out"));
        assert_eq!(
            summary.outputs.epochs, raw_summary.outputs.epochs,
            "{name}: {summary}"
        );
        assert_eq!(
            summary.outputs.outcomes, raw_summary.outputs.outcomes,
            "{name}"
        );
        for ((topic, counts), (_, raw_counts)) in summary.sensors.iter().zip(&raw_summary.sensors) {
            assert_eq!(counts.scans, raw_counts.scans, "{name} {topic}");
            assert_eq!(counts.imu_samples, raw_counts.imu_samples, "{name} {topic}");
            assert_eq!(
                (counts.decode_errors, counts.dropped),
                (0, 0),
                "{name} {topic}"
            );
        }
        let (position, attitude) = largest_difference(&raw, &ros);
        eprintln!("{name}: largest difference {position:.3e} m, {attitude:.3e} rad");
        assert!(position < POSITION_TOLERANCE_M, "{name}: {position} m");
        assert!(attitude < ATTITUDE_TOLERANCE_RAD, "{name}: {attitude} rad");
    }
}

fn replay_error(recording: &Path, config: Option<&Path>) -> String {
    let options = ReplayOptions {
        recording: recording.to_path_buf(),
        config: config.map(Path::to_path_buf),
        ..ReplayOptions::default()
    };
    let error = replay::replay(&options, |_, _| EventTrace::default()).unwrap_err();
    let line = error.to_string();
    assert!(!line.contains('\n'), "{line}");
    assert!(
        matches!(
            error,
            ReplayError::NoUsableTopic { .. } | ReplayError::RosWithoutConfig { .. }
        ),
        "{error:?}"
    );
    line
}

#[test]
fn a_ros_recording_without_a_configuration_or_with_none_of_its_topics_is_one_line_naming_them() {
    let recording = ros_recording("unmapped.mcap", rosmsg::Encoding::Cdr, &[]);
    let line = replay_error(&recording, None);
    assert!(line.contains("--config FILE"), "{line}");
    assert!(line.contains("/imu (sensor_msgs/msg/Imu)"), "{line}");

    let config = std::fs::read_to_string(&flight().ros_config).unwrap();
    let elsewhere = scratch("elsewhere.toml");
    std::fs::write(
        &elsewhere,
        config.replace("topic = \"/", "topic = \"/robot/"),
    )
    .unwrap();
    let line = replay_error(&recording, Some(&elsewhere));
    for topic in [
        "/horizontal_laser_2d (sensor_msgs/msg/LaserScan)",
        "/rosout (rcl_interfaces/msg/Log)",
    ] {
        assert!(line.contains(topic), "{topic} missing: {line}");
    }
    assert!(line.contains("`topic = \"/NAME\"`"), "{line}");
}

#[test]
fn a_ros_topic_of_the_wrong_type_for_its_sensor_is_counted_never_fused() {
    let recording = ros_recording("crossed.mcap", rosmsg::Encoding::Ros1, &[]);
    let config = std::fs::read_to_string(&flight().ros_config)
        .unwrap()
        .replace("topic = \"/imu\"", "topic = \"/imu-not-recorded\"")
        .replace("topic = \"/vertical_laser_2d\"", "topic = \"/imu\"");
    let crossed = scratch("crossed.toml");
    std::fs::write(&crossed, config).unwrap();
    let options = ReplayOptions {
        recording,
        config: Some(crossed),
        ..ReplayOptions::default()
    };
    let (summary, trace) = replay::replay(&options, |_, _| EventTrace::default()).unwrap();
    let (_, vertical) = &summary.sensors[1];
    assert!(vertical.decode_errors > 1000, "{summary}");
    assert_eq!(vertical.scans, 0);
    assert!(!trace.calls.iter().any(|c| matches!(
        c,
        Traced::Imu(_) | Traced::Scan(ladar_odometer::sensors::Scan { sensor: 1, .. })
    )));
}

/// The flight's mounts as its configuration states them, scanners then the IMU, and that
/// configuration with every mount left out and the body frame of `/tf_static` named instead.
fn mounts_and_config_without_them() -> (Vec<Mount>, PathBuf) {
    let path = &flight().ros_config;
    let config = Config::load(path).unwrap();
    let mounts = config
        .scanners
        .iter()
        .map(|s| Mount::from_rpy_deg(s.rpy_deg.unwrap(), s.translation_m.unwrap()))
        .chain([Mount::from_rpy_deg(config.imu.rpy_deg.unwrap(), [0.0; 3])])
        .collect();
    let text = std::fs::read_to_string(path).unwrap();
    let mut without: String = text
        .lines()
        .filter(|line| !line.starts_with("rpy_deg") && !line.starts_with("translation_m"))
        .map(|line| format!("{line}\n"))
        .collect();
    assert_eq!(text.lines().count() - without.lines().count(), 5, "{text}");
    without += &format!("\n[ros]\nbody_frame = \"{}\"\n", ros_mcap::BODY_FRAME);
    let without_path = scratch("flight-ros-tf.toml");
    std::fs::write(&without_path, without).unwrap();
    (mounts, without_path)
}

#[test]
fn mounts_from_tf_static_give_the_trajectory_of_mounts_stated_in_the_configuration() {
    let flight = flight();
    let (mounts, without) = mounts_and_config_without_them();
    for (name, encoding) in [
        ("tf-ros2.mcap", rosmsg::Encoding::Cdr),
        ("tf-ros1.mcap", rosmsg::Encoding::Ros1),
    ] {
        let recording = ros_recording_with_mounts(name, encoding, &[], &mounts);
        let (stated_summary, stated) = trajectory(
            &recording,
            Some(&flight.ros_config),
            &format!("{name}-stated"),
        );
        assert!(stated_summary.outputs.epochs > 10, "{stated_summary}");
        let (summary, from_tf) = trajectory(&recording, Some(&without), &format!("{name}-tf"));
        assert_eq!(summary.outputs, stated_summary.outputs, "{name}");
        assert_eq!(stated.len(), from_tf.len(), "{name}");
        // The same mounts, through a quaternion and back to degrees: rounding only.
        let (position, attitude) = largest_difference(&stated, &from_tf);
        assert!(
            position < 1e-9 && attitude < 1e-9,
            "{name}: {position} m, {attitude} rad"
        );
    }
}

#[test]
fn a_mount_left_out_of_a_recording_without_tf_static_is_one_line_naming_sensor_and_fix() {
    let (_, without) = mounts_and_config_without_them();
    let recording = ros_recording("no-tf.mcap", rosmsg::Encoding::Cdr, &[]);
    let options = ReplayOptions {
        recording,
        config: Some(without),
        ..ReplayOptions::default()
    };
    let error = replay::replay(&options, |_, _| EventTrace::default()).unwrap_err();
    let line = error.to_string();
    assert!(matches!(error, ReplayError::NoMount { .. }), "{error:?}");
    assert!(!line.contains('\n'), "{line}");
    for part in [
        "[[scanner]] 0 on /horizontal_laser_2d",
        "no chain from `base_link` to `horizontal_laser_2d_link`",
        "set rpy_deg and translation_m",
    ] {
        assert!(line.contains(part), "{part} missing: {line}");
    }
}
