//! The bench every study runs on: a simulated scenario feeding the geometry core, with each
//! extracted plane labelled by the patches its lines really hit (the simulator's ray labels), so
//! that planes are associated across epochs by truth rather than by the core's own matcher and
//! a moved patch is known exactly.

use super::StudyError;
use crate::least_squares::SolveError;
use crate::odometry::matching::PlaneMatch;
use crate::odometry::{EpochPlanes, Odometer, OdometryConfig, OdometryEpoch, RelativePose};
use crate::sensors::ScannerSetup;
use ladar_sim::{Motion, Profile, Scenario, Simulator, Trajectory};
use nalgebra::{Isometry3, Translation3, Vector3};

/// Prior sigmas around the true relative pose: an IMU-grade prior over one second. With truth
/// association they only start the rotation iteration and weigh the displacement's
/// normal-error term.
const PRIOR_SIGMA_RAD: f64 = 0.01;
const PRIOR_SIGMA_M: f64 = 0.05;

/// Epochs of a stationary scenario are this far apart (the paper's 1 Hz).
const STATIONARY_EPOCH_GAP_S: f64 = 1.0;

/// The patches (scene indices) the two lines of a plane hit, by majority of their readings.
pub(crate) type PlaneLabel = [Option<usize>; 2];

/// One epoch's planes with their labels.
#[derive(Debug, Clone)]
pub struct LabelledEpoch {
    pub planes: EpochPlanes,
    pub labels: Vec<PlaneLabel>,
    /// Start of the epoch's scans (scanner phases added), seconds.
    pub t0: f64,
}

impl LabelledEpoch {
    /// Whether both lines of plane `k` are on patch `patch`.
    pub fn on_patch(&self, k: usize, patch: usize) -> bool {
        self.labels[k] == [Some(patch), Some(patch)]
    }
}

/// A fault staged on one patch between the two epochs of a pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    /// The patch moves this far along its normal, away from the body.
    Translate { patch: usize, metres: f64 },
    /// The patch turns this much about an axis through the body perpendicular to its normal
    /// (its distance from the body is unchanged), the paper's rotating surface.
    Rotate { patch: usize, degrees: f64 },
}

impl Fault {
    pub(crate) fn patch(&self) -> usize {
        match *self {
            Self::Translate { patch, .. } | Self::Rotate { patch, .. } => patch,
        }
    }
}

/// A simulator and a core, with the times of the two epochs of every pair.
pub struct Rig {
    pub sim: Simulator,
    pub odometer: Odometer,
    scenario: Scenario,
    /// Start times of epochs i and j.
    pub epoch_times: [f64; 2],
}

impl Rig {
    pub fn new(scenario: &Scenario, seed: u64, config: OdometryConfig) -> Result<Self, StudyError> {
        let sim = Simulator::with_seed(scenario, seed).map_err(StudyError::Scenario)?;
        let odometer = odometer_for(&sim, config)?;
        let period = sim.scanners()[0]
            .config()
            .report_period(sim.scanners()[0].geometry());
        let gap = if matches!(scenario.trajectory, Trajectory::Stationary { .. }) {
            STATIONARY_EPOCH_GAP_S
        } else {
            period
        };
        if gap + sim.scanners()[0].geometry().scan_period() > scenario.duration_s + 1e-9 {
            return Err(StudyError::TooShort {
                scenario: scenario.name.clone(),
                needed_s: gap + sim.scanners()[0].geometry().scan_period(),
            });
        }
        Ok(Self {
            sim,
            odometer,
            scenario: scenario.clone(),
            epoch_times: [0.0, gap],
        })
    }

    pub(crate) fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    /// Scans both scanners from `t` (plus each scanner's phase) with fresh noise, extracts and
    /// labels the planes. Deskew uses the true motion.
    pub fn capture(&mut self, t: f64) -> LabelledEpoch {
        let [(a, hits_a), (b, hits_b)] = [0, 1].map(|k| {
            let phase = self.sim.scanners()[k].config().phase_s;
            self.sim.scan_labelled(k, t + phase)
        });
        let t_ref = t + self.sim.scanners()[0].geometry().scan_period() / 2.0;
        let reference = self.body_pose(t_ref).inverse();
        let sim = &self.sim;
        let pose_at = |time: f64| {
            let (p, q) = sim.trajectory.pose(time);
            reference * Isometry3::from_parts(Translation3::from(p), q)
        };
        let planes = self.odometer.extract([&a, &b], t_ref, &pose_at);
        let readings = [
            valid_readings(&a, &self.sim, 0, &hits_a),
            valid_readings(&b, &self.sim, 1, &hits_b),
        ];
        let labels = planes
            .planes
            .iter()
            .map(|plane| {
                plane.lines.map(|line| {
                    let segment = self.odometer.lines(line.scanner)[line.segment];
                    majority(&readings[line.scanner][segment.first..segment.end])
                })
            })
            .collect();
        LabelledEpoch {
            planes,
            labels,
            t0: t,
        }
    }

    fn body_pose(&self, t: f64) -> Isometry3<f64> {
        let (p, q) = self.sim.trajectory.pose(t);
        Isometry3::from_parts(Translation3::from(p), q)
    }

    /// True relative pose between the reference times of two epochs (C_j^i, dR in body i).
    pub fn true_relative_pose(&self, i: &LabelledEpoch, j: &LabelledEpoch) -> RelativePose {
        let between = self.body_pose(i.planes.t_ref).inverse() * self.body_pose(j.planes.t_ref);
        RelativePose {
            rotation: between.rotation,
            translation: between.translation.vector,
            ..RelativePose::stationary(PRIOR_SIGMA_RAD, PRIOR_SIGMA_M)
        }
    }

    /// Stages `fault` from the start of epoch j, or removes every staged fault (`None`).
    pub(crate) fn stage(&mut self, fault: Option<Fault>) {
        self.sim.scene = self.scenario.scene.clone();
        let Some(fault) = fault else { return };
        let at_s = self.epoch_times[1];
        let (body, _) = self.sim.trajectory.pose(at_s);
        let patch = &mut self.sim.scene.patches[fault.patch()];
        let placed = patch.rest();
        let outward = if placed.normal.dot(&(placed.centre - body)) >= 0.0 {
            placed.normal
        } else {
            -placed.normal
        };
        patch.motion = match fault {
            Fault::Translate { metres, .. } => Motion::Translate {
                direction: outward.into(),
                distance_m: Profile::Step {
                    at_s,
                    amount: metres,
                },
            },
            Fault::Rotate { degrees, .. } => Motion::Rotate {
                pivot_m: body.into(),
                axis: turn_axis(&outward).into(),
                angle_deg: Profile::Step {
                    at_s,
                    amount: degrees,
                },
            },
        };
    }

    /// Solves the pair with the planes associated by their labels.
    pub(crate) fn solve(&self, i: &LabelledEpoch, j: &LabelledEpoch) -> OdometryEpoch {
        let template = OdometryEpoch {
            matches: associate(i, j),
            prior: self.true_relative_pose(i, j),
            excluded: Vec::new(),
            rotation: Err(SolveError::BadCovariance),
            displacement: Err(SolveError::BadCovariance),
        };
        self.odometer.resolve(&i.planes, &j.planes, &template, &[])
    }
}

/// The core set up with the simulator's two scanners and their ranging sigmas.
pub(crate) fn odometer_for(
    sim: &Simulator,
    config: OdometryConfig,
) -> Result<Odometer, StudyError> {
    let scanners = sim.scanners();
    if scanners.len() != 2 {
        return Err(StudyError::ScannerCount(scanners.len()));
    }
    let setup = |k: usize| ScannerSetup {
        geometry: *scanners[k].geometry(),
        mount: *scanners[k].mount(),
        range_sigma_m: (scanners[k].range_sigma_m() > 0.0).then(|| scanners[k].range_sigma_m()),
    };
    Odometer::new([setup(0), setup(1)], config).map_err(|e| StudyError::Config(e.to_string()))
}

/// Labels of the readings that survive deskew, in beam order.
fn valid_readings(
    scan: &crate::sensors::Scan,
    sim: &Simulator,
    sensor: usize,
    hits: &[Option<usize>],
) -> Vec<Option<usize>> {
    let geometry = sim.scanners()[sensor].geometry();
    scan.ranges_m
        .iter()
        .zip(hits)
        .filter(|(range, _)| geometry.is_valid_range(**range))
        .map(|(_, hit)| *hit)
        .collect()
}

/// The patch most readings of a line hit, if more than half of them did.
fn majority(labels: &[Option<usize>]) -> Option<usize> {
    let mut counts: Vec<(usize, usize)> = Vec::new();
    for patch in labels.iter().flatten() {
        match counts.iter_mut().find(|(p, _)| p == patch) {
            Some((_, n)) => *n += 1,
            None => counts.push((*patch, 1)),
        }
    }
    counts
        .into_iter()
        .max_by_key(|&(_, n)| n)
        .filter(|&(_, n)| 2 * n > labels.len())
        .map(|(patch, _)| patch)
}

/// Pairs planes of i and j whose lines hit the same patches (in either order), one to one.
pub(crate) fn associate(i: &LabelledEpoch, j: &LabelledEpoch) -> Vec<PlaneMatch> {
    let key = |label: &PlaneLabel| match *label {
        [Some(a), Some(b)] => Some((a.min(b), a.max(b))),
        _ => None,
    };
    let mut taken = vec![false; j.labels.len()];
    let mut matches = Vec::new();
    for (previous, label) in i.labels.iter().enumerate() {
        let Some(wanted) = key(label) else { continue };
        let found = (0..j.labels.len()).find(|&c| !taken[c] && key(&j.labels[c]) == Some(wanted));
        if let Some(current) = found {
            taken[current] = true;
            matches.push(PlaneMatch {
                previous,
                current,
                distance_squared: 0.0,
            });
        }
    }
    matches
}

/// The axis a surface turns about: the vertical when the surface is not horizontal (a door),
/// otherwise north; always perpendicular to the normal.
fn turn_axis(normal: &Vector3<f64>) -> Vector3<f64> {
    let down = Vector3::z();
    let vertical = down - normal * normal.dot(&down);
    if vertical.norm() > 0.3 {
        vertical.normalize()
    } else {
        let north = Vector3::x();
        (north - normal * normal.dot(&north)).normalize()
    }
}
