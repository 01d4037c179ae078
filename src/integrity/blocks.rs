//! The plane map's integrity test: the paper's parity test and exclusion (eqs 34-44) with a
//! surface, a block of rows (two for each of its lines), in the role of a plane.
//!
//! The system tested is the filter's prediction of the pose together with the epoch's lines:
//! its parity space is spanned by the innovation `y` of the lines (covariance `S = H P H^T +
//! R`), so the global test is the NIS and each surface's test is Baarda's w-test generalised to
//! its block: with `u = S^-1 y` and `N_b = (S^-1)_bb`, `T_b = u_b^T N_b^-1 u_b` is chi-square
//! with the block's rows when the surface is static, and noncentral with `beta^T N_b beta`
//! when it moved by `beta`. The prediction takes part: a surface alone in facing a direction is
//! still tested against it, and its minimum detectable bias says how well (a start in motion,
//! whose prediction knows little, detects little, and the protection level shows it).

use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::thresholds::Thresholds;

/// One surface's rows in the stacked innovation.
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    pub surface: u64,
    pub rows: Range<usize>,
}

/// The lines of an epoch against the prediction: the innovation, its covariance, and the
/// position and velocity rows of `P H^T` with their own covariance, which give the gain.
#[derive(Debug, Clone, PartialEq)]
pub struct StackedInnovation<'a> {
    pub innovation: &'a DVector<f64>,
    pub covariance: &'a DMatrix<f64>,
    /// Six rows (position, velocity) of `P H^T`.
    pub cross: &'a DMatrix<f64>,
    /// Covariance of position and velocity before the update.
    pub prior: &'a DMatrix<f64>,
}

/// One surface's test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SurfaceTest {
    pub surface: u64,
    pub rows: usize,
    /// `sqrt(T_b)`.
    pub normalised_residual: f64,
    pub threshold: f64,
    /// Minimum detectable bias on the block's rows (m for offsets; a mixed norm when the
    /// block also has tilt rows, whose units are rad), over the weakest direction.
    pub mdb: f64,
}

/// Protection levels of position and velocity (navigation axes).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapProtection {
    pub position_m: [f64; 3],
    pub velocity_mps: [f64; 3],
}

/// What the map's test found in one epoch.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapIntegrity {
    /// The NIS of the rows kept, its degrees of freedom and its threshold.
    pub global: f64,
    pub dof: usize,
    pub global_threshold: f64,
    pub tests: Vec<SurfaceTest>,
    /// Surfaces excluded, in the order they were.
    pub excluded: Vec<u64>,
    /// A fault was detected that exclusion could not isolate: nothing is fused.
    pub not_isolable: bool,
    pub protection: Option<MapProtection>,
}

impl MapIntegrity {
    /// Whether the kept rows may be fused.
    pub fn usable(&self) -> bool {
        !self.not_isolable
    }
}

/// Tests the blocks, excluding the most suspect surface while the tests fire, up to
/// `max_exclusions` surfaces.
pub fn test_surfaces(
    stack: &StackedInnovation,
    blocks: &[Block],
    thresholds: &Thresholds,
    max_exclusions: usize,
) -> MapIntegrity {
    let mut kept: Vec<&Block> = blocks.iter().collect();
    let mut excluded = Vec::new();
    loop {
        let report = test_once(stack, &kept, thresholds);
        let fired = report.global > report.global_threshold
            || report
                .tests
                .iter()
                .any(|t| t.normalised_residual > t.threshold);
        if !fired || kept.is_empty() {
            return MapIntegrity { excluded, ..report };
        }
        if excluded.len() >= max_exclusions || kept.len() < 2 {
            return MapIntegrity {
                excluded,
                not_isolable: true,
                ..report
            };
        }
        let worst = report
            .tests
            .iter()
            .enumerate()
            .max_by(|a, b| severity(a.1).total_cmp(&severity(b.1)))
            .map(|(k, _)| k)
            .unwrap_or(0);
        excluded.push(kept.remove(worst).surface);
    }
}

fn severity(test: &SurfaceTest) -> f64 {
    test.normalised_residual / test.threshold
}

fn test_once(stack: &StackedInnovation, kept: &[&Block], thresholds: &Thresholds) -> MapIntegrity {
    let rows: Vec<usize> = kept.iter().flat_map(|b| b.rows.clone()).collect();
    let dof = rows.len();
    let empty = MapIntegrity {
        global: 0.0,
        dof,
        global_threshold: thresholds.global(dof.max(1)),
        tests: Vec::new(),
        excluded: Vec::new(),
        not_isolable: false,
        protection: None,
    };
    if rows.is_empty() {
        return empty;
    }
    let s = stack.covariance.select_rows(&rows).select_columns(&rows);
    let y = stack.innovation.select_rows(&rows);
    let Some(s_inv) = s.clone().try_inverse() else {
        return MapIntegrity {
            not_isolable: true,
            ..empty
        };
    };
    let u = &s_inv * &y;
    let cross = stack.cross.select_columns(&rows);
    let gain = &cross * &s_inv;
    let missed = thresholds.missed_detection_quantile;
    let mut fault = [0.0f64; 6];
    let mut at = 0;
    let mut tests = Vec::with_capacity(kept.len());
    for block in kept {
        let n = block.rows.len();
        let range = at..at + n;
        at += n;
        let n_b = s_inv.view((range.start, range.start), (n, n)).into_owned();
        let u_b = u.rows(range.start, n).into_owned();
        let threshold = thresholds.per_plane(n, kept.len());
        let (statistic, mdb, n_b_inv) = match n_b.clone().cholesky() {
            Some(cholesky) => {
                let weakest = n_b.symmetric_eigenvalues().min().max(0.0);
                (
                    cholesky.solve(&u_b).dot(&u_b).max(0.0).sqrt(),
                    (threshold + missed) / weakest.sqrt(),
                    Some(cholesky.inverse()),
                )
            }
            None => (0.0, f64::INFINITY, None),
        };
        let gain_b = gain.columns(range.start, n);
        for (axis, worst) in fault.iter_mut().enumerate() {
            let slope = match &n_b_inv {
                Some(inverse) => {
                    let k = gain_b.row(axis).transpose();
                    (k.transpose() * inverse * &k)[(0, 0)].max(0.0).sqrt()
                }
                None => f64::INFINITY,
            };
            *worst = worst.max(slope * (threshold + missed));
        }
        tests.push(SurfaceTest {
            surface: block.surface,
            rows: n,
            normalised_residual: statistic,
            threshold,
            mdb,
        });
    }
    let posterior = stack.prior - &gain * cross.transpose();
    let noise = |axis: usize| thresholds.noise_quantile * posterior[(axis, axis)].max(0.0).sqrt();
    let level = |axis: usize| fault[axis] + noise(axis);
    MapIntegrity {
        global: u.dot(&y),
        tests,
        protection: Some(MapProtection {
            position_m: [0, 1, 2].map(level),
            velocity_mps: [3, 4, 5].map(level),
        }),
        ..empty
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two surfaces measured with one row each against a prediction they share, plus a third.
    fn stack(y: [f64; 3]) -> (DVector<f64>, DMatrix<f64>, DMatrix<f64>, DMatrix<f64>) {
        // x (position along one axis) has prior sigma 0.1; three rows each y_k = x + e_k with
        // sigma 0.01: S = 0.01 * 1 1^T + 1e-4 I.
        let innovation = DVector::from_column_slice(&y);
        let covariance = DMatrix::from_fn(3, 3, |r, c| 0.01 + if r == c { 1e-4 } else { 0.0 });
        let mut cross = DMatrix::zeros(6, 3);
        cross.row_mut(0).fill(0.01);
        let mut prior = DMatrix::identity(6, 6) * 1e-6;
        prior[(0, 0)] = 0.01;
        (innovation, covariance, cross, prior)
    }

    fn blocks() -> Vec<Block> {
        (0..3)
            .map(|k| Block {
                surface: 10 + k as u64,
                rows: k..k + 1,
            })
            .collect()
    }

    /// The three surfaces' test with one exclusion allowed.
    fn verdict(y: [f64; 3]) -> MapIntegrity {
        let (innovation, covariance, cross, prior) = stack(y);
        let stacked = StackedInnovation {
            innovation: &innovation,
            covariance: &covariance,
            cross: &cross,
            prior: &prior,
        };
        test_surfaces(&stacked, &blocks(), &Thresholds::new(1e-3, 1e-3), 1)
    }

    #[test]
    fn a_surface_that_moved_is_found_and_excluded() {
        let report = verdict([0.05, 0.051, 0.2]);
        assert_eq!(report.excluded, vec![12]);
        assert!(report.usable());
        assert!(report.global <= report.global_threshold);
        let level = report.protection.unwrap().position_m[0];
        assert!(level > 0.01 && level < 0.2, "{level}");
    }

    #[test]
    fn agreeing_surfaces_pass_and_two_faults_are_not_isolable_with_one_exclusion() {
        let report = verdict([0.05, 0.051, 0.049]);
        assert!(report.excluded.is_empty() && report.usable());
        assert_eq!(report.tests.len(), 3);
        assert!(!verdict([0.05, 0.3, -0.2]).usable());
    }
}
