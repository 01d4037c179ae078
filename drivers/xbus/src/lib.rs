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
//! - `emulator::Emulator` (feature `emulator`): a device answering all of the above.

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
