//! Sans-IO device state machine: handshake, configuration check, measurement stream.
//!
//! Drive it like quinn-proto: feed received bytes with [`Device::handle_input`], write whatever
//! [`Device::poll_transmit`] returns, call [`Device::handle_timeout`] once the instant from
//! [`Device::poll_timeout`] has passed, and drain [`Device::poll_event`]. `now` is any monotonic
//! time since an epoch the caller chooses.

use core::fmt;
use core::time::Duration;
use std::collections::VecDeque;

use crate::command::{Command, CommandFrame, OutputConfiguration, OutputEntry, EVERY_PACKET};
use crate::data_id::{CoordinateSystem, DataType, Precision};
use crate::frame::{mid, FrameError, Framer, FramerStats, DEFAULT_MAX_PAYLOAD};
use crate::measurement::Measurement;
use crate::mtdata2::Mtdata2Error;

/// SampleTimeFine wraps after one day on MTi-10/100-series devices (incl. MTi-G-700/710).
pub const ONE_DAY_TICKS: u64 = 864_000_000;
/// SampleTimeFine wraps at 2^32 on MTi-1 and 600-series devices.
pub const U32_TICKS: u64 = 1 << 32;

/// Which inertial outputs to request besides SampleTimeFine, PacketCounter and StatusWord.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImuOutput {
    /// Acceleration + RateOfTurn.
    Rates,
    /// DeltaV + DeltaQ (strapdown increments over each output interval).
    Increments,
}

/// Where SampleTimeFine wraps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleTimeWrap {
    /// Decide from the product code the device reports.
    FromProductCode,
    /// Wrap after this many 10 kHz ticks.
    Ticks(u64),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceConfig {
    pub imu_output: ImuOutput,
    pub rate_hz: u16,
    pub precision: Precision,
    /// How long to wait for each acknowledgement.
    pub reply_timeout: Duration,
    /// Total tries per request before failing.
    pub attempts: u8,
    pub sample_time_wrap: SampleTimeWrap,
    /// Silence in measurement longer than this is reported (and reported again each period).
    pub data_timeout: Duration,
    pub max_payload: usize,
}

impl Default for DeviceConfig {
    fn default() -> Self {
        Self {
            imu_output: ImuOutput::Increments,
            rate_hz: 100,
            precision: Precision::Float32,
            reply_timeout: Duration::from_millis(500),
            attempts: 3,
            sample_time_wrap: SampleTimeWrap::FromProductCode,
            data_timeout: Duration::from_secs(1),
            max_payload: DEFAULT_MAX_PAYLOAD,
        }
    }
}

impl DeviceConfig {
    /// The NED-flagged output list this configuration asks the device for.
    pub fn output_configuration(&self) -> OutputConfiguration {
        let every = |t: DataType| OutputEntry {
            id: t.id(self.precision, CoordinateSystem::Ned),
            frequency: EVERY_PACKET,
        };
        let at_rate = |t: DataType| OutputEntry {
            id: t.id(self.precision, CoordinateSystem::Ned),
            frequency: self.rate_hz,
        };
        let (a, b) = match self.imu_output {
            ImuOutput::Rates => (DataType::Acceleration, DataType::RateOfTurn),
            ImuOutput::Increments => (DataType::DeltaV, DataType::DeltaQ),
        };
        let entries = [
            every(DataType::SampleTimeFine),
            every(DataType::PacketCounter),
            every(DataType::StatusWord),
            at_rate(a),
            at_rate(b),
        ];
        OutputConfiguration::new(&entries).expect("five entries fit in 32")
    }
}

/// Product code text as reported (at most 20 bytes).
#[derive(Clone, Copy, PartialEq, Eq, Default)]
pub struct ProductCode {
    bytes: [u8; 20],
    len: usize,
}

impl ProductCode {
    /// Keeps the printable prefix, without the padding devices append.
    pub fn from_bytes(raw: &[u8]) -> Self {
        let mut code = Self::default();
        let printable = raw
            .iter()
            .take(20)
            .take_while(|b| b.is_ascii_graphic() || **b == b' ');
        for (slot, &b) in code.bytes.iter_mut().zip(printable) {
            *slot = b;
            code.len += 1;
        }
        while code.len > 0 && code.bytes[code.len - 1] == b' ' {
            code.len -= 1;
        }
        code
    }

    pub fn as_str(&self) -> &str {
        core::str::from_utf8(&self.bytes[..self.len]).unwrap_or("")
    }

    /// SampleTimeFine wrap of this model: one day on 10/100-series, 2^32 otherwise.
    pub fn sample_time_wrap(&self) -> u64 {
        let model = self
            .as_str()
            .trim_start_matches("MTi-")
            .trim_start_matches("G-");
        let digits = model.bytes().take_while(u8::is_ascii_digit).count();
        match &model[..digits] {
            "10" | "20" | "30" | "100" | "200" | "300" | "700" | "710" => ONE_DAY_TICKS,
            _ => U32_TICKS,
        }
    }
}

impl fmt::Debug for ProductCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FirmwareRevision {
    pub major: u8,
    pub minor: u8,
    pub revision: u8,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceInfo {
    pub device_id: u32,
    pub product_code: ProductCode,
    pub firmware: FirmwareRevision,
    /// SampleTimeFine wrap in use (from the product code or the configuration).
    pub sample_time_wrap: u64,
}

/// Error code of a device Error (0x42) message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ErrorCode(pub u8);

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let meaning = match self.0 {
            3 => "invalid period",
            4 => "invalid message",
            30 => "timer overflow",
            32 => "baud rate out of range",
            33 => "invalid parameter",
            41 => "data overflow, the baud rate is too low for the output",
            42 => "buffer overflow",
            _ => "unlisted",
        };
        write!(f, "{} ({meaning})", self.0)
    }
}

/// Fatal handshake failures. After one, the device stays idle until [`Device::restart`].
// Kept inline (no Box) so that reporting never allocates; events are few.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Error {
    /// No acknowledgement after every try.
    Timeout { request: u8, attempts: u8 },
    /// The device answered the request with an Error message.
    Rejected { request: u8, code: ErrorCode },
    /// The acknowledgement of SetOutputConfiguration reports a different configuration.
    ConfigurationNotApplied {
        requested: OutputConfiguration,
        applied: OutputConfiguration,
    },
    /// A reply too short for its message type.
    MalformedReply { mid: u8, len: usize },
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Timeout { request, attempts } => write!(
                f,
                "xbus device did not acknowledge {} after {attempts} tries: check the port, baud rate and power",
                mid_name(*request)
            ),
            Self::Rejected { request, code } => write!(
                f,
                "xbus device rejected {} with error {code}: check the requested configuration against the device model",
                mid_name(*request)
            ),
            Self::ConfigurationNotApplied { requested, applied } => write!(
                f,
                "xbus device applied output configuration [{applied}] instead of [{requested}]: lower the rate or precision to what the model supports"
            ),
            Self::MalformedReply { mid, len } => write!(
                f,
                "xbus reply {} has only {len} bytes: the device firmware is not supported",
                mid_name(*mid)
            ),
        }
    }
}

impl std::error::Error for Error {}

/// Name of a message identifier, for messages.
pub fn mid_name(m: u8) -> &'static str {
    match m {
        mid::REQ_DID => "ReqDID",
        mid::DEVICE_ID => "DeviceID",
        mid::GO_TO_MEASUREMENT => "GoToMeasurement",
        mid::REQ_FW_REV => "ReqFWRev",
        mid::FIRMWARE_REV => "FirmwareRev",
        mid::SET_BAUDRATE => "SetBaudrate",
        mid::REQ_PRODUCT_CODE => "ReqProductCode",
        mid::PRODUCT_CODE => "ProductCode",
        mid::GO_TO_CONFIG => "GoToConfig",
        mid::MT_DATA2 => "MTData2",
        mid::WAKE_UP => "WakeUp",
        mid::WAKE_UP_ACK => "WakeUpAck",
        mid::RESET => "Reset",
        mid::ERROR => "Error",
        mid::SET_OUTPUT_CONFIGURATION => "SetOutputConfiguration",
        mid::OUTPUT_CONFIGURATION => "OutputConfiguration",
        _ => "an unlisted message",
    }
}

/// One MTData2 message received in measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuMeasurement {
    /// `now` of the `handle_input` call that completed the frame.
    pub received_at: Duration,
    /// SampleTimeFine unwrapped across wraps (10 kHz ticks, continuing from the first value).
    pub sample_time: Option<u64>,
    /// Packets missing between the previous PacketCounter and this one (mod 65536).
    pub lost_packets: u16,
    pub data: Measurement,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// The device announced a power-up; it was answered with WakeUpAck and the handshake
    /// restarted.
    WakeUp,
    Identified(DeviceInfo),
    /// The device acknowledged exactly the requested output configuration.
    Configured(OutputConfiguration),
    /// The device acknowledged GoToMeasurement; measurements follow.
    Measuring,
    Measurement(ImuMeasurement),
    /// Bytes dropped by the framer (the stream continues).
    FrameDropped(FrameError),
    /// A checksum-valid MTData2 message that could not be decoded (dropped).
    BadMeasurement(Mtdata2Error),
    /// An Error message outside a request, e.g. 41 data overflow in measurement.
    DeviceError(ErrorCode),
    /// No MTData2 for `silent_for` in measurement.
    DataTimeout {
        silent_for: Duration,
    },
    /// The handshake failed; nothing more is sent until `restart`.
    Failed(Error),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DeviceStats {
    pub framer: FramerStats,
    pub measurements: u64,
    pub lost_packets: u64,
    pub bad_measurements: u64,
    /// Checksum-valid frames that were not expected in the current state.
    pub ignored_frames: u64,
    pub retries: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    Handshake,
    Measuring { last_data: Duration },
    Failed,
}

struct Pending {
    command: Command,
    deadline: Duration,
    tries: u8,
}

struct Identity {
    device_id: u32,
    product_code: ProductCode,
}

/// Unwraps SampleTimeFine; small backward steps (GNSS-stamped frames) stay backward steps.
#[derive(Debug, Clone, Copy)]
struct SampleClock {
    modulus: u64,
    last_raw: Option<u64>,
    total: u64,
}

impl SampleClock {
    fn unwrap(&mut self, raw: u32) -> u64 {
        let raw = u64::from(raw) % self.modulus;
        match self.last_raw {
            None => self.total = raw,
            Some(last) => {
                let forward = (raw + self.modulus - last) % self.modulus;
                if forward <= self.modulus / 2 {
                    self.total += forward;
                } else {
                    self.total = self.total.saturating_sub(self.modulus - forward);
                }
            }
        }
        self.last_raw = Some(raw);
        self.total
    }
}

const REPLY_CAPACITY: usize = 4 * crate::command::MAX_OUTPUTS;

pub struct Device {
    config: DeviceConfig,
    requested: OutputConfiguration,
    framer: Framer,
    phase: Phase,
    pending: Option<Pending>,
    identity: Identity,
    clock: SampleClock,
    last_counter: Option<u16>,
    transmit: VecDeque<CommandFrame>,
    events: VecDeque<Event>,
    stats: DeviceStats,
}

impl Device {
    /// Starts the handshake at `now` with GoToConfig (valid whether the device is in config or
    /// already measuring).
    pub fn new(config: DeviceConfig, now: Duration) -> Self {
        let mut device = Self {
            config,
            requested: config.output_configuration(),
            framer: Framer::new(config.max_payload),
            phase: Phase::Handshake,
            pending: None,
            identity: Identity {
                device_id: 0,
                product_code: ProductCode::default(),
            },
            clock: SampleClock {
                modulus: U32_TICKS,
                last_raw: None,
                total: 0,
            },
            last_counter: None,
            transmit: VecDeque::with_capacity(4),
            events: VecDeque::with_capacity(64),
            stats: DeviceStats::default(),
        };
        device.restart(now);
        device
    }

    /// Forgets the device state and runs the handshake again from GoToConfig.
    pub fn restart(&mut self, now: Duration) {
        self.phase = Phase::Handshake;
        self.transmit.clear();
        self.send(Command::GoToConfig, now);
    }

    pub fn config(&self) -> &DeviceConfig {
        &self.config
    }

    pub fn is_measuring(&self) -> bool {
        matches!(self.phase, Phase::Measuring { .. })
    }

    pub fn stats(&self) -> DeviceStats {
        DeviceStats {
            framer: self.framer.stats(),
            ..self.stats
        }
    }

    /// The next frame to write to the device.
    pub fn poll_transmit(&mut self) -> Option<CommandFrame> {
        self.transmit.pop_front()
    }

    /// Drain after every `handle_input` and `handle_timeout`: undrained events accumulate.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// When `handle_timeout` must next be called.
    pub fn poll_timeout(&self) -> Option<Duration> {
        match self.phase {
            Phase::Handshake => self.pending.as_ref().map(|p| p.deadline),
            Phase::Measuring { last_data } => Some(last_data + self.config.data_timeout),
            Phase::Failed => None,
        }
    }

    pub fn handle_timeout(&mut self, now: Duration) {
        match self.phase {
            Phase::Handshake => self.retry_if_due(now),
            Phase::Measuring { last_data } => {
                let silent_for = now.saturating_sub(last_data);
                if silent_for >= self.config.data_timeout {
                    self.events.push_back(Event::DataTimeout { silent_for });
                    // Report again one period later rather than on every call.
                    self.phase = Phase::Measuring { last_data: now };
                }
            }
            Phase::Failed => {}
        }
    }

    /// Feeds bytes read from the device at `now`.
    pub fn handle_input(&mut self, now: Duration, mut bytes: &[u8]) {
        while let Some(result) = self.framer.decode(&mut bytes) {
            match result {
                Err(e) => self.events.push_back(Event::FrameDropped(e)),
                Ok(frame) => {
                    let (m, len) = (frame.mid, frame.payload.len());
                    // Replies fit a SetOutputConfiguration echo; MTData2 is decoded in place.
                    let mut payload = [0u8; REPLY_CAPACITY];
                    if m != mid::MT_DATA2 {
                        let n = len.min(payload.len());
                        payload[..n].copy_from_slice(&frame.payload[..n]);
                        self.handle_reply(now, m, &payload[..n], len);
                    } else if let Phase::Measuring { .. } = self.phase {
                        let decoded = Measurement::from_payload(frame.payload);
                        self.handle_measurement(now, decoded);
                    } else {
                        self.stats.ignored_frames += 1;
                    }
                }
            }
            if self.phase == Phase::Failed {
                return;
            }
        }
    }

    fn handle_measurement(&mut self, now: Duration, decoded: Result<Measurement, Mtdata2Error>) {
        self.phase = Phase::Measuring { last_data: now };
        let data = match decoded {
            Ok(data) => data,
            Err(e) => {
                self.stats.bad_measurements += 1;
                self.events.push_back(Event::BadMeasurement(e));
                return;
            }
        };
        let lost_packets = match (self.last_counter, data.packet_counter) {
            (Some(last), Some(counter)) => counter.wrapping_sub(last).wrapping_sub(1),
            _ => 0,
        };
        if data.packet_counter.is_some() {
            self.last_counter = data.packet_counter;
        }
        self.stats.measurements += 1;
        self.stats.lost_packets += u64::from(lost_packets);
        let sample_time = data.sample_time_fine.map(|raw| self.clock.unwrap(raw));
        self.events.push_back(Event::Measurement(ImuMeasurement {
            received_at: now,
            sample_time,
            lost_packets,
            data,
        }));
    }

    fn send(&mut self, command: Command, now: Duration) {
        self.transmit.push_back(command.to_frame());
        self.pending = Some(Pending {
            command,
            deadline: now + self.config.reply_timeout,
            tries: 1,
        });
    }

    fn retry_if_due(&mut self, now: Duration) {
        let Some(pending) = self.pending.as_mut() else {
            return;
        };
        if now < pending.deadline {
            return;
        }
        if pending.tries >= self.config.attempts {
            let error = Error::Timeout {
                request: pending.command.mid(),
                attempts: pending.tries,
            };
            self.fail(error);
            return;
        }
        pending.tries += 1;
        pending.deadline = now + self.config.reply_timeout;
        self.transmit.push_back(pending.command.to_frame());
        self.stats.retries += 1;
    }

    fn fail(&mut self, error: Error) {
        self.phase = Phase::Failed;
        self.pending = None;
        self.transmit.clear();
        self.events.push_back(Event::Failed(error));
    }

    fn handle_reply(&mut self, now: Duration, m: u8, payload: &[u8], len: usize) {
        if self.phase == Phase::Failed {
            return;
        }
        match m {
            mid::WAKE_UP => {
                self.events.push_back(Event::WakeUp);
                self.restart(now);
                // The acknowledgement goes first: it must reach the device within 500 ms.
                self.transmit.push_front(Command::WakeUpAck.to_frame());
            }
            mid::ERROR => {
                let code = ErrorCode(payload.first().copied().unwrap_or(0));
                match self.pending.as_ref() {
                    Some(p) => self.fail(Error::Rejected {
                        request: p.command.mid(),
                        code,
                    }),
                    None => self.events.push_back(Event::DeviceError(code)),
                }
            }
            _ => match self.pending.as_ref() {
                Some(p) if p.command.reply_mid() == m => self.advance(now, m, payload, len),
                _ => self.stats.ignored_frames += 1,
            },
        }
    }

    /// Handles the acknowledgement of the pending request and sends the next one.
    fn advance(&mut self, now: Duration, m: u8, payload: &[u8], len: usize) {
        self.pending = None;
        let next = match m {
            mid::GO_TO_CONFIG_ACK => Command::ReqDid,
            mid::DEVICE_ID => {
                let Some(id) = payload.first_chunk::<4>() else {
                    return self.fail(Error::MalformedReply { mid: m, len });
                };
                self.identity.device_id = u32::from_be_bytes(*id);
                Command::ReqProductCode
            }
            mid::PRODUCT_CODE => {
                self.identity.product_code = ProductCode::from_bytes(payload);
                Command::ReqFwRev
            }
            mid::FIRMWARE_REV => {
                let Some(&[major, minor, revision]) = payload.first_chunk::<3>() else {
                    return self.fail(Error::MalformedReply { mid: m, len });
                };
                self.identified(FirmwareRevision {
                    major,
                    minor,
                    revision,
                });
                Command::SetOutputConfiguration(self.requested)
            }
            mid::OUTPUT_CONFIGURATION => return self.check_output_configuration(now, payload, len),
            _ => {
                self.phase = Phase::Measuring { last_data: now };
                self.last_counter = None;
                self.clock.last_raw = None;
                self.events.push_back(Event::Measuring);
                return;
            }
        };
        self.send(next, now);
    }

    fn identified(&mut self, firmware: FirmwareRevision) {
        let product_code = self.identity.product_code;
        self.clock.modulus = match self.config.sample_time_wrap {
            SampleTimeWrap::FromProductCode => product_code.sample_time_wrap(),
            SampleTimeWrap::Ticks(t) => t.max(2),
        };
        self.events.push_back(Event::Identified(DeviceInfo {
            device_id: self.identity.device_id,
            product_code,
            firmware,
            sample_time_wrap: self.clock.modulus,
        }));
    }

    fn check_output_configuration(&mut self, now: Duration, payload: &[u8], len: usize) {
        let applied = OutputConfiguration::from_payload(payload).unwrap_or_default();
        if len != payload.len() || applied != self.requested {
            return self.fail(Error::ConfigurationNotApplied {
                requested: self.requested,
                applied,
            });
        }
        self.events.push_back(Event::Configured(applied));
        self.send(Command::GoToMeasurement, now);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_time_wrap_follows_the_model_family() {
        for (code, wrap) in [
            ("MTi-G-710-2A5G4", ONE_DAY_TICKS),
            ("MTi-G-700-2A5G4", ONE_DAY_TICKS),
            ("MTi-300-2A8G4", ONE_DAY_TICKS),
            ("MTi-30-2A5G4", ONE_DAY_TICKS),
            ("MTi-10", ONE_DAY_TICKS),
            ("MTi-630", U32_TICKS),
            ("MTi-680G", U32_TICKS),
            ("MTi-3-8A7G6", U32_TICKS),
            ("MTi-1", U32_TICKS),
            ("", U32_TICKS),
        ] {
            assert_eq!(
                ProductCode::from_bytes(code.as_bytes()).sample_time_wrap(),
                wrap,
                "{code}"
            );
        }
    }

    #[test]
    fn product_code_drops_padding() {
        let code = ProductCode::from_bytes(b"MTi-630     \0\0\0\0");
        assert_eq!(code.as_str(), "MTi-630");
    }

    #[test]
    fn sample_clock_unwraps_forward_and_keeps_small_backward_steps() {
        let mut clock = SampleClock {
            modulus: 1000,
            last_raw: None,
            total: 0,
        };
        let got: Vec<u64> = [900, 950, 20, 10, 400]
            .iter()
            .map(|&r| clock.unwrap(r))
            .collect();
        assert_eq!(got, [900, 950, 1020, 1010, 1400]);
    }
}
