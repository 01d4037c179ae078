//! A building's level surfaces as a measurement of the vertical: a body direction that lies in
//! a level floor or ceiling is square to gravity.

use nalgebra::{Matrix2, Matrix3, Vector3};

use super::{Eskf, UpdateError, UpdateKind, UpdateReport};
use crate::filter::state::ATT;
use crate::filter::update::{Jacobian3, Observability, Stacked};

/// A body direction a building holds level, and the variance of its sine against the vertical:
/// the surface's normal error along it and how level the building is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevelDirection {
    pub body: Vector3<f64>,
    pub variance: f64,
}

impl Eskf {
    /// The sigma, rad, of the filter's tilt about the horizontal axis that tips `body` out of
    /// level: what a level direction along it would measure.
    pub(crate) fn tilt_sigma_along(&self, body: &Vector3<f64>) -> f64 {
        let h = self.level_jacobian(body);
        let attitude: Matrix3<f64> = self.covariance.fixed_view::<3, 3>(ATT, ATT).into();
        (h.transpose() * attitude * h).x.max(0.0).sqrt()
    }

    /// The sigma, rad, of the filter's tilt about the horizontal axis it knows worst: no level
    /// direction measures more.
    pub(crate) fn largest_tilt_sigma(&self) -> f64 {
        let tilt: Matrix2<f64> = self.covariance.fixed_view::<2, 2>(ATT, ATT).into();
        tilt.symmetric_eigenvalues().max().max(0.0).sqrt()
    }

    /// Fuses `direction . down = 0` for up to three level directions of one surface; the gate
    /// refuses them together if the surface is not level after all.
    pub(crate) fn update_level_directions(
        &mut self,
        level: &[LevelDirection],
    ) -> Result<UpdateReport, UpdateError> {
        let t = self.aligned_time()?;
        let down = self.state.q.inverse_transform_vector(&Vector3::z());
        let mut innovation = Vector3::zeros();
        let mut noise = Matrix3::identity();
        let mut jacobian = Jacobian3::zeros();
        let rows = level.len().min(3);
        for (k, direction) in level.iter().take(rows).enumerate() {
            innovation[k] = -direction.body.dot(&down);
            noise[(k, k)] = direction.variance;
            jacobian
                .fixed_view_mut::<1, 3>(k, ATT)
                .copy_from(&self.level_jacobian(&direction.body).transpose());
        }
        let unused = [Vector3::x(), Vector3::y(), Vector3::z()];
        let mut stacked = Stacked::default();
        stacked.push(
            &innovation,
            &jacobian,
            &noise,
            &Observability::from_unobservable(&unused[rows..]),
        );
        self.fuse(&stacked, UpdateKind::LevelDirections, t)
    }

    /// How `direction . down` moves with the global attitude error (`q <- Exp(dtheta) q`):
    /// `down = R^T z` turns by `-dtheta`, so the derivative is `(R direction) x z`.
    fn level_jacobian(&self, body: &Vector3<f64>) -> Vector3<f64> {
        self.state.q.transform_vector(body).cross(&Vector3::z())
    }
}
