//! Rooms drawn from a seed (`random-room-N`), so that the odometer is judged on rooms nobody
//! tuned it on: any size from a small office to a hall, the start anywhere in it at any heading
//! to the walls, any floor clearance and body pitch, a few boxes and pillars, perhaps a person
//! walking along a wall, and a walk through two to four random waypoints at a random speed.
//! Half the seeds carry the paper's rig, half the rolled rig of `config/default.toml`.

use super::builtin::{box_room, tidy, walker};
use super::drawn_walk::{body_pitch_deg, DrawnWalk};
use super::scenario::Scenario;
use super::scene::{Motion, Profile, Scene};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The prefix of the built-in name; the seed follows it.
pub(crate) const PREFIX: &str = "random-room-";

/// How close the path comes to a wall, m.
const PATH_MARGIN_M: f64 = 1.2;
/// How close a pillar stands to the path, beyond its own half diagonal, m.
const PILLAR_CLEARANCE_M: f64 = 0.8;

/// The room's extent in NED: x from `back` to `front`, y from `left` to `right`, and the floor
/// and ceiling depths (positive down) with the start at z = 0.
#[derive(Debug)]
struct Room {
    back: f64,
    front: f64,
    left: f64,
    right: f64,
    floor: f64,
    ceiling: f64,
}

impl Room {
    fn draw(rng: &mut ChaCha8Rng) -> Self {
        let length = rng.gen_range(6.0..16.0);
        let width = rng.gen_range(3.0..10.0);
        let height: f64 = rng.gen_range(2.4..4.0);
        let floor = rng.gen_range(0.8..(height - 0.6).min(1.8));
        let back = -rng.gen_range(PATH_MARGIN_M..length - PATH_MARGIN_M);
        let left = -rng.gen_range(PATH_MARGIN_M..width - PATH_MARGIN_M);
        Self {
            back,
            front: back + length,
            left,
            right: left + width,
            floor,
            ceiling: floor - height,
        }
    }

    /// A point of the plane of the start at least `margin` from every wall.
    fn point_within(&self, margin: f64, rng: &mut ChaCha8Rng) -> [f64; 2] {
        [
            rng.gen_range(self.back + margin..self.front - margin),
            rng.gen_range(self.left + margin..self.right - margin),
        ]
    }

    fn shell(&self) -> Scene {
        Scene {
            patches: box_room(
                [self.back, self.front],
                [self.left, self.right],
                [self.ceiling, self.floor],
            )
            .into(),
        }
    }
}

/// The room, path and rig of `seed`; the same seed gives the same scenario on every machine.
pub(crate) fn random_room(seed: u64) -> Scenario {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let room = Room::draw(&mut rng);
    let path = draw_path(&room, &mut rng);
    let mut scene = room.shell();
    furnish(&mut scene, &room, &path, &mut rng);
    let pitch = body_pitch_deg(&mut rng);
    let yaw = rng.gen_range(-180.0..180.0);
    DrawnWalk {
        name: format!("{PREFIX}{seed}"),
        seed,
        scene,
        path,
        rpy_deg: [0.0, pitch, yaw],
        speeds_mps: 0.15..0.8,
    }
    .into_scenario(&mut rng)
}

/// The start and two to four waypoints, each leg 1.5 m or longer, within the path margin.
fn draw_path(room: &Room, rng: &mut ChaCha8Rng) -> Vec<[f64; 3]> {
    let mut path = vec![[0.0; 3]];
    let legs = rng.gen_range(2..=4);
    while path.len() <= legs {
        let [x, y] = room.point_within(PATH_MARGIN_M, rng);
        let last = path[path.len() - 1];
        if (x - last[0]).hypot(y - last[1]) >= 1.5 {
            path.push(tidy([x, y, rng.gen_range(-0.3..0.3)]));
        }
    }
    path
}

/// Up to four boxes on the floor (lower than the path), up to two pillars clear of the path,
/// and in half the rooms a person walking to and fro along a wall.
fn furnish(scene: &mut Scene, room: &Room, path: &[[f64; 3]], rng: &mut ChaCha8Rng) {
    for k in 0..rng.gen_range(0..=4) {
        let half: [f64; 2] = [rng.gen_range(0.15..0.8), rng.gen_range(0.15..0.8)];
        let half_height = rng.gen_range(0.1..(room.floor - 0.4) / 2.0);
        let [x, y] = room.point_within(0.2 + half[0].max(half[1]), rng);
        let centre = tidy([x, y, room.floor - half_height]);
        let size = tidy([half[0], half[1], half_height]);
        let yaw = tidy([rng.gen_range(0.0..90.0)])[0];
        scene.add_box(&format!("box-{k}"), centre, size, yaw, Motion::Static);
    }
    for k in 0..rng.gen_range(0..=2) {
        let half = rng.gen_range(0.15..0.4);
        let [x, y] = room.point_within(half, rng);
        let clearance = half * std::f64::consts::SQRT_2 + PILLAR_CLEARANCE_M;
        if distance_to_path(path, [x, y]) < clearance {
            continue;
        }
        let middle = (room.floor + room.ceiling) / 2.0;
        let half_height = (room.floor - room.ceiling) / 2.0;
        scene.add_box(
            &format!("pillar-{k}"),
            tidy([x, y, middle]),
            tidy([half, half, half_height]),
            0.0,
            Motion::Static,
        );
    }
    if rng.gen_bool(0.5) {
        let x = room.back + 0.5;
        let walk = room.front - room.back - 1.5;
        scene.patches.push(walker(
            "person",
            [x, room.left + 0.5],
            room.floor,
            [1.0, 0.0],
            Profile::Swing {
                start_s: rng.gen_range(0.0..20.0),
                period_s: tidy([walk / rng.gen_range(0.4..1.2) * 2.0])[0],
                cycles: 3,
                amplitude: tidy([walk])[0],
            },
        ));
    }
}

/// Horizontal distance from `point` to the polyline `path`, m.
fn distance_to_path(path: &[[f64; 3]], point: [f64; 2]) -> f64 {
    path.windows(2)
        .map(|leg| {
            let (a, b) = ((leg[0][0], leg[0][1]), (leg[1][0], leg[1][1]));
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let along = ((point[0] - a.0) * dx + (point[1] - a.1) * dy) / (dx * dx + dy * dy);
            let s = along.clamp(0.0, 1.0);
            (point[0] - a.0 - s * dx).hypot(point[1] - a.1 - s * dy)
        })
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drawn_walk::assert_every_seed_draws_the_same_valid_scene;
    use crate::trajectory::Trajectory;

    #[test]
    fn every_seed_draws_a_valid_room_the_same_way_each_time() {
        assert_every_seed_draws_the_same_valid_scene(random_room);
    }

    #[test]
    fn the_path_keeps_clear_of_the_pillars() {
        for seed in 0..200 {
            let scenario = random_room(seed);
            let Trajectory::Waypoints { waypoints_m, .. } = &scenario.trajectory else {
                panic!("seed {seed}: not a walk");
            };
            let path: Vec<[f64; 3]> = std::iter::once([0.0; 3])
                .chain(waypoints_m.iter().copied())
                .collect();
            for patch in &scenario.scene.patches {
                if !patch.name.starts_with("pillar") {
                    continue;
                }
                let centre = [patch.centre_m[0], patch.centre_m[1]];
                assert!(
                    distance_to_path(&path, centre) > PILLAR_CLEARANCE_M,
                    "seed {seed}: {} on the path",
                    patch.name
                );
            }
        }
    }
}
