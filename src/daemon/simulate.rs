//! `simulate`: a scenario's sensors, each behind its driver's emulator with the host-side driver
//! running the real handshake against it in process, recorded exactly as a live run records
//! (tx and rx chunks, host times), plus `/truth` and a configuration describing the simulated
//! rig. Replaying the file therefore exercises the same decoding as a flight.
//!
//! Host time runs [`HANDSHAKE_S`] ahead of simulation time: the handshake happens first, then
//! every simulated measurement is read `READ_LATENCY_NS` after the simulator makes it
//! available.

use super::config::Config;
use super::in_process::{Exchanged, ScipRig, XbusRig};
use super::readings::geometry_from;
use super::recording::{Encoding, Recorder, RecordingError};
use crate::filter::FilterConfig;
use crate::sensors::{ImuSample, ScannerGeometry, TruthSample};
use ladar_sim::{ImuOutput, Oscillation, Scenario, ScenarioError, SimEvent, Simulator, Trajectory};
use std::path::Path;

/// Host seconds given to the handshake before simulated time 0.
pub const HANDSHAKE_S: f64 = 1.0;
/// Host delay between a measurement being complete and its bytes being read.
pub(crate) const READ_LATENCY_NS: u64 = 500_000;
/// The device clocks start away from the host clock, as real ones do.
const SCANNER_CLOCK_OFFSET_MS: u32 = 3_141_592;
const IMU_CLOCK_OFFSET_TICKS: u64 = 27_182_818;
/// Recording chunks are closed this often (simulated seconds), bounding replay memory.
const FLUSH_EVERY_S: f64 = 1.0;

#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    #[error("{0}")]
    Scenario(#[from] ScenarioError),
    #[error("scenario `{0}` has no IMU; the daemon needs one: add an [imu] table")]
    NoImu(String),
    #[error("scenario `{scenario}` cannot be described as a daemon configuration: {errors}")]
    Config { scenario: String, errors: String },
    #[error(transparent)]
    Recording(#[from] RecordingError),
    #[error(
        "simulated sensor `{sensor}` did not finish its handshake with the emulator: {reason}"
    )]
    Handshake { sensor: String, reason: String },
}

/// What was written.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimulateSummary {
    pub duration_s: f64,
    pub scans: u64,
    pub imu_samples: u64,
    pub truth_samples: u64,
    pub chunks: u64,
}

/// Simulates `scenario` (a built-in name or a TOML file) into the MCAP file `out`.
pub fn simulate(scenario: &str, out: &Path) -> Result<SimulateSummary, SimulateError> {
    let scenario = Scenario::resolve(scenario)?;
    let mut simulator = Simulator::new(&scenario)?;
    let config_text = rig_config(&scenario)?;
    Config::parse(&config_text, Path::new("<simulated rig>")).map_err(|e| {
        SimulateError::Config {
            scenario: scenario.name.clone(),
            errors: e.to_string(),
        }
    })?;
    let mut rig = Rig::new(&scenario)?;
    let mut recorder = Recorder::create(out, &config_text)?;
    let mut chunks = Vec::new();
    let mut exchanged = Vec::new();
    rig.handshake(&mut chunks)?;
    let mut summary = SimulateSummary {
        duration_s: simulator.duration_s(),
        scans: 0,
        imu_samples: 0,
        truth_samples: 0,
        chunks: 0,
    };
    record(&mut recorder, &rig, &mut chunks, &mut summary)?;
    let mut next_flush = FLUSH_EVERY_S;
    while let Some(event) = simulator.next_event() {
        let read_at = host_ns(event.time()) + READ_LATENCY_NS;
        match event {
            SimEvent::Truth(truth) => {
                recorder.truth(host_ns(truth.t), &to_host(truth))?;
                summary.truth_samples += 1;
            }
            SimEvent::Imu(sample) => {
                rig.imu.rig.push_sample(&rig.imu.sample(&sample));
                rig.imu.rig.exchange(read_at, &mut exchanged);
                chunks.extend(exchanged.drain(..).map(|e| (rig.imu.sensor, e)));
                summary.imu_samples += 1;
            }
            SimEvent::Scan { scan, .. } => {
                let scanner = &mut rig.scanners[scan.sensor];
                let ranges = scanner.device_ranges(&scan.ranges_m, scan.first_step);
                let step0 = host_ns(scan.t0);
                scanner
                    .rig
                    .push_scan(step0, &ranges)
                    .map_err(|e| SimulateError::Handshake {
                        sensor: scanner.name.clone(),
                        reason: e.to_string(),
                    })?;
                scanner.rig.exchange(read_at, &mut exchanged);
                chunks.extend(exchanged.drain(..).map(|e| (scan.sensor, e)));
                summary.scans += 1;
            }
        }
        record(&mut recorder, &rig, &mut chunks, &mut summary)?;
        if event_time_passed(read_at, &mut next_flush) {
            recorder.flush()?;
        }
    }
    recorder.finish()?;
    Ok(summary)
}

fn event_time_passed(read_at: u64, next_flush: &mut f64) -> bool {
    let t = read_at as f64 * 1e-9 - HANDSHAKE_S;
    if t >= *next_flush {
        *next_flush = t.floor() + FLUSH_EVERY_S;
        true
    } else {
        false
    }
}

/// Host ns of simulated time `t`.
fn host_ns(t: f64) -> u64 {
    ((t + HANDSHAKE_S) * 1e9).round().max(1.0) as u64
}

/// Truth on the host clock, where the estimates are.
fn to_host(truth: TruthSample) -> TruthSample {
    TruthSample {
        t: truth.t + HANDSHAKE_S,
        ..truth
    }
}

/// Exchanged chunks tagged with their sensor number, in exchange order.
type Tagged = (usize, Exchanged);

fn record(
    recorder: &mut Recorder,
    rig: &Rig,
    chunks: &mut Vec<Tagged>,
    summary: &mut SimulateSummary,
) -> Result<(), RecordingError> {
    for (sensor, (direction, log_time, bytes)) in chunks.drain(..) {
        let (name, encoding) = rig.sensor(sensor);
        recorder.bytes(name, encoding, direction, log_time, &bytes)?;
        summary.chunks += 1;
    }
    Ok(())
}

struct ScannerRig {
    name: String,
    rig: ScipRig,
    geometry: ScannerGeometry,
    buffer: Vec<u32>,
}

impl ScannerRig {
    /// Device values (mm) for AMIN..=AMAX, from a scan covering `first_step` on; steps the
    /// scan does not cover read 0, which the stream never asks for anyway.
    fn device_ranges(&mut self, ranges_m: &[f64], first_step: u32) -> Vec<u32> {
        let count = (self.geometry.amax - self.geometry.amin + 1) as usize;
        self.buffer.clear();
        self.buffer.resize(count, 0);
        let offset = first_step.saturating_sub(self.geometry.amin) as usize;
        for (slot, range) in self.buffer.iter_mut().skip(offset).zip(ranges_m) {
            *slot = if range.is_finite() && *range > 0.0 {
                (range * 1000.0).round().min(f64::from(u32::MAX)) as u32
            } else {
                0
            };
        }
        self.buffer.clone()
    }
}

struct ImuRig {
    sensor: usize,
    rig: XbusRig,
    period_s: f64,
}

impl ImuRig {
    fn sample(&self, sample: &ImuSample) -> xbus::emulator::Sample {
        let ticks = ((sample.time() + HANDSHAKE_S) * 10_000.0).round() as u64;
        let stf = ((ticks + IMU_CLOCK_OFFSET_TICKS) % (1 << 32)) as u32;
        match *sample {
            ImuSample::Rate { gyro, accel, .. } => {
                xbus::emulator::Sample::from_rates(stf, accel.into(), gyro.into(), self.period_s)
            }
            ImuSample::Delta { dt, dq, dv, .. } => {
                let q = dq.quaternion();
                xbus::emulator::Sample::from_increments(stf, dv.into(), [q.w, q.i, q.j, q.k], dt)
            }
        }
    }
}

struct Rig {
    scanners: Vec<ScannerRig>,
    imu: ImuRig,
    imu_name: String,
}

impl Rig {
    fn new(scenario: &Scenario) -> Result<Self, SimulateError> {
        let imu = scenario
            .imu
            .as_ref()
            .ok_or_else(|| SimulateError::NoImu(scenario.name.clone()))?;
        let scanners = scenario
            .scanners
            .iter()
            .map(|s| {
                let geometry = s.resolved_geometry().unwrap_or(ScannerGeometry::UTM_30LX);
                let model = emulated_model(&s.name, &geometry);
                let [first, last] = s.steps.unwrap_or([geometry.amin, geometry.amax]);
                let config = scip::DeviceConfig {
                    steps: Some((clamp_u16(first), clamp_u16(last))),
                    // Simulated scans never stall; a scenario may report only every tenth one.
                    stream_timeout: std::time::Duration::from_secs(1_000_000_000),
                    ..scip::DeviceConfig::default()
                };
                ScannerRig {
                    name: s.name.clone(),
                    rig: ScipRig::new(model, config, SCANNER_CLOCK_OFFSET_MS),
                    geometry,
                    buffer: Vec::new(),
                }
            })
            .collect::<Vec<_>>();
        let device = xbus::DeviceConfig {
            imu_output: match imu.output {
                ImuOutput::Rate => xbus::ImuOutput::Rates,
                ImuOutput::Delta => xbus::ImuOutput::Increments,
            },
            rate_hz: imu.rate_hz.round().clamp(1.0, 2000.0) as u16,
            ..xbus::DeviceConfig::default()
        };
        Ok(Self {
            imu: ImuRig {
                sensor: scanners.len(),
                rig: XbusRig::new(xbus::emulator::EmulatorOptions::mti_630(), device),
                period_s: imu.period(),
            },
            imu_name: "imu".into(),
            scanners,
        })
    }

    fn sensor(&self, index: usize) -> (&str, Encoding) {
        match self.scanners.get(index) {
            Some(s) => (&s.name, Encoding::Scip2),
            None => (&self.imu_name, Encoding::Xbus),
        }
    }

    /// Steps every device through its handshake on the host clock before simulated time 0.
    fn handshake(&mut self, chunks: &mut Vec<Tagged>) -> Result<(), SimulateError> {
        let step_ns = 1_000_000;
        let mut now = step_ns;
        while now < host_ns(0.0) {
            for index in 0..self.scanners.len() {
                let mut exchanged = Vec::new();
                self.scanners[index].rig.exchange(now, &mut exchanged);
                chunks.extend(exchanged.into_iter().map(|e| (index, e)));
            }
            let mut exchanged = Vec::new();
            self.imu.rig.exchange(now, &mut exchanged);
            chunks.extend(exchanged.into_iter().map(|e| (self.imu.sensor, e)));
            if self.scanners.iter().all(|s| s.rig.is_streaming()) && self.imu.rig.is_measuring() {
                return Ok(());
            }
            now += step_ns;
        }
        let stuck = self
            .scanners
            .iter()
            .find(|s| !s.rig.is_streaming())
            .map_or(self.imu_name.clone(), |s| s.name.clone());
        Err(SimulateError::Handshake {
            sensor: stuck,
            reason: format!("not streaming after {HANDSHAKE_S} s"),
        })
    }
}

fn clamp_u16(step: u32) -> u16 {
    u16::try_from(step).unwrap_or(u16::MAX)
}

/// The SCIP models that answer PP with the scenario's scanner geometries, in scenario order.
pub fn emulated_models(scenario: &Scenario) -> Vec<scip::Model> {
    scenario
        .scanners
        .iter()
        .map(|s| {
            let geometry = s.resolved_geometry().unwrap_or(ScannerGeometry::UTM_30LX);
            emulated_model(&s.name, &geometry)
        })
        .collect()
}

/// A SCIP model answering PP with `geometry`.
fn emulated_model(name: &str, geometry: &ScannerGeometry) -> scip::Model {
    let mut model = scip::Model::utm_30lx();
    model.parameters = scip::Parameters {
        model: format!("SIMULATED-{name}"),
        min_distance_mm: (geometry.dmin_m * 1000.0).round() as u32,
        max_distance_mm: (geometry.dmax_m * 1000.0).round() as u32,
        angular_resolution: geometry.ares,
        first_step: clamp_u16(geometry.amin),
        last_step: clamp_u16(geometry.amax),
        front_step: clamp_u16(geometry.afrt),
        scan_rpm: geometry.rpm,
    };
    debug_assert_eq!(geometry_from(&model.parameters), *geometry);
    model
}

/// The placeholder port of a simulated sensor in [`rig_config`].
pub(crate) fn simulated_connection(sensor: &str) -> String {
    format!("serial:/dev/simulated-{sensor}")
}

/// The daemon configuration of the simulated rig, as the recording's metadata.
pub fn rig_config(scenario: &Scenario) -> Result<String, SimulateError> {
    let imu = scenario
        .imu
        .as_ref()
        .ok_or_else(|| SimulateError::NoImu(scenario.name.clone()))?;
    let mut text = format!(
        "# Simulated rig of scenario `{}` (seed {}), written by `ladar-odometer simulate`.\n",
        scenario.name, scenario.seed
    );
    for s in &scenario.scanners {
        text.push_str(&format!(
            "\n[[scanner]]\nname = \"{}\"\nconnection = \"{}\"\nrpy_deg = {:?}\ntranslation_m = {:?}\nrange_sigma_m = {:?}\n",
            s.name,
            simulated_connection(&s.name),
            s.mount_rpy_deg,
            s.mount_translation_m,
            s.range_sigma_m
        ));
        if let Some([first, last]) = s.steps {
            text.push_str(&format!("first_step = {first}\nlast_step = {last}\n"));
        }
    }
    let output = match imu.output {
        ImuOutput::Rate => "rate",
        ImuOutput::Delta => "delta",
    };
    text.push_str(&format!(
        "\n[imu]\nname = \"imu\"\nconnection = \"serial:/dev/simulated-imu\"\nrpy_deg = {:?}\noutput = \"{output}\"\nrate_hz = {}\nseries = \"600\"\n",
        imu.mount_rpy_deg,
        imu.rate_hz.round() as u32
    ));
    text.push_str(&fusion_tables(&scenario.trajectory));
    Ok(text)
}

/// Fusion keys the simulated rig needs beyond the defaults, so that replaying the recording
/// runs the fusion as it should run on that rig.
fn fusion_tables(trajectory: &Trajectory) -> String {
    // The scanners of the simulated rigs often pitch about the same axis, so their lines on the
    // floor and on the end walls are parallel; the odometry defaults keep the planes they make
    // while those are level or plumb (`building_max_tilt_deg`), which the rooms' are.
    let mut text = String::new();
    // Zero-velocity updates during motion would pull the filter off the truth, so the
    // stationary start ends when the scenario's motion begins.
    if let Some(still_s) = stationary_until(trajectory) {
        if (MIN_STATIONARY_S..FilterConfig::default().stationary_start_s).contains(&still_s) {
            text.push_str(&format!("\n[filter]\nstationary_start_s = {still_s:?}\n"));
        }
    }
    text
}

/// The filter needs at least its coarse alignment and a few zero-rate updates to start.
const MIN_STATIONARY_S: f64 = 5.0;

/// When the trajectory first moves (None: it never stands still at the start).
fn stationary_until(trajectory: &Trajectory) -> Option<f64> {
    let oscillates = |o: &Oscillation| {
        o.position_amplitude_m.iter().any(|a| *a != 0.0)
            || o.attitude_amplitude_deg.iter().any(|a| *a != 0.0)
    };
    match trajectory {
        Trajectory::Stationary { .. } => None,
        Trajectory::Hover { oscillation, .. } => {
            oscillates(oscillation).then_some(oscillation.start_s)
        }
        Trajectory::Flight {
            start_s,
            oscillation,
            ..
        }
        | Trajectory::Waypoints {
            start_s,
            oscillation,
            ..
        } => Some(if oscillates(oscillation) {
            start_s.min(oscillation.start_s)
        } else {
            *start_s
        }),
        Trajectory::Step { at_s, ramp_s, .. } => Some(at_s - ramp_s),
    }
}
