//! The passive half of the driver: received bytes in, data events out, nothing sent.
//!
//! [`Device`](crate::Device) runs every byte it receives through this same code, so a bare
//! [`Receiver`] fed a recording of those bytes (replay) emits the same data events, bit for bit,
//! as the device did live.

use std::collections::VecDeque;
use std::time::Duration;

use wrapping_counter::Unwrapper;

use crate::decoder::{Body, Decoder, Reply, ScanData};
use crate::device::{ClockSample, DeviceError, Event, Scan};
use crate::params::{ParameterError, Parameters};

/// The sensor's millisecond counter is 24 bits wide (wraps every ~4 h 40 min).
const CLOCK_MODULUS: u64 = 1 << 24;

/// Counters of what a receiver decoded.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReceiverStats {
    /// Replies that decoded, of any kind.
    pub replies: u64,
    pub scans: u64,
    /// Replies dropped as corrupt.
    pub decode_errors: u64,
}

/// Decodes a scanner's received bytes into the data events [`Event::Parameters`],
/// [`Event::ClockSample`], [`Event::Scan`] and [`Event::DecodeError`] (plus
/// [`Event::Error`]`(`[`DeviceError::BadParameters`]`)` for a `PP` reply that does not parse),
/// whatever command they answer and whoever sent it. It never sends and has no timeouts.
///
/// ```
/// use std::time::Duration;
/// let mut receiver = scip::Receiver::new();
/// receiver.handle_input(Duration::from_millis(5), b"TM1\n00P\n00000\n\n");
/// let Some(scip::Event::ClockSample(sample)) = receiver.poll_event() else { panic!() };
/// assert_eq!((sample.sensor_ms, sample.received), (0, Duration::from_millis(5)));
/// ```
#[derive(Debug, Default)]
pub struct Receiver {
    core: Core,
    events: VecDeque<Event>,
}

impl Receiver {
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds bytes read from the sensor at host time `now` (`Duration::ZERO` if untimed).
    pub fn handle_input(&mut self, now: Duration, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            self.core.next_reply(now, &mut bytes, &mut self.events);
        }
    }

    /// Drain after every `handle_input`: undrained events accumulate.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    pub fn stats(&self) -> ReceiverStats {
        self.core.stats
    }
}

/// A reply for the device's handshake, after its data events were queued.
pub(crate) struct Received<'a> {
    pub(crate) reply: Reply<'a>,
    /// What a `PP` info reply parsed to (a failure is already reported as an event).
    pub(crate) parameters: Option<Result<Parameters, ParameterError>>,
}

/// Everything a receiver keeps but its event queue, which the device shares with its own
/// events so that both come out in the order they happened.
#[derive(Debug)]
pub(crate) struct Core {
    decoder: Decoder,
    /// Scans and TM1 replies share the sensor clock, so one unwrapper puts both on one scale.
    clock: Unwrapper,
    stats: ReceiverStats,
}

impl Default for Core {
    fn default() -> Self {
        Self {
            decoder: Decoder::new(),
            clock: Unwrapper::new(CLOCK_MODULUS),
            stats: ReceiverStats::default(),
        }
    }
}

impl Core {
    pub(crate) fn stats(&self) -> ReceiverStats {
        self.stats
    }

    /// Consumes `bytes` up to the end of the next reply, queuing its data events; the reply is
    /// returned if it decoded.
    pub(crate) fn next_reply(
        &mut self,
        now: Duration,
        bytes: &mut &[u8],
        events: &mut VecDeque<Event>,
    ) -> Option<Received<'_>> {
        let used = self.decoder.push(bytes);
        *bytes = &bytes[used..];
        let reply = match self.decoder.reply()? {
            Ok(reply) => reply,
            Err(error) => {
                self.stats.decode_errors += 1;
                events.push_back(Event::DecodeError(error));
                return None;
            }
        };
        self.stats.replies += 1;
        let mut parameters = None;
        match reply.body {
            Body::Info(info) if reply.command() == b"PP" => {
                let parsed = Parameters::from_info(&info);
                events.push_back(match &parsed {
                    Ok(p) => Event::Parameters(p.clone()),
                    Err(e) => Event::Error(DeviceError::BadParameters(e.clone())),
                });
                parameters = Some(parsed);
            }
            Body::Time(sensor_ms) => {
                events.push_back(Event::ClockSample(ClockSample {
                    received: now,
                    sensor_ms,
                    sensor_ms_unwrapped: unwrap_clock(&mut self.clock, sensor_ms),
                }));
            }
            Body::Scan(scan) => {
                self.stats.scans += 1;
                let timestamp_ms = unwrap_clock(&mut self.clock, scan.timestamp);
                events.push_back(Event::Scan(scan_event(now, timestamp_ms, &scan)));
            }
            Body::Info(_) | Body::Empty => {}
        }
        Some(Received { reply, parameters })
    }
}

/// Clamped at zero: only a counter stepping back past its first reading goes below it.
fn unwrap_clock(clock: &mut Unwrapper, raw: u32) -> u64 {
    clock.unwrap(u64::from(raw)).max(0) as u64
}

fn scan_event(now: Duration, timestamp_ms: u64, scan: &ScanData<'_>) -> Scan {
    Scan {
        timestamp_ms,
        raw_timestamp: scan.timestamp,
        received: now,
        data: scan.data,
        range: scan.range,
        remaining: scan.stream.map_or(0, |s| s.remaining),
        ranges_mm: scan.ranges.to_vec(),
        intensities: scan.intensities.to_vec(),
    }
}
