//! Displacement between epochs (paper eqs 1-2): `rho_i - rho_j = n . dR` for every matched
//! plane, solved by weighted least squares with eq 37's covariance plus the term the normal's
//! own error adds, `dR^T Sigma_n dR`.
//!
//! `dR` is the position of body j's origin in body-i axes. When the rotation C = C_j^i is known,
//! the row's normal is the mean of `n_i` and `C n_j` (both measure the same direction), which
//! halves the normal-error variance; otherwise it is `n_i` as in the paper. The normal-error term
//! is evaluated at the prior `dR` only, never at an estimate from these same rows: a moving
//! plane drags that estimate (by metres along an axis the other planes barely see), and the
//! term evaluated there would inflate every row's variance with it, hiding the very bias the
//! integrity test looks for and making the solution's covariance meaningless (measured on
//! office-door, docs/figures.md section 4). Rows are tagged with the index of their match.

use super::matching::PlaneMatch;
use super::planes::Plane;
use crate::least_squares::{LinearSystem, Solution, SolveError};
use nalgebra::{DMatrix, DVector, Matrix3, UnitQuaternion, Vector3};

struct PlaneRow {
    normal: Vector3<f64>,
    normal_covariance: Matrix3<f64>,
    y: f64,
    distance_variance: f64,
}

impl PlaneRow {
    fn new(plane_i: &Plane, plane_j: &Plane, rotation: Option<&UnitQuaternion<f64>>) -> Self {
        let (normal, normal_covariance) = match rotation {
            Some(c) => {
                let c_matrix = c.to_rotation_matrix();
                let covariance = (plane_i.uncertainty.normal_covariance
                    + c_matrix * plane_j.uncertainty.normal_covariance * c_matrix.transpose())
                    / 4.0;
                (
                    (plane_i.normal + c * plane_j.normal).normalize(),
                    covariance,
                )
            }
            None => (plane_i.normal, plane_i.uncertainty.normal_covariance),
        };
        Self {
            normal,
            normal_covariance,
            y: plane_i.rho - plane_j.rho,
            distance_variance: plane_i.uncertainty.sigma_rho.powi(2)
                + plane_j.uncertainty.sigma_rho.powi(2),
        }
    }

    /// `E[dR^T Sigma_n dR]` over the prior `dR ~ (mean, covariance)`: at a well-known prior the
    /// familiar term at its mean, but along a direction the other planes leave unobserved the
    /// prior is vague, and a milliradian of normal error times a metre of motion nobody
    /// measured is a millimetre on this row, which read as information would tell that
    /// direction what no surface saw.
    fn variance(&self, mean: &Vector3<f64>, covariance: &Matrix3<f64>) -> f64 {
        self.distance_variance
            + mean.dot(&(self.normal_covariance * mean))
            + (self.normal_covariance * covariance).trace()
    }
}

/// Weighted least squares for dR, leaving out the matches listed in `excluded`, observing what
/// the planes' normals observe (`LinearSystem::solve_on_normals`).
pub(crate) fn solve_displacement(
    previous: &[Plane],
    current: &[Plane],
    matches: &[PlaneMatch],
    rotation: Option<&UnitQuaternion<f64>>,
    prior_displacement: &Vector3<f64>,
    prior_covariance: &Matrix3<f64>,
    excluded: &[usize],
) -> Result<Solution, SolveError> {
    let active = || {
        matches
            .iter()
            .enumerate()
            .filter(|(k, _)| !excluded.contains(k))
            .map(|(k, m)| {
                (
                    k,
                    PlaneRow::new(&previous[m.previous], &current[m.current], rotation),
                )
            })
    };
    let planes = active().count();
    let mut system = LinearSystem {
        h: DMatrix::zeros(planes, 3),
        y: DVector::zeros(planes),
        r: DMatrix::zeros(planes, planes),
        plane_of_row: Vec::with_capacity(planes),
    };
    for (row, (k, plane)) in active().enumerate() {
        let variance = plane.variance(prior_displacement, prior_covariance);
        if !variance.is_finite() || variance <= 0.0 {
            return Err(SolveError::BadCovariance);
        }
        system.h.row_mut(row).copy_from(&plane.normal.transpose());
        system.y[row] = plane.y;
        system.r[(row, row)] = variance;
        system.plane_of_row.push(k);
    }
    system.solve_on_normals()
}
