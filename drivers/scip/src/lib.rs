//! Hokuyo SCIP 2.0, sans-IO: command encoder, incremental reply decoder, device state machine,
//! passive receiver and (feature `emulator`) a sensor emulator. Bytes in, typed events out; time
//! is passed in.
//!
//! # The contract
//!
//! This crate and `xbus` share one contract, in the manner of quinn-proto's `Connection`. The
//! caller owns the port and the clock; time is a [`Duration`](std::time::Duration) of host
//! monotonic time since an epoch of the caller's choosing, `Duration::ZERO` meaning "no host
//! time" (an untimed raw dump).
//!
//! - [`Device::new`]`(config, now)` starts the handshake; [`Device::restart`]`(now)` runs it
//!   again and [`Device::stop`]`(now)` switches the laser off.
//! - [`Device::handle_input`]`(now, bytes)` with every chunk read from the port, `now` being
//!   when it was read.
//! - [`Device::poll_transmit`]`(now)` until `None`, writing each slice to the port.
//! - [`Device::poll_timeout`] says when to call [`Device::handle_timeout`]`(now)`.
//! - [`Device::poll_event`] until `None` after each of the calls above.
//! - [`Device::stats`] for health reporting.
//!
//! A [`Receiver`] is the passive half: [`Receiver::handle_input`] and [`Receiver::poll_event`],
//! no transmit, no timeouts. The device runs every byte it receives through the receiver's
//! code, in every phase of the handshake, and never resets it, so a `Receiver` fed the same
//! `(now, bytes)` sequence as a `Device` since its creation emits the same *data events* in the
//! same order: [`Event::Parameters`], [`Event::ClockSample`], [`Event::Scan`],
//! [`Event::DecodeError`] and [`Event::Error`]`(`[`DeviceError::BadParameters`]`)`. That is what
//! makes replaying recorded received bytes reproduce a live run. The other events come from the
//! device's handshake only. A new link (a reopened port) gets a new `Device`.
//!
//! ```
//! use std::time::Duration;
//! use scip::{Device, DeviceConfig, Emulator, Event, Model, Phase};
//!
//! let mut device = Device::new(DeviceConfig::default(), Duration::ZERO);
//! let mut sensor = Emulator::new(Model::utm_30lx());
//! let mut read = Vec::new();
//! for step in 1..=40u64 {
//!     let now = Duration::from_millis(step * 5);
//!     while let Some(bytes) = device.poll_transmit(now) {
//!         sensor.handle_input(bytes); // write to the port
//!     }
//!     if device.phase() == Phase::Streaming {
//!         let steps = sensor.model().step_count();
//!         sensor.push_scan(step as u32 * 5, &vec![1500; steps], None).unwrap();
//!     }
//!     sensor.drain_output(&mut read); // read from the port
//!     device.handle_input(now, &read);
//!     read.clear();
//!     if device.poll_timeout().is_some_and(|t| t <= now) {
//!         device.handle_timeout(now);
//!     }
//!     while let Some(event) = device.poll_event() {
//!         if let Event::Scan(scan) = event {
//!             assert_eq!(scan.ranges_mm[0], 1500);
//!         }
//!     }
//! }
//! assert_eq!(device.phase(), Phase::Streaming);
//! ```

pub mod command;
pub mod decoder;
pub mod encoding;

pub use command::{Command, DataKind, EncodeError, StepRange, TimeMode};
pub use decoder::{Body, DecodeError, Decoder, InfoLines, Reply, ScanData, Status, StreamEcho};
pub mod device;
pub mod params;
pub mod receiver;

pub use device::{
    ClockSample, Detection, Device, DeviceConfig, DeviceError, DeviceStats, Event, Phase, Scan,
};
pub use params::{ParameterError, Parameters, Version};
pub use receiver::{Receiver, ReceiverStats};

#[cfg(feature = "emulator")]
pub mod emulator;
#[cfg(feature = "emulator")]
pub use emulator::{Emulator, Model, ScanLengthError};
