//! Arbitrary bytes and timeouts into the device state machine, in config and in measurement.
#![no_main]

use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use xbus::emulator::{Emulator, EmulatorOptions};
use xbus::{Device, DeviceConfig};

fuzz_target!(|data: &[u8]| {
    let mut device = Device::new(DeviceConfig::default(), Duration::ZERO);
    if data.first().is_some_and(|b| b & 1 == 1) {
        // Bring it to measurement first so the MTData2 path is exercised.
        let mut emulator = Emulator::new(EmulatorOptions::mti_630());
        let mut bytes = Vec::new();
        for _ in 0..10 {
            while let Some(t) = device.poll_transmit() {
                emulator.handle_input(t.as_bytes());
            }
            emulator.drain_output(&mut bytes);
            device.handle_input(Duration::ZERO, &bytes);
            bytes.clear();
        }
        assert!(device.is_measuring());
    }
    for (i, chunk) in data.chunks(29).enumerate() {
        let now = Duration::from_millis(100 * i as u64);
        device.handle_input(now, chunk);
        device.handle_timeout(now);
        while device.poll_event().is_some() {}
        while device.poll_transmit().is_some() {}
    }
});
