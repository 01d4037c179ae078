//! Sans-IO device state machine following urg_library's connection sequence (docs/protocols.md, 1.9
//! "Start-up sequence"): probe with QT (recovering from SCIP 1.1, TM adjust mode or a running
//! stream), read VV and PP, sample the sensor clock with TM0/TM1/TM2, switch the laser on with BM,
//! then stream MD/ME.
//!
//! The caller moves bytes and time: `handle_input(now, bytes)`, `poll_transmit(now)`,
//! `poll_event()`, `poll_timeout()` / `handle_timeout(now)`. `now` is host monotonic seconds.

use std::collections::VecDeque;
use std::fmt;

use crate::command::{Command, DataKind, StepRange, TimeMode};
use crate::decoder::{Body, DecodeError, Decoder, Reply, ScanData, Status};
use crate::params::{ParameterError, Parameters, Version};
use crate::timestamp::TimestampUnwrapper;

/// What the device is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    Idle,
    Probing,
    SwitchingProtocol,
    LeavingTimeMode,
    ReadingVersion,
    ReadingParameters,
    EnteringClockMode,
    SamplingClock,
    LeavingClockMode,
    SwitchingLaserOn,
    StartingStream,
    Streaming,
    Stopping,
    Stopped,
    Failed,
}

/// Stream settings and patience.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceConfig {
    /// `Distance` streams MD, `DistanceIntensity` ME, `ShortDistance` MS.
    pub data: DataKind,
    /// First and last step; `None` streams PP's AMIN..=AMAX.
    pub steps: Option<(u16, u16)>,
    pub cluster: u8,
    /// Scans skipped between transmitted scans (0..=9).
    pub interval: u8,
    /// Scans to stream (1..=99), or 0 for unlimited until `stop`.
    pub scan_count: u8,
    /// TM1 round trips taken at start-up for clock alignment (0 skips TM entirely).
    pub clock_samples: u8,
    /// Seconds to wait for a command's reply.
    pub reply_timeout: f64,
    /// Seconds without a scan before the stream is declared stalled and restarted.
    pub stream_timeout: f64,
    /// QT probes sent before giving up on a silent sensor.
    pub probe_attempts: u8,
}

impl Default for DeviceConfig {
    fn default() -> Self {
        DeviceConfig {
            data: DataKind::Distance,
            steps: None,
            cluster: 1,
            interval: 0,
            scan_count: 0,
            clock_samples: 5,
            reply_timeout: 1.0,
            stream_timeout: 1.0,
            probe_attempts: 3,
        }
    }
}

/// Unusual sensor states found (and repaired) while probing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Detection {
    /// Answered in SCIP 1.1; `SCIP2.0` was sent.
    Scip11,
    /// Was in TM adjust mode; `TM2` was sent.
    TimeAdjustMode,
    /// Was already streaming; QT stops it.
    StreamRunning,
}

/// One TM1 round trip: host send and receive times bracket the sensor's counter reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockSample {
    pub host_send: f64,
    pub host_receive: f64,
    pub sensor_ms: u32,
    /// `sensor_ms` on the same unwrapped scale as [`Scan::timestamp_ms`].
    pub sensor_ms_unwrapped: u64,
}

/// One streamed scan. Hand it back with [`Device::recycle`] to reuse its buffers.
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    /// Sensor time of step 0 of this revolution, unwrapped, ms; step k was measured
    /// `k * 60 / (SCAN * ARES)` s later (docs/protocols.md, 1.7 "Timestamps").
    pub timestamp_ms: u64,
    pub raw_timestamp: u32,
    /// Host time when the reply's last byte arrived.
    pub host_receive: f64,
    pub data: DataKind,
    pub range: StepRange,
    /// Scans still to come for a finite stream (0 for unlimited).
    pub remaining: u8,
    pub ranges_mm: Vec<u32>,
    /// Empty unless `data` is `DistanceIntensity`.
    pub intensities: Vec<u32>,
}

/// Failures the device reports.
#[derive(Debug, Clone, PartialEq)]
pub enum DeviceError {
    /// No reply within `reply_timeout` while in `phase`.
    Timeout {
        phase: Phase,
    },
    /// A command was refused.
    Status {
        command: &'static str,
        status: Status,
    },
    BadParameters(ParameterError),
    /// No scan within `stream_timeout`; the device restarts from probing.
    StreamStalled,
    /// The configured stream cannot be encoded (e.g. interval above 9).
    BadConfig(crate::command::EncodeError),
}

impl fmt::Display for DeviceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DeviceError::Timeout { phase } => write!(f, "SCIP sensor did not answer while {phase:?}: check cable, port, baud rate and power"),
            DeviceError::Status { command, status } => write!(f, "SCIP sensor refused {command} with status {status}: see docs/protocols.md, section 1.6, for the code and fix the request or the sensor state"),
            DeviceError::BadParameters(e) => e.fmt(f),
            DeviceError::StreamStalled => f.write_str("SCIP stream stopped delivering scans: restarting; check the link if this repeats"),
            DeviceError::BadConfig(e) => write!(f, "SCIP stream configuration invalid: {e}"),
        }
    }
}

impl std::error::Error for DeviceError {}

/// What the device tells its owner.
#[derive(Debug, Clone, PartialEq)]
pub enum DeviceEvent {
    Detected(Detection),
    Version(Version),
    Parameters(Parameters),
    ClockSample(ClockSample),
    StreamStarted {
        command: Command,
    },
    Scan(Scan),
    /// A finite stream delivered its last scan.
    StreamEnded,
    Stopped,
    /// A corrupted reply was dropped; decoding continues with the next one.
    DecodeError(DecodeError),
    Error(DeviceError),
}

/// Counters for health reporting.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DeviceStats {
    pub replies: u64,
    pub scans: u64,
    pub decode_errors: u64,
    pub status_errors: u64,
    pub restarts: u64,
}

/// SCIP 2.0 device driver without I/O.
#[derive(Debug)]
pub struct Device {
    decoder: Decoder,
    inner: Inner,
}

#[derive(Debug)]
struct Inner {
    config: DeviceConfig,
    phase: Phase,
    outgoing: Vec<u8>,
    transmitted: Vec<u8>,
    awaiting_since: Option<f64>,
    deadline: Option<f64>,
    probes_sent: u8,
    stream_seen: bool,
    clock_samples_left: u8,
    last_send: f64,
    stream: Option<Command>,
    stream_prefix: Vec<u8>,
    parameters: Option<Parameters>,
    unwrapper: TimestampUnwrapper,
    events: VecDeque<DeviceEvent>,
    spare: Vec<(Vec<u32>, Vec<u32>)>,
    stats: DeviceStats,
}

impl Device {
    pub fn new(config: DeviceConfig) -> Self {
        Device {
            decoder: Decoder::new(),
            inner: Inner {
                config,
                phase: Phase::Idle,
                outgoing: Vec::with_capacity(64),
                transmitted: Vec::with_capacity(64),
                awaiting_since: None,
                deadline: None,
                probes_sent: 0,
                stream_seen: false,
                clock_samples_left: 0,
                last_send: 0.0,
                stream: None,
                stream_prefix: Vec::with_capacity(16),
                parameters: None,
                unwrapper: TimestampUnwrapper::new(),
                events: VecDeque::with_capacity(16),
                spare: Vec::new(),
                stats: DeviceStats::default(),
            },
        }
    }

    /// Begins (or restarts) the connection sequence with a QT probe.
    pub fn start(&mut self) {
        self.decoder.reset();
        self.inner.probe_from_scratch();
    }

    /// Stops streaming and switches the laser off; [`DeviceEvent::Stopped`] follows.
    pub fn stop(&mut self) {
        self.inner.send(Command::Quit, Phase::Stopping);
    }

    /// Feeds bytes read from the sensor at host time `now`.
    pub fn handle_input(&mut self, now: f64, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            let used = self.decoder.push(bytes);
            bytes = &bytes[used..];
            match self.decoder.reply() {
                Some(Ok(reply)) => self.inner.on_reply(now, reply),
                Some(Err(error)) => {
                    self.inner.stats.decode_errors += 1;
                    self.inner.events.push_back(DeviceEvent::DecodeError(error));
                }
                None => {}
            }
        }
    }

    /// Bytes to write to the sensor now, if any.
    pub fn poll_transmit(&mut self, now: f64) -> Option<&[u8]> {
        self.inner.poll_transmit(now)
    }

    pub fn poll_event(&mut self) -> Option<DeviceEvent> {
        self.inner.events.pop_front()
    }

    /// Host time at which [`Device::handle_timeout`] must be called.
    pub fn poll_timeout(&self) -> Option<f64> {
        self.inner.deadline
    }

    pub fn handle_timeout(&mut self, now: f64) {
        if self.inner.deadline.is_some_and(|deadline| now >= deadline) {
            self.inner.deadline = None;
            self.inner.on_timeout();
            if self.inner.phase == Phase::Probing {
                self.decoder.reset();
            }
        }
    }

    /// Returns a scan's buffers for reuse by later scans.
    pub fn recycle(&mut self, scan: Scan) {
        if self.inner.spare.len() < 8 {
            self.inner.spare.push((scan.ranges_mm, scan.intensities));
        }
    }

    pub fn phase(&self) -> Phase {
        self.inner.phase
    }

    /// The PP reply, once read.
    pub fn parameters(&self) -> Option<&Parameters> {
        self.inner.parameters.as_ref()
    }

    pub fn stats(&self) -> DeviceStats {
        self.inner.stats
    }
}

fn status_is(reply: &Reply<'_>, accepted: &[&[u8; 2]]) -> bool {
    matches!(reply.status, Status::Code(code) if accepted.iter().any(|a| **a == code))
}

impl Inner {
    fn probe_from_scratch(&mut self) {
        self.probes_sent = 0;
        self.stream_seen = false;
        self.send(Command::Quit, Phase::Probing);
    }

    fn send(&mut self, command: Command, phase: Phase) {
        self.outgoing.clear();
        if let Err(error) = command.encode(&mut self.outgoing) {
            self.fail(DeviceError::BadConfig(error));
            return;
        }
        if phase == Phase::Probing {
            self.probes_sent += 1;
        }
        self.phase = phase;
        self.deadline = None;
    }

    fn poll_transmit(&mut self, now: f64) -> Option<&[u8]> {
        if self.outgoing.is_empty() {
            return None;
        }
        std::mem::swap(&mut self.outgoing, &mut self.transmitted);
        self.outgoing.clear();
        self.last_send = now;
        self.awaiting_since = Some(now);
        self.deadline = Some(now + self.config.reply_timeout);
        Some(&self.transmitted)
    }

    fn fail(&mut self, error: DeviceError) {
        if matches!(error, DeviceError::Status { .. }) {
            self.stats.status_errors += 1;
        }
        self.events.push_back(DeviceEvent::Error(error));
        self.phase = Phase::Failed;
        self.deadline = None;
        self.outgoing.clear();
    }

    fn on_timeout(&mut self) {
        match self.phase {
            Phase::Probing if self.probes_sent < self.config.probe_attempts => {
                self.outgoing.clear();
                Command::Quit.encode(&mut self.outgoing).ok();
                self.probes_sent += 1;
            }
            Phase::Streaming => {
                self.events
                    .push_back(DeviceEvent::Error(DeviceError::StreamStalled));
                self.stats.restarts += 1;
                self.probe_from_scratch();
            }
            Phase::Stopping => {
                self.events
                    .push_back(DeviceEvent::Error(DeviceError::Timeout {
                        phase: Phase::Stopping,
                    }));
                self.phase = Phase::Stopped;
            }
            Phase::Idle | Phase::Stopped | Phase::Failed => {}
            phase => self.fail(DeviceError::Timeout { phase }),
        }
    }

    fn refuse(&mut self, command: &'static str, reply: &Reply<'_>) {
        self.fail(DeviceError::Status {
            command,
            status: reply.status,
        });
    }

    fn on_reply(&mut self, now: f64, reply: Reply<'_>) {
        self.stats.replies += 1;
        let command = reply.command();
        match self.phase {
            Phase::Probing => self.on_probe_reply(&reply),
            Phase::SwitchingProtocol if command == b"SCIP2.0" => self.probe_from_scratch(),
            Phase::LeavingTimeMode if command == b"TM2" => self.probe_from_scratch(),
            Phase::ReadingVersion if command == b"VV" => match reply.body {
                Body::Info(info) => {
                    self.events
                        .push_back(DeviceEvent::Version(Version::from_info(&info)));
                    self.send(Command::Parameters, Phase::ReadingParameters);
                }
                _ => self.refuse("VV", &reply),
            },
            Phase::ReadingParameters if command == b"PP" => self.on_parameters(&reply),
            Phase::EnteringClockMode if command == b"TM0" => {
                if status_is(&reply, &[b"00", b"02"]) {
                    self.clock_samples_left = self.config.clock_samples;
                    self.send(Command::Time(TimeMode::Request), Phase::SamplingClock);
                } else {
                    self.refuse("TM0", &reply);
                }
            }
            Phase::SamplingClock if command == b"TM1" => self.on_clock_sample(now, &reply),
            Phase::LeavingClockMode if command == b"TM2" => {
                if status_is(&reply, &[b"00", b"03"]) {
                    self.send(Command::LaserOn, Phase::SwitchingLaserOn);
                } else {
                    self.refuse("TM2", &reply);
                }
            }
            Phase::SwitchingLaserOn if command == b"BM" => {
                if status_is(&reply, &[b"00", b"02"]) {
                    self.start_stream();
                } else {
                    self.refuse("BM", &reply);
                }
            }
            Phase::StartingStream => self.on_stream_ack(now, &reply),
            Phase::Streaming => self.on_stream_reply(now, &reply),
            Phase::Stopping if command == b"QT" => {
                self.phase = Phase::Stopped;
                self.deadline = None;
                self.events.push_back(DeviceEvent::Stopped);
            }
            // Late replies to earlier commands and scans still in flight are dropped.
            _ => {}
        }
    }

    fn on_probe_reply(&mut self, reply: &Reply<'_>) {
        if reply.command() != b"QT" {
            // QT is already on its way; the sensor answers it after the scan in flight.
            let streaming =
                matches!(reply.body, Body::Scan(_)) || reply.status == Status::STREAM_DATA;
            if streaming && !self.stream_seen {
                self.stream_seen = true;
                self.events
                    .push_back(DeviceEvent::Detected(Detection::StreamRunning));
            }
            return;
        }
        match reply.status {
            Status::Scip11(_) => {
                self.events
                    .push_back(DeviceEvent::Detected(Detection::Scip11));
                self.send(Command::Scip2, Phase::SwitchingProtocol);
            }
            Status::Code([b'0', b'E']) => {
                self.events
                    .push_back(DeviceEvent::Detected(Detection::TimeAdjustMode));
                self.send(Command::Time(TimeMode::Leave), Phase::LeavingTimeMode);
            }
            status if status.is_ok() => self.send(Command::Version, Phase::ReadingVersion),
            _ => self.refuse("QT", reply),
        }
    }

    fn on_parameters(&mut self, reply: &Reply<'_>) {
        let Body::Info(info) = reply.body else {
            return self.refuse("PP", reply);
        };
        match Parameters::from_info(&info) {
            Ok(parameters) => {
                self.events
                    .push_back(DeviceEvent::Parameters(parameters.clone()));
                self.parameters = Some(parameters);
                if self.config.clock_samples > 0 {
                    self.send(Command::Time(TimeMode::Enter), Phase::EnteringClockMode);
                } else {
                    self.send(Command::LaserOn, Phase::SwitchingLaserOn);
                }
            }
            Err(error) => self.fail(DeviceError::BadParameters(error)),
        }
    }

    fn on_clock_sample(&mut self, now: f64, reply: &Reply<'_>) {
        let Body::Time(sensor_ms) = reply.body else {
            return self.refuse("TM1", reply);
        };
        self.events.push_back(DeviceEvent::ClockSample(ClockSample {
            host_send: self.last_send,
            host_receive: now,
            sensor_ms,
            sensor_ms_unwrapped: self.unwrapper.unwrap(sensor_ms),
        }));
        self.clock_samples_left = self.clock_samples_left.saturating_sub(1);
        if self.clock_samples_left > 0 {
            self.send(Command::Time(TimeMode::Request), Phase::SamplingClock);
        } else {
            self.send(Command::Time(TimeMode::Leave), Phase::LeavingClockMode);
        }
    }

    fn stream_command(&self) -> Command {
        let (start, end) = self.config.steps.unwrap_or_else(|| {
            let p = self.parameters.as_ref();
            p.map_or((0, 0), |p| (p.first_step, p.last_step))
        });
        Command::Stream {
            data: self.config.data,
            range: StepRange {
                start,
                end,
                cluster: self.config.cluster,
            },
            interval: self.config.interval,
            count: self.config.scan_count,
        }
    }

    fn start_stream(&mut self) {
        let command = self.stream_command();
        self.stream = Some(command);
        self.send(command, Phase::StartingStream);
        // Echo minus the two-digit count and LF, kept to match every scan without re-encoding.
        self.stream_prefix.clear();
        let prefix_len = self.outgoing.len().saturating_sub(3);
        self.stream_prefix
            .extend_from_slice(&self.outgoing[..prefix_len]);
    }

    /// True if `reply` echoes our stream command, ignoring the counting-down scan count.
    fn is_our_stream(&self, reply: &Reply<'_>) -> bool {
        let echo = reply.command();
        echo.len() == self.stream_prefix.len() + 2 && echo.starts_with(&self.stream_prefix)
    }

    fn on_stream_ack(&mut self, now: f64, reply: &Reply<'_>) {
        if !self.is_our_stream(reply) {
            return;
        }
        if reply.status.is_ok() {
            self.phase = Phase::Streaming;
            self.deadline = Some(now + self.config.stream_timeout);
            let command = self.stream.unwrap_or(Command::Quit);
            self.events
                .push_back(DeviceEvent::StreamStarted { command });
        } else {
            self.refuse("MD/ME", reply);
        }
    }

    fn on_stream_reply(&mut self, now: f64, reply: &Reply<'_>) {
        if !self.is_our_stream(reply) {
            return;
        }
        let Body::Scan(scan) = reply.body else {
            // 0M ("unstable") and similar mid-stream statuses skip one scan; a real stop shows
            // up as a stall and restarts the sequence.
            self.stats.status_errors += 1;
            self.events
                .push_back(DeviceEvent::Error(DeviceError::Status {
                    command: "MD/ME",
                    status: reply.status,
                }));
            return;
        };
        self.deadline = Some(now + self.config.stream_timeout);
        let event = self.scan_event(now, &scan);
        let finished = event.remaining == 0
            && matches!(self.stream, Some(Command::Stream { count, .. }) if count > 0);
        self.stats.scans += 1;
        self.events.push_back(DeviceEvent::Scan(event));
        if finished {
            self.phase = Phase::Idle;
            self.deadline = None;
            self.events.push_back(DeviceEvent::StreamEnded);
        }
    }

    fn scan_event(&mut self, now: f64, scan: &ScanData<'_>) -> Scan {
        let (mut ranges_mm, mut intensities) = self.spare.pop().unwrap_or_default();
        ranges_mm.clear();
        ranges_mm.extend_from_slice(scan.ranges);
        intensities.clear();
        intensities.extend_from_slice(scan.intensities);
        Scan {
            timestamp_ms: self.unwrapper.unwrap(scan.timestamp),
            raw_timestamp: scan.timestamp,
            host_receive: now,
            data: scan.data,
            range: scan.range,
            remaining: scan.stream.map_or(0, |s| s.remaining),
            ranges_mm,
            intensities,
        }
    }
}
