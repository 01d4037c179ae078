//! The device state machine driven against the emulator, including the recovery paths.

use scip::{
    DataKind, Detection, Device, DeviceConfig, DeviceError, DeviceEvent, Emulator, Model, Phase,
    Status,
};

struct Rig {
    device: Device,
    sensor: Emulator,
    now: f64,
    events: Vec<DeviceEvent>,
    link_up: bool,
    wire: Vec<u8>,
}

impl Rig {
    fn new(model: Model, config: DeviceConfig) -> Rig {
        let mut sensor = Emulator::new(model);
        sensor.set_clock(100_000);
        Rig {
            device: Device::new(config),
            sensor,
            now: 100.0,
            events: Vec::new(),
            link_up: true,
            wire: Vec::new(),
        }
    }

    /// Moves bytes both ways until the link is quiet, then advances time by `dt`.
    fn exchange(&mut self, dt: f64) {
        for _ in 0..50 {
            let mut moved = false;
            while let Some(bytes) = self.device.poll_transmit(self.now) {
                moved = true;
                if self.link_up {
                    self.sensor.handle_input(bytes);
                }
            }
            self.wire.clear();
            self.sensor.take_output(&mut self.wire);
            if !self.wire.is_empty() && self.link_up {
                moved = true;
                // Deliver in odd-sized chunks, as a serial port would.
                for chunk in self.wire.chunks(7) {
                    self.device.handle_input(self.now, chunk);
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
        self.sensor.set_clock((self.now * 1000.0) as u32);
        if self.device.poll_timeout().is_some_and(|t| t <= self.now) {
            self.device.handle_timeout(self.now);
        }
    }

    fn push_scan(&mut self, value: u32) {
        let steps = self.sensor.model().step_count();
        let ranges: Vec<u32> = (0..steps as u32).map(|i| value + i).collect();
        let intensities: Vec<u32> = (0..steps as u32).map(|i| 100 + i).collect();
        let time = (self.now * 1000.0) as u32;
        self.sensor
            .push_scan(time, &ranges, Some(&intensities))
            .unwrap();
    }

    fn scans(&self) -> Vec<&scip::Scan> {
        self.events
            .iter()
            .filter_map(|e| match e {
                DeviceEvent::Scan(scan) => Some(scan),
                _ => None,
            })
            .collect()
    }

    fn detections(&self) -> Vec<Detection> {
        self.events
            .iter()
            .filter_map(|e| match e {
                DeviceEvent::Detected(d) => Some(*d),
                _ => None,
            })
            .collect()
    }
}

fn start_and_stream(rig: &mut Rig, scans: u32) {
    rig.device.start();
    for _ in 0..40 {
        rig.exchange(0.005);
    }
    assert_eq!(
        rig.device.phase(),
        Phase::Streaming,
        "events: {:?}",
        rig.events
    );
    for i in 0..scans {
        rig.push_scan(1000 + i);
        rig.exchange(0.025);
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
            DeviceEvent::ClockSample(s) => Some(*s),
            _ => None,
        })
        .collect();
    assert_eq!(samples.len(), 3);
    for s in &samples {
        assert!(s.host_send <= s.host_receive);
        // The emulator's clock follows host time in ms, set at each exchange.
        assert!(
            (f64::from(s.sensor_ms) / 1000.0 - s.host_send).abs() < 0.011,
            "{s:?}"
        );
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

    rig.device.stop();
    rig.exchange(0.01);
    assert_eq!(rig.device.phase(), Phase::Stopped);
    assert!(rig.events.contains(&DeviceEvent::Stopped));
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
    assert_eq!(rig.scans().len(), 2);
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
    rig.device.start();
    for _ in 0..40 {
        rig.exchange(0.005);
    }
    assert_eq!(rig.device.phase(), Phase::Failed);
    assert!(rig
        .events
        .contains(&DeviceEvent::Error(DeviceError::Status {
            command: "MD/ME",
            status: Status::Code(*b"04"),
        })));
    let message = rig.events.iter().find_map(|e| match e {
        DeviceEvent::Error(e) => Some(e.to_string()),
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
            reply_timeout: 0.5,
            ..DeviceConfig::default()
        },
    );
    rig.link_up = false;
    rig.device.start();
    for _ in 0..10 {
        rig.exchange(0.4);
    }
    assert_eq!(rig.device.phase(), Phase::Failed);
    assert!(rig
        .events
        .contains(&DeviceEvent::Error(DeviceError::Timeout {
            phase: Phase::Probing
        })));
    // Three probes at 0.5 s each, not earlier.
    assert!(rig.now >= 101.5);
}

#[test]
fn a_stalled_stream_is_reported_and_restarted() {
    let mut rig = Rig::new(
        Model::utm_30lx(),
        DeviceConfig {
            stream_timeout: 0.3,
            clock_samples: 0,
            ..DeviceConfig::default()
        },
    );
    start_and_stream(&mut rig, 1);
    for _ in 0..4 {
        rig.exchange(0.1); // no scans pushed: the sensor went quiet
    }
    assert!(rig
        .events
        .contains(&DeviceEvent::Error(DeviceError::StreamStalled)));
    for _ in 0..10 {
        rig.exchange(0.005);
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
    rig.sensor.take_output(&mut bytes);
    bytes[100] ^= 0x01;
    rig.device.handle_input(rig.now, &bytes);
    rig.push_scan(3000);
    rig.exchange(0.025);
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
        rig.exchange(0.025);
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
    assert!(rig.events.contains(&DeviceEvent::StreamEnded));
    assert_eq!(rig.device.phase(), Phase::Idle);
    assert!(!rig.sensor.is_streaming());
}
