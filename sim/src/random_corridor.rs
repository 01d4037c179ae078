//! Corridors drawn from a seed (`random-corridor-N`), so that the odometer is judged on
//! corridors nobody tuned it on: 18-45 m long and 1.4-3.5 m wide, any height and floor
//! clearance, bare or with a few cabinets and pilasters along the walls, perhaps a person
//! walking along them, and a walk of two to four legs down the corridor (now and then back) at
//! 0.1-1 m/s, the body at any angle to its track. Along a corridor only what stands across it
//! measures the motion along it, so these are the scenes where an axis goes unobserved for the
//! longest. Even seeds carry the paper's rig, odd ones the rolled rig of `config/default.toml`.

use super::builtin::{box_room, tidy, walker};
use super::drawn_walk::{body_pitch_deg, DrawnWalk};
use super::scenario::Scenario;
use super::scene::{Motion, Profile, Scene};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The prefix of the built-in name; the seed follows it.
pub(crate) const PREFIX: &str = "random-corridor-";

/// How close the path comes to a side wall, m.
const SIDE_MARGIN_M: f64 = 0.6;
/// How close the path comes to an end wall, m.
const END_MARGIN_M: f64 = 1.2;
/// A person walks along the corridor only where it leaves this much room beside them, m.
const WIDTH_FOR_A_WALKER_M: f64 = 2.2;

/// The corridor's extent in NED: along x from `back` to `end`, across y within `half_width`
/// of the start's line, and the floor and ceiling depths (positive down) with the start at 0.
#[derive(Debug)]
struct Corridor {
    back: f64,
    end: f64,
    half_width: f64,
    floor: f64,
    ceiling: f64,
}

impl Corridor {
    fn draw(rng: &mut ChaCha8Rng) -> Self {
        let length = rng.gen_range(18.0..45.0);
        let half_width = rng.gen_range(0.7..1.75);
        let height: f64 = rng.gen_range(2.4..3.6);
        let floor = rng.gen_range(0.8..(height - 0.6).min(1.8));
        let back = -rng.gen_range(END_MARGIN_M..length / 3.0);
        Self {
            back,
            end: back + length,
            half_width,
            floor,
            ceiling: floor - height,
        }
    }

    fn shell(&self) -> Scene {
        let side = self.half_width;
        Scene {
            patches: box_room(
                [self.back, self.end],
                [-side, side],
                [self.ceiling, self.floor],
            )
            .into(),
        }
    }

    /// Where a wall fixture may stand along the corridor, clear of the end walls.
    fn along(&self, rng: &mut ChaCha8Rng) -> f64 {
        rng.gen_range(self.back + 1.0..self.end - 1.0)
    }
}

/// The corridor, path and rig of `seed`; the same seed gives the same scenario on every
/// machine.
pub(crate) fn random_corridor(seed: u64) -> Scenario {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let corridor = Corridor::draw(&mut rng);
    let path = draw_path(&corridor, &mut rng);
    let mut scene = corridor.shell();
    if !rng.gen_bool(0.25) {
        furnish(&mut scene, &corridor, &mut rng);
    }
    let pitch = body_pitch_deg(&mut rng);
    let yaw = angle_to_track(&path, &mut rng);
    DrawnWalk {
        name: format!("{PREFIX}{seed}"),
        seed,
        scene,
        path,
        rpy_deg: [0.0, pitch, yaw],
        speeds_mps: 0.1..1.0,
    }
    .into_scenario(&mut rng)
}

/// The start's heading: along the first leg in half the corridors, up to 30 degrees off it in
/// most others, and backwards in one in ten (the body keeps the angle as the track turns).
fn angle_to_track(path: &[[f64; 3]], rng: &mut ChaCha8Rng) -> f64 {
    let leg = [path[1][0] - path[0][0], path[1][1] - path[0][1]];
    let track = leg[1].atan2(leg[0]).to_degrees();
    let off = match rng.gen_range(0..10) {
        0..=4 => 0.0,
        5..=8 => rng.gen_range(-30.0..30.0),
        _ => 180.0 + rng.gen_range(-10.0..10.0),
    };
    let heading = track + off;
    if heading > 180.0 {
        heading - 360.0
    } else {
        heading
    }
}

/// The start and two to four waypoints down the corridor, each leg 1.5 m or longer; one leg in
/// five turns back the way it came.
fn draw_path(corridor: &Corridor, rng: &mut ChaCha8Rng) -> Vec<[f64; 3]> {
    let mut path: Vec<[f64; 3]> = vec![[0.0; 3]];
    let legs = rng.gen_range(2..=4);
    let lateral = corridor.half_width - SIDE_MARGIN_M;
    let (nearest, farthest) = (corridor.back + END_MARGIN_M, corridor.end - END_MARGIN_M);
    while path.len() <= legs {
        let last = path[path.len() - 1];
        let x = if rng.gen_bool(0.2) {
            rng.gen_range(nearest..last[0].max(nearest + 0.1))
        } else {
            rng.gen_range(last[0].min(farthest - 0.1)..farthest)
        };
        let y = rng.gen_range(-lateral..lateral);
        if (x - last[0]).hypot(y - last[1]) >= 1.5 {
            path.push(tidy([x, y, rng.gen_range(-0.2..0.2)]));
        }
    }
    path
}

/// Up to three cabinets on the floor against a side wall, up to four pilasters (full-height
/// piers standing out of a wall), and in half the corridors wide enough a person walking to and
/// fro along one wall.
fn furnish(scene: &mut Scene, corridor: &Corridor, rng: &mut ChaCha8Rng) {
    let against_a_wall = |depth: f64, rng: &mut ChaCha8Rng| {
        let side = if rng.gen_bool(0.5) { -1.0 } else { 1.0 };
        side * (corridor.half_width - depth)
    };
    for k in 0..rng.gen_range(0..=3) {
        let half = [rng.gen_range(0.2..0.6), rng.gen_range(0.1..0.3)];
        let half_height = rng.gen_range(0.2..((corridor.floor - 0.2) / 2.0).clamp(0.25, 1.0));
        let x = corridor.along(rng);
        let y = against_a_wall(half[1], rng);
        let centre = tidy([x, y, corridor.floor - half_height]);
        let size = tidy([half[0], half[1], half_height]);
        scene.add_box(&format!("cabinet-{k}"), centre, size, 0.0, Motion::Static);
    }
    let middle = (corridor.floor + corridor.ceiling) / 2.0;
    let half_height = (corridor.floor - corridor.ceiling) / 2.0;
    for k in 0..rng.gen_range(0..=4) {
        let half = [rng.gen_range(0.1..0.3), rng.gen_range(0.05..0.15)];
        let x = corridor.along(rng);
        let y = against_a_wall(half[1], rng);
        let size = tidy([half[0], half[1], half_height]);
        scene.add_box(
            &format!("pilaster-{k}"),
            tidy([x, y, middle]),
            size,
            0.0,
            Motion::Static,
        );
    }
    if 2.0 * corridor.half_width >= WIDTH_FOR_A_WALKER_M && rng.gen_bool(0.5) {
        let walk = corridor.end - corridor.back - 2.0;
        let y = against_a_wall(0.3, rng);
        scene.patches.push(walker(
            "person",
            [corridor.back + 1.0, y],
            corridor.floor,
            [1.0, 0.0],
            Profile::Swing {
                start_s: rng.gen_range(0.0..20.0),
                period_s: tidy([walk / rng.gen_range(0.4..1.2) * 2.0])[0],
                cycles: 2,
                amplitude: tidy([walk])[0],
            },
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drawn_walk::assert_every_seed_draws_the_same_valid_scene;
    use crate::trajectory::Trajectory;

    #[test]
    fn every_seed_draws_a_valid_corridor_the_same_way_each_time() {
        assert_every_seed_draws_the_same_valid_scene(random_corridor);
    }

    #[test]
    fn the_walk_stays_inside_the_corridor() {
        for seed in 0..200 {
            let scenario = random_corridor(seed);
            let Trajectory::Waypoints { waypoints_m, .. } = &scenario.trajectory else {
                panic!("seed {seed}: not a walk");
            };
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let corridor = Corridor::draw(&mut rng);
            for [x, y, _] in waypoints_m {
                assert!(
                    (corridor.back + END_MARGIN_M..=corridor.end - END_MARGIN_M).contains(x)
                        && y.abs() <= corridor.half_width - SIDE_MARGIN_M,
                    "seed {seed}: waypoint ({x}, {y}) outside {corridor:?}"
                );
            }
        }
    }
}
