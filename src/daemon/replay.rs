//! `replay`: a recording's chunks, in file order (the order the live daemon consumed them),
//! through the same [`Pipeline`] as `run`, so the estimates come out bit for bit the same. The
//! recording is streamed one MCAP chunk at a time, so a long flight replays in a few megabytes.

use super::config::{Config, MountOf};
use super::foxglove::FoxgloveWriter;
use super::link::{Link, LinkAddress, LinkError};
use super::mavlink_out::{Identity, MavlinkStream, Profile, QualityPolicy, DEFAULT_COMPONENT_ID};
use super::outputs::{write_truth, OutputError, Outputs, REPORT_FILE};
use super::pipeline::{
    configured_sensors, sensor_specs, Chunk, Configured, EpochCounts, Estimator, Output, Pipeline,
    SensorSpec,
};
use super::readings::{DecodeCounts, Receivers};
use super::recording::{
    Encoding, Loss, ReadMode, RecordedMessage, RecordingError, RecordingReader,
};
use super::ros;
use super::sink::{Autopilot, Sink, Tally};
use super::truth::{autopilot_view, truth_errors, AutopilotView, TruthErrors};
use crate::estimate::Estimate;
use crate::report::chart::ChartError;
use crate::report::RunReport;
use crate::sensors::{ImuSample, Scan, ScannerGeometry};
use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::MAVLinkV2MessageRaw;
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::path::PathBuf;
use std::time::{Duration, Instant};

fn triple(values: [f64; 3], decimals: usize) -> String {
    let [a, b, c] = values;
    format!("[{a:.decimals$} {b:.decimals$} {c:.decimals$}]")
}

/// The recording `replay` runs when given none.
pub const BUNDLED_RECORDING: &str = "data/hallway-hover.mcap";

#[derive(Debug, Clone, Default)]
pub struct ReplayOptions {
    pub recording: PathBuf,
    /// Replay with this configuration instead of the recorded one: a ROS recording carries
    /// none, and its sensors are found by the `topic` keys of this one.
    pub config: Option<PathBuf>,
    pub out: Option<PathBuf>,
    /// Pace the chunks at their recorded log times instead of as fast as possible.
    pub realtime: bool,
    /// Also send the MAVLink stream to this address (`udpout:127.0.0.1:14550`, ...).
    pub mavlink: Option<String>,
    /// Keep what is complete in a damaged recording instead of refusing it.
    pub tolerant: bool,
    /// Draw a progress bar (only drawn on a terminal in any case).
    pub progress: bool,
    /// Seconds into the recording at which the fusion starts: an in-motion start anywhere. The
    /// decoders still read everything before (a scanner's geometry comes only at its start-up).
    pub start_s: f64,
    /// Seconds replayed from `start_s` on; `None` to the end.
    pub duration_s: Option<f64>,
    /// Also draw `report.html` into `out`.
    pub report: bool,
}

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("no recording given and the bundled {0} is missing: pass a recording (ladar-odometer replay FILE.mcap) or make one with `ladar-odometer simulate --scenario NAME --out FILE.mcap`")]
    NoBundledRecording(PathBuf),
    #[error(transparent)]
    Recording(#[from] RecordingError),
    #[error("recording {path}: the mounts its /tf_static gives cannot be used: {errors}")]
    TfStaticMounts { path: PathBuf, errors: String },
    #[error("recording {path} carries a configuration that no longer loads: {errors}")]
    Config { path: PathBuf, errors: String },
    #[error("{0}")]
    ConfigFile(String),
    #[error("recording {path} holds ROS messages ({topics}) and no ladar-odometer configuration: pass --config FILE whose [[scanner]] and [imu] tables name their topics, with the mounts (docs/ros-data.md)")]
    RosWithoutConfig { path: PathBuf, topics: String },
    #[error("recording {path} has no topic the configuration reads: it has {topics}; set `topic = \"/NAME\"` in the [[scanner]] and [imu] tables of the --config file to LaserScan, MultiEchoLaserScan and Imu topics among them (docs/ros-data.md)")]
    NoUsableTopic { path: PathBuf, topics: String },
    #[error("recording from an unknown sensor: {path} has bytes from `{sensor}`, which its configuration does not list (replay the file the recording came with, or fix its [[scanner]]/[imu] names)")]
    UnknownSensor { path: PathBuf, sensor: String },
    #[error("replay --tolerant kept nothing of {path}: {loss} before any complete sensor message; if the file is cut, try `mcap recover` (Foxglove's mcap CLI), else record it again")]
    NothingKept { path: PathBuf, loss: Loss },
    #[error("recording {path} holds no sensor bytes to replay (expected /<sensor>/rx channels as `run --record` and `simulate` write)")]
    Empty { path: PathBuf },
    #[error("{path}: no mount for the {sensor} on {topic}: {problem}; set rpy_deg and translation_m in its table (docs/ros-data.md, \"Mounts\")")]
    NoMount {
        path: PathBuf,
        sensor: MountOf,
        topic: String,
        problem: String,
    },
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error("{0}")]
    Mavlink(#[from] LinkError),
    #[error("cannot start the MAVLink runtime: {0}")]
    Runtime(std::io::Error),
    #[error("replay --report needs --out DIR to write report.html into")]
    ReportWithoutOut,
    #[error(transparent)]
    Report(#[from] ChartError),
}

#[derive(Debug, Clone, PartialEq)]
pub struct ReplaySummary {
    pub duration_s: f64,
    pub chunks: u64,
    pub bytes: u64,
    pub sensors: Vec<(String, DecodeCounts)>,
    /// What the outputs added up to: estimates, epochs, planes, detections, exclusions and how
    /// the epochs ended.
    pub outputs: Tally,
    pub truth: Option<TruthErrors>,
    pub autopilot: Option<AutopilotView>,
    pub loss: Option<Loss>,
}

impl fmt::Display for ReplaySummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "replayed {:.1} s: {} chunks, {} bytes",
            self.duration_s, self.chunks, self.bytes
        )?;
        for (name, c) in &self.sensors {
            writeln!(
                f,
                "  {name}: {} scans, {} IMU samples, {} decode errors, {} dropped (decoded but unusable: no scanner geometry yet, no time, or a field missing), {} lost packets, {} clock restarts",
                c.scans, c.imu_samples, c.decode_errors, c.dropped, c.lost_packets, c.clock_restarts
            )?;
        }
        let outputs = &self.outputs;
        let per_epoch = if outputs.epochs > 0 {
            outputs.planes as f64 / outputs.epochs as f64
        } else {
            0.0
        };
        writeln!(
            f,
            "  {} estimates, {} epochs, {per_epoch:.1} planes per epoch, {} detections, {} exclusions",
            outputs.estimates, outputs.epochs, outputs.detections, outputs.exclusions
        )?;
        writeln!(f, "  epochs: {}", outputs.outcomes)?;
        match &self.truth {
            Some(t) => {
                writeln!(
                    f,
                    "  against truth after the {:.0} s stationary start ({} estimates at {KEPT_ESTIMATE_HZ} Hz):",
                    t.from_s, t.samples
                )?;
                writeln!(
                    f,
                    "    velocity error NED  std {} m/s, RMS {} m/s",
                    triple(t.velocity_std_ned, 4),
                    triple(t.velocity_rms_ned, 4)
                )?;
                writeln!(
                    f,
                    "    attitude error RPY  std {} mrad, RMS {} mrad",
                    triple(t.attitude_std_mrad, 2),
                    triple(t.attitude_rms_mrad, 2)
                )?;
                let [north, east, _] = t.position_drift_end_m;
                writeln!(
                    f,
                    "    position drift      RMS {} m, at the end {} m ({:.2} m horizontally after {:.1} m travelled)",
                    triple(t.position_drift_rms_m, 3),
                    triple(t.position_drift_end_m, 3),
                    north.hypot(east),
                    t.distance_travelled_m
                )?;
            }
            None => writeln!(f, "  no truth to compare with")?,
        }
        if let Some(view) = &self.autopilot {
            write_autopilot_view(f, view)?;
        }
        if let Some(loss) = &self.loss {
            writeln!(f, "  warning: {loss}")?;
        }
        Ok(())
    }
}

fn write_autopilot_view(f: &mut fmt::Formatter<'_>, view: &AutopilotView) -> fmt::Result {
    let first = view.first_valid_after_s.map_or_else(
        || "never".to_string(),
        |s| format!("{s:.1} s after the start"),
    );
    writeln!(
        f,
        "  what the autopilot was told ({} of {} estimates valid, the first {first}, {} resets):",
        view.valid, view.estimates, view.resets
    )?;
    writeln!(
        f,
        "    body velocity inside 3 sigma {}, mean NEES {} (1 if honest), worst error {:.3} m/s",
        triple(view.inside_3_sigma, 3),
        triple(view.mean_nees, 2),
        view.worst_valid_error_mps
    )
}

/// The recording to replay: the given one, or the bundled one if it exists.
pub fn resolve_recording(given: Option<PathBuf>) -> Result<PathBuf, ReplayError> {
    match given {
        Some(path) => Ok(path),
        None => {
            let bundled = PathBuf::from(BUNDLED_RECORDING);
            if bundled.exists() {
                Ok(bundled)
            } else {
                Err(ReplayError::NoBundledRecording(bundled))
            }
        }
    }
}

/// Replays `options.recording` through an estimator built from its configuration (`None` for a
/// raw dump or a recording without one) and its sensors.
pub fn replay<E: Estimator>(
    options: &ReplayOptions,
    make_estimator: impl FnOnce(Option<&Config>, &[SensorSpec]) -> E,
) -> Result<(ReplaySummary, E), ReplayError> {
    let path = options.recording.as_path();
    if options.report && options.out.is_none() {
        return Err(ReplayError::ReportWithoutOut);
    }
    let mode = if options.tolerant {
        ReadMode::Tolerant
    } else {
        ReadMode::Strict
    };
    let mut reader = RecordingReader::open(path, mode)?;
    let config = match (&options.config, reader.config_toml()) {
        (Some(file), _) => {
            Some(Config::load(file).map_err(|e| ReplayError::ConfigFile(e.to_string()))?)
        }
        (None, Some(text)) => Some(Config::parse(text, path).map_err(|e| ReplayError::Config {
            path: path.to_path_buf(),
            errors: e.to_string(),
        })?),
        (None, None) => None,
    };
    let config = match config {
        Some(mut config) => {
            mounts_from_tf_static(path, mode, &mut config)?;
            Some(config)
        }
        None => None,
    };
    let topics = config.as_ref().map(sensor_topics).unwrap_or_default();
    let mut ros_read = false;
    let mut specs = match &config {
        Some(config) => sensor_specs(config),
        None => Vec::new(),
    };
    // Without a configuration the sensors are whatever the file holds, in order of appearance.
    let discover = config.is_none();
    let first = reader.next_message()?;
    if first.is_none() && !reader.ros_topics().is_empty() {
        return Err(no_usable_topic(path, config.is_some(), reader.ros_topics()));
    }
    if first.is_none() {
        let path = path.to_path_buf();
        return Err(match reader.loss().cloned() {
            Some(loss) => ReplayError::NothingKept { path, loss },
            None => ReplayError::Empty { path },
        });
    }
    if discover {
        if let Some(message) = first.as_ref().filter(|m| is_raw(m)) {
            specs.push(spec_for(message, 0));
        }
    }
    let first_s = first.as_ref().map_or(0.0, |m| m.log_time_ns as f64 * 1e-9);
    let until_s = options.duration_s.map(|d| first_s + options.start_s + d);
    // A scan's step 0 precedes the chunk that carries it: from the recording's start nothing may
    // be held back, or the first scan of a scanner goes missing whenever its step 0 came before
    // the first byte logged.
    let from_s = if options.start_s > 0.0 {
        first_s + options.start_s
    } else {
        f64::NEG_INFINITY
    };
    let estimator = FromTime {
        inner: make_estimator(config.as_ref(), &specs),
        from_s,
        tapped: options.out.is_some().then(Vec::new),
    };
    let mut receivers = Receivers::new(specs.iter().map(SensorSpec::encoding));
    let mut pipeline = Pipeline::new(specs, estimator);
    let mut sink = Sink::new(MavlinkOut::new(
        config.as_ref(),
        options.mavlink.as_deref(),
    )?);
    let mut outputs = options.out.as_deref().map(Outputs::create).transpose()?;
    tracing::info!(
        recording = %path.display(),
        format = ?reader.format(),
        configuration = match (&options.config, &config) {
            (Some(_), _) => "given",
            (None, Some(_)) => "recorded",
            (None, None) => "none, sensors from the file",
        },
        "replaying"
    );
    let progress = progress_bar(options.progress, reader.position().1);
    let scanners: Vec<_> = config.as_ref().map_or_else(Vec::new, |c| {
        c.scanners
            .iter()
            .map(|s| (s.name.clone(), s.mount()))
            .collect()
    });
    let mut tally = Kept {
        epoch_lines: options.report.then(Vec::new),
        foxglove: options
            .out
            .as_deref()
            .map(|dir| FoxgloveWriter::create(dir, &scanners))
            .transpose()?,
        ..Kept::default()
    };
    let started = Instant::now();
    // One list of readings for the whole replay: a new one per chunk was the replay's largest
    // allocation (an IMU event is a few hundred bytes, and a list starts with room for four).
    let mut spare_readings = Vec::new();
    let mut next = first;
    while let Some(message) = next {
        if until_s.is_some_and(|until| message.log_time_ns as f64 * 1e-9 > until) {
            break;
        }
        let sensor = match (pipeline.sensor_named(&message.sensor), is_raw(&message)) {
            // A ROS topic no sensor reads (a camera, a third scanner) is not replayed.
            (_, false) => match topics.get(&message.sensor) {
                Some(&sensor) => {
                    ros_read = true;
                    sensor
                }
                None => {
                    next = reader.next_message()?;
                    continue;
                }
            },
            (Some(sensor), true) => sensor,
            (None, true) if discover => {
                let index = pipeline.specs().len();
                receivers.add(message.encoding);
                pipeline = pipeline.with_sensor(spec_for(&message, index));
                index
            }
            (None, true) => {
                return Err(ReplayError::UnknownSensor {
                    path: path.to_path_buf(),
                    sensor: message.sensor,
                })
            }
        };
        receivers.speaks(sensor, message.encoding);
        if options.realtime {
            tally.pace(message.log_time_ns, started);
        }
        tally.chunk(&message);
        tracing::trace!(
            sensor = %message.sensor,
            direction = message.direction.as_str(),
            log_time_ns = message.log_time_ns,
            bytes = message.data.len(),
            "chunk"
        );
        let mut chunk = Chunk {
            sensor,
            direction: message.direction,
            log_time_ns: message.log_time_ns,
            data: message.data,
            readings: std::mem::take(&mut spare_readings),
        };
        receivers.decode(&mut chunk);
        let mut failure = None;
        pipeline.push(&chunk, |output| {
            let routed = tally.output::<E>(&output, chunk.log_time_ns, outputs.as_mut(), &mut sink);
            if let Err(e) = routed {
                failure.get_or_insert(e);
            }
        });
        if let Some(e) = failure {
            return Err(e);
        }
        spare_readings = chunk.readings;
        spare_readings.clear();
        tally.tapped(pipeline.estimator_mut().drain_tapped())?;
        progress.set_position(reader.position().0);
        next = reader.next_message()?;
    }
    progress.finish_and_clear();
    if !ros_read && !reader.ros_topics().is_empty() {
        return Err(no_usable_topic(path, config.is_some(), reader.ros_topics()));
    }
    if let Some(outputs) = outputs {
        outputs.finish()?;
    }
    if let Some(foxglove) = tally.foxglove.take() {
        foxglove.finish()?;
    }
    let truth = reader.take_truth();
    if let (Some(dir), false) = (&options.out, truth.is_empty()) {
        write_truth(dir, &truth)?;
    }
    let stationary_start_s = config
        .as_ref()
        .map(Config::fusion_settings)
        .unwrap_or_default()
        .filter
        .stationary_start_s;
    // A start anywhere but the beginning has its own origin and north: only body axes compare.
    let ned_truth = if options.start_s > 0.0 {
        None
    } else {
        truth_errors(&tally.kept, &truth, stationary_start_s)
    };
    let (mavlink, routed) = sink.into_parts();
    let policy = mavlink.stream.policy();
    let summary = ReplaySummary {
        duration_s: tally.duration_s(),
        chunks: tally.chunks,
        bytes: tally.bytes,
        sensors: pipeline
            .specs()
            .iter()
            .map(|s| s.name().to_string())
            .zip(pipeline.decode_counts())
            .collect(),
        outputs: routed,
        truth: ned_truth,
        autopilot: autopilot_view(&tally.kept, &truth, &policy),
        loss: reader.loss().cloned(),
    };
    if let (true, Some(dir)) = (options.report, &options.out) {
        let report = RunReport {
            title: &path.display().to_string(),
            estimates: &tally.kept,
            truth: &truth,
            epochs: tally.epoch_lines.as_deref().unwrap_or_default(),
            policy: &policy,
            summary: &summary,
            shares_truth_frame: options.start_s == 0.0,
        };
        write_report(&dir.join(REPORT_FILE), &report.render()?)?;
    }
    Ok((summary, pipeline.into_estimator().inner))
}

fn write_report(path: &std::path::Path, html: &str) -> Result<(), ReplayError> {
    std::fs::write(path, html).map_err(|source| {
        ReplayError::Output(OutputError::Write {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// Holds back the IMU samples and scans before `from_s` (host time), so that a replay can
/// start anywhere in a recording: the decoders still see every byte, the fusion only what comes
/// after, as a daemon started at that moment would.
struct FromTime<E> {
    inner: E,
    from_s: f64,
    /// Scans and geometries seen, for `estimate.mcap`, when it is written.
    tapped: Option<Vec<Tapped>>,
}

/// What the fusion was given that `estimate.mcap` draws too.
enum Tapped {
    Geometry(usize, ScannerGeometry),
    Scan(Scan),
}

impl<E> FromTime<E> {
    fn drain_tapped(&mut self) -> Vec<Tapped> {
        self.tapped.as_mut().map(std::mem::take).unwrap_or_default()
    }
}

impl<E: Estimator> Estimator for FromTime<E> {
    type Epoch = E::Epoch;

    fn geometry(&mut self, scanner: usize, geometry: ScannerGeometry) {
        if let Some(tapped) = &mut self.tapped {
            tapped.push(Tapped::Geometry(scanner, geometry));
        }
        self.inner.geometry(scanner, geometry);
    }

    fn imu(&mut self, sample: ImuSample) -> Option<Estimate> {
        (sample.time() >= self.from_s)
            .then(|| self.inner.imu(sample))
            .flatten()
    }

    fn scan(&mut self, scan: Scan) -> Option<Self::Epoch> {
        if scan.t0 < self.from_s {
            return None;
        }
        if let Some(tapped) = &mut self.tapped {
            tapped.push(Tapped::Scan(scan.clone()));
        }
        self.inner.scan(scan)
    }

    fn epoch_estimate(&self) -> Option<Estimate> {
        self.inner.epoch_estimate()
    }

    fn sensor_stale(&mut self, sensor: usize, stale: bool, t: f64) {
        self.inner.sensor_stale(sensor, stale, t);
    }

    fn epoch_counts(epoch: &Self::Epoch) -> EpochCounts {
        E::epoch_counts(epoch)
    }
}

/// Sets the mounts `config` leaves to `/tf_static` from the recording's static transforms, as
/// the chain from `[ros] body_frame` to the frame of each sensor's first message.
///
/// A first pass over the whole file, before the replay: the fusion needs each mount from the
/// first scan on, and although recorders write `/tf_static` near the start (it is latched),
/// nothing orders it before the scans, e.g. when the recording starts before the node that
/// publishes it. The pass costs one more read of the file, and only when a mount is left out.
fn mounts_from_tf_static(
    path: &std::path::Path,
    mode: ReadMode,
    config: &mut Config,
) -> Result<(), ReplayError> {
    let missing = config.missing_mounts();
    let Some(body_frame) = config
        .ros
        .body_frame
        .clone()
        .filter(|_| !missing.is_empty())
    else {
        return Ok(());
    };
    let mut frames: HashMap<&str, String> = HashMap::new();
    let mut reader = RecordingReader::open(path, mode)?;
    while let Some(message) = reader.next_message()? {
        let Encoding::Ros(kind, encoding) = message.encoding else {
            continue;
        };
        if frames.contains_key(message.sensor.as_str()) {
            continue;
        }
        let Some((_, topic)) = missing.iter().find(|(_, topic)| *topic == message.sensor) else {
            continue;
        };
        let frame = match rosmsg::decode(kind, encoding, &message.data) {
            Ok(rosmsg::Message::LaserScan(m)) => m.header.frame_id,
            Ok(rosmsg::Message::MultiEchoLaserScan(m)) => m.header.frame_id,
            Ok(rosmsg::Message::Imu(m)) => m.header.frame_id,
            // The replay counts it as the decode error it is; a later message names the frame.
            Ok(rosmsg::Message::Tf(_)) | Err(_) => continue,
        };
        frames.insert(topic, frame);
    }
    for (sensor, topic) in &missing {
        let no_mount = |problem: String| ReplayError::NoMount {
            path: path.to_path_buf(),
            sensor: *sensor,
            topic: topic.clone(),
            problem,
        };
        let frame = frames.get(topic.as_str()).ok_or_else(|| {
            no_mount("the recording has no message on it to name its frame".into())
        })?;
        let mount = ros::mount_from_tf(&body_frame, frame, reader.tf_static()).map_err(no_mount)?;
        tracing::info!(%sensor, %topic, %frame, ?mount, "mount from /tf_static");
        config.set_mount(*sensor, &mount);
    }
    config
        .check_scan_planes_apart()
        .map_err(|errors| ReplayError::TfStaticMounts {
            path: path.to_path_buf(),
            errors: errors.to_string(),
        })
}

/// Whether a message holds a device's bytes, rather than a ROS message.
fn is_raw(message: &RecordedMessage) -> bool {
    !matches!(message.encoding, Encoding::Ros(..))
}

/// The sensor a raw-byte message found in a recording without a configuration comes from. ROS
/// topics become sensors only through a configuration: their messages carry no mount.
fn spec_for(message: &RecordedMessage, index: usize) -> SensorSpec {
    let name = message.sensor.clone();
    if message.encoding == Encoding::Xbus {
        SensorSpec::Imu {
            name,
            sample_time_modulus: xbus::U32_TICKS,
            rate_hz: 100.0,
        }
    } else {
        SensorSpec::Scanner { name, index }
    }
}

/// The configured sensors' ROS topics, each with its sensor number.
fn sensor_topics(config: &Config) -> HashMap<String, usize> {
    let topic = |sensor| match sensor {
        Configured::Scanner(scanner) => scanner.topic.clone(),
        Configured::Imu(imu) => imu.topic.clone(),
    };
    configured_sensors(config)
        .enumerate()
        .filter_map(|(number, sensor)| Some((topic(sensor)?, number)))
        .collect()
}

fn no_usable_topic(
    path: &std::path::Path,
    configured: bool,
    topics: &BTreeMap<String, String>,
) -> ReplayError {
    let path = path.to_path_buf();
    let topics = topics
        .iter()
        .map(|(topic, schema)| format!("{topic} ({schema})"))
        .collect::<Vec<_>>()
        .join(", ");
    if configured {
        ReplayError::NoUsableTopic { path, topics }
    } else {
        ReplayError::RosWithoutConfig { path, topics }
    }
}

fn progress_bar(wanted: bool, length: u64) -> indicatif::ProgressBar {
    if !wanted {
        return indicatif::ProgressBar::hidden();
    }
    // The default draw target is stderr and draws nothing unless it is a terminal.
    let bar = indicatif::ProgressBar::new(length);
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{bar:40} {bytes}/{total_bytes} {elapsed_precise} eta {eta}",
    ) {
        bar.set_style(style);
    }
    bar
}

/// Estimates kept for the truth comparison: at most this rate, so memory stays small.
const KEPT_ESTIMATE_HZ: f64 = 20.0;

/// What a replay keeps beside the outputs every run writes: the byte counts, the estimates for
/// the truth comparison, and what the report and `estimate.mcap` draw.
#[derive(Default)]
struct Kept {
    chunks: u64,
    bytes: u64,
    first_ns: Option<u64>,
    last_ns: u64,
    kept: Vec<Estimate>,
    /// The epochs as `epochs.jsonl` holds them, when a report will be drawn.
    epoch_lines: Option<Vec<serde_json::Value>>,
    foxglove: Option<FoxgloveWriter>,
}

impl Kept {
    fn chunk(&mut self, message: &RecordedMessage) {
        self.chunks += 1;
        self.bytes += message.data.len() as u64;
        if message.log_time_ns != 0 {
            self.first_ns.get_or_insert(message.log_time_ns);
            self.last_ns = self.last_ns.max(message.log_time_ns);
        }
    }

    fn duration_s(&self) -> f64 {
        self.first_ns
            .map_or(0.0, |first| (self.last_ns - first) as f64 * 1e-9)
    }

    /// Draws the scans and geometries the fusion was given into `estimate.mcap`.
    fn tapped(&mut self, tapped: Vec<Tapped>) -> Result<(), OutputError> {
        let Some(foxglove) = &mut self.foxglove else {
            return Ok(());
        };
        for event in tapped {
            match event {
                Tapped::Geometry(scanner, geometry) => foxglove.geometry(scanner, geometry),
                Tapped::Scan(scan) => foxglove.scan(&scan)?,
            }
        }
        Ok(())
    }

    fn pace(&self, log_time_ns: u64, started: Instant) {
        let Some(first) = self.first_ns else {
            return;
        };
        let due = Duration::from_nanos(log_time_ns.saturating_sub(first));
        if let Some(wait) = due.checked_sub(started.elapsed()) {
            std::thread::sleep(wait);
        }
    }

    /// Keeps and draws what the replay needs of `output`, then routes it as `run` does.
    fn output<E: Estimator>(
        &mut self,
        output: &Output<E::Epoch>,
        read_ns: u64,
        outputs: Option<&mut Outputs>,
        sink: &mut Sink<MavlinkOut>,
    ) -> Result<(), ReplayError> {
        match output {
            Output::Estimate(estimate) => self.keep(estimate)?,
            Output::Epoch(epoch) => self.draw(epoch)?,
            Output::EpochEstimate(_) => {}
        }
        sink.output::<E>(output, read_ns, outputs)
    }

    fn keep(&mut self, estimate: &Estimate) -> Result<(), OutputError> {
        if self
            .kept
            .last()
            .is_none_or(|last| estimate.t - last.t >= 1.0 / KEPT_ESTIMATE_HZ)
        {
            self.kept.push(estimate.clone());
            if let Some(foxglove) = &mut self.foxglove {
                foxglove.estimate(estimate)?;
            }
        }
        Ok(())
    }

    fn draw<T: Serialize>(&mut self, epoch: &T) -> Result<(), OutputError> {
        let drawn = self.epoch_lines.is_some() || self.foxglove.is_some();
        let line = drawn
            .then(|| serde_json::to_value(epoch))
            .transpose()
            .map_err(|source| OutputError::Serialise {
                path: REPORT_FILE.into(),
                source,
            })?;
        if let (Some(foxglove), Some(line)) = (&mut self.foxglove, &line) {
            foxglove.epoch(line)?;
        }
        if let (Some(lines), Some(line)) = (&mut self.epoch_lines, line) {
            lines.push(line);
        }
        Ok(())
    }
}

/// The MAVLink stream of a replay: frames to `mavlink.tlog` (stamped with the estimate time)
/// and, with `--mavlink`, to a live link.
struct MavlinkOut {
    stream: MavlinkStream,
    identity: Identity,
    sequence: u8,
    link: Option<(tokio::runtime::Runtime, Link)>,
}

impl MavlinkOut {
    fn new(config: Option<&Config>, address: Option<&str>) -> Result<Self, ReplayError> {
        let section = config.and_then(|c| c.mavlink.as_ref());
        let (profile, rate_hz) = section
            .map_or((Profile::Px4, Profile::Px4.default_rate_hz()), |m| {
                (m.profile, m.rate_hz())
            });
        let identity = section.map_or(
            Identity {
                system_id: 1,
                component_id: DEFAULT_COMPONENT_ID,
            },
            |m| m.identity(),
        );
        let link = match address {
            None => None,
            Some(text) => {
                let address: LinkAddress = text.parse()?;
                let runtime = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                    .map_err(ReplayError::Runtime)?;
                let link = runtime.block_on(Link::connect(&address, identity, None))?;
                Some((runtime, link))
            }
        };
        Ok(Self {
            stream: MavlinkStream::new(profile, rate_hz, QualityPolicy::default()),
            identity,
            sequence: 0,
            link,
        })
    }

    /// Sends `message`, if any, and logs it in `mavlink.tlog` at estimate time `t`.
    fn send(
        &mut self,
        message: Option<MavMessage>,
        t: f64,
        outputs: Option<&mut Outputs>,
    ) -> Result<(), ReplayError> {
        let Some(message) = message else {
            return Ok(());
        };
        let frame = match &self.link {
            Some((runtime, link)) => runtime.block_on(link.send(&message))?,
            None => Some(self.serialise(&message)),
        };
        if let (Some(frame), Some(outputs)) = (frame, outputs) {
            outputs.mavlink((t * 1e6).max(0.0) as u64, &frame)?;
        }
        Ok(())
    }

    fn serialise(&mut self, message: &MavMessage) -> Vec<u8> {
        let header = mavlink::MavHeader {
            sequence: self.sequence,
            ..self.identity.header()
        };
        self.sequence = self.sequence.wrapping_add(1);
        let mut raw = MAVLinkV2MessageRaw::new();
        raw.serialize_message(header, message);
        raw.raw_bytes().to_vec()
    }
}

/// The replay decides the HEARTBEAT on estimate time too, so `mavlink.tlog` carries the whole
/// stream, each frame stamped with the estimate it followed.
impl Autopilot for MavlinkOut {
    type Error = ReplayError;

    fn estimate(
        &mut self,
        estimate: &Estimate,
        mut outputs: Option<&mut Outputs>,
    ) -> Result<(), ReplayError> {
        let heartbeat = self.stream.heartbeat_due(estimate.t);
        self.send(heartbeat, estimate.t, outputs.as_deref_mut())?;
        let message = self.stream.on_estimate(estimate.t, estimate);
        self.send(message, estimate.t, outputs.as_deref_mut())?;
        let text = self.stream.take_statustext();
        self.send(text, estimate.t, outputs)
    }

    fn epoch_estimate(
        &mut self,
        estimate: &Estimate,
        _: u64,
        mut outputs: Option<&mut Outputs>,
    ) -> Result<(), ReplayError> {
        let message = self.stream.on_epoch_estimate(estimate);
        self.send(message, estimate.t, outputs.as_deref_mut())?;
        let text = self.stream.take_statustext();
        self.send(text, estimate.t, outputs)
    }
}
