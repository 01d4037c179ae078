//! Covariance propagation of the error state over one IMU interval.
//!
//! Continuous error dynamics (global attitude error, `R` = body->NED, `M` = IMU->body,
//! `f`, `w` the corrected IMU-frame specific force and rate):
//! `dp' = dv`, `dv' = -[R M f]x dtheta - R M (dba + f * dsa) / (1 + sa) + noise`,
//! `dtheta' = -R M (dbg + w * dsg) / (1 + sg) + noise`, biases and scale factors random walks.
//! Discretised as `F = I + A dt` (first order; at 100-1000 Hz the neglected `A^2 dt^2 / 2`
//! terms are below 1e-4 of the kept ones) and `Q = diag(q) dt` from the noise densities.
//! `A` has only five non-zero 3x3 blocks, so `F P F^T` is applied block-wise on the fixed
//! 33x33 augmented covariance: the clone and carried-noise columns are carried along, which is
//! what keeps their cross-covariance with the current state right.

use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

use super::config::FilterConfig;
use super::imu_noise::WhiteNoise;
use super::state::{
    Covariance, ACCEL_BIAS, ACCEL_SCALE, ATT, AUGMENTED, ERROR_STATES, GYRO_BIAS, GYRO_SCALE, VEL,
};
use super::strapdown::Corrected;

/// The non-zero blocks of the continuous error-dynamics matrix `A`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ErrorDynamics {
    vel_att: Matrix3<f64>,
    vel_accel_bias: Matrix3<f64>,
    vel_accel_scale: Matrix3<f64>,
    att_gyro_bias: Matrix3<f64>,
    att_gyro_scale: Matrix3<f64>,
}

impl ErrorDynamics {
    /// Linearised about the attitude at the start of the interval and the mean corrected rates.
    pub(crate) fn new(
        q: &UnitQuaternion<f64>,
        imu_to_body: &UnitQuaternion<f64>,
        inc: &Corrected,
        gyro_scale: &Vector3<f64>,
        accel_scale: &Vector3<f64>,
    ) -> Self {
        let imu_to_ned = (q * imu_to_body).to_rotation_matrix().into_inner();
        let f = inc.dv_imu / inc.dt;
        let w = inc.dtheta_imu / inc.dt;
        let inv_sa = Vector3::repeat(1.0).component_div(&accel_scale.add_scalar(1.0));
        let inv_sg = Vector3::repeat(1.0).component_div(&gyro_scale.add_scalar(1.0));
        let f_ned = imu_to_ned * f;
        Self {
            vel_att: -f_ned.cross_matrix(),
            vel_accel_bias: -imu_to_ned * Matrix3::from_diagonal(&inv_sa),
            vel_accel_scale: -imu_to_ned * Matrix3::from_diagonal(&f.component_mul(&inv_sa)),
            att_gyro_bias: -imu_to_ned * Matrix3::from_diagonal(&inv_sg),
            att_gyro_scale: -imu_to_ned * Matrix3::from_diagonal(&w.component_mul(&inv_sg)),
        }
    }

    /// The blocks times `dt`, so that products with them need no extra pass over the result.
    fn scaled(&self, dt: f64) -> Self {
        Self {
            vel_att: self.vel_att * dt,
            vel_accel_bias: self.vel_accel_bias * dt,
            vel_accel_scale: self.vel_accel_scale * dt,
            att_gyro_bias: self.att_gyro_bias * dt,
            att_gyro_scale: self.att_gyro_scale * dt,
        }
    }

    /// `dt A x` for one error-state vector `x`, given as its 3-blocks (with `self` already
    /// scaled by `dt`): only the 9 entries of position, velocity and attitude are non-zero.
    fn apply(&self, part: impl Fn(usize) -> Vector3<f64>, dt: f64) -> SVector<f64, 9> {
        let pos = part(VEL) * dt;
        let vel = self.vel_att * part(ATT)
            + self.vel_accel_bias * part(ACCEL_BIAS)
            + self.vel_accel_scale * part(ACCEL_SCALE);
        let att = self.att_gyro_bias * part(GYRO_BIAS) + self.att_gyro_scale * part(GYRO_SCALE);
        SVector::from([
            pos.x, pos.y, pos.z, vel.x, vel.y, vel.z, att.x, att.y, att.z,
        ])
    }

    /// `phi <- F phi` for the core rows of a transition product (`map_states::MapStates`):
    /// the columns of `phi` are error-state vectors, and `F = I + dt A` changes only their
    /// position, velocity and attitude entries.
    pub(crate) fn advance_transition(
        &self,
        phi: &mut SMatrix<f64, ERROR_STATES, ERROR_STATES>,
        dt: f64,
    ) {
        let step = self.scaled(dt);
        for j in 0..ERROR_STATES {
            let change = step.apply(|at| phi.fixed_view::<3, 1>(at, j).into_owned(), dt);
            for i in 0..9 {
                phi[(i, j)] += change[i];
            }
        }
    }

    /// `P <- F P F^T + Q dt` in place. With `with_clone` false the clone rows and columns
    /// (stale until the next clone overwrites them) are skipped. Returns whether every entry
    /// it changed is finite, so the caller need not scan the matrix again per IMU sample.
    pub(crate) fn propagate(
        &self,
        p: &mut Covariance,
        noise: &ProcessNoise,
        dt: f64,
        with_clone: bool,
    ) -> bool {
        let first_finite = if with_clone {
            self.propagate_first::<AUGMENTED>(p, dt)
        } else {
            self.propagate_first::<ERROR_STATES>(p, dt)
        };
        noise.add_to(p, dt) & first_finite
    }

    /// With `L = dt A P` (rows 0..9 only) and `P` symmetric, `F P F^T = P + L + L^T + dt L A^T`:
    /// rows 0..9 gain `L`, columns 0..9 gain `L^T`, and the 9x9 corner also gains the symmetric
    /// `dt A L^T`. `L` is formed column by column (3-vector products that stay in registers)
    /// and the columns 0..9 are written as the mirror of the rows, which keeps `P` exactly
    /// symmetric at about a third of the cost of `F P F^T` from both sides.
    fn propagate_first<const C: usize>(&self, p: &mut Covariance, dt: f64) -> bool {
        let step = self.scaled(dt);
        let mut l = SMatrix::<f64, 9, C>::zeros();
        for (j, mut column) in l.column_iter_mut().enumerate() {
            column.copy_from(&step.apply(|at| p.fixed_view::<3, 1>(at, j).into_owned(), dt));
        }
        let mut corner = SMatrix::<f64, 9, 9>::zeros();
        for (r, mut column) in corner.column_iter_mut().enumerate() {
            column.copy_from(&step.apply(|at| l.fixed_view::<1, 3>(r, at).transpose(), dt));
        }
        let n = AUGMENTED;
        let p = p.as_mut_slice();
        let l = l.as_slice();
        let mut finite = true;
        for j in 0..9 {
            for i in 0..=j {
                let gained =
                    (l[j * 9 + i] + l[i * 9 + j]) + 0.5 * (corner[(i, j)] + corner[(j, i)]);
                let value = p[j * n + i] + gained;
                p[j * n + i] = value;
                p[i * n + j] = value;
                finite &= value.is_finite();
            }
        }
        for j in 9..C {
            for i in 0..9 {
                let value = p[j * n + i] + l[j * 9 + i];
                p[j * n + i] = value;
                p[i * n + j] = value;
                finite &= value.is_finite();
            }
        }
        finite
    }
}

/// Diagonal white-noise spectral densities (squared) per error-state block.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ProcessNoise {
    blocks: [(usize, f64); 6],
}

impl ProcessNoise {
    pub(crate) fn new(config: &FilterConfig) -> Self {
        Self::with_white(
            config,
            config.gyro_noise_density,
            config.accel_noise_density,
        )
    }

    /// The configured process noise, with the white noise the IMU was `measured` to have
    /// where it is worse (`imu_noise`).
    pub(crate) fn at_least_measured(config: &FilterConfig, measured: &WhiteNoise) -> Self {
        Self::with_white(
            config,
            measured.gyro_density.max(config.gyro_noise_density),
            measured.accel_density.max(config.accel_noise_density),
        )
    }

    fn with_white(config: &FilterConfig, gyro_density: f64, accel_density: f64) -> Self {
        Self {
            blocks: [
                (VEL, accel_density.powi(2)),
                (ATT, gyro_density.powi(2)),
                (GYRO_BIAS, config.gyro_bias_random_walk.powi(2)),
                (ACCEL_BIAS, config.accel_bias_random_walk.powi(2)),
                (GYRO_SCALE, config.gyro_scale_random_walk.powi(2)),
                (ACCEL_SCALE, config.accel_scale_random_walk.powi(2)),
            ],
        }
    }

    /// Returns whether the diagonal entries it changed are finite.
    fn add_to(&self, p: &mut Covariance, dt: f64) -> bool {
        let mut finite = true;
        for (at, density) in self.blocks {
            for i in at..at + 3 {
                p[(i, i)] += density * dt;
                finite &= p[(i, i)].is_finite();
            }
        }
        finite
    }
}

pub(crate) fn symmetrise(p: &mut Covariance) {
    for i in 0..AUGMENTED {
        for j in i + 1..AUGMENTED {
            let mean = 0.5 * (p[(i, j)] + p[(j, i)]);
            p[(i, j)] = mean;
            p[(j, i)] = mean;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::state::POS;

    fn dense_a(d: &ErrorDynamics) -> SMatrix<f64, AUGMENTED, AUGMENTED> {
        let mut a = SMatrix::<f64, AUGMENTED, AUGMENTED>::zeros();
        a.fixed_view_mut::<3, 3>(POS, VEL)
            .copy_from(&Matrix3::identity());
        a.fixed_view_mut::<3, 3>(VEL, ATT).copy_from(&d.vel_att);
        a.fixed_view_mut::<3, 3>(VEL, ACCEL_BIAS)
            .copy_from(&d.vel_accel_bias);
        a.fixed_view_mut::<3, 3>(VEL, ACCEL_SCALE)
            .copy_from(&d.vel_accel_scale);
        a.fixed_view_mut::<3, 3>(ATT, GYRO_BIAS)
            .copy_from(&d.att_gyro_bias);
        a.fixed_view_mut::<3, 3>(ATT, GYRO_SCALE)
            .copy_from(&d.att_gyro_scale);
        a
    }

    #[test]
    fn block_propagation_equals_the_dense_product() {
        let inc = Corrected {
            dt: 0.01,
            dtheta_imu: Vector3::new(0.01, -0.02, 0.005),
            dv_imu: Vector3::new(0.3, 0.1, -0.098),
            dtheta: Vector3::zeros(),
            dv: Vector3::zeros(),
        };
        let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7);
        let mount = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3);
        let d = ErrorDynamics::new(&q, &mount, &inc, &Vector3::repeat(0.01), &Vector3::zeros());
        let root = Covariance::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 * 0.1);
        let p0 = root * root.transpose() + Covariance::identity();
        let f = Covariance::identity() + dense_a(&d) * inc.dt;
        let mut p = p0;
        let config = FilterConfig::default();
        assert!(d.propagate(&mut p, &ProcessNoise::new(&config), inc.dt, true));
        let mut expected = f * p0 * f.transpose();
        assert!(ProcessNoise::new(&config).add_to(&mut expected, inc.dt));
        assert!((p - expected).norm() < 1e-12 * expected.norm());
        assert_eq!(p, p.transpose(), "the mirrored half must match bit for bit");
        // The clone and carried-noise block itself is untouched by propagation.
        let clone = p.fixed_view::<12, 12>(ERROR_STATES, ERROR_STATES);
        assert_eq!(clone, p0.fixed_view::<12, 12>(ERROR_STATES, ERROR_STATES));
    }

    #[test]
    fn a_gathered_transition_moves_static_columns_as_propagation_does() {
        // The clone's columns are states the IMU does not drive, as a surface's are: two
        // steps of propagation must move them as the product of the two transitions does.
        let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7);
        let steps = [0.3, -0.4].map(|turn| Corrected {
            dt: 0.005,
            dtheta_imu: Vector3::new(0.01, turn * 0.02, 0.005),
            dv_imu: Vector3::new(0.05, 0.01, -0.049 + turn * 0.01),
            dtheta: Vector3::zeros(),
            dv: Vector3::zeros(),
        });
        let root = Covariance::from_fn(|i, j| ((i * 5 + j * 3) % 13) as f64 * 0.1);
        let p0 = root * root.transpose() + Covariance::identity();
        let noise = ProcessNoise::new(&FilterConfig::default());
        let mut p = p0;
        let mut phi = SMatrix::<f64, ERROR_STATES, ERROR_STATES>::identity();
        for inc in &steps {
            let d = ErrorDynamics::new(&q, &q, inc, &Vector3::zeros(), &Vector3::zeros());
            d.propagate(&mut p, &noise, inc.dt, true);
            d.advance_transition(&mut phi, inc.dt);
        }
        let columns = p0.fixed_view::<ERROR_STATES, 12>(0, ERROR_STATES);
        let expected = phi * columns;
        let moved = p.fixed_view::<ERROR_STATES, 12>(0, ERROR_STATES);
        assert!((moved - expected).norm() < 1e-12 * expected.norm());
    }
}
