//! Xsens Xbus / MTData2, sans-IO: bytes in, typed events out. No I/O, no clock (time is passed
//! in), no allocation per message after warm-up.
//!
//! - [`Framer`]: frames from arbitrary chunks (normal and extended length, checksum, size guard,
//!   one-byte resynchronisation).
//! - [`mtdata2::items`]: every MTData2 packet as a [`DataItem`], in all four precisions, with its
//!   coordinate flag; [`Measurement`] gathers the fields the daemon uses.
//! - [`Command`]: GoToConfig, GoToMeasurement, SetOutputConfiguration, ReqDID, ReqProductCode,
//!   ReqFWRev, SetBaudrate, WakeUpAck, Reset; [`encode_frame`] for anything else.
//! - [`Receiver`]: received bytes to data events, with packet-loss counting and SampleTimeFine
//!   unwrapping.
//! - [`Device`]: handshake and configuration check around a receiver.
//! - `emulator::Emulator` (feature `emulator`, off by default): a device answering all of the
//!   above and streaming MTData2 built from caller-supplied samples.
//!
//! # The contract
//!
//! This crate and `scip` share one contract, in the manner of quinn-proto's `Connection`. The
//! caller owns the port and the clock; time is a [`Duration`](core::time::Duration) of host
//! monotonic time since an epoch of the caller's choosing, `Duration::ZERO` meaning "no host
//! time" (an untimed raw dump).
//!
//! - [`Device::new`]`(config, now)` starts the handshake; [`Device::restart`]`(now)` runs it
//!   again.
//! - [`Device::handle_input`]`(now, bytes)` with every chunk read from the port, `now` being
//!   when it was read.
//! - [`Device::poll_transmit`]`(now)` until `None`, writing each slice to the port.
//! - [`Device::poll_timeout`] says when to call [`Device::handle_timeout`]`(now)`.
//! - [`Device::poll_event`] until `None` after each of the calls above.
//! - [`Device::stats`] for health reporting.
//!
//! A [`Receiver`] is the passive half: [`Receiver::handle_input`] and [`Receiver::poll_event`],
//! no transmit, no timeouts. The device runs every byte it receives through the receiver's
//! code, in every phase of the handshake, and never resets it, so a `Receiver` built with the
//! device's `sample_time_wrap` and `max_payload` and fed the same `(now, bytes)` sequence since
//! its creation emits the same *data events* in the same order: [`Event::ProductCode`],
//! [`Event::OutputConfiguration`], [`Event::Measuring`], [`Event::Measurement`],
//! [`Event::FrameDropped`] and [`Event::BadMeasurement`]. That is what makes replaying recorded
//! received bytes reproduce a live run. The other events come from the device's handshake only.
//! A new link (a reopened port) gets a new `Device`.
//!
//! Driving a device (the serial port is the caller's):
//!
//! ```
//! use std::time::Duration;
//! use xbus::emulator::{Emulator, EmulatorOptions, Sample};
//! use xbus::{Device, DeviceConfig, Event};
//!
//! let mut device = Device::new(DeviceConfig::default(), Duration::ZERO);
//! let mut port = Emulator::new(EmulatorOptions::mti_g_710());
//! let mut read = Vec::new();
//! for step in 0..10u32 {
//!     let now = Duration::from_millis(u64::from(step) * 10);
//!     while let Some(bytes) = device.poll_transmit(now) {
//!         port.handle_input(bytes); // write to the serial port
//!     }
//!     port.push_sample(&Sample::from_rates(step * 100, [0.0, 0.0, -9.81], [0.0; 3], 0.01));
//!     port.drain_output(&mut read); // read from the serial port
//!     device.handle_input(now, &read);
//!     read.clear();
//!     if device.poll_timeout().is_some_and(|t| t <= now) {
//!         device.handle_timeout(now);
//!     }
//!     while let Some(event) = device.poll_event() {
//!         if let Event::Measurement(m) = event {
//!             assert!(m.data.delta_v.is_some() && m.sample_time.is_some());
//!         }
//!     }
//! }
//! assert!(device.is_measuring());
//! ```

pub mod command;
pub mod data_id;
pub mod device;
#[cfg(feature = "emulator")]
pub mod emulator;
pub mod frame;
pub mod measurement;
pub mod mtdata2;
pub mod receiver;

pub use command::{
    Baudrate, Command, CommandFrame, OutputConfiguration, OutputEntry, TooManyOutputs,
    EVERY_PACKET, MAX_OUTPUTS,
};
pub use data_id::{CoordinateSystem, DataId, DataType, Precision};
pub use device::{
    Device, DeviceConfig, DeviceInfo, DeviceStats, Error, ErrorCode, Event, FirmwareRevision,
    ImuMeasurement, ImuOutput, ProductCode, SampleTimeWrap, ONE_DAY_TICKS, U32_TICKS,
};
pub use frame::{
    encode_frame, mid, Frame, FrameError, Framer, FramerStats, PayloadTooLong, DEFAULT_MAX_PAYLOAD,
};
pub use measurement::Measurement;
pub use mtdata2::{items, DataItem, Items, Mtdata2Error, UtcTime, Values};
pub use receiver::{Receiver, ReceiverStats};
