//! The odometer's relative pose between epochs i (reference, earlier) and j (current) as a
//! filter measurement: `C = C_j^i` rotates body-j vectors into body i, `dR` is body j's origin
//! in body-i coordinates.
//!
//! Cloned model (global attitude errors, `R_i`, `R_j` body->NED at the two epochs):
//! `Log(C_hat^T C) = R_j^T (dtheta_j - dtheta_i)` and
//! `dR - R_i^T (p_j - p_i) = R_i^T (dp_j - dp_i) + R_i^T [p_j - p_i]x dtheta_i`, the lever
//! `p_j - p_i` taken along the directions the planes observe, and along the free ones only where
//! the filter knows the motion there surely (`sure_lever`).
//! Velocity model (after the paper's): `dR / (t_j - t_i) = R_i^T v_j`, the predicted mean
//! velocity taken from the filter's positions at both ends, so the acceleration within the
//! interval is not read as a velocity error. The rotation is fused as what it measures without
//! a clone, the mean body rate over the interval: the same residual is
//! `R_j^T (dtheta_j - dtheta_i) = -T M (dbg + w * dsg) + gyro noise` (body j close to its mean
//! over the interval). The paper fused it on the attitude with the reference attitude taken as
//! exact: every epoch then re-measured the absolute attitude as `attitude_i * C`, the attitude
//! covariance collapsed to the odometer's relative-rotation noise while the attitude error
//! random-walked, gravity could no longer correct the tilt, and the velocity drifted along the
//! hallway whenever the board hid the end wall (docs/accuracy.md).

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use super::history::Pose;
use super::state::Covariance;
use super::state::{
    NominalState, ATT, CARRIED, CLONE_ATT, CLONE_POS, GYRO_BIAS, GYRO_SCALE, POS, VEL,
};
use super::update::{Jacobian3, Observability, Stacked};

/// A free motion at least this many of its own sigmas long is known surely enough to be the
/// lever of the attitude error in the Jacobian (`sure_lever`).
const SURE_LEVER_SIGMAS: f64 = 3.0;

/// Rotation part of an odometry epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativeRotation {
    /// Rotation vector of `C_j^i` (body j -> body i), rad.
    pub rotation_vector: Vector3<f64>,
    /// Its covariance, rad^2.
    pub covariance: Matrix3<f64>,
    pub observability: Observability,
}

/// Displacement part of an odometry epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativeTranslation {
    /// Body j's origin in body-i coordinates, m.
    pub displacement: Vector3<f64>,
    /// Its covariance, m^2.
    pub covariance: Matrix3<f64>,
    pub observability: Observability,
}

/// The part of a relative pose's noise that it shares with its neighbours. The planes of
/// epoch i were also the current planes of the previous relative pose h->i, and those of epoch j
/// will be the reference planes of the next one j->k, with the opposite sign: consecutive
/// relative poses are negatively correlated (lag-one correlation -0.2 to -0.5 on hallway-hover),
/// so their errors telescope when summed instead of adding up. Fused as independent, they make
/// the position covariance grow as the sum of all of them, far above the error
/// (docs/accuracy.md, "NEES"). Blocks: rotation (right perturbation, body-j axes), then
/// displacement (body-i axes), as the measurement's own covariances, which include both parts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SharedNoise {
    /// Covariance between the noise epoch i's planes put into this relative pose and the noise
    /// they put into the previous one (as that one's `current`).
    pub with_previous: [Matrix3<f64>; 2],
    /// Covariance of the noise epoch j's planes put into this relative pose.
    pub current: [Matrix3<f64>; 2],
}

/// The noise the reference epoch's planes put into the last fused relative pose, a state of
/// the filter (`CARRIED..`) while the clone is open: its covariance before that update (the
/// update's `SharedNoise::current`) and its estimate after it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CarriedNoise {
    pub prior: [Matrix3<f64>; 2],
    pub mean: [Vector3<f64>; 2],
}

/// One odometry epoch as the filter fuses it; either part may be missing (not solved, or not
/// cleared by integrity). Unlike the odometer's `odometry::RelativePose` it has times, its
/// rotation covariance is of a right perturbation (body-j axes), and each part says which
/// directions it observes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativePoseMeasurement {
    /// Host time of the reference epoch i, s.
    pub t_ref: f64,
    /// Host time of the current epoch j, s.
    pub t: f64,
    pub rotation: Option<RelativeRotation>,
    pub translation: Option<RelativeTranslation>,
    /// `None` fuses the relative pose as independent of its neighbours.
    pub shared: Option<SharedNoise>,
}

impl RelativePoseMeasurement {
    pub(crate) fn is_finite(&self) -> bool {
        let finite =
            |m: &Matrix3<f64>, v: &Vector3<f64>| m.iter().chain(v.iter()).all(|x| x.is_finite());
        self.t_ref.is_finite()
            && self.t.is_finite()
            && self
                .rotation
                .is_none_or(|r| finite(&r.covariance, &r.rotation_vector))
            && self
                .translation
                .is_none_or(|d| finite(&d.covariance, &d.displacement))
    }

    /// Predicted `C_j^i` and `dR` from two poses.
    pub(crate) fn predict(reference: &Pose, current: &Pose) -> (UnitQuaternion<f64>, Vector3<f64>) {
        (
            reference.q.inverse() * current.q,
            reference
                .q
                .inverse_transform_vector(&(current.p - reference.p)),
        )
    }

    /// The same measurement re-expressed between `from` (the clone, near `t_ref`) and `to` (the
    /// filter's current pose, near `t`), bridging the few milliseconds at each end with the
    /// filter's own propagated motion between `at_ref` (pose at `t_ref`) and `from`, and
    /// between `at_t` (pose at `t`) and `to`. Over such short bridges the IMU motion is far
    /// more precise than the odometry, so the covariances are kept as reported, turned into
    /// the new axes.
    pub(crate) fn bridged(&self, from: &Pose, at_ref: &Pose, at_t: &Pose, to: &Pose) -> Self {
        let (c_front, d_front) = Self::predict(from, at_ref);
        let (c_back, d_back) = Self::predict(at_t, to);
        let measured_rotation = match &self.rotation {
            Some(r) => UnitQuaternion::from_scaled_axis(r.rotation_vector),
            None => Self::predict(at_ref, at_t).0,
        };
        // A right perturbation in body-j axes is one in the `to` axes through `c_back`'s
        // inverse; the displacement's body-i axes are the clone's through `c_front`. The
        // directions each observes turn with them: kept in the old axes across a turn, they
        // let the anchored, unobserved motion into the observed rows. The shared noise stays
        // as it is: it holds the planes' own noise, along the observed directions, and a few
        // mrad of turn moves a few thousandths of it.
        let to_axes = c_back.inverse();
        Self {
            t_ref: from.t,
            t: to.t,
            rotation: self.rotation.map(|r| RelativeRotation {
                rotation_vector: (c_front * measured_rotation * c_back).scaled_axis(),
                covariance: turned(&r.covariance, &to_axes),
                observability: r.observability.turned(&to_axes),
            }),
            translation: self.translation.map(|d| RelativeTranslation {
                displacement: d_front + c_front * (d.displacement + measured_rotation * d_back),
                covariance: turned(&d.covariance, &c_front),
                observability: d.observability.turned(&c_front),
            }),
            shared: self.shared,
        }
    }

    /// Measurement rows against the current state, the cloned reference pose and the noise
    /// `carried` from the previous relative pose: `z = h(x_j, x_i) + L n_i + n_j + r`, with
    /// `L = C U^+` the regression of this pose's epoch-i noise on the carried `n_i` (covariance
    /// `U`, cross-covariance `C`), `n_j` the noise the current planes put in (carried out to the
    /// next pose by the update) and `r` the rest, of covariance `R - L C^T`.
    ///
    /// `covariance` (the filter's, with the clone open) adds what the attitude error does
    /// through motion the Jacobian leaves out of its lever (`lever_noise`).
    pub(crate) fn cloned_rows(
        &self,
        reference: &Pose,
        current: &NominalState,
        carried: Option<&CarriedNoise>,
        covariance: &Covariance,
    ) -> Stacked {
        let now = Pose {
            t: self.t,
            p: current.p,
            q: current.q,
        };
        let (c_hat, d_hat) = Self::predict(reference, &now);
        let r_i_t = reference.q.to_rotation_matrix().into_inner().transpose();
        let r_j_t = current.q.to_rotation_matrix().into_inner().transpose();
        let mut rows = Stacked::default();
        if let Some(rotation) = &self.rotation {
            let shared = SharedTerms::new(self.shared.as_ref(), carried, 0, &rotation.covariance);
            let mut h = Jacobian3::zeros();
            set(&mut h, ATT, &r_j_t);
            set(&mut h, CLONE_ATT, &-r_j_t);
            set(&mut h, CARRIED, &shared.l);
            let residual =
                rotation_residual(&c_hat, &rotation.rotation_vector) - shared.carried_mean;
            rows.push(&residual, &h, &shared.noise, &rotation.observability);
            rows.carry_out(0, &shared.current, &rotation.observability);
        }
        if let Some(translation) = &self.translation {
            let shared =
                SharedTerms::new(self.shared.as_ref(), carried, 1, &translation.covariance);
            let mut h = Jacobian3::zeros();
            set(&mut h, POS, &r_i_t);
            set(&mut h, CLONE_POS, &-r_i_t);
            // The lever of the clone's attitude error is the motion the planes observe only
            // (`lever_noise`).
            let motion = current.p - reference.p;
            let observed = r_i_t.transpose() * translation.observability.projector() * r_i_t;
            let observed_motion = observed * motion;
            let motion_error = motion_covariance(covariance);
            let lever = sure_lever(&motion, &observed_motion, &motion_error);
            set(&mut h, CLONE_ATT, &(r_i_t * lever.cross_matrix()));
            set(&mut h, CARRIED + 3, &shared.l);
            let residual = translation.displacement - d_hat - shared.carried_mean;
            let noise =
                shared.noise + lever_noise(&r_i_t, covariance, &motion_error, &(motion - lever));
            rows.push(&residual, &h, &noise, &translation.observability);
            rows.carry_out(1, &shared.current, &translation.observability);
        }
        rows
    }

    /// Rows without a clone: mean body velocity from the displacement, the reference pose
    /// (from the pose history) taken as exact, and mean body rate from the rotation, on the
    /// gyro bias and scale factor. `imu_to_body` is `M`; `gyro_noise_density` the white gyro
    /// noise, whose integral over the interval the rate residual also carries.
    pub(crate) fn velocity_rows(
        &self,
        reference: &Pose,
        current: &NominalState,
        imu_to_body: &UnitQuaternion<f64>,
        gyro_noise_density: f64,
    ) -> Stacked {
        let interval = self.t - self.t_ref;
        let c_hat = reference.q.inverse() * current.q;
        let r_i_t = reference.q.to_rotation_matrix().into_inner().transpose();
        let mut rows = Stacked::default();
        if let Some(rotation) = &self.rotation {
            let m = imu_to_body.to_rotation_matrix().into_inner();
            let rate_imu = imu_to_body.inverse_transform_vector(&c_hat.scaled_axis()) / interval;
            let mut h = Jacobian3::zeros();
            set(&mut h, GYRO_BIAS, &(-m * interval));
            set(
                &mut h,
                GYRO_SCALE,
                &(-m * Matrix3::from_diagonal(&rate_imu) * interval),
            );
            let residual = rotation_residual(&c_hat, &rotation.rotation_vector);
            let noise =
                rotation.covariance + Matrix3::identity() * gyro_noise_density.powi(2) * interval;
            rows.push(&residual, &h, &noise, &rotation.observability);
        }
        if let Some(translation) = &self.translation {
            let mut h = Jacobian3::zeros();
            set(&mut h, VEL, &r_i_t);
            // The mean velocity over the interval predicted from the filter's own positions at
            // both ends, not the end velocity: the two differ by the IMU-known acceleration
            // times half the interval (0.025 m/s for a gentle hover at 1 Hz, eight sigmas of a
            // good displacement), which would otherwise be read as a velocity error.
            let mean_velocity = (current.p - reference.p) / interval;
            let residual = translation.displacement / interval - r_i_t * mean_velocity;
            let noise = translation.covariance / (interval * interval);
            rows.push(&residual, &h, &noise, &translation.observability);
        }
        rows
    }
}

/// Covariance of what the clone's attitude error does to the displacement through motion the
/// Jacobian does not take as its lever. With the attitude error `dtheta_i` and the error `e` of
/// the estimated motion `p_j - p_i`, the displacement is `R_i^T (p_j - p_i + e + [p_j - p_i]x
/// dtheta_i + [e]x dtheta_i)`, and two parts of that lever are left to the noise:
/// - `e` itself, the second-order term. Negligible where the planes observe the motion, but
///   along a direction they leave free (a bare corridor, a start in motion) `e` is as large as
///   the velocity is uncertain, and a milliradian of tilt error times a metre of unknown motion
///   shows as a millimetre across the corridor, which a row there (the floor's, a wall's)
///   would read as information along it that no surface gave.
/// - the estimated motion along the free directions, `unobserved_motion`, where the Jacobian
///   takes the observed part only (`sure_lever` says when it takes it all). That estimate is
///   the dead-reckoned velocity, wrong by as much as it is uncertain and correlated with the
///   tilt error that drives it; as a lever it let the floor's row "measure" the tilt through a
///   motion nobody measured, and on the bare corridor the pitch and the accelerometer bias
///   moved together until the filter reported the velocity along the corridor to 0.5 m/s while
///   it was 1.7 m/s wrong (mean NEES 3-5;
///   `eskf_tests::a_corridor_leaves_the_velocity_along_it_honestly_uncertain`).
///
/// Both are `E[[x]x P [x]x^T]` over a motion `x` taken independent of the attitude error,
/// linear in `x`'s second moment `S = Cov(e) + m m^T`: `sum_k lambda_k [v_k]x P [v_k]x^T` over
/// the eigenpairs of `S`.
fn lever_noise(
    r_i_t: &Matrix3<f64>,
    covariance: &Covariance,
    motion_error: &Matrix3<f64>,
    unobserved_motion: &Vector3<f64>,
) -> Matrix3<f64> {
    let second_moment = motion_error + unobserved_motion * unobserved_motion.transpose();
    let attitude: Matrix3<f64> = covariance.fixed_view::<3, 3>(CLONE_ATT, CLONE_ATT).into();
    let eigen = second_moment.symmetric_eigen();
    let nav = (0..3).fold(Matrix3::zeros(), |sum, k| {
        let lever = Vector3::from(eigen.eigenvectors.column(k)).cross_matrix();
        sum + lever * attitude * lever.transpose() * eigen.eigenvalues[k].max(0.0)
    });
    r_i_t * nav * r_i_t.transpose()
}

/// Covariance of the error of the estimated motion `p_j - p_i` (navigation frame), symmetric.
fn motion_covariance(covariance: &Covariance) -> Matrix3<f64> {
    let block = |a: usize, b: usize| -> Matrix3<f64> { covariance.fixed_view::<3, 3>(a, b).into() };
    let error = block(POS, POS) + block(CLONE_POS, CLONE_POS)
        - block(POS, CLONE_POS)
        - block(CLONE_POS, POS);
    (error + error.transpose()) * 0.5
}

/// The motion the clone's attitude error is taken to act through in the Jacobian: the observed
/// motion, and the motion along the free directions too once the filter knows it surely, its
/// length `SURE_LEVER_SIGMAS` times its sigma or more.
///
/// Left to the noise, a free motion the filter knows is read again every epoch as if the
/// attitude error it multiplies were new each time, when it is the same error epoch after
/// epoch: walked at 1 m/s down a corridor nothing measures along (`random-corridor-4`), the
/// floor and the walls then taught the filter its tilt and its accelerometer bias apart,
/// and a turn at the corridor's end showed them 4-5 sigma off, the velocity along the corridor
/// with them: 2 m/s off at quality 10-60, 0.55 of the usable messages inside 3 sigma. In the
/// Jacobian the error is the state's own and is fused once. A free motion the filter does not
/// know surely (the bare corridor walked at 0.1 m/s with a velocity sigma of 0.5 m/s, a start
/// in motion) stays in the noise (`lever_noise`).
fn sure_lever(
    motion: &Vector3<f64>,
    observed_motion: &Vector3<f64>,
    motion_error: &Matrix3<f64>,
) -> Vector3<f64> {
    let free = motion - observed_motion;
    // |free|^2 >= k^2 (its variance along itself), both sides times |free|^2.
    if free.norm_squared().powi(2) >= SURE_LEVER_SIGMAS.powi(2) * free.dot(&(motion_error * free)) {
        *motion
    } else {
        *observed_motion
    }
}

/// One block's share of the noise: the carried noise's Jacobian `L` and its estimate's share
/// of the residual, the independent rest of the noise, and what this pose carries out.
struct SharedTerms {
    l: Matrix3<f64>,
    carried_mean: Vector3<f64>,
    noise: Matrix3<f64>,
    current: Matrix3<f64>,
}

impl SharedTerms {
    fn new(
        shared: Option<&SharedNoise>,
        carried: Option<&CarriedNoise>,
        block: usize,
        covariance: &Matrix3<f64>,
    ) -> Self {
        let independent = Self {
            l: Matrix3::zeros(),
            carried_mean: Vector3::zeros(),
            noise: *covariance,
            current: shared.map_or_else(Matrix3::zeros, |s| s.current[block]),
        };
        let (Some(shared), Some(carried)) = (shared, carried) else {
            return independent;
        };
        let cross = shared.with_previous[block];
        let l = cross * pseudo_inverse(&carried.prior[block]);
        let explained = l * cross.transpose();
        let noise = covariance - (explained + explained.transpose()) * 0.5;
        // By construction `R - L C^T` keeps at least the current planes' noise; a covariance
        // that disagrees (rounding on a nearly singular prior) falls back to independence.
        if noise.cholesky().is_none() {
            return independent;
        }
        Self {
            l,
            carried_mean: l * carried.mean[block],
            noise,
            ..independent
        }
    }
}

/// The smallest variance, relative to the largest, along which a carried noise counts as carried
/// (`pseudo_inverse`). Along the anchored direction of a relative pose the planes put no noise,
/// but rounding leaves some: in `random-corridor-4` at 10 Hz, 44.4 s in, 1e-15 m^2, 2e-9 of the
/// largest, and the next pose's share of the planes' noise, regressed on it, took coefficients
/// of up to 4700 where the telescoping gives about one. The variances carried along observed
/// directions that were seen lay within three orders of magnitude of each other.
const CARRIED_FLOOR: f64 = 1e-6;

/// Moore-Penrose inverse of a symmetric positive semi-definite matrix; directions with an
/// eigenvalue below `CARRIED_FLOOR` of the largest (nothing carried along them) are left out.
fn pseudo_inverse(m: &Matrix3<f64>) -> Matrix3<f64> {
    let eigen = m.symmetric_eigen();
    let largest = eigen.eigenvalues.amax();
    let mut inverse = Matrix3::zeros();
    for (k, &value) in eigen.eigenvalues.iter().enumerate() {
        if value > CARRIED_FLOOR * largest && value > 0.0 {
            let v = eigen.eigenvectors.column(k);
            inverse += v * v.transpose() / value;
        }
    }
    inverse
}

fn rotation_residual(predicted: &UnitQuaternion<f64>, measured: &Vector3<f64>) -> Vector3<f64> {
    (predicted.inverse() * UnitQuaternion::from_scaled_axis(*measured)).scaled_axis()
}

/// A covariance in axes turned by `rotation` (old axes -> new).
fn turned(covariance: &Matrix3<f64>, rotation: &UnitQuaternion<f64>) -> Matrix3<f64> {
    let r = rotation.to_rotation_matrix().into_inner();
    r * covariance * r.transpose()
}

fn set(h: &mut Jacobian3, column: usize, block: &Matrix3<f64>) {
    h.fixed_view_mut::<3, 3>(0, column).copy_from(block);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The carried displacement noise of `random-corridor-4` at 10 Hz, 44.4 s in: two observed
    /// directions and the anchored one, 2e-9 of the largest, which rounding left.
    #[test]
    fn a_carried_noise_is_inverted_only_along_what_it_carries() {
        let carried = Matrix3::from_diagonal(&Vector3::new(4.6e-7, 9.7e-16, 7.3e-8));
        let inverse = pseudo_inverse(&carried);
        assert_eq!(inverse[(1, 1)], 0.0);
        assert!((inverse[(0, 0)] * 4.6e-7 - 1.0).abs() < 1e-9);
        assert!((inverse[(2, 2)] * 7.3e-8 - 1.0).abs() < 1e-9);
    }

    #[test]
    fn a_free_motion_is_the_attitude_errors_lever_only_once_known_to_three_sigmas() {
        let observed = Vector3::new(0.0, 0.02, -0.01);
        let motion = observed + Vector3::new(0.9, 0.0, 0.0);
        let along_sigma =
            |sigma: f64| Matrix3::from_diagonal(&Vector3::new(sigma * sigma, 1e-6, 1e-6));
        assert_eq!(sure_lever(&motion, &observed, &along_sigma(0.29)), motion);
        assert_eq!(sure_lever(&motion, &observed, &along_sigma(0.31)), observed);
        assert_eq!(
            sure_lever(&observed, &observed, &along_sigma(0.0)),
            observed
        );
    }

    /// A corridor's epoch: the displacement along body-i x unobserved (anchored at `along_m`).
    fn corridor_epoch(along_m: f64) -> RelativePoseMeasurement {
        RelativePoseMeasurement {
            t_ref: 1.0,
            t: 1.1,
            rotation: None,
            translation: Some(RelativeTranslation {
                displacement: Vector3::new(along_m, 0.002, -0.001),
                covariance: Matrix3::identity() * 1e-6,
                observability: Observability::from_unobservable(&[Vector3::x()]),
            }),
            shared: None,
        }
    }

    #[test]
    fn a_bridge_across_a_turn_keeps_the_unobserved_motion_out_of_the_observed_rows() {
        let pose = |t: f64, yaw: f64| Pose {
            t,
            p: Vector3::zeros(),
            q: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        };
        // The clone 25 ms before the reference epoch, turning at 0.4 rad/s.
        let (from, at_ref, at_t) = (pose(0.975, 0.0), pose(1.0, 0.01), pose(1.1, 0.05));
        let bridge = |along_m: f64| {
            corridor_epoch(along_m)
                .bridged(&from, &at_ref, &at_t, &at_t)
                .translation
                .unwrap()
        };
        let (anchored_right, anchored_wrong) = (bridge(0.0), bridge(0.25));
        let observed = anchored_wrong.observability.projector();
        let leak = observed * (anchored_wrong.displacement - anchored_right.displacement);
        assert!(leak.norm() < 1e-9, "{leak:?}");
    }
}
