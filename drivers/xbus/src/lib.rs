//! Xsens Xbus / MTData2, sans-IO: bytes in, typed events out. No I/O, no clock (time is passed
//! in), no allocation per message after warm-up.
//!
//! - [`Framer`]: frames from arbitrary chunks (normal and extended length, checksum, size guard,
//!   one-byte resynchronisation).
//! - [`mtdata2::items`]: every MTData2 packet as a [`DataItem`], in all four precisions, with its
//!   coordinate flag; [`Measurement`] gathers the fields the daemon uses.
//! - [`Command`]: GoToConfig, GoToMeasurement, SetOutputConfiguration, ReqDID, ReqProductCode,
//!   ReqFWRev, SetBaudrate, WakeUpAck, Reset; [`encode_frame`] for anything else.
//! - [`Device`]: handshake, configuration check, measurement stream with packet-loss counting
//!   and SampleTimeFine unwrapping.
//! - `emulator::Emulator` (feature `emulator`, on by default): a device answering all of the
//!   above and streaming MTData2 built from caller-supplied samples.
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
//!     while let Some(frame) = device.poll_transmit() {
//!         port.handle_input(frame.as_bytes()); // write to the serial port
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
