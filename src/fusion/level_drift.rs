//! Level planes whose height wanders against the others'. The pitched scanner lays a level line
//! on the face of a low box square to it just as on a floor, and the other scanner's beams pass
//! over both (`odometry::level_lines`), so the face is taken for a level surface. Hovering, the
//! two read the same; moving towards the face by `d`, the line on it climbs by `d` times the
//! tangent of the beams' depression, a centimetre an epoch at a walk. Each epoch that error is
//! below what the parity test can see beside the floor, but it has the same sign epoch after
//! epoch, and the filter averaged it into a vertical velocity 5 mm/s off at a 1 mm/s sigma
//! (random room 58).
//!
//! Between two epochs every level surface's distance changes by the same vertical displacement,
//! so a level plane's change less the mean change of the other level planes matched in the
//! epoch is the plane's own error, whatever the filter knows. The others are those whose change
//! lies near the epoch's median, so that one wrong match does not move every plane's reference.
//! Summed along the plane's matches it stays within the line noise for a floor, a ceiling or a
//! table top (the sum of a plane's changes is its last height less its first, and so is the sum
//! of the others' means while they stay the same planes), and grows with the motion for a face.
//! The sum forgets over ten seconds: the filter's tilt, along which the distances are read,
//! also moves one level plane against another, slowly, while it is being learnt. A plane whose
//! sum leaves the noise is left out of the solves, and of the others' means, from then on, as
//! long as it keeps being matched. With fewer than three level planes the others are no
//! majority to judge by, and nothing is summed.

use crate::odometry::matching::PlaneMatch;
use crate::odometry::planes::{Building, Plane};
use crate::odometry::EpochPlanes;

/// Fewest level planes matched in an epoch for the others to be a majority.
const MIN_LEVEL_PLANES: usize = 3;
/// How far from the median change of the epoch's level planes a plane's own may be for it to
/// judge the others, m: a match between two box tops of different heights would move every
/// other plane's mean by its step.
const AGREE_M: f64 = 0.015;
/// Smallest summed change that condemns a plane, m: a line's centroid of a few dozen beams of
/// a 1-3 cm range noise is good to a few millimetres, and floors are flat to about a
/// centimetre. A plane's changes sum to its last height less its first, so the line noise does
/// not add up from epoch to epoch.
const MIN_WANDER_M: f64 = 0.025;
/// Sigma per epoch of what does add up, m: the others' mean as planes come and go, and a
/// floor's unevenness under a line that moves along it.
const STEP_SIGMA_M: f64 = 0.001;
/// How many sigmas of that random walk a plane's summed change may reach.
const GATE_SIGMAS: f64 = 4.0;
/// How long a plane's past changes count, s: a face climbs steadily while the platform moves
/// towards it, 1-1.5 cm a second at a walk, but the filter's tilt, along which a level plane's
/// distance is read, moves one plane's height against another's by the tilt's change times
/// the lines' horizontal reach, slowly and without end while a start in motion learns its tilt
/// (0.15 cm a second between a floor line ahead and a ceiling line behind in random room 58,
/// 3 cm over 20 s: the floor would have been left out).
const MEMORY_S: f64 = 10.0;

#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Track {
    /// Summed change of the plane's height less the other level planes' mean, the older
    /// changes faded, m.
    wander_m: f64,
    /// Epochs summed, up to as many as the memory holds.
    steps: u32,
    condemned: bool,
}

impl Track {
    /// Adds the change against the others of an epoch `interval_s` after the last, the older
    /// changes fading over `MEMORY_S`.
    fn step(mut self, change_m: f64, interval_s: f64) -> Self {
        self.wander_m = self.wander_m * (-interval_s / MEMORY_S).exp() + change_m;
        let remembered = (2.0 * MEMORY_S / interval_s).ceil() as u32;
        self.steps = (self.steps + 1).min(remembered);
        let walk = GATE_SIGMAS * STEP_SIGMA_M * f64::from(self.steps).sqrt();
        self.condemned |= self.wander_m.abs() > walk.max(MIN_WANDER_M);
        self
    }
}

/// The level planes' tracks, by plane id of the last solved epoch.
#[derive(Debug, Clone, Default)]
pub(super) struct LevelDrift {
    tracks: Vec<Option<Track>>,
}

impl LevelDrift {
    /// Nothing was matched this epoch: no track goes on.
    pub(super) fn forget(&mut self) {
        self.tracks.clear();
    }

    /// Follows the level planes through `matches` (previous -> current) and returns the
    /// indices into `matches` of those whose height has wandered; `buildings` are the two
    /// epochs' (what is level in each), none where the scene is not a building.
    pub(super) fn wandering(
        &mut self,
        previous: &EpochPlanes,
        current: &EpochPlanes,
        matches: &[PlaneMatch],
        buildings: [Option<Building>; 2],
    ) -> Vec<usize> {
        // `max` also turns a NaN interval into none.
        let interval_s = (current.t_ref - previous.t_ref).max(0.0);
        let [Some(before_building), Some(after_building)] = buildings else {
            self.forget();
            return Vec::new();
        };
        let level: Vec<(usize, f64, Track)> = matches
            .iter()
            .enumerate()
            .filter_map(|(k, m)| {
                let before = height(&previous.planes[m.previous], &before_building)?;
                let after = height(&current.planes[m.current], &after_building)?;
                let track = self.tracks.get(m.previous).copied().flatten();
                Some((k, after - before, track.unwrap_or_default()))
            })
            .collect();
        let judging: Vec<f64> = level
            .iter()
            .filter(|(_, _, track)| !track.condemned)
            .map(|&(_, change, _)| change)
            .collect();
        let common = median(&judging);
        let judges =
            |change: f64, track: &Track| !track.condemned && (change - common).abs() <= AGREE_M;
        let (sum, count) = level
            .iter()
            .filter(|(_, change, track)| judges(*change, track))
            .fold((0.0, 0usize), |(sum, count), (_, change, _)| {
                (sum + change, count + 1)
            });
        let mut tracks = vec![None; current.planes.len()];
        let mut wandering = Vec::new();
        for &(k, change, track) in &level {
            // The others' mean: this plane's own change is not among them.
            let (others_sum, others) = if judges(change, &track) {
                (sum - change, count - 1)
            } else {
                (sum, count)
            };
            let track = if others + 1 >= MIN_LEVEL_PLANES {
                track.step(change - others_sum / others as f64, interval_s)
            } else {
                track
            };
            if track.condemned {
                wandering.push(k);
            }
            tracks[matches[k].current] = Some(track);
        }
        self.tracks = tracks;
        wandering
    }
}

/// A level plane's height along the building's vertical, up to the body's own: its distance,
/// signed by the side it lies on. `None` for a plane that is not level.
fn height(plane: &Plane, building: &Building) -> Option<f64> {
    building
        .is_level(&plane.normal)
        .then(|| plane.rho * plane.normal.dot(&building.down).signum())
}

/// The middle value; 0 for none.
fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    match sorted.len() {
        0 => 0.0,
        n if n % 2 == 1 => sorted[n / 2],
        n => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Matrix3;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    use nalgebra::Vector3;

    use super::*;
    use crate::odometry::planes::LineRef;
    use crate::odometry::uncertainty::PlaneUncertainty;

    /// Level planes at `heights` (m below the body, negative above) at `t_ref`, seen through
    /// one line each, with the body's vertical along z.
    fn epoch(t_ref: f64, heights: &[f64]) -> EpochPlanes {
        let planes = heights
            .iter()
            .enumerate()
            .map(|(id, &h)| {
                let mut plane = Plane::through_one_line(
                    LineRef {
                        scanner: 1,
                        segment: id,
                    },
                    Vector3::z() * h.signum(),
                    h.abs(),
                    PlaneUncertainty {
                        normal_covariance: Matrix3::zeros(),
                        sigma_normal: 0.0,
                        sigma_rho: 0.01,
                    },
                    1.0,
                );
                plane.id = id;
                plane
            })
            .collect();
        EpochPlanes {
            t_ref,
            planes,
            down: Some(Vector3::z()),
            ..EpochPlanes::default()
        }
    }

    /// A building whose vertical is the body's z, level within 3 degrees.
    const BUILDING: Option<Building> = Some(Building {
        down: Vector3::new(0.0, 0.0, 1.0),
        max_tilt_rad: 0.052,
    });
    const BUILDINGS: [Option<Building>; 2] = [BUILDING, BUILDING];

    fn in_order(n: usize) -> Vec<PlaneMatch> {
        (0..n)
            .map(|k| PlaneMatch {
                previous: k,
                current: k,
                distance_squared: 0.0,
            })
            .collect()
    }

    /// Runs epochs `interval_s` apart whose level planes are at `heights(k)` in epoch k;
    /// returns how many epochs each plane was left out in.
    fn left_out<const N: usize>(
        epochs: usize,
        interval_s: f64,
        mut heights: impl FnMut(usize) -> [f64; N],
    ) -> [usize; N] {
        let mut drift = LevelDrift::default();
        let mut counts = [0; N];
        let mut previous = epoch(0.0, &heights(0));
        for k in 1..=epochs {
            let current = epoch(k as f64 * interval_s, &heights(k));
            for m in drift.wandering(&previous, &current, &in_order(N), BUILDINGS) {
                counts[m] += 1;
            }
            previous = current;
        }
        counts
    }

    /// A body climbing 2 cm an epoch over a floor (1.8 m down, seen twice), a table top and a
    /// ceiling, and a face whose line climbs `face_step_m` more each epoch, the lines read with
    /// `noise_m` of noise.
    fn room(face_step_m: f64, noise_m: f64) -> impl FnMut(usize) -> [f64; 5] {
        let mut rng = ChaCha8Rng::seed_from_u64(58);
        let noise = Normal::new(0.0, noise_m).unwrap();
        move |k| {
            let climb = 0.02 * k as f64;
            [1.8, 1.8, 0.9, -1.2, 1.0 - face_step_m * k as f64]
                .map(|h| h + climb + noise.sample(&mut rng))
        }
    }

    #[test]
    fn a_face_climbing_a_centimetre_and_a_half_an_epoch_is_left_out_from_the_second() {
        assert_eq!(left_out(10, 1.0, room(0.016, 0.0)), [0, 0, 0, 0, 9]);
    }

    #[test]
    fn level_planes_reading_their_line_noise_are_never_left_out_in_ten_thousand_epochs() {
        assert_eq!(left_out(10_000, 1.0, room(0.0, 0.004)), [0; 5]);
        assert_eq!(left_out(10_000, 0.1, room(0.0, 0.004)), [0; 5]);
    }

    #[test]
    fn the_line_noise_does_not_hide_a_face_for_long() {
        let counts = left_out(20, 1.0, room(0.015, 0.002));
        assert_eq!(counts[..4], [0; 4]);
        assert!(counts[4] >= 16, "{counts:?}");
    }

    #[test]
    fn at_10_hz_a_face_climbing_a_millimetre_and_a_half_an_epoch_is_left_out_within_3_s() {
        let counts = left_out(50, 0.1, room(0.0015, 0.002));
        assert_eq!(counts[..4], [0; 4]);
        assert!(counts[4] >= 20, "{counts:?}");
    }

    #[test]
    fn a_ceiling_moving_as_a_tilt_being_learnt_moves_it_is_kept() {
        // 1.5 mm a second, the most room 58's start in motion showed, and a face's 1 cm.
        let ceiling = |step_m: f64| move |k: usize| [1.8, 1.8, 1.8, -1.2 + step_m * k as f64];
        assert_eq!(left_out(60, 1.0, ceiling(0.0015)), [0; 4]);
        assert_eq!(left_out(600, 0.1, ceiling(0.00015)), [0; 4]);
        assert!(left_out(60, 1.0, ceiling(0.01))[3] > 0);
        assert!(left_out(600, 0.1, ceiling(0.001))[3] > 0);
    }

    #[test]
    fn one_match_between_tops_of_two_heights_moves_no_other_plane() {
        let tops = |k: usize| [1.8, 1.8, if k < 3 { 0.64 } else { 0.58 }, -1.2];
        assert_eq!(left_out(20, 1.0, tops), [0, 0, 18, 0]);
    }

    #[test]
    fn with_two_level_planes_there_is_no_majority_and_none_is_left_out() {
        let face = |k: usize| [1.8, 1.0 - 0.05 * k as f64];
        assert_eq!(left_out(10, 1.0, face), [0, 0]);
    }

    #[test]
    fn a_track_ends_with_its_matches() {
        let mut drift = LevelDrift::default();
        let mut previous = epoch(0.0, &[1.8, 1.8, 0.9, 1.0]);
        for k in 1..=3 {
            let current = epoch(f64::from(k), &[1.8, 1.8, 0.9, 1.0 - 0.03 * f64::from(k)]);
            drift.wandering(&previous, &current, &in_order(4), BUILDINGS);
            previous = current;
        }
        let next = epoch(4.0, &[1.8, 1.8, 0.9, 0.91]);
        assert_eq!(
            drift.wandering(&previous, &next, &in_order(4), BUILDINGS),
            [3]
        );
        drift.forget();
        assert!(drift
            .wandering(&next, &next, &in_order(4), BUILDINGS)
            .is_empty());
    }
}
