//! A device that answers the configuration messages and streams MTData2 built from samples the
//! caller supplies. Sans-IO like the host side: bytes in, bytes out, no clock.
//!
//! The 500 ms WakeUp rule is not emulated (there is no clock): after WakeUp the emulator stays
//! in config until told GoToMeasurement.

use crate::command::{OutputConfiguration, EVERY_PACKET};
use crate::data_id::DataType;
use crate::frame::{encode_frame, mid, Framer, DEFAULT_MAX_PAYLOAD};
use crate::mtdata2::{encode_floats, encode_raw, encode_u32, UtcTime};

/// How the emulated device identifies itself and which faults it shows.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EmulatorOptions {
    pub product_code: String,
    pub device_id: u32,
    pub firmware: [u8; 3],
    /// Send WakeUp first, as a device does at power-up.
    pub send_wake_up: bool,
    /// Start streaming `initial_output` right away (a device left in measurement).
    pub start_in_measurement: bool,
    pub initial_output: OutputConfiguration,
    /// Frequencies above this are lowered to it (0xFFFF "every packet" entries are kept), so the
    /// acknowledgement then differs from the request, as on a real device.
    pub max_output_rate: u16,
    /// Never answer this MID (to exercise timeouts).
    pub ignore_mid: Option<u8>,
    /// Answer this MID with Error(code).
    pub reject: Option<(u8, u8)>,
}

impl EmulatorOptions {
    /// A 100-series MTi-G-710 (SampleTimeFine wraps after one day).
    pub fn mti_g_710() -> Self {
        Self::with_identity("MTi-G-710-2A5G4", 0x0370_0C6E, [1, 8, 2])
    }

    /// A 600-series MTi-630 (SampleTimeFine wraps at 2^32).
    pub fn mti_630() -> Self {
        Self::with_identity("MTi-630", 0x0263_0A2B, [1, 12, 0])
    }

    fn with_identity(product_code: &str, device_id: u32, firmware: [u8; 3]) -> Self {
        Self {
            product_code: product_code.to_owned(),
            device_id,
            firmware,
            send_wake_up: false,
            start_in_measurement: false,
            initial_output: OutputConfiguration::default(),
            max_output_rate: 2000,
            ignore_mid: None,
            reject: None,
        }
    }
}

/// One instant of IMU truth to stream. Values are sent as given, labelled with the coordinate
/// flag of the configured identifier.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub sample_time_fine: u32,
    pub status_word: u32,
    /// m/s², gravity included.
    pub acceleration: [f64; 3],
    /// rad/s.
    pub rate_of_turn: [f64; 3],
    /// m/s over the output interval.
    pub delta_v: [f64; 3],
    /// (w, x, y, z) over the output interval.
    pub delta_q: [f64; 4],
    pub quaternion: [f64; 4],
    /// Degrees.
    pub euler_angles: [f64; 3],
    pub free_acceleration: [f64; 3],
    pub magnetic_field: [f64; 3],
    pub temperature: f64,
    pub utc_time: UtcTime,
}

impl Sample {
    /// Rates plus the increments they imply over `interval_s` (constant over the interval).
    pub fn from_rates(
        sample_time_fine: u32,
        acceleration: [f64; 3],
        rate_of_turn: [f64; 3],
        interval_s: f64,
    ) -> Self {
        let half_angle = rate_of_turn.map(|w| 0.5 * w * interval_s);
        let norm = half_angle.iter().map(|a| a * a).sum::<f64>().sqrt();
        let scale = if norm > 0.0 { norm.sin() / norm } else { 1.0 };
        Self {
            sample_time_fine,
            status_word: 0,
            acceleration,
            rate_of_turn,
            delta_v: acceleration.map(|a| a * interval_s),
            delta_q: [
                norm.cos(),
                half_angle[0] * scale,
                half_angle[1] * scale,
                half_angle[2] * scale,
            ],
            quaternion: [1.0, 0.0, 0.0, 0.0],
            euler_angles: [0.0; 3],
            free_acceleration: [0.0; 3],
            magnetic_field: [0.0; 3],
            temperature: 25.0,
            utc_time: UtcTime::default(),
        }
    }
}

impl Sample {
    /// Increments plus the mean rates they imply over `interval_s` (> 0), for recordings
    /// that hold strapdown increments.
    pub fn from_increments(
        sample_time_fine: u32,
        delta_v: [f64; 3],
        delta_q: [f64; 4],
        interval_s: f64,
    ) -> Self {
        let [w, x, y, z] = delta_q;
        let sin_half = (x * x + y * y + z * z).sqrt();
        let angle = 2.0 * sin_half.atan2(w);
        let axis_scale = if sin_half > 0.0 {
            angle / sin_half
        } else {
            2.0
        };
        let rate_of_turn = [x, y, z].map(|c| c * axis_scale / interval_s);
        Self {
            delta_v,
            delta_q,
            ..Self::from_rates(
                sample_time_fine,
                delta_v.map(|v| v / interval_s),
                rate_of_turn,
                interval_s,
            )
        }
    }
}

pub struct Emulator {
    options: EmulatorOptions,
    framer: Framer,
    measuring: bool,
    output: OutputConfiguration,
    packet_counter: u16,
    tx: Vec<u8>,
    payload: Vec<u8>,
}

impl Emulator {
    pub fn new(options: EmulatorOptions) -> Self {
        let mut emulator = Self {
            framer: Framer::new(DEFAULT_MAX_PAYLOAD),
            measuring: options.start_in_measurement,
            output: options.initial_output,
            packet_counter: 0,
            tx: Vec::with_capacity(4096),
            payload: Vec::with_capacity(1024),
            options,
        };
        if emulator.options.send_wake_up {
            emulator.reply(mid::WAKE_UP, &[]);
        }
        emulator
    }

    pub fn is_measuring(&self) -> bool {
        self.measuring
    }

    /// The configuration in force (as applied, after rate limiting).
    pub fn output_configuration(&self) -> &OutputConfiguration {
        &self.output
    }

    pub fn packet_counter(&self) -> u16 {
        self.packet_counter
    }

    /// Sets the next PacketCounter (e.g. to start near the wrap or to skip packets).
    pub fn set_packet_counter(&mut self, counter: u16) {
        self.packet_counter = counter;
    }

    /// Moves the bytes the device has sent so far to the end of `out`.
    pub fn drain_output(&mut self, out: &mut Vec<u8>) {
        out.append(&mut self.tx);
    }

    /// Sends an Error message unprompted (e.g. 41, data overflow).
    pub fn send_error(&mut self, code: u8) {
        self.reply(mid::ERROR, &[code]);
    }

    /// Sends WakeUp and returns to config, as after a power cycle.
    pub fn power_cycle(&mut self) {
        self.measuring = false;
        self.reply(mid::WAKE_UP, &[]);
    }

    /// Bytes from the host.
    pub fn handle_input(&mut self, mut bytes: &[u8]) {
        let mut request = [0u8; 256];
        while let Some(result) = self.framer.decode(&mut bytes) {
            let Ok(frame) = result else { continue };
            let (m, n) = (frame.mid, frame.payload.len().min(request.len()));
            request[..n].copy_from_slice(&frame.payload[..n]);
            self.answer(m, &request[..n]);
        }
    }

    fn answer(&mut self, m: u8, payload: &[u8]) {
        if self.options.ignore_mid == Some(m) {
            return;
        }
        if let Some((_, code)) = self.options.reject.filter(|(r, _)| *r == m) {
            return self.reply(mid::ERROR, &[code]);
        }
        match m {
            mid::GO_TO_CONFIG => {
                self.measuring = false;
                self.reply(mid::GO_TO_CONFIG_ACK, &[]);
            }
            mid::GO_TO_MEASUREMENT => {
                self.measuring = true;
                self.reply(mid::GO_TO_MEASUREMENT_ACK, &[]);
            }
            mid::REQ_DID => self.reply(mid::DEVICE_ID, &self.options.device_id.to_be_bytes()),
            mid::REQ_PRODUCT_CODE => {
                let code = self.options.product_code.clone();
                self.reply(mid::PRODUCT_CODE, code.as_bytes());
            }
            mid::REQ_FW_REV => self.reply(mid::FIRMWARE_REV, &self.options.firmware.clone()),
            mid::SET_BAUDRATE => self.reply(mid::SET_BAUDRATE_ACK, &[]),
            mid::WAKE_UP_ACK => {}
            mid::RESET => {
                self.reply(mid::RESET_ACK, &[]);
                self.power_cycle();
            }
            mid::SET_OUTPUT_CONFIGURATION => self.apply_output_configuration(payload),
            _ => self.reply(mid::ERROR, &[4]),
        }
    }

    fn apply_output_configuration(&mut self, payload: &[u8]) {
        let Ok(requested) = OutputConfiguration::from_payload(payload) else {
            return self.reply(mid::ERROR, &[33]);
        };
        let mut applied = OutputConfiguration::default();
        for &entry in requested.entries() {
            let mut entry = entry;
            if entry.frequency != EVERY_PACKET {
                entry.frequency = entry.frequency.min(self.options.max_output_rate);
            }
            // Cannot fail: no more entries than the request.
            let _ = applied.push(entry);
        }
        self.output = applied;
        let mut echo = [0u8; 128];
        for (e, slot) in applied.entries().iter().zip(echo.chunks_exact_mut(4)) {
            slot[..2].copy_from_slice(&e.id.0.to_be_bytes());
            slot[2..].copy_from_slice(&e.frequency.to_be_bytes());
        }
        self.reply(
            mid::OUTPUT_CONFIGURATION,
            &echo[..4 * applied.entries().len()],
        );
    }

    fn reply(&mut self, m: u8, payload: &[u8]) {
        // Replies are far below the 64 KiB limit.
        let _ = encode_frame(m, payload, &mut self.tx);
    }

    /// Streams one MTData2 frame for `sample` if measuring; returns whether it did. Outputs
    /// slower than the fastest configured one are included on every k-th packet.
    pub fn push_sample(&mut self, sample: &Sample) -> bool {
        if !self.measuring {
            return false;
        }
        let base_rate = self
            .output
            .entries()
            .iter()
            .filter(|e| e.frequency != EVERY_PACKET)
            .map(|e| e.frequency)
            .max()
            .unwrap_or(1)
            .max(1);
        let counter = self.packet_counter;
        let mut payload = core::mem::take(&mut self.payload);
        payload.clear();
        for entry in self.output.entries() {
            let divisor = if entry.frequency == EVERY_PACKET {
                1
            } else {
                base_rate / entry.frequency.max(1)
            };
            if counter.is_multiple_of(divisor.max(1)) {
                encode_entry(entry.id, sample, counter, &mut payload);
            }
        }
        let _ = encode_frame(mid::MT_DATA2, &payload, &mut self.tx);
        self.payload = payload;
        self.packet_counter = counter.wrapping_add(1);
        true
    }
}

fn encode_entry(id: crate::DataId, s: &Sample, counter: u16, out: &mut Vec<u8>) {
    let Some(data_type) = id.data_type() else {
        return;
    };
    match data_type {
        DataType::PacketCounter => encode_u32(data_type, u32::from(counter), out),
        DataType::SampleTimeFine => encode_u32(data_type, s.sample_time_fine, out),
        DataType::StatusWord => encode_u32(data_type, s.status_word, out),
        DataType::StatusByte => encode_u32(data_type, s.status_word & 0xFF, out),
        DataType::UtcTime => encode_raw(id, &s.utc_time.to_bytes(), out),
        DataType::Acceleration => _ = encode_floats(id, &s.acceleration, out),
        DataType::RateOfTurn => _ = encode_floats(id, &s.rate_of_turn, out),
        DataType::DeltaV => _ = encode_floats(id, &s.delta_v, out),
        DataType::DeltaQ => _ = encode_floats(id, &s.delta_q, out),
        DataType::Quaternion => _ = encode_floats(id, &s.quaternion, out),
        DataType::EulerAngles => _ = encode_floats(id, &s.euler_angles, out),
        DataType::FreeAcceleration => _ = encode_floats(id, &s.free_acceleration, out),
        DataType::MagneticField => _ = encode_floats(id, &s.magnetic_field, out),
        DataType::Temperature => _ = encode_floats(id, &[s.temperature], out),
        // Outputs the emulator has no truth for are left out, as a device without the sensor.
        _ => {}
    }
}
