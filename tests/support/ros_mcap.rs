//! ROS recordings of what a raw-byte replay fed the fusion: each scan a `LaserScan` (or a
//! `MultiEchoLaserScan` with one echo per beam), each IMU sample an `Imu`, in the order the
//! fusion took them, so that replaying the ROS file feeds the fusion the same measurements
//! rounded to what ROS messages carry (float32 ranges and rates, nanosecond stamps). Shared by
//! tests/ros_replay.rs and benches/ros_replay.rs.

use ladar_odometer::daemon::pipeline::{EventTrace, Traced};
use ladar_odometer::daemon::recording::{ReadMode, Recording};
use ladar_odometer::daemon::replay::{self, ReplayOptions};
use ladar_odometer::daemon::simulate;
use ladar_odometer::sensors::{ImuSample, Mount, Scan, ScannerGeometry};
use ladar_sim::{ImuOutput, Scenario};
use rosmsg::encode::encode;
use rosmsg::{Echoes, Encoding, Header, Imu, Kind, LaserScan, Message, MultiEchoLaserScan};
use std::collections::BTreeMap;
use std::f64::consts::TAU;
use std::path::Path;

/// Where each sensor's messages go: `topics[n]` for sensor number `n` (scanners, then the IMU),
/// which scanners write `MultiEchoLaserScan`, and the mounts (FRD, as the configuration gives
/// them) that `/tf_static` carries, none when empty.
pub struct RosRig<'a> {
    pub topics: &'a [&'a str],
    pub multi_echo: &'a [usize],
    pub mounts: &'a [Mount],
}

/// The topics of the two scanners and the IMU, in sensor order.
pub const TOPICS: [&str; 3] = ["/horizontal_laser_2d", "/vertical_laser_2d", "/imu"];

/// What the replay of a scenario's raw-byte recording fed the fusion, and the recorded
/// configuration with each sensor's ROS topic ([`TOPICS`]) added.
pub struct Simulated {
    pub calls: Vec<Traced>,
    pub ros_config: String,
}

/// Simulates `scenario` with rate output (ROS `Imu` messages carry rates, not increments) into
/// the raw-byte recording `raw` (the scenario file beside it), and replays it once to trace
/// what the fusion took.
pub fn simulate_with_topics(mut scenario: Scenario, raw: &Path) -> Simulated {
    scenario.imu.as_mut().unwrap().output = ImuOutput::Rate;
    let scenario_path = raw.with_extension("toml");
    std::fs::write(&scenario_path, scenario.to_toml().unwrap()).unwrap();
    simulate::simulate(scenario_path.to_str().unwrap(), raw).unwrap();
    let options = ReplayOptions {
        recording: raw.to_path_buf(),
        ..ReplayOptions::default()
    };
    let (_, trace) = replay::replay(&options, |_, _| EventTrace::default()).unwrap();
    let mut ros_config = Recording::open(raw, ReadMode::Strict)
        .unwrap()
        .config_toml
        .unwrap();
    let names = scenario
        .scanners
        .iter()
        .map(|s| s.name.as_str())
        .chain(["imu"]);
    for (name, topic) in names.zip(TOPICS) {
        let line = format!("\nname = \"{name}\"\n");
        assert!(ros_config.contains(&line), "{ros_config}");
        ros_config = ros_config.replace(&line, &format!("{line}topic = \"{topic}\"\n"));
    }
    Simulated {
        calls: trace.calls,
        ros_config,
    }
}

/// The ROS frame the body is in, the parent of every mount in `/tf_static`.
pub const BODY_FRAME: &str = "base_link";

/// The frame of a sensor's messages: its topic's, `/imu` in `imu_link`.
pub fn frame(topic: &str) -> String {
    format!("{}_link", topic.trim_start_matches('/'))
}

pub fn time(t: f64) -> rosmsg::Time {
    let ns = (t * 1e9).round() as i64;
    rosmsg::Time {
        sec: ns.div_euclid(1_000_000_000),
        nanosec: ns.rem_euclid(1_000_000_000) as u32,
    }
}

fn header(t: f64, frame_id: &str) -> Header {
    Header {
        seq: 0,
        stamp: time(t),
        frame_id: frame_id.into(),
    }
}

fn scan_message(scan: &Scan, g: &ScannerGeometry, multi_echo: bool, frame_id: &str) -> Message {
    let step = TAU / f64::from(g.ares);
    let cluster = f64::from(scan.cluster.max(1));
    // ROS angles turn counter-clockwise about z up: the FRD azimuth with its sign turned.
    let angle = |index: usize| (scan.step_of(index) - f64::from(g.afrt)) * step;
    let last = scan.ranges_m.len().saturating_sub(1);
    let info = rosmsg::ScanInfo {
        angle_min: angle(0) as f32,
        angle_max: angle(last) as f32,
        angle_increment: (step * cluster) as f32,
        time_increment: (g.step_period() * cluster) as f32,
        scan_time: g.scan_period() as f32,
        range_min: g.dmin_m as f32,
        range_max: g.dmax_m as f32,
    };
    let header = header(scan.time_of(0, g), frame_id);
    let ranges: Vec<f32> = scan.ranges_m.iter().map(|&r| r as f32).collect();
    if multi_echo {
        Message::MultiEchoLaserScan(MultiEchoLaserScan {
            header,
            info,
            ranges: Echoes::from_beams(ranges.chunks(1)),
            intensities: Echoes::default(),
        })
    } else {
        Message::LaserScan(LaserScan {
            header,
            info,
            ranges,
            intensities: Vec::new(),
        })
    }
}

/// FRD to FLU, the same half turn about x as back.
fn flu(v: &nalgebra::Vector3<f64>) -> rosmsg::Vector3 {
    rosmsg::Vector3 {
        x: v.x,
        y: -v.y,
        z: -v.z,
    }
}

/// The mounts as `/tf_static` gives them: each sensor's frame in the body's, turned from FRD to
/// FLU by the half turn about x on both sides (a quaternion's vector part turns as a vector).
fn tf_static(rig: &RosRig<'_>, t: f64) -> Message {
    let transforms = rig
        .mounts
        .iter()
        .zip(rig.topics)
        .map(|(mount, topic)| {
            let q = mount.rotation.quaternion();
            let axis = flu(&q.vector().into());
            rosmsg::TransformStamped {
                header: header(t, BODY_FRAME),
                child_frame_id: frame(topic),
                translation: flu(&mount.translation),
                rotation: rosmsg::Quaternion {
                    x: axis.x,
                    y: axis.y,
                    z: axis.z,
                    w: q.w,
                },
            }
        })
        .collect();
    Message::Tf(rosmsg::TfMessage { transforms })
}

fn imu_message(sample: &ImuSample, frame_id: &str) -> Message {
    let ImuSample::Rate { t, gyro, accel } = sample else {
        panic!("ROS Imu messages carry rates: simulate the IMU with output = \"rate\"");
    };
    let mut not_given = [0.0; 9];
    not_given[0] = -1.0;
    Message::Imu(Imu {
        header: header(*t, frame_id),
        orientation_covariance: not_given,
        angular_velocity: flu(gyro),
        linear_acceleration: flu(accel),
        ..Imu::default()
    })
}

struct Channels<W: std::io::Write + std::io::Seek> {
    writer: mcap::Writer<W>,
    ids: BTreeMap<String, u16>,
    encoding: Encoding,
    sequence: u32,
}

impl<W: std::io::Write + std::io::Seek> Channels<W> {
    fn write(&mut self, topic: &str, message: &Message, log_time_s: f64) {
        let kind = match message {
            Message::LaserScan(_) => Kind::LaserScan,
            Message::MultiEchoLaserScan(_) => Kind::MultiEchoLaserScan,
            Message::Imu(_) => Kind::Imu,
            Message::Tf(_) => Kind::TfMessage,
        };
        let id = self.channel(topic, kind.schema_name());
        self.sequence += 1;
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: self.sequence,
            log_time: (log_time_s * 1e9).round() as u64,
            publish_time: (log_time_s * 1e9).round() as u64,
        };
        let bytes = encode(message, self.encoding);
        self.writer.write_to_known_channel(&header, &bytes).unwrap();
    }

    /// The channel of `topic`, declared with a schema named as the ROS version names it.
    fn channel(&mut self, topic: &str, ros2_name: &str) -> u16 {
        if let Some(&id) = self.ids.get(topic) {
            return id;
        }
        let (name, schema_encoding, message_encoding) = match self.encoding {
            Encoding::Ros1 => (ros2_name.replace("/msg/", "/"), "ros1msg", "ros1"),
            Encoding::Cdr => (ros2_name.to_string(), "ros2msg", "cdr"),
        };
        let schema = self.writer.add_schema(&name, schema_encoding, b"").unwrap();
        let id = self
            .writer
            .add_channel(schema, topic, message_encoding, &BTreeMap::new())
            .unwrap();
        self.ids.insert(topic.to_string(), id);
        id
    }
}

fn call_time(call: &Traced) -> Option<f64> {
    match call {
        Traced::Scan(scan) => Some(scan.t0),
        Traced::Imu(sample) => Some(sample.time()),
        Traced::Geometry(..) | Traced::Stale { .. } => None,
    }
}

/// Writes `calls` (what a replay with an `EventTrace` saw) as a ROS recording at `path`, with
/// a log line channel beside them that the replay must skip.
pub fn write(path: &Path, encoding: Encoding, calls: &[Traced], rig: &RosRig<'_>) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut channels = Channels {
        writer: mcap::WriteOptions::new()
            // What rosbag2 writes, and what `mcap convert` does by default for ROS 1 bags.
            .compression(Some(match encoding {
                Encoding::Ros1 => mcap::Compression::Lz4,
                Encoding::Cdr => mcap::Compression::Zstd,
            }))
            .profile(match encoding {
                Encoding::Ros1 => "ros1",
                Encoding::Cdr => "ros2",
            })
            .create(file)
            .unwrap(),
        ids: BTreeMap::new(),
        encoding,
        sequence: 0,
    };
    let imu_topic = rig.topics[rig.topics.len() - 1];
    if let (false, Some(first)) = (rig.mounts.is_empty(), calls.iter().find_map(call_time)) {
        // Latched at the start, as a recorder writes it.
        channels.write("/tf_static", &tf_static(rig, first), first);
    }
    let mut geometries = BTreeMap::new();
    for call in calls {
        match call {
            Traced::Geometry(sensor, geometry) => {
                geometries.insert(*sensor, *geometry);
            }
            Traced::Scan(scan) => {
                let geometry = &geometries[&scan.sensor];
                let multi_echo = rig.multi_echo.contains(&scan.sensor);
                let topic = rig.topics[scan.sensor];
                let message = scan_message(scan, geometry, multi_echo, &frame(topic));
                let received = scan.t0 + geometry.scan_period();
                channels.write(topic, &message, received);
            }
            Traced::Imu(sample) => {
                let message = imu_message(sample, &frame(imu_topic));
                channels.write(imu_topic, &message, sample.time());
            }
            Traced::Stale { .. } => {}
        }
    }
    let log = channels.channel("/rosout", "rcl_interfaces/msg/Log");
    let header = mcap::records::MessageHeader {
        channel_id: log,
        sequence: 0,
        log_time: 1,
        publish_time: 1,
    };
    channels
        .writer
        .write_to_known_channel(&header, b"not a message the replay reads")
        .unwrap();
    channels.writer.finish().unwrap();
}
