//! Directions of an epoch's solves that a single plane alone observes, and how the filter's
//! prediction stands in as their second witness.
//!
//! The integrity test sees a moving plane only where another plane observes the same
//! direction. Where one plane alone faces a direction, its fault moves the estimate unseen, and
//! the test marks that direction unprotected, so it is not fused. But an under-determined
//! displacement is solved with an anchor along each unobservable direction (`anchor`), and a
//! lone plane a few degrees off square to an anchor shares a sliver of the anchor's direction:
//! the test then counts the plane as redundant, with a minimum detectable bias of metres. In an
//! ordinary room a person walking square on to the platform is such a plane: the only one
//! facing the motion along the room, it told the filter that direction to a centimetre while it
//! walked. So the directions are judged by the planes' geometry alone, as the solves judge what
//! they observe, and a lone plane is taken on trust only if it is a static surface by its size
//! or, in a building, by being level.
//!
//! Any other lone plane is checked by the filter's prediction of the relative pose, which is
//! the IMU's (`Check`): fused every epoch, it knows the along-track motion of a hallway to a
//! centimetre, and a lone cabinet that moved would stand out. A direction the prediction
//! contradicts is not fused. One the prediction cannot check (it has dead-reckoned along it, or
//! the filter has just started in motion and has nothing else to learn the velocity from) is
//! fused, but held `Provisional`: the estimate is not to be used until a later epoch checks
//! that direction against the prediction it now carries, or two planes observe it. One whose
//! plane is far vaguer than the prediction (a floor from two parallel lines, its normal a few
//! mrad off, beside a tilt known to one) needs no check: the filter takes so small a share of
//! it that no fault the test could miss moves the estimate past the prediction's own sigma.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use serde::Serialize;

use super::record::LoneDirection;
use crate::filter::Observability;
use crate::integrity::{IntegrityConfig, SolveKind, Thresholds};
use crate::least_squares::{Solution, PARALLEL_TOLERANCE};
use crate::odometry::matching::PlaneMatch;
use crate::odometry::planes::Building;
use crate::odometry::{EpochPlanes, RelativePose};

/// Directions (body i) that a single used plane alone observes, for the rotation and for the
/// displacement.
#[derive(Debug)]
pub(super) struct LoneWitnesses {
    pub rotation: Vec<Vector3<f64>>,
    pub displacement: Vec<Vector3<f64>>,
}

impl LoneWitnesses {
    /// Of the matches not in `excluded` (indices past `matches` are anchors: not planes),
    /// leaving out the directions of lone planes taken for static: crossing ones with a line of
    /// `min_extent_m` or more, and level crossing ones in a `building`. A static surface
    /// vouches for the displacement along its normal, and for the rotation it alone sees,
    /// only where the match `prior` left no room for another surface facing the same way
    /// (`SURE_MATCH_SIGMA_M`). Under a wider prior the attitude is vague too, and a plane
    /// joining a floor line to a line on a wall far ahead passes for level: its slope changes
    /// as the platform closes on the wall, so its relative pitch is wrong by milliradians at a
    /// sigma of hundredths. Trusted, it taught `random-corridor-29` (started in motion) a
    /// pitch-rate bias 1.6 mrad/s off.
    pub(super) fn of(
        previous: &EpochPlanes,
        matches: &[PlaneMatch],
        excluded: &[usize],
        min_extent_m: f64,
        building: Option<Building>,
        prior: &RelativePose,
    ) -> Self {
        let witnesses: Vec<Witness> = matches
            .iter()
            .enumerate()
            .filter(|(k, _)| !excluded.contains(k))
            .map(|(_, m)| {
                let plane = &previous.planes[m.previous];
                let level = building.is_some_and(|b| b.is_level(&plane.normal));
                let wide = plane.extent_m >= min_extent_m;
                // Only crossing lines show they lie on one surface: two parallel ones may join
                // a wall line to a floor line, long and nearly level as a floor.
                let static_surface = plane.crossing && (level || wide);
                let n = plane.normal;
                let prior_sigma = n.dot(&(prior.translation_covariance * n)).sqrt();
                Witness {
                    normal: n,
                    static_surface,
                    surely_matched: prior_sigma <= SURE_MATCH_SIGMA_M,
                    normal_assumed: plane.normal_assumed,
                }
            })
            .collect();
        Self {
            rotation: lone(&witnesses, rotation_geometry, |w| {
                w.static_surface && w.surely_matched
            }),
            displacement: lone(&witnesses, displacement_geometry, |w| {
                w.static_surface && w.surely_matched
            }),
        }
    }

    /// Checks the lone directions of the solves that integrity cleared against the filter's
    /// prediction `prior` over `interval_s` (a direction of a solve not cleared is not fused
    /// anyway).
    pub(super) fn checked(
        self,
        rotation: Option<&Solution>,
        displacement: Option<&Solution>,
        prior: &RelativePose,
        interval_s: f64,
        thresholds: &Thresholds,
        limits: &IntegrityConfig,
    ) -> CheckedLone {
        let rotation = rotation.map_or_else(Vec::new, |solution| {
            // Both are left perturbations in body-i axes.
            let difference = (UnitQuaternion::from_scaled_axis(solution.x)
                * prior.rotation.inverse())
            .scaled_axis();
            let witness = PriorWitness {
                difference,
                prediction: prior.rotation_covariance,
                solution: solution.covariance,
                max_mdb: limits.lone_plane_detect_mradps * 1e-3 * interval_s,
                epochs_per_baseline: epochs_per_baseline(interval_s),
            };
            witness.check_all(self.rotation, thresholds)
        });
        let displacement = displacement.map_or_else(Vec::new, |solution| {
            let witness = PriorWitness {
                difference: solution.x - prior.translation,
                prediction: prior.translation_covariance,
                solution: solution.covariance,
                max_mdb: limits.lone_plane_detect_mps * interval_s,
                epochs_per_baseline: epochs_per_baseline(interval_s),
            };
            witness.check_all(self.displacement, thresholds)
        });
        CheckedLone {
            rotation,
            displacement,
            speed_covariance: prior.translation_covariance / interval_s.powi(2),
        }
    }
}

/// What the filter's prediction makes of a lone direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Check {
    /// It agrees, and would have seen the plane move at `lone_plane_detect_*`.
    Confirmed,
    /// It agrees over the last second of epochs, summed, and they would have seen the plane
    /// move at `lone_plane_detect_*`, though no one of them could (`checks_over_second`).
    ConfirmedOverSecond,
    /// It agrees, and is so much surer than the plane that no fault the test could miss moves
    /// the estimate by more than the prediction's own sigma: the plane adds little, and cannot
    /// add much that is wrong.
    Outweighed,
    /// It disagrees beyond the test's threshold: the plane moved, or the filter is off.
    Contradicted,
    /// It is too uncertain to tell, though it knows the direction better than the plane's
    /// epochs over a second tell it: at 10 Hz one epoch is too short to see a plane moving at
    /// `lone_plane_detect_*`, and the filter learns little from it.
    Unchecked,
    /// It is too uncertain to tell, and knows the direction less well than the plane's epochs
    /// over a second tell it: what the filter knows of the direction once fused is mostly the
    /// plane's word (`Provisional`).
    Taught,
}

impl Check {
    /// Whether the prediction vouches for the direction.
    fn vouches(self) -> bool {
        matches!(
            self,
            Self::Confirmed | Self::ConfirmedOverSecond | Self::Outweighed
        )
    }
}

/// A lone direction (body i) with the prediction's check of it and what the check weighed.
#[derive(Debug, Clone, Copy)]
pub(super) struct LoneCheck {
    pub direction: Vector3<f64>,
    pub check: Check,
    pub evidence: Evidence,
}

/// What the prediction's check of a lone direction weighed, along the direction.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Evidence {
    /// The solve less the prediction, m or rad.
    pub difference: f64,
    /// The prediction's variance.
    pub predicted: f64,
    /// The solve's variance.
    pub solved: f64,
    /// The largest fault the check may miss for the plane to pass as still.
    pub max_mdb: f64,
}

impl Evidence {
    /// Sigma of the difference: the prediction's and the solve's doubts together.
    fn sigma(&self) -> f64 {
        (self.predicted + self.solved).sqrt()
    }

    /// The smallest fault the check sees with the missed-detection probability.
    fn mdb(&self, thresholds: &Thresholds) -> f64 {
        (thresholds.sole() + thresholds.missed_detection_quantile) * self.sigma()
    }

    /// Whether the solve agrees with the prediction.
    pub(super) fn agrees(&self, thresholds: &Thresholds) -> bool {
        self.difference.abs() <= thresholds.sole() * self.sigma()
    }

    /// Whether the check would have seen the plane move by `max_mdb`.
    pub(super) fn would_see_the_plane_move(&self, thresholds: &Thresholds) -> bool {
        self.mdb(thresholds) <= self.max_mdb
    }
}

/// The lone directions of an epoch, each with the prediction's check.
#[derive(Debug, Default)]
pub(super) struct CheckedLone {
    pub rotation: Vec<LoneCheck>,
    pub displacement: Vec<LoneCheck>,
    /// The prediction's velocity covariance over the epoch (body i), m^2/s^2: what the filter
    /// knew of a direction before a lone plane taught it (`Check::Taught`).
    pub speed_covariance: Matrix3<f64>,
}

impl CheckedLone {
    /// For epochs.jsonl.
    pub(super) fn described(&self) -> Vec<LoneDirection> {
        let of = |solve: SolveKind, directions: &[LoneCheck]| {
            directions
                .iter()
                .map(move |lone| LoneDirection {
                    solve,
                    direction: lone.direction.into(),
                    check: lone.check,
                })
                .collect::<Vec<_>>()
        };
        let mut described = of(SolveKind::Rotation, &self.rotation);
        described.extend(of(SolveKind::Displacement, &self.displacement));
        described
    }

    /// The directions not to fuse: those the prediction contradicts.
    pub(super) fn contradicted(
        directions: &[LoneCheck],
    ) -> impl Iterator<Item = Vector3<f64>> + '_ {
        directions
            .iter()
            .filter(|lone| lone.check == Check::Contradicted)
            .map(|lone| lone.direction)
    }
}

/// A solve's difference from the filter's prediction, with the covariances of both.
struct PriorWitness {
    difference: Vector3<f64>,
    prediction: Matrix3<f64>,
    solution: Matrix3<f64>,
    max_mdb: f64,
    /// How many epochs a steady fault has to pull the estimate before the check's second is
    /// up (`CHECK_BASELINE_S`).
    epochs_per_baseline: f64,
}

/// The time over which a steady fault's pulls add up before the estimate is judged against
/// the prediction again, s: the second the lone-plane detection speeds are given over. At 10 Hz
/// a plane that can pull each epoch by a tenth of the prediction's sigma pulls the estimate by
/// a sigma in that second. Held to the pull of one epoch, random room 54 at 10 Hz released the
/// pitch it held in doubt while its gyro bias was 3 mrad/s off, and sent velocities 2-4 m/s
/// off as usable.
pub(super) const CHECK_BASELINE_S: f64 = 1.0;

pub(super) fn epochs_per_baseline(interval_s: f64) -> f64 {
    (CHECK_BASELINE_S / interval_s).max(1.0)
}

impl PriorWitness {
    fn check_all(&self, directions: Vec<Vector3<f64>>, thresholds: &Thresholds) -> Vec<LoneCheck> {
        directions
            .into_iter()
            .map(|u| {
                let evidence = self.evidence(&u);
                LoneCheck {
                    direction: u,
                    check: self.check(&evidence, thresholds),
                    evidence,
                }
            })
            .collect()
    }

    fn evidence(&self, u: &Vector3<f64>) -> Evidence {
        Evidence {
            difference: u.dot(&self.difference),
            predicted: u.dot(&(self.prediction * u)),
            solved: u.dot(&(self.solution * u)),
            max_mdb: self.max_mdb,
        }
    }

    fn check(&self, evidence: &Evidence, thresholds: &Thresholds) -> Check {
        let predicted = evidence.predicted;
        let sigma = evidence.sigma();
        let mdb = evidence.mdb(thresholds);
        // The filter takes a share predicted / sigma^2 of the difference along u: a fault the
        // test cannot see moves the estimate by at most that share of the MDB, each epoch.
        let pull = mdb * predicted / (sigma * sigma) * self.epochs_per_baseline;
        // A second of the plane's epochs measures the velocity along u with the variance of
        // one epoch's displacement over the epochs in that second.
        let plane_over_baseline = (sigma * sigma - predicted) / self.epochs_per_baseline;
        if !evidence.agrees(thresholds) {
            Check::Contradicted
        } else if evidence.would_see_the_plane_move(thresholds) {
            Check::Confirmed
        } else if pull <= predicted.sqrt() {
            Check::Outweighed
        } else if predicted >= plane_over_baseline {
            Check::Taught
        } else {
            Check::Unchecked
        }
    }
}

/// Directions (navigation axes) the estimate cannot vouch for, for the rotation and the
/// displacement: fused on the word of a lone plane the prediction could not check, or where a
/// lone plane contradicted the prediction. A contradiction means the plane moved or the filter
/// is off, and nothing tells which: in `random-room-35` the far wall, the only plane along the
/// room, was right and the filter's velocity along it was 0.3 m/s off and growing.
#[derive(Debug, Clone, Default)]
pub(super) struct Provisional {
    rotation: Vec<Held>,
    displacement: Vec<Held>,
    /// Held tilt axes (navigation) and since when the displacement fused square to each has
    /// agreed with the filter, s (`vouch_for_tilts`).
    tilt_evidence: Vec<(Vector3<f64>, f64)>,
}

/// A direction (navigation) in doubt, and whether the filter learnt it on the word of the
/// lone plane that put it in doubt.
#[derive(Debug, Clone, Copy)]
struct Held {
    direction: Vector3<f64>,
    learnt_from_it: bool,
    /// The velocity variance along it the filter had before it learnt it, m^2/s^2 (0 when it
    /// did not learn it): how far its prediction along it may be off (`Provisional::widened`).
    taught_speed_variance: f64,
    /// Since when lone planes have agreed with it at every epoch, s.
    agreeing_since: Option<f64>,
}

/// Directions closer than this (cosine, 10 deg) count as one.
pub(super) const SAME_DIRECTION: f64 = 0.985;

impl Provisional {
    /// Whether nothing fused waits for a check.
    pub(super) fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// How many directions wait for a check.
    pub(super) fn len(&self) -> usize {
        self.rotation.len() + self.displacement.len()
    }

    pub(super) fn clear(&mut self) {
        self.rotation.clear();
        self.displacement.clear();
        self.tilt_evidence.clear();
    }

    /// The prior over `interval_s` a pairing of planes is doubted under: as vague along each
    /// held direction the filter learnt from a lone plane as the filter was before it learnt
    /// it (`to_navigation` turns body-i axes into navigation axes). Along such a direction the
    /// prediction is the lone plane's word, and a pairing under it confirms it whatever it
    /// pairs: in `random-corridor-49` started 25.7 s in, the first surface facing along the
    /// corridor was paired with another one 2 m from it and taught the filter a velocity
    /// 2.8 m/s off; then, standing still, the odometer paired each surface facing along the
    /// corridor with another one 2.7 m away, as that velocity predicted, and vouched for it at
    /// every epoch: 1200 messages went out usable 2.7 m/s off. Under the vaguer prior the
    /// surface's pairing with itself is a rival, and the matcher leaves out the pairing in
    /// doubt (`odometry::matching`). The planes are still paired under the prediction: paired
    /// under the vaguer prior they corrected such a velocity, but the filter had learnt its
    /// accelerometer bias from it meanwhile, and the correction ran the vertical velocity of
    /// `random-room-35` started 30.8 s in 0.9 m/s off while usable
    /// (`fusion::tests::a_surprised_update_does_not_release_a_direction_fused_unchecked`).
    pub(super) fn widened(
        &self,
        prior: &RelativePose,
        to_navigation: &UnitQuaternion<f64>,
        interval_s: f64,
    ) -> RelativePose {
        let mut widened = *prior;
        for held in self.displacement.iter().filter(|h| h.learnt_from_it) {
            let u = to_navigation.inverse_transform_vector(&held.direction);
            widened.translation_covariance +=
                u * u.transpose() * (held.taught_speed_variance * interval_s.powi(2));
        }
        widened
    }

    /// After an epoch whose relative pose the filter fused: `checked` its lone directions,
    /// `fused` the body-i directions of each of `[rotation, displacement]` that went in (`None`
    /// for a solve that did not), `to_navigation` turns body-i axes into navigation axes.
    /// `surprised`: the update's NIS was beyond what its degrees of freedom make likely
    /// (`filter::surprises_one_of`), so what it fused does not vouch for what was held. A held
    /// direction was fused unchecked, so if it was wrong the filter has learnt from it: in
    /// `random-room-35` started 30.8 s in, a table top matched to the floor put 0.7 m/s into
    /// the vertical velocity, and when the floor and the ceiling measured the vertical rightly
    /// four epochs later, the update (NIS 11.8 on 3 degrees of freedom) split the surprise
    /// between the velocity and the accelerometer's bias and scale, which then ran the vertical
    /// velocity off at 0.18 m/s^2 with a sigma of 1 cm/s. A surprised update releases nothing;
    /// a later one that agrees does. `t`: the epoch's time, s.
    pub(super) fn after_fusion(
        &mut self,
        checked: &CheckedLone,
        [rotation, displacement]: [Option<Observability>; 2],
        to_navigation: &UnitQuaternion<f64>,
        surprised: bool,
        t: f64,
    ) {
        settle(
            &mut self.rotation,
            (&checked.rotation, &Matrix3::zeros()),
            rotation,
            to_navigation,
            !surprised,
            t,
        );
        settle(
            &mut self.displacement,
            (&checked.displacement, &checked.speed_covariance),
            displacement,
            to_navigation,
            !surprised,
            t,
        );
        let vouching = |w: &Vector3<f64>| {
            !surprised
                && displacement.is_some_and(|o| {
                    o.contains(&to_navigation.inverse_transform_vector(w), SAME_DIRECTION)
                })
        };
        self.vouch_for_tilts(&vouching, t);
    }

    /// A held tilt is also checked by gravity. The paper's rig in a room rarely solves a
    /// rotation about a level axis (the walls' normals are level, and a wall line measures no
    /// rotation), so a tilt one plane alone gave during a start in motion waited for a check
    /// that never came, and the estimate with it: the open room started in motion stayed
    /// unusable for the whole run in starts whose velocity was right to 1 cm/s. But a tilt
    /// `delta` off puts `g delta` of acceleration square to its axis, and a velocity known to
    /// centimetres a second along that direction leaves no room for it within seconds: the
    /// filter learns the tilt from the velocity as any moving INS does, and a wrong one surprises
    /// it. So a held tilt axis is released once every epoch for `TILT_VOUCH_S` has fused,
    /// unsurprised, the displacement square to it (`vouching`), where no held direction of the
    /// displacement is: that evidence must not itself be in doubt. A heading is not released so.
    fn vouch_for_tilts(&mut self, vouching: &dyn Fn(&Vector3<f64>) -> bool, t: f64) {
        let Self {
            rotation,
            displacement,
            tilt_evidence,
        } = self;
        tilt_evidence.retain(|(axis, _)| rotation.iter().any(|held| held.direction == *axis));
        rotation.retain(
            |Held {
                 direction: axis, ..
             }| {
                let square = Vector3::z().cross(axis);
                let agreeing = axis.z.abs() <= MAX_TILT_AXIS_SINE
                    && vouching(&square.normalize())
                    && !displacement.iter().any(|held| {
                        held.direction.dot(&square).abs() > SAME_DIRECTION * square.norm()
                    });
                let known = tilt_evidence.iter().position(|(held, _)| held == axis);
                match (agreeing, known) {
                    (false, Some(k)) => {
                        tilt_evidence.swap_remove(k);
                        true
                    }
                    (false, None) => true,
                    (true, None) => {
                        tilt_evidence.push((*axis, t));
                        true
                    }
                    (true, Some(k)) => {
                        let released = t - tilt_evidence[k].1 >= TILT_VOUCH_S;
                        if released {
                            tilt_evidence.swap_remove(k);
                        }
                        !released
                    }
                }
            },
        );
    }
}

/// A held rotation axis within 30 degrees of level is a tilt (`Provisional::vouch_for_tilts`).
const MAX_TILT_AXIS_SINE: f64 = 0.5;
/// How long the displacement square to a held tilt must agree with the filter before it
/// vouches for the tilt, s: 3 s at 1 cm/s leaves a tilt at most 1 mrad off unseen, and no
/// sooner than the filter's own convergence (`filter.converged_after_epochs` at 1 Hz).
const TILT_VOUCH_S: f64 = 3.0;

/// Adds the unchecked lone directions that went in and the contradicted ones, and, if
/// `releases`, drops the held directions that went in checked at `t`: by two planes or a
/// surface taken for static at once, or by the prediction (`Check`). A direction the filter
/// learnt from a lone plane's word, though, the prediction along it is that plane's own word
/// again, and a glimpse of a mover agrees with it: in `random-corridor-25` started 29 s in, a
/// person walking ahead at the platform's pace was the only plane facing along the corridor for
/// three epochs, the next check found it where the prediction put it, and once released the
/// estimate went out usable 1.2 m/s off for 16 s after the person had left the view. Such a
/// direction is released by the prediction only once lone planes have gone on observing it,
/// uncontradicted and unsurprised, at every epoch for `SELF_VOUCH_S`: a cabinet beside a hover
/// stays in view and still, and a mover that stays in view at the platform's own pace is the
/// one left unseen. An epoch whose check cannot tell (`Unchecked`, `Taught`) continues the
/// count; it does not end it.
fn settle(
    held: &mut Vec<Held>,
    (checked, speed_covariance): (&[LoneCheck], &Matrix3<f64>),
    fused: Option<Observability>,
    to_navigation: &UnitQuaternion<f64>,
    releases: bool,
    t: f64,
) {
    let went_in = |u: &Vector3<f64>| fused.is_some_and(|o| o.contains(u, SAME_DIRECTION));
    held.retain_mut(|h| {
        let body = to_navigation.inverse_transform_vector(&h.direction);
        let witnesses: Vec<Check> = checked
            .iter()
            .filter(|lone| lone.direction.dot(&body).abs() > SAME_DIRECTION)
            .map(|lone| lone.check)
            .collect();
        let vouched = witnesses.iter().all(|check| check.vouches());
        if !releases || !went_in(&body) || witnesses.contains(&Check::Contradicted) {
            h.agreeing_since = None;
            return true;
        }
        if witnesses.is_empty() || !h.learnt_from_it {
            return !vouched;
        }
        let since = *h.agreeing_since.get_or_insert(t);
        !vouched || t - since < SELF_VOUCH_S
    });
    for LoneCheck {
        direction: u,
        check,
        ..
    } in checked
    {
        let navigation = to_navigation * u;
        let in_doubt = match check {
            Check::Unchecked | Check::Taught => went_in(u),
            Check::Contradicted => true,
            Check::Confirmed | Check::ConfirmedOverSecond | Check::Outweighed => false,
        };
        let learnt_from_it = in_doubt && *check == Check::Taught;
        let taught_speed_variance = if learnt_from_it {
            u.dot(&(speed_covariance * u))
        } else {
            0.0
        };
        match held
            .iter_mut()
            .find(|h| h.direction.dot(&navigation).abs() > SAME_DIRECTION)
        {
            Some(known) if learnt_from_it => {
                known.learnt_from_it = true;
                known.taught_speed_variance =
                    known.taught_speed_variance.max(taught_speed_variance);
                known.agreeing_since.get_or_insert(t);
            }
            Some(_) => {}
            None if in_doubt => held.push(Held {
                direction: navigation,
                learnt_from_it,
                taught_speed_variance,
                agreeing_since: learnt_from_it.then_some(t),
            }),
            None => {}
        }
    }
}

/// How long lone planes must go on agreeing with a direction learnt from a lone plane before it
/// is released, s (`settle`): three epochs at 1 Hz, the learning one included. A person
/// glimpsed in two is held; a cabinet seen all along, or a hover's only wall, is released within
/// the 10 s a start in motion has to become usable.
const SELF_VOUCH_S: f64 = 2.0;

/// What a plane tells of a rotation: the turn about any axis but its normal, and nothing when
/// the normal is the filter's own vertical.
fn rotation_geometry(witness: &Witness) -> Matrix3<f64> {
    let n = witness.normal;
    if witness.normal_assumed {
        return Matrix3::zeros();
    }
    Matrix3::identity() - n * n.transpose()
}

/// What a plane tells of a displacement: its component along its normal.
fn displacement_geometry(witness: &Witness) -> Matrix3<f64> {
    witness.normal * witness.normal.transpose()
}

/// A used plane's normal (body i), whether it is taken for a static surface, whether the prior
/// it was matched under was sure along its normal, and whether the normal is the filter's
/// vertical (it then witnesses no rotation).
struct Witness {
    normal: Vector3<f64>,
    static_surface: bool,
    surely_matched: bool,
    normal_assumed: bool,
}

/// The prior's displacement sigma along a static surface's normal (m) up to which its match
/// is sure. Distinct surfaces facing one way in a room stand 0.3 m apart or more (a table top
/// over the floor, a pillar before a wall), and the match gate admits about three sigmas.
/// Under a wider prior, as after a start in motion (0.6 m/s of velocity sigma), a floor seen
/// at one epoch and a table top at the next, each alone, pass the gate as one surface: in
/// `random-room-35` started 30.8 s in the pair measured 0.8 m of vertical displacement at a
/// 4 mm sigma, the filter learnt an accelerometer bias from it, and sent a vertical velocity
/// 1.2 m/s off at a 1.6 cm/s sigma as usable. Such a match must then be checked as any other
/// lone plane is (`Check`).
pub(super) const SURE_MATCH_SIGMA_M: f64 = 0.1;

/// For each plane not taken for static, the directions the others leave unobserved that it
/// observes, judged against the whole geometry (`sum` of `geometry` over the normals) as the
/// solves judge their own.
fn lone(
    witnesses: &[Witness],
    geometry: impl Fn(&Witness) -> Matrix3<f64>,
    trusted: impl Fn(&Witness) -> bool,
) -> Vec<Vector3<f64>> {
    if witnesses.iter().all(&trusted) {
        return Vec::new();
    }
    let each: Vec<Matrix3<f64>> = witnesses.iter().map(&geometry).collect();
    let all: Matrix3<f64> = each.iter().sum();
    let floor = PARALLEL_TOLERANCE * all.symmetric_eigen().eigenvalues.amax();
    let mut directions = Vec::new();
    for (own, _) in each.iter().zip(witnesses).filter(|(_, w)| !trusted(w)) {
        let others = (all - own).symmetric_eigen();
        let unseen: Matrix3<f64> = (0..3)
            .filter(|&i| others.eigenvalues[i] <= floor)
            .map(|i| {
                let u = others.eigenvectors.column(i);
                u * u.transpose()
            })
            .sum();
        // What the plane itself sees of the directions the others leave unseen.
        let seen_alone = (unseen * own * unseen).symmetric_eigen();
        directions.extend(
            (0..3)
                .filter(|&i| seen_alone.eigenvalues[i] > floor)
                .map(|i| seen_alone.eigenvectors.column(i).into_owned()),
        );
    }
    directions
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checked(direction: Vector3<f64>, check: Check) -> LoneCheck {
        LoneCheck {
            direction,
            check,
            evidence: Evidence::default(),
        }
    }

    fn unknown(normals: &[Vector3<f64>]) -> Vec<Witness> {
        normals
            .iter()
            .map(|&normal| Witness {
                normal,
                static_surface: false,
                surely_matched: true,
                normal_assumed: false,
            })
            .collect()
    }

    #[test]
    fn a_plane_alone_facing_a_direction_leaves_it_unprotected() {
        let person = Vector3::new(0.99, 0.0, -0.16).normalize();
        let mut normals = vec![Vector3::y(), -Vector3::y(), Vector3::y(), person];
        let lone_displacement = lone(&unknown(&normals), displacement_geometry, trusted);
        assert_eq!(lone_displacement.len(), 1, "{lone_displacement:?}");
        assert!(lone_displacement[0].dot(&person).abs() > 0.99);
        // A wall behind the person, facing the same way, makes the person testable.
        normals.push(person);
        assert!(lone(&unknown(&normals), displacement_geometry, trusted).is_empty());
    }

    fn trusted(witness: &Witness) -> bool {
        witness.static_surface && witness.surely_matched
    }

    #[test]
    fn a_lone_wall_is_trusted_and_a_lone_person_is_not() {
        let mut witnesses = unknown(&[Vector3::y(), -Vector3::y(), Vector3::x()]);
        witnesses[2].static_surface = true;
        assert!(lone(&witnesses, displacement_geometry, trusted).is_empty());
    }

    #[test]
    fn a_lone_floor_matched_under_a_wide_prior_is_checked_as_any_lone_plane() {
        use crate::odometry::planes::{LineRef, Plane};
        use crate::odometry::uncertainty::PlaneUncertainty;
        let floor = Plane::through_one_line(
            LineRef {
                scanner: 0,
                segment: 0,
            },
            Vector3::z(),
            1.8,
            PlaneUncertainty {
                normal_covariance: Matrix3::zeros(),
                sigma_normal: 0.001,
                sigma_rho: 0.004,
            },
            4.0,
        );
        let previous = EpochPlanes {
            planes: vec![Plane {
                crossing: true,
                ..floor
            }],
            ..EpochPlanes::default()
        };
        let matches = [PlaneMatch {
            previous: 0,
            current: 0,
            distance_squared: 0.0,
        }];
        let building = Some(Building {
            down: Vector3::z(),
            max_tilt_rad: 0.05,
        });
        let lone_floor = |prior_sigma_m: f64| {
            let prior = RelativePose::stationary(0.001, prior_sigma_m);
            LoneWitnesses::of(&previous, &matches, &[], 1.5, building, &prior).displacement
        };
        // Still or converged, nothing else faces the floor's way within the gate.
        assert!(lone_floor(0.01).is_empty());
        // Started in motion, a table top 0.75 m up would pass the gate as the floor.
        let lone = lone_floor(0.6);
        assert_eq!(lone.len(), 1);
        assert!(lone[0].z.abs() > 0.99, "{lone:?}");
    }

    #[test]
    fn a_lone_floor_matched_under_a_wide_prior_is_checked_for_the_pitch_too() {
        use crate::odometry::planes::{LineRef, Plane};
        use crate::odometry::uncertainty::PlaneUncertainty;
        let surface = |normal: Vector3<f64>, rho: f64| Plane {
            crossing: true,
            normal_assumed: false,
            ..Plane::through_one_line(
                LineRef {
                    scanner: 0,
                    segment: 0,
                },
                normal,
                rho,
                PlaneUncertainty {
                    normal_covariance: Matrix3::zeros(),
                    sigma_normal: 0.001,
                    sigma_rho: 0.004,
                },
                3.0,
            )
        };
        let previous = EpochPlanes {
            planes: vec![
                surface(Vector3::y(), 0.8),
                surface(-Vector3::y(), 0.8),
                surface(Vector3::z(), 1.2),
            ],
            ..EpochPlanes::default()
        };
        let matches: Vec<PlaneMatch> = (0..3)
            .map(|k| PlaneMatch {
                previous: k,
                current: k,
                distance_squared: 0.0,
            })
            .collect();
        let building = Some(Building {
            down: Vector3::z(),
            max_tilt_rad: 0.05,
        });
        let lone_rotation = |prior_sigma_m: f64| {
            let prior = RelativePose::stationary(0.001, prior_sigma_m);
            LoneWitnesses::of(&previous, &matches, &[], 1.5, building, &prior).rotation
        };
        assert!(lone_rotation(0.01).is_empty());
        // Started in motion, the one plane that sees the pitch may be a floor line joined to
        // a wall line far ahead, a plane that tilts as the platform closes on the wall.
        let lone = lone_rotation(0.6);
        assert_eq!(lone.len(), 1);
        assert!(lone[0].y.abs() > 0.99, "{lone:?}");
    }

    #[test]
    fn walls_of_one_direction_leave_the_rotation_about_it_to_nobody() {
        // Rotation about y is unobserved by all, so no plane is its lone witness; rotation
        // about x and z is seen by every wall.
        let walls = [Vector3::y(), -Vector3::y()];
        assert!(lone(&unknown(&walls), rotation_geometry, trusted).is_empty());
        let with_floor = [Vector3::y(), -Vector3::y(), Vector3::z()];
        let lone_rotation = lone(&unknown(&with_floor), rotation_geometry, trusted);
        assert_eq!(lone_rotation.len(), 1);
        assert!(lone_rotation[0].y.abs() > 0.99, "{lone_rotation:?}");
    }

    #[test]
    fn the_prediction_checks_a_lone_direction_only_while_it_knows_it() {
        let thresholds = Thresholds::new(1e-3, 1e-3);
        let tight = PriorWitness {
            difference: Vector3::new(0.01, 0.0, 0.0),
            prediction: Matrix3::identity() * 0.007f64.powi(2),
            solution: Matrix3::identity() * 0.007f64.powi(2),
            max_mdb: 0.1,
            epochs_per_baseline: 1.0,
        };
        assert_eq!(
            tight.check(&tight.evidence(&Vector3::x()), &thresholds),
            Check::Confirmed
        );
        // The same plane after the filter dead-reckoned along x: nothing checks it, and fused
        // it teaches the filter the direction.
        let loose = PriorWitness {
            prediction: Matrix3::identity() * 0.2f64.powi(2),
            ..tight
        };
        assert_eq!(
            loose.check(&loose.evidence(&Vector3::x()), &thresholds),
            Check::Taught
        );
        // A tight prediction that disagrees: the plane moved.
        let moved = PriorWitness {
            difference: Vector3::new(0.1, 0.0, 0.0),
            ..tight
        };
        assert_eq!(
            moved.check(&moved.evidence(&Vector3::x()), &thresholds),
            Check::Contradicted
        );
    }

    #[test]
    fn a_plane_far_vaguer_than_the_prediction_cannot_pull_it_off() {
        let thresholds = Thresholds::new(1e-3, 1e-3);
        // Its MDB (0.64 m) is far beyond what the check allows (0.1 m), but the filter takes
        // 0.25 % of it: 1.6 mm, under the prediction's 5 mm.
        let vague = PriorWitness {
            difference: Vector3::new(0.05, 0.0, 0.0),
            prediction: Matrix3::identity() * 0.005f64.powi(2),
            solution: Matrix3::identity() * 0.1f64.powi(2),
            max_mdb: 0.1,
            epochs_per_baseline: 1.0,
        };
        assert_eq!(
            vague.check(&vague.evidence(&Vector3::x()), &thresholds),
            Check::Outweighed
        );
        // At 10 Hz ten such pulls add up within the second: 1.6 cm, over the 5 mm.
        let at_10_hz = PriorWitness {
            epochs_per_baseline: 10.0,
            ..vague
        };
        assert_eq!(
            at_10_hz.check(&at_10_hz.evidence(&Vector3::x()), &thresholds),
            Check::Unchecked
        );
        // With the prediction at 3 cm the filter would take 8 % of a 0.67 m fault: 5.5 cm.
        let surer = PriorWitness {
            prediction: Matrix3::identity() * 0.03f64.powi(2),
            ..vague
        };
        assert_eq!(
            surer.check(&surer.evidence(&Vector3::x()), &thresholds),
            Check::Unchecked
        );
    }

    /// The open room started in motion: a lone plane gave the pitch unchecked, and no rotation
    /// solve about the level axis came after it.
    #[test]
    fn a_held_tilt_is_released_by_seconds_of_velocity_square_to_it() {
        let lone_pitch = CheckedLone {
            rotation: vec![checked(Vector3::y(), Check::Unchecked)],
            displacement: Vec::new(),
            ..CheckedLone::default()
        };
        let level = UnitQuaternion::identity();
        let full = Some(Observability::full());
        let along_x = Some(Observability::from_unobservable(&[
            Vector3::y(),
            Vector3::z(),
        ]));
        let along_y = Some(Observability::from_unobservable(&[
            Vector3::x(),
            Vector3::z(),
        ]));
        let epochs = |held: &mut Provisional, fused, surprised: &[bool], from: f64| {
            for (k, &surprise) in surprised.iter().enumerate() {
                let t = from + k as f64;
                held.after_fusion(&CheckedLone::default(), [None, fused], &level, surprise, t);
            }
        };
        let mut held = Provisional::default();
        held.after_fusion(&lone_pitch, [full, full], &level, false, 0.0);
        assert_eq!(held.len(), 1);
        epochs(&mut held, along_y, &[false; 6], 1.0);
        assert_eq!(
            held.len(),
            1,
            "the velocity along the axis says nothing of the tilt"
        );
        epochs(
            &mut held,
            along_x,
            &[false, false, true, false, false, false],
            7.0,
        );
        assert_eq!(held.len(), 1, "a surprise starts the evidence again");
        epochs(&mut held, along_x, &[false], 13.0);
        assert!(held.is_empty(), "3 s of agreeing velocity square to it");

        let lone_heading = CheckedLone {
            rotation: vec![checked(Vector3::z(), Check::Unchecked)],
            displacement: Vec::new(),
            ..CheckedLone::default()
        };
        let mut held = Provisional::default();
        held.after_fusion(&lone_heading, [full, full], &level, false, 0.0);
        epochs(&mut held, full, &[false; 8], 1.0);
        assert_eq!(held.len(), 1, "gravity vouches for no heading");
    }

    /// `random-corridor-25` started in motion: a person ahead, the only plane along the corridor.
    #[test]
    fn a_direction_learnt_from_a_lone_plane_waits_for_2_s_of_agreement_at_every_epoch() {
        let level = UnitQuaternion::identity();
        let full = Some(Observability::full());
        let along_x_unseen = Some(Observability::from_unobservable(&[Vector3::x()]));
        let lone_x = |check| CheckedLone {
            rotation: Vec::new(),
            displacement: vec![checked(Vector3::x(), check)],
            ..CheckedLone::default()
        };
        let mut held = Provisional::default();
        held.after_fusion(&lone_x(Check::Taught), [None, full], &level, false, 40.0);
        held.after_fusion(&lone_x(Check::Confirmed), [None, full], &level, false, 41.0);
        assert_eq!(held.len(), 1, "its own word an epoch later is a glimpse");
        held.after_fusion(
            &CheckedLone::default(),
            [None, along_x_unseen],
            &level,
            false,
            42.0,
        );
        for t in [43.0, 44.0] {
            held.after_fusion(&lone_x(Check::Confirmed), [None, full], &level, false, t);
        }
        assert_eq!(held.len(), 1, "out of view, the count starts again");
        held.after_fusion(&lone_x(Check::Confirmed), [None, full], &level, false, 45.0);
        assert!(held.is_empty(), "2 s of agreement at every epoch");

        // A plane that contradicted the prediction taught it nothing: its agreement counts.
        held.after_fusion(
            &lone_x(Check::Contradicted),
            [None, full],
            &level,
            false,
            46.0,
        );
        assert_eq!(held.len(), 1);
        held.after_fusion(&lone_x(Check::Confirmed), [None, full], &level, false, 47.0);
        assert!(held.is_empty());
    }

    /// `random-corridor-49` started in motion: a surface facing along the corridor paired with
    /// another taught the filter its velocity along it.
    #[test]
    fn a_pairing_is_doubted_as_vaguely_along_a_taught_direction_as_before_it_was_taught() {
        let level = UnitQuaternion::identity();
        let full = Some(Observability::full());
        let prior = RelativePose {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::new(-2.0, 0.0, 0.0),
            rotation_covariance: Matrix3::identity() * 1e-6,
            translation_covariance: Matrix3::identity() * 0.05f64.powi(2),
        };
        let lone_x = |check| CheckedLone {
            rotation: Vec::new(),
            displacement: vec![checked(Vector3::x(), check)],
            speed_covariance: Matrix3::from_diagonal(&Vector3::new(0.8f64.powi(2), 0.01, 0.01)),
        };
        let mut held = Provisional::default();
        held.after_fusion(&lone_x(Check::Unchecked), [None, full], &level, false, 0.0);
        assert_eq!(held.len(), 1);
        assert_eq!(
            held.widened(&prior, &level, 1.0),
            prior,
            "a direction the filter knew is doubted under its prediction"
        );
        let mut taught = Provisional::default();
        taught.after_fusion(&lone_x(Check::Taught), [None, full], &level, false, 0.0);
        let quarter_turn =
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        let widened = taught.widened(&prior, &quarter_turn, 0.5);
        let added = widened.translation_covariance - prior.translation_covariance;
        // Navigation x is body -y after the body turned a quarter left.
        assert!((added[(1, 1)] - 0.4f64.powi(2)).abs() < 1e-12, "{added}");
        assert!(
            added[(0, 0)].abs() < 1e-12 && added[(2, 2)].abs() < 1e-12,
            "{added}"
        );
        assert_eq!(widened.translation, prior.translation);
        for t in [1.0, 2.0] {
            taught.after_fusion(&lone_x(Check::Confirmed), [None, full], &level, false, t);
        }
        assert!(taught.is_empty());
        assert_eq!(taught.widened(&prior, &level, 1.0), prior, "released");
    }

    #[test]
    fn a_surprised_update_releases_no_held_direction() {
        let floor_wrongly_matched = CheckedLone {
            rotation: Vec::new(),
            displacement: vec![checked(Vector3::z(), Check::Unchecked)],
            ..CheckedLone::default()
        };
        let level = UnitQuaternion::identity();
        let full = Some(Observability::full());
        let mut held = Provisional::default();
        held.after_fusion(&floor_wrongly_matched, [None, full], &level, false, 0.0);
        assert_eq!(held.len(), 1);
        // The floor and the ceiling measure the vertical together, but surprise the filter.
        let two_planes = CheckedLone::default();
        held.after_fusion(&two_planes, [None, full], &level, true, 1.0);
        assert_eq!(held.len(), 1, "a surprise vouches for nothing");
        held.after_fusion(&two_planes, [None, full], &level, false, 2.0);
        assert!(held.is_empty(), "an update that agrees lets go");
    }
}
