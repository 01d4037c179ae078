//! Sans-IO device state machine following urg_library's connection sequence (docs/protocols.md, 1.9
//! "Start-up sequence"): probe with QT (recovering from SCIP 1.1, TM adjust mode or a running
//! stream), read VV and PP, sample the sensor clock with TM0/TM1/TM2, switch the laser on with BM,
//! then stream MD/ME. The contract is in the crate documentation.

use std::collections::VecDeque;
use std::fmt;
use std::time::Duration;

use crate::command::{Command, DataKind, StepRange, TimeMode};
use crate::decoder::{Body, DecodeError, Reply, Status};
use crate::params::{ParameterError, Parameters, Version};
use crate::receiver::{self, Received};

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
    /// How long to wait for a command's reply, from when it was transmitted.
    pub reply_timeout: Duration,
    /// Time without a scan before the stream is declared stalled and restarted.
    pub stream_timeout: Duration,
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
            reply_timeout: Duration::from_secs(1),
            stream_timeout: Duration::from_secs(1),
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

/// One TM1 reply: the sensor's counter, read just before the reply was sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockSample {
    /// `now` of the `handle_input` call that completed the reply.
    pub received: Duration,
    pub sensor_ms: u32,
    /// `sensor_ms` on the same unwrapped scale as [`Scan::timestamp_ms`].
    pub sensor_ms_unwrapped: u64,
}

/// One scan reply (MD/ME/MS streamed, or GD/GE/GS).
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    /// Sensor time of step 0 of this revolution, unwrapped, ms; step k was measured
    /// `k * 60 / (SCAN * ARES)` s later (docs/protocols.md, 1.7 "Timestamps").
    pub timestamp_ms: u64,
    pub raw_timestamp: u32,
    /// `now` of the `handle_input` call that completed the reply.
    pub received: Duration,
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
    Timeout { phase: Phase },
    /// A command was refused.
    Status {
        command: &'static str,
        status: Status,
    },
    /// A PP reply that does not parse (reported by the receiver in any phase; fatal while
    /// reading parameters).
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

/// What the device (or a bare [`Receiver`](crate::Receiver)) tells its owner.
///
/// Data events, from the receiver in every phase: `Parameters`, `ClockSample`, `Scan`,
/// `DecodeError`, and `Error(BadParameters)`. The others come from the device's handshake.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    Detected(Detection),
    Version(Version),
    /// A PP reply that parsed.
    Parameters(Parameters),
    /// A TM1 reply.
    ClockSample(ClockSample),
    StreamStarted {
        command: Command,
    },
    /// A scan reply, whether or not it belongs to the stream the device started.
    Scan(Scan),
    /// A finite stream delivered its last scan.
    StreamEnded,
    Stopped,
    /// A corrupted reply was dropped; decoding continues with the next one.
    DecodeError(DecodeError),
    Error(DeviceError),
}

impl Event {
    /// Whether the receiver emits it (and a bare `Receiver` fed the same bytes would too),
    /// rather than the device's handshake.
    pub fn is_data(&self) -> bool {
        matches!(
            self,
            Event::Parameters(_)
                | Event::ClockSample(_)
                | Event::Scan(_)
                | Event::DecodeError(_)
                | Event::Error(DeviceError::BadParameters(_))
        )
    }
}

/// Counters for health reporting.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DeviceStats {
    /// Replies that decoded, of any kind.
    pub replies: u64,
    /// Scan replies, whether or not they belong to the stream the device started.
    pub scans: u64,
    pub decode_errors: u64,
    pub status_errors: u64,
    pub restarts: u64,
}

/// SCIP 2.0 device driver without I/O: the handshake around a [`Receiver`](crate::Receiver)'s
/// decoding.
#[derive(Debug)]
pub struct Device {
    /// Never reset or bypassed: every received byte goes through it, in every phase.
    receiver: receiver::Core,
    inner: Inner,
}

#[derive(Debug)]
struct Inner {
    config: DeviceConfig,
    phase: Phase,
    outgoing: Vec<u8>,
    transmitted: Vec<u8>,
    deadline: Option<Duration>,
    probes_sent: u8,
    stream_seen: bool,
    clock_samples_left: u8,
    stream: Option<Command>,
    stream_prefix: Vec<u8>,
    parameters: Option<Parameters>,
    /// Shared with the receiver, so that data and handshake events keep their order.
    events: VecDeque<Event>,
    stats: DeviceStats,
}

impl Device {
    /// Starts the connection sequence at `now` with a QT probe.
    pub fn new(config: DeviceConfig, now: Duration) -> Self {
        let mut device = Device {
            receiver: receiver::Core::default(),
            inner: Inner {
                config,
                phase: Phase::Idle,
                outgoing: Vec::with_capacity(64),
                transmitted: Vec::with_capacity(64),
                deadline: None,
                probes_sent: 0,
                stream_seen: false,
                clock_samples_left: 0,
                stream: None,
                stream_prefix: Vec::with_capacity(16),
                parameters: None,
                events: VecDeque::with_capacity(16),
                stats: DeviceStats::default(),
            },
        };
        device.restart(now);
        device
    }

    /// Runs the connection sequence again from a QT probe. Bytes already received keep their
    /// place: a reply cut by the restart costs only itself.
    pub fn restart(&mut self, now: Duration) {
        self.inner.probe_from_scratch(now);
    }

    /// Stops streaming and switches the laser off; [`Event::Stopped`] follows.
    pub fn stop(&mut self, now: Duration) {
        self.inner.send(now, Command::Quit, Phase::Stopping);
    }

    /// Feeds bytes read from the sensor at host time `now`.
    pub fn handle_input(&mut self, now: Duration, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            let received = self
                .receiver
                .next_reply(now, &mut bytes, &mut self.inner.events);
            if let Some(received) = received {
                self.inner.on_reply(now, received);
            }
        }
    }

    /// Bytes to write to the sensor at `now`, if any.
    pub fn poll_transmit(&mut self, now: Duration) -> Option<&[u8]> {
        self.inner.poll_transmit(now)
    }

    /// Drain after every call that takes `now`: undrained events accumulate.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.inner.events.pop_front()
    }

    /// Host time at which [`Device::handle_timeout`] must be called.
    pub fn poll_timeout(&self) -> Option<Duration> {
        self.inner.deadline
    }

    pub fn handle_timeout(&mut self, now: Duration) {
        if self.inner.deadline.is_some_and(|deadline| now >= deadline) {
            self.inner.deadline = None;
            self.inner.on_timeout(now);
        }
    }

    pub fn phase(&self) -> Phase {
        self.inner.phase
    }

    /// The PP reply read by the handshake.
    pub fn parameters(&self) -> Option<&Parameters> {
        self.inner.parameters.as_ref()
    }

    pub fn stats(&self) -> DeviceStats {
        let received = self.receiver.stats();
        DeviceStats {
            replies: received.replies,
            scans: received.scans,
            decode_errors: received.decode_errors,
            ..self.inner.stats
        }
    }
}

fn status_is(reply: &Reply<'_>, accepted: &[&[u8; 2]]) -> bool {
    matches!(reply.status, Status::Code(code) if accepted.iter().any(|a| **a == code))
}

impl Inner {
    fn probe_from_scratch(&mut self, now: Duration) {
        self.probes_sent = 0;
        self.stream_seen = false;
        self.send(now, Command::Quit, Phase::Probing);
    }

    /// Queues `command`; its reply timeout runs from now, and again from its transmission.
    fn send(&mut self, now: Duration, command: Command, phase: Phase) {
        self.outgoing.clear();
        if let Err(error) = command.encode(&mut self.outgoing) {
            self.fail(DeviceError::BadConfig(error));
            return;
        }
        if phase == Phase::Probing {
            self.probes_sent += 1;
        }
        self.phase = phase;
        self.deadline = Some(now + self.config.reply_timeout);
    }

    fn poll_transmit(&mut self, now: Duration) -> Option<&[u8]> {
        if self.outgoing.is_empty() {
            return None;
        }
        std::mem::swap(&mut self.outgoing, &mut self.transmitted);
        self.outgoing.clear();
        self.deadline = Some(now + self.config.reply_timeout);
        Some(&self.transmitted)
    }

    fn fail(&mut self, error: DeviceError) {
        if matches!(error, DeviceError::Status { .. }) {
            self.stats.status_errors += 1;
        }
        self.events.push_back(Event::Error(error));
        self.halt();
    }

    /// Fails without an event of its own, for an error the receiver already reported.
    fn halt(&mut self) {
        self.phase = Phase::Failed;
        self.deadline = None;
        self.outgoing.clear();
    }

    fn on_timeout(&mut self, now: Duration) {
        match self.phase {
            // A reply cut short needs no reset: the receiver resynchronises at the next empty
            // line, at worst swallowing the reply to this probe, which the next one makes up for.
            Phase::Probing if self.probes_sent < self.config.probe_attempts => {
                self.send(now, Command::Quit, Phase::Probing);
            }
            Phase::Streaming => {
                self.events
                    .push_back(Event::Error(DeviceError::StreamStalled));
                self.stats.restarts += 1;
                self.probe_from_scratch(now);
            }
            Phase::Stopping => {
                self.events.push_back(Event::Error(DeviceError::Timeout {
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

    fn on_reply(&mut self, now: Duration, received: Received<'_>) {
        let Received { reply, parameters } = received;
        let command = reply.command();
        match self.phase {
            Phase::Probing => self.on_probe_reply(now, &reply),
            Phase::SwitchingProtocol if command == b"SCIP2.0" => self.probe_from_scratch(now),
            Phase::LeavingTimeMode if command == b"TM2" => self.probe_from_scratch(now),
            Phase::ReadingVersion if command == b"VV" => match reply.body {
                Body::Info(info) => {
                    self.events
                        .push_back(Event::Version(Version::from_info(&info)));
                    self.send(now, Command::Parameters, Phase::ReadingParameters);
                }
                _ => self.refuse("VV", &reply),
            },
            Phase::ReadingParameters if command == b"PP" => match parameters {
                Some(Ok(parameters)) => self.on_parameters(now, parameters),
                Some(Err(_)) => self.halt(),
                None => self.refuse("PP", &reply),
            },
            Phase::EnteringClockMode if command == b"TM0" => {
                if status_is(&reply, &[b"00", b"02"]) {
                    self.clock_samples_left = self.config.clock_samples;
                    self.send(now, Command::Time(TimeMode::Request), Phase::SamplingClock);
                } else {
                    self.refuse("TM0", &reply);
                }
            }
            Phase::SamplingClock if command == b"TM1" => self.on_clock_sample(now, &reply),
            Phase::LeavingClockMode if command == b"TM2" => {
                if status_is(&reply, &[b"00", b"03"]) {
                    self.send(now, Command::LaserOn, Phase::SwitchingLaserOn);
                } else {
                    self.refuse("TM2", &reply);
                }
            }
            Phase::SwitchingLaserOn if command == b"BM" => {
                if status_is(&reply, &[b"00", b"02"]) {
                    self.start_stream(now);
                } else {
                    self.refuse("BM", &reply);
                }
            }
            Phase::StartingStream => self.on_stream_ack(now, &reply),
            Phase::Streaming => self.on_stream_reply(now, &reply),
            Phase::Stopping if command == b"QT" => {
                self.phase = Phase::Stopped;
                self.deadline = None;
                self.events.push_back(Event::Stopped);
            }
            // Late replies to earlier commands and scans still in flight need no reaction (the
            // receiver has already reported what they carry).
            _ => {}
        }
    }

    fn on_probe_reply(&mut self, now: Duration, reply: &Reply<'_>) {
        if reply.command() != b"QT" {
            // QT is already on its way; the sensor answers it after the scan in flight.
            let streaming =
                matches!(reply.body, Body::Scan(_)) || reply.status == Status::STREAM_DATA;
            if streaming && !self.stream_seen {
                self.stream_seen = true;
                self.events
                    .push_back(Event::Detected(Detection::StreamRunning));
            }
            return;
        }
        match reply.status {
            Status::Scip11(_) => {
                self.events.push_back(Event::Detected(Detection::Scip11));
                self.send(now, Command::Scip2, Phase::SwitchingProtocol);
            }
            Status::Code([b'0', b'E']) => {
                self.events
                    .push_back(Event::Detected(Detection::TimeAdjustMode));
                self.send(now, Command::Time(TimeMode::Leave), Phase::LeavingTimeMode);
            }
            status if status.is_ok() => self.send(now, Command::Version, Phase::ReadingVersion),
            _ => self.refuse("QT", reply),
        }
    }

    fn on_parameters(&mut self, now: Duration, parameters: Parameters) {
        self.parameters = Some(parameters);
        if self.config.clock_samples > 0 {
            self.send(
                now,
                Command::Time(TimeMode::Enter),
                Phase::EnteringClockMode,
            );
        } else {
            self.send(now, Command::LaserOn, Phase::SwitchingLaserOn);
        }
    }

    fn on_clock_sample(&mut self, now: Duration, reply: &Reply<'_>) {
        if !matches!(reply.body, Body::Time(_)) {
            return self.refuse("TM1", reply);
        }
        self.clock_samples_left = self.clock_samples_left.saturating_sub(1);
        if self.clock_samples_left > 0 {
            self.send(now, Command::Time(TimeMode::Request), Phase::SamplingClock);
        } else {
            self.send(now, Command::Time(TimeMode::Leave), Phase::LeavingClockMode);
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

    fn start_stream(&mut self, now: Duration) {
        let command = self.stream_command();
        self.stream = Some(command);
        self.send(now, command, Phase::StartingStream);
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

    fn on_stream_ack(&mut self, now: Duration, reply: &Reply<'_>) {
        if !self.is_our_stream(reply) {
            return;
        }
        if reply.status.is_ok() {
            self.phase = Phase::Streaming;
            self.deadline = Some(now + self.config.stream_timeout);
            let command = self.stream.unwrap_or(Command::Quit);
            self.events.push_back(Event::StreamStarted { command });
        } else {
            self.refuse("MD/ME", reply);
        }
    }

    fn on_stream_reply(&mut self, now: Duration, reply: &Reply<'_>) {
        if !self.is_our_stream(reply) {
            return;
        }
        let Body::Scan(scan) = reply.body else {
            // 0M ("unstable") and similar mid-stream statuses skip one scan; a real stop shows
            // up as a stall and restarts the sequence.
            self.stats.status_errors += 1;
            self.events.push_back(Event::Error(DeviceError::Status {
                command: "MD/ME",
                status: reply.status,
            }));
            return;
        };
        self.deadline = Some(now + self.config.stream_timeout);
        let remaining = scan.stream.map_or(0, |s| s.remaining);
        let finite = matches!(self.stream, Some(Command::Stream { count, .. }) if count > 0);
        if remaining == 0 && finite {
            self.phase = Phase::Idle;
            self.deadline = None;
            self.events.push_back(Event::StreamEnded);
        }
    }
}
