#![no_main]
//! The device state machine fed arbitrary sensor bytes and timeouts must never panic, and a bare
//! receiver fed the same bytes must emit the same data events.

use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use scip::{Device, DeviceConfig, Event, Receiver};


fuzz_target!(|data: &[u8]| {
    let mut now = Duration::from_millis(1);
    let mut device = Device::new(DeviceConfig::default(), now);
    let mut receiver = Receiver::new();
    for piece in data.split(|&b| b == 0xFF) {
        while device.poll_transmit(now).is_some() {}
        device.handle_input(now, piece);
        receiver.handle_input(now, piece);
        let from_device: Vec<Event> = std::iter::from_fn(|| device.poll_event())
            .filter(Event::is_data)
            .collect();
        let from_receiver: Vec<Event> = std::iter::from_fn(|| receiver.poll_event()).collect();
        assert_eq!(from_device, from_receiver);
        now += Duration::from_millis(300);
        if device.poll_timeout().is_some_and(|t| t <= now) {
            device.handle_timeout(now);
        }
    }
});
