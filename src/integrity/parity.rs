//! Parity space of one weighted least-squares solve (eqs 34-40) and the per-plane tests on it.
//!
//! The system `y = H x + e`, `e ~ N(0, R)` is whitened with the Cholesky factor `R = L L^T`
//! (any square root of `R` whitens; Cholesky keeps the block-by-plane structure and is cheap).
//! The last `m - 3` rows of the full `Q^T` of `L^-1 H` form the parity basis `V` (`V L^-1 H = 0`,
//! `V V^T = I`), and `G = V L^-1` maps raw measurements to the parity vector `p = G y` (eq 36),
//! whose covariance `G R G^T` (eq 38 with eq 37 or 44 as `R`) is the identity: noise is
//! `N(0, I)` and a bias `b` on the rows of plane `k` adds `G_k b`, where `G_k` holds the columns
//! of `G` for those rows.
//!
//! Per plane the test is Baarda's w-test generalised to the plane's `d` rows (1 for
//! displacement, 2 tangent rows for rotation; a plane with more rows is refused): with
//! `N_k = G_k^T G_k` and `u_k = G_k^T p`, the statistic `T_k = u_k^T N_k^-1 u_k` is chi-square
//! with `d` degrees of freedom when the plane is fault free and noncentral with `b^T N_k b` when
//! it carries bias `b`. It is the most powerful
//! test for a fault confined to that plane, and `sqrt(T_k)` is the plane's normalised residual
//! (signed when `d = 1`: then it is `r_k / sigma(r_k)`, residual over its predicted sigma).
//! The threshold `gamma_k` (eq 39) comes from the false-alarm budget, and a bias is detected with
//! probability `1 - Pmd` once `b^T N_k b >= (gamma_k + z_(1-Pmd))^2`: the minimum detectable
//! bias (eq 40) is that noncentrality over the weakest direction, `(gamma_k + z) / sqrt(lambda_min
//! (N_k))`, in the row units (metres for displacement; for rotation the norm of the bias on the
//! two orthonormal tangent rows, i.e. the angle in radians by which the plane's normal turned).
//! A direction of `N_k` with (almost) no redundancy cannot be tested: the plane's MDB, slope and
//! so the protection levels are then infinite, which is the honest answer (e.g. rotation with
//! two planes, or the only plane that observes an axis).
//!
//! The paper's eq 39-40 index the parity components by plane, which only holds for diagonal
//! cases; the w-test above is the per-plane statistic those equations intend.

use super::protection::{protection_levels, ProtectionLevels};
use super::thresholds::Thresholds;
use crate::least_squares::LinearSystem;
use nalgebra::{DMatrix, DVector, Matrix3, Matrix3xX, Vector3};
use serde::Serialize;
use thiserror::Error;

/// A direction of a plane's bias counts as untestable when less than this fraction of its
/// information reaches the parity space (its redundancy number).
const UNTESTABLE_REDUNDANCY: f64 = 1e-9;

/// Why a solve could not be tested; the epoch is then `UnderDetermined`.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Untestable {
    #[error("{planes} planes, fewer than the {minimum} needed to test")]
    TooFewPlanes { planes: usize, minimum: usize },
    #[error("{rows} rows for 3 unknowns leave nothing to test")]
    NoRedundancy { rows: usize },
    #[error("whitened geometry condition number {condition:.3e} is above the limit {limit:.3e}")]
    IllConditioned { condition: f64, limit: f64 },
    #[error("measurement covariance is not positive definite")]
    BadCovariance,
    #[error("malformed system: {0}")]
    Malformed(&'static str),
    #[error("solve failed: {0}")]
    Solve(crate::least_squares::SolveError),
}

/// The parity space of a system, kept for callers that want to look inside the test.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ParitySpace {
    /// `L` with `R = L L^T`.
    pub square_root: DMatrix<f64>,
    /// `G = V L^-1`: raw measurements to parity (the paper's `Q_p` with weights).
    pub parity_map: DMatrix<f64>,
    /// `p = G y` (eq 36), distributed `N(0, I)` without fault.
    pub parity: DVector<f64>,
    /// `(H^T R^-1 H)^-1`.
    pub covariance: Matrix3<f64>,
    /// `P H^T R^-1`: how each row's bias moves the estimate.
    pub gain: Matrix3xX<f64>,
    /// Ratio of the largest to the smallest singular value of `L^-1 H`.
    pub condition: f64,
    /// Squared norm of each column of `L^-1`: a row's information, the scale of its redundancy.
    row_information: Vec<f64>,
}

impl ParitySpace {
    /// `V = G L`: orthonormal basis of the left null space of the whitened geometry `L^-1 H`.
    #[cfg(test)]
    pub(crate) fn basis(&self) -> DMatrix<f64> {
        &self.parity_map * &self.square_root
    }
}

/// One plane's test, in the units of its rows. Infinite values serialise as JSON `null`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlaneTest {
    pub plane: usize,
    pub rows: usize,
    /// Testable directions of the plane's bias (its statistic's degrees of freedom).
    pub dof: usize,
    /// `sqrt(T_k)`, signed for one row; 0 when the plane cannot be tested.
    pub normalised_residual: f64,
    /// `gamma_k` (eq 39); infinite when the plane cannot be tested.
    pub threshold: f64,
    /// Minimum detectable bias (eq 40) in row units; infinite when some direction is untestable.
    pub mdb: f64,
    /// Largest error on each axis of the estimate per unit of the plane's test noncentrality
    /// (the RAIM slope); infinite when a bias on the plane can hide from the test.
    pub slope: [f64; 3],
}

impl PlaneTest {
    pub(crate) fn fired(&self) -> bool {
        self.normalised_residual.abs() > self.threshold
    }

    /// How far past (> 1) or short of (< 1) its threshold the plane's statistic is.
    pub(crate) fn severity(&self) -> f64 {
        self.normalised_residual.abs() / self.threshold
    }
}

/// Everything one solve's test found, ready for epochs.jsonl and Monte Carlo studies.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SolveTest {
    /// `m - 3`, the dimension of the parity space.
    pub redundancy: usize,
    pub condition: f64,
    pub parity: Vec<f64>,
    /// `|p|^2`, chi-square with `redundancy` degrees of freedom without fault.
    pub chi_square: f64,
    pub chi_square_threshold: f64,
    pub planes: Vec<PlaneTest>,
    /// `y - H x`, one per row of the system, in row units.
    pub residuals: Vec<f64>,
    /// Predicted sigma of each residual, `sqrt(diag(R - H P H^T))`.
    pub residual_sigmas: Vec<f64>,
    /// Predicted sigma of each axis of the estimate, `sqrt(diag(P))`.
    pub estimate_sigmas: [f64; 3],
    pub protection: ProtectionLevels,
    /// Unit directions of the estimate along which a bias on one plane moves it without
    /// reaching the parity space (a plane alone in observing them): no test can catch a fault
    /// there, so the fusion must not trust the estimate along them.
    pub unprotected: Vec<[f64; 3]>,
    pub detected: bool,
    /// Each plane's testable directions in the parity space, whitened (orthonormal columns
    /// `G_k u`), side by side; only exclusion needs them, so they are kept only when the test
    /// fired (empty otherwise).
    #[serde(skip)]
    signatures: DMatrix<f64>,
    /// Per plane (as in `planes`), its first column in `signatures` and how many it has.
    #[serde(skip)]
    signature_columns: Vec<(usize, usize)>,
}

impl SolveTest {
    #[cfg(test)]
    pub(crate) fn global_fired(&self) -> bool {
        self.chi_square > self.chi_square_threshold
    }

    /// The plane with the largest statistic relative to its threshold: the one to exclude.
    pub(crate) fn most_suspect(&self) -> Option<&PlaneTest> {
        self.planes
            .iter()
            .filter(|plane| plane.dof > 0)
            .max_by(|a, b| a.severity().total_cmp(&b.severity()))
    }

    pub fn plane(&self, id: usize) -> Option<&PlaneTest> {
        self.planes.iter().find(|plane| plane.plane == id)
    }

    /// Canonical correlation of the tests of planes `a` and `b` (plane ids), if both are here
    /// and the test fired: how alike a fault on one moves both statistics (the largest
    /// singular value of `W_a^T W_b`; 0 when either plane cannot be tested). Near 1 the
    /// largest-residual rule cannot tell the two apart.
    pub(crate) fn correlation(&self, a: usize, b: usize) -> Option<f64> {
        let columns = |id| {
            let index = self.planes.iter().position(|plane| plane.plane == id)?;
            self.signature_columns.get(index).copied()
        };
        let ((a_first, a_count), (b_first, b_count)) = (columns(a)?, columns(b)?);
        if a_count == 0 || b_count == 0 {
            return Some(0.0);
        }
        let column = |c: usize| self.signatures.column(c);
        let mut cross = [[0.0; 2]; 2];
        for (i, row) in cross.iter_mut().enumerate().take(a_count) {
            for (j, entry) in row.iter_mut().enumerate().take(b_count) {
                *entry = column(a_first + i).dot(&column(b_first + j));
            }
        }
        let square =
            [0, 1].map(|i| [0, 1].map(|k| cross[i][0] * cross[k][0] + cross[i][1] * cross[k][1]));
        let (eigenvalues, _) = symmetric_eigen_2(&square, a_count);
        Some(eigenvalues[0].max(eigenvalues[1]).max(0.0).sqrt().min(1.0))
    }
}

/// The rows of one plane: one (displacement) or two (rotation tangent rows).
#[derive(Debug, Clone, Copy)]
struct PlaneRows {
    plane: usize,
    rows: [usize; 2],
    count: usize,
}

impl PlaneRows {
    fn rows(&self) -> &[usize] {
        &self.rows[..self.count]
    }
}

/// Rows grouped by plane, planes in order of first appearance.
fn group_rows(system: &LinearSystem) -> Result<Vec<PlaneRows>, Untestable> {
    let mut planes: Vec<PlaneRows> = Vec::with_capacity(system.rows());
    for (row, &plane) in system.plane_of_row.iter().enumerate() {
        match planes.iter_mut().find(|p| p.plane == plane) {
            Some(p) if p.count == 2 => {
                return Err(Untestable::Malformed("a plane has more than two rows"))
            }
            Some(p) => {
                p.rows[1] = row;
                p.count = 2;
            }
            None => planes.push(PlaneRows {
                plane,
                rows: [row, row],
                count: 1,
            }),
        }
    }
    Ok(planes)
}

fn check_shape(system: &LinearSystem) -> Result<(), Untestable> {
    let m = system.rows();
    if system.h.nrows() != m || system.h.ncols() != 3 {
        return Err(Untestable::Malformed("H is not rows x 3"));
    }
    if system.r.nrows() != m || system.r.ncols() != m || system.plane_of_row.len() != m {
        return Err(Untestable::Malformed(
            "R or plane_of_row does not match the rows",
        ));
    }
    // A NaN or infinity anywhere makes the sum non-finite; summing is the cheap way to look.
    let total = system.h.sum() + system.y.sum() + system.r.sum();
    if !total.is_finite() {
        return Err(Untestable::Malformed("non-finite entry"));
    }
    Ok(())
}

/// Parity space of `system`, refusing (rather than inverting) a geometry whose whitened
/// condition number exceeds `max_condition`.
pub(crate) fn parity_space(
    system: &LinearSystem,
    max_condition: f64,
) -> Result<ParitySpace, Untestable> {
    check_shape(system)?;
    let m = system.rows();
    if m <= 3 {
        return Err(Untestable::NoRedundancy { rows: m });
    }
    let (square_root, whitening) = match block_square_root(system) {
        Some(factors) => factors,
        None => {
            let cholesky = system
                .r
                .clone()
                .cholesky()
                .ok_or(Untestable::BadCovariance)?;
            let square_root = cholesky.unpack();
            let whitening = lower_triangular_inverse(&square_root);
            (square_root, whitening)
        }
    };
    let whitened_h = &whitening * &system.h;
    let qr = whitened_h.qr();
    let r1: Matrix3<f64> = qr.r().fixed_view::<3, 3>(0, 0).into();
    // Singular values of L^-1 H are the square roots of the eigenvalues of R1^T R1.
    let eigenvalues = r1.tr_mul(&r1).symmetric_eigenvalues();
    let condition = (eigenvalues.max() / eigenvalues.min()).sqrt();
    let ill = Untestable::IllConditioned {
        condition,
        limit: max_condition,
    };
    if condition.is_nan() || condition > max_condition {
        return Err(ill);
    }
    let r1_inv = r1.try_inverse().ok_or(ill)?;
    let covariance = r1_inv * r1_inv.transpose();
    // Q^T L^-1 in one pass: its last m - 3 rows are G = V L^-1, and as L^-1 H = Q1 R1 the
    // first three give the gain P H^T R^-1 = R1^-1 Q1^T L^-1.
    let mut rotated = whitening;
    qr.q_tr_mul(&mut rotated);
    let row_information = rotated.column_iter().map(|c| c.norm_squared()).collect();
    let gain = r1_inv * rotated.fixed_rows::<3>(0);
    let parity_map = rotated.rows(3, m - 3).into_owned();
    let parity = &parity_map * &system.y;
    Ok(ParitySpace {
        square_root,
        row_information,
        parity_map,
        parity,
        covariance,
        gain,
        condition,
    })
}

/// The Cholesky factor of R and its inverse when R only correlates the rows of one plane (the
/// odometer's solves: one row or two tangent rows per plane), block by block instead of by a
/// dense factorisation and inversion: half the work of a test. `None` (the dense path decides)
/// when R couples planes or a block is not positive definite.
fn block_square_root(system: &LinearSystem) -> Option<(DMatrix<f64>, DMatrix<f64>)> {
    let m = system.rows();
    let plane = &system.plane_of_row;
    for j in 0..m {
        for i in j + 1..m {
            if plane[i] != plane[j] && system.r[(i, j)] != 0.0 {
                return None;
            }
        }
    }
    let (mut square_root, mut inverse) = (DMatrix::zeros(m, m), DMatrix::zeros(m, m));
    for rows in group_rows(system).ok()? {
        let first = rows.rows[0];
        let diagonal = system.r[(first, first)];
        if diagonal <= 0.0 {
            return None;
        }
        let l00 = diagonal.sqrt();
        square_root[(first, first)] = l00;
        inverse[(first, first)] = 1.0 / l00;
        if rows.count == 2 {
            let second = rows.rows[1];
            let l10 = system.r[(second, first)] / l00;
            let rest = system.r[(second, second)] - l10 * l10;
            if rest <= 0.0 {
                return None;
            }
            let l11 = rest.sqrt();
            square_root[(second, first)] = l10;
            square_root[(second, second)] = l11;
            inverse[(second, first)] = -l10 / (l00 * l11);
            inverse[(second, second)] = 1.0 / l11;
        }
    }
    Some((square_root, inverse))
}

/// Inverse of a lower-triangular matrix with a positive diagonal (a Cholesky factor), by forward
/// substitution that skips the known zeros: a sixth of the work of a general triangular solve.
fn lower_triangular_inverse(l: &DMatrix<f64>) -> DMatrix<f64> {
    let m = l.nrows();
    let mut inverse = DMatrix::zeros(m, m);
    for j in 0..m {
        inverse[(j, j)] = 1.0 / l[(j, j)];
        for i in j + 1..m {
            let sum: f64 = (j..i).map(|k| l[(i, k)] * inverse[(k, j)]).sum();
            inverse[(i, j)] = -sum / l[(i, i)];
        }
    }
    inverse
}

/// Test one solve's system: global chi-square on `p`, and each plane's w-test.
pub(crate) fn test_system(
    system: &LinearSystem,
    thresholds: &Thresholds,
    min_planes: usize,
    max_condition: f64,
) -> Result<SolveTest, Untestable> {
    let groups = group_rows(system)?;
    if groups.len() < min_planes {
        return Err(Untestable::TooFewPlanes {
            planes: groups.len(),
            minimum: min_planes,
        });
    }
    let space = parity_space(system, max_condition)?;
    let redundancy = space.parity.len();
    let statistics: Vec<PlaneStatistic> = groups
        .iter()
        .map(|rows| plane_statistic(&space, rows))
        .collect();
    let tests = statistics.iter().filter(|s| s.test.dof > 0).count();
    let signatures: Vec<Signature> = statistics.iter().map(|s| s.signature).collect();
    let unprotected = statistics
        .iter()
        .flat_map(|s| s.hidden_shifts.iter().flatten())
        .filter(|shift| shift.norm() > 0.0)
        .map(|shift| shift.normalize().into())
        .collect();
    let planes: Vec<PlaneTest> = statistics
        .into_iter()
        .map(|statistic| {
            let gamma = if redundancy == 1 {
                thresholds.sole()
            } else {
                thresholds.per_plane(statistic.test.dof, tests)
            };
            with_threshold(statistic.test, statistic.weakest_root, thresholds, gamma)
        })
        .collect();
    let chi_square = space.parity.norm_squared();
    let chi_square_threshold = if redundancy == 1 {
        thresholds.sole().powi(2)
    } else {
        thresholds.global(redundancy)
    };
    let residuals = &system.y - &system.h * (&space.gain * &system.y);
    let detected = chi_square > chi_square_threshold || planes.iter().any(PlaneTest::fired);
    let (signatures, signature_columns) = if detected {
        whitened_signatures(&space, &signatures)
    } else {
        (DMatrix::zeros(0, 0), Vec::new())
    };
    let estimate_sigmas: [f64; 3] = space.covariance.diagonal().map(f64::sqrt).into();
    let protection = protection_levels(&planes, &estimate_sigmas, thresholds);
    Ok(SolveTest {
        redundancy,
        condition: space.condition,
        parity: space.parity.iter().copied().collect(),
        chi_square,
        chi_square_threshold,
        planes,
        residuals: residuals.iter().copied().collect(),
        residual_sigmas: residual_sigmas(system, &space.covariance),
        protection,
        estimate_sigmas,
        unprotected,
        detected,
        signatures,
        signature_columns,
    })
}

/// A plane's testable directions, whitened: with `N_k = V diag(lambda) V^T`, the columns
/// `u = v / sqrt(lambda)` of its testable eigenpairs, so that `G_k u` are orthonormal
/// directions of the parity space (at most two).
#[derive(Debug, Clone, Copy)]
struct Signature {
    rows: [usize; 2],
    directions: [[f64; 2]; 2],
    count: usize,
}

/// The parity directions `G_k u` of every plane's testable directions, side by side, with each
/// plane's first column and count.
fn whitened_signatures(
    space: &ParitySpace,
    signatures: &[Signature],
) -> (DMatrix<f64>, Vec<(usize, usize)>) {
    let total = signatures.iter().map(|s| s.count).sum();
    let mut columns = DMatrix::zeros(space.parity_map.nrows(), total);
    let mut spans = Vec::with_capacity(signatures.len());
    let mut next = 0;
    for signature in signatures {
        spans.push((next, signature.count));
        for direction in &signature.directions[..signature.count] {
            let mut column = columns.column_mut(next);
            // A one-row plane's second entry is zero (and its two rows are the same).
            for (row, weight) in signature.rows.iter().zip(direction) {
                column.axpy(*weight, &space.parity_map.column(*row), 1.0);
            }
            next += 1;
        }
    }
    (columns, spans)
}

/// One plane's test before its threshold, which needs the number of tests.
struct PlaneStatistic {
    test: PlaneTest,
    /// `sqrt(lambda_min(N_k))`, 0 when a direction is untestable.
    weakest_root: f64,
    signature: Signature,
    /// Where a bias along each untestable direction moves the estimate (`S_k v`).
    hidden_shifts: [Option<Vector3<f64>>; 2],
}

/// The plane's statistic and slopes, and where its untestable bias would move the estimate.
fn plane_statistic(space: &ParitySpace, plane: &PlaneRows) -> PlaneStatistic {
    let rows = plane.rows();
    let d = rows.len();
    let parity_column = |a: usize| space.parity_map.column(rows[a.min(d - 1)]);
    // Entries beyond the plane's rows are computed but never read.
    let information = [0, 1].map(|a| [0, 1].map(|b| parity_column(a).dot(&parity_column(b))));
    let projection = [0, 1].map(|a| parity_column(a).dot(&space.parity));
    let scale: f64 = rows.iter().map(|&row| space.row_information[row]).sum();
    let (eigenvalues, eigenvectors) = symmetric_eigen_2(&information, d);
    let mut statistic = 0.0;
    let mut slope_squared = Vector3::zeros();
    let mut dof = 0;
    let mut signature = Signature {
        rows: [rows[0], rows[d - 1]],
        directions: [[0.0; 2]; 2],
        count: 0,
    };
    let mut hidden_shifts = [None; 2];
    let shift = |direction: [f64; 2]| -> Vector3<f64> {
        (0..d)
            .map(|a| space.gain.column(rows[a]) * direction[a])
            .sum()
    };
    for j in 0..d {
        let (lambda, direction) = (eigenvalues[j], eigenvectors[j]);
        if lambda <= UNTESTABLE_REDUNDANCY * scale {
            hidden_shifts[j] = Some(shift(direction));
        } else {
            dof += 1;
            signature.directions[signature.count] = direction.map(|v| v / lambda.sqrt());
            signature.count += 1;
            let along = direction[0] * projection[0] + direction[1] * projection[1];
            statistic += along * along / lambda;
            let moved = shift(direction);
            slope_squared += moved.component_mul(&moved) / lambda;
        }
    }
    let all_testable = dof == d;
    let normalised_residual = match (d, dof) {
        (_, 0) => 0.0,
        (1, _) => projection[0] / information[0][0].sqrt(),
        _ => statistic.sqrt(),
    };
    let plane_test = PlaneTest {
        plane: plane.plane,
        rows: d,
        dof,
        normalised_residual,
        threshold: f64::INFINITY,
        mdb: f64::INFINITY,
        slope: if all_testable {
            slope_squared.map(f64::sqrt).into()
        } else {
            [f64::INFINITY; 3]
        },
    };
    let weakest = eigenvalues[..d]
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    PlaneStatistic {
        test: plane_test,
        weakest_root: if all_testable { weakest.sqrt() } else { 0.0 },
        signature,
        hidden_shifts,
    }
}

/// Eigenvalues and unit eigenvectors of the leading `d x d` (1 or 2) block of a symmetric matrix.
fn symmetric_eigen_2(m: &[[f64; 2]; 2], d: usize) -> ([f64; 2], [[f64; 2]; 2]) {
    if d == 1 {
        return ([m[0][0], 0.0], [[1.0, 0.0], [0.0, 1.0]]);
    }
    let mean = 0.5 * (m[0][0] + m[1][1]);
    let radius = (0.5 * (m[0][0] - m[1][1])).hypot(m[0][1]);
    let angle = 0.5 * (2.0 * m[0][1]).atan2(m[0][0] - m[1][1]);
    let (sin, cos) = angle.sin_cos();
    ([mean + radius, mean - radius], [[cos, sin], [-sin, cos]])
}

/// The plane's threshold `gamma` (kept infinite when nothing of the plane is testable) and
/// the MDB it gives.
fn with_threshold(
    mut plane: PlaneTest,
    weakest_root: f64,
    thresholds: &Thresholds,
    gamma: f64,
) -> PlaneTest {
    if plane.dof > 0 {
        plane.threshold = gamma;
    }
    if weakest_root > 0.0 {
        plane.mdb = (plane.threshold + thresholds.missed_detection_quantile) / weakest_root;
    }
    plane
}

fn residual_sigmas(system: &LinearSystem, covariance: &Matrix3<f64>) -> Vec<f64> {
    (0..system.rows())
        .map(|i| {
            let h: Vector3<f64> = system.h.fixed_view::<1, 3>(i, 0).transpose();
            let explained = h.dot(&(covariance * h));
            (system.r[(i, i)] - explained).max(0.0).sqrt()
        })
        .collect()
}

#[cfg(test)]
mod block_tests {
    use super::*;
    use nalgebra::DVector;

    /// Rows 0, 2 of plane 7 (interleaved with plane 3's row 1), plane 5 on rows 3 and 4.
    fn system(coupling: f64) -> LinearSystem {
        let mut r = DMatrix::from_diagonal(&DVector::from_vec(vec![4e-4, 1e-4, 2e-4, 3e-4, 5e-4]));
        for (i, j, v) in [(2, 0, 1.5e-4), (4, 3, -2e-4), (1, 0, coupling)] {
            r[(i, j)] = v;
            r[(j, i)] = v;
        }
        LinearSystem {
            h: DMatrix::from_fn(5, 3, |i, j| ((i * 3 + j) as f64).sin()),
            y: DVector::zeros(5),
            r,
            plane_of_row: vec![7, 3, 7, 5, 5],
        }
    }

    #[test]
    fn block_factors_equal_the_dense_cholesky_and_coupled_planes_fall_back() {
        let system = system(0.0);
        let (square_root, inverse) = block_square_root(&system).unwrap();
        let dense = system.r.clone().cholesky().unwrap().unpack();
        assert!((&square_root - &dense).norm() < 1e-15);
        let identity = &inverse * &square_root;
        assert!((identity - DMatrix::<f64>::identity(5, 5)).norm() < 1e-12);
        assert!(block_square_root(&self::system(1e-5)).is_none());
    }
}
