//! The fusion loop's synchronous core, identical live and in replay: chunks of device bytes, in
//! consumption order, with what the driver decoded from them -> host timing per sensor -> an
//! [`Estimator`] -> estimates and epoch records.
//!
//! Staleness is decided from the chunks alone, so replay reproduces it: a sensor whose link
//! dropped (the sensor task sends an empty rx chunk, which is recorded like any other) or that
//! has been silent for `STALE_AFTER_NS` while others spoke is marked stale, and fresh again on
//! its next bytes.

use super::config::{Config, ImuConfig, ImuSeries, ScannerConfig};
use super::readings::{DecodeCounts, Reading, SensorEvent, SensorTiming};
use super::recording::{Direction, Encoding};
use crate::estimate::Estimate;
use crate::sensors::{ImuSample, Scan, ScannerGeometry};
use serde::Serialize;

/// Silence after which a sensor is declared stale: ten scans of the slowest supported scanner.
pub(crate) const STALE_AFTER_NS: u64 = 1_000_000_000;

/// One chunk of bytes read from (`Rx`) or written to (`Tx`) sensor number `sensor`, stamped with
/// host monotonic ns since the daemon started, with the readings its driver decoded from it.
/// An empty `Rx` chunk says the link was lost. The bytes are what is recorded; the readings are
/// what the fusion takes.
#[derive(Debug, Clone, PartialEq)]
pub struct Chunk {
    pub sensor: usize,
    pub direction: Direction,
    pub log_time_ns: u64,
    pub data: Vec<u8>,
    pub readings: Vec<Reading>,
}

/// A configured sensor as the pipeline, the recording and the host timing know it; `name` is
/// its recording topic `/<name>/rx`.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorSpec {
    /// Scanner number `index` of the configuration.
    Scanner { name: String, index: usize },
    /// The IMU: `sample_time_modulus` until the product code is seen, `rate_hz` until the
    /// output configuration acknowledgement is.
    Imu {
        name: String,
        sample_time_modulus: u64,
        rate_hz: f64,
    },
}

impl SensorSpec {
    pub fn name(&self) -> &str {
        match self {
            Self::Scanner { name, .. } | Self::Imu { name, .. } => name,
        }
    }

    /// What its bytes speak.
    pub fn encoding(&self) -> Encoding {
        match self {
            Self::Scanner { .. } => Encoding::Scip2,
            Self::Imu { .. } => Encoding::Xbus,
        }
    }
}

/// One sensor of a configuration.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Configured<'a> {
    Scanner(&'a ScannerConfig),
    Imu(&'a ImuConfig),
}

/// The configuration's sensors in the one order that numbers them ([`Chunk::sensor`]):
/// scanners in configuration order, then the IMU. A scanner's number is its scanner index.
pub(crate) fn configured_sensors(config: &Config) -> impl Iterator<Item = Configured<'_>> {
    let scanners = config.scanners.iter().map(Configured::Scanner);
    scanners.chain(std::iter::once(Configured::Imu(&config.imu)))
}

pub fn sensor_specs(config: &Config) -> Vec<SensorSpec> {
    let spec = |(number, sensor)| match sensor {
        Configured::Scanner(scanner) => SensorSpec::Scanner {
            name: scanner.name.clone(),
            index: number,
        },
        Configured::Imu(imu) => SensorSpec::Imu {
            name: imu.name.clone(),
            sample_time_modulus: match imu.series {
                ImuSeries::Mti100 => xbus::ONE_DAY_TICKS,
                ImuSeries::Auto | ImuSeries::Mti600 => xbus::U32_TICKS,
            },
            rate_hz: f64::from(imu.rate_hz.max(1)),
        },
    };
    configured_sensors(config).enumerate().map(spec).collect()
}

/// What an odometry epoch contributes to the replay summary and to `run`'s log.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct EpochCounts {
    pub planes: usize,
    /// Integrity detected a fault in this epoch.
    pub detected: bool,
    /// Planes excluded as outliers (a moving door, say).
    pub excluded: usize,
    pub outcome: Outcome,
    /// Why the filter could not take the epoch, when it [`Outcome::Failed`].
    pub failure: Option<String>,
}

/// How an epoch ended, as epochs.jsonl's `outcome` and `status` say it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord)]
pub enum Outcome {
    /// Only the reference of the next epoch.
    #[default]
    Reference,
    Fused,
    UnderDetermined,
    NotIsolable,
    /// Solved and tested, but nothing cleared for fusion.
    NotFused,
    RejectedByGate,
    Failed,
}

impl Outcome {
    pub(crate) const ALL: [Self; 7] = [
        Self::Fused,
        Self::Reference,
        Self::UnderDetermined,
        Self::NotIsolable,
        Self::NotFused,
        Self::RejectedByGate,
        Self::Failed,
    ];

    /// The outcome and its reason, as a user reads it.
    pub(crate) fn describe(self) -> &'static str {
        match self {
            Self::Reference => {
                "reference only (the first, before the filter aligned, or after a gap)"
            }
            Self::Fused => "fused",
            Self::UnderDetermined => {
                "under-determined (fewer than three non-parallel planes matched), not fused"
            }
            Self::NotIsolable => "not fused: a fault detected that could not be isolated",
            Self::NotFused => "not fused: no direction cleared by the integrity tests",
            Self::RejectedByGate => "refused by the filter's innovation gate",
            Self::Failed => "failed in the filter",
        }
    }
}

/// The estimator the fusion loop drives: the real `Fusion` implements it. Calls come in the
/// order the sensors' bytes were consumed, with host times in seconds.
pub trait Estimator {
    /// One line of `epochs.jsonl`.
    type Epoch: Serialize;
    /// A scanner reported its geometry (start-up, and after each reconnect).
    fn geometry(&mut self, scanner: usize, geometry: ScannerGeometry);
    fn imu(&mut self, sample: ImuSample) -> Option<Estimate>;
    fn scan(&mut self, scan: Scan) -> Option<Self::Epoch>;
    /// The estimate to publish right after `scan` returned an epoch, so that the epoch reaches
    /// the autopilot without waiting for the next IMU sample. `None` for estimators without one.
    fn epoch_estimate(&self) -> Option<Estimate> {
        None
    }
    /// Sensor `sensor` (a [`Chunk::sensor`] number) went stale or came back at host time `t`.
    fn sensor_stale(&mut self, sensor: usize, stale: bool, t: f64);
    fn epoch_counts(epoch: &Self::Epoch) -> EpochCounts;
}

/// What the pipeline hands its owner.
// Handed straight to a callback and never stored in bulk, so boxing would only add an
// allocation per estimate.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Output<E> {
    /// An IMU-rate estimate.
    Estimate(Estimate),
    Epoch(E),
    /// The estimate published right after an [`Output::Epoch`]: at the time of the IMU-rate
    /// estimate before it, with the epoch's update applied. For the autopilot, not for
    /// `trajectory.tum` (one line per time).
    EpochEstimate(Estimate),
}

pub struct Pipeline<E: Estimator> {
    specs: Vec<SensorSpec>,
    timings: Vec<SensorTiming>,
    estimator: E,
    events: Vec<SensorEvent>,
    last_rx_ns: Vec<Option<u64>>,
    stale: Vec<bool>,
}

impl<E: Estimator> Pipeline<E> {
    pub fn new(specs: Vec<SensorSpec>, estimator: E) -> Self {
        let n = specs.len();
        Self {
            timings: specs.iter().map(SensorTiming::new).collect(),
            specs,
            estimator,
            events: Vec::new(),
            last_rx_ns: vec![None; n],
            stale: vec![false; n],
        }
    }

    /// Adds a sensor found in a recording without a configuration.
    pub(crate) fn with_sensor(mut self, spec: SensorSpec) -> Self {
        self.timings.push(SensorTiming::new(&spec));
        self.specs.push(spec);
        self.last_rx_ns.push(None);
        self.stale.push(false);
        self
    }

    pub(crate) fn specs(&self) -> &[SensorSpec] {
        &self.specs
    }

    /// Number of the sensor called `name`, if configured.
    pub(crate) fn sensor_named(&self, name: &str) -> Option<usize> {
        self.specs.iter().position(|s| s.name() == name)
    }

    /// Takes one chunk; `out` receives what it completed. Transmitted bytes are only recorded.
    pub fn push(&mut self, chunk: &Chunk, mut out: impl FnMut(Output<E::Epoch>)) {
        if chunk.direction != Direction::Rx || chunk.sensor >= self.timings.len() {
            return;
        }
        let t = chunk.log_time_ns as f64 / 1e9;
        if chunk.data.is_empty() {
            self.set_stale(chunk.sensor, true, t);
            return;
        }
        if chunk.log_time_ns != 0 {
            self.mark_silent_sensors(chunk.log_time_ns);
            self.last_rx_ns[chunk.sensor] = Some(chunk.log_time_ns);
        }
        self.set_stale(chunk.sensor, false, t);
        self.events.clear();
        let timing = &mut self.timings[chunk.sensor];
        timing.received(chunk.data.len());
        for reading in &chunk.readings {
            timing.take(chunk.log_time_ns, reading, &mut self.events);
        }
        for event in self.events.drain(..) {
            match event {
                SensorEvent::Geometry { sensor, geometry } => {
                    self.estimator.geometry(sensor, geometry)
                }
                SensorEvent::Scan(scan) => {
                    if let Some(epoch) = self.estimator.scan(scan) {
                        out(Output::Epoch(epoch));
                        if let Some(estimate) = self.estimator.epoch_estimate() {
                            out(Output::EpochEstimate(estimate));
                        }
                    }
                }
                SensorEvent::Imu(sample) => {
                    if let Some(estimate) = self.estimator.imu(sample) {
                        out(Output::Estimate(estimate));
                    }
                }
            }
        }
    }

    fn mark_silent_sensors(&mut self, now_ns: u64) {
        for sensor in 0..self.specs.len() {
            let silent = self.last_rx_ns[sensor]
                .is_some_and(|last| now_ns.saturating_sub(last) > STALE_AFTER_NS);
            if silent {
                self.set_stale(sensor, true, now_ns as f64 / 1e9);
            }
        }
    }

    fn set_stale(&mut self, sensor: usize, stale: bool, t: f64) {
        if self.stale[sensor] != stale {
            self.stale[sensor] = stale;
            self.estimator.sensor_stale(sensor, stale, t);
        }
    }

    pub(crate) fn is_stale(&self, sensor: usize) -> bool {
        self.stale[sensor]
    }

    /// Decoder health per sensor, in sensor order.
    pub(crate) fn decode_counts(&self) -> Vec<DecodeCounts> {
        self.timings.iter().map(SensorTiming::counts).collect()
    }

    #[cfg(test)]
    pub(crate) fn estimator(&self) -> &E {
        &self.estimator
    }

    pub(crate) fn estimator_mut(&mut self) -> &mut E {
        &mut self.estimator
    }

    pub(crate) fn into_estimator(self) -> E {
        self.estimator
    }
}

/// One call the pipeline made on its estimator.
#[derive(Debug, Clone, PartialEq)]
pub enum Traced {
    Geometry(usize, ScannerGeometry),
    Imu(ImuSample),
    Scan(Scan),
    Stale { sensor: usize, stale: bool, t: f64 },
}

/// Keeps every call, for comparing a live run with its replay; estimates nothing.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct EventTrace {
    pub calls: Vec<Traced>,
}

impl Estimator for EventTrace {
    type Epoch = ();
    fn geometry(&mut self, scanner: usize, geometry: ScannerGeometry) {
        self.calls.push(Traced::Geometry(scanner, geometry));
    }
    fn imu(&mut self, sample: ImuSample) -> Option<Estimate> {
        self.calls.push(Traced::Imu(sample));
        None
    }
    fn scan(&mut self, scan: Scan) -> Option<()> {
        self.calls.push(Traced::Scan(scan));
        None
    }
    fn sensor_stale(&mut self, sensor: usize, stale: bool, t: f64) {
        self.calls.push(Traced::Stale { sensor, stale, t });
    }
    fn epoch_counts(_: &()) -> EpochCounts {
        EpochCounts::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn specs() -> Vec<SensorSpec> {
        let scanner = |index: usize, name: &str| SensorSpec::Scanner {
            name: name.into(),
            index,
        };
        vec![scanner(0, "front"), scanner(1, "pitched")]
    }

    fn rx(sensor: usize, ms: u64, data: &[u8]) -> Chunk {
        Chunk {
            sensor,
            direction: Direction::Rx,
            log_time_ns: ms * 1_000_000,
            data: data.to_vec(),
            readings: Vec::new(),
        }
    }

    fn stale_marks(pipeline: &Pipeline<EventTrace>) -> Vec<(usize, bool, f64)> {
        pipeline
            .estimator()
            .calls
            .iter()
            .filter_map(|c| match c {
                Traced::Stale { sensor, stale, t } => Some((*sensor, *stale, *t)),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn a_silent_sensor_goes_stale_when_another_speaks_and_fresh_on_its_next_bytes() {
        let mut pipeline = Pipeline::new(specs(), EventTrace::default());
        let mut ignore = |_: Output<()>| {};
        pipeline.push(&rx(0, 100, b"\n"), &mut ignore);
        pipeline.push(&rx(1, 100, b"\n"), &mut ignore);
        pipeline.push(&rx(1, 1_000, b"\n"), &mut ignore);
        assert!(
            stale_marks(&pipeline).is_empty(),
            "900 ms of silence is fine"
        );
        pipeline.push(&rx(1, 1_200, b"\n"), &mut ignore);
        assert!(pipeline.is_stale(0));
        pipeline.push(&rx(0, 1_300, b"\n"), &mut ignore);
        assert_eq!(stale_marks(&pipeline), [(0, true, 1.2), (0, false, 1.3)]);
    }

    #[test]
    fn an_empty_rx_chunk_is_a_lost_link_and_transmitted_bytes_are_not_decoded() {
        let mut pipeline = Pipeline::new(specs(), EventTrace::default());
        let mut ignore = |_: Output<()>| {};
        pipeline.push(&rx(1, 10, b""), &mut ignore);
        let tx = Chunk {
            direction: Direction::Tx,
            ..rx(0, 20, b"QT\n")
        };
        pipeline.push(&tx, &mut ignore);
        assert_eq!(stale_marks(&pipeline), [(1, true, 0.01)]);
        assert_eq!(pipeline.decode_counts()[0].chunks, 0);
    }
}
