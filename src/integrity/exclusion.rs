//! Fault detection and exclusion over one solve or over an epoch's two solves.
//!
//! When a test fires, the plane with the largest statistic relative to its threshold is
//! excluded, the solves are re-solved without it (through the caller's re-solvers, which take
//! every plane excluded so far and keep plane ids unchanged) and re-tested, up to
//! `max_exclusions` planes. In an epoch a plane excluded from either solve is excluded from both.
//!
//! Isolation rule. A fault confined to plane `k` (`d_k` rows) moves the parity vector inside the
//! `d_k`-dimensional span of `G_k`. It can be told apart from a fault on plane `j` only if the
//! two spans meet in nothing but zero, which for general geometry needs a parity space of
//! dimension `r >= d_k + d_j`; otherwise some fault on `j` looks exactly like one on `k`, and,
//! since excluding `k` removes the span of `G_k` from the parity space, the wrong exclusion
//! would even pass the re-test. So plane `k` may be excluded only when
//! `r >= d_k + max_(j != k) d_j` in every solve that contains it, which also leaves at least one
//! redundant row to re-test with. Displacement (one row a plane, `r = M - 3`): `M >= 5`.
//! Rotation (two tangent rows a plane, `r = 2M - 3`): `M >= 4`. Otherwise the epoch is
//! `DetectedNotIsolable` and not fused.
//!
//! Separability guard. The spans may meet in nothing but zero and still be almost aligned: when
//! the canonical correlation of two planes' tests in a solve is near 1 (say the front wall and
//! the door are the only planes that see x), a fault on either moves both statistics alike and
//! which one is larger is decided by noise. The candidate is then only a tie with its rivals in
//! that solve; another solve whose test fired and that tells them apart breaks the tie (its most
//! severe plane among them is excluded), and if none does the epoch is `DetectedNotIsolable`.

use super::config::IntegrityConfig;
use super::parity::{test_system, SolveTest, Untestable};
use super::thresholds::Thresholds;
use crate::config::ConfigErrors;
use crate::estimate::IntegrityStatus;
use crate::least_squares::{LinearSystem, Solution, SolveError};
use serde::{Serialize, Serializer};

/// Two planes' tests correlated at least this much in a solve are told apart there by noise
/// rather than by the fault: with noncentrality `delta` the wrong one is larger with
/// probability about `Phi(-delta sqrt((1 - c) / 2))`, 38 % at `delta = 14` (twice the MDB).
/// Lower limits start refusing pairs the largest-residual rule still gets right most of the
/// time (at 0.99, 2 % of random six-plane displacement solves with a fault at twice the MDB).
const INSEPARABLE_CORRELATION: f64 = 0.999;

/// Re-solves a solve with the given planes (ids of the epoch) left out.
pub(crate) type Resolver<'a> = dyn FnMut(&[usize]) -> Result<Solution, SolveError> + 'a;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SolveKind {
    Rotation,
    Displacement,
}

/// Verdict and evidence for one solve.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SolveReport {
    pub kind: SolveKind,
    pub status: IntegrityStatus,
    /// Planes left out of `solution` and `test`.
    pub excluded: Vec<usize>,
    /// Why the solve could not be tested, when it could not.
    #[serde(serialize_with = "display_or_null")]
    pub untestable: Option<Untestable>,
    /// The test of the last solution tried.
    pub test: Option<SolveTest>,
    #[serde(serialize_with = "solution_summary")]
    pub solution: Option<Solution>,
}

/// Verdict and evidence for one odometry epoch (rotation and displacement).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EpochReport {
    pub status: IntegrityStatus,
    pub excluded: Vec<usize>,
    pub rotation: SolveReport,
    pub displacement: SolveReport,
}

/// The integrity layer: a validated configuration with its thresholds precomputed.
#[derive(Debug, Clone, PartialEq)]
pub struct IntegrityMonitor {
    config: IntegrityConfig,
    /// The whole false-alarm budget, for a solve checked on its own.
    alone: Thresholds,
    /// Half the budget each, for the two solves of an epoch.
    paired: Thresholds,
}

struct Track<'r, 'a> {
    kind: SolveKind,
    resolve: &'r mut Resolver<'a>,
    solution: Option<Solution>,
    test: Result<SolveTest, Untestable>,
}

impl IntegrityMonitor {
    pub fn new(config: IntegrityConfig) -> Result<Self, ConfigErrors> {
        config.validate()?;
        let pfa = config.false_alarm_probability;
        let pmd = config.missed_detection_probability;
        Ok(Self {
            alone: Thresholds::new(pfa, pmd),
            paired: Thresholds::new(pfa / 2.0, pmd),
            config,
        })
    }

    pub(crate) fn config(&self) -> &IntegrityConfig {
        &self.config
    }

    /// The thresholds of a test checked on its own, with the whole false-alarm budget.
    pub(crate) fn thresholds(&self) -> &Thresholds {
        &self.alone
    }

    /// Test one system with the whole false-alarm budget, without excluding anything.
    pub fn test(&self, kind: SolveKind, system: &LinearSystem) -> Result<SolveTest, Untestable> {
        self.test_with(&self.alone, kind, system)
    }

    /// Detect and exclude on one solve checked on its own.
    #[cfg(test)]
    pub(crate) fn check_solve(
        &self,
        kind: SolveKind,
        first: Result<Solution, SolveError>,
        resolve: &mut Resolver<'_>,
    ) -> SolveReport {
        let mut tracks = [self.track(&self.alone, kind, first, resolve)];
        // With one solve the loop's verdict is the solve's own.
        let (_, excluded) = self.exclude(&self.alone, &mut tracks);
        let [track] = tracks;
        report(track, excluded)
    }

    /// Detect and exclude on an epoch: a plane excluded from either solve leaves both, and the
    /// epoch is usable only if both solves pass.
    pub fn check_epoch(
        &self,
        rotation: Result<Solution, SolveError>,
        displacement: Result<Solution, SolveError>,
        resolve_rotation: &mut Resolver<'_>,
        resolve_displacement: &mut Resolver<'_>,
    ) -> EpochReport {
        let mut tracks = [
            self.track(
                &self.paired,
                SolveKind::Rotation,
                rotation,
                resolve_rotation,
            ),
            self.track(
                &self.paired,
                SolveKind::Displacement,
                displacement,
                resolve_displacement,
            ),
        ];
        let (status, excluded) = self.exclude(&self.paired, &mut tracks);
        let [rotation, displacement] = tracks;
        EpochReport {
            rotation: report(rotation, excluded.clone()),
            displacement: report(displacement, excluded.clone()),
            status,
            excluded,
        }
    }

    fn min_planes(&self, kind: SolveKind) -> usize {
        match kind {
            SolveKind::Rotation => self.config.min_planes_rotation,
            SolveKind::Displacement => self.config.min_planes_displacement,
        }
    }

    fn test_with(
        &self,
        thresholds: &Thresholds,
        kind: SolveKind,
        system: &LinearSystem,
    ) -> Result<SolveTest, Untestable> {
        test_system(
            system,
            thresholds,
            self.min_planes(kind),
            self.config.max_condition_number,
        )
    }

    fn track<'r, 'a>(
        &self,
        thresholds: &Thresholds,
        kind: SolveKind,
        solved: Result<Solution, SolveError>,
        resolve: &'r mut Resolver<'a>,
    ) -> Track<'r, 'a> {
        match solved {
            Ok(solution) => Track {
                kind,
                resolve,
                test: self.test_with(thresholds, kind, &solution.system),
                solution: Some(solution),
            },
            Err(error) => Track {
                kind,
                resolve,
                solution: None,
                test: Err(Untestable::Solve(error)),
            },
        }
    }

    /// The exclusion loop; leaves each track at the last state that was fully tested.
    fn exclude(
        &self,
        thresholds: &Thresholds,
        tracks: &mut [Track<'_, '_>],
    ) -> (IntegrityStatus, Vec<usize>) {
        let mut excluded = Vec::new();
        loop {
            let mut tests = Vec::with_capacity(tracks.len());
            for track in tracks.iter() {
                match &track.test {
                    Ok(test) => tests.push(test),
                    Err(_) => return (IntegrityStatus::UnderDetermined, excluded),
                }
            }
            let Some(suspect) = most_suspect(&tests) else {
                let status = if excluded.is_empty() {
                    IntegrityStatus::Ok
                } else {
                    IntegrityStatus::Excluded {
                        planes: excluded.clone(),
                    }
                };
                return (status, excluded);
            };
            let Some(candidate) = separated(&tests, suspect) else {
                return (IntegrityStatus::DetectedNotIsolable, excluded);
            };
            if excluded.len() >= self.config.max_exclusions
                || !tests.iter().all(|test| isolable(test, candidate))
            {
                return (IntegrityStatus::DetectedNotIsolable, excluded);
            }
            excluded.push(candidate);
            let retried: Vec<_> = tracks
                .iter_mut()
                .map(|track| {
                    let solved = (track.resolve)(&excluded).map_err(Untestable::Solve);
                    let test = solved.as_ref().map_err(Clone::clone).and_then(|solution| {
                        self.test_with(thresholds, track.kind, &solution.system)
                    });
                    (solved, test)
                })
                .collect();
            if retried.iter().any(|(_, test)| test.is_err()) {
                excluded.pop();
                return (IntegrityStatus::DetectedNotIsolable, excluded);
            }
            for (track, (solved, test)) in tracks.iter_mut().zip(retried) {
                track.solution = solved.ok();
                track.test = test;
            }
        }
    }
}

/// Among the solves whose tests fired, the plane that is furthest past its threshold.
fn most_suspect(tests: &[&SolveTest]) -> Option<usize> {
    tests
        .iter()
        .filter(|test| test.detected)
        .filter_map(|test| test.most_suspect())
        .max_by(|a, b| a.severity().total_cmp(&b.severity()))
        .map(|plane| plane.plane)
}

/// The separability guard of the module documentation: the plane to exclude in place of
/// `suspect`, or `None` when no solve can tell it from its rivals.
fn separated(tests: &[&SolveTest], suspect: usize) -> Option<usize> {
    let ties = |test: &SolveTest| -> Vec<usize> {
        test.planes
            .iter()
            .map(|plane| plane.plane)
            .filter(|&other| other != suspect)
            .filter(|&other| {
                test.correlation(suspect, other)
                    .is_some_and(|c| c >= INSEPARABLE_CORRELATION)
            })
            .collect()
    };
    let mut tied: Vec<usize> = tests.iter().flat_map(|test| ties(test)).collect();
    if tied.is_empty() {
        return Some(suspect);
    }
    tied.push(suspect);
    tests
        .iter()
        .filter(|test| test.detected)
        .find(|test| tells_apart(test, &tied))
        .and_then(|test| {
            tied.iter()
                .filter_map(|&id| test.plane(id))
                .max_by(|a, b| a.severity().total_cmp(&b.severity()))
                .map(|plane| plane.plane)
        })
}

/// Whether every pair of `planes` is in `test`, with tests correlated below the guard's limit.
fn tells_apart(test: &SolveTest, planes: &[usize]) -> bool {
    planes.iter().enumerate().all(|(i, &a)| {
        planes[i + 1..].iter().all(|&b| {
            a == b
                || test
                    .correlation(a, b)
                    .is_some_and(|c| c < INSEPARABLE_CORRELATION)
        })
    })
}

/// The isolation rule of the module documentation.
fn isolable(test: &SolveTest, candidate: usize) -> bool {
    let Some(plane) = test.plane(candidate) else {
        return true;
    };
    let largest_other = test
        .planes
        .iter()
        .filter(|other| other.plane != candidate)
        .map(|other| other.rows)
        .max()
        .unwrap_or(0);
    test.redundancy >= plane.rows + largest_other
}

/// The solve's own verdict on its last tested state.
fn report(track: Track<'_, '_>, excluded: Vec<usize>) -> SolveReport {
    let status = match &track.test {
        Err(_) => IntegrityStatus::UnderDetermined,
        Ok(test) if test.detected => IntegrityStatus::DetectedNotIsolable,
        Ok(_) if excluded.is_empty() => IntegrityStatus::Ok,
        Ok(_) => IntegrityStatus::Excluded {
            planes: excluded.clone(),
        },
    };
    let (test, untestable) = match track.test {
        Ok(test) => (Some(test), None),
        Err(reason) => (None, Some(reason)),
    };
    SolveReport {
        kind: track.kind,
        status,
        excluded,
        untestable,
        test,
        solution: track.solution,
    }
}

/// `system` without the rows of the `excluded` planes (rows and columns of `R` alike): the
/// re-solve of a linear solve such as displacement is `without_planes(..).solve()`.
pub fn without_planes(system: &LinearSystem, excluded: &[usize]) -> LinearSystem {
    let kept: Vec<usize> = (0..system.rows())
        .filter(|&row| !excluded.contains(&system.plane_of_row[row]))
        .collect();
    LinearSystem {
        h: system.h.select_rows(&kept),
        y: system.y.select_rows(&kept),
        r: system.r.select_rows(&kept).select_columns(&kept),
        plane_of_row: kept.iter().map(|&row| system.plane_of_row[row]).collect(),
    }
}

fn display_or_null<S: Serializer>(
    reason: &Option<Untestable>,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    match reason {
        Some(reason) => serializer.collect_str(reason),
        None => serializer.serialize_none(),
    }
}

#[derive(Serialize)]
struct SolutionSummary {
    x: [f64; 3],
    covariance: [[f64; 3]; 3],
    dilution: [f64; 3],
    condition: f64,
}

fn solution_summary<S: Serializer>(
    solution: &Option<Solution>,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    solution
        .as_ref()
        .map(|solution| SolutionSummary {
            x: solution.x.into(),
            covariance: solution.covariance.into(),
            dilution: solution.dilution.per_axis.into(),
            condition: solution.dilution.condition,
        })
        .serialize(serializer)
}
