#![no_main]
//! The device state machine fed arbitrary sensor bytes and timeouts must never panic.

use libfuzzer_sys::fuzz_target;
use scip::{Device, DeviceConfig};

fuzz_target!(|data: &[u8]| {
    let mut device = Device::new(DeviceConfig::default());
    device.start();
    let mut now = 0.0;
    for piece in data.split(|&b| b == 0xFF) {
        while device.poll_transmit(now).is_some() {}
        device.handle_input(now, piece);
        while let Some(event) = device.poll_event() {
            if let scip::DeviceEvent::Scan(scan) = event {
                device.recycle(scan);
            }
        }
        now += 0.3;
        if device.poll_timeout().is_some_and(|t| t <= now) {
            device.handle_timeout(now);
        }
    }
});
