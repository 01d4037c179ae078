//! Host-to-sensor command lines.

use std::fmt;

/// How each step's measurement is encoded in a scan reply (the second letter of GD/GS/MD/MS/ME).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataKind {
    /// `D`: 3-character distances (0..262143 mm).
    Distance,
    /// `S`: 2-character distances (0..4095 mm).
    ShortDistance,
    /// `E`: 3-character distance then 3-character intensity per step.
    DistanceIntensity,
}

impl DataKind {
    pub fn letter(self) -> u8 {
        match self {
            DataKind::Distance => b'D',
            DataKind::ShortDistance => b'S',
            DataKind::DistanceIntensity => b'E',
        }
    }

    pub fn from_letter(letter: u8) -> Option<Self> {
        match letter {
            b'D' => Some(DataKind::Distance),
            b'S' => Some(DataKind::ShortDistance),
            b'E' => Some(DataKind::DistanceIntensity),
            _ => None,
        }
    }

    /// Characters per encoded value (distance or intensity).
    pub fn value_width(self) -> usize {
        match self {
            DataKind::ShortDistance => 2,
            DataKind::Distance | DataKind::DistanceIntensity => 3,
        }
    }

    /// Characters per step (an intensity doubles it).
    pub fn step_width(self) -> usize {
        match self {
            DataKind::DistanceIntensity => 6,
            _ => self.value_width(),
        }
    }
}

/// Steps requested from a scan: `start..=end`, merged `cluster` at a time (0 and 1 both mean
/// no merging).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StepRange {
    pub start: u16,
    pub end: u16,
    pub cluster: u8,
}

impl StepRange {
    /// Number of values a reply carries for this range (urg_library's `(end-start)/cluster+1`).
    pub fn value_count(&self) -> usize {
        if self.end < self.start {
            return 0;
        }
        usize::from(self.end - self.start) / usize::from(self.cluster.max(1)) + 1
    }
}

/// `TM` sub-commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TimeMode {
    /// `TM0`: enter adjust mode (laser off, only TM accepted).
    Enter,
    /// `TM1`: ask for the sensor's 24-bit millisecond counter.
    Request,
    /// `TM2`: leave adjust mode.
    Leave,
}

/// Every command the driver sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// `SCIP2.0`: switch a SCIP 1.1 sensor to SCIP 2.0.
    Scip2,
    /// `VV`: version lines.
    Version,
    /// `PP`: geometry parameters.
    Parameters,
    /// `II`: state lines.
    Info,
    /// `BM`: laser on.
    LaserOn,
    /// `QT`: laser off, stop streaming.
    Quit,
    /// `RS`: reset settings and the sensor timer.
    Reset,
    /// `TM0/1/2`.
    Time(TimeMode),
    /// `GD/GS/GE`: one scan.
    Get { data: DataKind, range: StepRange },
    /// `MD/MS/ME`: stream scans, skipping `interval` (0..=9) between sent scans, `count`
    /// (0..=99) scans or unlimited for 0.
    Stream {
        data: DataKind,
        range: StepRange,
        interval: u8,
        count: u8,
    },
}

/// A command that cannot be expressed in SCIP's fixed-width fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodeError {
    /// Step numbers are four decimal digits.
    StepTooLarge(u16),
    /// Cluster count and scan count are two digits.
    FieldTooLarge {
        field: &'static str,
        value: u8,
        max: u8,
    },
    /// The optional string is at most 16 printable characters without `;`.
    BadTag,
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            EncodeError::StepTooLarge(step) => {
                write!(f, "SCIP step {step} does not fit four digits: use a step of at most 9999")
            }
            EncodeError::FieldTooLarge { field, value, max } => write!(
                f,
                "SCIP {field} {value} does not fit its field: use a value of at most {max}"
            ),
            EncodeError::BadTag => f.write_str(
                "SCIP command string must be at most 16 printable ASCII characters without ';': shorten it",
            ),
        }
    }
}

impl std::error::Error for EncodeError {}

/// Longest optional string a command may carry.
pub const MAX_TAG: usize = 16;

impl Command {
    /// Appends the command line (with LF) to `out`.
    pub fn encode(&self, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        self.encode_tagged(None, out)
    }

    /// Appends the command line with an optional `;string` that the sensor echoes back.
    pub fn encode_tagged(&self, tag: Option<&str>, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        if let Some(tag) = tag {
            let valid = tag.len() <= MAX_TAG
                && tag.bytes().all(|b| (0x21..=0x7E).contains(&b) && b != b';');
            if !valid {
                return Err(EncodeError::BadTag);
            }
        }
        let mark = out.len();
        let result = self.encode_body(out);
        if result.is_err() {
            out.truncate(mark);
            return result;
        }
        if let Some(tag) = tag {
            out.push(b';');
            out.extend_from_slice(tag.as_bytes());
        }
        out.push(b'\n');
        Ok(())
    }

    fn encode_body(&self, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        match *self {
            Command::Scip2 => out.extend_from_slice(b"SCIP2.0"),
            Command::Version => out.extend_from_slice(b"VV"),
            Command::Parameters => out.extend_from_slice(b"PP"),
            Command::Info => out.extend_from_slice(b"II"),
            Command::LaserOn => out.extend_from_slice(b"BM"),
            Command::Quit => out.extend_from_slice(b"QT"),
            Command::Reset => out.extend_from_slice(b"RS"),
            Command::Time(mode) => out.extend_from_slice(match mode {
                TimeMode::Enter => b"TM0",
                TimeMode::Request => b"TM1",
                TimeMode::Leave => b"TM2",
            }),
            Command::Get { data, range } => {
                out.extend_from_slice(&[b'G', data.letter()]);
                push_range(range, out)?;
            }
            Command::Stream {
                data,
                range,
                interval,
                count,
            } => {
                out.extend_from_slice(&[b'M', data.letter()]);
                push_range(range, out)?;
                push_decimal("scan interval", interval, 9, 1, out)?;
                push_decimal("scan count", count, 99, 2, out)?;
            }
        }
        Ok(())
    }
}

fn push_range(range: StepRange, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    for step in [range.start, range.end] {
        if step > 9999 {
            return Err(EncodeError::StepTooLarge(step));
        }
        out.extend_from_slice(format_digits(u32::from(step), 4).as_slice());
    }
    push_decimal("cluster count", range.cluster, 99, 2, out)
}

fn push_decimal(
    field: &'static str,
    value: u8,
    max: u8,
    width: usize,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    if value > max {
        return Err(EncodeError::FieldTooLarge { field, value, max });
    }
    out.extend_from_slice(format_digits(u32::from(value), width).as_slice());
    Ok(())
}

/// Fixed-width decimal digits without going through `format!` (no allocation).
fn format_digits(mut value: u32, width: usize) -> DigitBuf {
    let mut buf = DigitBuf {
        digits: [b'0'; 4],
        len: width,
    };
    for i in (0..width).rev() {
        buf.digits[i] = b'0' + (value % 10) as u8;
        value /= 10;
    }
    buf
}

struct DigitBuf {
    digits: [u8; 4],
    len: usize,
}

impl DigitBuf {
    fn as_slice(&self) -> &[u8] {
        &self.digits[..self.len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(cmd: Command, tag: Option<&str>) -> String {
        let mut out = Vec::new();
        cmd.encode_tagged(tag, &mut out).unwrap();
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn commands_encode_as_the_protocol_shows() {
        let range = StepRange {
            start: 384,
            end: 386,
            cluster: 1,
        };
        assert_eq!(
            line(
                Command::Get {
                    data: DataKind::Distance,
                    range
                },
                None
            ),
            "GD0384038601\n"
        );
        let stream = Command::Stream {
            data: DataKind::Distance,
            range: StepRange { end: 386, ..range },
            interval: 0,
            count: 2,
        };
        assert_eq!(line(stream, None), "MD0384038601002\n");
        assert_eq!(line(Command::Time(TimeMode::Request), None), "TM1\n");
        assert_eq!(line(Command::Scip2, None), "SCIP2.0\n");
        assert_eq!(line(Command::Quit, Some("stop")), "QT;stop\n");
    }

    #[test]
    fn out_of_range_fields_are_refused_without_output() {
        let mut out = b"x".to_vec();
        let cmd = Command::Stream {
            data: DataKind::DistanceIntensity,
            range: StepRange {
                start: 0,
                end: 1080,
                cluster: 1,
            },
            interval: 10,
            count: 0,
        };
        assert!(matches!(
            cmd.encode(&mut out),
            Err(EncodeError::FieldTooLarge { .. })
        ));
        assert_eq!(out, b"x");
        assert_eq!(
            Command::Quit.encode_tagged(Some("a;b"), &mut out),
            Err(EncodeError::BadTag)
        );
    }
}
