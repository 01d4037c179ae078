//! What the scenes drawn from a seed share (`random_room`, `random_corridor`): a still start,
//! the body pitched down by a drawn angle, a walk through the drawn waypoints at a drawn speed,
//! and the rig by the seed's parity (even seeds the paper's rig, odd ones the rolled rig of
//! `config/default.toml`).

use super::builtin::{gentle_hover, hallway_scanners, paper_rig_scanners, tidy};
use super::imu::ImuConfig;
use super::scenario::Scenario;
use super::scene::Scene;
use super::trajectory::Trajectory;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use std::ops::Range;

/// Still for this long at the start, as the other scenes, so that a still start is possible.
pub(crate) const STILL_S: f64 = 10.0;
const DURATION_S: f64 = 90.0;

/// The body's pitch, deg: the paper's 10 degrees down in half the scenes, 3-15 in the others.
pub(crate) fn body_pitch_deg(rng: &mut ChaCha8Rng) -> f64 {
    if rng.gen_bool(0.5) {
        -10.0
    } else {
        rng.gen_range(-15.0..-3.0)
    }
}

/// A drawn scene and the walk through it; what is left to draw is when the walk starts and
/// its speed, in that order.
pub(crate) struct DrawnWalk {
    pub name: String,
    pub seed: u64,
    pub scene: Scene,
    /// The start (the origin) and the waypoints after it.
    pub path: Vec<[f64; 3]>,
    pub rpy_deg: [f64; 3],
    pub speeds_mps: Range<f64>,
}

impl DrawnWalk {
    pub(crate) fn into_scenario(self, rng: &mut ChaCha8Rng) -> Scenario {
        let scanners = if self.seed.is_multiple_of(2) {
            paper_rig_scanners()
        } else {
            hallway_scanners()
        };
        Scenario {
            name: self.name,
            seed: self.seed,
            duration_s: DURATION_S,
            truth_rate_hz: 50.0,
            trajectory: Trajectory::Waypoints {
                position_m: [0.0; 3],
                rpy_deg: tidy(self.rpy_deg),
                start_s: STILL_S + rng.gen_range(0.0..10.0),
                waypoints_m: self.path[1..].to_vec(),
                speed_mps: tidy([rng.gen_range(self.speeds_mps)])[0],
                blend_s: 4.0,
                oscillation: gentle_hover(STILL_S),
            },
            scanners,
            imu: Some(ImuConfig::default()),
            scene: self.scene,
        }
    }
}

/// Asserts that every seed of `draw` gives a valid scene, the same each time, and that two
/// seeds differ.
#[cfg(test)]
pub(crate) fn assert_every_seed_draws_the_same_valid_scene(draw: fn(u64) -> Scenario) {
    for seed in 0..200 {
        let scenario = draw(seed);
        scenario
            .validate()
            .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
        assert_eq!(scenario, draw(seed), "seed {seed}");
    }
    assert_ne!(draw(1), draw(2));
}
