//! The noise consecutive relative poses share (`filter::SharedNoise`). An epoch's planes are the
//! current planes of one relative pose and the reference planes of the next, so their fitting
//! errors enter both, with opposite signs. Each fused solve is linear in its rows' noise,
//! `x = G y` with `G = (H^T R^-1 H)^-1 H^T R^-1`, and each row's noise is linear in the two
//! planes' errors: rotation rows `B^T (n_i - C n_j)` (B the tangent basis of `n_i`),
//! displacement rows `rho_i - rho_j`. That gives per plane a first-order map from its normal
//! error and its distance error to the fused measurement, for the epoch on either side; the
//! maps of one epoch's planes in two consecutive relative poses give their cross-covariance.
//! The displacement rows' share of the normal errors (the displacement times a few mrad) is
//! left out, as the small part the two poses do not share.

use nalgebra::{DMatrix, Matrix3, Matrix3x2, UnitQuaternion, Vector3};

use crate::filter::SharedNoise;
use crate::least_squares::Solution;
use crate::odometry::matching::PlaneMatch;
use crate::odometry::planes::Plane;
use crate::odometry::tangent_basis;

/// First-order map from one plane's errors to a fused relative pose, in the filter's
/// conventions: rotation (right perturbation, body axes of the current epoch) from the normal's
/// error (body axes of the plane's epoch), and displacement from the distance error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PlaneNoiseMap {
    /// Index of the plane in its epoch.
    plane: usize,
    rotation: Matrix3<f64>,
    displacement: Vector3<f64>,
}

/// The maps of one fused relative pose, for the planes of its reference and current epochs.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct NoiseMaps {
    pub reference: Vec<PlaneNoiseMap>,
    pub current: Vec<PlaneNoiseMap>,
}

impl NoiseMaps {
    /// The maps of the solves the filter is given (after exclusion), over `matches` between
    /// the `previous` epoch's planes and the current one's.
    pub(crate) fn new(
        rotation: Option<&Solution>,
        displacement: Option<&Solution>,
        matches: &[PlaneMatch],
        previous: &[Plane],
    ) -> Self {
        let mut maps = Self::default();
        if let Some((solution, gain)) = rotation.and_then(|s| Some((s, gain(s)?))) {
            maps.add_rotation(solution, &gain, matches, previous);
        }
        if let Some((solution, gain)) = displacement.and_then(|s| Some((s, gain(s)?))) {
            maps.add_displacement(solution, &gain, matches);
        }
        maps
    }

    fn add_rotation(
        &mut self,
        solution: &Solution,
        gain: &DMatrix<f64>,
        matches: &[PlaneMatch],
        previous: &[Plane],
    ) {
        // The solve's rotation error is a left perturbation in body-i axes; the filter's is a
        // right one in body-j axes: Exp(a) C = C Exp(C^T a).
        let c = UnitQuaternion::from_scaled_axis(solution.x)
            .to_rotation_matrix()
            .into_inner();
        let rows = &solution.system.plane_of_row;
        for (pair, &k) in rows.iter().step_by(2).enumerate() {
            let Some(m) = matches.get(k) else { continue };
            let basis = tangent_basis(&previous[m.previous].normal);
            let columns = Matrix3x2::from_fn(|axis, column| gain[(axis, 2 * pair + column)]);
            let on_reference = c.transpose() * columns * basis.transpose();
            entry(&mut self.reference, m.previous).rotation += on_reference;
            entry(&mut self.current, m.current).rotation -= on_reference * c;
        }
    }

    fn add_displacement(
        &mut self,
        solution: &Solution,
        gain: &DMatrix<f64>,
        matches: &[PlaneMatch],
    ) {
        for (row, &k) in solution.system.plane_of_row.iter().enumerate() {
            // Rows past the matches are the anchors' pseudo-planes: they carry the filter's
            // prior, not a plane's error.
            let Some(m) = matches.get(k) else { continue };
            let on_reference = Vector3::from_fn(|axis, _| gain[(axis, row)]);
            entry(&mut self.reference, m.previous).displacement += on_reference;
            entry(&mut self.current, m.current).displacement -= on_reference;
        }
    }

    /// What this relative pose shares with the previous one, whose maps of the same planes
    /// (then its current ones) are `earlier`, with every covariance scaled by `scale` as the
    /// measurement's own.
    pub(crate) fn shared_noise(
        &self,
        earlier: &[PlaneNoiseMap],
        previous: &[Plane],
        current: &[Plane],
        scale: f64,
    ) -> SharedNoise {
        let mut with_previous = [Matrix3::zeros(); 2];
        for now in &self.reference {
            if let Some(then) = earlier.iter().find(|then| then.plane == now.plane) {
                let [rotation, displacement] = cross(now, then, &previous[now.plane]);
                with_previous[0] += rotation;
                with_previous[1] += displacement;
            }
        }
        let mut own = [Matrix3::zeros(); 2];
        for map in &self.current {
            let [rotation, displacement] = cross(map, map, &current[map.plane]);
            own[0] += rotation;
            own[1] += displacement;
        }
        SharedNoise {
            with_previous: with_previous.map(|m| m * scale),
            current: own.map(|m| m * scale),
        }
    }
}

/// `Cov(a e, b e)` for the errors `e` of `plane`, per block (rotation, displacement).
fn cross(a: &PlaneNoiseMap, b: &PlaneNoiseMap, plane: &Plane) -> [Matrix3<f64>; 2] {
    let normal = plane.uncertainty.normal_covariance;
    let distance = plane.uncertainty.sigma_rho.powi(2);
    [
        a.rotation * normal * b.rotation.transpose(),
        a.displacement * b.displacement.transpose() * distance,
    ]
}

fn entry(maps: &mut Vec<PlaneNoiseMap>, plane: usize) -> &mut PlaneNoiseMap {
    let at = match maps.iter().position(|m| m.plane == plane) {
        Some(at) => at,
        None => {
            maps.push(PlaneNoiseMap {
                plane,
                rotation: Matrix3::zeros(),
                displacement: Vector3::zeros(),
            });
            maps.len() - 1
        }
    };
    &mut maps[at]
}

/// `G = (H^T R^-1 H)^-1 H^T R^-1` of a solved system: how the solution moves with each row.
fn gain(solution: &Solution) -> Option<DMatrix<f64>> {
    let system = &solution.system;
    let r_inv_h = system.r.clone().cholesky()?.solve(&system.h);
    let covariance = DMatrix::from_fn(3, 3, |i, j| solution.covariance[(i, j)]);
    Some(covariance * r_inv_h.transpose())
}
