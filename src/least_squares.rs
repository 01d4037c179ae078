//! The shape every odometer solve hands to integrity: a linearised weighted least-squares
//! problem `y = H x + e`, `e ~ N(0, R)`, in three unknowns, with each row tagged by the plane it
//! came from. Displacement (eq 2) and rotation (eqs 6-7) both produce one of these.

use nalgebra::{Cholesky, DMatrix, DVector, Dyn, Matrix3, SymmetricEigen, Vector3};
use std::fmt;

/// Relative eigenvalue of the information matrix below which a direction counts as unobserved.
/// Planes within about 0.5 deg of parallel leave their common normal's complement this weak.
pub(crate) const OBSERVABILITY_TOLERANCE: f64 = 1e-6;

/// Relative eigenvalue of the normals' own geometry below which a direction counts as
/// unobserved by the planes, whatever their weights: normals within about 1.8 deg of parallel
/// (`sum n n^T` for a displacement, `sum (I - n n^T)` for a rotation). Two walls of a corridor
/// measured a few milliradians off parallel would otherwise "observe" the direction between
/// their normals' errors (for the displacement, the motion along the corridor; for the
/// rotation, the turn about their common normal); along it the rows hold little but those
/// errors times the motion, which fused told the filter the corridor's velocity far more
/// precisely than any surface had measured it. The weights do not enter: a direction is seen
/// by surfaces that face it, however well or badly they were measured.
pub(crate) const PARALLEL_TOLERANCE: f64 = 1e-3;

#[derive(Debug, Clone, PartialEq)]
pub struct LinearSystem {
    /// Geometry matrix, rows x 3.
    pub h: DMatrix<f64>,
    /// Measurements (or, for an iterated solve, the residual at the linearisation point).
    pub y: DVector<f64>,
    /// Measurement covariance, rows x rows (block diagonal by plane).
    pub r: DMatrix<f64>,
    /// For each row, the index of the matched plane it came from.
    pub plane_of_row: Vec<usize>,
}

/// A least-squares estimate with everything integrity and the filter need to judge it.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    pub x: Vector3<f64>,
    pub covariance: Matrix3<f64>,
    /// `y - H x`, one per row of `system`.
    pub residuals: DVector<f64>,
    pub system: LinearSystem,
    pub dilution: Dilution,
}

/// DOP-like figures: square roots of the diagonal of `(H^T H)^-1` and its condition number.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dilution {
    pub per_axis: Vector3<f64>,
    pub condition: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub enum SolveError {
    /// The planes do not pin down every axis; `unobservable` spans the directions left free.
    UnderDetermined { unobservable: Vec<Vector3<f64>> },
    /// The measurement covariance is not positive definite.
    BadCovariance,
}

impl fmt::Display for SolveError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::UnderDetermined { unobservable } => {
                write!(f, "under-determined: no plane constrains direction(s)")?;
                for d in unobservable {
                    write!(f, " [{:.3} {:.3} {:.3}]", d.x, d.y, d.z)?;
                }
                Ok(())
            }
            Self::BadCovariance => write!(f, "measurement covariance is not positive definite"),
        }
    }
}

impl std::error::Error for SolveError {}

impl LinearSystem {
    pub fn rows(&self) -> usize {
        self.y.len()
    }

    /// Weighted least squares, refusing rather than inverting an ill-conditioned geometry
    /// (directions whose information is at most `OBSERVABILITY_TOLERANCE` of the strongest's).
    pub fn solve(self) -> Result<Solution, SolveError> {
        let r_chol = self.r.clone().cholesky().ok_or(SolveError::BadCovariance)?;
        let r_inv_y = r_chol.solve(&self.y);
        let information = self.information(&r_chol);
        let unobservable = directions_below(&information, OBSERVABILITY_TOLERANCE);
        if !unobservable.is_empty() {
            return Err(SolveError::UnderDetermined { unobservable });
        }
        let covariance = information
            .try_inverse()
            .ok_or_else(|| SolveError::UnderDetermined {
                unobservable: weakest_directions(&information),
            })?;
        let hty: Vector3<f64> = (self.h.transpose() * r_inv_y).fixed_rows::<3>(0).into();
        let x = covariance * hty;
        let residuals = &self.y - &self.h * x;
        let dilution = dilution(&self.h);
        Ok(Solution {
            x,
            covariance,
            residuals,
            system: self,
            dilution,
        })
    }

    /// As `solve`, for rows whose `H` are unit normals, judging what they observe on the normals
    /// alone (`H^T H` within `PARALLEL_TOLERANCE`): a far wall measured to centimetres beside a
    /// floor measured to a fraction of a millimetre still observes the motion it faces. The
    /// directions it then names free are the weighted information's weakest, those the
    /// observed directions must be square to: any other choice would hand the observed ones a
    /// share of whatever is assumed along the free ones.
    pub(crate) fn solve_on_normals(self) -> Result<Solution, SolveError> {
        let free = directions_below(&gram(&self.h), PARALLEL_TOLERANCE).len();
        if free == 0 {
            return self.solve();
        }
        let r_chol = self.r.clone().cholesky().ok_or(SolveError::BadCovariance)?;
        let eigen = SymmetricEigen::new(self.information(&r_chol));
        let mut order: Vec<usize> = (0..3).collect();
        order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
        let unobservable = order[..free.min(3)]
            .iter()
            .map(|&i| eigen.eigenvectors.column(i).into_owned())
            .collect();
        Err(SolveError::UnderDetermined { unobservable })
    }

    /// `H^T R^-1 H`, given the Cholesky factor of `R`.
    fn information(&self, r_chol: &Cholesky<f64, Dyn>) -> Matrix3<f64> {
        (self.h.transpose() * r_chol.solve(&self.h))
            .fixed_view::<3, 3>(0, 0)
            .into()
    }
}

/// Eigenvectors of the information matrix whose eigenvalue is negligible against the largest.
pub(crate) fn weakest_directions(information: &Matrix3<f64>) -> Vec<Vector3<f64>> {
    directions_below(information, OBSERVABILITY_TOLERANCE)
}

/// Eigenvectors of a symmetric matrix whose eigenvalue is at most `tolerance` of the largest.
pub(crate) fn directions_below(matrix: &Matrix3<f64>, tolerance: f64) -> Vec<Vector3<f64>> {
    let eigen = SymmetricEigen::new(*matrix);
    let largest = eigen.eigenvalues.amax();
    (0..3)
        .filter(|&i| {
            let value = eigen.eigenvalues[i];
            value.is_nan() || value <= tolerance * largest
        })
        .map(|i| eigen.eigenvectors.column(i).into_owned())
        .collect()
}

/// `sum n n^T` of `normals`: how much of each direction they face together.
pub(crate) fn facing<'a>(normals: impl IntoIterator<Item = &'a Vector3<f64>>) -> Matrix3<f64> {
    normals.into_iter().map(|n| n * n.transpose()).sum()
}

/// `H^T H`: the rows' geometry without their weights.
fn gram(h: &DMatrix<f64>) -> Matrix3<f64> {
    (h.transpose() * h).fixed_view::<3, 3>(0, 0).into()
}

fn dilution(h: &DMatrix<f64>) -> Dilution {
    let gram = gram(h);
    let eigen = SymmetricEigen::new(gram);
    let condition = eigen.eigenvalues.max() / eigen.eigenvalues.min().max(f64::MIN_POSITIVE);
    let per_axis = gram
        .try_inverse()
        .map(|inv| inv.diagonal().map(f64::sqrt))
        .unwrap_or_else(|| Vector3::repeat(f64::INFINITY));
    Dilution {
        per_axis,
        condition,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn system(normals: &[[f64; 3]], y: &[f64]) -> LinearSystem {
        let m = normals.len();
        LinearSystem {
            h: DMatrix::from_fn(m, 3, |i, j| normals[i][j]),
            y: DVector::from_column_slice(y),
            r: DMatrix::identity(m, m) * 1e-4,
            plane_of_row: (0..m).collect(),
        }
    }

    #[test]
    fn three_orthogonal_planes_give_the_exact_displacement() {
        let truth = Vector3::new(0.4, 0.6, -0.1);
        let normals = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let y: Vec<f64> = normals
            .iter()
            .map(|n| Vector3::from(*n).dot(&truth))
            .collect();
        let solution = system(&normals, &y).solve().unwrap();
        assert!((solution.x - truth).norm() < 1e-12);
        assert!((solution.covariance - Matrix3::identity() * 1e-4).norm() < 1e-15);
    }

    #[test]
    fn two_walls_leave_the_vertical_unobservable() {
        let normals = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, 0.8, 0.0]];
        let err = system(&normals, &[0.0; 3]).solve().unwrap_err();
        let SolveError::UnderDetermined { unobservable } = err else {
            panic!("{err}")
        };
        assert_eq!(unobservable.len(), 1);
        assert!((unobservable[0].z.abs() - 1.0).abs() < 1e-9);
    }
}
