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
#[derive(Debug, Clone, Default)]
pub(crate) struct Matcher {
    candidates: Vec<PlaneMatch>,
    /// Pairs that fit the distance and face the same way but that the normal gate refused.
    rivals: Vec<PlaneMatch>,
    taken: [Vec<bool>; 2],
    /// Which matches of the assignment are in doubt (`is_ambiguous`).
    doubtful: Vec<bool>,
    /// The matches of the assignment left in no doubt.
    certain: Vec<PlaneMatch>,
}

impl Matcher {
    /// Fills `out` (cleared first) with one-to-one matches, cheapest first, sorted by `previous`.
    /// Where the prior lets a plane pair with two different surfaces, the cheapest is a guess:
    /// under the prior of a start in motion (velocity known to 0.6 m/s) a box top was paired
    /// with another one 8 cm higher, and the solve measured the swap as motion
    /// (`random-room-13`: 7.6 cm of vertical displacement where there was 1 cm, at a sigma of
    /// 1 cm), which taught the filter a vertical velocity 1.3 m/s off that it then sent with a
    /// sigma of 1 cm/s. So the matches left in no doubt refine the prior and the planes are
    /// paired again under it; a match still in doubt is kept only if another surface facing
    /// the same way corroborates it (`is_corroborated`), and left out otherwise. Doubt is
    /// judged under `doubt_prior`, as wide as `prior` or wider where `prior` is only a doubtful
    /// plane's word (`fusion::witnesses`): the planes are paired as `prior` pairs them, but a
    /// pairing a vaguer prior would have let either plane make with another surface is in
    /// doubt.
    pub(crate) fn match_planes(
        &mut self,
        previous: &[Plane],
        current: &[Plane],
        [prior, doubt_prior]: [&RelativePose; 2],
        gates: &MatchGates,
        out: &mut Vec<PlaneMatch>,
    ) {
        let wider = (doubt_prior != prior).then_some(doubt_prior);
        self.assign(previous, current, prior, gates, out);
        if self.mark_doubtful(previous, current, wider, gates, out) {
            self.certain.clear();
            self.certain.extend(
                out.iter()
                    .zip(&self.doubtful)
                    .filter(|(_, doubtful)| !**doubtful)
                    .map(|(m, _)| *m),
            );
            let certain = &self.certain;
            if let Some(refined) = refined_prior(prior, previous, current, certain.iter()) {
                let refined_doubt =
                    wider.and_then(|p| refined_prior(p, previous, current, certain.iter()));
                self.assign(previous, current, &refined, gates, out);
                self.mark_doubtful(previous, current, refined_doubt.as_ref(), gates, out);
            }
            for (m, doubtful) in out.iter().zip(self.doubtful.iter_mut()) {
                *doubtful = *doubtful && !is_corroborated(m, out, previous, current);
            }
            let mut doubtful = self.doubtful.iter();
            out.retain(|_| !doubtful.next().copied().unwrap_or(false));
        }
        out.sort_unstable_by_key(|m| m.previous);
    }

    /// One-to-one matches under `prior`, cheapest first.
    fn assign(
        &mut self,
        previous: &[Plane],
        current: &[Plane],
        prior: &RelativePose,
        gates: &MatchGates,
        out: &mut Vec<PlaneMatch>,
    ) {
        out.clear();
        self.collect(previous, current, prior, gates);
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
    }

    /// The pairs `prior` admits (`candidates`), and those that fit the distance and face the
    /// same way but that the normal gate refused (`rivals`).
    fn collect(
        &mut self,
        previous: &[Plane],
        current: &[Plane],
        prior: &RelativePose,
        gates: &MatchGates,
    ) {
        self.candidates.clear();
        self.rivals.clear();
        for (i, plane_i) in previous.iter().enumerate() {
            for (j, plane_j) in current.iter().enumerate() {
                let Some(terms) = mahalanobis_terms(plane_i, plane_j, prior) else {
                    continue;
                };
                let pair = PlaneMatch {
                    previous: i,
                    current: j,
                    distance_squared: terms.normal + terms.distance,
                };
                if gates.admit(&terms) {
                    self.candidates.push(pair);
                } else if terms.distance <= gates.total_chi2
                    && plane_i.normal.dot(&(prior.rotation * plane_j.normal))
                        >= ONE_SURFACE_RAD.cos()
                {
                    self.rivals.push(pair);
                }
            }
        }
    }

    /// Marks which of `matches` are in doubt under the pairs their prior admitted, or under
    /// those a `wider` prior admits; returns whether any is.
    fn mark_doubtful(
        &mut self,
        previous: &[Plane],
        current: &[Plane],
        wider: Option<&RelativePose>,
        gates: &MatchGates,
        matches: &[PlaneMatch],
    ) -> bool {
        if let Some(prior) = wider {
            self.collect(previous, current, prior, gates);
        }
        let (candidates, rivals) = (&self.candidates, &self.rivals);
        self.doubtful.clear();
        self.doubtful.extend(matches.iter().map(|m| {
            is_ambiguous(m, candidates, previous, current)
                || is_ambiguous(m, rivals, previous, current)
        }));
        self.doubtful.contains(&true)
    }
}

/// Whether the prior also let either plane of `chosen` pair (`candidates`, the gated pairs)
/// with another plane that is a different surface: a surface that one epoch sees as two planes
/// (a wall split by a door) is one (`is_one_surface`).
fn is_ambiguous(
    chosen: &PlaneMatch,
    candidates: &[PlaneMatch],
    previous: &[Plane],
    current: &[Plane],
) -> bool {
    candidates.iter().any(|other| {
        (other.previous == chosen.previous
            && !is_one_surface(&current[other.current], &current[chosen.current]))
            || (other.current == chosen.current
                && !is_one_surface(&previous[other.previous], &previous[chosen.previous]))
    })
}

/// Whether another match, of a different surface facing the same way, moved it by the same
/// distance: two surfaces swapped would move by different ones. A hallway's wall and a cabinet
/// face 0.6 m in front of it are each ambiguous under the prior of a start in motion, but
/// together they leave no doubt; a lone box top beside another one 8 cm higher does.
fn is_corroborated(
    chosen: &PlaneMatch,
    matches: &[PlaneMatch],
    previous: &[Plane],
    current: &[Plane],
) -> bool {
    let plane = &previous[chosen.previous];
    let (moved, variance) = distance_change(chosen, previous, current);
    matches.iter().any(|other| {
        let other_plane = &previous[other.previous];
        let (other_moved, other_variance) = distance_change(other, previous, current);
        faces_the_same_way(other_plane, plane)
            && !is_one_surface(other_plane, plane)
            && (other_moved - moved).abs()
                <= CORROBORATION_SIGMAS * (other_variance + variance).sqrt()
                    + CORROBORATION_MARGIN_M
    })
}

/// `rho_i - rho_j` of a match, the displacement along its normal (eq 1), with its variance.
fn distance_change(m: &PlaneMatch, previous: &[Plane], current: &[Plane]) -> (f64, f64) {
    let (plane_i, plane_j) = (&previous[m.previous], &current[m.current]);
    (
        plane_i.rho - plane_j.rho,
        plane_i.uncertainty.sigma_rho.powi(2) + plane_j.uncertainty.sigma_rho.powi(2),
    )
}

fn faces_the_same_way(a: &Plane, b: &Plane) -> bool {
    a.normal.dot(&b.normal) >= ONE_SURFACE_RAD.cos()
}

/// Two planes of one epoch this close in distance (m) and in direction (rad) may be one surface
/// (a wall split by a door, its unevenness): mistaking one for the other costs the solve less
/// than its planes' own spread. A plane is one surface with itself.
fn is_one_surface(a: &Plane, b: &Plane) -> bool {
    faces_the_same_way(a, b) && (a.rho - b.rho).abs() <= ONE_SURFACE_M
}

/// How closely two surfaces' moves must agree to corroborate each other: within three sigmas
/// of their distances and a centimetre for the turn between the epochs, which moves surfaces at
/// different distances differently.
const CORROBORATION_SIGMAS: f64 = 3.0;
const CORROBORATION_MARGIN_M: f64 = 0.01;

/// The prior's translation updated with the distances of `matches` (`rho_i - rho_j = n_i . dR`,
/// eq 1), in information form; None when nothing is matched or the information is singular.
fn refined_prior<'a>(
    prior: &RelativePose,
    previous: &[Plane],
    current: &[Plane],
    matches: impl Iterator<Item = &'a PlaneMatch>,
) -> Option<RelativePose> {
    let mut information = prior.translation_covariance.try_inverse()?;
    let mut moment = information * prior.translation;
    let mut any = false;
    for m in matches {
        let n = previous[m.previous].normal;
        let (moved, variance) = distance_change(m, previous, current);
        information += n * n.transpose() / variance;
        moment += n * (moved / variance);
        any = true;
    }
    let covariance = information.try_inverse().filter(|_| any)?;
    Some(RelativePose {
        translation: covariance * moment,
        translation_covariance: covariance,
        ..*prior
    })
}

/// How close (m, rad) two planes of one epoch are when they may be one surface
/// (`is_one_surface`).
const ONE_SURFACE_M: f64 = 0.03;
const ONE_SURFACE_RAD: f64 = 0.035;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::odometry::uncertainty::PlaneUncertainty;
    use nalgebra::{Matrix3, Vector3};

    fn plane(normal: Vector3<f64>, rho: f64) -> Plane {
        let sigma_normal = 0.002;
        let sigma_rho = 0.003;
        Plane::through_one_line(
            super::super::planes::LineRef {
                scanner: 0,
                segment: 0,
            },
            normal,
            rho,
            PlaneUncertainty {
                normal_covariance: (Matrix3::identity() - normal * normal.transpose())
                    * (sigma_normal * sigma_normal / 2.0),
                sigma_normal,
                sigma_rho,
            },
            1.0,
        )
    }

    fn matched(previous: &[Plane], current: &[Plane], prior: &RelativePose) -> Vec<PlaneMatch> {
        let gates = MatchGates {
            total_chi2: 30.66,
            normal_chi2: 13.82,
        };
        let mut out = Vec::new();
        Matcher::default().match_planes(previous, current, [prior, prior], &gates, &mut out);
        out
    }

    /// The platform sinks 5 cm; the prior says it rose `-expected_m`, to `sigma_m`.
    fn sinking(expected_m: f64, sigma_m: f64) -> RelativePose {
        RelativePose {
            translation: Vector3::new(0.0, 0.0, expected_m),
            ..RelativePose::stationary(0.001, sigma_m)
        }
    }

    #[test]
    fn a_lone_box_top_that_the_prior_cannot_tell_from_another_is_left_out() {
        let down = Vector3::z();
        let previous = [plane(down, 0.49)];
        // The same box top 5 cm nearer, and another one 3 cm above it.
        let current = [plane(down, 0.44), plane(down, 0.52)];
        assert!(matched(&previous, &current, &sinking(0.01, 0.6)).is_empty());
        // With the motion known to a centimetre there is no doubt.
        let sure = matched(&previous, &current, &sinking(0.05, 0.01));
        let pairs: Vec<(usize, usize)> = sure.iter().map(|m| (m.previous, m.current)).collect();
        assert_eq!(pairs, vec![(0, 0)]);
    }

    #[test]
    fn a_box_top_is_paired_under_the_prior_that_the_floor_refines() {
        let down = Vector3::z();
        // A floor 1.5 m down, that nothing else resembles, places the vertical motion; the
        // prior's guess (3 cm up) alone would pair the box top with the other one.
        let previous = [plane(down, 0.49), plane(down, 1.5)];
        let current = [plane(down, 0.52), plane(down, 0.44), plane(down, 1.45)];
        let matches = matched(&previous, &current, &sinking(-0.03, 0.15));
        let pairs: Vec<(usize, usize)> = matches.iter().map(|m| (m.previous, m.current)).collect();
        assert_eq!(pairs, vec![(0, 1), (1, 2)]);
    }

    /// `random-room-90` started in motion: a table top 0.6 m over the floor, the filter's
    /// vertical known to 0.6 m. The table top comes back with its normal 15 mrad off, which the
    /// normal gate refuses, and the floor, a level line whose normal is the filter's vertical,
    /// passes it: paired with the table, it measured 0.6 m of climb that never happened.
    #[test]
    fn a_surface_the_normal_gate_refused_still_puts_a_match_in_doubt() {
        let down = Vector3::z();
        let previous = [plane(down, 0.78)];
        let tilted = (down + Vector3::x() * 0.015).normalize();
        let mut floor = plane(down, 1.39);
        floor.uncertainty.normal_covariance = Matrix3::identity() * 0.02_f64.powi(2);
        let current = [plane(tilted, 0.78), floor];
        assert!(matched(&previous, &current, &sinking(0.0, 0.6)).is_empty());
    }

    #[test]
    fn a_wall_and_a_cabinet_face_in_front_of_it_corroborate_each_other() {
        let left = -Vector3::y();
        let previous = [plane(left, 1.08), plane(left, 0.48)];
        let current = [plane(left, 1.11), plane(left, 0.51)];
        let matches = matched(&previous, &current, &RelativePose::stationary(0.001, 0.6));
        let pairs: Vec<(usize, usize)> = matches.iter().map(|m| (m.previous, m.current)).collect();
        assert_eq!(pairs, vec![(0, 0), (1, 1)]);
    }
}
