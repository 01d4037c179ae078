//! The passive half of the driver: received bytes in, data events out, nothing sent.
//!
//! [`Device`](crate::Device) runs every byte it receives through this same code, so a bare
//! [`Receiver`] fed a recording of those bytes (replay) emits the same data events, bit for bit,
//! as the device did live.

use core::time::Duration;
use std::collections::VecDeque;

use wrapping_counter::Unwrapper;

use crate::command::OutputConfiguration;
use crate::device::{Event, ImuMeasurement, ProductCode, SampleTimeWrap, U32_TICKS};
use crate::frame::{mid, Frame, FrameError, Framer, FramerStats};
use crate::measurement::Measurement;

/// Counters of what a receiver decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReceiverStats {
    pub framer: FramerStats,
    pub measurements: u64,
    pub lost_packets: u64,
    pub bad_measurements: u64,
}

/// Decodes an IMU's received bytes into the data events [`Event::ProductCode`],
/// [`Event::OutputConfiguration`], [`Event::Measuring`], [`Event::Measurement`],
/// [`Event::FrameDropped`] and [`Event::BadMeasurement`], whatever request they answer and
/// whoever sent it. It never sends and has no timeouts.
///
/// ```
/// use std::time::Duration;
/// use xbus::{Event, Receiver, SampleTimeWrap, DEFAULT_MAX_PAYLOAD};
///
/// let mut receiver = Receiver::new(SampleTimeWrap::FromProductCode, DEFAULT_MAX_PAYLOAD);
/// // GoToMeasurementAck: FA FF 11 00 F0.
/// receiver.handle_input(Duration::from_millis(5), &[0xFA, 0xFF, 0x11, 0x00, 0xF0]);
/// assert_eq!(receiver.poll_event(), Some(Event::Measuring));
/// ```
pub struct Receiver {
    core: Core,
    events: VecDeque<Event>,
}

impl Receiver {
    /// SampleTimeFine wraps as `sample_time_wrap` says (at 2^32 until a product code is seen,
    /// if it is to come from the product code); frames longer than `max_payload` are dropped.
    pub fn new(sample_time_wrap: SampleTimeWrap, max_payload: usize) -> Self {
        Self {
            core: Core::new(sample_time_wrap, max_payload),
            events: VecDeque::with_capacity(64),
        }
    }

    /// Feeds bytes read from the device at `now` (`Duration::ZERO` if untimed).
    pub fn handle_input(&mut self, now: Duration, mut bytes: &[u8]) {
        while self
            .core
            .next_frame(now, &mut bytes, &mut self.events)
            .is_some()
        {}
    }

    /// Drain after every `handle_input`: undrained events accumulate.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    pub fn stats(&self) -> ReceiverStats {
        self.core.stats()
    }
}

/// Everything a receiver keeps but its event queue, which the device shares with its own
/// events so that both come out in the order they happened.
pub(crate) struct Core {
    framer: Framer,
    /// Apart from the framer, whose frames borrow it.
    history: History,
}

/// What the receiver remembers from earlier frames.
struct History {
    sample_time_wrap: SampleTimeWrap,
    clock: Unwrapper,
    last_counter: Option<u16>,
    stats: ReceiverStats,
}

impl Core {
    pub(crate) fn new(sample_time_wrap: SampleTimeWrap, max_payload: usize) -> Self {
        let modulus = match sample_time_wrap {
            SampleTimeWrap::FromProductCode => U32_TICKS,
            SampleTimeWrap::Ticks(ticks) => ticks,
        };
        Self {
            framer: Framer::new(max_payload),
            history: History {
                sample_time_wrap,
                clock: Unwrapper::new(modulus),
                last_counter: None,
                stats: ReceiverStats::default(),
            },
        }
    }

    /// Where SampleTimeFine wraps, as far as is known now.
    pub(crate) fn sample_time_modulus(&self) -> u64 {
        self.history.clock.modulus()
    }

    pub(crate) fn stats(&self) -> ReceiverStats {
        ReceiverStats {
            framer: self.framer.stats(),
            ..self.history.stats
        }
    }

    /// Frames the next message in `bytes` and queues its data events; the frame is returned
    /// too, for the device's handshake. `None` once `bytes` holds no complete frame.
    pub(crate) fn next_frame(
        &mut self,
        now: Duration,
        bytes: &mut &[u8],
        events: &mut VecDeque<Event>,
    ) -> Option<Result<Frame<'_>, FrameError>> {
        let frame = match self.framer.decode(bytes)? {
            Ok(frame) => frame,
            Err(e) => {
                events.push_back(Event::FrameDropped(e));
                return Some(Err(e));
            }
        };
        if let Some(event) = self.history.event(now, frame) {
            events.push_back(event);
        }
        Some(Ok(frame))
    }
}

impl History {
    fn event(&mut self, now: Duration, frame: Frame<'_>) -> Option<Event> {
        match frame.mid {
            mid::MT_DATA2 => Some(match Measurement::from_payload(frame.payload) {
                Ok(data) => Event::Measurement(self.measurement(now, data)),
                Err(e) => {
                    self.stats.bad_measurements += 1;
                    Event::BadMeasurement(e)
                }
            }),
            mid::PRODUCT_CODE => {
                let code = ProductCode::from_bytes(frame.payload);
                let wrap = code.sample_time_wrap();
                let adopt = self.sample_time_wrap == SampleTimeWrap::FromProductCode;
                if adopt && wrap != self.clock.modulus() {
                    self.clock = Unwrapper::new(wrap);
                }
                Some(Event::ProductCode(code))
            }
            mid::OUTPUT_CONFIGURATION => OutputConfiguration::from_payload(frame.payload)
                .ok()
                .map(Event::OutputConfiguration),
            mid::GO_TO_MEASUREMENT_ACK => {
                // The device restarts its stream: the counters' history is no longer theirs.
                self.last_counter = None;
                self.clock.reset();
                Some(Event::Measuring)
            }
            _ => None,
        }
    }

    fn measurement(&mut self, now: Duration, data: Measurement) -> ImuMeasurement {
        let lost_packets = match (self.last_counter, data.packet_counter) {
            (Some(last), Some(counter)) => counter.wrapping_sub(last).wrapping_sub(1),
            _ => 0,
        };
        if data.packet_counter.is_some() {
            self.last_counter = data.packet_counter;
        }
        self.stats.measurements += 1;
        self.stats.lost_packets += u64::from(lost_packets);
        ImuMeasurement {
            received_at: now,
            // Clamped at zero: only a counter stepping back past its first reading goes below.
            sample_time: data
                .sample_time_fine
                .map(|raw| self.clock.unwrap(u64::from(raw)).max(0) as u64),
            lost_packets,
            data,
        }
    }
}
