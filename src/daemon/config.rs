//! The TOML configuration file: the daemon's sections (sensors, MAVLink, recording, outputs),
//! read with unknown keys refused and every value checked at start-up, so that each mistake is
//! one clear line naming the file and the key instead of a surprise in flight, and every
//! mistake of every table is listed at once.
//!
//! Example files: config/examples/.

use super::link::{parse_key_hex, read_key_file, LinkAddress, Signing};
use super::mavlink_out::{Identity, Profile, DEFAULT_COMPONENT_ID};
use crate::config::{ConfigError, Table};
// `run` and `serve` take the errors of `Config::parse` from here.
pub(crate) use crate::config::ConfigErrors;
use crate::sensors::Mount;
use serde::de::DeserializeOwned;
use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use toml::de::{DeTable, DeValue, ValueDeserializer};
use toml::Spanned;

/// The whole configuration file: the `[[scanner]]` tables, `[imu]` (required) and the tables
/// that default when left out.
#[derive(Debug, Clone)]
pub struct Config {
    pub scanners: Vec<ScannerConfig>,
    pub imu: ImuConfig,
    pub mavlink: Option<MavlinkConfig>,
    pub ros: RosConfig,
    pub recording: RecordingConfig,
    pub output: OutputConfig,
    pub fusion: crate::fusion::FusionConfig,
    pub odometry: crate::odometry::OdometryConfig,
    pub integrity: crate::integrity::IntegrityConfig,
    pub filter: crate::filter::FilterConfig,
}

/// How to reach a sensor: `serial:/dev/hokuyo_front`, `serial:/dev/xsens:115200` or
/// `tcp:192.168.0.10:10940`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SensorConnection {
    /// USB CDC devices ignore the baud rate; a real UART needs it.
    Serial {
        path: PathBuf,
        baud: Option<u32>,
    },
    Tcp {
        host: String,
        port: u16,
    },
}

impl FromStr for SensorConnection {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let usage = "use serial:/dev/NAME, serial:/dev/NAME:BAUD or tcp:HOST:PORT";
        match text.split_once(':') {
            Some(("serial", rest)) => {
                let (path, baud) = match rest.rsplit_once(':') {
                    Some((path, baud)) => {
                        let baud = baud
                            .parse::<u32>()
                            .ok()
                            .filter(|&b| b > 0)
                            .ok_or_else(|| format!("`{baud}` is not a baud rate; {usage}"))?;
                        (path, Some(baud))
                    }
                    None => (rest, None),
                };
                if !path.starts_with('/') {
                    return Err(format!("the device must be an absolute path; {usage}"));
                }
                Ok(Self::Serial {
                    path: PathBuf::from(path),
                    baud,
                })
            }
            Some(("tcp", rest)) => {
                let (host, port) = rest
                    .rsplit_once(':')
                    .ok_or_else(|| format!("no port; {usage}"))?;
                let port = port
                    .parse::<u16>()
                    .ok()
                    .filter(|&p| p > 0)
                    .ok_or_else(|| format!("`{port}` is not a port number; {usage}"))?;
                if host.is_empty() {
                    return Err(format!("the host is empty; {usage}"));
                }
                Ok(Self::Tcp {
                    host: host.to_string(),
                    port,
                })
            }
            _ => Err(usage.to_string()),
        }
    }
}

impl fmt::Display for SensorConnection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Serial { path, baud: None } => write!(f, "serial:{}", path.display()),
            Self::Serial {
                path,
                baud: Some(baud),
            } => write!(f, "serial:{}:{baud}", path.display()),
            Self::Tcp { host, port } => write!(f, "tcp:{host}:{port}"),
        }
    }
}

/// Which SCIP streaming command: distances only, or distances with intensities.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ScanStream {
    Md,
    Me,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScannerConfig {
    /// Also the recording topic `/<name>/rx`: letters, digits, `-` and `_`.
    pub name: String,
    pub connection: String,
    /// Mount `[roll, pitch, yaw]` in degrees (docs/design.md, "Frames"); with
    /// `translation_m`, left out only to take the mount from a ROS recording's `/tf_static`.
    #[serde(default)]
    pub rpy_deg: Option<[f64; 3]>,
    #[serde(default)]
    pub translation_m: Option<[f64; 3]>,
    /// Ranging noise, one sigma, metres.
    pub range_sigma_m: f64,
    #[serde(default = "ScannerConfig::default_stream")]
    pub stream: ScanStream,
    /// Defaults to the device's AMIN / AMAX.
    #[serde(default)]
    pub first_step: Option<u32>,
    #[serde(default)]
    pub last_step: Option<u32>,
    #[serde(default = "ScannerConfig::default_cluster")]
    pub cluster: u32,
    /// The ROS topic of its scans, when replaying ROS data (docs/ros-data.md).
    #[serde(default)]
    pub topic: Option<String>,
}

impl ScannerConfig {
    fn default_stream() -> ScanStream {
        ScanStream::Md
    }

    fn default_cluster() -> u32 {
        1
    }

    /// Valid after [`Config::parse`] and, for a mount left to `/tf_static`, after the replay
    /// has set it ([`Config::missing_mounts`] lists those).
    pub(crate) fn mount(&self) -> Mount {
        Mount::from_rpy_deg(
            self.rpy_deg.unwrap_or_default(),
            self.translation_m.unwrap_or_default(),
        )
    }

    /// Valid after [`Config::parse`].
    pub fn connection(&self) -> SensorConnection {
        self.connection
            .parse()
            .expect("validated when the configuration was loaded")
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ImuOutput {
    /// Acceleration and rate of turn.
    Rate,
    /// DeltaQ and DeltaV (strapdown-integrated on the device; no coning or sculling loss).
    Delta,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum ImuSeries {
    #[serde(rename = "auto")]
    Auto,
    #[serde(rename = "100")]
    Mti100,
    #[serde(rename = "600")]
    Mti600,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuConfig {
    #[serde(default = "ImuConfig::default_name")]
    pub name: String,
    pub connection: String,
    /// Identity when left out, unless `[ros] body_frame` takes it from `/tf_static`.
    #[serde(default)]
    pub rpy_deg: Option<[f64; 3]>,
    /// Neglected by the filter (docs/design.md, "Frames"), so never taken from `/tf_static`.
    #[serde(default)]
    pub translation_m: [f64; 3],
    #[serde(default = "ImuConfig::default_output")]
    pub output: ImuOutput,
    #[serde(default = "ImuConfig::default_rate_hz")]
    pub rate_hz: u32,
    #[serde(default = "ImuConfig::default_series")]
    pub series: ImuSeries,
    /// The ROS topic of its samples, when replaying ROS data (docs/ros-data.md).
    #[serde(default)]
    pub topic: Option<String>,
}

impl ImuConfig {
    fn default_name() -> String {
        "imu".into()
    }
    fn default_output() -> ImuOutput {
        ImuOutput::Rate
    }
    fn default_rate_hz() -> u32 {
        100
    }
    fn default_series() -> ImuSeries {
        ImuSeries::Auto
    }

    /// Valid after [`Config::parse`].
    pub fn connection(&self) -> SensorConnection {
        self.connection
            .parse()
            .expect("validated when the configuration was loaded")
    }
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MavlinkConfig {
    pub profile: Profile,
    /// `serial:/dev/ttyAMA0:921600`, `udpout:HOST:PORT`, `udpin:ADDR:PORT`, `tcpout:...`,
    /// `tcpin:...`.
    pub connection: String,
    #[serde(default = "MavlinkConfig::default_system_id")]
    pub system_id: u8,
    #[serde(default = "MavlinkConfig::default_component_id")]
    pub component_id: u8,
    /// Defaults to the profile's rate.
    #[serde(default)]
    pub rate_hz: Option<f64>,
    #[serde(default)]
    pub signing: Option<SigningConfigSection>,
}

impl MavlinkConfig {
    fn default_system_id() -> u8 {
        1
    }
    fn default_component_id() -> u8 {
        DEFAULT_COMPONENT_ID
    }

    pub(crate) fn identity(&self) -> Identity {
        Identity {
            system_id: self.system_id,
            component_id: self.component_id,
        }
    }

    pub(crate) fn rate_hz(&self) -> f64 {
        self.rate_hz.unwrap_or(self.profile.default_rate_hz())
    }

    /// Valid after [`Config::parse`].
    pub(crate) fn address(&self) -> LinkAddress {
        self.connection
            .parse()
            .expect("validated when the configuration was loaded")
    }

    /// Reads the key (again, from the file if it is one): valid after [`Config::parse`] unless
    /// the key file changed since.
    pub(crate) fn signing(&self) -> Result<Option<Signing>, String> {
        self.signing
            .as_ref()
            .map(SigningConfigSection::resolve)
            .transpose()
    }
}

/// `[mavlink.signing]`: exactly one of `key` (64 hex digits) and `key_file`.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SigningConfigSection {
    #[serde(default)]
    pub key: Option<String>,
    #[serde(default)]
    pub key_file: Option<PathBuf>,
    #[serde(default)]
    pub link_id: u8,
    #[serde(default)]
    pub allow_unsigned: bool,
}

impl SigningConfigSection {
    fn resolve(&self) -> Result<Signing, String> {
        let key = match (&self.key, &self.key_file) {
            (Some(hex), None) => parse_key_hex(hex),
            (None, Some(path)) => read_key_file(path),
            _ => return Err("give exactly one of `key` and `key_file`".into()),
        }
        .map_err(|e| e.to_string())?;
        Ok(Signing {
            key,
            link_id: self.link_id,
            allow_unsigned: self.allow_unsigned,
        })
    }
}

/// `[recording] path = "/var/lib/ladar-odometer"` (a directory: one MCAP file per run) or
/// `path = "off"`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingConfig {
    #[serde(default = "RecordingConfig::default_path")]
    pub path: String,
    /// Seconds between flushes: the most a crash or power cut can lose.
    #[serde(default = "RecordingConfig::default_flush_interval_s")]
    pub flush_interval_s: f64,
}

impl RecordingConfig {
    fn default_path() -> String {
        "off".into()
    }
    fn default_flush_interval_s() -> f64 {
        1.0
    }

    /// The directory to record into, or `None` when recording is off.
    pub(crate) fn directory(&self) -> Option<PathBuf> {
        (self.path != "off").then(|| PathBuf::from(&self.path))
    }
}

impl Default for RecordingConfig {
    fn default() -> Self {
        Self {
            path: Self::default_path(),
            flush_interval_s: Self::default_flush_interval_s(),
        }
    }
}

/// `[output] dir = "..."`: where `trajectory.tum`, `epochs.jsonl` and `mavlink.tlog` go
/// (`--out` overrides it); unset means no output files.
#[derive(Debug, Clone, Default, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    #[serde(default)]
    pub dir: Option<PathBuf>,
}

/// `[ros]`: how a replay of ROS data reads what the recording carries (docs/ros-data.md).
#[derive(Debug, Clone, Default, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RosConfig {
    /// The ROS frame of this project's body (`base_link`): a sensor whose table leaves its
    /// mount out takes it from `/tf_static`, as the chain from this frame to the sensor's.
    #[serde(default)]
    pub body_frame: Option<String>,
}

/// A sensor whose mount the configuration leaves to `/tf_static`; displays as its table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MountOf {
    Scanner(usize),
    Imu,
}

impl fmt::Display for MountOf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Scanner(i) => write!(f, "[[scanner]] {i}"),
            Self::Imu => f.write_str("[imu]"),
        }
    }
}

/// The tables of the file, in the order `Config` reads them.
const TABLES: &str = "[[scanner]], [imu], [mavlink], [ros], [recording], [output], [fusion], \
                      [odometry], [integrity], [filter]";

/// Keys that are not keys of their table because the file sets the same thing elsewhere, with
/// where: one place per setting, so the two cannot disagree.
const SET_ELSEWHERE: [(&str, &str); 1] = [(
    "filter.imu_mount_rpy_deg",
    "the IMU mount is set in [imu] rpy_deg: remove this key and set it there",
)];

impl Config {
    pub fn load(path: &Path) -> Result<Self, ConfigErrors> {
        Self::load_with_text(path).map(|(config, _)| config)
    }

    /// The configuration and the file's text, which the recording keeps as metadata.
    pub fn load_with_text(path: &Path) -> Result<(Self, String), ConfigErrors> {
        let text = std::fs::read_to_string(path).map_err(|source| {
            let mut errors = ConfigErrors::in_file(path);
            errors.push(ConfigError::new(
                "",
                format!(
                    "cannot read it: {source} (pass --config FILE; examples in config/examples/)"
                ),
            ));
            errors
        })?;
        Self::parse(&text, path).map(|config| (config, text))
    }

    /// Every problem of every table, one line each; `path` names the file in them. Each table
    /// is read on its own, so that a mistake in one hides nothing of the others.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigErrors> {
        let mut errors = ConfigErrors::in_file(path);
        let tables = match DeTable::parse(text) {
            Ok(tables) => tables.into_inner(),
            Err(error) => {
                errors.push(shape_error(text, "", None, &error));
                return Err(errors);
            }
        };
        let mut file = Tables {
            text,
            tables,
            errors: &mut errors,
        };
        let scanners = file.scanners();
        let imu = file.imu();
        let mavlink = file.table("mavlink", |mavlink: &Option<MavlinkConfig>, errors| {
            if let Some(mavlink) = mavlink {
                check_mavlink(mavlink, errors);
            }
        });
        let ros = file.table("ros", check_ros);
        let recording = file.table("recording", check_recording);
        let output = file.table("output", |_: &OutputConfig, _| {});
        let fusion = file.table("fusion", crate::fusion::FusionConfig::check);
        let odometry = file.table("odometry", crate::odometry::OdometryConfig::check);
        let integrity = file.table("integrity", crate::integrity::IntegrityConfig::check);
        let filter = file.table("filter", crate::filter::FilterConfig::check);
        file.refuse_the_rest();
        let (
            Some(scanners),
            Some(imu),
            Some(mavlink),
            Some(ros),
            Some(recording),
            Some(output),
            Some(fusion),
            Some(odometry),
            Some(integrity),
            Some(filter),
        ) = (
            scanners, imu, mavlink, ros, recording, output, fusion, odometry, integrity, filter,
        )
        else {
            return Err(errors);
        };
        let config = Self {
            scanners,
            imu,
            mavlink,
            ros,
            recording,
            output,
            fusion,
            odometry,
            integrity,
            filter,
        };
        config.check_across(&mut errors);
        errors.into_result().map(|()| config)
    }

    /// The checks that need more than one table.
    fn check_across(&self, errors: &mut ConfigErrors) {
        errors.table("imu").check(
            !self.scanners.iter().any(|s| s.name == self.imu.name),
            "name",
            &self.imu.name,
            "a scanner has the same name",
        );
        if let Some(topic) = &self.imu.topic {
            errors.table("imu").check(
                !self
                    .scanners
                    .iter()
                    .any(|s| s.topic.as_ref() == Some(topic)),
                "topic",
                topic,
                "a scanner reads the same topic: each sensor has its own",
            );
        }
        self.fusion_settings().check_history(errors);
        // A mount left out is one the replay of a ROS recording takes from `/tf_static`: only
        // with a body frame to chain from and a topic whose frame to chain to.
        for (i, scanner) in self.scanners.iter().enumerate() {
            let key = match (scanner.rpy_deg, scanner.translation_m) {
                (Some(_), Some(_)) => continue,
                (None, Some(_)) => "rpy_deg",
                (Some(_), None) => "translation_m",
                (None, None) if self.ros.body_frame.is_some() && scanner.topic.is_some() => {
                    continue
                }
                (None, None) => "rpy_deg",
            };
            errors.push(ConfigError::new(
                format!("scanner[{i}].{key}"),
                "missing: set rpy_deg and translation_m, or leave both out and set `topic` and [ros] body_frame to take the mount from a ROS recording's /tf_static",
            ));
        }
        if self.imu.rpy_deg.is_none() && self.ros.body_frame.is_some() && self.imu.topic.is_none() {
            errors.push(ConfigError::new(
                "imu.rpy_deg",
                "missing with [ros] body_frame set: set rpy_deg, or `topic` to take the mount from /tf_static",
            ));
        }
    }

    /// The sensors whose mount a replay takes from `/tf_static`, with their topics.
    pub(crate) fn missing_mounts(&self) -> Vec<(MountOf, String)> {
        if self.ros.body_frame.is_none() {
            return Vec::new();
        }
        let scanners = self.scanners.iter().enumerate().filter_map(|(i, s)| {
            let topic = s.topic.clone().filter(|_| s.rpy_deg.is_none())?;
            Some((MountOf::Scanner(i), topic))
        });
        let imu = self
            .imu
            .topic
            .clone()
            .filter(|_| self.imu.rpy_deg.is_none());
        scanners
            .chain(imu.map(|topic| (MountOf::Imu, topic)))
            .collect()
    }

    /// Whether the scan planes are far enough apart, once every mount is known.
    pub(crate) fn check_scan_planes_apart(&self) -> Result<(), ConfigErrors> {
        ConfigErrors::collect(|errors| check_scan_planes_apart(&self.scanners, errors))
    }

    /// Sets a mount [`Config::missing_mounts`] lists, in FRD as `/tf_static` gives it.
    pub(crate) fn set_mount(&mut self, of: MountOf, mount: &Mount) {
        let (roll, pitch, yaw) = mount.rotation.euler_angles();
        let rpy_deg = Some([roll, pitch, yaw].map(f64::to_degrees));
        match of {
            MountOf::Scanner(i) => {
                if let Some(scanner) = self.scanners.get_mut(i) {
                    scanner.rpy_deg = rpy_deg;
                    scanner.translation_m = Some(mount.translation.into());
                }
            }
            MountOf::Imu => self.imu.rpy_deg = rpy_deg,
        }
    }

    /// The `[fusion]`, `[odometry]`, `[integrity]` and `[filter]` tables, with the IMU mount
    /// taken from `[imu]` so that it is set in one place only.
    pub fn fusion_settings(&self) -> crate::fusion::FusionSettings {
        let mut filter = self.filter.clone();
        filter.imu_mount_rpy_deg = self.imu.rpy_deg.unwrap_or_default();
        crate::fusion::FusionSettings {
            fusion: self.fusion.clone(),
            odometry: self.odometry.clone(),
            integrity: self.integrity.clone(),
            filter,
        }
    }
}

/// The file's top-level tables, taken out one by one; what is left at the end is unknown.
struct Tables<'i, 'e> {
    text: &'i str,
    tables: DeTable<'i>,
    errors: &'e mut ConfigErrors,
}

impl<'i> Tables<'i, '_> {
    /// Table `name` (its default when the file leaves it out), checked with `check`; `None`
    /// when it does not read.
    fn table<T: DeserializeOwned + Default>(
        &mut self,
        name: &str,
        check: impl FnOnce(&T, &mut ConfigErrors),
    ) -> Option<T> {
        let table = match self.tables.remove(name) {
            Some(value) => self.read(name, &value)?,
            None => T::default(),
        };
        check(&table, self.errors);
        Some(table)
    }

    fn imu(&mut self) -> Option<ImuConfig> {
        let Some(value) = self.tables.remove("imu") else {
            self.errors.push(ConfigError::new(
                "imu",
                "missing: add an [imu] table with the MTi's connection (examples in config/examples/)",
            ));
            return None;
        };
        let imu = self.read("imu", &value)?;
        check_imu(&imu, self.errors);
        Some(imu)
    }

    /// Each `[[scanner]]` read on its own, so that every bad one is named by its index.
    fn scanners(&mut self) -> Option<Vec<ScannerConfig>> {
        let scanners = match self.tables.remove("scanner") {
            None => Vec::new(),
            Some(value) => match value.get_ref() {
                DeValue::Array(items) => {
                    let read: Vec<Option<ScannerConfig>> = items
                        .iter()
                        .enumerate()
                        .map(|(i, item)| self.read(&format!("scanner[{i}]"), item))
                        .collect();
                    read.into_iter().collect::<Option<_>>()?
                }
                _ => self.read("scanner", &value)?,
            },
        };
        check_scanners(&scanners, self.errors);
        Some(scanners)
    }

    /// `value` as a `T`, or `None` after recording why not.
    fn read<T: DeserializeOwned>(&mut self, name: &str, value: &Spanned<DeValue<'i>>) -> Option<T> {
        T::deserialize(ValueDeserializer::from(value.clone()))
            .map_err(|error| {
                self.errors
                    .push(shape_error(self.text, name, Some(value), &error));
            })
            .ok()
    }

    fn refuse_the_rest(self) {
        for (name, value) in self.tables.iter() {
            self.errors.push(ConfigError {
                key: name.get_ref().to_string(),
                value: shown_value(self.text, value),
                position: Some(position(self.text, name.span().start)),
                problem: format!("unknown table; the tables are {TABLES}"),
            });
        }
    }
}

/// A table that does not read as its type: an unknown key, a missing key or a value of the
/// wrong type, named with its line.
fn shape_error(
    text: &str,
    table: &str,
    value: Option<&Spanned<DeValue<'_>>>,
    error: &toml::de::Error,
) -> ConfigError {
    let at = error.span().map(|span| span.start);
    let found = at.zip(value).and_then(|(at, value)| match value.get_ref() {
        DeValue::Table(entries) => key_at(entries, at),
        _ => None,
    });
    let (key, shown) = match found {
        Some((keys, value)) => {
            let key = format!("{table}.{}", keys.join("."));
            // A misspelt signing key would otherwise print the secret.
            let shown = (!key.starts_with("mavlink.signing"))
                .then(|| shown_value(text, value))
                .flatten();
            (key, shown)
        }
        None => (table.to_string(), None),
    };
    let message = error.message().trim().replace('\n', " ");
    let problem = match message
        .strip_prefix("unknown field `")
        .and_then(|rest| rest.split_once("`, "))
    {
        Some((_, expected)) => match SET_ELSEWHERE.iter().find(|(moved, _)| *moved == key) {
            Some((_, hint)) => format!("not a key of [{table}]: {hint}"),
            None => format!("unknown key, {expected}"),
        },
        None => message,
    };
    ConfigError {
        key,
        value: shown,
        position: at.map(|at| position(text, at)),
        problem,
    }
}

/// The keys leading to the key or value at byte `at`, and that value.
fn key_at<'a, 'i>(
    table: &'a DeTable<'i>,
    at: usize,
) -> Option<(Vec<&'a str>, &'a Spanned<DeValue<'i>>)> {
    table.iter().find_map(|(key, value)| {
        let inner = match value.get_ref() {
            DeValue::Table(entries) => key_at(entries, at),
            _ => None,
        };
        match inner {
            Some((mut keys, found)) => {
                keys.insert(0, key.get_ref());
                Some((keys, found))
            }
            None => (key.span().contains(&at) || value.span().contains(&at))
                .then(|| (vec![key.get_ref().as_ref()], value)),
        }
    })
}

/// The value as the file writes it, when it fits on the line.
fn shown_value(text: &str, value: &Spanned<DeValue<'_>>) -> Option<String> {
    let written = text.get(value.span())?.trim();
    (!matches!(value.get_ref(), DeValue::Table(_)) && !written.contains('\n'))
        .then(|| written.to_string())
}

/// Line and column, from 1, of byte `at`.
fn position(text: &str, at: usize) -> (usize, usize) {
    let before = text.get(..at).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let column = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
    (line, column)
}

fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// The parts of a mount the table gives; one left out is checked by `Config::check_across`.
fn check_mount(
    table: &mut Table<'_>,
    rpy_deg: Option<&[f64; 3]>,
    translation_m: Option<&[f64; 3]>,
) {
    if let Some(rpy_deg) = rpy_deg {
        table.check(
            rpy_deg.iter().all(|a| a.is_finite() && a.abs() <= 180.0),
            "rpy_deg",
            rpy_deg,
            "angles must be finite degrees within [-180, 180]",
        );
    }
    let Some(translation_m) = translation_m else {
        return;
    };
    table.check(
        translation_m
            .iter()
            .all(|t| t.is_finite() && t.abs() <= 10.0),
        "translation_m",
        translation_m,
        "offsets must be finite metres within 10 m of the body origin",
    );
}

fn check_scanners(scanners: &[ScannerConfig], errors: &mut ConfigErrors) {
    if scanners.len() < 2 {
        errors.push(ConfigError::new(
            "scanner",
            format!(
                "{} [[scanner]] tables: the odometer needs two (two scan planes at different pitch)",
                scanners.len()
            ),
        ));
    }
    for (i, scanner) in scanners.iter().enumerate() {
        let name = format!("scanner[{i}]");
        let mut table = errors.table(&name);
        check_scanner(&mut table, scanner);
        table.check(
            !scanners[..i].iter().any(|s| s.name == scanner.name),
            "name",
            &scanner.name,
            "another scanner has this name",
        );
        if let Some(topic) = &scanner.topic {
            table.check(
                !scanners[..i]
                    .iter()
                    .any(|s| s.topic.as_ref() == Some(topic)),
                "topic",
                topic,
                "another scanner reads this topic: each scanner has its own",
            );
        }
    }
    check_scan_planes_apart(scanners, errors);
}

/// The two scan planes must differ for lines of both to make planes. Mounts from /tf_static are
/// known only once the recording is read, so a mount left out is checked then.
fn check_scan_planes_apart(scanners: &[ScannerConfig], errors: &mut ConfigErrors) {
    if let [a @ ScannerConfig {
        rpy_deg: Some(_), ..
    }, b @ ScannerConfig {
        rpy_deg: Some(b_rpy),
        ..
    }, ..] = scanners
    {
        let normal = |s: &ScannerConfig| s.mount().rotation * nalgebra::Vector3::z();
        let angle = normal(a).angle(&normal(b)).to_degrees();
        errors.table("scanner[1]").check(
            !angle.is_finite() || (5.0..=175.0).contains(&angle),
            "rpy_deg",
            b_rpy,
            format!("the two scan planes are {angle:.1} deg apart: tilt one by 5 deg or more so that planes can be found"),
        );
    }
}

fn check_scanner(table: &mut Table<'_>, s: &ScannerConfig) {
    table.check(
        valid_name(&s.name),
        "name",
        &s.name,
        "use letters, digits, `-` and `_` (it names the recording topics)",
    );
    if let Err(problem) = s.connection.parse::<SensorConnection>() {
        table.refuse("connection", &s.connection, problem);
    }
    check_mount(table, s.rpy_deg.as_ref(), s.translation_m.as_ref());
    table.check(
        s.range_sigma_m > 0.0 && s.range_sigma_m <= 0.5,
        "range_sigma_m",
        s.range_sigma_m,
        "must be in (0, 0.5] metres (Hokuyo datasheets give 0.01 to 0.03)",
    );
    table.check(
        (1..=99).contains(&s.cluster),
        "cluster",
        s.cluster,
        "SCIP cluster counts are 1 to 99",
    );
    check_topic(table, s.topic.as_deref());
    if let (Some(first), Some(last)) = (s.first_step, s.last_step) {
        table.check(
            first < last,
            "first_step",
            first,
            format!("must be smaller than last_step = {last}"),
        );
    }
}

fn check_imu(imu: &ImuConfig, errors: &mut ConfigErrors) {
    let mut table = errors.table("imu");
    table.check(
        valid_name(&imu.name),
        "name",
        &imu.name,
        "use letters, digits, `-` and `_` (it names the recording topics)",
    );
    match imu.connection.parse::<SensorConnection>() {
        Err(problem) => table.refuse("connection", &imu.connection, problem),
        Ok(SensorConnection::Tcp { .. }) => table.refuse(
            "connection",
            &imu.connection,
            "the MTi is a serial device: use serial:/dev/NAME:BAUD",
        ),
        Ok(_) => {}
    }
    check_mount(&mut table, imu.rpy_deg.as_ref(), Some(&imu.translation_m));
    check_topic(&mut table, imu.topic.as_deref());
    table.check(
        (1..=2000).contains(&imu.rate_hz),
        "rate_hz",
        imu.rate_hz,
        "must be 1 to 2000 Hz (the MTi outputs at divisors of 400, 1000 or 2000 Hz)",
    );
}

fn check_topic(table: &mut Table<'_>, topic: Option<&str>) {
    let Some(topic) = topic else {
        return;
    };
    table.check(
        topic.len() > 1 && topic.starts_with('/') && !topic.contains(char::is_whitespace),
        "topic",
        topic,
        "a ROS topic as the recording names it, from the root: \"/horizontal_laser_2d\"",
    );
}

fn check_mavlink(m: &MavlinkConfig, errors: &mut ConfigErrors) {
    let mut table = errors.table("mavlink");
    if let Err(e) = m.connection.parse::<LinkAddress>() {
        table.refuse("connection", &m.connection, e.to_string());
    }
    table.check(
        m.system_id > 0,
        "system_id",
        m.system_id,
        "must be 1 to 255 (use the autopilot's)",
    );
    table.check(
        m.component_id > 0,
        "component_id",
        m.component_id,
        "must be 1 to 255 (197 is the odometry component)",
    );
    let (low, high) = m.profile.rate_range_hz();
    if let Some(rate) = m.rate_hz {
        table.check(
            rate >= low && rate <= high,
            "rate_hz",
            rate,
            format!("profile {} needs {low} to {high} Hz", m.profile),
        );
    }
    if let Err(problem) = m.signing() {
        // No value: it would be the key.
        errors.push(ConfigError::new("mavlink.signing", problem));
    }
}

fn check_ros(ros: &RosConfig, errors: &mut ConfigErrors) {
    if let Some(frame) = &ros.body_frame {
        errors.table("ros").check(
            !frame.trim_start_matches('/').is_empty() && !frame.contains(char::is_whitespace),
            "body_frame",
            frame,
            "a ROS frame as /tf_static names it: \"base_link\"",
        );
    }
}

fn check_recording(recording: &RecordingConfig, errors: &mut ConfigErrors) {
    let mut table = errors.table("recording");
    let flush = recording.flush_interval_s;
    table.check(
        flush > 0.0 && flush <= 60.0,
        "flush_interval_s",
        flush,
        "must be in (0, 60] seconds",
    );
    table.check(
        !recording.path.is_empty(),
        "path",
        &recording.path,
        "empty: give a directory or \"off\"",
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    const VALID: &str = r#"
[[scanner]]
name = "front"
connection = "serial:/dev/hokuyo_front"
rpy_deg = [0.0, 0.0, 0.0]
translation_m = [0.10, 0.0, 0.0]
range_sigma_m = 0.01

[[scanner]]
name = "tilted"
connection = "tcp:192.168.0.10:10940"
rpy_deg = [0.0, 20.0, 0.0]
translation_m = [0.10, 0.0, -0.05]
range_sigma_m = 0.02
stream = "me"
first_step = 100
last_step = 980
cluster = 2

[imu]
connection = "serial:/dev/xsens:115200"
output = "delta"
rate_hz = 200
series = "600"

[mavlink]
profile = "px4"
connection = "serial:/dev/ttyAMA0:921600"

[mavlink.signing]
key = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff"
link_id = 1

[recording]
path = "/var/lib/ladar-odometer"
"#;

    fn path() -> &'static Path {
        Path::new("/etc/ladar-odometer/config.toml")
    }

    fn problems(text: &str) -> Vec<String> {
        Config::parse(text, path())
            .unwrap_err()
            .to_string()
            .lines()
            .map(String::from)
            .collect()
    }

    /// Whether a line is about `key`: the file, then the key.
    fn names(line: &str, key: &str) -> bool {
        line.strip_prefix("config /etc/ladar-odometer/config.toml: ")
            .is_some_and(|rest| rest.starts_with(key))
    }

    #[test]
    fn a_valid_file_loads_with_defaults_filled_in() {
        let config = Config::parse(VALID, path()).unwrap();
        assert_eq!(config.scanners.len(), 2);
        assert_eq!(config.scanners[0].stream, ScanStream::Md);
        assert_eq!(config.scanners[1].cluster, 2);
        assert_eq!(
            config.scanners[1].connection(),
            SensorConnection::Tcp {
                host: "192.168.0.10".into(),
                port: 10940
            }
        );
        assert_eq!(
            config.imu.connection(),
            SensorConnection::Serial {
                path: "/dev/xsens".into(),
                baud: Some(115_200)
            }
        );
        assert_eq!(config.imu.name, "imu");
        assert_eq!(config.imu.series, ImuSeries::Mti600);
        let mavlink = config.mavlink.unwrap();
        assert_eq!(mavlink.identity().component_id, DEFAULT_COMPONENT_ID);
        assert_eq!(mavlink.rate_hz(), 30.0);
        let signing = mavlink.signing().unwrap().unwrap();
        assert_eq!((signing.key[1], signing.link_id), (0x11, 1));
        assert_eq!(
            config.recording.directory(),
            Some(PathBuf::from("/var/lib/ladar-odometer"))
        );
        assert_eq!(config.output.dir, None);
        let pitch = config.scanners[1].mount().rotation.euler_angles().1;
        assert!((pitch - 20f64.to_radians()).abs() < 1e-12);
    }

    #[test]
    fn a_mount_is_both_keys_or_neither_and_neither_only_for_a_ros_topic() {
        let half = VALID.replace("translation_m = [0.10, 0.0, 0.0]\n", "");
        let errors = problems(&half);
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(
            names(&errors[0], "scanner[0].translation_m: missing"),
            "{errors:?}"
        );

        let neither = half.replace("rpy_deg = [0.0, 0.0, 0.0]\n", "");
        let errors = problems(&neither);
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(
            names(&errors[0], "scanner[0].rpy_deg: missing"),
            "{errors:?}"
        );
        assert!(errors[0].contains("[ros] body_frame"), "{errors:?}");

        let from_tf = neither.replace(
            "range_sigma_m = 0.01\n",
            "range_sigma_m = 0.01\ntopic = \"/scan\"\n",
        ) + "\n[ros]\nbody_frame = \"base_link\"\n";
        // The IMU then needs its own mount or a topic too.
        let errors = problems(&from_tf);
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(names(&errors[0], "imu.rpy_deg: missing"), "{errors:?}");
        let from_tf = from_tf.replace("[imu]\n", "[imu]\nrpy_deg = [0.0, 0.0, 0.0]\n");
        let mut config = Config::parse(&from_tf, path()).unwrap();
        assert_eq!(config.missing_mounts().len(), 1);

        // The mount /tf_static gives is held to the same separation of the scan planes.
        let tilted = config.scanners[1].mount();
        config.set_mount(MountOf::Scanner(0), &tilted);
        let error = config.check_scan_planes_apart().unwrap_err().to_string();
        assert!(
            error.contains("scanner[1].rpy_deg") && error.contains("0.0 deg apart"),
            "{error}"
        );
    }

    #[test]
    fn a_body_frame_is_a_frame_name() {
        for frame in ["", "/", "base link"] {
            let text = format!("{VALID}\n[ros]\nbody_frame = \"{frame}\"\n")
                .replace("[imu]\n", "[imu]\nrpy_deg = [0.0, 0.0, 0.0]\n");
            let errors = problems(&text);
            assert_eq!(errors.len(), 1, "{frame:?}: {errors:?}");
            assert!(names(&errors[0], "ros.body_frame"), "{errors:?}");
        }
    }

    #[test]
    fn an_unknown_key_names_it_with_its_line() {
        let text = VALID.replace("range_sigma_m = 0.02", "range_sigma = 0.02");
        let errors = problems(&text);
        assert_eq!(errors.len(), 1);
        let line = text
            .lines()
            .position(|l| l.starts_with("range_sigma ="))
            .unwrap()
            + 1;
        assert!(
            errors[0].contains("/etc/ladar-odometer/config.toml"),
            "{}",
            errors[0]
        );
        assert!(
            names(&errors[0], "scanner[1].range_sigma = 0.02 "),
            "{}",
            errors[0]
        );
        assert!(errors[0].contains(&format!("line {line}")), "{}", errors[0]);
        assert!(errors[0].contains("unknown key"), "{}", errors[0]);

        let text = format!("{VALID}\n[odometry]\nrotation_tolerance = 1e-9\n");
        let errors = problems(&text);
        assert_eq!(errors.len(), 1, "{errors:#?}");
        assert!(
            names(&errors[0], "odometry.rotation_tolerance"),
            "{}",
            errors[0]
        );
    }

    #[test]
    fn mistakes_in_several_tables_are_all_reported_each_on_its_own_line() {
        let text = format!(
            "{}\n[odometry]\nmin_line_points = 2\n[filter]\nmax_imu_gap_s = -1.0\n",
            VALID.replace("cluster = 2", "cluster = 0")
        );
        let errors = problems(&text);
        assert_eq!(errors.len(), 3, "{errors:#?}");
        assert!(names(&errors[0], "scanner[1].cluster = 0: "), "{errors:#?}");
        assert!(
            names(&errors[1], "odometry.min_line_points = 2: "),
            "{errors:#?}"
        );
        assert!(
            names(&errors[2], "filter.max_imu_gap_s = -1.0: "),
            "{errors:#?}"
        );

        // A table that does not read hides nothing of the others.
        let text = format!(
            "{VALID}\n[integrity]\nfalse_alarm_probabilty = 0.01\n[filter]\nmax_imu_gap_s = -1.0\n"
        );
        let errors = problems(&text);
        assert_eq!(errors.len(), 2, "{errors:#?}");
        assert!(
            names(&errors[0], "integrity.false_alarm_probabilty"),
            "{errors:#?}"
        );
        assert!(names(&errors[1], "filter.max_imu_gap_s"), "{errors:#?}");
    }

    #[test]
    fn the_imu_mount_in_the_filter_table_points_to_the_imu_table() {
        for mount in ["[0.0, 0.0, 0.0]", "[0.0, 0.0, 90.0]"] {
            let text = format!("{VALID}\n[filter]\nimu_mount_rpy_deg = {mount}\n");
            let errors = problems(&text);
            assert_eq!(errors.len(), 1, "{errors:#?}");
            assert!(
                names(
                    &errors[0],
                    &format!("filter.imu_mount_rpy_deg = {mount} at line")
                ),
                "{}",
                errors[0]
            );
            assert!(errors[0].contains("[imu] rpy_deg"), "{}", errors[0]);
        }
    }

    #[test]
    fn an_unknown_table_is_named_with_the_known_ones() {
        let errors = problems(&format!("{VALID}\n[filtre]\ngate_probability = 0.99\n"));
        assert_eq!(errors.len(), 1, "{errors:#?}");
        assert!(names(&errors[0], "filtre at line"), "{}", errors[0]);
        assert!(errors[0].contains("[filter]"), "{}", errors[0]);
    }

    #[test]
    fn every_bad_value_is_its_own_line_naming_the_key() {
        let text = VALID
            .replace("serial:/dev/hokuyo_front", "/dev/hokuyo_front")
            .replace("range_sigma_m = 0.01", "range_sigma_m = -1.0")
            .replace("cluster = 2", "cluster = 0")
            .replace("rate_hz = 200", "rate_hz = 0")
            .replace("serial:/dev/ttyAMA0:921600", "udp:1.2.3.4:14550")
            .replace("link_id = 1", "link_id = 1\nkey_file = \"/k\"")
            .replace("name = \"tilted\"", "name = \"front\"");
        let errors = problems(&text);
        for key in [
            "scanner[0].connection",
            "scanner[0].range_sigma_m",
            "scanner[1].cluster",
            "scanner[1].name",
            "imu.rate_hz",
            "mavlink.connection",
            "mavlink.signing",
        ] {
            assert!(
                errors.iter().any(|e| names(e, key)),
                "{key} missing from {errors:#?}"
            );
        }
        assert_eq!(errors.len(), 7, "{errors:#?}");
        assert!(errors
            .iter()
            .all(|e| !e.contains('\n') && e.contains("config.toml")));
    }

    fn with_topics(front: &str, tilted: &str, imu: &str) -> String {
        VALID
            .replace(
                "name = \"front\"",
                &format!("name = \"front\"\ntopic = \"{front}\""),
            )
            .replace(
                "name = \"tilted\"",
                &format!("name = \"tilted\"\ntopic = \"{tilted}\""),
            )
            .replace(
                "output = \"delta\"",
                &format!("output = \"delta\"\ntopic = \"{imu}\""),
            )
    }

    #[test]
    fn ros_topics_are_read_and_a_bad_or_shared_one_is_named() {
        let config =
            Config::parse(&with_topics("/horizontal_laser_2d", "/v", "/imu"), path()).unwrap();
        assert_eq!(
            config.scanners[0].topic.as_deref(),
            Some("/horizontal_laser_2d")
        );
        assert_eq!(config.imu.topic.as_deref(), Some("/imu"));
        assert_eq!(Config::parse(VALID, path()).unwrap().imu.topic, None);

        let errors = problems(&with_topics("/h", "/imu", "/imu"));
        assert_eq!(errors.len(), 1, "{errors:#?}");
        assert!(names(&errors[0], "imu.topic = \"/imu\": "), "{errors:#?}");
        assert!(errors[0].contains("a scanner reads the same topic"));

        let errors = problems(&with_topics("/h", "/h", "/imu"));
        assert!(
            names(&errors[0], "scanner[1].topic = \"/h\": "),
            "{errors:#?}"
        );

        let errors = problems(&with_topics("scan", "/v", "/imu"));
        assert_eq!(errors.len(), 1, "{errors:#?}");
        assert!(
            names(&errors[0], "scanner[0].topic = \"scan\": ")
                && errors[0].contains("from the root"),
            "{errors:#?}"
        );
    }

    #[test]
    fn parallel_scan_planes_are_refused() {
        let text = VALID.replace("rpy_deg = [0.0, 20.0, 0.0]", "rpy_deg = [0.0, 2.0, 90.0]");
        let errors = problems(&text);
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(errors[0].contains("scanner[1].rpy_deg") && errors[0].contains("apart"));
    }

    #[test]
    fn rate_outside_the_profile_range_is_refused() {
        let text = VALID.replace(
            "profile = \"px4\"",
            "profile = \"ardupilot\"\nrate_hz = 30.0",
        );
        let errors = problems(&text);
        assert!(
            errors[0].contains("mavlink.rate_hz") && errors[0].contains("10 to 20"),
            "{errors:?}"
        );
    }

    #[test]
    fn a_bad_enum_value_and_a_missing_section_are_clear() {
        let bad_enum = problems(&VALID.replace("\"px4\"", "\"apm\""));
        assert!(
            bad_enum[0].contains("apm") && bad_enum[0].contains("line"),
            "{bad_enum:?}"
        );
        let start = VALID.find("[imu]").unwrap();
        let end = VALID.find("[mavlink]").unwrap();
        let without_imu = format!("{}{}", &VALID[..start], &VALID[end..]);
        let errors = problems(&without_imu);
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(names(&errors[0], "imu: missing"), "{errors:?}");
    }

    #[test]
    fn loading_from_a_file_keeps_its_text_for_the_recording() {
        let file = std::env::temp_dir().join(format!("ladar-config-{}.toml", std::process::id()));
        let text = VALID.replace("[mavlink.signing]", "[mavlink.signing]\n# comment kept");
        std::fs::write(&file, &text).unwrap();
        let (config, kept) = Config::load_with_text(&file).unwrap();
        std::fs::remove_file(&file).unwrap();
        assert_eq!(kept, text);
        assert_eq!(config.scanners[0].name, "front");
    }

    #[test]
    fn a_missing_file_names_the_file_and_the_flag() {
        let err = Config::load(Path::new("/nonexistent/ladar.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("/nonexistent/ladar.toml") && err.contains("--config"),
            "{err}"
        );
    }

    proptest::proptest! {
        #[test]
        fn any_text_gives_a_config_or_lines_naming_the_file(text in "\\PC{0,200}") {
            if let Err(errors) = Config::parse(&text, path()) {
                for line in errors.to_string().lines() {
                    proptest::prop_assert!(line.starts_with("config /etc/ladar-odometer/config.toml: "), "{}", line);
                }
            }
        }

        #[test]
        fn a_damaged_valid_file_never_panics(cut in 0..VALID.len(), insert in "\\PC{0,8}") {
            let mut text = VALID.to_string();
            let at = (0..=cut).rev().find(|&i| text.is_char_boundary(i)).unwrap_or(0);
            text.insert_str(at, &insert);
            let _ = Config::parse(&text, path());
        }

        #[test]
        fn sensor_connections_print_back(
            device in "/dev/[a-z_]{1,12}",
            baud in proptest::option::of(1u32..4_000_000),
            host in "[a-z0-9.]{1,15}",
            port in 1u16..,
        ) {
            let serial = SensorConnection::Serial { path: device.into(), baud };
            proptest::prop_assert_eq!(serial.to_string().parse::<SensorConnection>(), Ok(serial));
            let tcp = SensorConnection::Tcp { host, port };
            proptest::prop_assert_eq!(tcp.to_string().parse::<SensorConnection>(), Ok(tcp));
        }
    }

    #[test]
    fn example_configs_are_valid() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/examples");
        let key_file =
            std::env::temp_dir().join(format!("ladar-example-key-{}", std::process::id()));
        std::fs::write(&key_file, "ab".repeat(32)).unwrap();
        let mut count = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                // Key files live on the target; stand one in for the test.
                let text = std::fs::read_to_string(&path).unwrap().replace(
                    "/etc/ladar-odometer/mavlink.key",
                    &key_file.to_string_lossy(),
                );
                if let Err(e) = Config::parse(&text, &path) {
                    panic!("{e}");
                }
                count += 1;
            }
        }
        std::fs::remove_file(&key_file).unwrap();
        assert!(
            count >= 3,
            "expected the px4, ardupilot and ethernet examples"
        );
    }
}
