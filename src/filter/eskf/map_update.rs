//! The plane map's update: lines of the current epoch on mapped surfaces (docs/design.md,
//! 4.11 "Plane map"). A line on a plane gives two rows: its centroid's offset from the plane
//! and its direction's tilt out of it, each against the pose at the epoch's reference time.

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Matrix3x2, SMatrix, Vector2, Vector3};

use super::{Eskf, UpdateError, UpdateKind, UpdateReport};
use crate::filter::consistency::chi_square_quantile;
use crate::filter::history::Pose;
use crate::filter::map_states::{JointRows, MapStates, Surface, SurfacePrior, SURFACE_STATES};
use crate::filter::state::{ATT, AUGMENTED, POS, VEL};
use crate::least_squares::{facing, PARALLEL_TOLERANCE};

/// A line of one scan in the body frame at its epoch's reference time, as the map sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapLine {
    pub centroid: Vector3<f64>,
    /// Unit direction.
    pub direction: Vector3<f64>,
    /// Length, m.
    pub length_m: f64,
    /// Unit, in the scan plane and square to the line: the one way its noise moves it.
    pub across: Vector3<f64>,
    /// Sigma of the centroid along `across`, m.
    pub centroid_sigma_m: f64,
    /// Sigma of the direction's turn towards `across`, rad.
    pub direction_sigma_rad: f64,
    /// Mean of its beams' times less the reference time, s: a velocity error `dv` deskews the
    /// centroid by `dv` times this.
    pub time_offset_s: f64,
    /// Slope of its beams' times along the line, s/m: the same error turns the line by `dv`
    /// times this.
    pub time_slope_s_per_m: f64,
}

/// What a real surface adds to a line's own noise: its unevenness under the line's offset, and
/// its waviness under the line's tilt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceAllowance {
    pub roughness_m: f64,
    pub waviness_rad: f64,
}

/// Where a new surface lies, seen from the body at an epoch: the surface is carried by the
/// body's pose at that time, so its error starts as the pose's, plus a part of its own.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePlacement {
    /// Unit normal and distance (`normal . x = distance`, x NED).
    pub normal: Vector3<f64>,
    pub distance: f64,
    /// Directions of the normal's two error states, square to `normal`.
    pub basis: Matrix3x2<f64>,
    /// A point of the surface the body carries (NED): the centroid of the lines that place it.
    /// Its own turns turn the surface about it.
    pub anchor: Vector3<f64>,
    /// Whether each turn follows the body's attitude; a building's assumption (a wall plumb,
    /// a floor level) holds in the navigation frame, whatever the attitude's error.
    pub turns_follow_body: [bool; 2],
    /// Covariance of its own turns (rad) and of its own distance at `anchor` (m): a vague
    /// prior, which the lines that place the surface then narrow.
    pub own_covariance: Matrix3<f64>,
}

impl SurfacePlacement {
    /// The prior over the surface's error states: `distance = n . anchor`, the anchor moving
    /// with the pose at the epoch (`p(t_ref) = p(now) - v lag`) and the normal with its attitude.
    fn prior(&self, epoch: &Epoch) -> SurfacePrior {
        let n = self.normal;
        let arm = self.anchor - epoch.pose.p;
        let mut on_state = SMatrix::<f64, SURFACE_STATES, AUGMENTED>::zeros();
        let mut distance_on_attitude = arm.cross(&n);
        for (k, follows) in self.turns_follow_body.into_iter().enumerate() {
            let b = self.basis.column(k).into_owned();
            if follows {
                let turn = n.cross(&b);
                on_state
                    .fixed_view_mut::<1, 3>(k, ATT)
                    .copy_from(&turn.transpose());
                distance_on_attitude += turn * b.dot(&self.anchor);
            }
        }
        let row = SURFACE_STATES - 1;
        on_state
            .fixed_view_mut::<1, 3>(row, POS)
            .copy_from(&n.transpose());
        on_state
            .fixed_view_mut::<1, 3>(row, VEL)
            .copy_from(&(-epoch.lag_s * n).transpose());
        on_state
            .fixed_view_mut::<1, 3>(row, ATT)
            .copy_from(&distance_on_attitude.transpose());
        let to_distance = self.own_to_distance();
        SurfacePrior {
            normal: n,
            distance: self.distance,
            basis: self.basis,
            on_state,
            covariance: to_distance * self.own_covariance * to_distance.transpose(),
        }
    }

    /// Maps the own parameters `[turn_1, turn_2, distance at the anchor]` to the error states
    /// `[turn_1, turn_2, distance]`: a turn about the anchor moves the distance by the anchor's
    /// reach along the turn.
    fn own_to_distance(&self) -> Matrix3<f64> {
        let mut map = Matrix3::identity();
        for k in 0..2 {
            map[(SURFACE_STATES - 1, k)] = self.basis.column(k).dot(&self.anchor);
        }
        map
    }

    /// The surface fitted to `lines` (a Gauss-Newton step from the placement, which came from
    /// the same lines) with its own covariance from them, the pose held, and how well they lie
    /// on it.
    fn fitted(
        &self,
        lines: &[MapLine],
        epoch: &Epoch,
        allowance: &SurfaceAllowance,
    ) -> Option<Fit> {
        let nominal = Surface {
            id: 0,
            normal: self.normal,
            distance: self.distance,
            basis: self.basis,
        };
        let to_distance = self.own_to_distance();
        let prior_information = self.own_covariance.try_inverse()?;
        let mut information = prior_information;
        let mut gradient = Vector3::zeros();
        let mut rows = Vec::with_capacity(lines.len());
        for line in lines {
            let fit = line_rows(line, &nominal, epoch, allowance);
            let h = fit.surface * to_distance;
            let weight = fit.noise.try_inverse()?;
            information += h.transpose() * weight * h;
            gradient += h.transpose() * weight * fit.innovation;
            rows.push((h, weight, fit.innovation));
        }
        let covariance = information.try_inverse()?;
        let own = covariance * gradient;
        let misfit = rows
            .iter()
            .map(|(h, weight, y)| {
                let r = y - h * own;
                r.dot(&(weight * r))
            })
            .sum::<f64>()
            + own.dot(&(prior_information * own));
        let determined = if self.turns_follow_body.iter().all(|&f| f) {
            3
        } else {
            2
        };
        let mut surface = nominal;
        surface.inject(&(to_distance * own));
        Some(Fit {
            placement: Self {
                normal: surface.normal,
                distance: surface.distance,
                basis: surface.basis,
                own_covariance: covariance,
                ..*self
            },
            misfit,
            dof: (2 * lines.len()).saturating_sub(determined),
        })
    }
}

/// A placement fitted to its lines: the chi-square of their misfit and its degrees of freedom
/// (the lines' rows less the parameters they determined).
struct Fit {
    placement: SurfacePlacement,
    misfit: f64,
    dof: usize,
}

/// A line on a surface, to be fused.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineOnSurface {
    pub line: MapLine,
    pub surface: u64,
}

/// A line's two rows against one surface.
#[derive(Debug, Clone, Copy)]
struct LineRows {
    innovation: Vector2<f64>,
    /// Over `POS`, `VEL`, `ATT`.
    core: SMatrix<f64, 2, 9>,
    surface: SMatrix<f64, 2, 3>,
    noise: Matrix2<f64>,
}

/// The epoch's lines stacked against the prediction, for the integrity test: the innovation,
/// its covariance, and what gives the gain on position and velocity.
#[derive(Debug, Clone, PartialEq)]
pub struct LineStack {
    pub innovation: DVector<f64>,
    pub covariance: DMatrix<f64>,
    /// Position and velocity rows of `P H^T`, one column per row of the stack.
    pub cross: DMatrix<f64>,
    /// Covariance of position and velocity.
    pub prior: DMatrix<f64>,
}

/// The pose of the epoch's reference time, and how long before the filter's time it is: what
/// every line of the epoch is measured against (`Eskf::map_epoch`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Epoch {
    pose: Pose,
    lag_s: f64,
}

impl Eskf {
    /// The body's place in the navigation frame (NED, m): in the map's frame, which lies at
    /// the map's origin (`MapStates::hand_place_to_map`).
    pub(crate) fn position(&self) -> Vector3<f64> {
        self.state.p + self.map_origin()
    }

    /// Where the map's frame lies in the navigation frame (NED, m).
    pub(crate) fn map_origin(&self) -> Vector3<f64> {
        self.map.origin()
    }

    /// Covariance of `position`'s error with the state's (`MapStates::with_place`).
    pub(crate) fn with_position(&self) -> SMatrix<f64, AUGMENTED, 3> {
        self.map.with_place(&self.covariance)
    }

    /// Covariance of the position, NED, m^2.
    pub(crate) fn position_covariance(&self) -> Matrix3<f64> {
        self.with_position().fixed_rows::<3>(POS).into_owned()
    }

    /// Gives the body its place in the navigation frame back as the map is dropped: without
    /// surfaces there is nothing to hold the body's place for.
    pub(super) fn dissolve_map(&mut self) {
        let origin = self.map.dissolve(&mut self.covariance);
        if origin.iter().all(|x| x.is_finite()) {
            self.state.p += origin;
        }
    }

    /// The mapped surfaces.
    pub(crate) fn surfaces(&self) -> &[Surface] {
        self.map.surfaces()
    }

    /// Adds a surface to the map where the body at `t_ref` sees `lines` on it; returns its id,
    /// or `None` when the lines do not lie on one surface. The lines place it and are spent on
    /// it: fitted in the surface's own three parameters, with the pose's error carried in by
    /// correlation, they tell the state nothing, as one sighting of a new surface cannot.
    pub(crate) fn add_surface(
        &mut self,
        placement: &SurfacePlacement,
        lines: &[MapLine],
        t_ref: f64,
        allowance: &SurfaceAllowance,
    ) -> Result<Option<u64>, UpdateError> {
        self.aligned_time()?;
        let epoch = self
            .epoch(t_ref)
            .ok_or(UpdateError::OutsideHistory { t_ref })?;
        let Some(fit) = placement.fitted(lines, &epoch, allowance) else {
            return Ok(None);
        };
        if fit.dof > 0 && fit.misfit > self.map_gate(fit.dof) {
            return Ok(None);
        }
        let fitted = fit.placement;
        self.map.settle();
        Ok(Some(self.map.add(&self.covariance, &fitted.prior(&epoch))))
    }

    /// Drops a surface from the map; a surface the map no longer holds is ignored.
    pub(crate) fn remove_surface(&mut self, id: u64) {
        if let Some(index) = self.map.index_of(id) {
            self.map.remove(index);
        }
    }

    /// The sigmas of a surface's error states `[turn, turn, distance]`.
    pub(crate) fn surface_sigmas(&self, id: u64) -> Option<Vector3<f64>> {
        Some(self.map.sigmas(self.map.index_of(id)?))
    }

    /// The innovation of `line` on surface `id` at the epoch `t_ref` and its covariance: what
    /// associates a line with a surface. Every line of an epoch is tried on every surface near
    /// it, so this works in fixed sizes, apart from `stack_lines`.
    pub(crate) fn line_fit(
        &self,
        line: &MapLine,
        id: u64,
        epoch: &Epoch,
        allowance: &SurfaceAllowance,
    ) -> Option<(Vector2<f64>, Matrix2<f64>)> {
        let index = self.map.index_of(id)?;
        let rows = line_rows(line, &self.map.surfaces()[index], epoch, allowance);
        let core = self.core_covariance();
        let cross = self.core_cross(index);
        let own = self.map.own_block(index, index);
        let on_core = core * rows.core.transpose() + cross * rows.surface.transpose();
        let on_surface = cross.transpose() * rows.core.transpose() + own * rows.surface.transpose();
        let covariance = rows.core * on_core + rows.surface * on_surface + rows.noise;
        Some((rows.innovation, covariance))
    }

    /// The pose the lines of the epoch `t_ref` are measured against, with the map brought up
    /// to the filter's time; `None` outside the pose history.
    pub(crate) fn map_epoch(&mut self, t_ref: f64) -> Option<Epoch> {
        self.map.settle();
        self.epoch(t_ref)
    }

    /// The prediction's sigma of `line`'s offset from surface `id` at the epoch `t_ref`, m: what
    /// the state and the surface together leave of where the line should lie, its own noise
    /// apart.
    pub(crate) fn offset_prediction_sigma(
        &self,
        line: &MapLine,
        id: u64,
        epoch: &Epoch,
    ) -> Option<f64> {
        let exact = MapLine {
            centroid_sigma_m: 0.0,
            direction_sigma_rad: 0.0,
            ..*line
        };
        let none = SurfaceAllowance {
            roughness_m: 0.0,
            waviness_rad: 0.0,
        };
        let (_, covariance) = self.line_fit(&exact, id, epoch, &none)?;
        Some(covariance[(0, 0)].max(0.0).sqrt())
    }

    /// The lines stacked against the prediction, two rows each in the order given. `None` when
    /// the epoch lies outside the pose history or a surface is not mapped.
    pub(crate) fn stack_lines(
        &mut self,
        lines: &[LineOnSurface],
        t_ref: f64,
        allowance: &SurfaceAllowance,
    ) -> Option<LineStack> {
        let epoch = self.epoch(t_ref)?;
        self.map.settle();
        let rows = self.rows_of(lines, &epoch, allowance).ok()?;
        let mut used: Vec<usize> = Vec::new();
        let slots: Vec<usize> = rows
            .iter()
            .map(|(index, _)| {
                used.iter().position(|u| u == index).unwrap_or_else(|| {
                    used.push(*index);
                    used.len() - 1
                })
            })
            .collect();
        let covariance = self.joint_covariance(&used);
        let (innovation, noise) = innovation_and_noise(&rows);
        let mut h = DMatrix::zeros(innovation.len(), covariance.ncols());
        for (r, ((_, line), slot)) in rows.iter().zip(&slots).enumerate() {
            h.view_mut((2 * r, 0), (2, 9)).copy_from(&line.core);
            h.view_mut((2 * r, 9 + SURFACE_STATES * slot), (2, SURFACE_STATES))
                .copy_from(&line.surface);
        }
        let pht = &covariance * h.transpose();
        let s = &h * &pht + noise;
        Some(LineStack {
            innovation,
            covariance: s,
            cross: pht.rows(0, 6).into_owned(),
            prior: covariance.view((0, 0), (6, 6)).into_owned(),
        })
    }

    /// Fuses the lines on their surfaces as one odometry update, holding the position along
    /// each of `unfaced` (unit directions, navigation axes, that none of the surfaces faces)
    /// where it was (`held_along`).
    pub(crate) fn update_map_lines(
        &mut self,
        lines: &[LineOnSurface],
        t_ref: f64,
        allowance: &SurfaceAllowance,
        unfaced: &[Vector3<f64>],
    ) -> Result<UpdateReport, UpdateError> {
        let held = Self::held_along(unfaced);
        let unmapped = self.unfaced_by_the_map(unfaced);
        if let (Some(q), Ok(_)) = (Self::held_along(&unmapped), self.aligned_time()) {
            let clone_open = self.clone.is_some();
            self.map
                .hand_place_to_map(&mut self.covariance, &q, clone_open);
        }
        let report = self.fuse_lines(lines, t_ref, allowance, held.as_ref())?;
        self.after_odometry_update(&report, [t_ref, t_ref], report.t);
        Ok(report)
    }

    /// Those of `unfaced` that no surface the map holds faces either: only along them is the
    /// body's place given to the map (`MapStates::hand_place_to_map`). Where a surface the
    /// map holds faces a direction, seeing it again must correct the body, not move the map:
    /// given away there in every epoch of the open room's hover, the place drifted 5.6 cm in a
    /// minute instead of 0.2 cm.
    fn unfaced_by_the_map(&self, unfaced: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let gram = facing(self.map.surfaces().iter().map(|s| &s.normal));
        let largest = gram.symmetric_eigenvalues().max();
        unfaced
            .iter()
            .filter(|u| u.dot(&(gram * *u)) <= PARALLEL_TOLERANCE * largest)
            .copied()
            .collect()
    }

    /// The projection onto the position's directions along `unfaced`. No surface measures where the body
    /// is along such a direction, yet the updates moved it there: along a bare corridor every
    /// epoch's lines on the walls and the floor corrected the position along it by decimetres
    /// (through its correlations with the attitude, the velocity and the surfaces), the
    /// corrections counted as 30-90 jumps of the pose in two minutes, and the filter grew sure
    /// of a velocity it had not measured (velocity NEES 1.9 per axis over 20 runs, 9-dof NEES
    /// 124; the same runs with noise-free IMUs stayed honest). Holding the position there
    /// leaves the velocity's information from the walls, the floor and gravity as it is; also
    /// holding the velocity, or the accelerometer bias with it, left the velocity a metre a
    /// second unsure within a minute, when the IMU's information through the floor's tilt was
    /// worth having.
    fn held_along(unfaced: &[Vector3<f64>]) -> Option<Matrix3<f64>> {
        (!unfaced.is_empty()).then(|| unfaced.iter().map(|u| u * u.transpose()).sum())
    }

    fn fuse_lines(
        &mut self,
        lines: &[LineOnSurface],
        t_ref: f64,
        allowance: &SurfaceAllowance,
        held: Option<&Matrix3<f64>>,
    ) -> Result<UpdateReport, UpdateError> {
        let now = self.aligned_time()?;
        let epoch = self
            .epoch(t_ref)
            .ok_or(UpdateError::OutsideHistory { t_ref })?;
        let rows = self.rows_of(lines, &epoch, allowance)?;
        let (innovation, noise) = innovation_and_noise(&rows);
        let k = innovation.len();
        let mut joint = JointRows {
            innovation,
            core: DMatrix::zeros(k, AUGMENTED),
            surfaces: DMatrix::zeros(k, self.map.states()),
            noise,
        };
        for (r, (index, line)) in rows.iter().enumerate() {
            for (block, at) in CORE.into_iter().enumerate() {
                joint
                    .core
                    .view_mut((2 * r, at), (2, 3))
                    .copy_from(&line.core.fixed_view::<2, 3>(0, 3 * block));
            }
            joint
                .surfaces
                .view_mut((2 * r, MapStates::column_of(*index)), (2, SURFACE_STATES))
                .copy_from(&line.surface);
        }
        let threshold = self.map_gate(k);
        self.fuse_joint(&joint, (k, threshold), held, UpdateKind::MapLines, now)
    }

    /// Each line's rows against its surface, with the surface's place in the map.
    fn rows_of(
        &self,
        lines: &[LineOnSurface],
        epoch: &Epoch,
        allowance: &SurfaceAllowance,
    ) -> Result<Vec<(usize, LineRows)>, UpdateError> {
        lines
            .iter()
            .map(|on| {
                let index = self
                    .map
                    .index_of(on.surface)
                    .ok_or(UpdateError::NoSurface { id: on.surface })?;
                let surface = &self.map.surfaces()[index];
                Ok((index, line_rows(&on.line, surface, epoch, allowance)))
            })
            .collect()
    }

    /// The gate's chi-square threshold for `dof` rows of lines, computed once per count.
    fn map_gate(&mut self, dof: usize) -> f64 {
        let probability = self.config.gate_probability;
        let known = self.map_gates.len();
        self.map_gates
            .extend((known..=dof).map(|rows| chi_square_quantile(probability, rows)));
        self.map_gates[dof]
    }

    fn epoch(&self, t_ref: f64) -> Option<Epoch> {
        let now = self.t?;
        let pose = self.pose_or_ahead(t_ref)?;
        Some(Epoch {
            pose,
            lag_s: now - t_ref,
        })
    }

    /// The covariance of position, velocity and attitude, in that order (`line_rows`' columns).
    fn core_covariance(&self) -> SMatrix<f64, 9, 9> {
        SMatrix::from_fn(|r, c| self.covariance[(CORE[r / 3] + r % 3, CORE[c / 3] + c % 3)])
    }

    /// The cross-covariance of position, velocity and attitude with surface `index`.
    fn core_cross(&self, index: usize) -> SMatrix<f64, 9, 3> {
        let cross = self.map.cross_block(index);
        SMatrix::from_fn(|r, c| cross[(CORE[r / 3] + r % 3, c)])
    }

    /// The covariance of position, velocity, attitude and the surfaces `used`, in that order.
    fn joint_covariance(&self, used: &[usize]) -> DMatrix<f64> {
        let n = 9 + SURFACE_STATES * used.len();
        let mut c = DMatrix::zeros(n, n);
        c.view_mut((0, 0), (9, 9))
            .copy_from(&self.core_covariance());
        for (slot, &index) in used.iter().enumerate() {
            let at = 9 + SURFACE_STATES * slot;
            let cross = self.core_cross(index);
            c.view_mut((0, at), (9, 3)).copy_from(&cross);
            c.view_mut((at, 0), (3, 9)).copy_from(&cross.transpose());
            for (other, &index_b) in used.iter().enumerate() {
                c.fixed_view_mut::<3, 3>(at, 9 + SURFACE_STATES * other)
                    .copy_from(&self.map.own_block(index, index_b));
            }
        }
        c
    }
}

/// The lines' innovations and their block-diagonal noise, two rows a line in order.
fn innovation_and_noise(rows: &[(usize, LineRows)]) -> (DVector<f64>, DMatrix<f64>) {
    let k = 2 * rows.len();
    let mut innovation = DVector::zeros(k);
    let mut noise = DMatrix::zeros(k, k);
    for (r, (_, line)) in rows.iter().enumerate() {
        innovation.rows_mut(2 * r, 2).copy_from(&line.innovation);
        noise
            .view_mut((2 * r, 2 * r), (2, 2))
            .copy_from(&line.noise);
    }
    (innovation, noise)
}

/// The error states `line_rows` measures, in its columns' order.
const CORE: [usize; 3] = [POS, VEL, ATT];

/// The rows of `line` on `surface`: `n . (R c + p) - d = 0` and `n . (R u) = 0`, with the
/// pose at the epoch (`p(t_ref) = p(now) - v lag` to first order) and the deskew's velocity.
fn line_rows(
    line: &MapLine,
    surface: &Surface,
    epoch: &Epoch,
    allowance: &SurfaceAllowance,
) -> LineRows {
    let n = surface.normal;
    let rotation = epoch.pose.q;
    let arm = rotation.transform_vector(&line.centroid);
    let point = arm + epoch.pose.p;
    let along = rotation.transform_vector(&line.direction);
    let across = rotation.transform_vector(&line.across);
    let mut core = SMatrix::<f64, 2, 9>::zeros();
    let mut put = |row: usize, block: usize, v: Vector3<f64>| {
        core.fixed_view_mut::<1, 3>(row, 3 * block)
            .copy_from(&v.transpose());
    };
    put(0, 0, n);
    put(0, 1, n * (line.time_offset_s - epoch.lag_s));
    put(0, 2, arm.cross(&n));
    put(1, 1, (n - along * n.dot(&along)) * line.time_slope_s_per_m);
    put(1, 2, along.cross(&n));
    let b = surface.basis;
    let surface_rows = SMatrix::<f64, 2, 3>::new(
        point.dot(&b.column(0)),
        point.dot(&b.column(1)),
        -1.0,
        along.dot(&b.column(0)),
        along.dot(&b.column(1)),
        0.0,
    );
    let reach = n.dot(&across).powi(2);
    LineRows {
        innovation: Vector2::new(surface.distance - n.dot(&point), -n.dot(&along)),
        core,
        surface: surface_rows,
        noise: Matrix2::new(
            line.centroid_sigma_m.powi(2) * reach + allowance.roughness_m.powi(2),
            0.0,
            0.0,
            line.direction_sigma_rad.powi(2) * reach + allowance.waviness_rad.powi(2),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::state::NominalState;
    use crate::filter::testkit::{Stationary, Trajectory};
    use crate::filter::FilterConfig;
    use crate::odometry::tangent_basis;
    use nalgebra::UnitQuaternion;

    const ALLOWANCE: SurfaceAllowance = SurfaceAllowance {
        roughness_m: 0.003,
        waviness_rad: 0.002,
    };

    fn still_filter() -> Eskf {
        let state = NominalState::at_rest(UnitQuaternion::identity(), Vector3::zeros());
        Eskf::with_initial_state(FilterConfig::default(), 0.0, state).unwrap()
    }

    /// A level line across a wall `ahead_m` in front of the body, `up_m` above it (NED: z
    /// down), as a level scanner lays it.
    fn wall_line(ahead_m: f64, up_m: f64) -> MapLine {
        MapLine {
            centroid: Vector3::new(ahead_m, 0.0, -up_m),
            direction: Vector3::y(),
            length_m: 2.0,
            across: Vector3::x(),
            centroid_sigma_m: 0.001,
            direction_sigma_rad: 0.001,
            time_offset_s: 0.0,
            time_slope_s_per_m: 0.0,
        }
    }

    /// The wall facing the body at `ahead_m`, vague about its own turns and distance.
    fn wall(ahead_m: f64) -> SurfacePlacement {
        let normal = Vector3::x();
        SurfacePlacement {
            normal,
            distance: ahead_m,
            basis: tangent_basis(&normal),
            anchor: normal * ahead_m,
            turns_follow_body: [true, true],
            own_covariance: Matrix3::from_diagonal(&Vector3::new(0.0076, 0.0076, 1.0)),
        }
    }

    fn placed_wall(filter: &mut Eskf) -> u64 {
        let lines = [wall_line(5.0, 0.4), wall_line(5.0, -0.4)];
        filter
            .add_surface(&wall(5.0), &lines, 0.0, &ALLOWANCE)
            .unwrap()
            .expect("two lines of one wall place it")
    }

    #[test]
    fn a_surface_placed_from_the_pose_carries_its_error_and_tells_it_nothing() {
        let mut filter = still_filter();
        let before = filter.covariance;
        let id = placed_wall(&mut filter);
        assert_eq!(filter.covariance, before);
        let index = filter.map.index_of(id).unwrap();
        // The wall's distance moves with the position along its normal: where the body is
        // unsure of itself, it is unsure of the wall by as much, and no more.
        let position_variance = before[(POS, POS)];
        let with_position = filter.map.cross_block(index)[(POS, 2)];
        assert!((with_position / position_variance - 1.0).abs() < 1e-9);
        let own = filter.surface_sigmas(id).unwrap().z.powi(2) - position_variance;
        assert!(own > 0.0 && own < 1e-5, "{own}");
        assert!((filter.surfaces()[index].distance - 5.0).abs() < 1e-9);
    }

    #[test]
    fn lines_off_one_plane_place_nothing() {
        let mut filter = still_filter();
        let lines = [
            wall_line(5.0, 0.4),
            wall_line(5.3, -0.4),
            wall_line(5.0, 0.0),
        ];
        let placed = filter
            .add_surface(&wall(5.0), &lines, 0.0, &ALLOWANCE)
            .unwrap();
        assert_eq!(placed, None);
        assert!(filter.surfaces().is_empty());
    }

    #[test]
    fn a_line_seen_again_measures_the_motion_along_the_wall_and_nothing_across_it() {
        let mut filter = still_filter();
        let id = placed_wall(&mut filter);
        let still = Stationary {
            q: UnitQuaternion::identity(),
        };
        for sample in still.imu_samples(0.0, 1.0, 100.0, false) {
            filter.push_imu(&sample);
        }
        let t = filter.time().unwrap();
        let before = filter.covariance;
        // The wall 4 mm nearer: the body crept towards it.
        let seen = LineOnSurface {
            line: wall_line(4.996, 0.0),
            surface: id,
        };
        let report = filter
            .update_map_lines(&[seen], t, &ALLOWANCE, &[])
            .unwrap();
        assert!(report.accepted, "{report:?}");
        let after = filter.covariance;
        assert!(after[(POS, POS)] < 0.5 * before[(POS, POS)]);
        assert!(after[(VEL, VEL)] < before[(VEL, VEL)]);
        assert!(filter.state.p.x > 0.002, "{}", filter.state.p);
        for across in [1, 2] {
            let kept = after[(POS + across, POS + across)] / before[(POS + across, POS + across)];
            assert!(kept > 0.99, "axis {across}: {kept}");
        }
    }
}
