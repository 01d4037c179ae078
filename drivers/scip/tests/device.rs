//! The device state machine driven against the emulator, including the recovery paths.

use std::time::Duration;

use scip::encoding::push_summed_line;
use scip::{
    DataKind, Detection, Device, DeviceConfig, DeviceError, Emulator, Event, Model, Phase,
    Receiver, Status,
};

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

struct Rig {
    device: Device,
    sensor: Emulator,
    now: Duration,
    events: Vec<Event>,
    link_up: bool,
    wire: Vec<u8>,
    /// Every `handle_input` call the device got, for replaying into a bare receiver.
    received: Vec<(Duration, Vec<u8>)>,
}

impl Rig {
    /// The device starts its handshake at once; nothing moves until `exchange`.
    fn new(model: Model, config: DeviceConfig) -> Rig {
        let mut sensor = Emulator::new(model);
        sensor.set_clock(100_000);
        let now = ms(100_000);
        Rig {
            device: Device::new(config, now),
            sensor,
            now,
            events: Vec::new(),
            link_up: true,
            wire: Vec::new(),
            received: Vec::new(),
        }
    }

    fn input(&mut self, bytes: &[u8]) {
        self.device.handle_input(self.now, bytes);
        self.received.push((self.now, bytes.to_vec()));
    }

    /// Moves bytes both ways until the link is quiet, then advances time by `dt`.
    fn exchange(&mut self, dt: Duration) {
        for _ in 0..50 {
            let mut moved = false;
            while let Some(bytes) = self.device.poll_transmit(self.now) {
                moved = true;
                if self.link_up {
                    self.sensor.handle_input(bytes);
                }
            }
            self.wire.clear();
            self.sensor.drain_output(&mut self.wire);
            if !self.wire.is_empty() && self.link_up {
                moved = true;
                // Deliver in odd-sized chunks, as a serial port would.
                for chunk in std::mem::take(&mut self.wire).chunks(7) {
                    self.input(chunk);
                }
            }
            while let Some(event) = self.device.poll_event() {
                self.events.push(event);
            }
            if !moved {
                break;
            }
        }
        self.now += dt;
        self.sensor.set_clock(self.now.as_millis() as u32);
        if self.device.poll_timeout().is_some_and(|t| t <= self.now) {
            self.device.handle_timeout(self.now);
        }
    }

    fn push_scan(&mut self, value: u32) {
        let steps = self.sensor.model().step_count();
        let ranges: Vec<u32> = (0..steps as u32).map(|i| value + i).collect();
        let intensities: Vec<u32> = (0..steps as u32).map(|i| 100 + i).collect();
        let time = self.now.as_millis() as u32;
        self.sensor
            .push_scan(time, &ranges, Some(&intensities))
            .unwrap();
    }

    fn scans(&self) -> Vec<&scip::Scan> {
        self.events
            .iter()
            .filter_map(|e| match e {
                Event::Scan(scan) => Some(scan),
                _ => None,
            })
            .collect()
    }

    fn detections(&self) -> Vec<Detection> {
        self.events
            .iter()
            .filter_map(|e| match e {
                Event::Detected(d) => Some(*d),
                _ => None,
            })
            .collect()
    }
}

fn start_and_stream(rig: &mut Rig, scans: u32) {
    for _ in 0..40 {
        rig.exchange(ms(5));
    }
    assert_eq!(
        rig.device.phase(),
        Phase::Streaming,
        "events: {:?}",
        rig.events
    );
    for i in 0..scans {
        rig.push_scan(1000 + i);
        rig.exchange(ms(25));
    }
}

#[test]
fn utm_streams_me_with_parameters_clock_samples_and_clean_stop() {
    let config = DeviceConfig {
        data: DataKind::DistanceIntensity,
        clock_samples: 3,
        ..DeviceConfig::default()
    };
    let mut rig = Rig::new(Model::utm_30lx(), config);
    start_and_stream(&mut rig, 4);
    let params = rig.device.parameters().expect("PP read");
    assert_eq!(
        (params.first_step, params.last_step, params.front_step),
        (0, 1080, 540)
    );
    assert_eq!(params.angular_resolution, 1440);
    let samples: Vec<_> = rig
        .events
        .iter()
        .filter_map(|e| match e {
            Event::ClockSample(s) => Some(*s),
            _ => None,
        })
        .collect();
    assert_eq!(samples.len(), 3);
    for s in &samples {
        // The emulator's clock follows host time in ms, set at each exchange.
        assert_eq!(u128::from(s.sensor_ms), s.received.as_millis(), "{s:?}");
        assert_eq!(u64::from(s.sensor_ms), s.sensor_ms_unwrapped);
    }
    let scans = rig.scans();
    assert_eq!(scans.len(), 4);
    assert_eq!(scans[0].ranges_mm.len(), 1081);
    assert_eq!(scans[0].intensities.len(), 1081);
    assert_eq!(scans[2].ranges_mm[5], 1002 + 5);
    assert_eq!(scans[2].intensities[5], 105);
    assert!(scans
        .windows(2)
        .all(|w| w[1].timestamp_ms > w[0].timestamp_ms));
    assert!(!rig.detections().contains(&Detection::StreamRunning));

    rig.device.stop(rig.now);
    rig.exchange(ms(10));
    assert_eq!(rig.device.phase(), Phase::Stopped);
    assert!(rig.events.contains(&Event::Stopped));
    assert!(!rig.sensor.is_streaming() && !rig.sensor.is_laser_on());
}

#[test]
fn urg_geometry_comes_from_pp_and_scans_cover_amin_to_amax() {
    let mut rig = Rig::new(
        Model::urg_04lx(),
        DeviceConfig {
            clock_samples: 0,
            ..DeviceConfig::default()
        },
    );
    start_and_stream(&mut rig, 2);
    let scans = rig.scans();
    assert_eq!(scans.len(), 2);
    assert_eq!((scans[0].range.start, scans[0].range.end), (44, 725));
    assert_eq!(scans[0].ranges_mm.len(), 682);
    assert!(scans[0].intensities.is_empty());
}

#[test]
fn a_sensor_already_streaming_is_stopped_and_restarted() {
    let mut rig = Rig::new(Model::ust_20lx(), DeviceConfig::default());
    rig.sensor.handle_input(b"MD0000108001000\n");
    rig.push_scan(500); // a scan in flight when the driver starts
    start_and_stream(&mut rig, 2);
    assert!(rig.detections().contains(&Detection::StreamRunning));
    let firsts: Vec<u32> = rig.scans().iter().map(|s| s.ranges_mm[0]).collect();
    // The scan in flight is data too: a receiver replaying these bytes reports it as well.
    assert_eq!(firsts, [500, 1000, 1001]);
    assert_receiver_agrees(&rig);
}

#[test]
fn scip11_sensor_is_switched_to_scip2() {
    let mut rig = Rig::new(Model::urg_04lx(), DeviceConfig::default());
    rig.sensor.boot_in_scip11();
    start_and_stream(&mut rig, 1);
    assert_eq!(rig.detections(), vec![Detection::Scip11]);
    assert_eq!(rig.scans().len(), 1);
}

#[test]
fn time_adjust_mode_is_left_with_tm2() {
    let mut rig = Rig::new(Model::utm_30lx(), DeviceConfig::default());
    rig.sensor.enter_time_adjust_mode();
    start_and_stream(&mut rig, 1);
    assert_eq!(rig.detections(), vec![Detection::TimeAdjustMode]);
    assert_eq!(rig.scans().len(), 1);
}

#[test]
fn bad_stream_parameters_give_a_typed_status_error() {
    let config = DeviceConfig {
        steps: Some((0, 2000)),
        ..DeviceConfig::default()
    };
    let mut rig = Rig::new(Model::utm_30lx(), config);
    for _ in 0..40 {
        rig.exchange(ms(5));
    }
    assert_eq!(rig.device.phase(), Phase::Failed);
    assert!(rig.events.contains(&Event::Error(DeviceError::Status {
        command: "MD/ME",
        status: Status::Code(*b"04"),
    })));
    let message = rig.events.iter().find_map(|e| match e {
        Event::Error(e) => Some(e.to_string()),
        _ => None,
    });
    assert!(message.unwrap().contains("status 04"));
}

#[test]
fn silent_sensor_times_out_after_the_configured_probes() {
    let mut rig = Rig::new(
        Model::utm_30lx(),
        DeviceConfig {
            probe_attempts: 3,
            reply_timeout: ms(500),
            ..DeviceConfig::default()
        },
    );
    rig.link_up = false;
    for _ in 0..10 {
        rig.exchange(ms(400));
    }
    assert_eq!(rig.device.phase(), Phase::Failed);
    assert!(rig.events.contains(&Event::Error(DeviceError::Timeout {
        phase: Phase::Probing
    })));
    // Three probes at 0.5 s each, not earlier.
    assert!(rig.now >= ms(101_500));
}

#[test]
fn a_stalled_stream_is_reported_and_restarted() {
    let mut rig = Rig::new(
        Model::utm_30lx(),
        DeviceConfig {
            stream_timeout: ms(300),
            clock_samples: 0,
            ..DeviceConfig::default()
        },
    );
    start_and_stream(&mut rig, 1);
    for _ in 0..4 {
        rig.exchange(ms(100)); // no scans pushed: the sensor went quiet
    }
    assert!(rig
        .events
        .contains(&Event::Error(DeviceError::StreamStalled)));
    for _ in 0..10 {
        rig.exchange(ms(5));
    }
    assert_eq!(rig.device.phase(), Phase::Streaming);
    assert_eq!(rig.device.stats().restarts, 1);
}

#[test]
fn corrupted_scan_is_dropped_and_counted() {
    let mut rig = Rig::new(
        Model::utm_30lx(),
        DeviceConfig {
            clock_samples: 0,
            ..DeviceConfig::default()
        },
    );
    start_and_stream(&mut rig, 1);
    rig.push_scan(2000);
    let mut bytes = Vec::new();
    rig.sensor.drain_output(&mut bytes);
    bytes[100] ^= 0x01;
    rig.input(&bytes);
    rig.push_scan(3000);
    rig.exchange(ms(25));
    let scans = rig.scans();
    assert_eq!(scans.len(), 2);
    assert_eq!(scans[1].ranges_mm[0], 3000);
    assert_eq!(rig.device.stats().decode_errors, 1);
}

#[test]
fn timestamps_unwrap_across_the_24_bit_wrap() {
    let mut rig = Rig::new(
        Model::utm_30lx(),
        DeviceConfig {
            clock_samples: 0,
            ..DeviceConfig::default()
        },
    );
    start_and_stream(&mut rig, 0);
    let steps = rig.sensor.model().step_count();
    let ranges = vec![1500u32; steps];
    let wrap = 1u32 << 24;
    for i in 0..6u32 {
        let time = wrap - 75 + 25 * i; // the last three scans are past the wrap
        rig.sensor
            .push_scan(time & (wrap - 1), &ranges, None)
            .unwrap();
        rig.exchange(ms(25));
    }
    let stamps: Vec<u64> = rig.scans().iter().map(|s| s.timestamp_ms).collect();
    let expected: Vec<u64> = (0..6).map(|i| u64::from(wrap) - 75 + 25 * i).collect();
    assert_eq!(stamps, expected);
}

#[test]
fn a_finite_stream_counts_down_and_ends() {
    let config = DeviceConfig {
        scan_count: 3,
        clock_samples: 0,
        ..DeviceConfig::default()
    };
    let mut rig = Rig::new(Model::urg_04lx(), config);
    start_and_stream(&mut rig, 5);
    let remaining: Vec<u8> = rig.scans().iter().map(|s| s.remaining).collect();
    assert_eq!(remaining, vec![2, 1, 0]);
    assert!(rig.events.contains(&Event::StreamEnded));
    assert_eq!(rig.device.phase(), Phase::Idle);
    assert!(!rig.sensor.is_streaming());
}

/// A bare receiver fed what the device was fed emits the device's data events, in order.
fn assert_receiver_agrees(rig: &Rig) {
    let mut receiver = Receiver::new();
    let mut replayed = Vec::new();
    for (now, bytes) in &rig.received {
        receiver.handle_input(*now, bytes);
        replayed.extend(std::iter::from_fn(|| receiver.poll_event()));
    }
    let live: Vec<&Event> = rig.events.iter().filter(|e| e.is_data()).collect();
    assert!(!live.is_empty());
    assert_eq!(live, replayed.iter().collect::<Vec<_>>());
    let stats = rig.device.stats();
    let received = receiver.stats();
    assert_eq!(
        (stats.replies, stats.scans, stats.decode_errors),
        (received.replies, received.scans, received.decode_errors)
    );
}

#[test]
fn a_receiver_replaying_the_bytes_reports_the_same_data_as_the_device() {
    let config = DeviceConfig {
        data: DataKind::DistanceIntensity,
        stream_timeout: ms(300),
        ..DeviceConfig::default()
    };
    let mut rig = Rig::new(Model::utm_30lx(), config);
    rig.sensor.handle_input(b"ME0000108001000\n");
    rig.push_scan(500); // in flight while probing
    start_and_stream(&mut rig, 3);
    // A corrupted scan, then a stall and the restart it causes (clock samples again).
    rig.push_scan(2000);
    let mut bytes = Vec::new();
    rig.sensor.drain_output(&mut bytes);
    bytes[100] ^= 0x01;
    rig.input(&bytes);
    for _ in 0..4 {
        rig.exchange(ms(100));
    }
    for _ in 0..10 {
        rig.exchange(ms(5));
    }
    assert_eq!(rig.device.phase(), Phase::Streaming);
    rig.push_scan(3000);
    rig.exchange(ms(25));
    let count = |f: fn(&Event) -> bool| rig.events.iter().filter(|e| f(e)).count();
    assert_eq!(count(|e| matches!(e, Event::Parameters(_))), 2);
    assert_eq!(count(|e| matches!(e, Event::ClockSample(_))), 10);
    assert_eq!(count(|e| matches!(e, Event::DecodeError(_))), 1);
    assert_eq!(rig.scans().len(), 5);
    assert_receiver_agrees(&rig);
}

#[test]
fn a_reply_cut_before_a_probe_retry_costs_only_itself() {
    let mut rig = Rig::new(
        Model::utm_30lx(),
        DeviceConfig {
            clock_samples: 0,
            reply_timeout: ms(500),
            ..DeviceConfig::default()
        },
    );
    // The first probe's reply loses its end on the wire; the rest of the exchange is clean.
    let probe = rig.device.poll_transmit(rig.now).unwrap().to_vec();
    rig.sensor.handle_input(&probe);
    let mut reply = Vec::new();
    rig.sensor.drain_output(&mut reply);
    rig.input(&reply[..reply.len() - 2]);
    // The cut reply swallows the next probe's reply; the probe after that gets through.
    for _ in 0..20 {
        rig.exchange(ms(300));
        if rig.device.phase() == Phase::Streaming {
            break;
        }
    }
    assert_eq!(rig.device.phase(), Phase::Streaming, "{:?}", rig.events);
    assert_eq!(
        rig.events[0],
        Event::DecodeError(scip::DecodeError::BadStatus)
    );
    assert_eq!(rig.device.stats().decode_errors, 1);
    rig.push_scan(1000);
    rig.exchange(ms(25));
    assert_eq!(rig.scans().len(), 1);
    assert_receiver_agrees(&rig);
}

/// A reply built by hand: echo, status, then summed info lines.
fn info_reply(echo: &[u8], lines: &[&str]) -> Vec<u8> {
    let mut out = echo.to_vec();
    out.push(b'\n');
    push_summed_line(b"00", &mut out);
    for line in lines {
        push_summed_line(line.as_bytes(), &mut out);
    }
    out.push(b'\n');
    out
}

#[test]
fn a_pp_reply_that_does_not_parse_is_reported_once_and_fails_only_the_handshake_reading_it() {
    let now = ms(1);
    let mut device = Device::new(DeviceConfig::default(), now);
    let mut receiver = Receiver::new();
    let bad_pp = info_reply(b"PP", &["MODL:X;", "DMIN:20;"]);
    let mut feed = |device: &mut Device, bytes: &[u8]| {
        while device.poll_transmit(now).is_some() {}
        device.handle_input(now, bytes);
        receiver.handle_input(now, bytes);
        let events: Vec<Event> = std::iter::from_fn(|| device.poll_event()).collect();
        let data: Vec<Event> = std::iter::from_fn(|| receiver.poll_event()).collect();
        (events, data)
    };
    // While probing, a late PP is only data.
    let (events, data) = feed(&mut device, &bad_pp);
    let bad = Event::Error(DeviceError::BadParameters(scip::ParameterError {
        key: "DMAX",
    }));
    assert_eq!((&events, &data), (&vec![bad.clone()], &vec![bad.clone()]));
    assert_eq!(device.phase(), Phase::Probing);
    feed(&mut device, b"QT\n00P\n\n");
    feed(&mut device, &info_reply(b"VV", &["VEND:Hokuyo;"]));
    assert_eq!(device.phase(), Phase::ReadingParameters);
    let (events, data) = feed(&mut device, &bad_pp);
    assert_eq!((&events, &data), (&vec![bad.clone()], &vec![bad]));
    assert_eq!(device.phase(), Phase::Failed);
}
