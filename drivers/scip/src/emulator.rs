//! A SCIP 2.0 sensor on the other side of the wire, fed with scans and a clock by its owner. Tests
//! and `serve-emulators` use it; it answers like the real sensors in docs/protocols.md, 1.6
//! "Commands and statuses".

use std::fmt;

use crate::command::{DataKind, StepRange};
use crate::encoding::{encode_value, push_data_blocks, push_summed_line};
use crate::params::{Parameters, Version};

/// What the emulated sensor reports about itself. Only the PP values of the presets are sourced
/// (docs/protocols.md, 1.8 "Model parameters"); their VV strings are plausible placeholders.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Model {
    pub version: Version,
    pub parameters: Parameters,
}

impl Model {
    fn new(vendor: &str, product: &str, firmware: &str, parameters: Parameters) -> Model {
        Model {
            version: Version {
                vendor: vendor.into(),
                product: product.into(),
                firmware: firmware.into(),
                protocol: "SCIP 2.0".into(),
                serial: "H0000001".into(),
            },
            parameters,
        }
    }

    /// URG-04LX, values from the SCIP 2.0 specification's PP example.
    pub fn urg_04lx() -> Model {
        Model::new(
            "Hokuyo Automatic Co.,Ltd.",
            "SOKUIKI Sensor URG-04LX",
            "3.2.00(28/Aug./2007)",
            Parameters {
                model: "URG-04LX(Hokuyo Automatic Co.,Ltd.)".into(),
                min_distance_mm: 20,
                max_distance_mm: 5600,
                angular_resolution: 1024,
                first_step: 44,
                last_step: 725,
                front_step: 384,
                scan_rpm: 600,
            },
        )
    }

    /// UTM-30LX, with the PP values of a real UTM-30LX-EW reply.
    pub fn utm_30lx() -> Model {
        Model::new(
            "Hokuyo Automatic Co.,Ltd.",
            "SOKUIKI Sensor TOP-URG UTM-30LX",
            "1.1.0",
            Parameters {
                model: "UTM-30LX".into(),
                min_distance_mm: 23,
                max_distance_mm: 60000,
                angular_resolution: 1440,
                first_step: 0,
                last_step: 1080,
                front_step: 540,
                scan_rpm: 2400,
            },
        )
    }

    /// UST-20LX; DMIN/DMAX are datasheet values (docs/protocols.md, 1.8 "Model parameters", marks
    /// them unconfirmed).
    pub fn ust_20lx() -> Model {
        Model::new(
            "Hokuyo Automatic Co.,Ltd.",
            "SOKUIKI Sensor UST-20LX",
            "1.0.0",
            Parameters {
                model: "UST-20LX".into(),
                min_distance_mm: 20,
                max_distance_mm: 20000,
                angular_resolution: 1440,
                first_step: 0,
                last_step: 1080,
                front_step: 540,
                scan_rpm: 2400,
            },
        )
    }

    /// Steps a pushed scan must cover: AMIN..=AMAX.
    pub fn step_count(&self) -> usize {
        usize::from(self.parameters.last_step - self.parameters.first_step) + 1
    }
}

/// A pushed scan that does not match the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScanLengthError {
    pub expected: usize,
    pub got: usize,
}

impl fmt::Display for ScanLengthError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "emulated scan has {} values but the model has {} steps (AMIN..=AMAX): supply one value per step", self.got, self.expected)
    }
}

impl std::error::Error for ScanLengthError {}

#[derive(Debug, Clone)]
struct ActiveStream {
    data: DataKind,
    range: StepRange,
    interval: u8,
    /// `None` streams until QT.
    remaining: Option<u8>,
    skipped: u8,
    tag: Vec<u8>,
}

/// Longest command line accepted; longer input is dropped as garbage.
const MAX_COMMAND: usize = 64;

/// Emulated SCIP 2.0 sensor.
#[derive(Debug, Clone)]
pub struct Emulator {
    model: Model,
    line: Vec<u8>,
    output: Vec<u8>,
    clock_ms: u32,
    clock_zero: u32,
    laser_on: bool,
    scip11: bool,
    time_adjust: bool,
    stream: Option<ActiveStream>,
    scan_time: u32,
    ranges: Vec<u32>,
    intensities: Vec<u32>,
    scratch: Vec<u8>,
}

impl Emulator {
    pub fn new(model: Model) -> Self {
        let steps = model.step_count();
        Emulator {
            model,
            line: Vec::with_capacity(MAX_COMMAND),
            output: Vec::new(),
            clock_ms: 0,
            clock_zero: 0,
            laser_on: false,
            scip11: false,
            time_adjust: false,
            stream: None,
            scan_time: 0,
            ranges: vec![0; steps],
            intensities: vec![0; steps],
            scratch: Vec::new(),
        }
    }

    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Boot in SCIP 1.1, as old URG-04LX firmware does.
    pub fn boot_in_scip11(&mut self) {
        self.scip11 = true;
    }

    /// Start in TM adjust mode, as a host that died mid-sync leaves it.
    pub fn enter_time_adjust_mode(&mut self) {
        self.time_adjust = true;
        self.laser_on = false;
    }

    /// Sets the device clock (milliseconds since power-up); TM1 reports it.
    pub fn set_clock(&mut self, device_ms: u32) {
        self.clock_ms = device_ms;
    }

    pub fn is_streaming(&self) -> bool {
        self.stream.is_some()
    }

    pub fn is_laser_on(&self) -> bool {
        self.laser_on
    }

    /// Bytes the sensor has sent since the last call, appended to `out`.
    pub fn drain_output(&mut self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.output);
        self.output.clear();
    }

    /// Supplies the next measured revolution (one value per step AMIN..=AMAX, sensor time of
    /// step 0 in ms). Streams transmit it, GD answers from the latest one.
    pub fn push_scan(
        &mut self,
        timestamp_ms: u32,
        ranges_mm: &[u32],
        intensities: Option<&[u32]>,
    ) -> Result<(), ScanLengthError> {
        let expected = self.model.step_count();
        for got in [Some(ranges_mm.len()), intensities.map(<[u32]>::len)]
            .into_iter()
            .flatten()
        {
            if got != expected {
                return Err(ScanLengthError { expected, got });
            }
        }
        self.scan_time = timestamp_ms.wrapping_sub(self.clock_zero) & 0xFF_FFFF;
        self.ranges.copy_from_slice(ranges_mm);
        match intensities {
            Some(values) => self.intensities.copy_from_slice(values),
            None => self.intensities.fill(0),
        }
        self.transmit_stream_scan();
        Ok(())
    }

    /// Feeds bytes the host wrote.
    pub fn handle_input(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            match byte {
                b'\n' | b'\r' => {
                    if !self.line.is_empty() {
                        let line = std::mem::take(&mut self.line);
                        self.execute(&line);
                        self.line = line;
                        self.line.clear();
                    }
                }
                _ if self.line.len() >= MAX_COMMAND => self.line.clear(),
                _ => self.line.push(byte),
            }
        }
    }

    fn reply_status(&mut self, echo: &[u8], status: &[u8; 2]) {
        self.output.extend_from_slice(echo);
        self.output.push(b'\n');
        push_summed_line(status, &mut self.output);
        self.output.push(b'\n');
    }

    fn execute(&mut self, line: &[u8]) {
        if self.scip11 {
            return self.execute_scip11(line);
        }
        let (command, tag) = match line.iter().position(|&b| b == b';') {
            Some(i) => (&line[..i], &line[i + 1..]),
            None => (line, &line[line.len()..]),
        };
        if tag.len() > 16 {
            return self.reply_status(line, b"0G");
        }
        if self.time_adjust && !command.starts_with(b"TM") {
            return self.reply_status(line, b"0E");
        }
        match command {
            b"VV" | b"PP" | b"II" => self.reply_info(line, command),
            b"BM" => {
                let status = if self.laser_on { b"02" } else { b"00" };
                self.laser_on = true;
                self.reply_status(line, status);
            }
            b"QT" => {
                self.stream = None;
                self.laser_on = false;
                self.reply_status(line, b"00");
            }
            b"RS" => {
                self.stream = None;
                self.laser_on = false;
                self.clock_zero = self.clock_ms;
                self.reply_status(line, b"00");
            }
            b"TM0" => {
                let status = if self.time_adjust { b"02" } else { b"00" };
                self.time_adjust = true;
                self.stream = None;
                self.laser_on = false;
                self.reply_status(line, status);
            }
            b"TM1" if self.time_adjust => {
                self.reply_status(line, b"00");
                self.output.truncate(self.output.len() - 1);
                self.push_timestamp(self.clock_ms.wrapping_sub(self.clock_zero));
                self.output.push(b'\n');
            }
            b"TM1" => self.reply_status(line, b"04"),
            b"TM2" => {
                let status = if self.time_adjust { b"00" } else { b"03" };
                self.time_adjust = false;
                self.reply_status(line, status);
            }
            [b'G', letter, ..] if DataKind::from_letter(*letter).is_some() => {
                self.execute_get(line, command)
            }
            [b'M', letter, ..] if DataKind::from_letter(*letter).is_some() => {
                self.execute_stream(line, command, tag)
            }
            _ => self.reply_status(line, b"0E"),
        }
    }

    fn execute_scip11(&mut self, line: &[u8]) {
        self.output.extend_from_slice(line);
        if line == b"SCIP2.0" {
            self.scip11 = false;
            self.output.extend_from_slice(b"\n0\n\n");
        } else {
            self.output.extend_from_slice(b"\nE\n\n");
        }
    }

    fn reply_info(&mut self, echo: &[u8], command: &[u8]) {
        let v = &self.model.version;
        let p = &self.model.parameters;
        let lines: Vec<(&str, String)> = match command {
            b"VV" => vec![
                ("VEND", v.vendor.clone()),
                ("PROD", v.product.clone()),
                ("FIRM", v.firmware.clone()),
                ("PROT", v.protocol.clone()),
                ("SERI", v.serial.clone()),
            ],
            b"PP" => vec![
                ("MODL", p.model.clone()),
                ("DMIN", p.min_distance_mm.to_string()),
                ("DMAX", p.max_distance_mm.to_string()),
                ("ARES", p.angular_resolution.to_string()),
                ("AMIN", p.first_step.to_string()),
                ("AMAX", p.last_step.to_string()),
                ("AFRT", p.front_step.to_string()),
                ("SCAN", p.scan_rpm.to_string()),
            ],
            _ => vec![
                ("MODL", p.model.clone()),
                ("LASR", if self.laser_on { "ON" } else { "OFF" }.into()),
                ("SCSP", format!("{}[rpm]", p.scan_rpm)),
                ("MESM", "Measuring by Normal Mode".into()),
                ("SBPS", "USB only".into()),
                (
                    "TIME",
                    format!(
                        "{:06X}",
                        self.clock_ms.wrapping_sub(self.clock_zero) & 0xFF_FFFF
                    ),
                ),
                ("STAT", "Sensor works well.".into()),
            ],
        };
        self.output.extend_from_slice(echo);
        self.output.extend_from_slice(b"\n00P\n");
        for (key, value) in lines {
            // The sum excludes the ';', the variant the spec's examples use (docs/protocols.md, 1.4
            // "Line sum").
            let content = format!("{key}:{value}");
            self.output.extend_from_slice(content.as_bytes());
            self.output.push(b';');
            self.output
                .push(crate::encoding::checksum(content.as_bytes()));
            self.output.push(b'\n');
        }
        self.output.push(b'\n');
    }

    /// Parses and range-checks GD/MD step fields, returning the SCIP error status on failure.
    fn parse_range(&self, command: &[u8]) -> Result<StepRange, &'static [u8; 2]> {
        let start = digits(&command[2..6]).ok_or(b"01")?;
        let end = digits(&command[6..10]).ok_or(b"02")?;
        let cluster = digits(&command[10..12]).ok_or(b"03")?;
        let p = &self.model.parameters;
        let bounds = u32::from(p.first_step)..=u32::from(p.last_step);
        if !bounds.contains(&start) || !bounds.contains(&end) {
            return Err(b"04");
        }
        if end < start {
            return Err(b"05");
        }
        Ok(StepRange {
            start: start as u16,
            end: end as u16,
            cluster: cluster as u8,
        })
    }

    fn execute_get(&mut self, line: &[u8], command: &[u8]) {
        if command.len() != 12 {
            return self.reply_status(line, b"0C");
        }
        let range = match self.parse_range(command) {
            Ok(range) => range,
            Err(status) => return self.reply_status(line, status),
        };
        if !self.laser_on {
            return self.reply_status(line, b"10");
        }
        let data = DataKind::from_letter(command[1]).unwrap_or(DataKind::Distance);
        self.output.extend_from_slice(line);
        self.output.extend_from_slice(b"\n00P\n");
        self.push_scan_payload(data, range);
    }

    fn execute_stream(&mut self, line: &[u8], command: &[u8], tag: &[u8]) {
        if command.len() != 15 {
            return self.reply_status(line, b"0C");
        }
        let range = match self.parse_range(command) {
            Ok(range) => range,
            Err(status) => return self.reply_status(line, status),
        };
        let Some(interval) = digits(&command[12..13]) else {
            return self.reply_status(line, b"06");
        };
        let Some(count) = digits(&command[13..15]) else {
            return self.reply_status(line, b"07");
        };
        self.laser_on = true;
        self.stream = Some(ActiveStream {
            data: DataKind::from_letter(command[1]).unwrap_or(DataKind::Distance),
            range,
            interval: interval as u8,
            remaining: (count > 0).then_some(count as u8),
            skipped: 0,
            tag: tag.to_vec(),
        });
        self.reply_status(line, b"00");
    }

    fn transmit_stream_scan(&mut self) {
        let Some(mut stream) = self.stream.take() else {
            return;
        };
        if stream.skipped < stream.interval {
            stream.skipped += 1;
            self.stream = Some(stream);
            return;
        }
        stream.skipped = 0;
        let remaining = stream.remaining.map(|n| n - 1);
        let r = stream.range;
        self.scratch.clear();
        self.scratch
            .extend_from_slice(&[b'M', stream.data.letter()]);
        let fields = format!(
            "{:04}{:04}{:02}{}{:02}",
            r.start,
            r.end,
            r.cluster,
            stream.interval,
            remaining.unwrap_or(0)
        );
        self.scratch.extend_from_slice(fields.as_bytes());
        if !stream.tag.is_empty() {
            self.scratch.push(b';');
            self.scratch.extend_from_slice(&stream.tag);
        }
        self.output.extend_from_slice(&self.scratch);
        self.output.extend_from_slice(b"\n99b\n");
        self.push_scan_payload(stream.data, r);
        if remaining != Some(0) {
            stream.remaining = remaining;
            self.stream = Some(stream);
        }
    }

    fn push_timestamp(&mut self, time_ms: u32) {
        let mut chars = Vec::with_capacity(4);
        encode_value(time_ms & 0xFF_FFFF, 4, &mut chars);
        push_summed_line(&chars, &mut self.output);
    }

    /// Timestamp line, data blocks and the closing empty line for the latest scan.
    fn push_scan_payload(&mut self, data: DataKind, range: StepRange) {
        self.push_timestamp(self.scan_time);
        let first = self.model.parameters.first_step;
        let from = usize::from(range.start - first);
        let to = usize::from(range.end - first);
        let cluster = usize::from(range.cluster.max(1));
        let max_value = (1u32 << (6 * data.value_width())) - 1;
        let mut chars = Vec::with_capacity(range.value_count() * data.step_width());
        for group in (from..=to).step_by(cluster) {
            let last = (group + cluster - 1).min(to);
            // Clustered steps report their nearest echo, as the sensors do.
            let nearest = (group..=last).map(|i| self.ranges[i]).min().unwrap_or(0);
            encode_value(nearest.min(max_value), data.value_width(), &mut chars);
            if data == DataKind::DistanceIntensity {
                let intensity = (group..=last)
                    .map(|i| self.intensities[i])
                    .max()
                    .unwrap_or(0);
                encode_value(intensity.min(max_value), data.value_width(), &mut chars);
            }
        }
        push_data_blocks(&chars, &mut self.output);
        self.output.push(b'\n');
    }
}

fn digits(text: &[u8]) -> Option<u32> {
    text.iter().try_fold(0u32, |acc, &c| {
        c.is_ascii_digit().then(|| acc * 10 + u32::from(c - b'0'))
    })
}
