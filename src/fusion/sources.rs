//! Replay-side decoding of each sensor's received bytes into host-timed measurements, shared
//! by the live daemon and replay so that both see exactly the same events.
//!
//! A decoder is fed only the chunks read from its device, each with the host time at which it
//! was read (`log_time_ns`, monotonic since daemon start). It understands the handshake replies
//! it needs (SCIP `PP` for the scanner geometry and `TM1` for clock samples; Xbus product code
//! for the SampleTimeFine wrap and the output configuration acknowledgement for the output
//! interval) and the measurement stream, and maps device clocks to host time with a
//! [`ClockEstimator`] per sensor. Nothing here reads a clock or does I/O: the same chunks give
//! the same events, bit for bit.
//!
//! A raw port dump has no host times (`log_time_ns == 0` on every chunk): it is timed by the
//! sensor's own clock, unwrapped, from the first sample.

use super::clock::{ClockConfig, ClockEstimator};
use crate::sensors::{ImuSample, Scan, ScannerGeometry};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use xbus::{CoordinateSystem, DataType, Framer, Measurement, OutputConfiguration, ProductCode};

/// What a sensor's bytes turned into.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorEvent {
    /// A scanner reported its geometry (`PP`), before its first scan and after each reconnect.
    Geometry {
        sensor: usize,
        geometry: ScannerGeometry,
    },
    Scan(Scan),
    Imu(ImuSample),
}

/// Health counters of one decoder.
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

/// Which decoder a configured sensor needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SensorSetup {
    /// Scanner number `index` in the configuration. `geometry` is used until a `PP` reply is
    /// seen (a raw dump or a recording started mid-stream has none).
    Scanner {
        index: usize,
        geometry: Option<ScannerGeometry>,
    },
    /// The IMU: `sample_time_modulus` until the product code is seen, `rate_hz` until the
    /// output configuration acknowledgement is.
    Imu {
        sample_time_modulus: u64,
        rate_hz: f64,
    },
}

/// Decoder of one sensor's received bytes.
#[derive(Debug)]
pub enum SensorDecoder {
    Scanner(ScannerDecoder),
    Imu(ImuDecoder),
}

impl SensorDecoder {
    pub fn new(setup: SensorSetup) -> Self {
        match setup {
            SensorSetup::Scanner { index, geometry } => {
                Self::Scanner(ScannerDecoder::new(index, geometry))
            }
            SensorSetup::Imu {
                sample_time_modulus,
                rate_hz,
            } => Self::Imu(ImuDecoder::new(sample_time_modulus, rate_hz)),
        }
    }

    /// Decodes one received chunk, appending what it completed to `events`.
    pub fn push(&mut self, log_time_ns: u64, bytes: &[u8], events: &mut Vec<SensorEvent>) {
        match self {
            Self::Scanner(d) => d.push(log_time_ns, bytes, events),
            Self::Imu(d) => d.push(log_time_ns, bytes, events),
        }
    }

    pub fn counts(&self) -> DecodeCounts {
        match self {
            Self::Scanner(d) => d.counts(),
            Self::Imu(d) => d.counts(),
        }
    }

    /// The link dropped: a frame cut in half must not swallow the first reply after reconnect.
    pub fn link_lost(&mut self) {
        match self {
            Self::Scanner(d) => d.decoder.reset(),
            Self::Imu(d) => {
                d.framer.clear();
                d.last_counter = None;
            }
        }
    }
}

/// Maps a device counter to host seconds: through the clock estimator when chunks carry host
/// times, by unwrapping the counter alone when they do not (raw dumps).
#[derive(Debug, Clone)]
struct DeviceClock {
    estimator: ClockEstimator,
    unwrapped: Unwrapper,
}

impl DeviceClock {
    fn new(tick_hz: f64, modulus: u64) -> Self {
        let config = ClockConfig::with_counter(tick_hz, modulus.clamp(2, 1 << 62));
        Self {
            unwrapped: Unwrapper::new(config.modulus),
            estimator: ClockEstimator::new(config)
                .expect("the fixed tick rates and a clamped modulus always validate"),
        }
    }

    /// Host time of device counter `raw`, given that the packet carrying it would have been
    /// received at `earliest_receive_s` had the link no latency.
    fn observe(&mut self, raw: u64, earliest_receive_s: Option<f64>, tick_hz: f64) -> f64 {
        let ticks = self.unwrapped.unwrap(raw);
        earliest_receive_s
            .and_then(|host| self.estimator.observe(raw, host))
            .unwrap_or(ticks as f64 / tick_hz)
    }

    fn restarts(&self) -> u64 {
        self.estimator.restarts()
    }
}

/// Counter unwrapping for raw dumps, where there is no host clock to check steps against.
#[derive(Debug, Clone, Copy)]
struct Unwrapper {
    modulus: u64,
    last_raw: Option<u64>,
    total: i64,
}

impl Unwrapper {
    fn new(modulus: u64) -> Self {
        Self {
            modulus: modulus.max(2),
            last_raw: None,
            total: 0,
        }
    }

    fn unwrap(&mut self, raw: u64) -> i64 {
        let raw = raw % self.modulus;
        if let Some(last) = self.last_raw {
            let forward = (raw + self.modulus - last) % self.modulus;
            self.total += if forward > self.modulus / 2 {
                forward as i64 - self.modulus as i64
            } else {
                forward as i64
            };
        }
        self.last_raw = Some(raw);
        self.total
    }
}

fn host_seconds(log_time_ns: u64) -> Option<f64> {
    (log_time_ns != 0).then_some(log_time_ns as f64 * 1e-9)
}

/// SCIP 2.0 scanner: `PP` geometry, `TM1` clock samples, `MD`/`ME`/`GD` scans.
#[derive(Debug)]
pub struct ScannerDecoder {
    index: usize,
    decoder: scip::Decoder,
    geometry: Option<ScannerGeometry>,
    clock: DeviceClock,
    counts: DecodeCounts,
}

impl ScannerDecoder {
    pub fn new(index: usize, geometry: Option<ScannerGeometry>) -> Self {
        Self {
            index,
            decoder: scip::Decoder::new(),
            geometry,
            clock: DeviceClock::new(1000.0, 1 << 24),
            counts: DecodeCounts::default(),
        }
    }

    pub fn geometry(&self) -> Option<ScannerGeometry> {
        self.geometry
    }

    pub fn counts(&self) -> DecodeCounts {
        DecodeCounts {
            clock_restarts: self.clock.restarts(),
            ..self.counts
        }
    }

    pub fn push(&mut self, log_time_ns: u64, mut bytes: &[u8], events: &mut Vec<SensorEvent>) {
        self.counts.chunks += 1;
        self.counts.bytes += bytes.len() as u64;
        let received = host_seconds(log_time_ns);
        while !bytes.is_empty() {
            let used = self.decoder.push(bytes);
            bytes = &bytes[used..];
            let reply = match self.decoder.reply() {
                None => continue,
                Some(Err(_)) => {
                    self.counts.decode_errors += 1;
                    continue;
                }
                Some(Ok(reply)) => reply,
            };
            match reply.body {
                scip::Body::Info(info) if reply.command() == b"PP" => {
                    match scip::Parameters::from_info(&info) {
                        Ok(parameters) => {
                            let geometry = geometry_from(&parameters);
                            self.geometry = Some(geometry);
                            events.push(SensorEvent::Geometry {
                                sensor: self.index,
                                geometry,
                            });
                        }
                        Err(_) => self.counts.decode_errors += 1,
                    }
                }
                scip::Body::Time(device_ms) => {
                    // A TM1 reply is read right after the sensor sampled its clock.
                    self.clock.observe(u64::from(device_ms), received, 1000.0);
                }
                scip::Body::Scan(data) => {
                    let Some(geometry) = self.geometry else {
                        self.counts.dropped += 1;
                        continue;
                    };
                    // A revolution is sent once it is complete, one scan period after step 0
                    // (docs/design.md, "Clocks"; the simulator's convention too).
                    let t0 = self.clock.observe(
                        u64::from(data.timestamp),
                        received.map(|r| r - geometry.scan_period()),
                        1000.0,
                    );
                    self.counts.scans += 1;
                    events.push(SensorEvent::Scan(Scan {
                        sensor: self.index,
                        t0,
                        first_step: u32::from(data.range.start),
                        cluster: u32::from(data.range.cluster.max(1)),
                        ranges_m: data
                            .ranges
                            .iter()
                            .map(|&mm| f64::from(mm) / 1000.0)
                            .collect(),
                    }));
                }
                _ => {}
            }
        }
    }
}

/// The sensor geometry a `PP` reply describes.
pub fn geometry_from(parameters: &scip::Parameters) -> ScannerGeometry {
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
pub struct ImuDecoder {
    framer: Framer,
    clock: DeviceClock,
    modulus: u64,
    output_interval_s: f64,
    last_counter: Option<u16>,
    counts: DecodeCounts,
}

const TICK_HZ: f64 = 10_000.0;

impl ImuDecoder {
    pub fn new(sample_time_modulus: u64, rate_hz: f64) -> Self {
        Self {
            framer: Framer::new(xbus::DEFAULT_MAX_PAYLOAD),
            clock: DeviceClock::new(TICK_HZ, sample_time_modulus),
            modulus: sample_time_modulus,
            output_interval_s: 1.0 / rate_hz,
            last_counter: None,
            counts: DecodeCounts::default(),
        }
    }

    pub fn counts(&self) -> DecodeCounts {
        DecodeCounts {
            clock_restarts: self.clock.restarts(),
            ..self.counts
        }
    }

    pub fn push(&mut self, log_time_ns: u64, mut bytes: &[u8], events: &mut Vec<SensorEvent>) {
        self.counts.chunks += 1;
        self.counts.bytes += bytes.len() as u64;
        let received = host_seconds(log_time_ns);
        loop {
            let (mid, payload) = match self.framer.decode(&mut bytes) {
                None => break,
                Some(Err(_)) => {
                    self.counts.decode_errors += 1;
                    continue;
                }
                Some(Ok(frame)) => (frame.mid, frame.payload),
            };
            match mid {
                xbus::mid::MT_DATA2 => match Measurement::from_payload(payload) {
                    Ok(m) => self.measurement(received, &m, events),
                    Err(_) => self.counts.decode_errors += 1,
                },
                xbus::mid::PRODUCT_CODE => {
                    let modulus = ProductCode::from_bytes(payload).sample_time_wrap();
                    if modulus != self.modulus {
                        self.modulus = modulus;
                        self.clock = DeviceClock::new(TICK_HZ, modulus);
                    }
                }
                xbus::mid::OUTPUT_CONFIGURATION => {
                    if let Some(hz) = OutputConfiguration::from_payload(payload)
                        .ok()
                        .and_then(|c| increment_rate_hz(&c))
                    {
                        self.output_interval_s = 1.0 / hz;
                    }
                }
                xbus::mid::GO_TO_MEASUREMENT_ACK => self.last_counter = None,
                _ => {}
            }
        }
    }

    fn measurement(&mut self, received: Option<f64>, m: &Measurement, out: &mut Vec<SensorEvent>) {
        if let (Some(last), Some(counter)) = (self.last_counter, m.packet_counter) {
            self.counts.lost_packets += u64::from(counter.wrapping_sub(last).wrapping_sub(1));
        }
        if m.packet_counter.is_some() {
            self.last_counter = m.packet_counter;
        }
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

impl std::fmt::Debug for ImuDecoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ImuDecoder")
            .field("modulus", &self.modulus)
            .field("output_interval_s", &self.output_interval_s)
            .field("counts", &self.counts)
            .finish_non_exhaustive()
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
#[path = "sources_tests.rs"]
mod tests;
