//! Recordings (docs/design.md, "Recordings"): every byte to and from every device, in MCAP, so that
//! a flight can be replayed through exactly the code that ran live.
//!
//! One schemaless channel per direction per device, topic `/<sensor>/rx` or `/<sensor>/tx`,
//! message encoding `scip2` or `xbus`, one message per chunk of bytes exactly as read or
//! written, `log_time` the host monotonic clock in ns. The configuration in force is a metadata
//! record `ladar-odometer.config` with key `toml`; simulated recordings add `/truth` in JSON.
//!
//! The reader also reads ROS recordings (docs/ros-data.md): a channel whose schema is a
//! `LaserScan`, `MultiEchoLaserScan` or `Imu` in ROS 1 or ROS 2 encoding gives one message per
//! ROS message, named by its topic, and the replay maps topics to sensors by the configuration.
//! `/tf_static` is kept for the mounts it carries (`RecordingReader::tf_static`); other ROS
//! channels (`/tf`, images, logs) are skipped, and listed for the error that names
//! what a recording holds when none of its topics is usable.
//!
//! The reader also takes a raw dump of one port (`cat /dev/ttyACM0 > file`), recognised by its
//! content; such a dump carries no host times, so its chunks have `log_time_ns == 0` and the
//! replay times them with the sensor's own clock.

use crate::sensors::TruthSample;
use mcap::records::{MessageHeader, Metadata, Record};
use mcap::{McapError, WriteOptions, Writer};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Seek, Write};
use std::path::{Path, PathBuf};

pub const CONFIG_METADATA_NAME: &str = "ladar-odometer.config";
pub const CONFIG_METADATA_KEY: &str = "toml";
pub(crate) const TRUTH_TOPIC: &str = "/truth";
pub(crate) const TRUTH_ENCODING: &str = "json";
/// The ROS topic of the static transforms, a robot's mounts.
const TF_STATIC_TOPIC: &str = "/tf_static";
/// Sensor name given to the bytes of a raw port dump.
pub(crate) const RAW_DUMP_SENSOR: &str = "raw";
const RAW_DUMP_CHUNK: usize = 4096;
/// How much of a raw dump is looked at to decide what it is.
const SNIFF_BYTES: usize = 64 * 1024;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Bytes from the device.
    Rx,
    /// Bytes to the device.
    Tx,
}

impl Direction {
    pub(crate) fn as_str(self) -> &'static str {
        match self {
            Self::Rx => "rx",
            Self::Tx => "tx",
        }
    }
}

/// The wire protocol of a device's bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Encoding {
    /// Hokuyo SCIP 2.0.
    Scip2,
    /// Xsens Xbus.
    Xbus,
    /// One ROS message of this type per recorded message.
    Ros(rosmsg::Kind, rosmsg::Encoding),
}

impl Encoding {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Scip2 => "scip2",
            Self::Xbus => "xbus",
            Self::Ros(_, encoding) => encoding.as_str(),
        }
    }

    fn parse(name: &str) -> Option<Self> {
        match name {
            "scip2" => Some(Self::Scip2),
            "xbus" => Some(Self::Xbus),
            _ => None,
        }
    }
}

impl fmt::Display for Encoding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("cannot create recording {path}: {source} (check [recording] path and permissions)")]
    Create { path: PathBuf, source: io::Error },
    #[error("cannot write recording: {0} (check free space)")]
    Write(#[from] McapError),
    #[error("cannot read recording {path}: {source}")]
    Open { path: PathBuf, source: io::Error },
    #[error("recording {path} is truncated or corrupt at byte {offset} ({reason}); replay it with --tolerant to keep what is complete")]
    Corrupt {
        path: PathBuf,
        offset: u64,
        reason: String,
    },
    #[error("recording from an unknown sensor: {path} has topic `{topic}` with message encoding `{encoding}` (expected scip2, xbus, json on /truth, or ROS messages: ros1 with ros1msg schemas, cdr with ros2msg)")]
    UnknownEncoding {
        path: PathBuf,
        topic: String,
        encoding: String,
    },
    #[error("recording {path} has topic `{topic}`, expected /<sensor>/rx or /<sensor>/tx")]
    BadTopic { path: PathBuf, topic: String },
    #[error("recording {path} has a /truth message at {log_time_ns} ns that is not {{\"t\", \"p\", \"q\", \"v\"}} JSON: {reason}")]
    BadTruth {
        path: PathBuf,
        log_time_ns: u64,
        reason: String,
    },
    #[error("{path} is neither an MCAP recording nor a raw SCIP or Xbus dump of one port")]
    UnknownFormat { path: PathBuf },
}

/// The `/truth` message: position NED, attitude body->NED as (w, x, y, z), velocity NED.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TruthJson {
    t: f64,
    p: [f64; 3],
    q: [f64; 4],
    v: [f64; 3],
}

impl From<&TruthSample> for TruthJson {
    fn from(s: &TruthSample) -> Self {
        let q = s.q.quaternion();
        Self {
            t: s.t,
            p: s.p.into(),
            q: [q.w, q.i, q.j, q.k],
            v: s.v.into(),
        }
    }
}

impl TruthJson {
    fn to_sample(self) -> Result<TruthSample, String> {
        let [w, x, y, z] = self.q;
        let q = Quaternion::new(w, x, y, z);
        if !(q.norm() > 0.5 && q.norm() < 2.0) {
            return Err(format!("quaternion {:?} is not a rotation", self.q));
        }
        Ok(TruthSample {
            t: self.t,
            p: Vector3::from(self.p),
            q: UnitQuaternion::from_quaternion(q),
            v: Vector3::from(self.v),
        })
    }
}

/// Writes a recording. Channels are created on first use. Dropping it finishes the file (the
/// MCAP writer's own drop does), so an orderly shutdown after SIGINT keeps every byte; call
/// [`Recorder::flush`] about once a second so that a crash or power cut loses at most that.
pub(crate) struct Recorder<W: Write + Seek = BufWriter<File>> {
    writer: Writer<W>,
    channels: HashMap<(String, Direction), u16>,
    truth_channel: Option<u16>,
    sequence: u32,
}

impl Recorder<BufWriter<File>> {
    pub(crate) fn create(path: &Path, config_toml: &str) -> Result<Self, RecordingError> {
        let file = File::create(path).map_err(|source| RecordingError::Create {
            path: path.to_path_buf(),
            source,
        })?;
        Self::new(BufWriter::new(file), config_toml)
    }
}

impl<W: Write + Seek> Recorder<W> {
    pub(crate) fn new(out: W, config_toml: &str) -> Result<Self, RecordingError> {
        let mut writer = WriteOptions::new()
            .compression(None)
            .profile("")
            .create(out)?;
        writer.write_metadata(&Metadata {
            name: CONFIG_METADATA_NAME.to_string(),
            metadata: BTreeMap::from([(CONFIG_METADATA_KEY.to_string(), config_toml.to_string())]),
        })?;
        Ok(Self {
            writer,
            channels: HashMap::new(),
            truth_channel: None,
            sequence: 0,
        })
    }

    /// Records one chunk of bytes read from (`Rx`) or written to (`Tx`) a device.
    pub(crate) fn bytes(
        &mut self,
        sensor: &str,
        encoding: Encoding,
        direction: Direction,
        log_time_ns: u64,
        data: &[u8],
    ) -> Result<(), RecordingError> {
        let key = (sensor.to_string(), direction);
        let channel_id = match self.channels.get(&key) {
            Some(&id) => id,
            None => {
                let topic = format!("/{sensor}/{}", direction.as_str());
                let id = self
                    .writer
                    .add_channel(0, &topic, encoding.as_str(), &BTreeMap::new())?;
                self.channels.insert(key, id);
                id
            }
        };
        self.message(channel_id, log_time_ns, data)
    }

    /// Records the simulator's ground truth at `log_time_ns`.
    pub(crate) fn truth(
        &mut self,
        log_time_ns: u64,
        sample: &TruthSample,
    ) -> Result<(), RecordingError> {
        let channel_id = match self.truth_channel {
            Some(id) => id,
            None => {
                let id =
                    self.writer
                        .add_channel(0, TRUTH_TOPIC, TRUTH_ENCODING, &BTreeMap::new())?;
                self.truth_channel = Some(id);
                id
            }
        };
        let json = serde_json::to_vec(&TruthJson::from(sample))
            .expect("a struct of finite-or-not floats always serialises");
        self.message(channel_id, log_time_ns, &json)
    }

    fn message(
        &mut self,
        channel_id: u16,
        log_time: u64,
        data: &[u8],
    ) -> Result<(), RecordingError> {
        self.sequence = self.sequence.wrapping_add(1);
        self.writer.write_to_known_channel(
            &MessageHeader {
                channel_id,
                sequence: self.sequence,
                log_time,
                publish_time: log_time,
            },
            data,
        )?;
        Ok(())
    }

    /// Closes the current MCAP chunk and flushes it to the OS: everything recorded so far
    /// survives a crash and is readable with [`ReadMode::Tolerant`].
    pub(crate) fn flush(&mut self) -> Result<(), RecordingError> {
        self.writer.flush()?;
        Ok(())
    }

    /// Writes the summary and footer and hands back the stream (to `sync_all` a file, say).
    pub(crate) fn finish(mut self) -> Result<W, RecordingError> {
        self.writer.finish()?;
        Ok(self.writer.into_inner())
    }
}

/// One chunk of device bytes from a recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedMessage {
    pub log_time_ns: u64,
    pub sensor: String,
    pub direction: Direction,
    pub encoding: Encoding,
    pub data: Vec<u8>,
}

impl RecordedMessage {
    pub fn topic(&self) -> String {
        format!("/{}/{}", self.sensor, self.direction.as_str())
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Mcap,
    /// A raw dump of one port, with the protocol recognised from its content.
    RawDump(Encoding),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadMode {
    /// Any damage is an error.
    Strict,
    /// Keep every complete record before the damage and report what was lost.
    Tolerant,
}

/// What a tolerant read could not recover.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Loss {
    /// Bytes after the last complete record.
    pub bytes: u64,
    pub reason: String,
}

impl fmt::Display for Loss {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "the last {} bytes were incomplete or corrupt ({})",
            self.bytes, self.reason
        )
    }
}

/// A whole recording in memory, device messages in file order (the order the live daemon
/// consumed them, which replay must keep to reproduce it bit for bit).
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    pub format: Format,
    pub messages: Vec<RecordedMessage>,
    /// The configuration in force when it was recorded, if the recording says.
    pub config_toml: Option<String>,
    pub truth: Vec<TruthSample>,
    /// Set only by a tolerant read of a damaged file.
    pub loss: Option<Loss>,
}

impl Recording {
    pub fn open(path: &Path, mode: ReadMode) -> Result<Self, RecordingError> {
        let bytes = std::fs::read(path).map_err(|source| RecordingError::Open {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&bytes, path, mode)
    }

    /// `path` only names the source in errors.
    pub(crate) fn parse(bytes: &[u8], path: &Path, mode: ReadMode) -> Result<Self, RecordingError> {
        if bytes.starts_with(mcap::MAGIC) {
            return McapParser::new(path, mode).parse(bytes);
        }
        let encoding = sniff_raw_dump(bytes).ok_or_else(|| RecordingError::UnknownFormat {
            path: path.to_path_buf(),
        })?;
        Ok(Self {
            format: Format::RawDump(encoding),
            messages: bytes
                .chunks(RAW_DUMP_CHUNK)
                .map(|chunk| RecordedMessage {
                    log_time_ns: 0,
                    sensor: RAW_DUMP_SENSOR.to_string(),
                    direction: Direction::Rx,
                    encoding,
                    data: chunk.to_vec(),
                })
                .collect(),
            config_toml: None,
            truth: Vec::new(),
            loss: None,
        })
    }
}

/// Largest top-level record the streaming reader accepts: chunks are closed about once a
/// second, so a real one is far smaller; a bigger length is damage, not a reason to allocate.
const MAX_STREAMED_RECORD: u64 = 256 << 20;

/// Reads a recording message by message in file order, holding at most one MCAP chunk in
/// memory, so that a long flight replays in a few megabytes.
pub(crate) struct RecordingReader<'p> {
    input: BufReader<File>,
    parser: McapParser<'p>,
    format: Format,
    offset: u64,
    pending: VecDeque<RecordedMessage>,
    raw_head: Option<Vec<u8>>,
    done: bool,
    loss: Option<Loss>,
    length: u64,
}

impl<'p> RecordingReader<'p> {
    pub(crate) fn open(path: &'p Path, mode: ReadMode) -> Result<Self, RecordingError> {
        let open_error = |source| RecordingError::Open {
            path: path.to_path_buf(),
            source,
        };
        let file = File::open(path).map_err(open_error)?;
        let length = file.metadata().map_err(open_error)?.len();
        let mut input = BufReader::with_capacity(1 << 16, file);
        let mut head = Vec::with_capacity(SNIFF_BYTES);
        (&mut input)
            .take(SNIFF_BYTES as u64)
            .read_to_end(&mut head)
            .map_err(open_error)?;
        let mut reader = Self {
            input,
            parser: McapParser::new(path, mode),
            format: Format::Mcap,
            offset: 0,
            pending: VecDeque::new(),
            raw_head: None,
            done: false,
            loss: None,
            length,
        };
        if head.starts_with(mcap::MAGIC) {
            reader.offset = mcap::MAGIC.len() as u64;
            reader
                .input
                .seek(io::SeekFrom::Start(reader.offset))
                .map_err(open_error)?;
            // Metadata (the configuration) precedes the first message.
            reader.fill_until_message()?;
        } else {
            let encoding = sniff_raw_dump(&head).ok_or_else(|| RecordingError::UnknownFormat {
                path: path.to_path_buf(),
            })?;
            reader.format = Format::RawDump(encoding);
            reader.raw_head = Some(head);
        }
        Ok(reader)
    }

    pub(crate) fn format(&self) -> Format {
        self.format
    }

    /// The configuration the recording was made with, if it says.
    pub(crate) fn config_toml(&self) -> Option<&str> {
        self.parser.config_toml.as_deref()
    }

    /// Bytes read so far and the file's length, for progress.
    pub(crate) fn position(&self) -> (u64, u64) {
        (self.offset.min(self.length), self.length)
    }

    /// Set once a tolerant read met damage.
    pub(crate) fn loss(&self) -> Option<&Loss> {
        self.loss.as_ref()
    }

    /// The ROS topics seen so far, each with its schema name.
    pub(crate) fn ros_topics(&self) -> &BTreeMap<String, String> {
        &self.parser.ros_topics
    }

    /// The `/tf_static` transforms read so far, in file order.
    pub(crate) fn tf_static(&self) -> &[rosmsg::TransformStamped] {
        &self.parser.tf_static
    }

    /// `/truth` samples read so far, in `log_time` order once the file is read.
    pub(crate) fn take_truth(&mut self) -> Vec<TruthSample> {
        self.parser.truth.sort_by_key(|(log_time, _)| *log_time);
        std::mem::take(&mut self.parser.truth)
            .into_iter()
            .map(|(_, sample)| sample)
            .collect()
    }

    /// The next device message in file order, `None` at the end.
    pub(crate) fn next_message(&mut self) -> Result<Option<RecordedMessage>, RecordingError> {
        loop {
            if let Some(message) = self.pending.pop_front() {
                return Ok(Some(message));
            }
            if self.done {
                return Ok(None);
            }
            match self.format {
                Format::Mcap => self.read_record()?,
                Format::RawDump(encoding) => self.read_raw(encoding)?,
            }
        }
    }

    fn fill_until_message(&mut self) -> Result<(), RecordingError> {
        while self.pending.is_empty() && !self.done {
            self.read_record()?;
        }
        Ok(())
    }

    fn read_raw(&mut self, encoding: Encoding) -> Result<(), RecordingError> {
        let mut data = match self.raw_head.take() {
            Some(head) => head,
            None => {
                let mut buffer = Vec::with_capacity(RAW_DUMP_CHUNK);
                (&mut self.input)
                    .take(RAW_DUMP_CHUNK as u64)
                    .read_to_end(&mut buffer)
                    .map_err(|source| RecordingError::Open {
                        path: self.parser.path.to_path_buf(),
                        source,
                    })?;
                buffer
            }
        };
        if data.is_empty() {
            self.done = true;
        }
        self.offset += data.len() as u64;
        while !data.is_empty() {
            let rest = data.split_off(data.len().min(RAW_DUMP_CHUNK));
            self.pending.push_back(RecordedMessage {
                log_time_ns: 0,
                sensor: RAW_DUMP_SENSOR.to_string(),
                direction: Direction::Rx,
                encoding,
                data,
            });
            data = rest;
        }
        Ok(())
    }

    fn read_record(&mut self) -> Result<(), RecordingError> {
        let at = self.offset;
        let mut header = [0u8; 9];
        let body = match read_full(&mut self.input, &mut header) {
            Ok(true) => {
                let length = u64::from_le_bytes(header[1..].try_into().expect("8 bytes"));
                if length > MAX_STREAMED_RECORD {
                    return self.damaged(at, format!("record of {length} bytes is implausible"));
                }
                let mut body = vec![0u8; length as usize];
                match read_full(&mut self.input, &mut body) {
                    Ok(true) => body,
                    Ok(false) => {
                        return self.damaged(at, format!("record of {length} bytes cut short"))
                    }
                    Err(e) => return self.damaged(at, e.to_string()),
                }
            }
            Ok(false) => {
                return self.damaged(at, "no footer: the recording was not finished".into())
            }
            Err(e) => return self.damaged(at, e.to_string()),
        };
        self.offset += 9 + body.len() as u64;
        let record = match mcap::parse_record(header[0], &body) {
            Ok(record) => record,
            Err(e) => return self.damaged(at, e.to_string()),
        };
        let outcome = match self.parser.record(record)? {
            Step::Continue => Ok(()),
            Step::Chunk(inner) => self
                .parser
                .records(&inner, 0, false)?
                .map_err(|damage| format!("chunk: {}", damage.reason)),
            Step::Damaged(reason) => Err(reason),
            Step::End => {
                self.done = true;
                Ok(())
            }
        };
        self.pending.extend(self.parser.messages.drain(..));
        match outcome {
            Ok(()) => Ok(()),
            Err(reason) => self.damaged(at, reason),
        }
    }

    fn damaged(&mut self, offset: u64, reason: String) -> Result<(), RecordingError> {
        self.done = true;
        match self.parser.mode {
            ReadMode::Strict => Err(RecordingError::Corrupt {
                path: self.parser.path.to_path_buf(),
                offset,
                reason,
            }),
            ReadMode::Tolerant => {
                self.loss = Some(Loss {
                    bytes: self.length.saturating_sub(offset),
                    reason,
                });
                Ok(())
            }
        }
    }
}

/// Fills `buffer`; false if the input ended first (a partial read counts as ended).
fn read_full(input: &mut impl Read, buffer: &mut [u8]) -> io::Result<bool> {
    match input.read_exact(buffer) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    }
}

enum ChannelKind {
    Device {
        sensor: String,
        direction: Direction,
        encoding: Encoding,
    },
    Truth,
    /// `/tf_static`: the mounts a ROS recording may carry.
    TfStatic(rosmsg::Encoding),
    /// A ROS channel of a type the replay does not read.
    Skipped,
}

/// Reads the records one by one, keeping byte offsets so damage can be located and measured.
/// [`Recorder`] writes chunks uncompressed; other tools' zstd and lz4 chunks are decompressed
/// whole, and damage inside them is located at the chunk.
struct McapParser<'p> {
    path: &'p Path,
    mode: ReadMode,
    channels: HashMap<u16, ChannelKind>,
    messages: Vec<RecordedMessage>,
    config_toml: Option<String>,
    truth: Vec<(u64, TruthSample)>,
    /// Schema id to (name, encoding), for recognising ROS channels.
    schemas: HashMap<u16, (String, String)>,
    /// Every ROS topic seen, with its schema name.
    ros_topics: BTreeMap<String, String>,
    tf_static: Vec<rosmsg::TransformStamped>,
}

/// A record that could not be read, at `offset`.
struct Damage {
    offset: u64,
    reason: String,
}

impl<'p> McapParser<'p> {
    fn new(path: &'p Path, mode: ReadMode) -> Self {
        Self {
            path,
            mode,
            channels: HashMap::new(),
            messages: Vec::new(),
            config_toml: None,
            truth: Vec::new(),
            schemas: HashMap::new(),
            ros_topics: BTreeMap::new(),
            tf_static: Vec::new(),
        }
    }

    fn parse(mut self, bytes: &[u8]) -> Result<Recording, RecordingError> {
        let start = mcap::MAGIC.len();
        let loss = match self.records(bytes, start, true) {
            Ok(Ok(())) => None,
            Ok(Err(damage)) => match self.mode {
                ReadMode::Strict => {
                    return Err(RecordingError::Corrupt {
                        path: self.path.to_path_buf(),
                        offset: damage.offset,
                        reason: damage.reason,
                    })
                }
                ReadMode::Tolerant => Some(Loss {
                    bytes: bytes.len() as u64 - damage.offset,
                    reason: damage.reason,
                }),
            },
            Err(fatal) => return Err(fatal),
        };
        self.truth.sort_by_key(|(log_time, _)| *log_time);
        Ok(Recording {
            format: Format::Mcap,
            messages: self.messages,
            config_toml: self.config_toml,
            truth: self.truth.into_iter().map(|(_, sample)| sample).collect(),
            loss,
        })
    }

    /// Walks `opcode u8, length u64 LE, body` records from `offset`. The outer `Result` is for
    /// errors that are not damage (an unknown sensor), the inner one for damage.
    fn records(
        &mut self,
        bytes: &[u8],
        mut offset: usize,
        top_level: bool,
    ) -> Result<Result<(), Damage>, RecordingError> {
        let damage = |offset: usize, reason: String| Damage {
            offset: offset as u64,
            reason,
        };
        while offset < bytes.len() {
            let Some(length) = bytes
                .get(offset + 1..offset + 9)
                .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
            else {
                return Ok(Err(damage(offset, "record header cut short".into())));
            };
            let body_start = offset + 9;
            let Some(body) = usize::try_from(length)
                .ok()
                .and_then(|length| bytes.get(body_start..body_start.checked_add(length)?))
            else {
                return Ok(Err(damage(
                    offset,
                    format!("record of {length} bytes cut short"),
                )));
            };
            let record = match mcap::parse_record(bytes[offset], body) {
                Ok(record) => record,
                Err(e) => return Ok(Err(damage(offset, e.to_string()))),
            };
            match self.record(record)? {
                Step::Continue => {}
                // Chunks never nest; refusing it also bounds the recursion on hostile input.
                Step::Chunk(_) if !top_level => {
                    return Ok(Err(damage(offset, "a chunk inside a chunk".into())))
                }
                Step::Chunk(inner) => {
                    if let Err(inner_damage) = self.records(&inner, 0, false)? {
                        return Ok(Err(damage(
                            offset,
                            format!("chunk: {}", inner_damage.reason),
                        )));
                    }
                }
                Step::Damaged(reason) => return Ok(Err(damage(offset, reason))),
                Step::End if top_level => return Ok(Ok(())),
                Step::End => {}
            }
            offset = body_start + body.len();
        }
        if top_level {
            Ok(Err(damage(
                offset,
                "no footer: the recording was not finished".into(),
            )))
        } else {
            Ok(Ok(()))
        }
    }

    fn record(&mut self, record: Record<'_>) -> Result<Step, RecordingError> {
        match record {
            Record::Schema { header, .. } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(channel) => self.channel(
                channel.id,
                channel.schema_id,
                channel.topic,
                channel.message_encoding,
            )?,
            Record::Message { header, data } => return self.message(header, &data),
            Record::Metadata(metadata) if metadata.name == CONFIG_METADATA_NAME => {
                self.config_toml = metadata.metadata.get(CONFIG_METADATA_KEY).cloned();
            }
            Record::Chunk { header, data } if header.compression.is_empty() => {
                return Ok(Step::Chunk(data.into_owned()));
            }
            Record::Chunk { header, data } => {
                return Ok(
                    match decompress_chunk(&header.compression, &data, header.uncompressed_size) {
                        Ok(inner) => Step::Chunk(inner),
                        Err(reason) => Step::Damaged(reason),
                    },
                );
            }
            Record::DataEnd(_) | Record::Footer(_) => return Ok(Step::End),
            _ => {}
        }
        Ok(Step::Continue)
    }

    fn channel(
        &mut self,
        id: u16,
        schema_id: u16,
        topic: String,
        encoding: String,
    ) -> Result<(), RecordingError> {
        let kind = if topic == TRUTH_TOPIC && encoding == TRUTH_ENCODING {
            ChannelKind::Truth
        } else if let Some(kind) = self.ros_channel(schema_id, &topic, &encoding) {
            kind
        } else {
            let Some(encoding_kind) = Encoding::parse(&encoding) else {
                return Err(RecordingError::UnknownEncoding {
                    path: self.path.to_path_buf(),
                    topic,
                    encoding,
                });
            };
            let (sensor, direction) =
                split_topic(&topic).ok_or_else(|| RecordingError::BadTopic {
                    path: self.path.to_path_buf(),
                    topic: topic.clone(),
                })?;
            ChannelKind::Device {
                sensor,
                direction,
                encoding: encoding_kind,
            }
        };
        self.channels.insert(id, kind);
        Ok(())
    }

    /// The channel's kind if its schema is a ROS message, read or skipped.
    fn ros_channel(&mut self, schema_id: u16, topic: &str, encoding: &str) -> Option<ChannelKind> {
        let (name, schema_encoding) = self.schemas.get(&schema_id)?;
        let ros_encoding = rosmsg::Encoding::from_mcap(encoding, schema_encoding)?;
        self.ros_topics.insert(topic.to_string(), name.clone());
        Some(match rosmsg::Kind::from_schema_name(name) {
            Some(
                kind @ (rosmsg::Kind::LaserScan
                | rosmsg::Kind::MultiEchoLaserScan
                | rosmsg::Kind::Imu),
            ) => ChannelKind::Device {
                sensor: topic.to_string(),
                direction: Direction::Rx,
                encoding: Encoding::Ros(kind, ros_encoding),
            },
            Some(rosmsg::Kind::TfMessage) if topic == TF_STATIC_TOPIC => {
                ChannelKind::TfStatic(ros_encoding)
            }
            Some(rosmsg::Kind::TfMessage) | None => ChannelKind::Skipped,
        })
    }

    fn message(&mut self, header: MessageHeader, data: &[u8]) -> Result<Step, RecordingError> {
        match self.channels.get(&header.channel_id) {
            Some(ChannelKind::Device {
                sensor,
                direction,
                encoding,
            }) => self.messages.push(RecordedMessage {
                log_time_ns: header.log_time,
                sensor: sensor.clone(),
                direction: *direction,
                encoding: *encoding,
                data: data.to_vec(),
            }),
            Some(ChannelKind::Truth) => {
                let sample = serde_json::from_slice::<TruthJson>(data)
                    .map_err(|e| e.to_string())
                    .and_then(TruthJson::to_sample)
                    .map_err(|reason| RecordingError::BadTruth {
                        path: self.path.to_path_buf(),
                        log_time_ns: header.log_time,
                        reason,
                    })?;
                self.truth.push((header.log_time, sample));
            }
            Some(ChannelKind::TfStatic(encoding)) => {
                match rosmsg::decode(rosmsg::Kind::TfMessage, *encoding, data) {
                    Ok(rosmsg::Message::Tf(tf)) => self.tf_static.extend(tf.transforms),
                    // A mount it would have given is missing, and the replay names it.
                    Ok(_) | Err(_) => tracing::warn!(
                        log_time_ns = header.log_time,
                        "a {TF_STATIC_TOPIC} message that does not decode is skipped"
                    ),
                }
            }
            Some(ChannelKind::Skipped) => {}
            None => {
                return Ok(Step::Damaged(format!(
                    "a message on channel {} that was never declared",
                    header.channel_id
                )))
            }
        }
        Ok(Step::Continue)
    }
}

/// The records of a chunk other tools compressed: Python's `mcap` writer and ROS 2 write zstd
/// by default, some writers lz4.
fn decompress_chunk(
    compression: &str,
    data: &[u8],
    uncompressed_size: u64,
) -> Result<Vec<u8>, String> {
    // The size comes from the file: bound it before allocating, as for any other record.
    if uncompressed_size > MAX_STREAMED_RECORD {
        return Err(format!(
            "chunk of {uncompressed_size} bytes uncompressed is implausible"
        ));
    }
    let size = uncompressed_size as usize;
    let inner = match compression {
        "zstd" => zstd::bulk::decompress(data, size).map_err(|e| format!("zstd chunk: {e}"))?,
        "lz4" => {
            let mut inner = Vec::with_capacity(size);
            lz4::Decoder::new(data)
                .and_then(|decoder| decoder.take(uncompressed_size + 1).read_to_end(&mut inner))
                .map_err(|e| format!("lz4 chunk: {e}"))?;
            inner
        }
        other => {
            return Err(format!(
            "chunk compressed with `{other}`, which ladar-odometer cannot read (zstd, lz4 or none)"
        ))
        }
    };
    if inner.len() != size {
        return Err(format!(
            "{compression} chunk decompressed to {} bytes, its header says {size}",
            inner.len()
        ));
    }
    Ok(inner)
}

enum Step {
    Continue,
    Chunk(Vec<u8>),
    Damaged(String),
    End,
}

fn split_topic(topic: &str) -> Option<(String, Direction)> {
    let rest = topic.strip_prefix('/')?;
    let (sensor, direction) = rest.rsplit_once('/')?;
    let direction = match direction {
        "rx" => Direction::Rx,
        "tx" => Direction::Tx,
        _ => return None,
    };
    (!sensor.is_empty()).then(|| (sensor.to_string(), direction))
}

/// Decides whether the start of a raw dump is Xbus (at least two checksum-valid frames) or
/// SCIP 2.0 (text: printable ASCII and line feeds, with the blank line that ends a response).
pub(crate) fn sniff_raw_dump(bytes: &[u8]) -> Option<Encoding> {
    let head = &bytes[..bytes.len().min(SNIFF_BYTES)];
    if count_xbus_frames(head) >= 2 {
        return Some(Encoding::Xbus);
    }
    let text = head
        .iter()
        .filter(|&&b| b == b'\n' || (0x20..0x7f).contains(&b))
        .count();
    let looks_like_scip =
        !head.is_empty() && text * 100 >= head.len() * 99 && head.windows(2).any(|w| w == b"\n\n");
    looks_like_scip.then_some(Encoding::Scip2)
}

/// Xbus frame: 0xFA, bus id, message id, length (0xFF: two more length bytes), data, checksum
/// making the sum from the bus id on zero modulo 256.
fn count_xbus_frames(bytes: &[u8]) -> usize {
    let mut count = 0;
    let mut i = 0;
    while i + 5 <= bytes.len() {
        match xbus_frame_len(&bytes[i..]) {
            Some(len) => {
                count += 1;
                i += len;
            }
            None => i += 1,
        }
    }
    count
}

fn xbus_frame_len(bytes: &[u8]) -> Option<usize> {
    if bytes.first() != Some(&0xFA) {
        return None;
    }
    let (data_len, header_len) = match *bytes.get(3)? {
        0xFF => (
            usize::from(u16::from_be_bytes([*bytes.get(4)?, *bytes.get(5)?])),
            6,
        ),
        len => (usize::from(len), 4),
    };
    let frame_len = header_len + data_len + 1;
    let sum = bytes
        .get(1..frame_len)?
        .iter()
        .fold(0u8, |sum, b| sum.wrapping_add(*b));
    (sum == 0).then_some(frame_len)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    const CONFIG: &str = "[mavlink]\nprofile = \"px4\"\n";

    fn path() -> PathBuf {
        PathBuf::from("test.mcap")
    }

    /// A deterministic mix of device traffic: (sensor, encoding, direction, time, bytes).
    fn traffic() -> Vec<(&'static str, Encoding, Direction, u64, Vec<u8>)> {
        let mut out = Vec::new();
        for i in 0..300u64 {
            let bytes: Vec<u8> = (0..(i * 7 % 97) as u8)
                .map(|b| b.wrapping_mul(31).wrapping_add(i as u8))
                .collect();
            let (sensor, encoding) = if i % 3 == 0 {
                ("imu", Encoding::Xbus)
            } else {
                ("front", Encoding::Scip2)
            };
            let direction = if i % 5 == 0 {
                Direction::Tx
            } else {
                Direction::Rx
            };
            out.push((sensor, encoding, direction, 1_000 + i * 1_000, bytes));
        }
        out
    }

    fn record_all<W: Write + Seek>(recorder: &mut Recorder<W>) {
        for (sensor, encoding, direction, t, bytes) in traffic() {
            recorder
                .bytes(sensor, encoding, direction, t, &bytes)
                .unwrap();
        }
    }

    fn concatenated(messages: &[RecordedMessage], sensor: &str, direction: Direction) -> Vec<u8> {
        messages
            .iter()
            .filter(|m| m.sensor == sensor && m.direction == direction)
            .flat_map(|m| m.data.iter().copied())
            .collect()
    }

    fn expected(sensor: &str, direction: Direction) -> Vec<u8> {
        traffic()
            .into_iter()
            .filter(|(s, _, d, _, _)| *s == sensor && *d == direction)
            .flat_map(|(_, _, _, _, bytes)| bytes)
            .collect()
    }

    fn assert_every_byte_is_back(recording: &Recording) {
        for sensor in ["imu", "front"] {
            for direction in [Direction::Rx, Direction::Tx] {
                assert_eq!(
                    concatenated(&recording.messages, sensor, direction),
                    expected(sensor, direction),
                    "{sensor} {direction:?}"
                );
            }
        }
        assert_eq!(recording.messages.len(), traffic().len());
    }

    fn scratch(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("ladar-rec-{name}-{}.mcap", std::process::id()))
    }

    fn truth_sample() -> TruthSample {
        TruthSample {
            t: 0.5,
            p: Vector3::new(1.0, 2.0, 3.0),
            q: UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
            v: Vector3::new(-1.0, 0.0, 0.5),
        }
    }

    #[test]
    fn every_byte_written_is_read_back_with_its_channel_config_and_truth() {
        let file = scratch("full");
        let mut recorder = Recorder::create(&file, CONFIG).unwrap();
        record_all(&mut recorder);
        recorder.truth(500, &truth_sample()).unwrap();
        recorder.finish().unwrap();

        let recording = Recording::open(&file, ReadMode::Strict).unwrap();
        assert_eq!(recording.format, Format::Mcap);
        assert_eq!(recording.loss, None);
        assert_eq!(recording.config_toml.as_deref(), Some(CONFIG));
        assert_every_byte_is_back(&recording);
        assert!(recording
            .messages
            .windows(2)
            .all(|w| w[0].log_time_ns <= w[1].log_time_ns));
        let first_imu = recording
            .messages
            .iter()
            .find(|m| m.sensor == "imu")
            .unwrap();
        assert_eq!(first_imu.encoding, Encoding::Xbus);
        assert_eq!(first_imu.topic(), "/imu/tx");
        let truth = recording.truth[0];
        let want = truth_sample();
        assert_eq!((truth.t, truth.p, truth.v), (want.t, want.p, want.v));
        assert!(truth.q.angle_to(&want.q) < 1e-12);
        std::fs::remove_file(&file).unwrap();
    }

    /// `traffic()` as another tool writes it: compressed chunks of about 2 kB.
    fn written_by_another_tool(compression: mcap::Compression) -> Vec<u8> {
        let mut out = Cursor::new(Vec::new());
        let mut writer = WriteOptions::new()
            .compression(Some(compression))
            .chunk_size(Some(2048))
            .create(&mut out)
            .unwrap();
        let mut channels = HashMap::new();
        for (sequence, (sensor, encoding, direction, t, bytes)) in traffic().into_iter().enumerate()
        {
            let topic = format!("/{sensor}/{}", direction.as_str());
            let channel = *channels.entry(topic.clone()).or_insert_with(|| {
                writer
                    .add_channel(0, &topic, encoding.as_str(), &BTreeMap::new())
                    .unwrap()
            });
            let header = MessageHeader {
                channel_id: channel,
                sequence: sequence as u32,
                log_time: t,
                publish_time: t,
            };
            writer.write_to_known_channel(&header, &bytes).unwrap();
        }
        writer.finish().unwrap();
        drop(writer);
        out.into_inner()
    }

    #[test]
    fn zstd_and_lz4_chunks_from_other_tools_are_read_whole_and_streamed() {
        for compression in [mcap::Compression::Zstd, mcap::Compression::Lz4] {
            let bytes = written_by_another_tool(compression);
            let recording = Recording::parse(&bytes, &path(), ReadMode::Strict)
                .unwrap_or_else(|e| panic!("{compression:?}: {e}"));
            assert_every_byte_is_back(&recording);
            let file = scratch(&format!("{compression:?}"));
            std::fs::write(&file, &bytes).unwrap();
            let mut reader = RecordingReader::open(&file, ReadMode::Strict).unwrap();
            let mut messages = Vec::new();
            while let Some(message) = reader.next_message().unwrap() {
                messages.push(message);
            }
            assert_eq!(messages, recording.messages, "{compression:?}");
            std::fs::remove_file(&file).unwrap();
        }
    }

    #[test]
    fn a_damaged_compressed_chunk_is_refused_in_one_line_and_the_chunks_before_it_kept() {
        let mut bytes = written_by_another_tool(mcap::Compression::Zstd);
        let mut chunks = Vec::new();
        let mut offset = mcap::MAGIC.len();
        while bytes[offset] != 0x0F {
            // Up to the data end record, top-level records: opcode, u64 length, body.
            if bytes[offset] == 0x06 {
                chunks.push(offset);
            }
            let length = u64::from_le_bytes(bytes[offset + 1..offset + 9].try_into().unwrap());
            offset += 9 + length as usize;
        }
        assert!(chunks.len() >= 3, "{} chunks", chunks.len());
        // The zstd frame's magic number: the chunk header is times, sizes, crc and "zstd".
        let frame = chunks[chunks.len() / 2] + 9 + 8 + 8 + 8 + 4 + 4 + 4 + 8;
        bytes[frame] ^= 0xFF;
        let err = Recording::parse(&bytes, &path(), ReadMode::Strict)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("truncated or corrupt") && !err.contains('\n'),
            "{err}"
        );
        let kept = Recording::parse(&bytes, &path(), ReadMode::Tolerant).unwrap();
        assert!(kept.loss.is_some());
        assert!(
            !kept.messages.is_empty() && kept.messages.len() < traffic().len(),
            "{}",
            kept.messages.len()
        );
    }

    #[test]
    fn an_unknown_compression_names_what_can_be_read() {
        let reason = decompress_chunk("bz2", &[1, 2, 3], 3).unwrap_err();
        assert!(
            reason.contains("`bz2`") && reason.contains("zstd, lz4"),
            "{reason}"
        );
        let reason = decompress_chunk("zstd", &[1, 2, 3], MAX_STREAMED_RECORD + 1).unwrap_err();
        assert!(reason.contains("implausible"), "{reason}");
    }

    #[test]
    fn streaming_reader_gives_file_order_even_when_log_times_go_back() {
        let file = scratch("streaming.mcap");
        let mut recorder = Recorder::create(&file, CONFIG).unwrap();
        // Two sensor tasks stamp their reads independently, so consumption order can run
        // against log_time; replay must keep the order of consumption.
        let times = [5_000u64, 4_000, 6_000, 1_000];
        for (i, t) in times.iter().enumerate() {
            recorder
                .bytes("front", Encoding::Scip2, Direction::Rx, *t, &[i as u8])
                .unwrap();
            if i == 1 {
                recorder.flush().unwrap();
            }
        }
        recorder.truth(10, &truth_sample()).unwrap();
        drop(recorder);
        let mut reader = RecordingReader::open(&file, ReadMode::Strict).unwrap();
        assert_eq!(reader.config_toml(), Some(CONFIG));
        let mut got = Vec::new();
        while let Some(message) = reader.next_message().unwrap() {
            got.push((message.log_time_ns, message.data[0]));
        }
        assert_eq!(got, [(5_000, 0), (4_000, 1), (6_000, 2), (1_000, 3)]);
        assert_eq!(reader.take_truth().len(), 1);
        let whole = Recording::open(&file, ReadMode::Strict).unwrap();
        let order: Vec<u64> = whole.messages.iter().map(|m| m.log_time_ns).collect();
        assert_eq!(order, times);
        std::fs::remove_file(&file).unwrap();
    }

    #[test]
    fn streaming_reader_reports_truncation_strictly_and_keeps_chunks_tolerantly() {
        let file = scratch("streaming-cut.mcap");
        let mut recorder = Recorder::create(&file, CONFIG).unwrap();
        record_all(&mut recorder);
        recorder.flush().unwrap();
        recorder
            .bytes("imu", Encoding::Xbus, Direction::Rx, 1, &[1, 2, 3])
            .unwrap();
        std::mem::forget(recorder);
        let mut strict = RecordingReader::open(&file, ReadMode::Strict).unwrap();
        let error = loop {
            match strict.next_message() {
                Ok(Some(_)) => {}
                Ok(None) => panic!("a cut file must not read as complete"),
                Err(e) => break e,
            }
        };
        assert!(
            error.to_string().contains("truncated or corrupt"),
            "{error}"
        );
        let mut tolerant = RecordingReader::open(&file, ReadMode::Tolerant).unwrap();
        let mut count = 0;
        while tolerant.next_message().unwrap().is_some() {
            count += 1;
        }
        assert_eq!(count, traffic().len());
        assert!(tolerant.loss().is_some());
        std::fs::remove_file(&file).unwrap();
    }

    #[test]
    fn dropping_the_recorder_after_sigint_finishes_the_file() {
        let file = scratch("dropped");
        {
            let mut recorder = Recorder::create(&file, CONFIG).unwrap();
            record_all(&mut recorder);
            // The task is cancelled here: no finish(), only the drop of an orderly shutdown.
        }
        let recording = Recording::open(&file, ReadMode::Strict).unwrap();
        assert_every_byte_is_back(&recording);
        std::fs::remove_file(&file).unwrap();
    }

    #[test]
    fn a_crash_after_flush_loses_nothing_that_was_flushed() {
        let file = scratch("crash");
        let mut recorder = Recorder::create(&file, CONFIG).unwrap();
        record_all(&mut recorder);
        recorder.flush().unwrap();
        recorder
            .bytes("front", Encoding::Scip2, Direction::Rx, 9_999_999, b"lost")
            .unwrap();
        // A power cut now: the file holds exactly what was flushed.
        let on_disk = std::fs::read(&file).unwrap();
        std::mem::forget(recorder);

        let err = Recording::parse(&on_disk, &file, ReadMode::Strict)
            .unwrap_err()
            .to_string();
        assert!(err.contains("--tolerant") && !err.contains('\n'), "{err}");
        let recording = Recording::parse(&on_disk, &file, ReadMode::Tolerant).unwrap();
        assert_every_byte_is_back(&recording);
        assert!(recording.loss.is_some());
        std::fs::remove_file(&file).unwrap();
    }

    #[test]
    fn a_truncated_file_keeps_complete_chunks_and_reports_the_loss() {
        let file = scratch("truncated");
        let mut recorder = Recorder::create(&file, CONFIG).unwrap();
        record_all(&mut recorder);
        recorder.flush().unwrap();
        let flushed_len = std::fs::metadata(&file).unwrap().len() as usize;
        recorder
            .bytes("front", Encoding::Scip2, Direction::Rx, 9_999_999, b"tail")
            .unwrap();
        recorder.finish().unwrap();
        let whole = std::fs::read(&file).unwrap();
        std::fs::remove_file(&file).unwrap();
        let complete = Recording::parse(&whole, &file, ReadMode::Strict).unwrap();
        assert_eq!(complete.messages.last().unwrap().data, b"tail");

        // Cut inside the second chunk: every message of the first one survives.
        let cut = &whole[..flushed_len + 10];
        let recording = Recording::parse(cut, &file, ReadMode::Tolerant).unwrap();
        assert_every_byte_is_back(&recording);
        let loss = recording.loss.expect("a truncated file reports its loss");
        assert_eq!(loss.bytes, 10, "{loss}");
        assert!(Recording::parse(cut, &file, ReadMode::Strict).is_err());

        let header_only = Recording::parse(&whole[..20], &file, ReadMode::Tolerant).unwrap();
        assert!(header_only.messages.is_empty() && header_only.loss.is_some());
    }

    #[test]
    fn corrupt_bytes_never_panic() {
        let file = scratch("corrupt");
        let mut recorder = Recorder::create(&file, CONFIG).unwrap();
        record_all(&mut recorder);
        recorder.finish().unwrap();
        let whole = std::fs::read(&file).unwrap();
        std::fs::remove_file(&file).unwrap();
        for (i, position) in (9..whole.len()).step_by(37).enumerate() {
            let mut damaged = whole.clone();
            damaged[position] ^= 0x5A ^ (i as u8);
            for mode in [ReadMode::Strict, ReadMode::Tolerant] {
                if let Err(e) = Recording::parse(&damaged, &file, mode) {
                    assert!(!e.to_string().contains('\n'));
                }
            }
        }
    }

    /// An MCAP chunk record (opcode 0x06, uncompressed) around `records`.
    fn chunk_record(records: &[u8]) -> Vec<u8> {
        let mut body = Vec::new();
        body.extend_from_slice(&[0; 24]); // start time, end time, uncompressed size
        body.extend_from_slice(&[0; 4]); // crc: not computed
        body.extend_from_slice(&[0; 4]); // compression "": none
        body.extend_from_slice(&(records.len() as u64).to_le_bytes());
        body.extend_from_slice(records);
        let mut record = vec![0x06];
        record.extend_from_slice(&(body.len() as u64).to_le_bytes());
        record.extend_from_slice(&body);
        record
    }

    #[test]
    fn deeply_nested_chunks_are_refused_without_exhausting_the_stack() {
        let mut nested = Vec::new();
        for _ in 0..1_000 {
            nested = chunk_record(&nested);
        }
        let mut bytes = mcap::MAGIC.to_vec();
        bytes.extend_from_slice(&nested);
        let err = Recording::parse(&bytes, &path(), ReadMode::Strict)
            .unwrap_err()
            .to_string();
        assert!(err.contains("a chunk inside a chunk"), "{err}");
    }

    #[test]
    fn an_unknown_encoding_is_a_recording_from_an_unknown_sensor() {
        let mut out = Cursor::new(Vec::new());
        {
            let mut writer = WriteOptions::new()
                .compression(None)
                .create(&mut out)
                .unwrap();
            let channel = writer
                .add_channel(0, "/lidar/rx", "nmea", &BTreeMap::new())
                .unwrap();
            writer
                .write_to_known_channel(
                    &MessageHeader {
                        channel_id: channel,
                        sequence: 1,
                        log_time: 1,
                        publish_time: 1,
                    },
                    b"$GPGGA",
                )
                .unwrap();
            writer.finish().unwrap();
        }
        let err = Recording::parse(out.get_ref(), &path(), ReadMode::Tolerant)
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("recording from an unknown sensor"), "{err}");
        assert!(err.contains("nmea") && err.contains("/lidar/rx"), "{err}");
    }

    #[test]
    fn raw_scip_dump_is_recognised_and_kept_whole() {
        let mut dump = Vec::new();
        for i in 0..2000 {
            dump.extend_from_slice(
                format!("MD0044072501000\n99b\n{i:04}\n0C0C0C0C0\n\n").as_bytes(),
            );
        }
        let recording = Recording::parse(&dump, &path(), ReadMode::Strict).unwrap();
        assert_eq!(recording.format, Format::RawDump(Encoding::Scip2));
        let back: Vec<u8> = recording
            .messages
            .iter()
            .flat_map(|m| m.data.clone())
            .collect();
        assert_eq!(back, dump);
        assert!(recording
            .messages
            .iter()
            .all(|m| m.log_time_ns == 0 && m.sensor == RAW_DUMP_SENSOR));
    }

    #[test]
    fn raw_xbus_dump_is_recognised() {
        // MTData2 frames with a valid checksum, after some line noise.
        let mut dump = vec![0x00, 0x13, 0xFA];
        for counter in 0..50u8 {
            let payload = [0x10, 0x20, 0x02, 0x00, counter];
            let mut frame = vec![0xFA, 0xFF, 0x36, payload.len() as u8];
            frame.extend_from_slice(&payload);
            let sum = frame[1..].iter().fold(0u8, |s, b| s.wrapping_add(*b));
            frame.push(0u8.wrapping_sub(sum));
            dump.extend_from_slice(&frame);
        }
        let recording = Recording::parse(&dump, &path(), ReadMode::Strict).unwrap();
        assert_eq!(recording.format, Format::RawDump(Encoding::Xbus));
        assert_eq!(recording.messages.concat_data(), dump);
    }

    #[test]
    fn neither_mcap_nor_a_dump_is_one_clear_line() {
        let noise: Vec<u8> = (0..5000u32)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8)
            .collect();
        let err = Recording::parse(&noise, &path(), ReadMode::Tolerant)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("neither an MCAP recording nor a raw SCIP or Xbus dump"),
            "{err}"
        );
        assert!(Recording::parse(b"", &path(), ReadMode::Tolerant).is_err());
    }

    #[test]
    fn real_captures_are_recognised_as_raw_dumps() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/vectors");
        if !dir.exists() {
            assert!(
                std::env::var_os("CI").is_none(),
                "../shared/vectors is missing on CI"
            );
            eprintln!("skipped: ../shared/vectors not found");
            return;
        }
        let scip = std::fs::read(dir.join("scip_urg04lx_GD0044072501_capture_B.txt")).unwrap();
        assert_eq!(sniff_raw_dump(&scip), Some(Encoding::Scip2));
        for set in 1..=5 {
            let xbus =
                std::fs::read(dir.join(format!("xsens-go-testdata/{set}/output.bin"))).unwrap();
            assert_eq!(count_xbus_frames(&xbus), 100, "set {set}");
            let recording = Recording::parse(&xbus, &path(), ReadMode::Strict).unwrap();
            assert_eq!(recording.format, Format::RawDump(Encoding::Xbus));
            assert_eq!(recording.messages.concat_data(), xbus);
        }
    }

    proptest::proptest! {
        #[test]
        fn any_bytes_parse_without_panicking(
            tail in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..400),
            as_mcap in proptest::prelude::any::<bool>(),
        ) {
            let mut bytes = if as_mcap { mcap::MAGIC.to_vec() } else { Vec::new() };
            bytes.extend_from_slice(&tail);
            for mode in [ReadMode::Strict, ReadMode::Tolerant] {
                if let Err(e) = Recording::parse(&bytes, &path(), mode) {
                    proptest::prop_assert!(!e.to_string().contains('\n'));
                }
            }
        }

        #[test]
        fn any_traffic_round_trips_byte_for_byte(
            chunks in proptest::collection::vec(
                (0..3usize, proptest::prelude::any::<bool>(),
                 proptest::collection::vec(proptest::prelude::any::<u8>(), 0..64)),
                0..40),
            flush_after in 0..40usize,
        ) {
            let names = ["front", "pitched", "imu"];
            let mut recorder = Recorder::new(Cursor::new(Vec::new()), CONFIG).unwrap();
            for (i, (sensor, tx, data)) in chunks.iter().enumerate() {
                let direction = if *tx { Direction::Tx } else { Direction::Rx };
                recorder.bytes(names[*sensor], Encoding::Xbus, direction, i as u64, data).unwrap();
                if i == flush_after {
                    recorder.flush().unwrap();
                }
            }
            let bytes = recorder.finish().unwrap().into_inner();
            let recording = Recording::parse(&bytes, &path(), ReadMode::Strict).unwrap();
            let back: Vec<(usize, bool, Vec<u8>)> = recording
                .messages
                .iter()
                .map(|m| {
                    let sensor = names.iter().position(|n| *n == m.sensor).unwrap();
                    (sensor, m.direction == Direction::Tx, m.data.clone())
                })
                .collect();
            proptest::prop_assert_eq!(back, chunks);
        }
    }

    trait ConcatData {
        fn concat_data(&self) -> Vec<u8>;
    }

    impl ConcatData for Vec<RecordedMessage> {
        fn concat_data(&self) -> Vec<u8> {
            self.iter().flat_map(|m| m.data.iter().copied()).collect()
        }
    }
}
