//! The device state machine against its emulator, including every failure path.

mod support;

use std::time::Duration;

use support::{assert_receiver_agrees, measuring_link, Link};
use xbus::emulator::{EmulatorOptions, Sample};
use xbus::{
    mid, CoordinateSystem, DeviceConfig, Error, ErrorCode, Event, ImuMeasurement, ImuOutput,
    OutputConfiguration, Precision, ProductCode, SampleTimeWrap, ONE_DAY_TICKS, U32_TICKS,
};

fn measurements(events: &[Event]) -> Vec<ImuMeasurement> {
    events
        .iter()
        .filter_map(|e| match e {
            Event::Measurement(m) => Some(*m),
            _ => None,
        })
        .collect()
}

fn failure(events: &[Event]) -> Error {
    events
        .iter()
        .find_map(|e| match e {
            Event::Failed(f) => Some(*f),
            _ => None,
        })
        .unwrap_or_else(|| panic!("no failure in {events:?}"))
}

fn still(stf: u32) -> Sample {
    Sample::from_rates(stf, [0.1, -0.2, -9.81], [0.01, 0.02, -0.03], 0.01)
}

#[test]
fn handshake_identifies_configures_and_measures() {
    let config = DeviceConfig::default();
    let mut link = Link::new(config, EmulatorOptions::mti_g_710());
    link.pump();
    let events = link.take_events();
    assert_receiver_agrees(&link);
    let code = ProductCode::from_bytes(b"MTi-G-710-2A5G4");
    assert_eq!(events[0], Event::ProductCode(code));
    let Event::Identified(info) = events[1] else {
        panic!("{events:?}")
    };
    assert_eq!(info.product_code.as_str(), "MTi-G-710-2A5G4");
    assert_eq!(info.device_id, 0x0370_0C6E);
    assert_eq!(
        (
            info.firmware.major,
            info.firmware.minor,
            info.firmware.revision
        ),
        (1, 8, 2)
    );
    assert_eq!(info.sample_time_wrap, ONE_DAY_TICKS);
    assert_eq!(
        events[2],
        Event::OutputConfiguration(config.output_configuration())
    );
    assert_eq!(events[3], Event::Measuring);
    assert_eq!(events.len(), 4);
    assert_eq!(
        link.emulator.output_configuration(),
        &config.output_configuration()
    );
    assert!(link.emulator.is_measuring());
    // The device was asked for NED-flagged increments at 100 Hz.
    let ids: Vec<u16> = config
        .output_configuration()
        .entries()
        .iter()
        .map(|e| e.id.0)
        .collect();
    assert_eq!(ids, [0x1060, 0x1020, 0xE020, 0x4014, 0x8034]);
}

#[test]
fn increments_arrive_in_every_precision() {
    for precision in Precision::ALL {
        let config = DeviceConfig {
            precision,
            ..DeviceConfig::default()
        };
        let mut link = measuring_link(config, EmulatorOptions::mti_630());
        let sample = still(1000);
        link.push(&sample);
        let got = measurements(&link.take_events());
        assert_eq!(got.len(), 1);
        let m = got[0];
        assert_eq!(m.sample_time, Some(1000));
        assert_eq!(m.data.packet_counter, Some(0));
        let dv = m.data.delta_v.unwrap();
        let dq = m.data.delta_q.unwrap();
        assert_eq!((dv.frame, dv.precision), (CoordinateSystem::Ned, precision));
        let tolerance = match precision {
            Precision::Float32 => 1e-7,
            Precision::Fp1220 => 1e-6,
            Precision::Fp1632 | Precision::Float64 => 1e-9,
        };
        for (g, w) in dv
            .values
            .iter()
            .zip(sample.delta_v)
            .chain(dq.values.iter().zip(sample.delta_q))
        {
            assert!((g - w).abs() < tolerance, "{precision:?}: {g} vs {w}");
        }
        assert!(m.data.acceleration.is_none());
    }
}

#[test]
fn rates_output_carries_acceleration_and_rate_of_turn() {
    let config = DeviceConfig {
        imu_output: ImuOutput::Rates,
        rate_hz: 400,
        ..DeviceConfig::default()
    };
    let mut link = measuring_link(config, EmulatorOptions::mti_630());
    let sample = still(5);
    link.push(&sample);
    let m = measurements(&link.take_events())[0];
    let acc = m.data.acceleration.unwrap();
    let gyro = m.data.rate_of_turn.unwrap();
    for (g, w) in acc
        .values
        .iter()
        .zip(sample.acceleration)
        .chain(gyro.values.iter().zip(sample.rate_of_turn))
    {
        assert!((g - w).abs() < 1e-6);
    }
    assert!(m.data.delta_v.is_none());
}

#[test]
fn lost_packets_are_counted_across_the_counter_wrap() {
    let mut link = measuring_link(DeviceConfig::default(), EmulatorOptions::mti_630());
    link.emulator.set_packet_counter(65534);
    link.push(&still(100));
    link.push(&still(200));
    // 0 and 1 never arrive.
    link.emulator.set_packet_counter(2);
    link.push(&still(500));
    let lost: Vec<u16> = measurements(&link.take_events())
        .iter()
        .map(|m| m.lost_packets)
        .collect();
    assert_eq!(lost, [0, 0, 2]);
    assert_eq!(link.device.stats().lost_packets, 2);
    assert_eq!(link.device.stats().measurements, 3);
}

fn sample_times(options: EmulatorOptions, config: DeviceConfig, raw: &[u32]) -> Vec<u64> {
    let mut link = measuring_link(config, options);
    for &stf in raw {
        link.push(&still(stf));
    }
    measurements(&link.take_events())
        .iter()
        .map(|m| m.sample_time.unwrap())
        .collect()
}

#[test]
fn sample_time_unwraps_after_one_day_on_100_series() {
    let day = ONE_DAY_TICKS as u32;
    let got = sample_times(
        EmulatorOptions::mti_g_710(),
        DeviceConfig::default(),
        &[day - 200, day - 100, 0, 100],
    );
    let base = u64::from(day - 200);
    assert_eq!(got, [base, base + 100, base + 200, base + 300]);
}

#[test]
fn sample_time_unwraps_at_two_to_the_32_on_600_series() {
    let got = sample_times(
        EmulatorOptions::mti_630(),
        DeviceConfig::default(),
        &[u32::MAX - 49, 50, 150],
    );
    let base = u64::from(u32::MAX - 49);
    assert_eq!(got, [base, base + 100, base + 200]);
    assert!(got[2] > U32_TICKS);
}

#[test]
fn configured_wrap_overrides_the_product_code() {
    let config = DeviceConfig {
        sample_time_wrap: SampleTimeWrap::Ticks(1000),
        ..DeviceConfig::default()
    };
    let got = sample_times(EmulatorOptions::mti_630(), config, &[900, 0]);
    assert_eq!(got, [900, 1000]);
}

#[test]
fn gnss_stamped_frames_step_back_without_a_false_wrap() {
    let got = sample_times(
        EmulatorOptions::mti_g_710(),
        DeviceConfig::default(),
        &[5000, 4581, 5100],
    );
    assert_eq!(got, [5000, 4581, 5100]);
}

#[test]
fn silent_device_times_out_after_every_retry() {
    let options = EmulatorOptions {
        ignore_mid: Some(mid::REQ_PRODUCT_CODE),
        ..EmulatorOptions::mti_630()
    };
    let mut link = Link::new(DeviceConfig::default(), options);
    link.pump();
    assert!(link.events.iter().all(|e| !matches!(e, Event::Failed(_))));
    link.advance(Duration::from_secs(5));
    let error = failure(&link.events);
    assert_eq!(
        error,
        Error::Timeout {
            request: mid::REQ_PRODUCT_CODE,
            attempts: 3
        }
    );
    assert_eq!(link.device.stats().retries, 2);
    let requests = link
        .host_sent
        .windows(5)
        .filter(|w| *w == [0xFA, 0xFF, 0x1C, 0x00, 0xE5])
        .count();
    assert_eq!(requests, 3);
    assert_eq!(link.device.poll_timeout(), None);
    assert_eq!(
        error.to_string(),
        "xbus device did not acknowledge ReqProductCode after 3 tries: check the port, baud rate and power"
    );
}

#[test]
fn a_reply_lost_once_is_recovered_by_a_retry() {
    let mut link = Link::new(DeviceConfig::default(), EmulatorOptions::mti_630());
    // The first GoToConfig is lost on the wire.
    let lost = link.device.poll_transmit(link.now).unwrap();
    assert_eq!(lost, [0xFA, 0xFF, 0x30, 0x00, 0xD1]);
    link.pump();
    assert!(!link.device.is_measuring());
    link.advance(Duration::from_millis(600));
    assert!(link.device.is_measuring(), "{:?}", link.events);
    assert_eq!(link.device.stats().retries, 1);
}

#[test]
fn device_error_reply_fails_the_handshake() {
    let options = EmulatorOptions {
        reject: Some((mid::SET_OUTPUT_CONFIGURATION, 33)),
        ..EmulatorOptions::mti_630()
    };
    let mut link = Link::new(DeviceConfig::default(), options);
    link.pump();
    let error = failure(&link.events);
    assert_eq!(
        error,
        Error::Rejected {
            request: mid::SET_OUTPUT_CONFIGURATION,
            code: ErrorCode(33)
        }
    );
    assert!(!link.emulator.is_measuring());
    assert!(!error.to_string().contains('\n'));
}

#[test]
fn acknowledgement_that_does_not_echo_the_request_is_an_error() {
    let options = EmulatorOptions {
        max_output_rate: 50,
        ..EmulatorOptions::mti_g_710()
    };
    let config = DeviceConfig {
        rate_hz: 100,
        ..DeviceConfig::default()
    };
    let mut link = Link::new(config, options);
    link.pump();
    let Error::ConfigurationNotApplied { requested, applied } = failure(&link.events) else {
        panic!("{:?}", link.events)
    };
    assert_eq!(requested, config.output_configuration());
    assert_eq!(applied.entries()[3].frequency, 50);
    // The acknowledgement is reported once, as data, before the failure it causes.
    let acknowledgements: Vec<&Event> = link
        .events
        .iter()
        .filter(|e| matches!(e, Event::OutputConfiguration(_)))
        .collect();
    assert_eq!(acknowledgements, [&Event::OutputConfiguration(applied)]);
    assert!(!link.device.is_measuring());
    assert!(!link.emulator.is_measuring());
}

#[test]
fn device_already_measuring_is_brought_back_to_config() {
    let stale =
        OutputConfiguration::from_payload(&[0x10, 0x20, 0xFF, 0xFF, 0x40, 0x20, 0x00, 0x64])
            .unwrap();
    let options = EmulatorOptions {
        start_in_measurement: true,
        initial_output: stale,
        ..EmulatorOptions::mti_630()
    };
    let mut link = Link::new(DeviceConfig::default(), options);
    // Stale-configuration data is already on the wire before GoToConfig arrives.
    for stf in [10, 20, 30] {
        assert!(link.emulator.push_sample(&still(stf)));
    }
    link.emulator.set_packet_counter(7);
    link.pump();
    assert!(link.device.is_measuring(), "{:?}", link.events);
    // Measurements before the handshake are data like any other.
    let early = measurements(&link.events);
    let counters: Vec<Option<u16>> = early.iter().map(|m| m.data.packet_counter).collect();
    assert_eq!(counters, [Some(0), Some(1), Some(2)]);
    assert!(early.iter().all(|m| m.lost_packets == 0));
    assert_eq!(link.device.stats().ignored_frames, 0);
    // After GoToMeasurementAck the packet counter is counted afresh: no loss from 2 to 7.
    link.push(&still(40));
    let events = link.take_events();
    assert_receiver_agrees(&link);
    let after = measurements(&events);
    assert_eq!(after.len(), 4);
    assert_eq!(
        (after[3].data.packet_counter, after[3].lost_packets),
        (Some(7), 0)
    );
}

#[test]
fn wake_up_is_acknowledged_and_handshake_completes() {
    let options = EmulatorOptions {
        send_wake_up: true,
        ..EmulatorOptions::mti_g_710()
    };
    let mut link = Link::new(DeviceConfig::default(), options);
    link.pump();
    assert_eq!(link.events[0], Event::WakeUp);
    assert!(link
        .host_sent
        .windows(5)
        .any(|w| w == [0xFA, 0xFF, 0x3F, 0x00, 0xC2]));
    assert!(link.device.is_measuring(), "{:?}", link.events);
}

#[test]
fn power_cycle_in_measurement_restarts_the_handshake() {
    let mut link = measuring_link(DeviceConfig::default(), EmulatorOptions::mti_630());
    link.emulator.power_cycle();
    link.pump();
    let events = link.take_events();
    assert_eq!(events[0], Event::WakeUp);
    assert_eq!(events.last(), Some(&Event::Measuring));
    link.push(&still(1));
    assert_eq!(measurements(&link.take_events()).len(), 1);
    assert_receiver_agrees(&link);
}

#[test]
fn unsolicited_device_error_is_reported_without_stopping() {
    let mut link = measuring_link(DeviceConfig::default(), EmulatorOptions::mti_630());
    link.emulator.send_error(41);
    link.pump();
    assert_eq!(link.take_events(), [Event::DeviceError(ErrorCode(41))]);
    assert!(link.device.is_measuring());
    assert_eq!(
        ErrorCode(41).to_string(),
        "41 (data overflow, the baud rate is too low for the output)"
    );
}

#[test]
fn silence_in_measurement_is_reported_each_period() {
    let mut link = measuring_link(DeviceConfig::default(), EmulatorOptions::mti_630());
    link.advance(Duration::from_millis(2500));
    let timeouts = link
        .events
        .iter()
        .filter(|e| matches!(e, Event::DataTimeout { .. }))
        .count();
    assert_eq!(timeouts, 2);
    link.push(&still(1));
    assert_eq!(measurements(&link.take_events()).len(), 1);
}

#[test]
fn restart_after_failure_recovers() {
    let options = EmulatorOptions {
        ignore_mid: Some(mid::REQ_DID),
        ..EmulatorOptions::mti_630()
    };
    let mut link = Link::new(DeviceConfig::default(), options);
    link.pump();
    link.advance(Duration::from_secs(5));
    failure(&link.events);
    link.emulator = xbus::emulator::Emulator::new(EmulatorOptions::mti_630());
    link.device.restart(link.now);
    link.pump();
    assert!(link.device.is_measuring());
}
