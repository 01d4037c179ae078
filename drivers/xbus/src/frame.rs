//! Xbus framing: `FA FF MID LEN [EXT_HI EXT_LO] DATA CS`, checksum over BID..CS == 0 mod 256.

use core::fmt;

/// Start of every frame.
pub const PREAMBLE: u8 = 0xFA;
/// Bus identifier of a directly connected device (the only one we accept, which makes a false
/// synchronisation on payload bytes 256 times less likely).
pub const BUS_ID: u8 = 0xFF;
/// LEN value announcing a 16-bit big-endian extended length.
const EXTENDED_LENGTH: u8 = 0xFF;
/// Default size guard: the largest payload real devices send (as capped by xsens-mti).
pub const DEFAULT_MAX_PAYLOAD: usize = 2048;
/// Largest payload the wire format can describe.
pub const MAX_WIRE_PAYLOAD: usize = u16::MAX as usize;

/// Message identifiers used by this crate (docs/protocols.md, 2.3 "Message identifiers").
pub mod mid {
    pub const REQ_DID: u8 = 0x00;
    pub const DEVICE_ID: u8 = 0x01;
    pub const GO_TO_MEASUREMENT: u8 = 0x10;
    pub const GO_TO_MEASUREMENT_ACK: u8 = 0x11;
    pub const REQ_FW_REV: u8 = 0x12;
    pub const FIRMWARE_REV: u8 = 0x13;
    pub const SET_BAUDRATE: u8 = 0x18;
    pub const SET_BAUDRATE_ACK: u8 = 0x19;
    pub const REQ_PRODUCT_CODE: u8 = 0x1C;
    pub const PRODUCT_CODE: u8 = 0x1D;
    pub const GO_TO_CONFIG: u8 = 0x30;
    pub const GO_TO_CONFIG_ACK: u8 = 0x31;
    pub const MT_DATA2: u8 = 0x36;
    pub const WAKE_UP: u8 = 0x3E;
    pub const WAKE_UP_ACK: u8 = 0x3F;
    pub const RESET: u8 = 0x40;
    pub const RESET_ACK: u8 = 0x41;
    pub const ERROR: u8 = 0x42;
    pub const SET_OUTPUT_CONFIGURATION: u8 = 0xC0;
    pub const OUTPUT_CONFIGURATION: u8 = 0xC1;
}

/// One checksum-valid message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    pub mid: u8,
    pub payload: &'a [u8],
}

/// Why bytes were dropped instead of becoming a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameError {
    /// The candidate frame's bytes did not sum to zero; the framer resynchronised one byte later.
    BadChecksum { mid: u8, len: usize },
    /// The length field exceeds the size guard; the framer resynchronised one byte later.
    Oversize { len: usize, max: usize },
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::BadChecksum { mid, len } => write!(
                f,
                "xbus frame MID 0x{mid:02X} with {len}-byte payload failed its checksum: check the serial line (baud rate, noise)"
            ),
            Self::Oversize { len, max } => write!(
                f,
                "xbus frame announces a {len}-byte payload, above the {max}-byte guard: raise max_payload if the device really sends this"
            ),
        }
    }
}

impl std::error::Error for FrameError {}

/// Counters for everything the framer has seen.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FramerStats {
    pub frames: u64,
    pub bad_checksums: u64,
    pub oversize: u64,
    /// Bytes discarded while hunting for a preamble (includes resynchronisation skips).
    pub skipped_bytes: u64,
}

/// Incremental frame decoder over arbitrary chunks. Its buffer is allocated once, at construction.
pub struct Framer {
    buf: Box<[u8]>,
    start: usize,
    end: usize,
    /// Bytes of the frame handed out by the last call, released on the next call.
    pending_release: usize,
    max_payload: usize,
    stats: FramerStats,
}

enum Scan {
    NeedMore,
    Skip(usize),
    Frame { header: usize, payload: usize },
    Error(FrameError),
}

impl Framer {
    /// `max_payload` is the size guard (clamped to what the wire can express).
    pub fn new(max_payload: usize) -> Self {
        let max_payload = max_payload.min(MAX_WIRE_PAYLOAD);
        Self {
            buf: vec![0; max_payload + 7].into_boxed_slice(),
            start: 0,
            end: 0,
            pending_release: 0,
            max_payload,
            stats: FramerStats::default(),
        }
    }

    pub fn stats(&self) -> FramerStats {
        self.stats
    }

    /// Drops buffered bytes (e.g. after reopening the port).
    pub fn clear(&mut self) {
        self.start = 0;
        self.end = 0;
        self.pending_release = 0;
    }

    /// Takes bytes from the front of `input` and returns the next frame or framing error, or
    /// `None` once `input` is exhausted without completing one. Call in a loop:
    /// `while let Some(r) = framer.decode(&mut rest) { ... }`.
    pub fn decode(&mut self, input: &mut &[u8]) -> Option<Result<Frame<'_>, FrameError>> {
        self.start += core::mem::take(&mut self.pending_release);
        loop {
            match scan(&self.buf[self.start..self.end], self.max_payload) {
                Scan::Skip(n) => {
                    self.start += n;
                    self.stats.skipped_bytes += n as u64;
                }
                Scan::Error(e) => {
                    self.start += 1;
                    match e {
                        FrameError::BadChecksum { .. } => self.stats.bad_checksums += 1,
                        FrameError::Oversize { .. } => self.stats.oversize += 1,
                    }
                    return Some(Err(e));
                }
                Scan::Frame { header, payload } => {
                    let at = self.start;
                    self.pending_release = header + payload + 1;
                    self.stats.frames += 1;
                    return Some(Ok(Frame {
                        mid: self.buf[at + 2],
                        payload: &self.buf[at + header..at + header + payload],
                    }));
                }
                Scan::NeedMore => {
                    if input.is_empty() {
                        return None;
                    }
                    self.refill(input);
                }
            }
        }
    }

    fn refill(&mut self, input: &mut &[u8]) {
        if self.start > 0 {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        let n = (self.buf.len() - self.end).min(input.len());
        self.buf[self.end..self.end + n].copy_from_slice(&input[..n]);
        self.end += n;
        *input = &input[n..];
    }
}

fn scan(bytes: &[u8], max_payload: usize) -> Scan {
    let Some(&first) = bytes.first() else {
        return Scan::NeedMore;
    };
    if first != PREAMBLE {
        let garbage = bytes
            .iter()
            .position(|&b| b == PREAMBLE)
            .unwrap_or(bytes.len());
        return Scan::Skip(garbage);
    }
    if bytes.len() < 4 {
        return Scan::NeedMore;
    }
    if bytes[1] != BUS_ID {
        return Scan::Skip(1);
    }
    let (header, payload) = if bytes[3] == EXTENDED_LENGTH {
        if bytes.len() < 6 {
            return Scan::NeedMore;
        }
        (6, usize::from(u16::from_be_bytes([bytes[4], bytes[5]])))
    } else {
        (4, usize::from(bytes[3]))
    };
    if payload > max_payload {
        return Scan::Error(FrameError::Oversize {
            len: payload,
            max: max_payload,
        });
    }
    let total = header + payload + 1;
    if bytes.len() < total {
        return Scan::NeedMore;
    }
    if checksum_residue(&bytes[1..total]) != 0 {
        return Scan::Error(FrameError::BadChecksum {
            mid: bytes[2],
            len: payload,
        });
    }
    Scan::Frame { header, payload }
}

pub(crate) fn checksum_residue(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |acc, &b| acc.wrapping_add(b))
}

/// The payload does not fit the 16-bit extended length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PayloadTooLong {
    pub len: usize,
}

impl fmt::Display for PayloadTooLong {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "xbus payload of {} bytes exceeds the 65535-byte extended length: split the message",
            self.len
        )
    }
}

impl std::error::Error for PayloadTooLong {}

/// Appends one complete frame (normal or extended length) to `out`.
pub fn encode_frame(mid: u8, payload: &[u8], out: &mut Vec<u8>) -> Result<(), PayloadTooLong> {
    if payload.len() > MAX_WIRE_PAYLOAD {
        return Err(PayloadTooLong { len: payload.len() });
    }
    let from = out.len();
    out.extend_from_slice(&[PREAMBLE, BUS_ID, mid]);
    if payload.len() < usize::from(EXTENDED_LENGTH) {
        out.push(payload.len() as u8);
    } else {
        out.push(EXTENDED_LENGTH);
        out.extend_from_slice(&(payload.len() as u16).to_be_bytes());
    }
    out.extend_from_slice(payload);
    let sum = checksum_residue(&out[from + 1..]);
    out.push(sum.wrapping_neg());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames_of(framer: &mut Framer, mut input: &[u8]) -> Vec<(u8, Vec<u8>)> {
        let mut got = Vec::new();
        while let Some(r) = framer.decode(&mut input) {
            if let Ok(f) = r {
                got.push((f.mid, f.payload.to_vec()));
            }
        }
        got
    }

    #[test]
    fn zero_payload_frames_match_the_documented_bytes() {
        for (mid, bytes) in [
            (mid::REQ_DID, [0xFA, 0xFF, 0x00, 0x00, 0x01]),
            (mid::GO_TO_MEASUREMENT, [0xFA, 0xFF, 0x10, 0x00, 0xF1]),
            (mid::REQ_FW_REV, [0xFA, 0xFF, 0x12, 0x00, 0xEF]),
            (mid::REQ_PRODUCT_CODE, [0xFA, 0xFF, 0x1C, 0x00, 0xE5]),
            (mid::GO_TO_CONFIG, [0xFA, 0xFF, 0x30, 0x00, 0xD1]),
            (mid::WAKE_UP_ACK, [0xFA, 0xFF, 0x3F, 0x00, 0xC2]),
        ] {
            let mut out = Vec::new();
            encode_frame(mid, &[], &mut out).unwrap();
            assert_eq!(out, bytes);
        }
    }

    #[test]
    fn known_good_minimal_frame_decodes() {
        let mut framer = Framer::new(DEFAULT_MAX_PAYLOAD);
        let got = frames_of(
            &mut framer,
            &[0xFA, 0xFF, 0x00, 0x03, 0x0A, 0x0B, 0x0C, 0xDD],
        );
        assert_eq!(got, vec![(0x00, vec![0x0A, 0x0B, 0x0C])]);
    }

    #[test]
    fn extended_length_round_trips_one_byte_at_a_time() {
        let payload: Vec<u8> = (0..600u32).map(|i| (i % 251) as u8).collect();
        let mut wire = Vec::new();
        encode_frame(mid::MT_DATA2, &payload, &mut wire).unwrap();
        assert_eq!(&wire[3..6], &[0xFF, 0x02, 0x58]);
        let mut framer = Framer::new(DEFAULT_MAX_PAYLOAD);
        let mut got = Vec::new();
        for b in &wire {
            got.extend(frames_of(&mut framer, std::slice::from_ref(b)));
        }
        assert_eq!(got, vec![(mid::MT_DATA2, payload)]);
    }

    #[test]
    fn resync_finds_frame_hidden_inside_a_corrupt_one() {
        let mut inner = Vec::new();
        encode_frame(mid::GO_TO_CONFIG_ACK, &[], &mut inner).unwrap();
        // A corrupt frame whose payload carries a complete valid frame: scanning from the next
        // 0xFA after the corrupt frame's end would miss it; advancing one byte finds it.
        let mut wire = vec![0xFA, 0xFF, 0x36, inner.len() as u8];
        wire.extend_from_slice(&inner);
        wire.push(0x00);
        let mut framer = Framer::new(DEFAULT_MAX_PAYLOAD);
        let got = frames_of(&mut framer, &wire);
        assert_eq!(got, vec![(mid::GO_TO_CONFIG_ACK, vec![])]);
        assert_eq!(framer.stats().bad_checksums, 1);
    }

    #[test]
    fn oversize_is_reported_and_skipped() {
        let mut wire = vec![0xFA, 0xFF, 0x36, 0xFF, 0x10, 0x00];
        encode_frame(mid::WAKE_UP, &[], &mut wire).unwrap();
        let mut framer = Framer::new(1024);
        let mut input = &wire[..];
        assert_eq!(
            framer.decode(&mut input),
            Some(Err(FrameError::Oversize {
                len: 4096,
                max: 1024
            }))
        );
        assert_eq!(
            framer.decode(&mut input),
            Some(Ok(Frame {
                mid: mid::WAKE_UP,
                payload: &[]
            }))
        );
        assert_eq!(framer.decode(&mut input), None);
    }
}
