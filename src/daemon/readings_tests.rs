use super::*;
use crate::daemon::in_process::{Exchanged, ScipRig, XbusRig};
use crate::daemon::recording::Direction;

/// A replay's view of one sensor: the driver's receiver, then the host timing.
struct Decoder {
    receiver: Receiver,
    timing: SensorTiming,
}

impl Decoder {
    fn new(spec: SensorSpec) -> Self {
        Self {
            receiver: Receiver::new(spec.encoding()),
            timing: SensorTiming::new(&spec),
        }
    }

    fn counts(&self) -> DecodeCounts {
        self.timing.counts()
    }
}

const MS: u64 = 1_000_000;

/// Two seconds of a URG-04LX on a simulated host clock: the handshake, then scans whose last
/// byte arrives 1 ms after the revolution completed. Returns the rx chunks and the host time
/// of step 0 of every transmitted scan.
fn scanner_session(device_offset_ms: u32) -> (Vec<Exchanged>, Vec<u64>) {
    let model = scip::Model::urg_04lx();
    let steps = model.step_count();
    let geometry = geometry_from(&model.parameters);
    let mut rig = ScipRig::new(model, scip::DeviceConfig::default(), device_offset_ms);
    let mut chunks = Vec::new();
    let mut step0s = Vec::new();
    let tail_ns = (geometry.scan_period() * 1e9) as u64 + MS;
    let mut next_step0 = None;
    for now in (0..2000).map(|ms| 1_000 * MS + ms * MS) {
        if let Some(step0) = next_step0.filter(|&s: &u64| s + tail_ns <= now) {
            let ranges: Vec<u32> = (0..steps as u32).map(|k| 1000 + k).collect();
            rig.push_scan(step0, &ranges).unwrap();
            step0s.push(step0);
            next_step0 = Some(step0 + 100 * MS);
        }
        rig.exchange(now, &mut chunks);
        if next_step0.is_none() && rig.is_streaming() {
            next_step0 = Some(now);
        }
    }
    chunks.retain(|(direction, _, _)| *direction == Direction::Rx);
    (chunks, step0s)
}

fn decode(decoder: &mut Decoder, chunks: &[Exchanged]) -> Vec<SensorEvent> {
    let mut events = Vec::new();
    let mut readings = Vec::new();
    for (_, log_time, bytes) in chunks {
        decoder.timing.received(bytes.len());
        readings.clear();
        decoder.receiver.decode(*log_time, bytes, &mut readings);
        for reading in &readings {
            decoder.timing.take(*log_time, reading, &mut events);
        }
    }
    events
}

fn scanner_decoder() -> Decoder {
    Decoder::new(SensorSpec::Scanner {
        name: "pitched".into(),
        index: 1,
    })
}

#[test]
fn scans_carry_the_pp_geometry_metres_and_the_host_time_of_step_0() {
    let (chunks, step0s) = scanner_session(123_456);
    let mut decoder = scanner_decoder();
    let events = decode(&mut decoder, &chunks);
    let expected = geometry_from(&scip::Model::urg_04lx().parameters);
    assert_eq!(
        events[0],
        SensorEvent::Geometry {
            sensor: 1,
            geometry: expected
        }
    );
    assert_eq!(expected, ScannerGeometry::URG_04LX);
    let scans: Vec<&Scan> = events
        .iter()
        .filter_map(|e| match e {
            SensorEvent::Scan(s) => Some(s),
            _ => None,
        })
        .collect();
    assert_eq!(scans.len(), step0s.len());
    assert!(scans.len() > 15, "{}", scans.len());
    for (scan, &step0) in scans.iter().zip(&step0s) {
        assert_eq!(scan.sensor, 1);
        assert_eq!(scan.first_step, 44);
        assert_eq!(scan.ranges_m[0], 1.0);
        assert_eq!(scan.ranges_m[1], 1.001);
        // Device milliseconds quantise step 0; the lower envelope removes the 1 ms latency.
        let error = scan.t0 - step0 as f64 * 1e-9;
        assert!(error.abs() < 2.5e-3, "t0 off by {error} s");
    }
    let counts = decoder.counts();
    assert_eq!(counts.decode_errors, 0);
    assert_eq!(counts.scans, scans.len() as u64);
}

#[test]
fn same_chunks_give_the_same_events_bit_for_bit() {
    let (chunks, _) = scanner_session(7);
    let first = decode(&mut scanner_decoder(), &chunks);
    let second = decode(&mut scanner_decoder(), &chunks);
    let bits = |events: &[SensorEvent]| format!("{events:?}");
    assert_eq!(bits(&first), bits(&second));
}

#[test]
fn byte_by_byte_delivery_gives_the_same_scans() {
    let (chunks, _) = scanner_session(99);
    let whole = decode(&mut scanner_decoder(), &chunks);
    let split: Vec<Exchanged> = chunks
        .iter()
        .flat_map(|(d, t, bytes)| bytes.iter().map(move |b| (*d, *t, vec![*b])))
        .collect();
    assert_eq!(whole, decode(&mut scanner_decoder(), &split));
}

#[test]
fn garbage_is_counted_and_the_stream_recovers() {
    let (mut chunks, _) = scanner_session(5);
    let clean = decode(&mut scanner_decoder(), &chunks).len();
    let at = chunks.len() / 2;
    let time = chunks[at].1;
    chunks.insert(at, (Direction::Rx, time, b"\x00\xffgarbage\n\n".to_vec()));
    let mut decoder = scanner_decoder();
    let events = decode(&mut decoder, &chunks);
    assert!(decoder.counts().decode_errors >= 1);
    assert!(events.len() + 1 >= clean, "{} vs {clean}", events.len());
}

#[test]
fn scans_before_any_geometry_are_dropped_and_counted() {
    let (chunks, _) = scanner_session(5);
    // Skip the handshake: a recording that starts mid-stream.
    let tail = &chunks[20..];
    let mut decoder = scanner_decoder();
    let events = decode(&mut decoder, tail);
    assert!(events.is_empty());
    let dropped = decoder.counts().dropped;
    assert!(dropped > 0);
    // The same scans, after the handshake's PP: they were dropped for want of geometry alone.
    let mut from_start = scanner_decoder();
    decode(&mut from_start, &chunks);
    assert!(from_start.counts().scans >= dropped, "{dropped} dropped");
}

#[test]
fn raw_dumps_are_timed_by_the_sensor_clock() {
    let (chunks, step0s) = scanner_session(40_000);
    let untimed: Vec<Exchanged> = chunks
        .into_iter()
        .map(|(d, _, bytes)| (d, 0, bytes))
        .collect();
    let events = decode(&mut scanner_decoder(), &untimed);
    let t0s: Vec<f64> = events
        .iter()
        .filter_map(|e| match e {
            SensorEvent::Scan(s) => Some(s.t0),
            _ => None,
        })
        .collect();
    assert_eq!(t0s.len(), step0s.len());
    for (pair, t0) in t0s.windows(2).zip(&t0s) {
        assert!(t0.is_finite());
        assert!((pair[1] - pair[0] - 0.1).abs() < 1.5e-3, "{pair:?}");
    }
}

fn imu_session(
    options: xbus::emulator::EmulatorOptions,
    config: xbus::DeviceConfig,
) -> Vec<Exchanged> {
    let mut rig = XbusRig::new(options, config);
    let mut chunks = Vec::new();
    let stf_offset = 4_000_000_000u64;
    for ms in 0..1500u64 {
        let now = 500 * MS + ms * MS;
        if ms % 10 == 0 && rig.is_measuring() {
            let stf = ((now / 100_000 + stf_offset) % (1 << 32)) as u32;
            let sample = xbus::emulator::Sample::from_rates(
                stf,
                [0.1, 0.2, -9.81],
                [0.01, 0.02, 0.03],
                0.01,
            );
            rig.push_sample(&sample);
        }
        rig.exchange(now, &mut chunks);
    }
    chunks.retain(|(d, _, _)| *d == Direction::Rx);
    chunks
}

fn imu_decoder() -> Decoder {
    Decoder::new(SensorSpec::Imu {
        name: "imu".into(),
        sample_time_modulus: xbus::ONE_DAY_TICKS,
        rate_hz: 50.0,
    })
}

#[test]
fn imu_increments_at_host_times_with_the_acknowledged_interval() {
    let chunks = imu_session(
        xbus::emulator::EmulatorOptions::mti_630(),
        xbus::DeviceConfig::default(),
    );
    let mut decoder = imu_decoder();
    let events = decode(&mut decoder, &chunks);
    let samples: Vec<ImuSample> = events
        .iter()
        .filter_map(|e| match e {
            SensorEvent::Imu(s) => Some(*s),
            _ => None,
        })
        .collect();
    assert!(samples.len() > 100, "{}", samples.len());
    for (sample, (_, log_time, _)) in samples.iter().zip(&chunks[chunks.len() - samples.len()..]) {
        let ImuSample::Delta { t, dt, dv, .. } = sample else {
            panic!("increments were configured: {sample:?}")
        };
        // The acknowledged configuration says 100 Hz, overriding the 50 Hz fallback.
        assert_eq!(*dt, 0.01);
        assert!(
            (t - *log_time as f64 * 1e-9).abs() < 2e-4,
            "{t} vs {log_time}"
        );
        assert!((dv.z + 0.0981).abs() < 1e-6, "NED flag kept as is: {dv}");
    }
    let counts = decoder.counts();
    assert_eq!(counts.lost_packets, 0);
    assert_eq!(
        counts.clock_restarts, 0,
        "the product code chose the 2^32 wrap"
    );
}

#[test]
fn imu_rates_when_configured() {
    let config = xbus::DeviceConfig {
        imu_output: xbus::ImuOutput::Rates,
        ..xbus::DeviceConfig::default()
    };
    let chunks = imu_session(xbus::emulator::EmulatorOptions::mti_630(), config);
    let events = decode(&mut imu_decoder(), &chunks);
    let Some(SensorEvent::Imu(ImuSample::Rate { gyro, accel, .. })) = events.last() else {
        panic!("{:?}", events.last())
    };
    assert!((gyro - Vector3::new(0.01, 0.02, 0.03)).norm() < 1e-6);
    assert!((accel - Vector3::new(0.1, 0.2, -9.81)).norm() < 1e-5);
}

#[test]
fn enu_and_nwu_flags_turn_about_x_into_ned() {
    let v = [1.0, 2.0, 3.0];
    assert_eq!(
        to_ned(v, CoordinateSystem::Ned),
        Vector3::new(1.0, 2.0, 3.0)
    );
    assert_eq!(
        to_ned(v, CoordinateSystem::Enu),
        Vector3::new(1.0, -2.0, -3.0)
    );
    assert_eq!(
        to_ned(v, CoordinateSystem::Nwu),
        Vector3::new(1.0, -2.0, -3.0)
    );
    let half = std::f64::consts::FRAC_PI_4;
    let yaw_left_enu = [half.cos(), 0.0, 0.0, half.sin()];
    let q = quaternion_to_ned(yaw_left_enu, CoordinateSystem::Enu);
    // A turn about +z up is a turn about -z down.
    let expected =
        UnitQuaternion::from_axis_angle(&-Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
    assert!(q.angle_to(&expected) < 1e-12);
}
