//! Plane matching: each plane of epoch j is predicted into epoch i's body frame with the prior
//! relative pose and paired one-to-one with the epoch-i plane it fits best, within a
//! chi-square gate on the normal (2 degrees of freedom) and the distance (1) together, and a
//! tighter one on the normal alone. The normal is predicted with the gyro's rotation, nearly
//! exact, so its gate is a real test that keeps a turning door out; the distance is predicted
//! with the filter's velocity, which is off exactly when the filter is wrong, so the gate on it
//! stays wide (`OdometryConfig::match_gate_chi2`).

use super::planes::Plane;
use super::{tangent_basis, RelativePose};
use nalgebra::{Matrix2, Vector2};

/// A plane of epoch i (`previous`) paired with a plane of epoch j (`current`), by index into
/// each epoch's plane list.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneMatch {
    pub previous: usize,
    pub current: usize,
    /// Squared Mahalanobis distance of the pair under the prior (3 degrees of freedom).
    pub distance_squared: f64,
}

/// Reusable buffers for the assignment.
#[derive(Debug, Default)]
pub(crate) struct Matcher {
    candidates: Vec<PlaneMatch>,
    taken: [Vec<bool>; 2],
}

impl Matcher {
    /// Fills `out` (cleared first) with one-to-one matches, cheapest first, sorted by `previous`.
    pub(crate) fn match_planes(
        &mut self,
        previous: &[Plane],
        current: &[Plane],
        prior: &RelativePose,
        gates: &MatchGates,
        out: &mut Vec<PlaneMatch>,
    ) {
        out.clear();
        self.candidates.clear();
        for (i, plane_i) in previous.iter().enumerate() {
            for (j, plane_j) in current.iter().enumerate() {
                let Some(terms) = mahalanobis_terms(plane_i, plane_j, prior) else {
                    continue;
                };
                if gates.admit(&terms) {
                    self.candidates.push(PlaneMatch {
                        previous: i,
                        current: j,
                        distance_squared: terms.normal + terms.distance,
                    });
                }
            }
        }
        self.candidates
            .sort_unstable_by(|a, b| a.distance_squared.total_cmp(&b.distance_squared));
        self.taken[0].clear();
        self.taken[0].resize(previous.len(), false);
        self.taken[1].clear();
        self.taken[1].resize(current.len(), false);
        for candidate in &self.candidates {
            if self.taken[0][candidate.previous] || self.taken[1][candidate.current] {
                continue;
            }
            self.taken[0][candidate.previous] = true;
            self.taken[1][candidate.current] = true;
            out.push(*candidate);
        }
        out.sort_unstable_by_key(|m| m.previous);
    }
}

/// Chi-square gates of a match: on the normal and distance together (3 degrees of freedom) and
/// on the normal alone (2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct MatchGates {
    pub total_chi2: f64,
    pub normal_chi2: f64,
}

impl MatchGates {
    /// Whether a pair with these terms passes both gates.
    pub(crate) fn admit(&self, terms: &MahalanobisTerms) -> bool {
        terms.normal <= self.normal_chi2 && terms.normal + terms.distance <= self.total_chi2
    }
}

/// Whether some plane of `previous` (epoch i) passes `gates` with `plane` (of epoch j) under
/// `prior`, whatever else it matches: the one-to-one assignment is for solving, and a surface
/// seen as two planes at j is still one surface at i.
pub(crate) fn has_counterpart(
    previous: &[Plane],
    plane: &Plane,
    prior: &RelativePose,
    gates: &MatchGates,
) -> bool {
    previous.iter().any(|plane_i| {
        mahalanobis_terms(plane_i, plane, prior).is_some_and(|terms| gates.admit(&terms))
    })
}

/// The normal's (2 degrees of freedom) and the distance's (1) share of the squared Mahalanobis
/// distance between plane i and plane j predicted into frame i.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct MahalanobisTerms {
    pub normal: f64,
    pub distance: f64,
}

/// The squared Mahalanobis terms of plane j predicted into frame i, or None if they face
/// opposite ways.
pub(crate) fn mahalanobis_terms(
    plane_i: &Plane,
    plane_j: &Plane,
    prior: &RelativePose,
) -> Option<MahalanobisTerms> {
    let n_i = plane_i.normal;
    let predicted = prior.rotation * plane_j.normal;
    if n_i.dot(&predicted) <= 0.0 {
        return None;
    }
    let basis = tangent_basis(&n_i);
    let rotated_j = prior.rotation.to_rotation_matrix();
    let skew = predicted.cross_matrix();
    let normal_covariance = plane_i.uncertainty.normal_covariance
        + rotated_j * plane_j.uncertainty.normal_covariance * rotated_j.transpose()
        + skew * prior.rotation_covariance * skew.transpose();
    let tangent_covariance: Matrix2<f64> = basis.transpose() * normal_covariance * basis;
    let normal_residual: Vector2<f64> = basis.transpose() * (n_i - predicted);
    let normal_term = normal_residual.dot(&(tangent_covariance.try_inverse()? * normal_residual));

    let dr = prior.translation;
    let rho_residual = plane_i.rho - plane_j.rho - n_i.dot(&dr);
    let rho_variance = plane_i.uncertainty.sigma_rho.powi(2)
        + plane_j.uncertainty.sigma_rho.powi(2)
        + n_i.dot(&(prior.translation_covariance * n_i))
        + dr.dot(&(plane_i.uncertainty.normal_covariance * dr));
    Some(MahalanobisTerms {
        normal: normal_term,
        distance: rho_residual.powi(2) / rho_variance,
    })
}
