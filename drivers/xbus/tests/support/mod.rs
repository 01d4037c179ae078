//! A host `Device` wired to an `Emulator`, with a manual clock.
// Each test binary that includes this module uses only part of it.
#![allow(dead_code)]

use std::time::Duration;

use xbus::emulator::{Emulator, EmulatorOptions, Sample};
use xbus::{Device, DeviceConfig, Event, Receiver};

pub struct Link {
    pub device: Device,
    pub emulator: Emulator,
    pub now: Duration,
    pub events: Vec<Event>,
    /// Every event, including those taken.
    pub log: Vec<Event>,
    /// Every byte the host wrote, for checking what was sent.
    pub host_sent: Vec<u8>,
    /// Every `handle_input` call the device got, for replaying into a bare receiver.
    pub received: Vec<(Duration, Vec<u8>)>,
}

impl Link {
    pub fn new(config: DeviceConfig, options: EmulatorOptions) -> Self {
        let now = Duration::from_secs(10);
        Self {
            device: Device::new(config, now),
            emulator: Emulator::new(options),
            now,
            events: Vec::new(),
            log: Vec::new(),
            host_sent: Vec::new(),
            received: Vec::new(),
        }
    }

    /// Feeds the device bytes from the emulator's side of the wire.
    pub fn input(&mut self, bytes: &[u8]) {
        self.device.handle_input(self.now, bytes);
        self.received.push((self.now, bytes.to_vec()));
    }

    /// Exchanges bytes until neither side has anything to say.
    pub fn pump(&mut self) {
        loop {
            let mut moved = false;
            while let Some(frame) = self.device.poll_transmit(self.now) {
                self.host_sent.extend_from_slice(frame);
                self.emulator.handle_input(frame);
                moved = true;
            }
            let mut from_device = Vec::new();
            self.emulator.drain_output(&mut from_device);
            if !from_device.is_empty() {
                self.input(&from_device);
                moved = true;
            }
            while let Some(e) = self.device.poll_event() {
                self.events.push(e);
                self.log.push(e);
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

/// A bare receiver fed what the device was fed emits the device's data events, in order.
pub fn assert_receiver_agrees(link: &Link) {
    let config = link.device.config();
    let mut receiver = Receiver::new(config.sample_time_wrap, config.max_payload);
    let mut replayed = Vec::new();
    for (now, bytes) in &link.received {
        receiver.handle_input(*now, bytes);
        replayed.extend(std::iter::from_fn(|| receiver.poll_event()));
    }
    let live: Vec<Event> = link.log.iter().copied().filter(Event::is_data).collect();
    assert!(!live.is_empty());
    assert_eq!(live, replayed);
    let (device, receiver) = (link.device.stats(), receiver.stats());
    assert_eq!(
        (
            device.framer,
            device.measurements,
            device.lost_packets,
            device.bad_measurements
        ),
        (
            receiver.framer,
            receiver.measurements,
            receiver.lost_packets,
            receiver.bad_measurements
        )
    );
}

pub fn measuring_link(config: DeviceConfig, options: EmulatorOptions) -> Link {
    let mut link = Link::new(config, options);
    link.pump();
    assert!(link.device.is_measuring(), "{:?}", link.events);
    link.take_events();
    link
}
