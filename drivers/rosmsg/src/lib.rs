//! The ROS messages a 2D LADAR/IMU replay needs, decoded from the bytes of an MCAP message in
//! either ROS encoding: `sensor_msgs` `LaserScan`, `MultiEchoLaserScan` and `Imu`, and
//! `tf2_msgs/TFMessage` (with `std_msgs/Header` and the `geometry_msgs` parts they hold).
//!
//! Sans-IO and never panicking: bytes in, a message or a one-line [`DecodeError`] out. Every
//! length read from the bytes is checked against what is left before anything is allocated, so
//! hostile input cannot ask for more memory than its own size.
//!
//! - ROS 1 (`ros1msg` schemas, `ros1` message encoding, as `mcap convert` writes from a bag):
//!   little-endian, packed, strings and arrays behind a u32 length, `time` as u32 seconds and
//!   u32 nanoseconds, and a `seq` in the header.
//! - ROS 2 (`ros2msg` schemas, `cdr` message encoding): a 4-byte encapsulation header (plain
//!   CDR, little- or big-endian), then XCDR1: each primitive aligned to its size counted from
//!   after that header, strings behind a u32 length that counts their NUL, `time` as i32
//!   seconds and u32 nanoseconds, and no `seq`.

mod reader;

#[cfg(feature = "encode")]
pub mod encode;

use reader::Reader;
use std::fmt;

/// How a message's bytes are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Encoding {
    Ros1,
    Cdr,
}

impl Encoding {
    /// From an MCAP channel's message encoding and its schema's encoding; `None` for anything
    /// else (JSON, protobuf, this project's raw bytes).
    pub fn from_mcap(message_encoding: &str, schema_encoding: &str) -> Option<Self> {
        match (message_encoding, schema_encoding) {
            ("ros1", "ros1msg") => Some(Self::Ros1),
            ("cdr", "ros2msg" | "ros2idl") => Some(Self::Cdr),
            _ => None,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Ros1 => "ros1",
            Self::Cdr => "cdr",
        }
    }
}

/// The message types this crate decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    LaserScan,
    MultiEchoLaserScan,
    Imu,
    TfMessage,
}

impl Kind {
    pub const ALL: [Self; 4] = [
        Self::LaserScan,
        Self::MultiEchoLaserScan,
        Self::Imu,
        Self::TfMessage,
    ];

    /// From a schema name, ROS 2 (`sensor_msgs/msg/Imu`) or ROS 1 (`sensor_msgs/Imu`) style.
    pub fn from_schema_name(name: &str) -> Option<Self> {
        let (package, rest) = name.split_once('/')?;
        let message = rest.strip_prefix("msg/").unwrap_or(rest);
        match (package, message) {
            ("sensor_msgs", "LaserScan") => Some(Self::LaserScan),
            ("sensor_msgs", "MultiEchoLaserScan") => Some(Self::MultiEchoLaserScan),
            ("sensor_msgs", "Imu") => Some(Self::Imu),
            ("tf2_msgs", "TFMessage") => Some(Self::TfMessage),
            _ => None,
        }
    }

    /// The ROS 2 schema name.
    pub fn schema_name(self) -> &'static str {
        match self {
            Self::LaserScan => "sensor_msgs/msg/LaserScan",
            Self::MultiEchoLaserScan => "sensor_msgs/msg/MultiEchoLaserScan",
            Self::Imu => "sensor_msgs/msg/Imu",
            Self::TfMessage => "tf2_msgs/msg/TFMessage",
        }
    }
}

/// A ROS time: seconds and nanoseconds since the epoch of the recording's clock.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord)]
pub struct Time {
    pub sec: i64,
    /// Below 1e9: the decoder refuses anything else.
    pub nanosec: u32,
}

impl Time {
    pub fn as_secs_f64(self) -> f64 {
        self.sec as f64 + f64::from(self.nanosec) * 1e-9
    }
}

/// `std_msgs/Header`; ROS 2 has no `seq`, read as 0.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Header {
    pub seq: u32,
    pub stamp: Time,
    pub frame_id: String,
}

/// `geometry_msgs/Vector3`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/Quaternion`, in ROS order (x, y, z, w).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

/// The angular and range limits and the timing of a planar scan, shared by `LaserScan` and
/// `MultiEchoLaserScan`. Angles in radians counter-clockwise about the scanner's z (up) axis
/// from its x axis, times in seconds.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ScanInfo {
    pub angle_min: f32,
    pub angle_max: f32,
    pub angle_increment: f32,
    /// Between two beams; 0 when the driver does not say.
    pub time_increment: f32,
    /// Between two scans; 0 when the driver does not say.
    pub scan_time: f32,
    pub range_min: f32,
    pub range_max: f32,
}

/// `sensor_msgs/LaserScan`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LaserScan {
    pub header: Header,
    pub info: ScanInfo,
    pub ranges: Vec<f32>,
    pub intensities: Vec<f32>,
}

/// A `sensor_msgs/LaserEcho[]`, flattened: beam `i` has the values
/// `values[starts[i]..starts[i + 1]]` (the last one runs to the end), so that a scan is two
/// allocations rather than one per beam.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Echoes {
    starts: Vec<u32>,
    values: Vec<f32>,
}

impl Echoes {
    /// From each beam's echoes.
    pub fn from_beams<'a>(beams: impl IntoIterator<Item = &'a [f32]>) -> Self {
        let mut echoes = Self::default();
        for beam in beams {
            echoes.push_beam(beam.iter().copied());
        }
        echoes
    }

    fn push_beam(&mut self, values: impl IntoIterator<Item = f32>) {
        // The decoder bounds the total by the message size, far below u32::MAX.
        self.starts.push(self.values.len() as u32);
        self.values.extend(values);
    }

    pub fn beams(&self) -> usize {
        self.starts.len()
    }

    /// The echoes of beam `index`, empty past the last beam.
    pub fn beam(&self, index: usize) -> &[f32] {
        let Some(&start) = self.starts.get(index) else {
            return &[];
        };
        let end = self
            .starts
            .get(index + 1)
            .map_or(self.values.len(), |&end| end as usize);
        self.values.get(start as usize..end).unwrap_or_default()
    }
}

/// `sensor_msgs/MultiEchoLaserScan`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MultiEchoLaserScan {
    pub header: Header,
    pub info: ScanInfo,
    pub ranges: Echoes,
    pub intensities: Echoes,
}

/// `sensor_msgs/Imu`; a covariance whose first element is -1 says the field is not provided.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Imu {
    pub header: Header,
    pub orientation: Quaternion,
    pub orientation_covariance: [f64; 9],
    /// rad/s about the IMU's axes (ROS: x forward, y left, z up).
    pub angular_velocity: Vector3,
    pub angular_velocity_covariance: [f64; 9],
    /// m/s^2, specific force along the IMU's axes.
    pub linear_acceleration: Vector3,
    pub linear_acceleration_covariance: [f64; 9],
}

/// `geometry_msgs/TransformStamped`: where `child_frame_id` sits in `header.frame_id`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub translation: Vector3,
    pub rotation: Quaternion,
}

/// `tf2_msgs/TFMessage`, as `/tf_static` carries a robot's mounts.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TfMessage {
    pub transforms: Vec<TransformStamped>,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Message {
    LaserScan(LaserScan),
    MultiEchoLaserScan(MultiEchoLaserScan),
    Imu(Imu),
    Tf(TfMessage),
}

/// Why a message could not be decoded; displays as one line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DecodeError {
    /// The bytes ended (or a length pointed) past the end, at byte `at` reading `field`.
    CutShort {
        field: &'static str,
        at: usize,
        needed: usize,
        left: usize,
    },
    /// A CDR payload whose encapsulation is not plain CDR (parameter lists, XCDR2).
    Representation([u8; 2]),
    /// A time whose nanoseconds are a second or more.
    Nanoseconds { field: &'static str, value: u32 },
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::CutShort {
                field,
                at,
                needed,
                left,
            } => write!(
                f,
                "message cut short at byte {at}: `{field}` needs {needed} bytes, {left} are left"
            ),
            Self::Representation([a, b]) => write!(
                f,
                "CDR encapsulation {a:#04x} {b:#04x} is not plain CDR (0x00 0x00 or 0x00 0x01); re-record with the default ROS 2 serialisation"
            ),
            Self::Nanoseconds { field, value } => {
                write!(f, "`{field}` has {value} nanoseconds, a second or more")
            }
        }
    }
}

impl std::error::Error for DecodeError {}

/// Decodes one message of type `kind` from its bytes.
pub fn decode(kind: Kind, encoding: Encoding, bytes: &[u8]) -> Result<Message, DecodeError> {
    let mut r = Reader::new(encoding, bytes)?;
    Ok(match kind {
        Kind::LaserScan => Message::LaserScan(laser_scan(&mut r)?),
        Kind::MultiEchoLaserScan => Message::MultiEchoLaserScan(multi_echo_laser_scan(&mut r)?),
        Kind::Imu => Message::Imu(imu(&mut r)?),
        Kind::TfMessage => Message::Tf(tf_message(&mut r)?),
    })
}

fn header(r: &mut Reader<'_>) -> Result<Header, DecodeError> {
    let seq = match r.encoding() {
        Encoding::Ros1 => r.u32("header.seq")?,
        Encoding::Cdr => 0,
    };
    Ok(Header {
        seq,
        stamp: r.time("header.stamp")?,
        frame_id: r.string("header.frame_id")?,
    })
}

fn scan_info(r: &mut Reader<'_>) -> Result<ScanInfo, DecodeError> {
    Ok(ScanInfo {
        angle_min: r.f32("angle_min")?,
        angle_max: r.f32("angle_max")?,
        angle_increment: r.f32("angle_increment")?,
        time_increment: r.f32("time_increment")?,
        scan_time: r.f32("scan_time")?,
        range_min: r.f32("range_min")?,
        range_max: r.f32("range_max")?,
    })
}

fn laser_scan(r: &mut Reader<'_>) -> Result<LaserScan, DecodeError> {
    Ok(LaserScan {
        header: header(r)?,
        info: scan_info(r)?,
        ranges: r.f32_sequence("ranges")?,
        intensities: r.f32_sequence("intensities")?,
    })
}

fn multi_echo_laser_scan(r: &mut Reader<'_>) -> Result<MultiEchoLaserScan, DecodeError> {
    Ok(MultiEchoLaserScan {
        header: header(r)?,
        info: scan_info(r)?,
        ranges: echoes(r, "ranges")?,
        intensities: echoes(r, "intensities")?,
    })
}

fn echoes(r: &mut Reader<'_>, field: &'static str) -> Result<Echoes, DecodeError> {
    // Each LaserEcho is at least its own u32 length.
    let beams = r.sequence_length(field, 4)?;
    let mut echoes = Echoes {
        starts: Vec::with_capacity(beams),
        values: Vec::new(),
    };
    for _ in 0..beams {
        let count = r.sequence_length(field, 4)?;
        echoes.starts.push(echoes.values.len() as u32);
        echoes.values.reserve(count);
        for _ in 0..count {
            echoes.values.push(r.f32(field)?);
        }
    }
    Ok(echoes)
}

fn vector3(r: &mut Reader<'_>, field: &'static str) -> Result<Vector3, DecodeError> {
    Ok(Vector3 {
        x: r.f64(field)?,
        y: r.f64(field)?,
        z: r.f64(field)?,
    })
}

fn quaternion(r: &mut Reader<'_>, field: &'static str) -> Result<Quaternion, DecodeError> {
    Ok(Quaternion {
        x: r.f64(field)?,
        y: r.f64(field)?,
        z: r.f64(field)?,
        w: r.f64(field)?,
    })
}

fn covariance(r: &mut Reader<'_>, field: &'static str) -> Result<[f64; 9], DecodeError> {
    let mut values = [0.0; 9];
    for value in &mut values {
        *value = r.f64(field)?;
    }
    Ok(values)
}

fn imu(r: &mut Reader<'_>) -> Result<Imu, DecodeError> {
    Ok(Imu {
        header: header(r)?,
        orientation: quaternion(r, "orientation")?,
        orientation_covariance: covariance(r, "orientation_covariance")?,
        angular_velocity: vector3(r, "angular_velocity")?,
        angular_velocity_covariance: covariance(r, "angular_velocity_covariance")?,
        linear_acceleration: vector3(r, "linear_acceleration")?,
        linear_acceleration_covariance: covariance(r, "linear_acceleration_covariance")?,
    })
}

fn tf_message(r: &mut Reader<'_>) -> Result<TfMessage, DecodeError> {
    // A TransformStamped is at least a header's stamp and two string lengths, and seven f64.
    let count = r.sequence_length("transforms", 8 + 4 + 4 + 7 * 8)?;
    let mut transforms = Vec::with_capacity(count);
    for _ in 0..count {
        transforms.push(TransformStamped {
            header: header(r)?,
            child_frame_id: r.string("child_frame_id")?,
            translation: vector3(r, "transform.translation")?,
            rotation: quaternion(r, "transform.rotation")?,
        });
    }
    Ok(TfMessage { transforms })
}
