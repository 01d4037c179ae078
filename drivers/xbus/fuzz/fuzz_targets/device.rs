//! Arbitrary bytes and timeouts into the device state machine, in config and in measurement; a
//! bare receiver fed the same bytes must emit the same data events.
#![no_main]

use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use xbus::emulator::{Emulator, EmulatorOptions};
use xbus::{Device, DeviceConfig, Event, Receiver};


fuzz_target!(|data: &[u8]| {
    let config = DeviceConfig::default();
    let mut device = Device::new(config, Duration::ZERO);
    let mut receiver = Receiver::new(config.sample_time_wrap, config.max_payload);
    if data.first().is_some_and(|b| b & 1 == 1) {
        // Bring it to measurement first so the MTData2 path is exercised.
        let mut emulator = Emulator::new(EmulatorOptions::mti_630());
        let mut bytes = Vec::new();
        for _ in 0..10 {
            while let Some(t) = device.poll_transmit(Duration::ZERO) {
                emulator.handle_input(t);
            }
            emulator.drain_output(&mut bytes);
            device.handle_input(Duration::ZERO, &bytes);
            receiver.handle_input(Duration::ZERO, &bytes);
            bytes.clear();
        }
        assert!(device.is_measuring());
    }
    for (i, chunk) in data.chunks(29).enumerate() {
        let now = Duration::from_millis(100 * i as u64);
        device.handle_input(now, chunk);
        receiver.handle_input(now, chunk);
        device.handle_timeout(now);
        let live: Vec<Event> = std::iter::from_fn(|| device.poll_event())
            .filter(Event::is_data)
            .collect();
        let replayed: Vec<Event> = std::iter::from_fn(|| receiver.poll_event()).collect();
        assert_eq!(live, replayed);
        while device.poll_transmit(now).is_some() {}
    }
});
