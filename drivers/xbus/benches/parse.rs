//! Decoding speed of one MTData2 message, and a check that nothing allocates per message.
//!
//! `cargo bench -p xbus --bench parse`

#[path = "../tests/support/alloc.rs"]
mod alloc;

use std::time::Duration;

use divan::{black_box, Bencher};
use xbus::emulator::{Emulator, EmulatorOptions, Sample};
use xbus::{
    mid, Command, Device, DeviceConfig, Event, Framer, ImuOutput, Measurement, OutputEntry,
    Precision,
};

#[global_allocator]
static COUNTING: alloc::Counting = alloc::Counting;

/// One MTData2 frame as the daemon requests it, in the given form and precision.
fn frame(imu_output: ImuOutput, precision: Precision) -> Vec<u8> {
    let config = DeviceConfig {
        imu_output,
        precision,
        ..DeviceConfig::default()
    };
    let options = EmulatorOptions {
        start_in_measurement: true,
        initial_output: config.output_configuration(),
        ..EmulatorOptions::mti_g_710()
    };
    let mut emulator = Emulator::new(options);
    emulator.push_sample(&Sample::from_rates(
        123_456,
        [0.3, -0.2, -9.81],
        [0.01, -0.02, 0.5],
        0.01,
    ));
    let mut out = Vec::new();
    emulator.drain_output(&mut out);
    out
}

const FORMS: [(ImuOutput, Precision); 3] = [
    (ImuOutput::Increments, Precision::Float32),
    (ImuOutput::Rates, Precision::Fp1220),
    (ImuOutput::Increments, Precision::Float64),
];

#[divan::bench(args = FORMS)]
fn mtdata2_payload_to_measurement(bencher: Bencher, form: (ImuOutput, Precision)) {
    let wire = frame(form.0, form.1);
    let payload = &wire[4..wire.len() - 1];
    bencher.bench(|| Measurement::from_payload(black_box(payload)).unwrap());
}

#[divan::bench(args = FORMS)]
fn bytes_to_frame_to_measurement(bencher: Bencher, form: (ImuOutput, Precision)) {
    let wire = frame(form.0, form.1);
    let mut framer = Framer::new(xbus::DEFAULT_MAX_PAYLOAD);
    bencher.bench_local(|| {
        let mut input = black_box(&wire[..]);
        let f = framer.decode(&mut input).unwrap().unwrap();
        Measurement::from_payload(f.payload).unwrap()
    });
}

#[divan::bench]
fn device_handle_input_one_message(bencher: Bencher) {
    let mut device = measuring_device();
    let wire = frame(ImuOutput::Increments, Precision::Float32);
    bencher.bench_local(|| {
        device.handle_input(Duration::from_secs(1), black_box(&wire));
        device.poll_event().unwrap()
    });
}

/// A host device taken through the handshake by an emulator.
fn measuring_device() -> Device {
    let mut device = Device::new(DeviceConfig::default(), Duration::ZERO);
    let mut emulator = Emulator::new(EmulatorOptions::mti_g_710());
    let mut bytes = Vec::new();
    for _ in 0..10 {
        while let Some(t) = device.poll_transmit(Duration::ZERO) {
            emulator.handle_input(t);
        }
        emulator.drain_output(&mut bytes);
        device.handle_input(Duration::ZERO, &bytes);
        bytes.clear();
    }
    while device.poll_event().is_some() {}
    assert!(device.is_measuring());
    device
}

/// Steady state must not allocate: decode 10 000 messages after a warm-up and count.
fn assert_no_allocation_per_message() {
    let mut device = measuring_device();
    let wire = frame(ImuOutput::Increments, Precision::Float32);
    let mut out = Vec::with_capacity(256);
    let mut decode = |n: u32| {
        for i in 0..n {
            device.handle_input(Duration::from_millis(u64::from(i)), &wire);
            assert!(matches!(device.poll_event(), Some(Event::Measurement(_))));
        }
        out.clear();
        let entry = OutputEntry {
            id: xbus::DataId(0x1020),
            frequency: 1,
        };
        let c = xbus::OutputConfiguration::new(&[entry]).unwrap();
        black_box(Command::SetOutputConfiguration(c).to_frame());
        Command::GoToConfig.encode(&mut out);
        assert_eq!(out[2], mid::GO_TO_CONFIG);
    };
    decode(100);
    let before = alloc::allocations();
    decode(10_000);
    let per_message = (alloc::allocations() - before) as f64 / 10_000.0;
    println!("allocations per message after warm-up: {per_message}");
    assert_eq!(per_message, 0.0);
}

fn main() {
    assert_no_allocation_per_message();
    divan::main();
}
