//! Ray-cast scanners, IMU and moving scene with ground truth: a pure, deterministic simulator.
//! It speaks the sensor vocabulary of [`ladar_sensors`] and knows nothing of the odometer it
//! feeds: the daemon's `simulate` and `serve-emulators` commands, the integrity check, the lab's
//! studies and the tests use it.
//!
//! Frames follow docs/design.md, "Frames" (NED navigation, FRD body, scanner mounts as
//! [`ladar_sensors::Mount`]). Gravity is the constant standard value [`GRAVITY`] along NED +z,
//! and the Earth does not rotate: a still IMU measures zero rate and a specific force of -g along
//! NED z. Events stream in time order, so a 500 s scenario never sits in memory.
//!
//! Conventions the consumers must match:
//! - IMU samples are in the IMU frame (NED-flagged); the IMU sits at the body origin. `Delta`
//!   samples are exact: `dq = q(t - dt)^-1 q(t)` and `v(t) = v(t - dt) + C(t - dt) dv + g dt`,
//!   with `C` the IMU-to-NED rotation at the start of the interval and `g = [0, 0, GRAVITY]`.
//!   Errors: `(1 + scale) * truth + bias (+ bias * dt for increments) + white noise`.
//! - Scans: `Scan::t0` is the time of step 0; every beam leaves from the body pose at its own
//!   time; ranges are the device's value / 1000 (1 mm steps), with its codes for no return,
//!   too near and dropouts (see [`ScannerModel`]).
//! - True planes are Hesse planes in the body frame: `normal . x = distance`, `distance >= 0`.

mod builtin;
mod drawn_walk;
mod imu;
mod random_corridor;
mod random_room;
mod scanner;
mod scenario;
mod scene;
mod trajectory;

pub use builtin::{wall_facing_origin, PaperBias, PAPER_SCANNER};
pub use imu::{ImuConfig, ImuOutput, ImuSpread, TriadErrors};
pub use scanner::{ScannerConfig, ScannerModel, SimScanner};
pub use scenario::{Scenario, ScenarioError, BUILTIN_NAMES};
pub use scene::{Motion, Patch, PlacedPatch, Profile, Scene, TruePlane};
pub use trajectory::{Kinematics, Oscillation, Trajectory};

use imu::ImuGenerator;
use ladar_sensors::{ImuSample, Scan, ScannerSetup, TruthSample};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use scene::CastScene;

/// Standard gravity, m/s^2, along NED +z everywhere (no latitude model, no Earth rate).
pub const GRAVITY: f64 = 9.80665;

impl Scenario {
    /// The paper's sec. 4.1 scene with one of its bias experiments.
    pub fn paper_sim(bias: PaperBias) -> Self {
        builtin::paper_sim(bias)
    }

    /// The same scene and flight with the rig of `config/default.toml`, the pitched scanner also
    /// rolled 40 deg (hallway-hover's), in place of the scenario's scanners; named `NAME-rolled`.
    /// Set anything else about the scanners (`skip`) after this.
    pub fn with_rolled_rig(self) -> Self {
        builtin::with_rolled_rig(self)
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum SimEvent {
    /// A complete revolution; `t` is when its last revolution step has passed (`t0` + one scan
    /// period), which is when the device would send it.
    Scan {
        scan: Scan,
        t: f64,
    },
    Imu(ImuSample),
    Truth(TruthSample),
}

impl SimEvent {
    /// When the event becomes available; events stream in order of this time.
    pub fn time(&self) -> f64 {
        match self {
            Self::Scan { t, .. } => *t,
            Self::Imu(sample) => sample.time(),
            Self::Truth(truth) => truth.t,
        }
    }
}

/// Random stream numbers: one per scanner (by index) and one for the IMU, so each sensor's noise
/// does not depend on how the others are sampled.
const IMU_STREAM: u64 = u64::MAX;

fn stream(seed: u64, index: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(index);
    rng
}

/// Next pending item of each source, as counters (time = counter / rate).
#[derive(Debug, Clone, Default)]
struct Cursor {
    truth: u64,
    imu: u64,
    scans: Vec<u64>,
}

pub struct Simulator {
    /// The world; change it between `scan` calls to stage a study (move or turn one patch).
    pub scene: Scene,
    pub trajectory: Trajectory,
    scanners: Vec<SimScanner>,
    imu: Option<ImuConfig>,
    truth_rate_hz: f64,
    duration_s: f64,
    cast_scene: CastScene,
    cast_scene_source: Scene,
    scan_rngs: Vec<ChaCha8Rng>,
    imu_rng: ChaCha8Rng,
    imu_generator: Option<ImuGenerator>,
    cursor: Cursor,
}

impl Simulator {
    /// A simulator at t = 0 with the scenario's own seed; fails if the scenario (perhaps edited
    /// by hand) is invalid.
    pub fn new(scenario: &Scenario) -> Result<Self, ScenarioError> {
        Self::with_seed(scenario, scenario.seed)
    }

    /// Same, with another seed (Monte Carlo runs).
    pub fn with_seed(scenario: &Scenario, seed: u64) -> Result<Self, ScenarioError> {
        scenario.validate()?;
        let scanners: Vec<SimScanner> = scenario.scanners.iter().map(SimScanner::new).collect();
        Ok(Self {
            scene: scenario.scene.clone(),
            trajectory: scenario.trajectory.clone(),
            scan_rngs: (0..scanners.len() as u64)
                .map(|i| stream(seed, i))
                .collect(),
            imu_rng: stream(seed, IMU_STREAM),
            imu_generator: scenario.imu.as_ref().map(ImuGenerator::new),
            imu: scenario.imu.clone(),
            truth_rate_hz: scenario.truth_rate_hz,
            duration_s: scenario.duration_s,
            cast_scene: CastScene::new(&scenario.scene),
            cast_scene_source: scenario.scene.clone(),
            cursor: Cursor {
                scans: vec![0; scanners.len()],
                ..Cursor::default()
            },
            scanners,
        })
    }

    /// The scanners in scenario order (index = `Scan::sensor`): geometry, mount, range sigma.
    pub fn scanners(&self) -> &[SimScanner] {
        &self.scanners
    }

    /// The two scanners as the fusion and the odometer take them; `None` unless there are two.
    pub fn scanner_setups(&self) -> Option<[ScannerSetup; 2]> {
        let scanners = self.scanners();
        if scanners.len() != 2 {
            return None;
        }
        Some([0, 1].map(|k| ScannerSetup {
            geometry: *scanners[k].geometry(),
            mount: *scanners[k].mount(),
            range_sigma_m: Some(scanners[k].range_sigma_m()),
        }))
    }

    pub fn imu(&self) -> Option<&ImuConfig> {
        self.imu.as_ref()
    }

    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// Ground truth of the body at any time.
    pub fn truth_at(&self, t: f64) -> TruthSample {
        let k = self.trajectory.kinematics(t);
        TruthSample {
            t,
            p: k.p,
            q: k.q,
            v: k.v,
        }
    }

    /// Full kinematics (acceleration, body rate, specific force) at any time.
    pub fn kinematics_at(&self, t: f64) -> Kinematics {
        self.trajectory.kinematics(t)
    }

    /// Every patch as a plane (unit normal towards it, distance >= 0) in the body frame of the
    /// true pose at `t`, with the patches where their motion has them at `t`.
    pub fn true_planes_in_body(&self, t: f64) -> Vec<TruePlane> {
        let (p, q) = self.trajectory.pose(t);
        self.scene.planes_in_body(t, &p, &q)
    }

    /// One revolution of scanner `sensor` with step 0 at `t0`, with fresh noise from that
    /// scanner's random stream. Panics if `sensor` is out of range.
    pub fn scan(&mut self, sensor: usize, t0: f64) -> Scan {
        self.cast(sensor, t0, None)
    }

    /// Like [`Self::scan`], also giving the index of the patch each reading came from (`None`
    /// where the beam hit nothing).
    pub fn scan_labelled(&mut self, sensor: usize, t0: f64) -> (Scan, Vec<Option<usize>>) {
        let mut hits = Vec::new();
        let scan = self.cast(sensor, t0, Some(&mut hits));
        (scan, hits)
    }

    fn cast(&mut self, sensor: usize, t0: f64, hits: Option<&mut Vec<Option<usize>>>) -> Scan {
        if self.cast_scene_source != self.scene {
            self.cast_scene = CastScene::new(&self.scene);
            self.cast_scene_source = self.scene.clone();
        }
        self.scanners[sensor].cast(
            sensor,
            t0,
            &self.trajectory,
            &mut self.cast_scene,
            &mut self.scan_rngs[sensor],
            hits,
        )
    }

    /// Step-0 time of the `index`-th reported revolution of scanner `sensor`.
    fn scan_t0(&self, sensor: usize, index: u64) -> f64 {
        let scanner = &self.scanners[sensor];
        scanner.config().phase_s + index as f64 * scanner.config().report_period(scanner.geometry())
    }

    /// All remaining events in time order. (Not `impl Iterator for Simulator`: its `scan` adapter
    /// would shadow [`Self::scan`].)
    pub fn events(&mut self) -> impl Iterator<Item = SimEvent> + '_ {
        std::iter::from_fn(|| self.next_event())
    }

    /// The next event in time order (ties: truth, then IMU, then scanners by index), or `None`
    /// after `duration_s`.
    pub fn next_event(&mut self) -> Option<SimEvent> {
        #[derive(Clone, Copy)]
        enum Source {
            Truth,
            Imu,
            Scanner(usize),
        }
        let truth = (self.cursor.truth as f64 / self.truth_rate_hz, Source::Truth);
        let imu = self
            .imu
            .as_ref()
            .map(|imu| ((self.cursor.imu + 1) as f64 * imu.period(), Source::Imu));
        let scans = (0..self.scanners.len()).map(|sensor| {
            let t0 = self.scan_t0(sensor, self.cursor.scans[sensor]);
            let done = t0 + self.scanners[sensor].geometry().scan_period();
            (done, Source::Scanner(sensor))
        });
        // The first of equal times wins, which gives the documented tie order.
        let (time, source) = std::iter::once(truth)
            .chain(imu)
            .chain(scans)
            .reduce(|best, next| if next.0 < best.0 { next } else { best })?;
        if time > self.duration_s {
            return None;
        }
        Some(match source {
            Source::Truth => {
                self.cursor.truth += 1;
                SimEvent::Truth(self.truth_at(time))
            }
            Source::Imu => {
                self.cursor.imu += 1;
                let generator = self.imu_generator.as_mut()?;
                SimEvent::Imu(generator.sample(
                    self.cursor.imu,
                    &self.trajectory,
                    &mut self.imu_rng,
                ))
            }
            Source::Scanner(sensor) => {
                let t0 = self.scan_t0(sensor, self.cursor.scans[sensor]);
                self.cursor.scans[sensor] += 1;
                SimEvent::Scan {
                    scan: self.scan(sensor, t0),
                    t: time,
                }
            }
        })
    }
}

#[cfg(test)]
mod tests;
