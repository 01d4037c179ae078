//! Primitive reads in either encoding, each bounds-checked.

use crate::{DecodeError, Encoding, Time};

/// Length of the CDR encapsulation header; alignment counts from after it.
const ENCAPSULATION: usize = 4;

pub(crate) struct Reader<'a> {
    encoding: Encoding,
    big_endian: bool,
    /// The serialised message, after any encapsulation header.
    bytes: &'a [u8],
    /// Offset of `bytes` in the message, for errors that locate a byte of the input.
    base: usize,
    at: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(encoding: Encoding, bytes: &'a [u8]) -> Result<Self, DecodeError> {
        let (big_endian, base) = match encoding {
            Encoding::Ros1 => (false, 0),
            Encoding::Cdr => {
                let Some(&[a, b, _, _]) = bytes.first_chunk::<ENCAPSULATION>() else {
                    return Err(DecodeError::CutShort {
                        field: "CDR encapsulation header",
                        at: 0,
                        needed: ENCAPSULATION,
                        left: bytes.len(),
                    });
                };
                match [a, b] {
                    [0, 0] => (true, ENCAPSULATION),
                    [0, 1] => (false, ENCAPSULATION),
                    other => return Err(DecodeError::Representation(other)),
                }
            }
        };
        Ok(Self {
            encoding,
            big_endian,
            bytes: &bytes[base..],
            base,
            at: 0,
        })
    }

    pub(crate) fn encoding(&self) -> Encoding {
        self.encoding
    }

    /// The next `N` bytes, after CDR's alignment to `N` (ROS 1 is packed).
    fn take<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], DecodeError> {
        if self.encoding == Encoding::Cdr {
            self.at = self.at.next_multiple_of(N).min(self.bytes.len());
        }
        let taken = self
            .bytes
            .get(self.at..)
            .and_then(|rest| rest.first_chunk::<N>())
            .copied()
            .ok_or_else(|| self.cut_short(field, N))?;
        self.at += N;
        Ok(taken)
    }

    fn cut_short(&self, field: &'static str, needed: usize) -> DecodeError {
        DecodeError::CutShort {
            field,
            at: self.base + self.at,
            needed,
            left: self.bytes.len().saturating_sub(self.at),
        }
    }

    pub(crate) fn u32(&mut self, field: &'static str) -> Result<u32, DecodeError> {
        let bytes = self.take::<4>(field)?;
        Ok(if self.big_endian {
            u32::from_be_bytes(bytes)
        } else {
            u32::from_le_bytes(bytes)
        })
    }

    pub(crate) fn f32(&mut self, field: &'static str) -> Result<f32, DecodeError> {
        self.u32(field).map(f32::from_bits)
    }

    pub(crate) fn f64(&mut self, field: &'static str) -> Result<f64, DecodeError> {
        let bytes = self.take::<8>(field)?;
        Ok(f64::from_bits(if self.big_endian {
            u64::from_be_bytes(bytes)
        } else {
            u64::from_le_bytes(bytes)
        }))
    }

    /// ROS 1 `time` (u32 seconds) or ROS 2 `builtin_interfaces/Time` (i32 seconds).
    pub(crate) fn time(&mut self, field: &'static str) -> Result<Time, DecodeError> {
        let raw = self.u32(field)?;
        let sec = match self.encoding {
            Encoding::Ros1 => i64::from(raw),
            Encoding::Cdr => i64::from(raw as i32),
        };
        let nanosec = self.u32(field)?;
        if nanosec >= 1_000_000_000 {
            return Err(DecodeError::Nanoseconds {
                field,
                value: nanosec,
            });
        }
        Ok(Time { sec, nanosec })
    }

    /// A sequence's element count, refused when `min_element_bytes` each would not fit in what
    /// is left: the bound that keeps allocations within the input's size.
    pub(crate) fn sequence_length(
        &mut self,
        field: &'static str,
        min_element_bytes: usize,
    ) -> Result<usize, DecodeError> {
        let count = self.u32(field)? as usize;
        let needed = count.saturating_mul(min_element_bytes);
        let left = self.bytes.len() - self.at;
        if needed > left {
            // Located at the length, the byte that is wrong.
            return Err(DecodeError::CutShort {
                field,
                at: self.base + self.at - 4,
                needed,
                left,
            });
        }
        Ok(count)
    }

    pub(crate) fn f32_sequence(&mut self, field: &'static str) -> Result<Vec<f32>, DecodeError> {
        let count = self.sequence_length(field, 4)?;
        (0..count).map(|_| self.f32(field)).collect()
    }

    /// A string; bytes that are not UTF-8 are replaced rather than refused, since frame names
    /// only label things here.
    pub(crate) fn string(&mut self, field: &'static str) -> Result<String, DecodeError> {
        let length = self.sequence_length(field, 1)?;
        let bytes = &self.bytes[self.at..self.at + length];
        self.at += length;
        let text = match self.encoding {
            // CDR counts the terminating NUL.
            Encoding::Cdr => bytes.strip_suffix(&[0]).unwrap_or(bytes),
            Encoding::Ros1 => bytes,
        };
        Ok(String::from_utf8_lossy(text).into_owned())
    }
}
