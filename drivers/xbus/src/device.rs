//! Sans-IO device state machine: handshake, configuration check, measurement stream. The
//! contract is in the crate documentation.

use core::fmt;
use core::time::Duration;
use std::collections::VecDeque;

use crate::command::{Command, CommandFrame, OutputConfiguration, OutputEntry, EVERY_PACKET};
use crate::data_id::{CoordinateSystem, DataType, Precision};
use crate::frame::{mid, FrameError, FramerStats, DEFAULT_MAX_PAYLOAD};
use crate::measurement::Measurement;
use crate::mtdata2::Mtdata2Error;
use crate::receiver;

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
    /// How long to wait for each acknowledgement, from when the request was transmitted.
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

/// One MTData2 message, received in any phase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuMeasurement {
    /// `now` of the `handle_input` call that completed the frame.
    pub received_at: Duration,
    /// SampleTimeFine unwrapped across wraps (10 kHz ticks, continuing from the first value
    /// since creation, the last GoToMeasurementAck or a product code changing the wrap; clamped
    /// at zero).
    pub sample_time: Option<u64>,
    /// Packets missing between the previous PacketCounter and this one (mod 65536); 0 for the
    /// first since creation or the last GoToMeasurementAck.
    pub lost_packets: u16,
    pub data: Measurement,
}

/// What the device (or a bare [`Receiver`](crate::Receiver)) tells its owner.
///
/// Data events, from the receiver in every phase: `ProductCode`, `OutputConfiguration`,
/// `Measuring`, `Measurement`, `FrameDropped` and `BadMeasurement`. The others come from the
/// device's handshake.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// The device announced a power-up; it was answered with WakeUpAck and the handshake
    /// restarted.
    WakeUp,
    /// A ProductCode reply. With [`SampleTimeWrap::FromProductCode`], SampleTimeFine wraps as
    /// it says from here on.
    ProductCode(ProductCode),
    Identified(DeviceInfo),
    /// An OutputConfiguration reply that parses. Its first one after the device requested a
    /// configuration is the acknowledgement: anything but the request is followed by
    /// [`Event::Failed`]`(`[`Error::ConfigurationNotApplied`]`)`.
    OutputConfiguration(OutputConfiguration),
    /// A GoToMeasurementAck: measurements follow, packets counted afresh.
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

impl Event {
    /// Whether the receiver emits it (and a bare `Receiver` fed the same bytes would too),
    /// rather than the device's handshake.
    pub fn is_data(&self) -> bool {
        matches!(
            self,
            Event::ProductCode(_)
                | Event::OutputConfiguration(_)
                | Event::Measuring
                | Event::Measurement(_)
                | Event::FrameDropped(_)
                | Event::BadMeasurement(_)
        )
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DeviceStats {
    pub framer: FramerStats,
    pub measurements: u64,
    pub lost_packets: u64,
    pub bad_measurements: u64,
    /// Checksum-valid replies other than MTData2 that the handshake did not expect.
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

const REPLY_CAPACITY: usize = 4 * crate::command::MAX_OUTPUTS;

/// Xbus device driver without I/O: the handshake around a [`Receiver`](crate::Receiver)'s
/// decoding.
pub struct Device {
    config: DeviceConfig,
    requested: OutputConfiguration,
    /// Never reset or bypassed: every received byte goes through it, in every phase.
    receiver: receiver::Core,
    phase: Phase,
    pending: Option<Pending>,
    identity: Identity,
    transmit: VecDeque<Command>,
    transmitted: Option<CommandFrame>,
    /// Shared with the receiver, so that data and handshake events keep their order.
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
            receiver: receiver::Core::new(config.sample_time_wrap, config.max_payload),
            phase: Phase::Handshake,
            pending: None,
            identity: Identity {
                device_id: 0,
                product_code: ProductCode::default(),
            },
            transmit: VecDeque::with_capacity(4),
            transmitted: None,
            events: VecDeque::with_capacity(64),
            stats: DeviceStats::default(),
        };
        device.restart(now);
        device
    }

    /// Runs the handshake again from GoToConfig. Bytes already received keep their place.
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
        let received = self.receiver.stats();
        DeviceStats {
            framer: received.framer,
            measurements: received.measurements,
            lost_packets: received.lost_packets,
            bad_measurements: received.bad_measurements,
            ..self.stats
        }
    }

    /// The next frame to write to the device at `now`, if any.
    pub fn poll_transmit(&mut self, now: Duration) -> Option<&[u8]> {
        let command = self.transmit.pop_front()?;
        if let Some(pending) = self.pending.as_mut().filter(|p| p.command == command) {
            pending.deadline = now + self.config.reply_timeout;
        }
        Some(self.transmitted.insert(command.to_frame()).as_bytes())
    }

    /// Drain after every call that takes `now`: undrained events accumulate.
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
        while let Some(result) = self.receiver.next_frame(now, &mut bytes, &mut self.events) {
            let Ok(frame) = result else { continue };
            let (m, len) = (frame.mid, frame.payload.len());
            if m == mid::MT_DATA2 {
                // Decoded or not, data is flowing.
                if let Phase::Measuring { .. } = self.phase {
                    self.phase = Phase::Measuring { last_data: now };
                }
                continue;
            }
            // Replies fit a SetOutputConfiguration echo.
            let mut payload = [0u8; REPLY_CAPACITY];
            let n = len.min(payload.len());
            payload[..n].copy_from_slice(&frame.payload[..n]);
            self.handle_reply(now, m, &payload[..n], len);
        }
    }

    /// Queues `command`; its reply timeout runs from now, and again from its transmission.
    fn send(&mut self, command: Command, now: Duration) {
        self.transmit.push_back(command);
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
        self.transmit.push_back(pending.command);
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
                self.transmit.push_front(Command::WakeUpAck);
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
            // GoToMeasurementAck, reported by the receiver.
            _ => {
                self.phase = Phase::Measuring { last_data: now };
                return;
            }
        };
        self.send(next, now);
    }

    fn identified(&mut self, firmware: FirmwareRevision) {
        self.events.push_back(Event::Identified(DeviceInfo {
            device_id: self.identity.device_id,
            product_code: self.identity.product_code,
            firmware,
            sample_time_wrap: self.receiver.sample_time_modulus(),
        }));
    }

    /// The receiver has reported the acknowledged configuration (if it parses).
    fn check_output_configuration(&mut self, now: Duration, payload: &[u8], len: usize) {
        let applied = OutputConfiguration::from_payload(payload).unwrap_or_default();
        if len != payload.len() || applied != self.requested {
            return self.fail(Error::ConfigurationNotApplied {
                requested: self.requested,
                applied,
            });
        }
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
}
