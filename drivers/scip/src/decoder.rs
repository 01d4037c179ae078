//! Incremental reply decoder: bytes in any chunking, one typed reply per `\n\n`-terminated frame.
//!
//! Framing is by the empty line that ends every reply, so a corrupted reply costs only itself:
//! the next frame starts clean. Buffers are reused, so steady-state decoding does not allocate.

use std::fmt;

use crate::command::{DataKind, StepRange};
use crate::encoding::{checksum, decode_value, MAX_BLOCK};

/// Default frame limit: an ME reply of 1081 steps is about 6.8 KiB; this leaves room for larger
/// sensors while bounding what garbage without empty lines can make us hold.
pub const DEFAULT_MAX_FRAME: usize = 16 * 1024;

/// Reply status line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Status {
    /// Two-character SCIP 2.0 status (`00`, `99`, `0E`, ...).
    Code([u8; 2]),
    /// One-character answer of a sensor still speaking SCIP 1.1.
    Scip11(u8),
}

impl Status {
    pub const OK: Status = Status::Code([b'0', b'0']);
    pub const STREAM_DATA: Status = Status::Code([b'9', b'9']);

    pub fn is_ok(self) -> bool {
        self == Status::OK
    }
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Status::Code([a, b]) => write!(f, "{}{}", a as char, b as char),
            Status::Scip11(c) => write!(f, "SCIP1.1 '{}'", c.escape_ascii()),
        }
    }
}

/// Echo fields of an MD/MS/ME scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamEcho {
    pub interval: u8,
    /// Scans still to come after this one; 0 for an unlimited stream.
    pub remaining: u8,
}

/// One decoded scan; slices borrow the decoder's reused buffers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanData<'a> {
    pub data: DataKind,
    pub range: StepRange,
    /// `Some` for MD/MS/ME, `None` for GD/GS/GE.
    pub stream: Option<StreamEcho>,
    /// Sensor's 24-bit millisecond counter at step 0.
    pub timestamp: u32,
    /// One value per cluster of steps, mm (values below DMIN are sensor error codes).
    pub ranges: &'a [u32],
    /// Same length as `ranges` for `DistanceIntensity`, empty otherwise.
    pub intensities: &'a [u32],
}

/// `KEY:VALUE` lines of a VV/PP/II reply, all sums already verified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InfoLines<'a> {
    text: &'a str,
}

impl<'a> InfoLines<'a> {
    /// `(key, value)` pairs in order, without the `;` and sum.
    pub fn iter(&self) -> impl Iterator<Item = (&'a str, &'a str)> + 'a {
        self.text.split('\n').filter_map(split_info_line)
    }

    pub fn get(&self, key: &str) -> Option<&'a str> {
        self.iter().find(|(k, _)| *k == key).map(|(_, v)| v)
    }
}

/// Reply payload after the status line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Body<'a> {
    Empty,
    Info(InfoLines<'a>),
    /// TM1: the sensor's 24-bit millisecond counter.
    Time(u32),
    Scan(ScanData<'a>),
}

/// One sensor reply.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reply<'a> {
    /// The echoed command line, verbatim (including any `;string`).
    pub echo: &'a [u8],
    pub status: Status,
    pub body: Body<'a>,
}

impl<'a> Reply<'a> {
    /// The echoed command without its `;string`.
    pub fn command(&self) -> &'a [u8] {
        let end = self
            .echo
            .iter()
            .position(|&b| b == b';')
            .unwrap_or(self.echo.len());
        &self.echo[..end]
    }
}

/// Why a frame was rejected. Line numbers count from 1 at the echo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DecodeError {
    FrameTooLong { limit: usize },
    MissingStatus,
    BadStatus,
    Checksum { line: usize },
    BadCharacter,
    LineTooLong { line: usize },
    BadEcho,
    BadTimestamp,
    BadInfoLine { line: usize },
    DataLength { expected: usize, got: usize },
    UnexpectedPayload,
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            DecodeError::FrameTooLong { limit } => write!(f, "SCIP reply longer than {limit} bytes without an empty line: check the baud rate and that the port carries SCIP 2.0"),
            DecodeError::MissingStatus => f.write_str("SCIP reply has no status line: the reply was cut; check the link"),
            DecodeError::BadStatus => f.write_str("SCIP status line is not two characters plus a valid sum: check the link for corruption"),
            DecodeError::Checksum { line } => write!(f, "SCIP checksum mismatch on reply line {line}: check the link for corruption"),
            DecodeError::BadCharacter => f.write_str("SCIP scan data holds a character outside the 6-bit alphabet: check the link for corruption"),
            DecodeError::LineTooLong { line } => write!(f, "SCIP data line {line} is longer than 64 characters plus sum: check the link for lost line feeds"),
            DecodeError::BadEcho => f.write_str("SCIP scan echo is not a well-formed GD/GS/GE/MD/MS/ME command: check the link for corruption"),
            DecodeError::BadTimestamp => f.write_str("SCIP timestamp line is not four characters plus a valid sum: check the link for corruption"),
            DecodeError::BadInfoLine { line } => write!(f, "SCIP info line {line} is not KEY:VALUE;sum with a valid sum: check the link for corruption"),
            DecodeError::DataLength { expected, got } => write!(f, "SCIP scan carries {got} data characters where its echo implies {expected}: check the link for lost bytes"),
            DecodeError::UnexpectedPayload => f.write_str("SCIP reply carries payload lines its command and status do not allow: check the link for corruption"),
        }
    }
}

impl std::error::Error for DecodeError {}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FrameState {
    Collecting,
    Complete,
    Taken,
    /// Frame limit exceeded; the error is reported next, then bytes are discarded.
    Overflowed {
        after_lf: bool,
    },
    /// Skipping an oversized frame up to its empty line; the flag records a trailing LF.
    Discarding {
        after_lf: bool,
    },
}

/// Incremental SCIP reply decoder.
///
/// ```
/// let mut decoder = scip::Decoder::new();
/// let mut ok = 0;
/// decoder.feed(b"QT\n00P\n\n", |reply| ok += reply.is_ok() as u32);
/// assert_eq!(ok, 1);
/// ```
#[derive(Debug)]
pub struct Decoder {
    frame: Vec<u8>,
    state: FrameState,
    max_frame: usize,
    data: Vec<u8>,
    ranges: Vec<u32>,
    intensities: Vec<u32>,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    pub fn new() -> Self {
        Self::with_max_frame(DEFAULT_MAX_FRAME)
    }

    /// A decoder that drops any frame longer than `max_frame` bytes.
    pub fn with_max_frame(max_frame: usize) -> Self {
        Decoder {
            frame: Vec::with_capacity(max_frame.min(DEFAULT_MAX_FRAME)),
            state: FrameState::Collecting,
            max_frame,
            data: Vec::new(),
            ranges: Vec::new(),
            intensities: Vec::new(),
        }
    }

    /// Consumes bytes up to and including the end of the next complete frame (or all of
    /// `input`), returning how many were used. Call [`Decoder::reply`] after each call.
    pub fn push(&mut self, input: &[u8]) -> usize {
        if let FrameState::Overflowed { after_lf } = self.state {
            // The caller skipped `reply()`; the error is dropped but discarding still happens.
            self.state = FrameState::Discarding { after_lf };
        }
        if matches!(self.state, FrameState::Complete | FrameState::Taken) {
            self.frame.clear();
            self.state = FrameState::Collecting;
        }
        let mut used = 0;
        while used < input.len() {
            let rest = &input[used..];
            match self.state {
                FrameState::Discarding { after_lf } => {
                    let byte = rest[0];
                    used += 1;
                    if byte == b'\n' && after_lf {
                        self.state = FrameState::Collecting;
                    } else if byte != b'\r' {
                        self.state = FrameState::Discarding {
                            after_lf: byte == b'\n',
                        };
                    }
                }
                FrameState::Collecting => {
                    let lf = rest.iter().position(|&b| b == b'\n');
                    let line = &rest[..lf.unwrap_or(rest.len())];
                    used += line.len() + usize::from(lf.is_some());
                    // Checked before copying, so one huge chunk cannot grow the buffer either; an
                    // empty line always gets through, since it is what ends the frame.
                    if !line.is_empty() && self.frame.len() + line.len() > self.max_frame {
                        self.overflow(lf.is_some());
                        return used;
                    }
                    self.frame.extend_from_slice(line);
                    if lf.is_some() && self.end_line() {
                        self.state = FrameState::Complete;
                        return used;
                    }
                }
                _ => unreachable!("push resets finished frames before the loop"),
            }
        }
        used
    }

    fn overflow(&mut self, after_lf: bool) {
        self.frame.clear();
        self.state = FrameState::Overflowed { after_lf };
    }

    /// Closes the current line; true if it was the empty line that ends a frame.
    fn end_line(&mut self) -> bool {
        if self.frame.last() == Some(&b'\r') {
            self.frame.pop();
        }
        match self.frame.last() {
            None => false, // line feeds between replies
            Some(b'\n') => true,
            Some(_) => {
                self.frame.push(b'\n');
                false
            }
        }
    }

    /// The frame completed by the last [`Decoder::push`], decoded; `None` if none completed.
    pub fn reply(&mut self) -> Option<Result<Reply<'_>, DecodeError>> {
        match self.state {
            FrameState::Overflowed { after_lf } => {
                self.state = FrameState::Discarding { after_lf };
                Some(Err(DecodeError::FrameTooLong {
                    limit: self.max_frame,
                }))
            }
            FrameState::Complete => {
                self.state = FrameState::Taken;
                let body = &self.frame[..self.frame.len() - 1];
                Some(parse_frame(
                    body,
                    &mut self.data,
                    &mut self.ranges,
                    &mut self.intensities,
                ))
            }
            _ => None,
        }
    }

    /// Pushes all of `input`, calling `on_reply` for every frame it completes.
    pub fn feed(
        &mut self,
        mut input: &[u8],
        mut on_reply: impl FnMut(Result<Reply<'_>, DecodeError>),
    ) {
        while !input.is_empty() {
            let used = self.push(input);
            input = &input[used..];
            if let Some(reply) = self.reply() {
                on_reply(reply);
            }
        }
    }

    /// Forgets any partial frame (e.g. after reopening the port).
    pub fn reset(&mut self) {
        self.frame.clear();
        self.state = FrameState::Collecting;
    }
}

/// Splits off the first line of `text` (without its LF).
fn split_line(text: &[u8]) -> (&[u8], Option<&[u8]>) {
    match text.iter().position(|&b| b == b'\n') {
        Some(lf) => (&text[..lf], Some(&text[lf + 1..])),
        None => (text, None),
    }
}

fn parse_frame<'a>(
    frame: &'a [u8],
    data: &mut Vec<u8>,
    ranges: &'a mut Vec<u32>,
    intensities: &'a mut Vec<u32>,
) -> Result<Reply<'a>, DecodeError> {
    let (echo, rest) = split_line(frame);
    let rest = rest.ok_or(DecodeError::MissingStatus)?;
    let (status_line, payload) = split_line(rest);
    let status = parse_status(status_line)?;
    let command = echo.split(|&b| b == b';').next().unwrap_or_default();
    let body = match (command, status) {
        (b"VV" | b"PP" | b"II", Status::Code([b'0', b'0'])) if payload.is_some() => {
            Body::Info(parse_info(payload.unwrap_or_default())?)
        }
        (b"TM1", Status::Code([b'0', b'0'])) => {
            let (line, after) = split_line(payload.ok_or(DecodeError::BadTimestamp)?);
            if after.is_some() {
                return Err(DecodeError::UnexpectedPayload);
            }
            Body::Time(parse_timestamp(line)?)
        }
        ([b'G', _, ..], Status::Code([b'0', b'0']))
        | ([b'M', _, ..], Status::Code([b'9', b'9']))
            if payload.is_some() =>
        {
            let payload = payload.unwrap_or_default();
            Body::Scan(parse_scan(command, payload, data, ranges, intensities)?)
        }
        _ if payload.is_some() => return Err(DecodeError::UnexpectedPayload),
        _ => Body::Empty,
    };
    Ok(Reply { echo, status, body })
}

fn parse_status(line: &[u8]) -> Result<Status, DecodeError> {
    match *line {
        [c] => Ok(Status::Scip11(c)),
        [a, b, sum] if a.is_ascii_alphanumeric() && b.is_ascii_alphanumeric() => {
            if checksum(&[a, b]) == sum {
                Ok(Status::Code([a, b]))
            } else {
                Err(DecodeError::Checksum { line: 2 })
            }
        }
        _ => Err(DecodeError::BadStatus),
    }
}

fn parse_timestamp(line: &[u8]) -> Result<u32, DecodeError> {
    match line {
        [chars @ .., sum] if chars.len() == 4 && checksum(chars) == *sum => {
            decode_value(chars).ok_or(DecodeError::BadTimestamp)
        }
        _ => Err(DecodeError::BadTimestamp),
    }
}

fn parse_info(payload: &[u8]) -> Result<InfoLines<'_>, DecodeError> {
    let text = std::str::from_utf8(payload).map_err(|_| DecodeError::BadInfoLine { line: 3 })?;
    for (index, line) in text.split('\n').enumerate() {
        let number = index + 3;
        let bytes = line.as_bytes();
        let [content @ .., sum] = bytes else {
            return Err(DecodeError::BadInfoLine { line: number });
        };
        if !info_sum_matches(content, *sum) || split_info_line(line).is_none() {
            return Err(DecodeError::BadInfoLine { line: number });
        }
    }
    Ok(InfoLines { text })
}

/// Sensors differ on what an info line's sum covers: without the `;` (spec examples), with it
/// (accepted by urg_library), or stopping before a `<-` comment (UTM-30LX 2009 firmware).
fn info_sum_matches(content: &[u8], sum: u8) -> bool {
    let without_semicolon = content.strip_suffix(b";").unwrap_or(content);
    if checksum(without_semicolon) == sum || checksum(content) == sum {
        return true;
    }
    content
        .windows(2)
        .position(|w| w == b"<-")
        .is_some_and(|comment| checksum(&content[..comment]) == sum)
}

fn split_info_line(line: &str) -> Option<(&str, &str)> {
    let content = &line[..line.len().checked_sub(1)?];
    let content = content.strip_suffix(';').unwrap_or(content);
    let (key, value) = content.split_once(':')?;
    (!key.is_empty()).then_some((key, value))
}

fn parse_digits(text: &[u8]) -> Option<u16> {
    text.iter().try_fold(0u16, |acc, &c| {
        c.is_ascii_digit().then(|| acc * 10 + u16::from(c - b'0'))
    })
}

fn parse_scan_echo(command: &[u8]) -> Option<(DataKind, StepRange, Option<StreamEcho>)> {
    let (kind, streamed) = match command {
        [b'G', letter, ..] if command.len() == 12 => (DataKind::from_letter(*letter)?, false),
        [b'M', letter, ..] if command.len() == 15 => (DataKind::from_letter(*letter)?, true),
        _ => return None,
    };
    let range = StepRange {
        start: parse_digits(&command[2..6])?,
        end: parse_digits(&command[6..10])?,
        cluster: parse_digits(&command[10..12])? as u8,
    };
    let stream = if streamed {
        Some(StreamEcho {
            interval: parse_digits(&command[12..13])? as u8,
            remaining: parse_digits(&command[13..15])? as u8,
        })
    } else {
        None
    };
    Some((kind, range, stream))
}

fn parse_scan<'a>(
    command: &[u8],
    payload: &[u8],
    data: &mut Vec<u8>,
    ranges: &'a mut Vec<u32>,
    intensities: &'a mut Vec<u32>,
) -> Result<ScanData<'a>, DecodeError> {
    let (kind, range, stream) = parse_scan_echo(command).ok_or(DecodeError::BadEcho)?;
    let (timestamp_line, mut rest) = split_line(payload);
    let timestamp = parse_timestamp(timestamp_line)?;
    data.clear();
    let mut number = 4;
    while let Some(text) = rest {
        let (line, after) = split_line(text);
        let [block @ .., sum] = line else {
            return Err(DecodeError::UnexpectedPayload);
        };
        if block.len() > MAX_BLOCK {
            return Err(DecodeError::LineTooLong { line: number });
        }
        if checksum(block) != *sum {
            return Err(DecodeError::Checksum { line: number });
        }
        data.extend_from_slice(block);
        rest = after;
        number += 1;
    }
    let count = range.value_count();
    let expected = count * kind.step_width();
    if data.len() != expected {
        return Err(DecodeError::DataLength {
            expected,
            got: data.len(),
        });
    }
    let width = kind.value_width();
    ranges.clear();
    intensities.clear();
    for step in data.chunks_exact(kind.step_width()) {
        let bad = DecodeError::BadCharacter;
        ranges.push(decode_value(&step[..width]).ok_or(bad)?);
        if kind == DataKind::DistanceIntensity {
            intensities.push(decode_value(&step[width..]).ok_or(bad)?);
        }
    }
    Ok(ScanData {
        data: kind,
        range,
        stream,
        timestamp,
        ranges,
        intensities,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn garbage_without_empty_lines_is_bounded_and_reported_once() {
        let mut decoder = Decoder::with_max_frame(1000);
        let garbage: Vec<u8> = (0..200_000u32)
            .map(|i| if i % 50 == 49 { b'\n' } else { b'A' })
            .collect();
        let mut errors = Vec::new();
        decoder.feed(&garbage, |r| errors.push(r.err()));
        decoder.feed(&[b'x'; 1_000_000], |r| errors.push(r.err()));
        assert_eq!(
            errors,
            vec![Some(DecodeError::FrameTooLong { limit: 1000 })]
        );
        assert!(decoder.frame.capacity() <= 1000);
        let mut ok = 0;
        decoder.feed(b"\n\nQT\n00P\n\n", |r| ok += usize::from(r.is_ok()));
        assert_eq!(ok, 1);
    }

    #[test]
    fn frame_filled_to_the_limit_still_ends_at_its_empty_line() {
        // Regression (proptest): a frame at exactly the limit swallowed the reply after it.
        let mut decoder = Decoder::with_max_frame(8);
        let mut results = Vec::new();
        decoder.feed(b"ABCDEFG\n\nQT\n00P\n\n", |r| {
            results.push(r.map(|r| r.status))
        });
        assert_eq!(
            results,
            vec![Err(DecodeError::MissingStatus), Ok(Status::OK)]
        );
    }

    #[test]
    fn crlf_line_ends_are_accepted() {
        let mut decoder = Decoder::new();
        let mut statuses = Vec::new();
        decoder.feed(b"BM\r\n02R\r\n\r\n", |r| statuses.push(r.map(|r| r.status)));
        assert_eq!(statuses, vec![Ok(Status::Code(*b"02"))]);
    }
}
