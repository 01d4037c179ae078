//! The plane map's surfaces as states of the filter (docs/design.md, 4.11 "Plane map").
//!
//! A surface is a plane `n . x = d` in navigation axes (`x` NED), with three error states: two
//! turns of its normal in a tangent basis that follows it, then its distance. Carried with the
//! state, a surface's error keeps its correlation with the poses that measured it, so a line
//! seen on it minutes later tells the filter exactly what the surface and the pose share, and
//! nothing twice.
//!
//! The covariance is `[[P, X], [X^T, M]]`: `P` the filter's fixed 33x33 covariance, `X` its
//! cross-covariance with the surfaces, `M` theirs. Surfaces do not move, so between updates
//! only the rows of `X` that the IMU drives change, as `X <- F X`; the products of the
//! transitions `F` are gathered in `transition` and applied to `X` only when it is read
//! (`settle`), so that an IMU sample costs the same 21 columns however many surfaces there are.

use std::ops::SubAssign;

use nalgebra::{DMatrix, DVector, Matrix3, Matrix3x2, SMatrix, Vector3};

use super::covariance::{symmetrise, ErrorDynamics};
use super::state::{
    Covariance, ErrorState, ATT, AUGMENTED, CLONE_ATT, CLONE_POS, ERROR_STATES, POS,
};
use super::update::{reset_attitude_error, NotPositiveDefinite};

/// Error states of one surface: two tangent turns of its normal, then its distance.
pub(crate) const SURFACE_STATES: usize = 3;

/// Error states of the map's origin: where the map's frame lies in the navigation frame
/// (`MapStates::hand_place_to_map`), ahead of the surfaces' in `X` and `M`.
const ORIGIN_STATES: usize = 3;

/// One mapped surface's nominal parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    /// Stable name, never reused within a filter's life.
    pub id: u64,
    /// Unit normal, navigation axes.
    pub normal: Vector3<f64>,
    /// `normal . x = distance` for the surface's points `x` (NED), metres.
    pub distance: f64,
    /// Directions of the normal's two error states, square to it.
    pub basis: Matrix3x2<f64>,
}

impl Surface {
    /// Adds an error-state correction `[turn_1, turn_2, distance]`, carrying the basis along
    /// (Gram-Schmidt against the new normal) so that the states keep their meaning.
    pub(crate) fn inject(&mut self, correction: &Vector3<f64>) {
        let turn = self.basis * correction.xy();
        self.normal = (self.normal + turn).normalize();
        self.distance += correction.z;
        let first = self.basis.column(0).into_owned();
        let first = (first - self.normal * self.normal.dot(&first)).normalize();
        self.basis = Matrix3x2::from_columns(&[first, self.normal.cross(&first)]);
    }
}

/// A surface about to enter the map. Its error is `on_state dx + own`: the part the pose's
/// error makes (a surface placed from where the body is inherits that pose's error, so that
/// placing it tells the state nothing) and a part of its own, independent of the state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePrior {
    pub normal: Vector3<f64>,
    pub distance: f64,
    /// Directions of the normal's two error states, square to `normal`.
    pub basis: Matrix3x2<f64>,
    /// How `[turn_1, turn_2, distance]` follows the state's error.
    pub on_state: SMatrix<f64, SURFACE_STATES, AUGMENTED>,
    /// Covariance of the part of `[turn_1, turn_2, distance]` of its own.
    pub covariance: Matrix3<f64>,
}

/// Measurement rows over the state and the surfaces: `innovation = core dx + surfaces dm +
/// noise`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct JointRows {
    pub innovation: DVector<f64>,
    /// Rows x `AUGMENTED`.
    pub core: DMatrix<f64>,
    /// Rows x the surfaces' error states, in map order.
    pub surfaces: DMatrix<f64>,
    pub noise: DMatrix<f64>,
}

impl JointRows {
    pub(crate) fn is_finite(&self) -> bool {
        [&self.core, &self.surfaces, &self.noise]
            .into_iter()
            .flat_map(|m| m.iter())
            .chain(self.innovation.iter())
            .all(|x| x.is_finite())
    }
}

/// The outcome of a joint update: the NIS and, when the gate passed, the state's correction
/// (the surfaces are corrected in place).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct JointGated {
    pub nis: f64,
    pub correction: Option<ErrorState>,
    /// How far the update moved the map's origin (NED, m), which the body's reported place
    /// moves with.
    pub origin_moved: Vector3<f64>,
}

/// The surfaces, their covariance and their cross-covariance with the filter's state.
///
/// The surfaces, the body's position and its clone are in the map's frame, which lies at
/// `origin` in the navigation frame: the body is at `p + origin` there. The origin's three
/// error states come first in `X` and `M`; it is zero, and known, until the body's place along
/// a direction no surface faces is first given to the map.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct MapStates {
    surfaces: Vec<Surface>,
    origin: Vector3<f64>,
    /// Whether the body's place was given to the origin since the map was last cleared: its
    /// states then matter even with no surface left.
    origin_in_use: bool,
    cross: DMatrix<f64>,
    own: DMatrix<f64>,
    /// Product of the core transitions since `cross` was last brought up to date.
    transition: SMatrix<f64, ERROR_STATES, ERROR_STATES>,
    pending: bool,
    next_id: u64,
}

impl Default for MapStates {
    fn default() -> Self {
        Self {
            surfaces: Vec::new(),
            origin: Vector3::zeros(),
            origin_in_use: false,
            cross: DMatrix::zeros(AUGMENTED, ORIGIN_STATES),
            own: DMatrix::zeros(ORIGIN_STATES, ORIGIN_STATES),
            transition: SMatrix::identity(),
            pending: false,
            next_id: 0,
        }
    }
}

impl MapStates {
    /// Whether the map holds nothing the state is correlated with.
    pub(crate) fn is_empty(&self) -> bool {
        self.surfaces.is_empty() && !self.origin_in_use
    }

    pub(crate) fn surfaces(&self) -> &[Surface] {
        &self.surfaces
    }

    pub(crate) fn index_of(&self, id: u64) -> Option<usize> {
        self.surfaces.iter().position(|s| s.id == id)
    }

    /// The map's error states: the origin's, then every surface's.
    pub(crate) fn states(&self) -> usize {
        ORIGIN_STATES + SURFACE_STATES * self.surfaces.len()
    }

    /// The first error state of surface `index`.
    pub(crate) fn column_of(index: usize) -> usize {
        ORIGIN_STATES + SURFACE_STATES * index
    }

    /// Where the map's frame lies in the navigation frame (NED, m).
    pub(crate) fn origin(&self) -> Vector3<f64> {
        self.origin
    }

    /// The covariance of the origin's error.
    pub(crate) fn origin_covariance(&self) -> Matrix3<f64> {
        self.own.fixed_view::<3, 3>(0, 0).into_owned()
    }

    /// The cross-covariance between the state's error states and the origin's, with the
    /// transitions not yet applied to `X` applied here.
    pub(crate) fn origin_cross(&self) -> SMatrix<f64, AUGMENTED, 3> {
        let mut cross: SMatrix<f64, AUGMENTED, 3> = SMatrix::from_fn(|r, c| self.cross[(r, c)]);
        if self.pending {
            let core = self.transition * cross.fixed_rows::<ERROR_STATES>(0);
            cross.fixed_rows_mut::<ERROR_STATES>(0).copy_from(&core);
        }
        cross
    }

    /// One IMU interval of the state's transition, to be applied to `X` when it is next read.
    pub(crate) fn advance(&mut self, dynamics: &ErrorDynamics, dt: f64) {
        if self.is_empty() {
            return;
        }
        dynamics.advance_transition(&mut self.transition, dt);
        self.pending = true;
    }

    /// Applies the gathered transitions to the cross-covariance.
    pub(crate) fn settle(&mut self) {
        if !self.pending {
            return;
        }
        let core = self.cross.rows(0, ERROR_STATES).into_owned();
        self.cross
            .rows_mut(0, ERROR_STATES)
            .copy_from(&(self.transition * core));
        self.transition = SMatrix::identity();
        self.pending = false;
    }

    /// The cross-covariance between the state's error states and surface `index`'s.
    pub(crate) fn cross_block(&self, index: usize) -> SMatrix<f64, AUGMENTED, 3> {
        debug_assert!(
            !self.pending,
            "settle() before reading the cross-covariance"
        );
        SMatrix::from_fn(|r, c| self.cross[(r, Self::column_of(index) + c)])
    }

    /// The covariance between surfaces `a` and `b`.
    pub(crate) fn own_block(&self, a: usize, b: usize) -> Matrix3<f64> {
        self.own
            .fixed_view::<3, 3>(Self::column_of(a), Self::column_of(b))
            .into_owned()
    }

    /// Adds a surface with its prior, correlated with the state (covariance `p`) and so with
    /// the other surfaces through `prior.on_state`; returns its id.
    pub(crate) fn add(&mut self, p: &Covariance, prior: &SurfacePrior) -> u64 {
        self.settle();
        let id = self.next_id;
        self.next_id += 1;
        let n = self.states();
        let on_state =
            DMatrix::from_column_slice(SURFACE_STATES, AUGMENTED, prior.on_state.as_slice());
        let p = DMatrix::from_column_slice(AUGMENTED, AUGMENTED, p.as_slice());
        let with_state = &p * on_state.transpose();
        let with_surfaces = &on_state * &self.cross;
        let own_new =
            &on_state * &with_state + DMatrix::from_column_slice(3, 3, prior.covariance.as_slice());
        let mut cross = self.cross.clone().insert_columns(n, SURFACE_STATES, 0.0);
        cross.columns_mut(n, SURFACE_STATES).copy_from(&with_state);
        self.cross = cross;
        let mut own = self
            .own
            .clone()
            .insert_columns(n, SURFACE_STATES, 0.0)
            .insert_rows(n, SURFACE_STATES, 0.0);
        own.view_mut((n, 0), (SURFACE_STATES, n))
            .copy_from(&with_surfaces);
        own.view_mut((0, n), (n, SURFACE_STATES))
            .copy_from(&with_surfaces.transpose());
        own.view_mut((n, n), (SURFACE_STATES, SURFACE_STATES))
            .copy_from(&own_new);
        self.own = own;
        self.symmetrise_own();
        self.surfaces.push(Surface {
            id,
            normal: prior.normal,
            distance: prior.distance,
            basis: prior.basis,
        });
        id
    }

    /// Drops surface `index` (marginalises it out, which a Gaussian allows as it is).
    pub(crate) fn remove(&mut self, index: usize) {
        self.settle();
        let at = Self::column_of(index);
        self.cross = self.cross.clone().remove_columns(at, SURFACE_STATES);
        self.own = self
            .own
            .clone()
            .remove_columns(at, SURFACE_STATES)
            .remove_rows(at, SURFACE_STATES);
        self.surfaces.remove(index);
    }

    /// Forgets every surface (a restart: the state they were correlated with is gone).
    pub(crate) fn clear(&mut self) {
        let next_id = self.next_id;
        *self = Self {
            next_id,
            ..Self::default()
        };
    }

    /// The Kalman update of the state (`p`) and the surfaces together, gated on the NIS at
    /// `threshold`. Leaves everything untouched when the gate refuses.
    ///
    /// `held` projects onto the position's directions the update must not move: their gain is
    /// zeroed, a suboptimal gain whose covariance `P - G + Q G Q^T` (`G = P H^T S^-1 H P`, `Q`
    /// the projection, zero outside the position) keeps them as unsure as before, while their
    /// correlations with everything else are updated exactly as by the optimal gain.
    pub(crate) fn update(
        &mut self,
        p: &mut Covariance,
        rows: &JointRows,
        threshold: f64,
        held: Option<&Matrix3<f64>>,
    ) -> Result<JointGated, NotPositiveDefinite> {
        self.settle();
        // Rows touch few columns (a line: position, velocity, attitude and one surface), so
        // `P H^T` is formed from those columns alone.
        let core_columns = touched_columns(&rows.core);
        let surface_columns = touched_columns(&rows.surfaces);
        let core_t = rows.core.select_columns(&core_columns).transpose();
        let surfaces_t = rows.surfaces.select_columns(&surface_columns).transpose();
        let p_dyn = DMatrix::from_column_slice(AUGMENTED, AUGMENTED, p.as_slice());
        // P H^T, split into the state's rows and the surfaces'.
        let pht_core = p_dyn.select_columns(&core_columns) * &core_t
            + self.cross.select_columns(&surface_columns) * &surfaces_t;
        let pht_map = self.cross.select_rows(&core_columns).transpose() * &core_t
            + self.own.select_columns(&surface_columns) * &surfaces_t;
        let s = core_t.transpose() * pht_core.select_rows(&core_columns)
            + surfaces_t.transpose() * pht_map.select_rows(&surface_columns)
            + &rows.noise;
        let cholesky = s.cholesky().ok_or(NotPositiveDefinite)?;
        let y = &rows.innovation;
        let nis = cholesky.solve(y).dot(y);
        if nis > threshold {
            return Ok(JointGated {
                nis,
                correction: None,
                origin_moved: Vector3::zeros(),
            });
        }
        // With S^-1 formed once, the gains are products, not a triangular solve per column.
        let s_inverse = cholesky.inverse();
        let gain_core_t = &s_inverse * pht_core.transpose();
        let gain_map_t = &s_inverse * pht_map.transpose();
        let mut dx = gain_core_t.transpose() * y;
        let dm = gain_map_t.transpose() * y;
        let mut p_change = &pht_core * &gain_core_t;
        if let Some(q) = held {
            let moved = q * dx.fixed_rows::<3>(POS);
            dx.fixed_rows_mut::<3>(POS).sub_assign(&moved);
            let kept = q * p_change.fixed_view::<3, 3>(POS, POS) * q;
            p_change.fixed_view_mut::<3, 3>(POS, POS).sub_assign(&kept);
        }
        for (entry, change) in p.iter_mut().zip(p_change.iter()) {
            *entry -= change;
        }
        self.cross -= &pht_core * &gain_map_t;
        self.own -= &pht_map * &gain_map_t;
        let correction = ErrorState::from_iterator(dx.iter().copied());
        for at in [ATT, CLONE_ATT] {
            let turn = Vector3::new(correction[at], correction[at + 1], correction[at + 2]);
            reset_attitude_rows(&mut self.cross, at, &turn);
            reset_attitude_error(p, at, &turn);
        }
        self.symmetrise_own();
        let origin_moved = dm.fixed_rows::<ORIGIN_STATES>(0).into_owned();
        self.origin += origin_moved;
        for (k, surface) in self.surfaces.iter_mut().enumerate() {
            surface.inject(&dm.fixed_rows::<3>(Self::column_of(k)).into_owned());
        }
        symmetrise(p);
        Ok(JointGated {
            nis,
            correction: Some(correction),
            origin_moved,
        })
    }

    pub(crate) fn is_finite(&self) -> bool {
        self.cross
            .iter()
            .chain(self.own.iter())
            .all(|x| x.is_finite())
            && self
                .surfaces
                .iter()
                .all(|s| s.distance.is_finite() && s.normal.iter().all(|x| x.is_finite()))
            && self.origin.iter().all(|x| x.is_finite())
    }

    /// Moves the map's frame along the directions `q` projects on (unit directions no fused
    /// surface faces) so that the body is where the map believes it, in the errors alone: the
    /// position's error along them goes to the origin, and out of the open clone (when
    /// `clone_open`) and every surface's distance, which are in the map's frame. The body's
    /// place in the navigation frame, `p + origin`, keeps its error and every correlation it
    /// had: a velocity later measured still corrects it, through the origin.
    ///
    /// A translation of the body, its clone and the whole map together is never observed, so
    /// this tells the filter nothing and takes nothing from it. What it changes is where the
    /// lines are linearised: a surface's turn moves a line's offset by the turn times where
    /// the body is, and along a direction no surface faces the body's place drifts without
    /// bound (16 m off at a 4 m sigma after 100 s of a bare corridor at 10 Hz). Linearised
    /// there, every epoch taught the floor and the walls a tilt along the corridor that they
    /// did not have, and the pitch and the velocity followed them (docs/design.md 4.11,
    /// "The body's place along an unfaced direction").
    pub(crate) fn hand_place_to_map(
        &mut self,
        p: &mut Covariance,
        q: &Matrix3<f64>,
        clone_open: bool,
    ) {
        let mut to_core = SMatrix::<f64, AUGMENTED, 3>::zeros();
        to_core.fixed_view_mut::<3, 3>(POS, 0).copy_from(&(-q));
        if clone_open {
            to_core
                .fixed_view_mut::<3, 3>(CLONE_POS, 0)
                .copy_from(&(-q));
        }
        let mut to_map = DMatrix::<f64>::zeros(self.states(), 3);
        to_map.fixed_view_mut::<3, 3>(0, 0).copy_from(q);
        for (k, surface) in self.surfaces.iter().enumerate() {
            let row = -(surface.normal.transpose() * q);
            to_map
                .row_mut(Self::column_of(k) + SURFACE_STATES - 1)
                .copy_from(&row);
        }
        self.origin_in_use = true;
        self.move_position_error(p, &to_core, &to_map);
    }

    /// Gives the body its place in the navigation frame back, as the map is dropped: the
    /// position becomes `p + origin` (returned, to be added to the nominal position) with the
    /// origin's error, and the map is cleared.
    pub(crate) fn dissolve(&mut self, p: &mut Covariance) -> Vector3<f64> {
        let origin = self.origin;
        let with_place = self.with_place(p);
        put_place(p, &with_place);
        self.clear();
        origin
    }

    /// The covariance of the state's errors (`p`) with the body's place in the navigation
    /// frame, `e_p + e_origin`: the position's columns with the origin's added; at the
    /// position's rows, the place's own covariance.
    pub(crate) fn with_place(&self, p: &Covariance) -> SMatrix<f64, AUGMENTED, 3> {
        let own: SMatrix<f64, AUGMENTED, 3> = p.fixed_view::<AUGMENTED, 3>(0, POS).into();
        if !self.origin_in_use {
            return own;
        }
        let with_origin = self.origin_cross();
        let mut with = own + with_origin;
        let origin_on_position = with_origin.fixed_rows::<3>(POS).transpose();
        let mut block = with.fixed_rows_mut::<3>(POS);
        block += origin_on_position + self.origin_covariance();
        with
    }

    /// Adds `to_core e_p` to the state's error and `to_map e_p` to the map's, `e_p` the
    /// position's error: the covariance of `(I + A S) e`, `S` picking the position out.
    fn move_position_error(
        &mut self,
        p: &mut Covariance,
        to_core: &SMatrix<f64, AUGMENTED, 3>,
        to_map: &DMatrix<f64>,
    ) {
        self.settle();
        let place = p.fixed_view::<3, 3>(POS, POS).into_owned();
        let with_place = p.fixed_view::<AUGMENTED, 3>(0, POS).into_owned();
        let map_with_place = self.cross.rows(POS, 3).into_owned();
        let to_core_dyn = DMatrix::from_column_slice(AUGMENTED, 3, to_core.as_slice());
        let with_place_dyn = DMatrix::from_column_slice(AUGMENTED, 3, with_place.as_slice());
        let place_dyn = DMatrix::from_column_slice(3, 3, place.as_slice());
        self.cross += &to_core_dyn * &map_with_place
            + &with_place_dyn * to_map.transpose()
            + &to_core_dyn * &place_dyn * to_map.transpose();
        self.own += to_map * &map_with_place
            + map_with_place.transpose() * to_map.transpose()
            + to_map * &place_dyn * to_map.transpose();
        *p += to_core * with_place.transpose()
            + with_place * to_core.transpose()
            + to_core * place * to_core.transpose();
        symmetrise(p);
        self.symmetrise_own();
    }

    /// The surfaces' error-state sigmas, in map order.
    pub(crate) fn sigmas(&self, index: usize) -> Vector3<f64> {
        self.own_block(index, index)
            .diagonal()
            .map(|v| v.max(0.0).sqrt())
    }

    fn symmetrise_own(&mut self) {
        let n = self.own.nrows();
        for i in 0..n {
            for j in i + 1..n {
                let mean = 0.5 * (self.own[(i, j)] + self.own[(j, i)]);
                self.own[(i, j)] = mean;
                self.own[(j, i)] = mean;
            }
        }
    }
}

/// Writes `with_place` (`MapStates::with_place`) into the position's rows and columns of `p`.
pub(crate) fn put_place(p: &mut Covariance, with_place: &SMatrix<f64, AUGMENTED, 3>) {
    p.fixed_view_mut::<AUGMENTED, 3>(0, POS)
        .copy_from(with_place);
    p.fixed_view_mut::<3, AUGMENTED>(POS, 0)
        .copy_from(&with_place.transpose());
}

/// The columns of `rows` with an entry other than zero.
fn touched_columns(rows: &DMatrix<f64>) -> Vec<usize> {
    (0..rows.ncols())
        .filter(|&c| rows.column(c).iter().any(|x| *x != 0.0))
        .collect()
}

/// The ESKF reset of an attitude block's rows of the cross-covariance (`update::apply` does the
/// same to `P`).
fn reset_attitude_rows(cross: &mut DMatrix<f64>, at: usize, dtheta: &Vector3<f64>) {
    if cross.ncols() == 0 {
        return;
    }
    let g = Matrix3::identity() + (dtheta * 0.5).cross_matrix();
    let rows = g * cross.fixed_rows::<3>(at);
    cross.fixed_rows_mut::<3>(at).copy_from(&rows);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::odometry::tangent_basis;

    fn prior(normal: Vector3<f64>, distance: f64, sigma: f64) -> SurfacePrior {
        SurfacePrior {
            normal,
            distance,
            basis: tangent_basis(&normal),
            on_state: SMatrix::zeros(),
            covariance: Matrix3::identity() * sigma * sigma,
        }
    }

    /// One row `innovation = n . dp - dd`: a point of the body's on the surface.
    fn point_row(map: &MapStates, index: usize, innovation: f64, noise: f64) -> JointRows {
        let normal = map.surfaces()[index].normal;
        let mut core = DMatrix::zeros(1, AUGMENTED);
        for k in 0..3 {
            core[(0, POS + k)] = normal[k];
        }
        let mut surfaces = DMatrix::zeros(1, map.states());
        surfaces[(0, MapStates::column_of(index) + 2)] = -1.0;
        JointRows {
            innovation: DVector::from_element(1, innovation),
            core,
            surfaces,
            noise: DMatrix::from_element(1, 1, noise * noise),
        }
    }

    #[test]
    fn a_surface_seen_from_two_poses_ties_them_together() {
        // The position is known to 1 m along x; a wall facing x is added with a vague prior,
        // seen once (which only places the wall), then the position gets its own fix: the
        // wall's distance follows it through the correlation the first sighting made.
        let mut p = Covariance::identity();
        let mut map = MapStates::default();
        let id = map.add(&p, &prior(Vector3::x(), 5.0, 10.0));
        assert_eq!(map.index_of(id), Some(0));
        let first = map
            .update(&mut p, &point_row(&map, 0, 0.0, 0.01), 1e9, None)
            .unwrap();
        assert!(first.correction.is_some());
        assert!((map.sigmas(0).z - 1.0).abs() < 1e-2, "{}", map.sigmas(0));
        let cross = map.cross_block(0);
        assert!((cross[(POS, 2)] - 1.0).abs() < 1e-2, "{cross}");
        // A position fix of 0.5 m along x, exact: the wall moves with it.
        let mut fix = point_row(&map, 0, 0.5, 1e-6);
        fix.surfaces.fill(0.0);
        fix.core.fill(0.0);
        fix.core[(0, POS)] = 1.0;
        let gated = map.update(&mut p, &fix, 1e9, None).unwrap();
        assert!((gated.correction.unwrap()[POS] - 0.5).abs() < 1e-6);
        assert!((map.surfaces()[0].distance - 5.5).abs() < 1e-3);
        assert!(map.sigmas(0).z < 0.02);
    }

    #[test]
    fn a_held_direction_keeps_its_estimate_and_sigma_while_the_surface_takes_the_innovation() {
        let mut p = Covariance::identity() * 0.01;
        let mut map = MapStates::default();
        map.add(&p, &prior(Vector3::x(), 5.0, 0.1));
        let held = Matrix3::from_diagonal(&Vector3::x());
        let before = p;
        let gated = map
            .update(&mut p, &point_row(&map, 0, 0.05, 0.001), 1e9, Some(&held))
            .unwrap();
        let correction = gated.correction.unwrap();
        assert_eq!(correction[POS], 0.0);
        assert!((p[(POS, POS)] - before[(POS, POS)]).abs() < 1e-15);
        // The wall moved instead, and is now known relative to the body.
        assert!((map.surfaces()[0].distance - 5.0 + 0.05 * 0.01 / 0.02).abs() < 2e-3);
        assert!(map.sigmas(0).z < 0.1);
        // Unheld, the same update splits the innovation between the two.
        let mut p = before;
        let mut free = MapStates::default();
        free.add(&p, &prior(Vector3::x(), 5.0, 0.1));
        let gated = free.update(&mut p, &point_row(&free, 0, 0.05, 0.001), 1e9, None);
        assert!(gated.unwrap().correction.unwrap()[POS] > 0.002);
        assert!(p[(POS, POS)] < before[(POS, POS)]);
    }

    #[test]
    fn handing_the_place_to_the_map_changes_nothing_any_line_can_see() {
        use crate::filter::state::VEL;
        // A corridor: a wall facing y, a floor facing z, and an end wall facing x, placed
        // from the body, which then walked on until it was 2 m unsure of its place along x.
        let mut p = Covariance::identity() * 1e-4;
        let mut map = MapStates::default();
        let mut placed = |normal: Vector3<f64>, distance: f64| {
            let mut prior = prior(normal, distance, 0.01);
            for k in 0..3 {
                prior.on_state[(SURFACE_STATES - 1, POS + k)] = normal[k];
            }
            map.add(&p, &prior);
        };
        placed(Vector3::y(), 1.1);
        placed(Vector3::z(), 1.2);
        placed(Vector3::x(), 27.0);
        p[(POS, POS)] += 4.0;
        p[(POS, VEL)] = 0.01;
        p[(VEL, POS)] = 0.01;
        // What any line sees: the body against each surface (`n . dp - dd`), and the velocity.
        let seen = |map: &MapStates, p: &Covariance| -> Vec<f64> {
            let mut variances: Vec<f64> = (0..3)
                .map(|index| {
                    let row = point_row(map, index, 0.0, 0.0);
                    let joint = |a: &DMatrix<f64>, b: &DMatrix<f64>| (a * b)[(0, 0)];
                    let p_dyn = DMatrix::from_column_slice(AUGMENTED, AUGMENTED, p.as_slice());
                    joint(&(&row.core * &p_dyn), &row.core.transpose())
                        + 2.0 * joint(&(&row.core * &map.cross), &row.surfaces.transpose())
                        + joint(&(&row.surfaces * &map.own), &row.surfaces.transpose())
                })
                .collect();
            variances.push(p[(VEL, VEL)]);
            variances
        };
        let before = seen(&map, &p);
        let along = Matrix3::from_diagonal(&Vector3::x());
        map.hand_place_to_map(&mut p, &along, false);
        assert!(p[(POS, POS)].abs() < 1e-12 && p[(POS, VEL)].abs() < 1e-12);
        // The origin took it over, with its correlation with the velocity.
        let origin = map.origin_covariance()[(0, 0)];
        assert!((origin - 4.0001).abs() < 1e-12, "{origin}");
        assert!((map.origin_cross()[(VEL, 0)] - 0.01).abs() < 1e-12);
        // The end wall now carries the body's unsureness along x; the others are untouched.
        assert!(
            (map.sigmas(2).z.powi(2) - 4.0).abs() < 1e-3,
            "{}",
            map.sigmas(2)
        );
        assert!(map.sigmas(0).z < 0.02 && map.sigmas(1).z < 0.02);
        for (after, before) in seen(&map, &p).iter().zip(&before) {
            assert!((after - before).abs() < 1e-12, "{after} against {before}");
        }
    }

    #[test]
    fn a_velocity_measured_after_the_hand_over_still_corrects_the_place() {
        use crate::filter::state::VEL;
        // A walk along x at a velocity known to 0.1 m/s, 10 s on: the place is 1 m unsure,
        // wholly through the velocity, when it is handed to the map.
        let mut p = Covariance::identity() * 1e-6;
        p[(VEL, VEL)] = 0.01;
        p[(POS, POS)] = 1.0;
        p[(POS, VEL)] = 0.1;
        p[(VEL, POS)] = 0.1;
        let mut map = MapStates::default();
        map.add(&p, &prior(Vector3::y(), 1.1, 0.01));
        map.hand_place_to_map(&mut p, &Matrix3::from_diagonal(&Vector3::x()), false);
        // The velocity is then measured 0.05 m/s too fast: the place was 0.5 m too far on.
        let mut rows = point_row(&map, 0, 0.0, 0.0);
        rows.core.fill(0.0);
        rows.surfaces.fill(0.0);
        rows.core[(0, VEL)] = 1.0;
        rows.innovation[0] = -0.05;
        rows.noise[(0, 0)] = 1e-8;
        map.update(&mut p, &rows, 1e9, None).unwrap();
        assert!((map.origin().x + 0.5).abs() < 1e-3, "{}", map.origin());
        let place =
            p[(POS, POS)] + 2.0 * map.origin_cross()[(POS, 0)] + map.origin_covariance()[(0, 0)];
        assert!(place < 1e-3, "{place}");
        // Dropping the map gives the body its place back, as sure as the velocity made it.
        let mut dropped = p;
        assert!((map.dissolve(&mut dropped) - map_origin(-0.5)).norm() < 1e-3);
        assert!((dropped[(POS, POS)] - place).abs() < 1e-12);
        assert!(map.is_empty());
    }

    fn map_origin(x: f64) -> Vector3<f64> {
        Vector3::new(x, 0.0, 0.0)
    }

    #[test]
    fn a_refused_update_changes_nothing_and_removal_keeps_the_rest() {
        let mut p = Covariance::identity() * 1e-4;
        let mut map = MapStates::default();
        map.add(&p, &prior(Vector3::x(), 5.0, 0.01));
        let second = map.add(&p, &prior(Vector3::y(), -2.0, 0.02));
        let before = map.clone();
        let gated = map
            .update(&mut p, &point_row(&map, 0, 3.0, 0.01), 9.0, None)
            .unwrap();
        assert!(gated.correction.is_none() && gated.nis > 9.0);
        assert_eq!(map, before);
        map.remove(0);
        assert_eq!(map.surfaces().len(), 1);
        assert_eq!(map.index_of(second), Some(0));
        assert!((map.sigmas(0).z - 0.02).abs() < 1e-12);
        map.clear();
        assert!(map.is_empty());
        assert!(map.add(&p, &prior(Vector3::z(), 1.0, 0.1)) > second);
    }

    #[test]
    fn injection_keeps_the_basis_square_to_the_normal() {
        let mut surface = Surface {
            id: 0,
            normal: Vector3::z(),
            distance: 1.0,
            basis: tangent_basis(&Vector3::z()),
        };
        surface.inject(&Vector3::new(0.1, -0.05, 0.2));
        assert!((surface.normal.norm() - 1.0).abs() < 1e-12);
        let b = surface.basis;
        assert!(b.column(0).dot(&surface.normal).abs() < 1e-12);
        assert!(b.column(1).dot(&surface.normal).abs() < 1e-12);
        assert!((b.column(0).norm() - 1.0).abs() < 1e-12);
        assert!((surface.distance - 1.2).abs() < 1e-12);
    }
}
