//! The Kalman measurement update shared by every measurement (relative pose, zero velocity),
//! with projection onto the observable directions and the chi-square innovation gate.

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

use super::consistency::chi_square_quantile;
use super::covariance::symmetrise;
use super::map_states::JointRows;
use super::state::{Covariance, ErrorState, ATT, AUGMENTED, CARRIED, CLONE_ATT};

/// Up to six measurement rows: two three-row blocks (e.g. rotation and displacement).
pub(crate) const ROWS: usize = 6;
pub(crate) type Jacobian3 = SMatrix<f64, 3, AUGMENTED>;

/// The directions of a three-dimensional measurement that the sensor actually observed.
/// Columns `0..rank` of `basis` are an orthonormal basis of the observable subspace.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observability {
    basis: Matrix3<f64>,
    rank: usize,
}

impl Observability {
    pub fn full() -> Self {
        Self {
            basis: Matrix3::identity(),
            rank: 3,
        }
    }

    /// Every direction except those spanned by `unobservable` (as `SolveError::UnderDetermined`
    /// reports them; they need not be normalised or orthogonal).
    pub fn from_unobservable(unobservable: &[Vector3<f64>]) -> Self {
        let spanned = unobservable
            .iter()
            .filter(|d| d.norm() > 0.0 && d.iter().all(|x| x.is_finite()))
            .map(|d| {
                let u = d.normalize();
                u * u.transpose()
            })
            .fold(Matrix3::zeros(), |sum, m| sum + m);
        let eigen = spanned.symmetric_eigen();
        let mut order = [0, 1, 2];
        order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
        let rank = order
            .iter()
            .filter(|&&i| eigen.eigenvalues[i] < 1e-6)
            .count();
        let basis = Matrix3::from_columns(
            &order.map(|i| -> Vector3<f64> { eigen.eigenvectors.column(i).into() }),
        );
        Self { basis, rank }
    }

    /// The same directions in axes turned by `rotation` (old axes -> new).
    pub(crate) fn turned(&self, rotation: &UnitQuaternion<f64>) -> Self {
        Self {
            basis: rotation.to_rotation_matrix().into_inner() * self.basis,
            rank: self.rank,
        }
    }

    pub fn rank(&self) -> usize {
        self.rank
    }

    /// Whether the unit vector `u` lies in the observable subspace to within the angle whose
    /// cosine is `cosine`.
    pub(crate) fn contains(&self, u: &Vector3<f64>, cosine: f64) -> bool {
        let projected: f64 = (0..self.rank)
            .map(|i| self.basis.column(i).dot(u).powi(2))
            .sum();
        projected.sqrt() >= cosine
    }

    /// Projector onto the observable subspace.
    pub(crate) fn projector(&self) -> Matrix3<f64> {
        (0..self.rank).fold(Matrix3::zeros(), |sum, i| {
            let d = self.basis.column(i);
            sum + d * d.transpose()
        })
    }

    #[cfg(test)]
    pub(crate) fn observable_directions(&self) -> impl Iterator<Item = Vector3<f64>> + '_ {
        (0..self.rank).map(|i| self.basis.column(i).into())
    }
}

/// A measurement in observable coordinates, padded to six rows: unused rows have zero
/// Jacobian, zero innovation and unit variance uncorrelated with the rest, so they change
/// neither the state, the covariance nor the NIS.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Stacked {
    innovation: SVector<f64, ROWS>,
    jacobian: SMatrix<f64, ROWS, AUGMENTED>,
    noise: SMatrix<f64, ROWS, ROWS>,
    /// Covariance between the rows' noise and the noise the measurement carries out to the next
    /// one (the filter's `CARRIED..` states after the update), and that noise's own covariance.
    carried_out: Option<(SMatrix<f64, ROWS, 6>, SMatrix<f64, 6, 6>)>,
    dof: usize,
    next_row: usize,
}

impl Default for Stacked {
    fn default() -> Self {
        Self {
            innovation: SVector::zeros(),
            jacobian: SMatrix::zeros(),
            noise: SMatrix::identity(),
            carried_out: None,
            dof: 0,
            next_row: 0,
        }
    }
}

impl Stacked {
    /// Adds a three-row block `innovation = H dx + noise`, keeping only its observable part.
    pub(crate) fn push(
        &mut self,
        innovation: &Vector3<f64>,
        jacobian: &Jacobian3,
        noise: &Matrix3<f64>,
        observability: &Observability,
    ) {
        let row = self.next_row;
        let u = observability.basis;
        let rank = observability.rank;
        let projected_innovation = u.transpose() * innovation;
        let projected_jacobian = u.transpose() * jacobian;
        let projected_noise = u.transpose() * noise * u;
        for i in 0..rank {
            self.innovation[row + i] = projected_innovation[i];
            self.jacobian
                .row_mut(row + i)
                .copy_from(&projected_jacobian.row(i));
            for j in 0..rank {
                self.noise[(row + i, row + j)] = projected_noise[(i, j)];
            }
        }
        self.dof += rank;
        self.next_row += 3;
    }

    /// Marks part of the last pushed block's noise, of covariance `covariance`, as carried out
    /// to the next measurement as block `block` (0 rotation, 1 displacement) of the carried
    /// states; `observability` is the one the block was pushed with.
    pub(crate) fn carry_out(
        &mut self,
        block: usize,
        covariance: &Matrix3<f64>,
        observability: &Observability,
    ) {
        let row = self.next_row - 3;
        let (cross, own) = self
            .carried_out
            .get_or_insert_with(|| (SMatrix::zeros(), SMatrix::zeros()));
        let projected = observability.basis.transpose() * covariance;
        let rows_noise: Matrix3<f64> = self.noise.fixed_view::<3, 3>(row, row).into();
        let shrink = correlation_shrink(
            &rows_noise,
            &(projected * observability.basis),
            observability.rank,
        );
        for i in 0..observability.rank {
            for j in 0..3 {
                cross[(row + i, 3 * block + j)] = shrink * projected[(i, j)];
            }
        }
        own.fixed_view_mut::<3, 3>(3 * block, 3 * block)
            .copy_from(covariance);
    }

    /// The carried-out noise's own covariance, as `carry_out` set it.
    pub(crate) fn carried_out_covariance(&self) -> Option<SMatrix<f64, 6, 6>> {
        self.carried_out.map(|(_, own)| own)
    }

    /// Observable rows.
    pub(crate) fn dof(&self) -> usize {
        self.dof
    }

    /// The same rows over the state and `surface_states` map states they do not measure.
    pub(crate) fn joint(&self, surface_states: usize) -> JointRows {
        JointRows {
            innovation: DVector::from_column_slice(self.innovation.as_slice()),
            core: DMatrix::from_column_slice(ROWS, AUGMENTED, self.jacobian.as_slice()),
            surfaces: DMatrix::zeros(ROWS, surface_states),
            noise: DMatrix::from_column_slice(ROWS, ROWS, self.noise.as_slice()),
        }
    }

    pub(crate) fn is_finite(&self) -> bool {
        self.innovation.iter().all(|x| x.is_finite())
            && self.jacobian.iter().all(|x| x.is_finite())
            && self.noise.iter().all(|x| x.is_finite())
    }

    /// Innovation covariance `H P H^T + R` of the observable rows.
    pub(crate) fn innovation_covariance(&self, p: &Covariance) -> SMatrix<f64, ROWS, ROWS> {
        self.jacobian * p * self.jacobian.transpose() + self.noise
    }
}

/// The factor (at most 1) on the correlation between a block's fused rows (noise `rows_noise`,
/// the first `rank` rows observed) and the noise it carries out, whose share of those rows is
/// `shared`: the carried-out noise is part of the rows' own, so the share can be no larger
/// along any fused direction, or the joint covariance of the state and the carried noise turns
/// indefinite. The per-plane shares are a first-order model and do sum to more (over the
/// whole block, by 6 % at the median of the hallway hover's poses, 50 % at the 90th
/// percentile, 7000-fold at worst); in `random-room-15` at 10 Hz the position's variance went
/// to -8e-4 m^2 within a second. With the correlation shrunk by `1 / sqrt(lambda_max)` of the
/// share whitened by the rows' noise, `rows_noise - shrink^2 shared` stays positive
/// semi-definite.
fn correlation_shrink(rows_noise: &Matrix3<f64>, shared: &Matrix3<f64>, rank: usize) -> f64 {
    let fused = |m: &Matrix3<f64>, fill: f64| {
        Matrix3::from_fn(|i, j| match (i < rank, j < rank) {
            (true, true) => m[(i, j)],
            _ if i == j => fill,
            _ => 0.0,
        })
    };
    let Some(inverse_factor) = fused(rows_noise, 1.0)
        .cholesky()
        .and_then(|c| c.l().try_inverse())
    else {
        return 0.0;
    };
    let whitened = inverse_factor * fused(shared, 0.0) * inverse_factor.transpose();
    let largest = whitened.symmetric_eigenvalues().max();
    if largest > 1.0 {
        largest.sqrt().recip()
    } else {
        1.0
    }
}

/// Result of the gate and, if it passed, of the update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Gated {
    pub nis: f64,
    pub dof: usize,
    /// NIS threshold at the configured gate probability (infinite when the gate is off).
    pub threshold: f64,
    /// The error-state correction, `None` when the gate rejected the measurement.
    pub correction: Option<ErrorState>,
    /// Estimate of the noise the measurement carried out, when it carried some and passed.
    pub carried: Option<SVector<f64, 6>>,
}

/// The innovation covariance is not positive definite (a broken measurement covariance).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NotPositiveDefinite;

/// NIS thresholds of the gate for 0..=6 observable rows, computed once per filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GateThresholds([f64; ROWS + 1]);

impl GateThresholds {
    pub(crate) fn new(gate_probability: f64) -> Self {
        Self(std::array::from_fn(|dof| {
            chi_square_quantile(gate_probability, dof)
        }))
    }

    pub(crate) fn threshold(&self, dof: usize) -> f64 {
        self.0[dof.min(ROWS)]
    }
}

/// Gates on the NIS, then applies `K = P H^T S^-1`, `P <- P - K S K^T` and the ESKF reset of
/// the attitude blocks (current and cloned): for a global error `Exp(dtheta_true) = Exp(dtheta) Exp(dtheta_hat)^-1`
/// to second order, so `G = I + [dtheta_hat / 2]x` (Sola sec. 7, the sign flipped from the
/// local-error eq. 287). Leaves `p` untouched on rejection.
pub(crate) fn apply(
    p: &mut Covariance,
    measurement: &Stacked,
    gate: &GateThresholds,
) -> Result<Gated, NotPositiveDefinite> {
    let pht = *p * measurement.jacobian.transpose();
    let s = measurement.jacobian * pht + measurement.noise;
    let cholesky = s.cholesky().ok_or(NotPositiveDefinite)?;
    let y = measurement.innovation;
    let nis = cholesky.solve(&y).dot(&y);
    let threshold = gate.0[measurement.dof];
    let mut gated = Gated {
        nis,
        dof: measurement.dof,
        threshold,
        correction: None,
        carried: None,
    };
    if measurement.dof == 0 || nis > threshold {
        return Ok(gated);
    }
    let gain_t = cholesky.solve(&pht.transpose());
    let dx = gain_t.transpose() * y;
    *p -= pht * gain_t;
    if let Some((cross, own)) = &measurement.carried_out {
        gated.carried = Some(carry_forward(p, &pht, &cholesky, cross, own, &y));
    }
    for at in [ATT, CLONE_ATT] {
        reset_attitude_error(p, at, &Vector3::new(dx[at], dx[at + 1], dx[at + 2]));
    }
    symmetrise(p);
    gated.correction = Some(dx);
    Ok(gated)
}

/// Replaces the carried states (the previous measurement's noise, now marginalised out) with
/// the noise `n` this measurement carries out, as if it had been a state of prior covariance
/// `own` and zero cross-covariance: `Cov(dx, n) = -K cross`,
/// `Cov(n) = own - cross^T S^-1 cross`, `n_hat = cross^T S^-1 y`.
fn carry_forward(
    p: &mut Covariance,
    pht: &SMatrix<f64, AUGMENTED, ROWS>,
    s: &nalgebra::Cholesky<f64, nalgebra::Const<ROWS>>,
    cross: &SMatrix<f64, ROWS, 6>,
    own: &SMatrix<f64, 6, 6>,
    y: &SVector<f64, ROWS>,
) -> SVector<f64, 6> {
    let s_inv_cross = s.solve(cross);
    let with_state = -(pht * s_inv_cross);
    let posterior = own - cross.transpose() * s_inv_cross;
    for c in 0..6 {
        for i in 0..CARRIED {
            p[(i, CARRIED + c)] = with_state[(i, c)];
            p[(CARRIED + c, i)] = with_state[(i, c)];
        }
        for r in 0..6 {
            p[(CARRIED + r, CARRIED + c)] = posterior[(r, c)];
        }
    }
    s_inv_cross.transpose() * y
}

pub(crate) fn reset_attitude_error(p: &mut Covariance, at: usize, dtheta: &Vector3<f64>) {
    let g = Matrix3::identity() + (dtheta * 0.5).cross_matrix();
    let rows = g * p.fixed_rows::<3>(at);
    p.fixed_rows_mut::<3>(at).copy_from(&rows);
    let columns = p.fixed_columns::<3>(at) * g.transpose();
    p.fixed_columns_mut::<3>(at).copy_from(&columns);
}

#[cfg(test)]
mod tests {
    use super::super::state::POS;
    use super::*;

    /// The joint covariance of a block's fused rows and the noise it carries out, after
    /// pushing rows of noise `noise` and carrying out `shared`.
    fn rows_and_carried(
        noise: f64,
        shared: &Matrix3<f64>,
        observability: &Observability,
    ) -> SMatrix<f64, 6, 6> {
        let mut rows = Stacked::default();
        let innovation = Vector3::zeros();
        let noise = Matrix3::identity() * noise;
        rows.push(&innovation, &Jacobian3::zeros(), &noise, observability);
        rows.carry_out(0, shared, observability);
        let (cross, own) = rows.carried_out.unwrap();
        let mut joint = SMatrix::<f64, 6, 6>::zeros();
        joint
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&rows.noise.fixed_view::<3, 3>(0, 0));
        joint
            .fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&cross.fixed_view::<3, 3>(0, 0));
        joint
            .fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&cross.fixed_view::<3, 3>(0, 0).transpose());
        joint
            .fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&own.fixed_view::<3, 3>(0, 0));
        joint
    }

    #[test]
    fn a_block_carries_out_no_more_of_its_noise_than_it_holds() {
        let full = Observability::full();
        let within = Matrix3::identity() * 0.5e-6;
        let joint = rows_and_carried(1e-6, &within, &full);
        assert_eq!(joint.fixed_view::<3, 3>(0, 3), within);
        // Twice the rows' own noise: carried as it is, the joint covariance is indefinite and
        // the update leaves negative variances; the correlation is shrunk until it fits.
        let beyond = Matrix3::identity() * 2e-6;
        let joint = rows_and_carried(1e-6, &beyond, &full);
        assert_eq!(joint.fixed_view::<3, 3>(3, 3), beyond);
        assert!(joint.symmetric_eigenvalues().min() > -1e-18, "{joint}");
        let shrunk = joint[(0, 3)] / beyond[(0, 0)];
        assert!((shrunk - 0.5f64.sqrt()).abs() < 1e-9, "{shrunk}");
        // Along a direction the rows leave unobserved the share claims nothing of them.
        let along_x = Observability::from_unobservable(&[Vector3::x()]);
        let unobserved_share = Matrix3::from_diagonal(&Vector3::new(1.0, 0.5e-6, 0.5e-6));
        let joint = rows_and_carried(1e-6, &unobserved_share, &along_x);
        assert!((joint.fixed_view::<2, 3>(0, 3).norm() - 0.5e-6 * 2f64.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn unobservable_directions_leave_an_orthonormal_complement() {
        let o = Observability::from_unobservable(&[Vector3::new(1.0, 1.0, 0.0)]);
        assert_eq!(o.rank(), 2);
        for d in o.observable_directions() {
            assert!((d.norm() - 1.0).abs() < 1e-12);
            assert!(d.dot(&Vector3::new(1.0, 1.0, 0.0)).abs() < 1e-9);
        }
        assert_eq!(Observability::from_unobservable(&[]).rank(), 3);
        let plane = [Vector3::x(), Vector3::new(1.0, 1.0, 0.0)];
        let o = Observability::from_unobservable(&plane);
        assert_eq!(o.rank(), 1);
        assert!((o.observable_directions().next().unwrap().z.abs() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_position_fix_along_one_axis_shrinks_only_that_axis() {
        let mut p = Covariance::identity();
        let mut m = Stacked::default();
        let mut h = Jacobian3::zeros();
        h.fixed_view_mut::<3, 3>(0, POS)
            .copy_from(&Matrix3::identity());
        let along_x = Observability::from_unobservable(&[Vector3::y(), Vector3::z()]);
        m.push(
            &Vector3::new(0.5, 100.0, -100.0),
            &h,
            &(Matrix3::identity() * 0.01),
            &along_x,
        );
        let gated = apply(&mut p, &m, &GateThresholds::new(1.0)).unwrap();
        let dx = gated.correction.unwrap();
        assert_eq!(gated.dof, 1);
        assert!((dx[0] - 0.5 / 1.01).abs() < 1e-12);
        assert_eq!((dx[1], dx[2]), (0.0, 0.0));
        assert!((p[(0, 0)] - 0.01 / 1.01).abs() < 1e-12);
        assert_eq!((p[(1, 1)], p[(2, 2)]), (1.0, 1.0));
    }

    #[test]
    fn the_gate_rejects_a_large_innovation_and_leaves_the_covariance() {
        let mut p = Covariance::identity();
        let mut m = Stacked::default();
        let mut h = Jacobian3::zeros();
        h.fixed_view_mut::<3, 3>(0, POS)
            .copy_from(&Matrix3::identity());
        m.push(
            &Vector3::new(10.0, 0.0, 0.0),
            &h,
            &Matrix3::identity(),
            &Observability::full(),
        );
        let gated = apply(&mut p, &m, &GateThresholds::new(0.999)).unwrap();
        assert!(gated.correction.is_none());
        assert!((gated.nis - 50.0).abs() < 1e-9);
        assert_eq!(p, Covariance::identity());
    }
}
