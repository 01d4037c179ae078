//! Host-to-device configuration messages.

use core::fmt;

use crate::data_id::DataId;
use crate::frame::{checksum_residue, mid, BUS_ID, PREAMBLE};

/// Largest number of entries SetOutputConfiguration accepts.
pub const MAX_OUTPUTS: usize = 32;
/// Output frequency meaning "with every packet" (PacketCounter, SampleTimeFine, StatusWord).
pub const EVERY_PACKET: u16 = 0xFFFF;

/// One requested output: identifier including precision/coordinate bits, and frequency in Hz.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct OutputEntry {
    pub id: DataId,
    pub frequency: u16,
}

/// An output configuration of at most 32 entries, stored inline.
#[derive(Clone, Copy, Eq)]
pub struct OutputConfiguration {
    entries: [OutputEntry; MAX_OUTPUTS],
    len: usize,
}

/// More than 32 outputs were requested.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TooManyOutputs;

impl fmt::Display for TooManyOutputs {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "xbus output configuration holds at most {MAX_OUTPUTS} entries: request fewer outputs"
        )
    }
}

impl std::error::Error for TooManyOutputs {}

impl PartialEq for OutputConfiguration {
    fn eq(&self, other: &Self) -> bool {
        self.entries() == other.entries()
    }
}

impl Default for OutputConfiguration {
    fn default() -> Self {
        Self {
            entries: [OutputEntry {
                id: DataId(0),
                frequency: 0,
            }; MAX_OUTPUTS],
            len: 0,
        }
    }
}

impl fmt::Debug for OutputConfiguration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.entries()).finish()
    }
}

impl fmt::Display for OutputConfiguration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, e) in self.entries().iter().enumerate() {
            let sep = if i == 0 { "" } else { ", " };
            write!(f, "{sep}0x{:04X}@{}", e.id.0, e.frequency)?;
        }
        Ok(())
    }
}

impl OutputConfiguration {
    pub fn new(entries: &[OutputEntry]) -> Result<Self, TooManyOutputs> {
        let mut c = Self::default();
        for &e in entries {
            c.push(e)?;
        }
        Ok(c)
    }

    pub fn push(&mut self, entry: OutputEntry) -> Result<(), TooManyOutputs> {
        let slot = self.entries.get_mut(self.len).ok_or(TooManyOutputs)?;
        *slot = entry;
        self.len += 1;
        Ok(())
    }

    pub fn entries(&self) -> &[OutputEntry] {
        &self.entries[..self.len]
    }

    /// Parses the payload of SetOutputConfiguration or its 0xC1 acknowledgement. A trailing
    /// partial entry is ignored; more than 32 entries is an error.
    pub fn from_payload(payload: &[u8]) -> Result<Self, TooManyOutputs> {
        let mut c = Self::default();
        for pair in payload.chunks_exact(4) {
            c.push(OutputEntry {
                id: DataId(u16::from_be_bytes([pair[0], pair[1]])),
                frequency: u16::from_be_bytes([pair[2], pair[3]]),
            })?;
        }
        Ok(c)
    }

    /// Writes the (DataID, frequency) pairs and returns how many bytes that took.
    fn write_payload(&self, out: &mut [u8; 4 * MAX_OUTPUTS]) -> usize {
        for (e, slot) in self.entries().iter().zip(out.chunks_exact_mut(4)) {
            slot[..2].copy_from_slice(&e.id.0.to_be_bytes());
            slot[2..].copy_from_slice(&e.frequency.to_be_bytes());
        }
        4 * self.len
    }
}

/// Baud rate codes of SetBaudrate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Baudrate {
    B115200,
    B230400,
    B460800,
    B921600,
    B2000000,
    B4000000,
}

impl Baudrate {
    pub fn code(self) -> u8 {
        match self {
            Self::B115200 => 0x02,
            Self::B230400 => 0x01,
            Self::B460800 => 0x00,
            Self::B921600 => 0x80,
            Self::B2000000 => 0x0C,
            Self::B4000000 => 0x0D,
        }
    }

    pub fn bits_per_second(self) -> u32 {
        match self {
            Self::B115200 => 115_200,
            Self::B230400 => 230_400,
            Self::B460800 => 460_800,
            Self::B921600 => 921_600,
            Self::B2000000 => 2_000_000,
            Self::B4000000 => 4_000_000,
        }
    }
}

/// A message the host sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    GoToConfig,
    GoToMeasurement,
    ReqDid,
    ReqProductCode,
    ReqFwRev,
    SetBaudrate(Baudrate),
    WakeUpAck,
    Reset,
    SetOutputConfiguration(OutputConfiguration),
}

impl Command {
    pub fn mid(&self) -> u8 {
        match self {
            Self::GoToConfig => mid::GO_TO_CONFIG,
            Self::GoToMeasurement => mid::GO_TO_MEASUREMENT,
            Self::ReqDid => mid::REQ_DID,
            Self::ReqProductCode => mid::REQ_PRODUCT_CODE,
            Self::ReqFwRev => mid::REQ_FW_REV,
            Self::SetBaudrate(_) => mid::SET_BAUDRATE,
            Self::WakeUpAck => mid::WAKE_UP_ACK,
            Self::Reset => mid::RESET,
            Self::SetOutputConfiguration(_) => mid::SET_OUTPUT_CONFIGURATION,
        }
    }

    /// The MID of the device's positive answer.
    pub fn reply_mid(&self) -> u8 {
        match self {
            Self::WakeUpAck => mid::WAKE_UP_ACK,
            other => other.mid() + 1,
        }
    }

    /// Appends the complete frame to `out`.
    pub fn encode(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(self.to_frame().as_bytes());
    }

    /// The complete frame, built without allocating.
    pub fn to_frame(&self) -> CommandFrame {
        let mut payload = [0u8; 4 * MAX_OUTPUTS];
        let len = match self {
            Self::SetBaudrate(b) => {
                payload[0] = b.code();
                1
            }
            Self::SetOutputConfiguration(c) => c.write_payload(&mut payload),
            _ => 0,
        };
        // At most 128 payload bytes: always a normal-length frame.
        let mut frame = CommandFrame {
            bytes: [0; COMMAND_FRAME_CAPACITY],
            len: len + 5,
        };
        frame.bytes[..4].copy_from_slice(&[PREAMBLE, BUS_ID, self.mid(), len as u8]);
        frame.bytes[4..4 + len].copy_from_slice(&payload[..len]);
        frame.bytes[4 + len] = checksum_residue(&frame.bytes[1..4 + len]).wrapping_neg();
        frame
    }
}

const COMMAND_FRAME_CAPACITY: usize = 5 + 4 * MAX_OUTPUTS;

/// One encoded host message, stored inline so it can be queued without allocating.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct CommandFrame {
    bytes: [u8; COMMAND_FRAME_CAPACITY],
    len: usize,
}

impl CommandFrame {
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

impl fmt::Debug for CommandFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "CommandFrame({:02X?})", self.as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_output_configuration_matches_the_documented_example() {
        let c = OutputConfiguration::new(&[
            OutputEntry {
                id: DataId(0x1020),
                frequency: EVERY_PACKET,
            },
            OutputEntry {
                id: DataId(0x1060),
                frequency: EVERY_PACKET,
            },
            OutputEntry {
                id: DataId(0x2010),
                frequency: 400,
            },
            OutputEntry {
                id: DataId(0x4010),
                frequency: 400,
            },
            OutputEntry {
                id: DataId(0x8030),
                frequency: 400,
            },
            OutputEntry {
                id: DataId(0xE020),
                frequency: EVERY_PACKET,
            },
        ])
        .unwrap();
        let mut out = Vec::new();
        Command::SetOutputConfiguration(c).encode(&mut out);
        let expected = [
            0xFA, 0xFF, 0xC0, 0x18, 0x10, 0x20, 0xFF, 0xFF, 0x10, 0x60, 0xFF, 0xFF, 0x20, 0x10,
            0x01, 0x90, 0x40, 0x10, 0x01, 0x90, 0x80, 0x30, 0x01, 0x90, 0xE0, 0x20, 0xFF, 0xFF,
            0xAC,
        ];
        assert_eq!(out, expected);
    }

    #[test]
    fn baudrate_frame_carries_its_code() {
        let mut out = Vec::new();
        Command::SetBaudrate(Baudrate::B921600).encode(&mut out);
        assert_eq!(out, [0xFA, 0xFF, 0x18, 0x01, 0x80, 0x68]);
    }

    #[test]
    fn thirty_three_outputs_are_refused() {
        let e = OutputEntry {
            id: DataId(0x1020),
            frequency: 1,
        };
        assert_eq!(OutputConfiguration::new(&[e; 33]), Err(TooManyOutputs));
        assert!(OutputConfiguration::new(&[e; 32]).is_ok());
    }
}
