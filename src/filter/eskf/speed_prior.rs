//! The platform's speed envelope as a prior on the velocity along the directions nothing
//! observes (`FilterConfig::speed_prior_sigma_mps`).

use nalgebra::{Matrix3, Vector3};

use super::{Eskf, UpdateKind, UpdateReport};
use crate::filter::state::VEL;
use crate::filter::update::{Jacobian3, Observability, Stacked};

impl Eskf {
    /// Fuses `v = 0 +- speed_prior_sigma_mps` along the velocity directions (navigation axes)
    /// whose sigma exceeds the prior's, once per `speed_prior_interval_s`. Along any other
    /// direction the prior would only add a little information the platform's motion does not
    /// justify; along these it bounds a velocity the IMU alone would let run off. Since it
    /// acts only where the filter knows less than it, a direction it holds keeps a sigma of at
    /// least `1 / sqrt(2)` times the prior's.
    pub(super) fn apply_speed_prior(&mut self, t: f64) -> Option<UpdateReport> {
        let sigma = self.config.speed_prior_sigma_mps;
        let due = self
            .last_speed_prior
            .is_none_or(|last| t - last >= self.config.speed_prior_interval_s);
        if sigma <= 0.0 || !due {
            return None;
        }
        self.last_speed_prior = Some(t);
        let velocity: Matrix3<f64> = self.covariance.fixed_view::<3, 3>(VEL, VEL).into();
        let eigen = velocity.symmetric_eigen();
        let known: Vec<Vector3<f64>> = (0..3)
            .filter(|&k| eigen.eigenvalues[k] <= sigma * sigma)
            .map(|k| eigen.eigenvectors.column(k).into())
            .collect();
        if known.len() == 3 {
            return None;
        }
        let mut h = Jacobian3::zeros();
        h.fixed_view_mut::<3, 3>(0, VEL)
            .copy_from(&Matrix3::identity());
        let mut rows = Stacked::default();
        rows.push(
            &-self.state.v,
            &h,
            &(Matrix3::identity() * sigma * sigma),
            &Observability::from_unobservable(&known),
        );
        self.fuse(&rows, UpdateKind::SpeedPrior, t).ok()
    }
}
