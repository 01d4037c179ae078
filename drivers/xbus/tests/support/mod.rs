//! A host `Device` wired to an `Emulator`, with a manual clock.
// Each test binary that includes this module uses only part of it.
#![allow(dead_code)]

use std::time::Duration;

use xbus::emulator::{Emulator, EmulatorOptions, Sample};
use xbus::{Device, DeviceConfig, Event};

pub struct Link {
    pub device: Device,
    pub emulator: Emulator,
    pub now: Duration,
    pub events: Vec<Event>,
    /// Every byte the host wrote, for checking what was sent.
    pub host_sent: Vec<u8>,
}

impl Link {
    pub fn new(config: DeviceConfig, options: EmulatorOptions) -> Self {
        let now = Duration::from_secs(10);
        Self {
            device: Device::new(config, now),
            emulator: Emulator::new(options),
            now,
            events: Vec::new(),
            host_sent: Vec::new(),
        }
    }

    /// Exchanges bytes until neither side has anything to say.
    pub fn pump(&mut self) {
        loop {
            let mut moved = false;
            while let Some(frame) = self.device.poll_transmit() {
                self.host_sent.extend_from_slice(frame.as_bytes());
                self.emulator.handle_input(frame.as_bytes());
                moved = true;
            }
            let mut from_device = Vec::new();
            self.emulator.drain_output(&mut from_device);
            if !from_device.is_empty() {
                self.device.handle_input(self.now, &from_device);
                moved = true;
            }
            while let Some(e) = self.device.poll_event() {
                self.events.push(e);
            }
            if !moved {
                return;
            }
        }
    }

    /// Lets time pass in steps, firing due timeouts.
    pub fn advance(&mut self, by: Duration) {
        let until = self.now + by;
        while let Some(deadline) = self.device.poll_timeout().filter(|d| *d <= until) {
            self.now = self.now.max(deadline);
            self.device.handle_timeout(self.now);
            self.pump();
        }
        self.now = until;
    }

    pub fn push(&mut self, sample: &Sample) {
        self.now += Duration::from_millis(10);
        assert!(self.emulator.push_sample(sample));
        self.pump();
    }

    pub fn take_events(&mut self) -> Vec<Event> {
        std::mem::take(&mut self.events)
    }
}

pub fn measuring_link(config: DeviceConfig, options: EmulatorOptions) -> Link {
    let mut link = Link::new(config, options);
    link.pump();
    assert!(link.device.is_measuring(), "{:?}", link.events);
    link.take_events();
    link
}
