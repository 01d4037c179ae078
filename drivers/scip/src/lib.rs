//! Hokuyo SCIP 2.0, sans-IO: command encoder, incremental reply decoder, device state machine
//! and (feature `emulator`) a sensor emulator. Bytes in, typed events out; time is passed in.

pub mod command;
pub mod decoder;
pub mod encoding;

pub use command::{Command, DataKind, EncodeError, StepRange, TimeMode};
pub use decoder::{Body, DecodeError, Decoder, InfoLines, Reply, ScanData, Status, StreamEcho};
pub mod device;
pub mod params;
pub mod timestamp;

pub use device::{
    ClockSample, Detection, Device, DeviceConfig, DeviceError, DeviceEvent, DeviceStats, Phase,
    Scan,
};
pub use params::{ParameterError, Parameters, Version};
pub use timestamp::TimestampUnwrapper;

#[cfg(feature = "emulator")]
pub mod emulator;
#[cfg(feature = "emulator")]
pub use emulator::{Emulator, Model, ScanLengthError};
