//! An under-determined displacement still measures its observable directions (three walls and a
//! floor in a long hallway pin down everything but the motion along it). The core refuses to
//! solve it, so each unobservable direction is anchored with a pseudo-plane carrying the
//! filter's prior along it; the solve and the integrity test then run as usual, and the filter
//! fuses only the observable directions, so the anchor itself is never fused.
//!
//! The anchor's information lies only along its unobservable direction, where the planes have
//! none, so the solution's observable part is the planes' alone.
//!
//! How firmly an anchor is held decides whether the solve accepts it (it refuses an anchor that
//! carries less than `PARALLEL_TOLERANCE` of the planes' weight), and so whether the epoch
//! gives the filter anything:
//! - one free direction (a corridor, a hall along its length): always accepted. The two
//!   observed directions are fused epoch after epoch whatever the filter knows along the third;
//!   that stays consistent because the filter's attitude lever leaves out the motion along the
//!   free direction (`filter::relative_pose`).
//! - two free directions (one wall or the floor alone): accepted only while the filter's prior
//!   along them is tight. Fused every epoch, a single wall leaves the open room started in
//!   motion optimistic along its length (mean NEES 6.1 over 20 runs): the pitch-rate bias
//!   that such a start learns from floor planes of parallel lines drives it, and nothing else
//!   observes the pitch (docs/accuracy.md, "Level lines").

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::least_squares::{Solution, SolveError, PARALLEL_TOLERANCE};
use crate::odometry::displacement::solve_displacement;
use crate::odometry::matching::PlaneMatch;
use crate::odometry::planes::{LineRef, Plane};
use crate::odometry::uncertainty::PlaneUncertainty;
use crate::odometry::{EpochPlanes, OdometryEpoch, RelativePose};

/// Largest sigma of the anchor of a sole free direction, m. The free direction is the weakest
/// of the planes' weighted information (`LinearSystem::solve_on_normals`), so the anchor adds
/// information along an eigenvector of it and leaves the observed directions' solution as the
/// planes alone make it, whatever its sigma; its value along its direction is never fused. It
/// is held at least as firmly as all the rows together (`sole_anchor_sigma`), so that
/// `Anchored::refuse_loose_anchors` never refuses it and the two observed directions with it:
/// a fixed 1 cm anchor carries under 1e-3 of the weight of a floor measured to a tenth of a
/// millimetre.
const SOLE_ANCHOR_SIGMA_M: f64 = 0.01;
/// Smallest and largest sigma given to each anchor of two free directions, m: from the prior,
/// so that they are refused once the filter no longer knows the motion along them (above).
const MIN_ANCHOR_SIGMA_M: f64 = 0.01;
const MAX_ANCHOR_SIGMA_M: f64 = 0.1;

/// Largest turn rate (rad/s) across which an unobservable direction is anchored. The anchor
/// holds one direction of body i, but over a sharp turn the motion along the free direction
/// sweeps through the observed ones, and the solve hands the filter the prior's own (possibly
/// wrong) velocity as if the planes had measured it. Seen at the corner of hallway-flight
/// started in motion (60 degrees in an epoch, a 1.8 m/s along-track error of the start): the
/// error stayed while its sigma fell to 0.27 m/s, and the 20 starts sent only 94 % of their
/// valid messages inside 3 sigma. 20 degrees a second is more than the hovers and walks turn.
/// It is a rate, not a turn per epoch: at 10 Hz the corner is 6 degrees an epoch, each epoch
/// anchored, and the same starts sent 2 m/s of along-track error at quality 50-67, 60 sigma off
/// (`anchored_turn_limit`).
const MAX_ANCHORED_TURN_RATE_RADPS: f64 = 0.35;

/// The largest turn across an epoch of `interval_s` that is anchored: the rate's, and never
/// more than a second of it, so that an epoch slower than 1 Hz anchors no more than one at 1 Hz.
fn anchored_turn_limit(interval_s: f64) -> f64 {
    MAX_ANCHORED_TURN_RATE_RADPS * interval_s.abs().min(1.0)
}

/// An epoch's planes and matches with one pseudo-plane per unobservable direction appended.
pub(super) struct Anchored {
    previous: Vec<Plane>,
    current: Vec<Plane>,
    matches: Vec<PlaneMatch>,
    rotation: Option<UnitQuaternion<f64>>,
    prior: Vector3<f64>,
    prior_covariance: Matrix3<f64>,
    /// The matches the epoch left out of its own solves.
    epoch_excluded: Vec<usize>,
    /// Matches from this index on are anchors.
    first_anchor: usize,
    pub unobservable: Vec<Vector3<f64>>,
}

impl Anchored {
    /// `None` unless the displacement was under-determined with at least one observable
    /// direction.
    pub(crate) fn new(
        previous: &EpochPlanes,
        current: &EpochPlanes,
        epoch: &OdometryEpoch,
        prior: &RelativePose,
    ) -> Option<Self> {
        let Err(SolveError::UnderDetermined { unobservable }) = &epoch.displacement else {
            return None;
        };
        if unobservable.is_empty()
            || unobservable.len() >= 3
            || epoch.matches.is_empty()
            || prior.rotation.angle() > anchored_turn_limit(current.t_ref - previous.t_ref)
        {
            return None;
        }
        let rotation = epoch
            .rotation
            .as_ref()
            .ok()
            .map(|solution| UnitQuaternion::from_scaled_axis(solution.x));
        let mut anchored = Self {
            previous: previous.planes.clone(),
            current: current.planes.clone(),
            matches: epoch.matches.clone(),
            rotation,
            prior: prior.translation,
            prior_covariance: prior.translation_covariance,
            epoch_excluded: epoch.excluded.clone(),
            first_anchor: epoch.matches.len(),
            unobservable: Vec::with_capacity(unobservable.len()),
        };
        for direction in unobservable {
            let u = direction.normalize();
            let sigma = match unobservable.len() {
                1 => sole_anchor_sigma(previous, current, &epoch.matches),
                _ => u
                    .dot(&(prior.translation_covariance * u))
                    .sqrt()
                    .clamp(MIN_ANCHOR_SIGMA_M, MAX_ANCHOR_SIGMA_M),
            };
            anchored.push(u, sigma);
        }
        Some(anchored)
    }

    /// A plane pair whose displacement row reads `u . dR = u . prior` with sigma `sigma`.
    fn push(&mut self, u: Vector3<f64>, sigma: f64) {
        let plane = |id: usize, normal: Vector3<f64>, rho: f64, sigma_rho: f64| Plane {
            id,
            normal,
            rho,
            uncertainty: PlaneUncertainty {
                normal_covariance: Matrix3::zeros(),
                sigma_normal: 0.0,
                sigma_rho,
            },
            lines: [LineRef {
                scanner: 0,
                segment: usize::MAX,
            }; 2],
            crossing: false,
            confirmed: false,
            extent_m: 0.0,
            normal_assumed: false,
        };
        // The row's normal is the mean of n_i and C n_j: make both u.
        let current_normal = self.rotation.map_or(u, |c| c.inverse() * u);
        let (i, j) = (self.previous.len(), self.current.len());
        self.previous.push(plane(i, u, u.dot(&self.prior), sigma));
        self.current.push(plane(j, current_normal, 0.0, 0.0));
        self.matches.push(PlaneMatch {
            previous: i,
            current: j,
            distance_squared: 0.0,
        });
        self.unobservable.push(u);
    }

    /// The anchored displacement without the matches in `excluded`.
    pub(crate) fn solve(&self, excluded: &[usize]) -> Result<Solution, SolveError> {
        let mut excluded = excluded.to_vec();
        excluded.extend(&self.epoch_excluded);
        self.refuse_loose_anchors(&excluded)?;
        solve_displacement(
            &self.previous,
            &self.current,
            &self.matches,
            self.rotation.as_ref(),
            &self.prior,
            &self.prior_covariance,
            &excluded,
        )
    }

    /// An anchor held loosely beside planes of a millimetre (two free directions under a vague
    /// prior) would pass a test on the normals and be fused as if the planes had pinned what
    /// it holds: each must carry `PARALLEL_TOLERANCE` of the planes' weight. The planes are
    /// judged on their normals, as the plain solve judges them: a far wall measured to
    /// centimetres beside walls measured to a millimetre observes the motion it faces.
    fn refuse_loose_anchors(&self, excluded: &[usize]) -> Result<(), SolveError> {
        let (planes, anchors) = self.matches.split_at(self.first_anchor);
        let weight = |m: &PlaneMatch| distance_weight(&self.previous, &self.current, m);
        let planes_weight: f64 = planes
            .iter()
            .enumerate()
            .filter(|(k, _)| !excluded.contains(k))
            .map(|(_, m)| weight(m))
            .sum();
        let loose: Vec<Vector3<f64>> = anchors
            .iter()
            .zip(&self.unobservable)
            .filter(|(m, _)| weight(m) < PARALLEL_TOLERANCE * planes_weight)
            .map(|(_, u)| *u)
            .collect();
        if loose.is_empty() {
            Ok(())
        } else {
            Err(SolveError::UnderDetermined {
                unobservable: loose,
            })
        }
    }
}

/// The sigma of a sole anchor: `SOLE_ANCHOR_SIGMA_M`, or that of all the matched planes'
/// distance rows combined where they are firmer.
fn sole_anchor_sigma(previous: &EpochPlanes, current: &EpochPlanes, matches: &[PlaneMatch]) -> f64 {
    let information: f64 = matches
        .iter()
        .map(|m| distance_weight(&previous.planes, &current.planes, m))
        .sum();
    SOLE_ANCHOR_SIGMA_M.min(information.sqrt().recip())
}

/// The weight of a match's distance row, `1 / (sigma_rho_i^2 + sigma_rho_j^2)`.
fn distance_weight(previous: &[Plane], current: &[Plane], m: &PlaneMatch) -> f64 {
    let variance = previous[m.previous].uncertainty.sigma_rho.powi(2)
        + current[m.current].uncertainty.sigma_rho.powi(2);
    variance.max(f64::MIN_POSITIVE).recip()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::Observability;

    const TRUTH: Vector3<f64> = Vector3::new(0.8, 0.05, -0.02);
    const WALLS_AND_FLOOR: [([f64; 3], f64); 3] = [
        ([0.0, 1.0, 0.0], 1.1),
        ([0.0, -1.0, 0.0], 1.1),
        ([0.0, 0.0, 1.0], 1.2),
    ];

    fn plane(id: usize, normal: [f64; 3], rho: f64, sigma_rho: f64) -> Plane {
        Plane {
            id,
            normal: Vector3::from(normal),
            rho,
            uncertainty: PlaneUncertainty {
                normal_covariance: Matrix3::identity() * 1e-8,
                sigma_normal: 1e-4,
                sigma_rho,
            },
            lines: [LineRef {
                scanner: 0,
                segment: 0,
            }; 2],
            crossing: true,
            confirmed: false,
            extent_m: 1.0,
            normal_assumed: false,
        }
    }

    /// Surfaces seen before and after moving by `TRUTH`, under a prior 0.1 m short along x
    /// with isotropic sigma `prior_sigma_m`: the anchored epoch, if the displacement was
    /// under-determined.
    fn anchored(
        surfaces: &[([f64; 3], f64)],
        sigma_rho: f64,
        prior_sigma_m: f64,
    ) -> Option<Anchored> {
        anchored_turning(surfaces, sigma_rho, prior_sigma_m, 0.0, 1.0)
    }

    /// As `anchored`, with a prior that also turns `turn_rad` about the vertical over an epoch
    /// of `interval_s` (the planes themselves are given in the body axes of each epoch,
    /// unturned: only the prior matters).
    fn anchored_turning(
        surfaces: &[([f64; 3], f64)],
        sigma_rho: f64,
        prior_sigma_m: f64,
        turn_rad: f64,
        interval_s: f64,
    ) -> Option<Anchored> {
        let sigmas = vec![sigma_rho; surfaces.len()];
        anchored_with_sigmas(surfaces, &sigmas, prior_sigma_m, turn_rad, interval_s)
    }

    /// As `anchored_turning`, each surface measured to its own sigma.
    fn anchored_with_sigmas(
        surfaces: &[([f64; 3], f64)],
        sigmas: &[f64],
        prior_sigma_m: f64,
        turn_rad: f64,
        interval_s: f64,
    ) -> Option<Anchored> {
        let epoch_planes = |shift: &Vector3<f64>, t_ref: f64| EpochPlanes {
            t_ref,
            planes: surfaces
                .iter()
                .zip(sigmas)
                .enumerate()
                .map(|(k, ((n, rho), sigma))| {
                    plane(k, *n, rho - Vector3::from(*n).dot(shift), *sigma)
                })
                .collect(),
            ..EpochPlanes::default()
        };
        let (previous, current) = (
            epoch_planes(&Vector3::zeros(), 0.0),
            epoch_planes(&TRUTH, interval_s),
        );
        let matches: Vec<PlaneMatch> = (0..surfaces.len())
            .map(|k| PlaneMatch {
                previous: k,
                current: k,
                distance_squared: 0.0,
            })
            .collect();
        let mut prior = RelativePose::stationary(0.01, prior_sigma_m);
        prior.translation = Vector3::new(0.7, 0.0, 0.0);
        prior.rotation = UnitQuaternion::from_scaled_axis(Vector3::z() * turn_rad);
        let displacement = solve_displacement(
            &previous.planes,
            &current.planes,
            &matches,
            None,
            &prior.translation,
            &prior.translation_covariance,
            &[],
        );
        assert!(matches!(
            displacement,
            Err(SolveError::UnderDetermined { .. })
        ));
        let epoch = OdometryEpoch {
            matches,
            prior,
            excluded: Vec::new(),
            rotation: Err(SolveError::BadCovariance),
            displacement,
        };
        Anchored::new(&previous, &current, &epoch, &prior)
    }

    #[test]
    fn a_hallway_displacement_keeps_its_observable_part_and_anchors_the_rest() {
        let anchored = anchored(&WALLS_AND_FLOOR, 0.005, 0.3).unwrap();
        assert_eq!(anchored.unobservable.len(), 1);
        assert!((anchored.unobservable[0].x.abs() - 1.0).abs() < 1e-6);
        let solution = anchored.solve(&[]).unwrap();
        assert!((solution.x.y - TRUTH.y).abs() < 1e-9);
        assert!((solution.x.z - TRUTH.z).abs() < 1e-9);
        // Along the hallway the solution is the prior's, and that direction is not fused.
        assert!((solution.x.x - 0.7).abs() < 1e-9);
        let observability = Observability::from_unobservable(&anchored.unobservable);
        assert_eq!(observability.rank(), 2);
        assert!(observability
            .observable_directions()
            .all(|d| d.x.abs() < 1e-6));
    }

    #[test]
    fn a_sole_free_direction_is_anchored_however_vague_the_prior() {
        let anchored = anchored(&WALLS_AND_FLOOR, 0.001, 5.0).unwrap();
        let solution = anchored.solve(&[]).unwrap();
        assert!((solution.x.y - TRUTH.y).abs() < 1e-9);
        assert!((solution.x.z - TRUTH.z).abs() < 1e-9);
    }

    #[test]
    fn a_sole_anchor_is_accepted_beside_a_floor_measured_to_a_tenth_of_a_millimetre() {
        let anchored = anchored_with_sigmas(&WALLS_AND_FLOOR, &[0.001, 0.001, 1e-4], 0.3, 0.0, 1.0);
        let solution = anchored.unwrap().solve(&[]).unwrap();
        assert!((solution.x.y - TRUTH.y).abs() < 1e-9);
        assert!((solution.x.z - TRUTH.z).abs() < 1e-9);
    }

    /// The paper's rig in an open room: walls to either side measured to a millimetre, the
    /// far wall ahead only to 3 cm (a plumb plane through one level line), no floor. The
    /// vertical is free; the motion ahead is the far wall's to measure.
    #[test]
    fn a_coarse_far_wall_beside_millimetre_walls_still_measures_the_motion_it_faces() {
        let surfaces = [
            WALLS_AND_FLOOR[0],
            WALLS_AND_FLOOR[1],
            ([-1.0, 0.0, 0.0], 2.5),
        ];
        let anchored =
            anchored_with_sigmas(&surfaces, &[0.001, 0.001, 0.03], 0.6, 0.0, 1.0).unwrap();
        assert_eq!(anchored.unobservable.len(), 1);
        assert!(anchored.unobservable[0].z.abs() > 0.999);
        let solution = anchored.solve(&[]).unwrap();
        assert!((solution.x.x - TRUTH.x).abs() < 1e-9);
        assert!((solution.x.y - TRUTH.y).abs() < 1e-9);
    }

    #[test]
    fn two_free_directions_count_only_while_the_prior_along_them_is_tight() {
        let floor = [WALLS_AND_FLOOR[2]];
        let tight = anchored(&floor, 0.001, 0.01).unwrap();
        assert_eq!(tight.unobservable.len(), 2);
        assert!((tight.solve(&[]).unwrap().x.z - TRUTH.z).abs() < 1e-9);
        let vague = anchored(&floor, 0.001, 0.5).unwrap();
        assert!(vague.solve(&[]).is_err());
    }

    #[test]
    fn a_free_direction_is_not_anchored_across_a_sharp_turn() {
        assert!(anchored_turning(&WALLS_AND_FLOOR, 0.005, 0.3, 0.3, 1.0).is_some());
        assert!(anchored_turning(&WALLS_AND_FLOOR, 0.005, 0.3, 0.4, 1.0).is_none());
    }

    #[test]
    fn at_10_hz_a_turn_is_judged_by_its_rate_not_by_each_epoch() {
        // A corner taken at 60 degrees a second: 6 degrees an epoch at 10 Hz.
        assert!(anchored_turning(&WALLS_AND_FLOOR, 0.005, 0.3, 0.105, 0.1).is_none());
        // The hovers' and walks' turns, under 20 degrees a second, stay anchored.
        assert!(anchored_turning(&WALLS_AND_FLOOR, 0.005, 0.3, 0.03, 0.1).is_some());
        // Slower than 1 Hz, an epoch anchors no more of a turn than one at 1 Hz.
        assert!(anchored_turning(&WALLS_AND_FLOOR, 0.005, 0.3, 0.4, 2.0).is_none());
    }
}
