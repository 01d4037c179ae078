//! From what the drivers decoded to host-timed measurements, the same live and in replay.
//!
//! The drivers decode each sensor's bytes once: live, the sensor task's `Device` does it as it
//! runs the handshake; in replay, a bare `Receiver` of the same driver does it from the recorded
//! bytes. Both emit the same data events from the same bytes, so the fusion cannot tell a replay
//! from the run it recorded. What is left here is what the drivers cannot know: the scanner
//! geometry in metres, the host time of each measurement (through a `ClockEstimator` per
//! sensor), the IMU's frame conventions, and the health counts.
//!
//! A ROS recording's messages are decoded whole, one reading each, and timed by their header
//! stamps (`super::ros`).
//!
//! A raw port dump has no host times (`log_time_ns == 0` on every chunk): it is timed by the
//! sensor's own clock, unwrapped, from the first sample.

use super::pipeline::{Chunk, SensorSpec};
use super::recording::{Direction, Encoding};
use super::ros::{self, Ranges, ScanConverter};
use crate::fusion::clock::{ClockConfig, ClockEstimator};
use crate::sensors::{ImuSample, Scan, ScannerGeometry};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use std::time::Duration;
use xbus::{CoordinateSystem, DataType, OutputConfiguration};

/// A data event of a sensor's driver: what its bytes held, not how the handshake went.
// Most readings are IMU samples, the large variant: boxing it would allocate per sample.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Reading {
    Scanner(scip::Event),
    Imu(xbus::Event),
    /// One ROS message, or why its bytes are not one.
    Ros(Result<rosmsg::Message, rosmsg::DecodeError>),
}

impl Reading {
    /// The driver event as a reading, if it is a data event (the handshake's are the sensor
    /// task's business).
    pub(crate) fn from_scanner(event: scip::Event) -> Option<Self> {
        event.is_data().then_some(Self::Scanner(event))
    }

    pub(crate) fn from_imu(event: xbus::Event) -> Option<Self> {
        event.is_data().then_some(Self::Imu(event))
    }
}

/// The passive half of a sensor's driver, for replay: bytes in, readings out.
pub(crate) enum Receiver {
    Scanner(scip::Receiver),
    Imu(xbus::Receiver),
    /// Each ROS message stands alone: nothing to keep between them.
    Ros(rosmsg::Kind, rosmsg::Encoding),
}

impl Receiver {
    pub(crate) fn new(encoding: Encoding) -> Self {
        match encoding {
            Encoding::Scip2 => Self::Scanner(scip::Receiver::new()),
            // The fusion times samples by the raw SampleTimeFine (the clock estimator unwraps
            // it), so the receiver's own unwrapping needs no configured wrap.
            Encoding::Xbus => Self::Imu(xbus::Receiver::new(
                xbus::SampleTimeWrap::FromProductCode,
                xbus::DEFAULT_MAX_PAYLOAD,
            )),
            Encoding::Ros(kind, encoding) => Self::Ros(kind, encoding),
        }
    }

    /// Decodes bytes read at host time `log_time_ns`, appending the readings they completed.
    pub(crate) fn decode(&mut self, log_time_ns: u64, bytes: &[u8], out: &mut Vec<Reading>) {
        let now = Duration::from_nanos(log_time_ns);
        match self {
            Self::Scanner(receiver) => {
                receiver.handle_input(now, bytes);
                out.extend(
                    std::iter::from_fn(|| receiver.poll_event()).filter_map(Reading::from_scanner),
                );
            }
            Self::Imu(receiver) => {
                receiver.handle_input(now, bytes);
                out.extend(
                    std::iter::from_fn(|| receiver.poll_event()).filter_map(Reading::from_imu),
                );
            }
            Self::Ros(kind, encoding) => {
                out.push(Reading::Ros(rosmsg::decode(*kind, *encoding, bytes)));
            }
        }
    }
}

/// A replay's receivers, one per sensor: the only decoding a replay does, of the bytes the live
/// sensor tasks' devices decoded.
#[derive(Default)]
pub struct Receivers {
    receivers: Vec<(Encoding, Receiver)>,
}

impl Receivers {
    pub fn new(encodings: impl IntoIterator<Item = Encoding>) -> Self {
        let mut receivers = Self::default();
        for encoding in encodings {
            receivers.add(encoding);
        }
        receivers
    }

    /// The next sensor number speaks `encoding`.
    pub(crate) fn add(&mut self, encoding: Encoding) {
        self.receivers.push((encoding, Receiver::new(encoding)));
    }

    /// Sensor `sensor` speaks `encoding` from now on. A configured sensor's receiver is its
    /// device's protocol until a ROS recording says its topic carries ROS messages.
    pub(crate) fn speaks(&mut self, sensor: usize, encoding: Encoding) {
        if let Some(entry) = self.receivers.get_mut(sensor) {
            if entry.0 != encoding {
                *entry = (encoding, Receiver::new(encoding));
            }
        }
    }

    /// Fills `chunk.readings` from its received bytes, as the sensor task's device did live. A
    /// lost link (an empty rx chunk) gives the sensor a fresh receiver, as the task opens a
    /// fresh device when the link comes back.
    pub fn decode(&mut self, chunk: &mut Chunk) {
        let Some((encoding, receiver)) = self.receivers.get_mut(chunk.sensor) else {
            return;
        };
        if chunk.direction != Direction::Rx {
            return;
        }
        if chunk.data.is_empty() {
            *receiver = Receiver::new(*encoding);
            return;
        }
        receiver.decode(chunk.log_time_ns, &chunk.data, &mut chunk.readings);
    }
}

/// What the readings turned into.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum SensorEvent {
    /// A scanner reported its geometry (`PP`), before its first scan and after each reconnect.
    Geometry {
        sensor: usize,
        geometry: ScannerGeometry,
    },
    Scan(Scan),
    Imu(ImuSample),
}

/// Health counters of one sensor.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecodeCounts {
    pub chunks: u64,
    pub bytes: u64,
    /// Frames dropped as corrupt (bad sums, bad framing, undecodable payloads).
    pub decode_errors: u64,
    /// Scans or samples decoded but dropped: no geometry yet, no device time, missing fields.
    pub dropped: u64,
    /// IMU packets missing according to the packet counter.
    pub lost_packets: u64,
    /// Sensor-clock jumps that restarted the clock estimate (a sensor reset or reconnect).
    pub clock_restarts: u64,
    pub scans: u64,
    pub imu_samples: u64,
}

/// Turns one sensor's readings into host-timed measurements.
#[derive(Debug)]
pub(crate) enum SensorTiming {
    Scanner(ScannerTiming),
    Imu(ImuTiming),
}

impl SensorTiming {
    pub(crate) fn new(spec: &SensorSpec) -> Self {
        match *spec {
            SensorSpec::Scanner { index, .. } => Self::Scanner(ScannerTiming::new(index)),
            SensorSpec::Imu {
                sample_time_modulus,
                rate_hz,
                ..
            } => Self::Imu(ImuTiming::new(sample_time_modulus, rate_hz)),
        }
    }

    /// Counts one chunk of received bytes.
    pub(crate) fn received(&mut self, bytes: usize) {
        let counts = match self {
            Self::Scanner(t) => &mut t.counts,
            Self::Imu(t) => &mut t.counts,
        };
        counts.chunks += 1;
        counts.bytes += bytes as u64;
    }

    /// Times one reading read at host time `log_time_ns`, appending what it completed.
    pub(crate) fn take(
        &mut self,
        log_time_ns: u64,
        reading: &Reading,
        events: &mut Vec<SensorEvent>,
    ) {
        let received = host_seconds(log_time_ns);
        match (self, reading) {
            (Self::Scanner(t), Reading::Scanner(event)) => t.take(received, event, events),
            (Self::Imu(t), Reading::Imu(event)) => t.take(received, event, events),
            (Self::Scanner(t), Reading::Ros(Ok(message))) => t.ros(message, events),
            (Self::Imu(t), Reading::Ros(Ok(rosmsg::Message::Imu(imu)))) => {
                t.counts.imu_samples += 1;
                events.push(SensorEvent::Imu(ros::imu_sample(imu)));
            }
            // Each sensor's readings come from a decoder of its own encoding, so this arm means
            // undecodable ROS bytes, a topic of the wrong type for its sensor, or a caller that
            // crossed two sensors' chunks: counted as errors, never fused.
            (Self::Scanner(ScannerTiming { counts, .. }), _)
            | (Self::Imu(ImuTiming { counts, .. }), _) => counts.decode_errors += 1,
        }
    }

    pub(crate) fn counts(&self) -> DecodeCounts {
        match self {
            Self::Scanner(t) => DecodeCounts {
                clock_restarts: t.clock.restarts(),
                ..t.counts
            },
            Self::Imu(t) => DecodeCounts {
                clock_restarts: t.clock.restarts(),
                ..t.counts
            },
        }
    }
}

/// Maps a device counter to host seconds: through the clock estimator when chunks carry host
/// times, by unwrapping the counter alone when they do not (raw dumps).
#[derive(Debug, Clone)]
struct DeviceClock {
    estimator: ClockEstimator,
    unwrapper: wrapping_counter::Unwrapper,
    /// The first unwrapped value: a raw dump's time starts at zero.
    origin: Option<i64>,
}

impl DeviceClock {
    fn new(tick_hz: f64, modulus: u64) -> Self {
        let config = ClockConfig::with_counter(tick_hz, modulus.clamp(2, 1 << 62));
        Self {
            unwrapper: wrapping_counter::Unwrapper::new(config.modulus),
            estimator: ClockEstimator::new(config)
                .expect("the fixed tick rates and a clamped modulus always validate"),
            origin: None,
        }
    }

    /// Host time of device counter `raw`, given that the packet carrying it would have been
    /// received at `earliest_receive_s` had the link no latency.
    fn observe(&mut self, raw: u64, earliest_receive_s: Option<f64>, tick_hz: f64) -> f64 {
        let unwrapped = self.unwrapper.unwrap(raw);
        let ticks = unwrapped - *self.origin.get_or_insert(unwrapped);
        earliest_receive_s
            .and_then(|host| self.estimator.observe(raw, host))
            .unwrap_or(ticks as f64 / tick_hz)
    }

    fn restarts(&self) -> u64 {
        self.estimator.restarts()
    }
}

fn host_seconds(log_time_ns: u64) -> Option<f64> {
    (log_time_ns != 0).then_some(log_time_ns as f64 * 1e-9)
}

/// SCIP 2.0 scanner: `PP` geometry, `TM1` clock samples, scans.
#[derive(Debug)]
pub(crate) struct ScannerTiming {
    index: usize,
    geometry: Option<ScannerGeometry>,
    clock: DeviceClock,
    counts: DecodeCounts,
    ros: ScanConverter,
}

impl ScannerTiming {
    fn new(index: usize) -> Self {
        Self {
            index,
            geometry: None,
            clock: DeviceClock::new(1000.0, 1 << 24),
            counts: DecodeCounts::default(),
            ros: ScanConverter::default(),
        }
    }

    /// A ROS scan, timed by its stamp; one whose description is no planar scanner's is
    /// dropped.
    fn ros(&mut self, message: &rosmsg::Message, out: &mut Vec<SensorEvent>) {
        let (header, info, ranges) = match message {
            rosmsg::Message::LaserScan(m) => (&m.header, &m.info, Ranges::Single(&m.ranges)),
            rosmsg::Message::MultiEchoLaserScan(m) => {
                (&m.header, &m.info, Ranges::FirstEcho(&m.ranges))
            }
            rosmsg::Message::Imu(_) | rosmsg::Message::Tf(_) => {
                self.counts.decode_errors += 1;
                return;
            }
        };
        let stamp_s = header.stamp.as_secs_f64();
        if self.ros.take(self.index, stamp_s, info, ranges, out) {
            self.counts.scans += 1;
        } else {
            self.counts.dropped += 1;
        }
    }

    fn take(&mut self, received: Option<f64>, event: &scip::Event, out: &mut Vec<SensorEvent>) {
        match event {
            scip::Event::Parameters(parameters) => {
                let geometry = geometry_from(parameters);
                self.geometry = Some(geometry);
                out.push(SensorEvent::Geometry {
                    sensor: self.index,
                    geometry,
                });
            }
            scip::Event::ClockSample(sample) => {
                // A TM1 reply is read right after the sensor sampled its clock.
                self.clock
                    .observe(u64::from(sample.sensor_ms), received, 1000.0);
            }
            scip::Event::Scan(scan) => self.scan(received, scan, out),
            _ => self.counts.decode_errors += 1,
        }
    }

    fn scan(&mut self, received: Option<f64>, scan: &scip::Scan, out: &mut Vec<SensorEvent>) {
        let Some(geometry) = self.geometry else {
            self.counts.dropped += 1;
            return;
        };
        // A revolution is sent once it is complete, one scan period after step 0
        // (docs/design.md, "Clocks"; the simulator's convention too).
        let t0 = self.clock.observe(
            u64::from(scan.raw_timestamp),
            received.map(|r| r - geometry.scan_period()),
            1000.0,
        );
        self.counts.scans += 1;
        out.push(SensorEvent::Scan(Scan {
            sensor: self.index,
            t0,
            first_step: u32::from(scan.range.start),
            cluster: u32::from(scan.range.cluster.max(1)),
            ranges_m: scan
                .ranges_mm
                .iter()
                .map(|&mm| f64::from(mm) / 1000.0)
                .collect(),
        }));
    }
}

/// The sensor geometry a `PP` reply describes.
pub(crate) fn geometry_from(parameters: &scip::Parameters) -> ScannerGeometry {
    ScannerGeometry {
        ares: parameters.angular_resolution,
        amin: u32::from(parameters.first_step),
        amax: u32::from(parameters.last_step),
        afrt: u32::from(parameters.front_step),
        rpm: parameters.scan_rpm,
        dmin_m: f64::from(parameters.min_distance_mm) / 1000.0,
        dmax_m: f64::from(parameters.max_distance_mm) / 1000.0,
    }
}

/// Xsens Xbus IMU: product code, output configuration acknowledgement, MTData2 samples.
#[derive(Debug)]
pub(crate) struct ImuTiming {
    clock: DeviceClock,
    modulus: u64,
    output_interval_s: f64,
    counts: DecodeCounts,
}

const TICK_HZ: f64 = 10_000.0;

impl ImuTiming {
    fn new(sample_time_modulus: u64, rate_hz: f64) -> Self {
        Self {
            clock: DeviceClock::new(TICK_HZ, sample_time_modulus),
            modulus: sample_time_modulus,
            output_interval_s: 1.0 / rate_hz,
            counts: DecodeCounts::default(),
        }
    }

    fn take(&mut self, received: Option<f64>, event: &xbus::Event, out: &mut Vec<SensorEvent>) {
        match event {
            xbus::Event::Measurement(m) => {
                self.counts.lost_packets += u64::from(m.lost_packets);
                self.measurement(received, &m.data, out);
            }
            xbus::Event::ProductCode(code) => {
                let modulus = code.sample_time_wrap();
                if modulus != self.modulus {
                    self.modulus = modulus;
                    self.clock = DeviceClock::new(TICK_HZ, modulus);
                }
            }
            xbus::Event::OutputConfiguration(configuration) => {
                if let Some(hz) = increment_rate_hz(configuration) {
                    self.output_interval_s = 1.0 / hz;
                }
            }
            xbus::Event::Measuring => {}
            _ => self.counts.decode_errors += 1,
        }
    }

    fn measurement(
        &mut self,
        received: Option<f64>,
        m: &xbus::Measurement,
        out: &mut Vec<SensorEvent>,
    ) {
        let Some(stf) = m.sample_time_fine else {
            self.counts.dropped += 1;
            return;
        };
        let rates = m.acceleration.zip(m.rate_of_turn);
        let increments = m.delta_v.zip(m.delta_q);
        let imu = match (rates, increments) {
            (Some((accel, gyro)), _) => ImuSample::Rate {
                t: self.clock.observe(u64::from(stf), received, TICK_HZ),
                gyro: to_ned(gyro.values, gyro.frame),
                accel: to_ned(accel.values, accel.frame),
            },
            (None, Some((dv, dq))) => ImuSample::Delta {
                t: self.clock.observe(u64::from(stf), received, TICK_HZ),
                dt: self.output_interval_s,
                dq: quaternion_to_ned(dq.values, dq.frame),
                dv: to_ned(dv.values, dv.frame),
            },
            (None, None) => {
                self.counts.dropped += 1;
                return;
            }
        };
        self.counts.imu_samples += 1;
        out.push(SensorEvent::Imu(imu));
    }
}

/// Output rate of the increments (or rates) in an acknowledged configuration.
fn increment_rate_hz(config: &OutputConfiguration) -> Option<f64> {
    config
        .entries()
        .iter()
        .find(|e| {
            matches!(
                e.id.data_type(),
                Some(DataType::DeltaV | DataType::Acceleration)
            )
        })
        .filter(|e| e.frequency != 0 && e.frequency != xbus::EVERY_PACKET)
        .map(|e| f64::from(e.frequency))
}

/// Sensor-frame vectors: the NED flag turns the sensor frame 180 deg about x relative to the
/// ENU/NWU sensor frame (x forward, y left, z up).
fn to_ned(v: [f64; 3], frame: CoordinateSystem) -> Vector3<f64> {
    match frame {
        CoordinateSystem::Ned => Vector3::new(v[0], v[1], v[2]),
        CoordinateSystem::Enu | CoordinateSystem::Nwu => Vector3::new(v[0], -v[1], -v[2]),
    }
}

/// A sensor-frame rotation increment (w, x, y, z) expressed in the NED-flagged sensor frame.
fn quaternion_to_ned(q: [f64; 4], frame: CoordinateSystem) -> UnitQuaternion<f64> {
    let axis = to_ned([q[1], q[2], q[3]], frame);
    UnitQuaternion::from_quaternion(Quaternion::new(q[0], axis.x, axis.y, axis.z))
}

#[cfg(test)]
#[path = "readings_tests.rs"]
mod tests;
