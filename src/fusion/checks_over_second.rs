//! A lone direction checked over the second its detection speed is given over, where one
//! epoch is too short to tell.
//!
//! At 10 Hz one epoch's check of a lone plane (`witnesses::Check`) cannot see it move at
//! `integrity.lone_plane_detect_mps`: 3 cm in an epoch hides in one epoch's plane noise. A
//! hover's only wall facing along a hallway was `Unchecked` at every epoch while the filter
//! knew the velocity along it to millimetres a second, and a direction learnt from it at a
//! start in motion stayed in doubt until one epoch's check happened to vouch: `hallway-hover`
//! started 94.4 s in became usable only after 34.8 s. Summed over the epochs of the last
//! second, the differences from the prediction show the plane's motion over that second, as
//! the check of one 1 Hz epoch does. The sum is weighed conservatively:
//! - the solves' noise as if independent, though consecutive epochs share a scan's planes and
//!   their noise telescopes;
//! - the predictions' doubts as if one error ran through all of them, as the velocity's does;
//! - and only what the filter leaves of a steady fault: fusing each epoch, it takes a share
//!   `predicted / (predicted + solved)` of it into every later prediction, so a fault must show
//!   with what is left.
//!
//! At 1 Hz the second is one epoch, and this check is never looser than the epoch's own.
//!
//! Only the plane map's odometer sums the second (`Fusion::solve_and_fuse`); the map measures
//! the sideways velocity honestly and takes over once nothing is held in doubt. The pairs at
//! 10 Hz claim too small a sideways sigma in the hallway's hover (the door's slow swing ends
//! bias the cross-track displacement, docs/accuracy.md), and starts of `hallway-flight` in its
//! hover that the second made usable sent sideways errors of 3 mm/s at sigmas of 1 mm/s: 0.93
//! of their usable messages inside 3 sigma sideways, where on the pairs they stay in doubt.

use std::collections::VecDeque;

use nalgebra::{UnitQuaternion, Vector3};

use super::witnesses::{Check, CheckedLone, Evidence, LoneCheck, CHECK_BASELINE_S, SAME_DIRECTION};
use crate::integrity::Thresholds;

/// The share of a steady fault the sum must keep for its test to stand: with less, the
/// filter has learnt the direction from the plane within the second, and the prediction
/// is the plane's word.
const MIN_RETAINED: f64 = 0.5;

/// The recent checks of each lone direction of the rotation and of the displacement, one per
/// epoch without a gap.
#[derive(Debug, Clone, Default)]
pub(super) struct ChecksOverSecond {
    rotation: Vec<Track>,
    displacement: Vec<Track>,
}

/// A lone direction (navigation axes) and its checks at consecutive epochs, back to a second.
#[derive(Debug, Clone)]
struct Track {
    direction: Vector3<f64>,
    epochs: VecDeque<Epoch>,
}

#[derive(Debug, Clone, Copy)]
struct Epoch {
    t_previous: f64,
    t: f64,
    /// Signed along the track's direction.
    evidence: Evidence,
}

impl ChecksOverSecond {
    /// Adds the checks of the epoch from `t_previous` to `t` (`to_navigation` turns its body-i
    /// axes into navigation axes) and makes `ConfirmedOverSecond` each one that could not tell
    /// alone but the last second's epochs, summed, can. A direction missing from an epoch or
    /// contradicted starts again.
    pub(super) fn review(
        &mut self,
        lone: &mut CheckedLone,
        to_navigation: &UnitQuaternion<f64>,
        interval: [f64; 2],
        thresholds: &Thresholds,
    ) {
        review_solve(
            &mut self.rotation,
            &mut lone.rotation,
            to_navigation,
            interval,
            thresholds,
        );
        review_solve(
            &mut self.displacement,
            &mut lone.displacement,
            to_navigation,
            interval,
            thresholds,
        );
    }

    pub(super) fn clear(&mut self) {
        self.rotation.clear();
        self.displacement.clear();
    }
}

fn review_solve(
    tracks: &mut Vec<Track>,
    checks: &mut [LoneCheck],
    to_navigation: &UnitQuaternion<f64>,
    [t_previous, t]: [f64; 2],
    thresholds: &Thresholds,
) {
    let half_epoch = (t - t_previous) / 2.0;
    let mut continued = Vec::with_capacity(checks.len());
    for lone in checks.iter_mut() {
        let navigation = to_navigation * lone.direction;
        let mut track = match tracks
            .iter()
            .position(|track| track.continues(&navigation, t_previous))
        {
            Some(k) => tracks.swap_remove(k),
            None => Track {
                direction: navigation,
                epochs: VecDeque::new(),
            },
        };
        if lone.check == Check::Contradicted {
            continue;
        }
        let mut evidence = lone.evidence;
        evidence.difference *= navigation.dot(&track.direction).signum();
        track.epochs.push_back(Epoch {
            t_previous,
            t,
            evidence,
        });
        let oldest = t - CHECK_BASELINE_S - half_epoch;
        while track.epochs.front().is_some_and(|e| e.t_previous < oldest) {
            track.epochs.pop_front();
        }
        let spans_second = track
            .epochs
            .front()
            .is_some_and(|e| e.t_previous <= t - CHECK_BASELINE_S + half_epoch);
        let undecided = matches!(lone.check, Check::Unchecked | Check::Taught);
        if undecided
            && spans_second
            && confirms(track.epochs.iter().map(|e| &e.evidence), thresholds)
        {
            lone.check = Check::ConfirmedOverSecond;
        }
        continued.push(track);
    }
    *tracks = continued;
}

impl Track {
    fn continues(&self, navigation: &Vector3<f64>, t_previous: f64) -> bool {
        self.direction.dot(navigation).abs() > SAME_DIRECTION
            && self
                .epochs
                .back()
                .is_some_and(|last| (last.t - t_previous).abs() < 1e-9)
    }
}

/// Whether the epochs' checks, summed, agree with the prediction and would have seen the
/// plane move at the detection speed over their span.
fn confirms<'a>(epochs: impl Iterator<Item = &'a Evidence>, thresholds: &Thresholds) -> bool {
    let sum = epochs.fold(Summed::default(), |sum, e| Summed {
        difference: sum.difference + e.difference,
        solved: sum.solved + e.solved,
        predicted_sigma: sum.predicted_sigma + e.predicted.sqrt(),
        absorbed: sum.absorbed + e.predicted / (e.predicted + e.solved).max(f64::MIN_POSITIVE),
        max_mdb: sum.max_mdb + e.max_mdb,
    });
    let retained = 1.0 - sum.absorbed;
    let over_second = Evidence {
        difference: sum.difference,
        predicted: sum.predicted_sigma.powi(2),
        solved: sum.solved,
        max_mdb: retained * sum.max_mdb,
    };
    retained >= MIN_RETAINED
        && over_second.agrees(thresholds)
        && over_second.would_see_the_plane_move(thresholds)
}

/// A second of checks summed: the differences, the solves' variances, the predictions' sigmas,
/// the shares of a steady fault the filter took into later predictions, and the MDBs allowed.
#[derive(Default)]
struct Summed {
    difference: f64,
    solved: f64,
    predicted_sigma: f64,
    absorbed: f64,
    max_mdb: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    const INTERVAL_S: f64 = 0.1;

    /// A hover's only wall along a hallway at 10 Hz: each epoch's plane known to 8 mm, the
    /// prediction to 0.2 mm (the velocity to 2 mm/s), the plane allowed 3 cm an epoch.
    fn wall(difference: f64) -> Evidence {
        Evidence {
            difference,
            predicted: 0.0002f64.powi(2),
            solved: 0.008f64.powi(2),
            max_mdb: 0.3 * INTERVAL_S,
        }
    }

    fn epoch(check: Check, evidence: Evidence) -> CheckedLone {
        CheckedLone {
            rotation: Vec::new(),
            displacement: vec![LoneCheck {
                direction: Vector3::x(),
                check,
                evidence,
            }],
            ..CheckedLone::default()
        }
    }

    /// Reviews `epochs` one every `INTERVAL_S` from `from_s`; returns each one's check after.
    fn review_all(
        checks: &mut ChecksOverSecond,
        epochs: impl IntoIterator<Item = (Check, Evidence)>,
        from_s: f64,
    ) -> Vec<Check> {
        let thresholds = Thresholds::new(1e-3, 1e-3);
        let level = UnitQuaternion::identity();
        epochs
            .into_iter()
            .enumerate()
            .map(|(k, (check, evidence))| {
                let t = from_s + k as f64 * INTERVAL_S;
                let mut lone = epoch(check, evidence);
                checks.review(&mut lone, &level, [t, t + INTERVAL_S], &thresholds);
                lone.displacement[0].check
            })
            .collect()
    }

    /// The plane's noise alternating by 5 mm about a still wall.
    fn still_wall(epochs: usize) -> Vec<(Check, Evidence)> {
        (0..epochs)
            .map(|k| {
                (
                    Check::Unchecked,
                    wall(if k % 2 == 0 { 0.005 } else { -0.005 }),
                )
            })
            .collect()
    }

    #[test]
    fn a_second_of_epochs_confirms_a_still_wall_no_epoch_could() {
        let mut checks = ChecksOverSecond::default();
        let after = review_all(&mut checks, still_wall(12), 0.0);
        assert!(
            after[..9].iter().all(|&c| c == Check::Unchecked),
            "{after:?}"
        );
        assert!(
            after[9..].iter().all(|&c| c == Check::ConfirmedOverSecond),
            "{after:?}"
        );
    }

    #[test]
    fn a_wall_moving_at_the_detection_speed_is_not_confirmed() {
        let mut checks = ChecksOverSecond::default();
        let walker = (0..15).map(|_| (Check::Unchecked, wall(0.3 * INTERVAL_S)));
        let after = review_all(&mut checks, walker, 0.0);
        assert!(after.iter().all(|&c| c == Check::Unchecked), "{after:?}");
    }

    #[test]
    fn a_gap_or_a_contradiction_starts_the_second_again() {
        let mut checks = ChecksOverSecond::default();
        review_all(&mut checks, still_wall(12), 0.0);
        // One epoch missed: the next begins at 1.3 s, not where the last ended (1.2 s).
        let after = review_all(&mut checks, still_wall(12), 1.3);
        assert_eq!(after[8], Check::Unchecked, "{after:?}");
        assert_eq!(after[9], Check::ConfirmedOverSecond, "{after:?}");
        let mut moved = still_wall(12);
        moved[0] = (Check::Contradicted, wall(0.2));
        let after = review_all(&mut checks, moved, 2.5);
        assert_eq!(after[0], Check::Contradicted);
        assert_eq!(after[9], Check::Unchecked, "{after:?}");
        assert_eq!(after[10], Check::ConfirmedOverSecond, "{after:?}");
    }

    #[test]
    fn a_prediction_the_plane_teaches_confirms_nothing() {
        // Known to 2 mm an epoch, the filter takes 6 % of each epoch's difference into the next
        // prediction: over ten, more than half of a steady fault.
        let taught = Evidence {
            predicted: 0.002f64.powi(2),
            ..wall(0.0)
        };
        let mut checks = ChecksOverSecond::default();
        let after = review_all(&mut checks, (0..15).map(|_| (Check::Taught, taught)), 0.0);
        assert!(after.iter().all(|&c| c == Check::Taught), "{after:?}");
    }

    #[test]
    fn at_1_hz_the_second_is_the_epoch_itself() {
        let thresholds = Thresholds::new(1e-3, 1e-3);
        let mut checks = ChecksOverSecond::default();
        // Too vague for the epoch's own check (MDB 0.34 m against 0.3 m), so too for the sum.
        let vague = Evidence {
            difference: 0.01,
            predicted: 0.01f64.powi(2),
            solved: 0.05f64.powi(2),
            max_mdb: 0.3,
        };
        for t in [0.0, 1.0, 2.0, 3.0] {
            let mut lone = epoch(Check::Unchecked, vague);
            checks.review(
                &mut lone,
                &UnitQuaternion::identity(),
                [t, t + 1.0],
                &thresholds,
            );
            assert_eq!(lone.displacement[0].check, Check::Unchecked);
        }
    }
}
