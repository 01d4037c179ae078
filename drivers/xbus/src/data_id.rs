//! MTData2 data identifiers: type (`id & 0xFFF0`), precision (`id & 0x3`), coordinates (`id & 0xC`).

use core::fmt;

/// How each floating-point component is sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Precision {
    #[default]
    Float32,
    /// Signed fixed point, 12 integer and 20 fraction bits, 4 bytes.
    Fp1220,
    /// Signed fixed point, 6 bytes: u32 fraction first, then i16 integer part.
    Fp1632,
    Float64,
}

impl Precision {
    pub const ALL: [Precision; 4] = [Self::Float32, Self::Fp1220, Self::Fp1632, Self::Float64];

    pub fn bits(self) -> u16 {
        match self {
            Self::Float32 => 0,
            Self::Fp1220 => 1,
            Self::Fp1632 => 2,
            Self::Float64 => 3,
        }
    }

    /// Bytes per component on the wire.
    pub fn component_size(self) -> usize {
        match self {
            Self::Float32 | Self::Fp1220 => 4,
            Self::Fp1632 => 6,
            Self::Float64 => 8,
        }
    }

    /// Reads one component; `bytes` must be exactly `component_size()` long.
    pub(crate) fn read(self, bytes: &[u8]) -> f64 {
        match self {
            Self::Float32 => f64::from(f32::from_be_bytes(array(bytes))),
            Self::Fp1220 => f64::from(i32::from_be_bytes(array(bytes))) / FP1220_ONE,
            Self::Fp1632 => {
                let fraction = u32::from_be_bytes(array(&bytes[..4]));
                let integer = i16::from_be_bytes(array(&bytes[4..6]));
                f64::from(integer) + f64::from(fraction) / FP1632_ONE
            }
            Self::Float64 => f64::from_be_bytes(array(bytes)),
        }
    }

    /// Appends one component, saturating at the fixed-point ranges.
    pub(crate) fn write(self, value: f64, out: &mut Vec<u8>) {
        match self {
            Self::Float32 => out.extend_from_slice(&(value as f32).to_be_bytes()),
            Self::Fp1220 => {
                out.extend_from_slice(&((value * FP1220_ONE).round() as i32).to_be_bytes())
            }
            Self::Fp1632 => {
                let raw = (value * FP1632_ONE).round() as i64;
                let raw = raw.clamp(
                    i64::from(i16::MIN) << 32,
                    (i64::from(i16::MAX) << 32) | 0xFFFF_FFFF,
                );
                out.extend_from_slice(&(raw as u32).to_be_bytes());
                out.extend_from_slice(&((raw >> 32) as i16).to_be_bytes());
            }
            Self::Float64 => out.extend_from_slice(&value.to_be_bytes()),
        }
    }
}

const FP1220_ONE: f64 = (1u64 << 20) as f64;
const FP1632_ONE: f64 = (1u64 << 32) as f64;

fn array<const N: usize>(bytes: &[u8]) -> [u8; N] {
    let mut a = [0; N];
    a.copy_from_slice(bytes);
    a
}

/// Reference frame flag of vector and orientation outputs. Reported with each value so the
/// caller converts; nothing is converted here.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum CoordinateSystem {
    #[default]
    Enu,
    Ned,
    Nwu,
}

impl CoordinateSystem {
    pub const ALL: [CoordinateSystem; 3] = [Self::Enu, Self::Ned, Self::Nwu];

    pub fn bits(self) -> u16 {
        match self {
            Self::Enu => 0x0,
            Self::Ned => 0x4,
            Self::Nwu => 0x8,
        }
    }
}

/// The measured quantity, without format bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataType {
    Temperature,
    UtcTime,
    PacketCounter,
    SampleTimeFine,
    SampleTimeCoarse,
    Quaternion,
    RotationMatrix,
    EulerAngles,
    BaroPressure,
    DeltaV,
    Acceleration,
    FreeAcceleration,
    AccelerationHr,
    AltitudeEllipsoid,
    PositionEcef,
    LatLon,
    GnssPvtData,
    GnssSatInfo,
    RateOfTurn,
    DeltaQ,
    RateOfTurnHr,
    MagneticField,
    VelocityXyz,
    StatusByte,
    StatusWord,
    DeviceId,
    LocationId,
}

/// Whether a type's components are floating values whose format bits matter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Layout {
    /// `n` components in the precision given by the identifier.
    Floats(usize),
    /// Fixed-size integer or raw content: format bits are ignored.
    Fixed(usize),
    /// Raw content of any size.
    Raw,
}

impl DataType {
    const TABLE: [(DataType, u16); 27] = [
        (Self::Temperature, 0x0810),
        (Self::UtcTime, 0x1010),
        (Self::PacketCounter, 0x1020),
        (Self::SampleTimeFine, 0x1060),
        (Self::SampleTimeCoarse, 0x1070),
        (Self::Quaternion, 0x2010),
        (Self::RotationMatrix, 0x2020),
        (Self::EulerAngles, 0x2030),
        (Self::BaroPressure, 0x3010),
        (Self::DeltaV, 0x4010),
        (Self::Acceleration, 0x4020),
        (Self::FreeAcceleration, 0x4030),
        (Self::AccelerationHr, 0x4040),
        (Self::AltitudeEllipsoid, 0x5020),
        (Self::PositionEcef, 0x5030),
        (Self::LatLon, 0x5040),
        (Self::GnssPvtData, 0x7010),
        (Self::GnssSatInfo, 0x7020),
        (Self::RateOfTurn, 0x8020),
        (Self::DeltaQ, 0x8030),
        (Self::RateOfTurnHr, 0x8040),
        (Self::MagneticField, 0xC020),
        (Self::VelocityXyz, 0xD010),
        (Self::StatusByte, 0xE010),
        (Self::StatusWord, 0xE020),
        (Self::DeviceId, 0xE080),
        (Self::LocationId, 0xE090),
    ];

    /// `id & 0xFFF0` of this type.
    pub fn type_bits(self) -> u16 {
        Self::TABLE
            .iter()
            .find(|(t, _)| *t == self)
            .map_or(0, |(_, bits)| *bits)
    }

    pub fn from_type_bits(bits: u16) -> Option<Self> {
        Self::TABLE
            .iter()
            .find(|(_, b)| *b == bits)
            .map(|(t, _)| *t)
    }

    /// Identifier with the given format. Format bits are meaningful only for float types.
    pub fn id(self, precision: Precision, coordinates: CoordinateSystem) -> DataId {
        let format = match self.layout() {
            Layout::Floats(_) => precision.bits() | coordinates.bits(),
            Layout::Fixed(_) | Layout::Raw => 0,
        };
        DataId(self.type_bits() | format)
    }

    pub(crate) fn layout(self) -> Layout {
        match self {
            Self::Temperature | Self::AltitudeEllipsoid => Layout::Floats(1),
            Self::LatLon => Layout::Floats(2),
            Self::EulerAngles
            | Self::DeltaV
            | Self::Acceleration
            | Self::FreeAcceleration
            | Self::AccelerationHr
            | Self::PositionEcef
            | Self::RateOfTurn
            | Self::RateOfTurnHr
            | Self::MagneticField
            | Self::VelocityXyz => Layout::Floats(3),
            Self::Quaternion | Self::DeltaQ => Layout::Floats(4),
            Self::RotationMatrix => Layout::Floats(9),
            Self::UtcTime => Layout::Fixed(12),
            Self::PacketCounter | Self::LocationId => Layout::Fixed(2),
            Self::StatusByte => Layout::Fixed(1),
            Self::SampleTimeFine
            | Self::SampleTimeCoarse
            | Self::BaroPressure
            | Self::StatusWord
            | Self::DeviceId => Layout::Fixed(4),
            Self::GnssPvtData | Self::GnssSatInfo => Layout::Raw,
        }
    }
}

/// A 16-bit MTData2 data identifier, as sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct DataId(pub u16);

impl DataId {
    pub fn data_type(self) -> Option<DataType> {
        DataType::from_type_bits(self.0 & 0xFFF0)
    }

    pub fn precision(self) -> Precision {
        Precision::ALL[usize::from(self.0 & 0x3)]
    }

    /// `None` for the reserved value 0xC.
    pub fn coordinates(self) -> Option<CoordinateSystem> {
        match self.0 & 0xC {
            0x0 => Some(CoordinateSystem::Enu),
            0x4 => Some(CoordinateSystem::Ned),
            0x8 => Some(CoordinateSystem::Nwu),
            _ => None,
        }
    }
}

impl fmt::Display for DataId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.data_type() {
            Some(t) => write!(f, "{t:?} (0x{:04X})", self.0),
            None => write!(f, "unknown data identifier 0x{:04X}", self.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fp1632_sends_fraction_first() {
        let mut out = Vec::new();
        Precision::Fp1632.write(-1.25, &mut out);
        // -1.25 = -2 + 0.75: fraction 0xC0000000, integer -2.
        assert_eq!(out, [0xC0, 0x00, 0x00, 0x00, 0xFF, 0xFE]);
        assert_eq!(Precision::Fp1632.read(&out), -1.25);
    }

    #[test]
    fn fp1220_scales_by_two_to_the_twenty() {
        let mut out = Vec::new();
        Precision::Fp1220.write(1.5, &mut out);
        assert_eq!(out, 0x0018_0000i32.to_be_bytes());
        assert_eq!(Precision::Fp1220.read(&out), 1.5);
    }

    #[test]
    fn identifiers_carry_format_bits() {
        let id = DataType::Acceleration.id(Precision::Fp1632, CoordinateSystem::Ned);
        assert_eq!(id, DataId(0x4026));
        assert_eq!(id.data_type(), Some(DataType::Acceleration));
        assert_eq!(id.precision(), Precision::Fp1632);
        assert_eq!(id.coordinates(), Some(CoordinateSystem::Ned));
        assert_eq!(
            DataType::PacketCounter.id(Precision::Float64, CoordinateSystem::Nwu),
            DataId(0x1020)
        );
    }
}
