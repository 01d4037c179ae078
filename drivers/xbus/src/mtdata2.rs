//! MTData2 payload: a sequence of `DataID u16 | size u8 | data`, decoded without allocating.

use core::fmt;

use crate::data_id::{CoordinateSystem, DataId, DataType, Layout, Precision};

/// `N` floating components with the reference frame and precision they were sent in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Values<const N: usize> {
    pub values: [f64; N],
    pub frame: CoordinateSystem,
    pub precision: Precision,
}

/// UTC time as the device reports it (`flags` bit 2 = valid UTC).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct UtcTime {
    pub nanoseconds: u32,
    pub year: u16,
    pub month: u8,
    pub day: u8,
    pub hour: u8,
    pub minute: u8,
    pub second: u8,
    pub flags: u8,
}

/// One decoded MTData2 packet. Raw variants borrow the payload.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DataItem<'a> {
    /// °C.
    Temperature(Values<1>),
    UtcTime(UtcTime),
    PacketCounter(u16),
    /// 10 kHz ticks; wraps (see `SampleTimeWrap`).
    SampleTimeFine(u32),
    /// Seconds.
    SampleTimeCoarse(u32),
    /// (w, x, y, z).
    Quaternion(Values<4>),
    /// Row-major as sent.
    RotationMatrix(Values<9>),
    /// Roll, pitch, yaw in degrees.
    EulerAngles(Values<3>),
    /// Pascal.
    BaroPressure(u32),
    /// m/s over the output interval.
    DeltaV(Values<3>),
    /// m/s², gravity included.
    Acceleration(Values<3>),
    /// m/s², gravity removed.
    FreeAcceleration(Values<3>),
    AccelerationHr(Values<3>),
    /// m.
    AltitudeEllipsoid(Values<1>),
    /// m.
    PositionEcef(Values<3>),
    /// Degrees.
    LatLon(Values<2>),
    GnssPvtData(&'a [u8]),
    GnssSatInfo(&'a [u8]),
    /// rad/s.
    RateOfTurn(Values<3>),
    /// Orientation increment (w, x, y, z) over the output interval.
    DeltaQ(Values<4>),
    RateOfTurnHr(Values<3>),
    /// Normalised units.
    MagneticField(Values<3>),
    /// m/s.
    VelocityXyz(Values<3>),
    StatusByte(u8),
    StatusWord(u32),
    DeviceId(u32),
    LocationId(u16),
    /// An identifier this crate does not know, skipped by its size.
    Unknown {
        id: DataId,
        data: &'a [u8],
    },
}

/// Why an MTData2 payload could not be fully decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mtdata2Error {
    /// Fewer than the 3 header bytes remain at `offset`.
    TruncatedHeader { offset: usize, remaining: usize },
    /// The packet at `offset` announces more bytes than remain.
    Truncated {
        id: DataId,
        offset: usize,
        size: usize,
        remaining: usize,
    },
    /// The packet's size does not match its type and precision.
    BadSize {
        id: DataId,
        size: usize,
        expected: usize,
    },
    /// Coordinate bits 0xC are reserved.
    BadCoordinates { id: DataId },
}

impl fmt::Display for Mtdata2Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::TruncatedHeader { offset, remaining } => write!(
                f,
                "MTData2 payload ends {remaining} byte(s) into a packet header at offset {offset}: the frame is truncated or corrupt"
            ),
            Self::Truncated { id, offset, size, remaining } => write!(
                f,
                "MTData2 packet {id} at offset {offset} announces {size} bytes but only {remaining} remain: the frame is truncated or corrupt"
            ),
            Self::BadSize { id, size, expected } => write!(
                f,
                "MTData2 packet {id} has {size} bytes, expected {expected}: the device output format does not match its identifier"
            ),
            Self::BadCoordinates { id } => write!(
                f,
                "MTData2 packet {id} uses the reserved coordinate-system bits 0xC: reconfigure the output with ENU, NED or NWU"
            ),
        }
    }
}

impl std::error::Error for Mtdata2Error {}

/// Iterates the packets of one MTData2 payload. Stops after the first error.
#[derive(Debug, Clone)]
pub struct Items<'a> {
    payload: &'a [u8],
    offset: usize,
}

/// Decodes `payload` (the data of a MID 0x36 frame) lazily.
pub fn items(payload: &[u8]) -> Items<'_> {
    Items { payload, offset: 0 }
}

impl<'a> Iterator for Items<'a> {
    type Item = Result<DataItem<'a>, Mtdata2Error>;

    fn next(&mut self) -> Option<Self::Item> {
        let rest = &self.payload[self.offset..];
        if rest.is_empty() {
            return None;
        }
        let offset = self.offset;
        // Any error ends the iteration: nothing after it can be trusted.
        self.offset = self.payload.len();
        if rest.len() < 3 {
            return Some(Err(Mtdata2Error::TruncatedHeader {
                offset,
                remaining: rest.len(),
            }));
        }
        let id = DataId(u16::from_be_bytes([rest[0], rest[1]]));
        let size = usize::from(rest[2]);
        let Some(data) = rest.get(3..3 + size) else {
            return Some(Err(Mtdata2Error::Truncated {
                id,
                offset,
                size,
                remaining: rest.len() - 3,
            }));
        };
        let item = decode_item(id, data);
        if item.is_ok() {
            self.offset = offset + 3 + size;
        }
        Some(item)
    }
}

/// Decodes one packet's data.
pub fn decode_item(id: DataId, data: &[u8]) -> Result<DataItem<'_>, Mtdata2Error> {
    let Some(data_type) = id.data_type() else {
        return Ok(DataItem::Unknown { id, data });
    };
    match data_type.layout() {
        Layout::Floats(n) => {
            let expected = n * id.precision().component_size();
            if data.len() != expected {
                return Err(Mtdata2Error::BadSize {
                    id,
                    size: data.len(),
                    expected,
                });
            }
            let frame = id
                .coordinates()
                .ok_or(Mtdata2Error::BadCoordinates { id })?;
            Ok(float_item(
                data_type,
                FloatReader {
                    data,
                    precision: id.precision(),
                    frame,
                },
            ))
        }
        Layout::Fixed(expected) if data.len() != expected => Err(Mtdata2Error::BadSize {
            id,
            size: data.len(),
            expected,
        }),
        Layout::Fixed(_) | Layout::Raw => Ok(fixed_item(data_type, data)),
    }
}

struct FloatReader<'a> {
    data: &'a [u8],
    precision: Precision,
    frame: CoordinateSystem,
}

impl FloatReader<'_> {
    fn values<const N: usize>(&self) -> Values<N> {
        let size = self.precision.component_size();
        let mut values = [0.0; N];
        for (v, chunk) in values.iter_mut().zip(self.data.chunks_exact(size)) {
            *v = self.precision.read(chunk);
        }
        Values {
            values,
            frame: self.frame,
            precision: self.precision,
        }
    }
}

fn float_item<'a>(data_type: DataType, r: FloatReader<'_>) -> DataItem<'a> {
    match data_type {
        DataType::Temperature => DataItem::Temperature(r.values()),
        DataType::AltitudeEllipsoid => DataItem::AltitudeEllipsoid(r.values()),
        DataType::LatLon => DataItem::LatLon(r.values()),
        DataType::EulerAngles => DataItem::EulerAngles(r.values()),
        DataType::DeltaV => DataItem::DeltaV(r.values()),
        DataType::Acceleration => DataItem::Acceleration(r.values()),
        DataType::FreeAcceleration => DataItem::FreeAcceleration(r.values()),
        DataType::AccelerationHr => DataItem::AccelerationHr(r.values()),
        DataType::PositionEcef => DataItem::PositionEcef(r.values()),
        DataType::RateOfTurn => DataItem::RateOfTurn(r.values()),
        DataType::RateOfTurnHr => DataItem::RateOfTurnHr(r.values()),
        DataType::MagneticField => DataItem::MagneticField(r.values()),
        DataType::VelocityXyz => DataItem::VelocityXyz(r.values()),
        DataType::Quaternion => DataItem::Quaternion(r.values()),
        DataType::DeltaQ => DataItem::DeltaQ(r.values()),
        _ => DataItem::RotationMatrix(r.values()),
    }
}

fn be_u32(d: &[u8]) -> u32 {
    u32::from_be_bytes([d[0], d[1], d[2], d[3]])
}

fn be_u16(d: &[u8]) -> u16 {
    u16::from_be_bytes([d[0], d[1]])
}

fn fixed_item(data_type: DataType, d: &[u8]) -> DataItem<'_> {
    match data_type {
        DataType::UtcTime => DataItem::UtcTime(UtcTime {
            nanoseconds: be_u32(d),
            year: be_u16(&d[4..]),
            month: d[6],
            day: d[7],
            hour: d[8],
            minute: d[9],
            second: d[10],
            flags: d[11],
        }),
        DataType::PacketCounter => DataItem::PacketCounter(be_u16(d)),
        DataType::LocationId => DataItem::LocationId(be_u16(d)),
        DataType::StatusByte => DataItem::StatusByte(d[0]),
        DataType::SampleTimeFine => DataItem::SampleTimeFine(be_u32(d)),
        DataType::SampleTimeCoarse => DataItem::SampleTimeCoarse(be_u32(d)),
        DataType::BaroPressure => DataItem::BaroPressure(be_u32(d)),
        DataType::StatusWord => DataItem::StatusWord(be_u32(d)),
        DataType::DeviceId => DataItem::DeviceId(be_u32(d)),
        DataType::GnssPvtData => DataItem::GnssPvtData(d),
        _ => DataItem::GnssSatInfo(d),
    }
}

/// Appends one packet carrying `values` (in the precision of `id`) to an MTData2 payload.
/// Returns false, appending nothing, when `id` is not a float type taking `values.len()`
/// components.
pub fn encode_floats(id: DataId, values: &[f64], out: &mut Vec<u8>) -> bool {
    let fits = id
        .data_type()
        .is_some_and(|t| t.layout() == Layout::Floats(values.len()));
    if !fits || id.coordinates().is_none() {
        return false;
    }
    let precision = id.precision();
    out.extend_from_slice(&id.0.to_be_bytes());
    out.push((values.len() * precision.component_size()) as u8);
    for &v in values {
        precision.write(v, out);
    }
    true
}

/// Appends one packet with raw data (integers, UTC time, GNSS blobs). Data longer than 255
/// bytes cannot be sent in one packet and is truncated to 255.
pub fn encode_raw(id: DataId, data: &[u8], out: &mut Vec<u8>) {
    let data = &data[..data.len().min(255)];
    out.extend_from_slice(&id.0.to_be_bytes());
    out.push(data.len() as u8);
    out.extend_from_slice(data);
}

/// Appends the packet for an integer item.
pub fn encode_u32(data_type: DataType, value: u32, out: &mut Vec<u8>) {
    let id = DataId(data_type.type_bits());
    match data_type.layout() {
        Layout::Fixed(1) => encode_raw(id, &[value as u8], out),
        Layout::Fixed(2) => encode_raw(id, &(value as u16).to_be_bytes(), out),
        _ => encode_raw(id, &value.to_be_bytes(), out),
    }
}

impl UtcTime {
    pub fn to_bytes(&self) -> [u8; 12] {
        let mut b = [0; 12];
        b[..4].copy_from_slice(&self.nanoseconds.to_be_bytes());
        b[4..6].copy_from_slice(&self.year.to_be_bytes());
        b[6..].copy_from_slice(&[
            self.month,
            self.day,
            self.hour,
            self.minute,
            self.second,
            self.flags,
        ]);
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_identifier_is_skipped_by_size() {
        let payload = [0x12, 0x34, 0x02, 0xAA, 0xBB, 0x10, 0x20, 0x02, 0x01, 0x02];
        let got: Vec<_> = items(&payload).collect();
        assert_eq!(
            got,
            vec![
                Ok(DataItem::Unknown {
                    id: DataId(0x1234),
                    data: &[0xAA, 0xBB]
                }),
                Ok(DataItem::PacketCounter(0x0102)),
            ]
        );
    }

    #[test]
    fn truncation_is_a_typed_error_and_ends_iteration() {
        let payload = [0x10, 0x20, 0x02, 0x01, 0x02, 0x40, 0x20, 0x0C, 0x00];
        let mut it = items(&payload);
        assert_eq!(it.next(), Some(Ok(DataItem::PacketCounter(0x0102))));
        assert_eq!(
            it.next(),
            Some(Err(Mtdata2Error::Truncated {
                id: DataId(0x4020),
                offset: 5,
                size: 12,
                remaining: 1
            }))
        );
        assert_eq!(it.next(), None);
        assert_eq!(
            items(&[0x10, 0x20]).next(),
            Some(Err(Mtdata2Error::TruncatedHeader {
                offset: 0,
                remaining: 2
            }))
        );
    }

    #[test]
    fn size_must_match_precision() {
        // Acceleration flagged Float64 but carrying Float32-sized data.
        let mut payload = vec![0x40, 0x23, 12];
        payload.extend_from_slice(&[0; 12]);
        assert_eq!(
            items(&payload).next(),
            Some(Err(Mtdata2Error::BadSize {
                id: DataId(0x4023),
                size: 12,
                expected: 24
            }))
        );
    }

    #[test]
    fn reserved_coordinate_bits_are_rejected() {
        let mut payload = vec![0x40, 0x2C, 12];
        payload.extend_from_slice(&[0; 12]);
        assert_eq!(
            items(&payload).next(),
            Some(Err(Mtdata2Error::BadCoordinates { id: DataId(0x402C) }))
        );
    }
}
