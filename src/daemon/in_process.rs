//! A host-side driver and its device emulator wired back to back in memory, on a simulated
//! clock: what `simulate` records and what the tests replay. Every chunk one side writes is
//! handed to the other at the same simulated instant and reported with the direction a live
//! sensor task would record it under, so a simulated recording has exactly the shape of a live
//! one.

use super::recording::Direction;
use std::time::Duration;

/// One chunk exchanged with a device: direction, host time in ns, bytes.
pub(crate) type Exchanged = (Direction, u64, Vec<u8>);

/// A SCIP host driver against an emulated scanner whose millisecond clock runs
/// `device_offset_ms` ahead of the host clock.
#[derive(Debug)]
pub(crate) struct ScipRig {
    pub device: scip::Device,
    pub emulator: scip::Emulator,
    device_offset_ms: u32,
    scratch: Vec<u8>,
}

impl ScipRig {
    pub(crate) fn new(
        model: scip::Model,
        config: scip::DeviceConfig,
        device_offset_ms: u32,
    ) -> Self {
        Self {
            device: scip::Device::new(config, Duration::ZERO),
            emulator: scip::Emulator::new(model),
            device_offset_ms,
            scratch: Vec::new(),
        }
    }

    /// The scanner's clock reading at host time `host_ns`.
    pub(crate) fn device_ms(&self, host_ns: u64) -> u32 {
        let host_ms = (host_ns / 1_000_000) as u32;
        host_ms.wrapping_add(self.device_offset_ms) & 0xFF_FFFF
    }

    /// Runs both sides at host time `now_ns` until neither has anything more to say.
    pub(crate) fn exchange(&mut self, now_ns: u64, out: &mut Vec<Exchanged>) {
        let now = Duration::from_nanos(now_ns);
        self.emulator.set_clock(self.device_ms(now_ns));
        self.device.handle_timeout(now);
        loop {
            let mut quiet = true;
            if let Some(bytes) = self.device.poll_transmit(now) {
                let bytes = bytes.to_vec();
                self.emulator.handle_input(&bytes);
                out.push((Direction::Tx, now_ns, bytes));
                quiet = false;
            }
            self.scratch.clear();
            self.emulator.drain_output(&mut self.scratch);
            if !self.scratch.is_empty() {
                self.device.handle_input(now, &self.scratch);
                out.push((Direction::Rx, now_ns, self.scratch.clone()));
                quiet = false;
            }
            while self.device.poll_event().is_some() {}
            if quiet {
                return;
            }
        }
    }

    /// Hands the emulator the revolution whose step 0 was measured at host time `step0_ns`;
    /// a stream sends it at the next [`ScipRig::exchange`].
    pub(crate) fn push_scan(
        &mut self,
        step0_ns: u64,
        ranges_mm: &[u32],
    ) -> Result<(), scip::ScanLengthError> {
        self.emulator
            .push_scan(self.device_ms(step0_ns), ranges_mm, None)
    }

    pub(crate) fn is_streaming(&self) -> bool {
        self.device.phase() == scip::Phase::Streaming
    }
}

/// An Xbus host driver against an emulated MTi.
pub(crate) struct XbusRig {
    pub device: xbus::Device,
    pub emulator: xbus::emulator::Emulator,
    scratch: Vec<u8>,
}

impl XbusRig {
    pub(crate) fn new(
        options: xbus::emulator::EmulatorOptions,
        config: xbus::DeviceConfig,
    ) -> Self {
        Self {
            device: xbus::Device::new(config, Duration::ZERO),
            emulator: xbus::emulator::Emulator::new(options),
            scratch: Vec::new(),
        }
    }

    pub(crate) fn exchange(&mut self, now_ns: u64, out: &mut Vec<Exchanged>) {
        let now = Duration::from_nanos(now_ns);
        if self.device.poll_timeout().is_some_and(|t| t <= now) {
            self.device.handle_timeout(now);
        }
        loop {
            let mut quiet = true;
            while let Some(bytes) = self.device.poll_transmit(now) {
                let bytes = bytes.to_vec();
                self.emulator.handle_input(&bytes);
                out.push((Direction::Tx, now_ns, bytes));
                quiet = false;
            }
            self.scratch.clear();
            self.emulator.drain_output(&mut self.scratch);
            if !self.scratch.is_empty() {
                self.device.handle_input(now, &self.scratch);
                out.push((Direction::Rx, now_ns, self.scratch.clone()));
                quiet = false;
            }
            while self.device.poll_event().is_some() {}
            if quiet {
                return;
            }
        }
    }

    /// Streams `sample` if the device is measuring; it is read at the next exchange.
    pub(crate) fn push_sample(&mut self, sample: &xbus::emulator::Sample) -> bool {
        self.emulator.push_sample(sample)
    }

    pub(crate) fn is_measuring(&self) -> bool {
        self.device.is_measuring()
    }
}
