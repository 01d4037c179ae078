//! `run`: the live daemon. Sensor tasks feed one chunk queue; the fusion thread records each
//! chunk, decodes it, drives the estimator through the same [`Pipeline`] as replay and decides
//! the MAVLink messages as replay does; the MAVLink task sends them; the watchdog follows the
//! fusion loop. Cancelling the
//! token (SIGINT/SIGTERM in `main`) stops the sensors, drains the queue and finishes the
//! recording.

use super::chunk_queue::{ChunkQueue, Popped, QUEUE_CHUNKS};
use super::config::{
    Config, ConfigErrors, ImuConfig, ImuOutput, ImuSeries, ScanStream, ScannerConfig,
};
use super::health::Health;
use super::latency::{LatencyLog, LatencySummary};
use super::link::{Link, LinkError};
use super::mavlink_out::{MavlinkStream, QualityPolicy};
use super::mavlink_task::{Feed, Outgoing, SharedState, QUEUE_MESSAGES};
use super::outcomes::OutcomeCounts;
use super::outputs::{OutputError, Outputs};
use super::pipeline::{
    configured_sensors, sensor_specs, Configured, Estimator, Output, Pipeline, SensorSpec,
};
use super::readings::DecodeCounts;
use super::recorder_thread::{self, RecorderHandle, RecorderSummary, Tap};
use super::recording::{Recorder, RecordingError};
use super::sensor_task::{self, Driver, HostClock, SensorLink};
use super::sink::Sink;
use super::{mavlink_task, watchdog};
use mavlink::dialects::ardupilotmega::MavState;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    pub config: PathBuf,
    /// Record to this file instead of the configuration's `[recording] path`.
    pub record: Option<PathBuf>,
    /// Write the output files here instead of the configuration's `[output] dir`.
    pub out: Option<PathBuf>,
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("{0}")]
    Config(#[from] ConfigErrors),
    #[error("{0}")]
    Port(String),
    #[error("the {0} leaves its mount to /tf_static, which only a replay of ROS data has: set its rpy_deg and translation_m to run")]
    MountFromTfStatic(super::config::MountOf),
    #[error(transparent)]
    Recording(#[from] RecordingError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error(transparent)]
    Mavlink(#[from] LinkError),
    #[error("MAVLink signing: {0}")]
    Signing(String),
    #[error("the fusion loop stopped unexpectedly: {0}")]
    Fusion(String),
}

/// What a run did, once it has shut down.
#[derive(Debug)]
pub struct RunReport<E> {
    pub estimator: E,
    pub chunks: u64,
    /// From reading a scan's last byte to the write of the first MAVLink message carrying its
    /// epoch (None without MAVLink or before the first epoch).
    pub latency: Option<LatencySummary>,
    /// From reading a scan's last byte to its epoch fused and its outputs handed on.
    pub fused_latency: Option<LatencySummary>,
    /// MAVLink messages dropped because the link did not keep up.
    pub mavlink_dropped: u64,
    /// Chunks the fusion never saw because it fell behind.
    pub dropped_chunks: u64,
    /// Chunks the recorder could not keep up with.
    pub unrecorded_chunks: u64,
    pub recording: Option<(PathBuf, RecorderSummary)>,
    pub sensors: Vec<(String, DecodeCounts)>,
    /// How the epochs ended.
    pub outcomes: OutcomeCounts,
}

/// Runs until `cancel`, then shuts down in order and reports.
pub async fn run<E>(
    options: RunOptions,
    make_estimator: impl FnOnce(&Config, &[SensorSpec]) -> E,
    cancel: CancellationToken,
) -> Result<RunReport<E>, RunError>
where
    E: Estimator + Send + 'static,
    E::Epoch: Send,
{
    let (config, config_text) = Config::load_with_text(&options.config)?;
    // A live run has no /tf_static: every mount must be in the file.
    if let Some((sensor, _)) = config.missing_mounts().first() {
        return Err(RunError::MountFromTfStatic(*sensor));
    }
    let specs = sensor_specs(&config);
    let links = sensor_links(&config);
    sensor_task::wait_for_ports(&links, sensor_task::DEVICE_WAIT, &cancel)
        .await
        .map_err(RunError::Port)?;
    let recording = recording_path(&config, options.record.clone());
    let recorder = match &recording {
        Some(path) => {
            let recorder = Recorder::create(path, &config_text)?;
            let flush = Duration::from_secs_f64(config.recording.flush_interval_s);
            Some(recorder_thread::spawn(recorder, flush))
        }
        None => None,
    };
    let out_dir = options.out.clone().or_else(|| config.output.dir.clone());
    let outputs = Arc::new(Mutex::new(
        out_dir.as_deref().map(Outputs::create).transpose()?,
    ));
    let clock = HostClock::start();
    let queue = Arc::new(ChunkQueue::new(QUEUE_CHUNKS));
    let tracker = TaskTracker::new();
    let tasks_cancel = cancel.child_token();
    let mavlink_latency = Arc::new(Mutex::new(LatencyLog::new("scan-to-MAVLink")));
    let system_state: SharedState = Arc::new(Mutex::new(MavState::MAV_STATE_CALIBRATING));
    let feed = match &config.mavlink {
        Some(section) => {
            let signing = section.signing().map_err(RunError::Signing)?;
            let address = section.address();
            let link = Arc::new(Link::connect(&address, section.identity(), signing).await?);
            let (messages, messages_rx) = mpsc::channel(QUEUE_MESSAGES);
            let shared = MavlinkShared {
                outputs: outputs.clone(),
                latency: mavlink_latency.clone(),
                state: system_state.clone(),
            };
            spawn_mavlink(
                &tracker,
                link,
                messages_rx,
                shared,
                clock,
                tasks_cancel.clone(),
            );
            let stream =
                MavlinkStream::new(section.profile, section.rate_hz(), QualityPolicy::default());
            Some(Feed::new(stream, messages, system_state.clone()))
        }
        None => None,
    };
    let streaming: Vec<Arc<AtomicBool>> = links.iter().map(|_| Arc::default()).collect();
    for (link, flag) in links.into_iter().zip(&streaming) {
        tracker.spawn(sensor_task::run(
            link,
            queue.clone(),
            clock,
            flag.clone(),
            tasks_cancel.clone(),
        ));
    }
    let progress = watchdog::Progress::default();
    tracker.spawn(watchdog::run(progress.clone(), tasks_cancel.clone()));
    let estimator = make_estimator(&config, &specs);
    let fusion = {
        let pipeline = Pipeline::new(specs, estimator);
        let queue = queue.clone();
        let handle = recorder.as_ref().map(|(handle, _)| handle.clone());
        let outputs = outputs.clone();
        std::thread::Builder::new()
            .name("fusion".into())
            .spawn(move || fusion_loop(pipeline, &queue, handle, &outputs, feed, &progress, clock))
            .map_err(|e| RunError::Fusion(e.to_string()))?
    };
    let unrecorded = recorder.as_ref().map(|(handle, _)| handle.clone());
    tokio::select! {
        () = cancel.cancelled() => {}
        () = wait_streaming(&streaming) => {
            tracing::info!(sensors = streaming.len(), "all sensors streaming");
            watchdog::ready("all sensors streaming").await;
            cancel.cancelled().await;
        }
    }
    tracing::info!("shutting down");
    watchdog::stopping().await;
    tasks_cancel.cancel();
    tracker.close();
    tracker.wait().await;
    queue.close();
    let fused = tokio::task::spawn_blocking(move || fusion.join())
        .await
        .map_err(|e| RunError::Fusion(e.to_string()))?
        .map_err(|_| RunError::Fusion("the fusion thread panicked".into()))?;
    let unrecorded_chunks = unrecorded.as_ref().map_or(0, RecorderHandle::dropped);
    drop(unrecorded);
    let recording = match (recording, recorder) {
        (Some(path), Some((handle, thread))) => {
            // The thread finishes the file once the last handle is gone.
            drop(handle);
            let summary = tokio::task::spawn_blocking(move || thread.join())
                .await
                .map_err(|e| RunError::Fusion(e.to_string()))?
                .map_err(|_| RunError::Fusion("the recorder thread panicked".into()))??;
            tracing::info!(path = %path.display(), chunks = summary.chunks, "recording finished");
            Some((path, summary))
        }
        _ => None,
    };
    if let Some(outputs) = outputs
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .take()
    {
        outputs.finish()?;
    }
    let latency = mavlink_latency
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .summary();
    Ok(RunReport {
        sensors: fused
            .pipeline
            .specs()
            .iter()
            .map(|s| s.name().to_string())
            .zip(fused.pipeline.decode_counts())
            .collect(),
        estimator: fused.pipeline.into_estimator(),
        outcomes: fused.sink.tally().outcomes.clone(),
        chunks: fused.chunks,
        latency,
        fused_latency: fused.latency.summary(),
        mavlink_dropped: fused.sink.autopilot().as_ref().map_or(0, Feed::dropped),
        dropped_chunks: queue.dropped(),
        unrecorded_chunks,
        recording,
    })
}

/// How to reach each sensor, numbered as [`sensor_specs`] numbers them.
pub(crate) fn sensor_links(config: &Config) -> Vec<SensorLink> {
    configured_sensors(config)
        .enumerate()
        .map(|(index, sensor)| match sensor {
            Configured::Scanner(scanner) => SensorLink {
                index,
                name: scanner.name.clone(),
                connection: scanner.connection(),
                driver: Driver::Scip(scanner_driver(scanner)),
            },
            Configured::Imu(imu) => SensorLink {
                index,
                name: imu.name.clone(),
                connection: imu.connection(),
                driver: Driver::Xbus(imu_driver(imu)),
            },
        })
        .collect()
}

fn scanner_driver(scanner: &ScannerConfig) -> scip::DeviceConfig {
    let steps = scanner
        .first_step
        .zip(scanner.last_step)
        .map(|(first, last)| {
            (
                u16::try_from(first).unwrap_or(u16::MAX),
                u16::try_from(last).unwrap_or(u16::MAX),
            )
        });
    scip::DeviceConfig {
        data: match scanner.stream {
            ScanStream::Md => scip::DataKind::Distance,
            ScanStream::Me => scip::DataKind::DistanceIntensity,
        },
        steps,
        cluster: u8::try_from(scanner.cluster).unwrap_or(u8::MAX),
        ..scip::DeviceConfig::default()
    }
}

fn imu_driver(imu: &ImuConfig) -> xbus::DeviceConfig {
    xbus::DeviceConfig {
        imu_output: match imu.output {
            ImuOutput::Rate => xbus::ImuOutput::Rates,
            ImuOutput::Delta => xbus::ImuOutput::Increments,
        },
        rate_hz: u16::try_from(imu.rate_hz).unwrap_or(u16::MAX),
        sample_time_wrap: match imu.series {
            ImuSeries::Auto => xbus::SampleTimeWrap::FromProductCode,
            ImuSeries::Mti100 => xbus::SampleTimeWrap::Ticks(xbus::ONE_DAY_TICKS),
            ImuSeries::Mti600 => xbus::SampleTimeWrap::Ticks(xbus::U32_TICKS),
        },
        ..xbus::DeviceConfig::default()
    }
}

/// `--record FILE`, else a new file named after the start time in `[recording] path`.
fn recording_path(config: &Config, record: Option<PathBuf>) -> Option<PathBuf> {
    record.or_else(|| {
        let seconds = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        config
            .recording
            .directory()
            .map(|dir| dir.join(format!("ladar-odometer-{seconds}.mcap")))
    })
}

async fn wait_streaming(flags: &[Arc<AtomicBool>]) {
    let mut poll = tokio::time::interval(Duration::from_millis(50));
    while !flags.iter().all(|f| f.load(Ordering::Relaxed)) {
        poll.tick().await;
    }
}

/// What the MAVLink task shares with the rest of the daemon.
struct MavlinkShared {
    /// `mavlink.tlog` goes here.
    outputs: Arc<Mutex<Option<Outputs>>>,
    latency: Arc<Mutex<LatencyLog>>,
    /// The HEARTBEAT state the fusion decides.
    state: SharedState,
}

fn spawn_mavlink(
    tracker: &TaskTracker,
    link: Arc<Link>,
    messages: mpsc::Receiver<Outgoing>,
    shared: MavlinkShared,
    clock: HostClock,
    cancel: CancellationToken,
) {
    let MavlinkShared {
        outputs,
        latency,
        state,
    } = shared;
    let tlog = move |frame: &[u8]| {
        let wall_us = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        let mut outputs = outputs.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(out) = outputs.as_mut() {
            if let Err(e) = out.mavlink(wall_us, frame) {
                tracing::error!("{e}; output files stop here");
                *outputs = None;
            }
        }
    };
    let receiver = {
        let (link, cancel, tlog) = (link.clone(), cancel.clone(), tlog.clone());
        async move {
            let now_ns = move || clock.now_ns() as i64;
            if let Err(e) = link.receive_loop(now_ns, tlog, cancel).await {
                tracing::warn!("{e}");
            }
        }
    };
    tracker.spawn(receiver);
    tracker.spawn(async move {
        let now_ns = move || clock.now_ns();
        let sent = mavlink_task::run(&link, messages, now_ns, tlog, &latency, &state, cancel).await;
        if let Err(e) = sent {
            tracing::error!("{e}; MAVLink output stopped");
        }
    });
}

struct Fused<E: Estimator> {
    pipeline: Pipeline<E>,
    chunks: u64,
    latency: LatencyLog,
    sink: Sink<Option<Feed>>,
}

/// The fusion thread: consumption order is recording order is replay order.
fn fusion_loop<E: Estimator>(
    mut pipeline: Pipeline<E>,
    queue: &ChunkQueue,
    recorder: Option<RecorderHandle>,
    outputs: &Mutex<Option<Outputs>>,
    feed: Option<Feed>,
    progress: &watchdog::Progress,
    clock: HostClock,
) -> Fused<E> {
    let names: Vec<(Arc<str>, _)> = pipeline
        .specs()
        .iter()
        .map(|s| (Arc::from(s.name()), s.encoding()))
        .collect();
    let mut chunks = 0;
    let mut latency = LatencyLog::new("scan-to-fused");
    let mut health = Health::new(names.iter().map(|(name, _)| name.to_string()).collect());
    let mut sink = Sink::new(feed);
    loop {
        progress.advance();
        let chunk = match queue.pop(Duration::from_millis(100)) {
            Popped::Chunk(chunk) => chunk,
            Popped::Idle => continue,
            Popped::Closed => break,
        };
        chunks += 1;
        let mut closed_epoch = false;
        let mut newest = None;
        let now_s = chunk.log_time_ns as f64 * 1e-9;
        pipeline.push(&chunk, |output| {
            match &output {
                Output::Epoch(_) => closed_epoch = true,
                Output::Estimate(estimate) => newest = Some(estimate.clone()),
                Output::EpochEstimate(_) => {}
            }
            let mut files = outputs.lock().unwrap_or_else(PoisonError::into_inner);
            if let Err(e) = sink.output::<E>(&output, chunk.log_time_ns, files.as_mut()) {
                tracing::error!("{e}; output files stop here");
                *files = None;
            }
        });
        let stale: Vec<bool> = (0..names.len()).map(|k| pipeline.is_stale(k)).collect();
        if let Some(line) = health.observe(newest.as_ref(), &stale, now_s) {
            watchdog::status(&line);
        }
        if closed_epoch {
            latency.add(chunk.log_time_ns, clock.now_ns());
        }
        if let Some(recorder) = &recorder {
            let (sensor, encoding) = names[chunk.sensor].clone();
            recorder.record(Tap {
                sensor,
                encoding,
                direction: chunk.direction,
                log_time_ns: chunk.log_time_ns,
                data: chunk.data,
            });
        }
    }
    Fused {
        pipeline,
        chunks,
        latency,
        sink,
    }
}
