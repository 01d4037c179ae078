//! Rotation between epochs (paper section 2, eqs 3-7), improved as docs/design.md, 4.6 "Rotation",
//! says: the residual of each matched normal is taken in the 2-D tangent plane of `n_i`, so a plane
//! gives two independent rows whose covariance comes from both epochs' normal errors, and the
//! linearisation is iterated from the IMU prior to convergence.
//!
//! Conventions: `C = C_j^i` rotates body-j vectors into body i (`C n_j = n_i`, eq 3). Each step
//! perturbs on the left, `C <- exp([delta]x) C`, with `delta` in body-i axes. The returned
//! `Solution::x` is the rotation vector (scaled axis) of the final C; its `covariance` is that of
//! the left perturbation `delta`; its `system` is linearised at the final C, so the system's own
//! unknown is the last correction (about zero) and `residuals = y - H delta`. Rows come in pairs,
//! tagged with the index of their match.

use super::matching::PlaneMatch;
use super::planes::Plane;
use super::tangent_basis;
use crate::least_squares::{
    directions_below, weakest_directions, LinearSystem, Solution, SolveError, PARALLEL_TOLERANCE,
};
use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Matrix3x2, UnitQuaternion, Vector2, Vector3};

/// Iteration limits of the rotation solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct RotationParameters {
    pub max_iterations: usize,
    /// Stop when a correction is smaller than this, radians.
    pub tolerance_rad: f64,
}

/// The two tangent-plane rows of one matched plane, linearised at the current rotation.
struct PlaneRows {
    h: Matrix3x2<f64>,
    y: Vector2<f64>,
    r: Matrix2<f64>,
}

fn plane_rows(plane_i: &Plane, plane_j: &Plane, rotation: &UnitQuaternion<f64>) -> PlaneRows {
    let n_i = plane_i.normal;
    let predicted = rotation * plane_j.normal;
    let basis = tangent_basis(&n_i);
    // n_i - C n_j ~= delta x (C n_j), and t . (delta x m) = delta . (m x t).
    let h = Matrix3x2::from_columns(&[
        predicted.cross(&basis.column(0)),
        predicted.cross(&basis.column(1)),
    ]);
    let r_j = rotation.to_rotation_matrix();
    let covariance = plane_i.uncertainty.normal_covariance
        + r_j * plane_j.uncertainty.normal_covariance * r_j.transpose();
    PlaneRows {
        h,
        y: basis.transpose() * (n_i - predicted),
        r: basis.transpose() * covariance * basis,
    }
}

/// Gauss-Newton on SO(3) from `prior`, leaving out the matches listed in `excluded`.
pub(crate) fn solve_rotation(
    previous: &[Plane],
    current: &[Plane],
    matches: &[PlaneMatch],
    prior: &UnitQuaternion<f64>,
    excluded: &[usize],
    parameters: &RotationParameters,
) -> Result<Solution, SolveError> {
    // A plane whose normal is the filter's own vertical measures no rotation.
    let active = || {
        matches
            .iter()
            .enumerate()
            .filter(|(k, _)| !excluded.contains(k))
            .map(|(k, m)| (k, &previous[m.previous], &current[m.current]))
            .filter(|(_, i, j)| !i.normal_assumed && !j.normal_assumed)
    };
    let geometry: Matrix3<f64> = active()
        .map(|(_, plane_i, _)| Matrix3::identity() - plane_i.normal * plane_i.normal.transpose())
        .sum();
    let unobservable = directions_below(&geometry, PARALLEL_TOLERANCE);
    if !unobservable.is_empty() {
        return Err(SolveError::UnderDetermined { unobservable });
    }
    let mut rotation = *prior;
    for _ in 0..parameters.max_iterations {
        let mut information = Matrix3::zeros();
        let mut gradient = Vector3::zeros();
        for (_, plane_i, plane_j) in active() {
            let rows = plane_rows(plane_i, plane_j, &rotation);
            let weight = rows.r.try_inverse().ok_or(SolveError::BadCovariance)?;
            information += rows.h * weight * rows.h.transpose();
            gradient += rows.h * weight * rows.y;
        }
        let unobservable = weakest_directions(&information);
        if !unobservable.is_empty() {
            return Err(SolveError::UnderDetermined { unobservable });
        }
        let correction = information
            .cholesky()
            .ok_or(SolveError::BadCovariance)?
            .solve(&gradient);
        rotation = UnitQuaternion::from_scaled_axis(correction) * rotation;
        if correction.norm() < parameters.tolerance_rad {
            break;
        }
    }
    let planes = active().count();
    let rows = active().map(|(k, i, j)| (k, plane_rows(i, j, &rotation)));
    let mut solution = final_system(planes, rows).solve()?;
    solution.x = (UnitQuaternion::from_scaled_axis(solution.x) * rotation).scaled_axis();
    Ok(solution)
}

fn final_system(planes: usize, rows: impl Iterator<Item = (usize, PlaneRows)>) -> LinearSystem {
    let count = 2 * planes;
    let mut system = LinearSystem {
        h: DMatrix::zeros(count, 3),
        y: DVector::zeros(count),
        r: DMatrix::zeros(count, count),
        plane_of_row: Vec::with_capacity(count),
    };
    for (pair, (k, plane)) in rows.enumerate() {
        let row = 2 * pair;
        system
            .h
            .fixed_view_mut::<2, 3>(row, 0)
            .copy_from(&plane.h.transpose());
        system.y.fixed_rows_mut::<2>(row).copy_from(&plane.y);
        system
            .r
            .fixed_view_mut::<2, 2>(row, row)
            .copy_from(&plane.r);
        system.plane_of_row.extend([k, k]);
    }
    system
}
