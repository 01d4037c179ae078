//! The built-in scenarios, after the paper's section 4. All coordinates are NED with the body
//! starting at the origin; floors are at positive z (below), ceilings at negative z.

use super::imu::ImuConfig;
use super::scanner::{ScannerConfig, ScannerModel};
use super::scenario::Scenario;
use super::scene::{Motion, Patch, Profile, Scene};
use super::trajectory::{Oscillation, Trajectory};
use ladar_sensors::ScannerGeometry;
use nalgebra::{UnitQuaternion, Vector3};

/// The paper's sec. 4.1 bias experiments, applied to plane 2 at epoch 1 (t = 1 s).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PaperBias {
    None,
    /// Plane 2 moves 0.1 m away from the scanner; the body steps to NED [0.6, 0.4, 0].
    Translated,
    /// The body stays put but turns 5 deg in heading; plane 2 turns 5.7 deg about the vertical
    /// through the scanner, which keeps its distance.
    Rotated,
}

/// The paper's 180 deg / 0.5 deg / 1 Hz scanner (steps 180..=540 of 720, front at 360).
pub const PAPER_SCANNER: ScannerGeometry = ScannerGeometry {
    ares: 720,
    amin: 180,
    amax: 540,
    afrt: 360,
    rpm: 60,
    dmin_m: 0.02,
    dmax_m: 30.0,
};

pub(crate) const PAPER_EPOCH_S: f64 = 1.0;
/// The rig moves in the 0.2 s before the second epoch: the scans take 0.25-0.75 s of each 1 s
/// revolution (steps 180-540 of 720), so both still see the paper's two poses exactly, and an
/// IMU can follow the move (6.8 m/s and 104 m/s^2 at the peak: violent, but only the
/// recording and the emulators use the IMU, never the paper's studies).
const PAPER_RAMP_S: f64 = 0.2;

/// Wall facing the origin, as the paper's scenes place them: centre at `range` along azimuth
/// `az_deg` (from north, to the right), normal towards the origin, then skewed about the
/// vertical and tilted about its horizontal axis; `width_deg` of azimuth wide, 3 m tall.
pub fn wall_facing_origin(
    name: &str,
    az_deg: f64,
    range: f64,
    [skew_deg, tilt_deg]: [f64; 2],
    width_deg: f64,
) -> Patch {
    let az = az_deg.to_radians();
    let towards = Vector3::new(az.cos(), az.sin(), 0.0);
    let skew = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), skew_deg.to_radians());
    let horizontal = skew * Vector3::z().cross(&towards).normalize();
    let tilt = UnitQuaternion::from_axis_angle(
        &nalgebra::Unit::new_normalize(horizontal),
        tilt_deg.to_radians(),
    );
    let up_in_plane = tilt * -Vector3::z();
    Patch::new(
        name,
        (towards * range).into(),
        horizontal.into(),
        up_in_plane.into(),
        [range * (width_deg / 2.0).to_radians().tan(), 1.5],
    )
}

/// A paper-sim plane: about 50 beams of 0.5 deg, 25 deg of azimuth.
fn paper_plane(name: &str, az_deg: f64, range: f64, skew_deg: f64, tilt_deg: f64) -> Patch {
    wall_facing_origin(name, az_deg, range, [skew_deg, tilt_deg], 25.0)
}

pub(crate) fn paper_sim(bias: PaperBias) -> Scenario {
    let mut scene = Scene {
        patches: vec![
            paper_plane("plane-1", -65.0, 3.0, 20.0, 25.0),
            paper_plane("plane-2", -20.0, 5.0, 0.0, 0.0),
            paper_plane("plane-3", 25.0, 4.5, -15.0, -20.0),
            paper_plane("plane-4", 70.0, 3.5, 10.0, 35.0),
        ],
    };
    let moved = &mut scene.patches[1];
    let (position_after_m, rpy_after_deg, name) = match bias {
        PaperBias::None => ([0.6, 0.4, 0.0], [0.0; 3], "paper-sim"),
        PaperBias::Translated => {
            moved.motion = Motion::Translate {
                direction: moved.centre_m,
                distance_m: Profile::Step {
                    at_s: PAPER_EPOCH_S,
                    amount: 0.1,
                },
            };
            ([0.6, 0.4, 0.0], [0.0; 3], "paper-sim-translated-plane")
        }
        PaperBias::Rotated => {
            moved.motion = Motion::Rotate {
                pivot_m: [0.0; 3],
                axis: [0.0, 0.0, 1.0],
                angle_deg: Profile::Step {
                    at_s: PAPER_EPOCH_S,
                    amount: 5.7,
                },
            };
            ([0.0; 3], [0.0, 0.0, 5.0], "paper-sim-rotated-plane")
        }
    };
    let scanner = |name: &str, pitch: f64| ScannerConfig {
        geometry: Some(PAPER_SCANNER),
        ..ScannerConfig::new(name, ScannerModel::Custom, [0.0, pitch, 0.0], 0.01)
    };
    Scenario {
        name: name.to_string(),
        seed: 1,
        duration_s: 2.0,
        truth_rate_hz: 50.0,
        trajectory: Trajectory::Step {
            position_m: [0.0; 3],
            rpy_deg: [0.0; 3],
            at_s: PAPER_EPOCH_S,
            position_after_m,
            rpy_after_deg,
            ramp_s: PAPER_RAMP_S,
        },
        scanners: vec![scanner("level", 0.0), scanner("raised", 10.0)],
        // Not in the paper's simulation; it lets the scenario be recorded, replayed and served.
        imu: Some(ImuConfig::default()),
        scene,
    }
}

/// Rounds away binary noise such as 0.7999999999999999 so the scenario files read cleanly.
pub(crate) fn tidy<const N: usize>(values: [f64; N]) -> [f64; N] {
    values.map(|v| (v * 1e9).round() / 1e9)
}

/// Vertical wall patch from `(x0, y0)` to `(x1, y1)` between heights `z_top` and `z_bottom`.
fn wall(name: &str, from: [f64; 2], to: [f64; 2], z_top: f64, z_bottom: f64) -> Patch {
    let along = Vector3::new(to[0] - from[0], to[1] - from[1], 0.0);
    Patch::new(
        name,
        tidy([
            (from[0] + to[0]) / 2.0,
            (from[1] + to[1]) / 2.0,
            (z_top + z_bottom) / 2.0,
        ]),
        tidy(along.normalize().into()),
        [0.0, 0.0, 1.0],
        tidy([along.norm() / 2.0, (z_bottom - z_top) / 2.0]),
    )
}

/// A wall along `y` from `x[0]` to `x[1]` with a doorway over `doorway`: the wall on either
/// side and the lintel above, from `ceiling` down to `floor` and to `door_top`.
fn wall_with_doorway(
    y: f64,
    x: [f64; 2],
    doorway: [f64; 2],
    [ceiling, floor, door_top]: [f64; 3],
) -> [Patch; 3] {
    [
        wall(
            "right-wall-rear",
            [x[0], y],
            [doorway[0], y],
            ceiling,
            floor,
        ),
        wall(
            "right-wall-front",
            [doorway[1], y],
            [x[1], y],
            ceiling,
            floor,
        ),
        wall(
            "lintel",
            [doorway[0], y],
            [doorway[1], y],
            ceiling,
            door_top,
        ),
    ]
}

/// A box-shaped room over `x` and `y`: floor, ceiling and four walls between `ceiling` and
/// `floor` (NED depths).
pub(crate) fn box_room(x: [f64; 2], y: [f64; 2], [ceiling, floor]: [f64; 2]) -> [Patch; 6] {
    let ([back, front], [left, right]) = (x, y);
    [
        slab("floor", x, y, floor),
        slab("ceiling", x, y, ceiling),
        wall("back-wall", [back, left], [back, right], ceiling, floor),
        wall("front-wall", [front, left], [front, right], ceiling, floor),
        wall("left-wall", [back, left], [front, left], ceiling, floor),
        wall("right-wall", [back, right], [front, right], ceiling, floor),
    ]
}

/// Horizontal patch at height `z` over `[x0, x1] x [y0, y1]`.
fn slab(name: &str, x: [f64; 2], y: [f64; 2], z: f64) -> Patch {
    Patch::new(
        name,
        tidy([(x[0] + x[1]) / 2.0, (y[0] + y[1]) / 2.0, z]),
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        tidy([(x[1] - x[0]) / 2.0, (y[1] - y[0]) / 2.0]),
    )
}

/// Sec. 4.2: two URG-04LX (5.6 m, 240 deg) on a tripod near the back-left corner of an office
/// (left wall y = -1.5, front wall x = 3.5, right wall y = 2.0, floor 1.3 m below, ceiling 1.5 m
/// above). Each scan plane is tilted both ways (pitch and roll), differently, so both scanners
/// see the floor, the left, front and right walls (three independent normals besides the door)
/// and their lines on each cross or lie apart. The door (x = -0.05 .. 0.95) is recessed 0.1 m in
/// its frame in the right wall, so its lines break from the wall's and it is its own plane even
/// when closed; hinged at x = 0.95, it swings into the room 0 -> 90 -> 0 deg five times (period
/// 9 s from t = 2 s). A corridor wall shows through the open doorway.
pub(crate) fn office_door() -> Scenario {
    let (ceiling, floor, door_top) = (-1.5, 1.3, -0.95);
    let (left, right, front, back) = (-1.5, 2.0, 3.5, -2.0);
    let doorway = [0.0, 0.9];
    let door_hinge = [0.95, right + 0.1];
    let door = Patch::new(
        "door",
        tidy([0.45, door_hinge[1], (door_top + floor) / 2.0]),
        [1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        tidy([0.5, (floor - door_top) / 2.0]),
    )
    .with_motion(Motion::Rotate {
        pivot_m: [door_hinge[0], door_hinge[1], 0.0],
        axis: [0.0, 0.0, 1.0],
        angle_deg: Profile::Swing {
            start_s: 2.0,
            period_s: 9.0,
            cycles: 5,
            amplitude: 90.0,
        },
    });
    let scene = Scene {
        patches: [
            wall("front-wall", [front, left], [front, right], ceiling, floor),
            wall("left-wall", [back, left], [front, left], ceiling, floor),
        ]
        .into_iter()
        .chain(wall_with_doorway(
            right,
            [back, front],
            doorway,
            [ceiling, floor, door_top],
        ))
        .chain([
            wall("back-wall", [back, left], [back, right], ceiling, floor),
            wall("corridor-wall", [-2.0, 3.5], [3.0, 3.5], ceiling, floor),
            slab("ceiling", [back, front], [left, right], ceiling),
            slab("floor", [back, front], [left, right], floor),
            door,
        ])
        .collect(),
    };
    let urg = |name: &str, rpy: [f64; 3], z: f64| ScannerConfig {
        mount_translation_m: [0.0, 0.0, z],
        skip: 2,
        ..ScannerConfig::new(name, ScannerModel::Urg04lx, rpy, 0.015)
    };
    Scenario {
        name: "office-door".into(),
        seed: 2,
        duration_s: 50.0,
        truth_rate_hz: 50.0,
        trajectory: Trajectory::Stationary {
            position_m: [0.0; 3],
            rpy_deg: [0.0; 3],
        },
        // Scan planes z = 0.35 x - 0.35 y (front and left down) and z = 0.1 x + 0.55 y (right
        // down), 6 cm apart in height.
        scanners: vec![
            urg("urg-low", [-18.3, -19.3, 0.0], 0.03),
            urg("urg-high", [28.7, -5.7, 0.0], -0.03),
        ],
        // The paper's tripod had none; it lets the scenario be recorded, replayed and served.
        imu: Some(ImuConfig::default()),
        scene,
    }
}

/// Hallway 2.2 m wide (y = -1.1 .. 1.1), floor 1.2 m below and ceiling 1.3 m above the start,
/// from `back_x` to `end_x`; a door in the right wall at x = 0.3 .. 1.2 opening away from the
/// hallway into a room, and a 1.6 m tall cabinet against the left wall at x = 0.6 .. 1.2.
fn hallway(back_x: f64, end_x: f64, door: Profile) -> Scene {
    let (ceiling, floor, door_top) = (-1.3, 1.2, -0.8);
    let (door_from, door_to) = (0.3, 1.2);
    let mut scene = Scene {
        patches: [
            slab("floor", [back_x, end_x], [-1.1, 1.1], floor),
            slab("ceiling", [back_x, end_x], [-1.1, 1.1], ceiling),
            wall("left-wall", [back_x, -1.1], [end_x, -1.1], ceiling, floor),
        ]
        .into_iter()
        .chain(wall_with_doorway(
            1.1,
            [back_x, end_x],
            [door_from, door_to],
            [ceiling, floor, door_top],
        ))
        .chain([
            wall("end-wall", [end_x, -1.1], [end_x, 1.1], ceiling, floor),
            wall("back-wall", [back_x, -1.1], [back_x, 1.1], ceiling, floor),
            wall("room-wall", [-1.0, 3.5], [2.5, 3.5], ceiling, floor),
            Patch::new(
                "door",
                tidy([(door_from + door_to) / 2.0, 1.1, (door_top + floor) / 2.0]),
                [1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0],
                tidy([(door_to - door_from) / 2.0, (floor - door_top) / 2.0]),
            )
            .with_motion(Motion::Rotate {
                pivot_m: [door_to, 1.1, 0.0],
                axis: [0.0, 0.0, -1.0],
                angle_deg: door,
            }),
        ])
        .collect(),
    };
    scene.add_box(
        "cabinet",
        [0.9, -0.8, 0.4],
        [0.3, 0.3, 0.8],
        0.0,
        Motion::Static,
    );
    scene
}

/// The UTM-30LX level and the UST-20LX pitched 30 deg down as in the paper's rig, and also
/// rolled 40 deg: two scanners pitched about the same axis draw parallel lines on the floor, the
/// end walls and every box face, and two parallel lines are coplanar whatever surfaces they lie
/// on, so most planes would be fictitious. The roll makes the lines cross on every surface.
pub(crate) fn hallway_scanners() -> Vec<ScannerConfig> {
    vec![
        ScannerConfig {
            mount_translation_m: [0.05, 0.0, -0.05],
            skip: 9,
            ..ScannerConfig::new("utm", ScannerModel::Utm30lx, [0.0, 0.0, 0.0], 0.01)
        },
        ScannerConfig {
            mount_translation_m: [0.05, 0.0, 0.05],
            skip: 9,
            phase_s: 0.0123,
            ..ScannerConfig::new("ust", ScannerModel::Ust20lx, [40.0, -30.0, 0.0], 0.01)
        },
    ]
}

pub(crate) fn gentle_hover(start_s: f64) -> Oscillation {
    Oscillation {
        position_amplitude_m: [0.03, 0.03, 0.02],
        position_period_s: [7.3, 5.9, 4.1],
        attitude_amplitude_deg: [0.5, 0.5, 1.0],
        attitude_period_s: [6.1, 4.7, 8.3],
        start_s,
        ramp_s: 10.0,
    }
}

/// Sec. 4.3: 500 s hover at -10 deg pitch, still for the first 40 s (ZUPT), UTM-30LX level and
/// UST-20LX pitched 30 deg further down and rolled 40 deg (both 4 Hz: SCIP scan interval 9), IMU at 400 Hz. The
/// door opens and closes 15 times (19 s each from t = 5 s); from t = 300 s a 60 x 90 cm board
/// approaches from 5 m to 1 m in front and departs, 10 times (19 s each).
pub(crate) fn hallway_hover() -> Scenario {
    let mut scene = hallway(
        -6.0,
        9.0,
        Profile::Swing {
            start_s: 5.0,
            period_s: 19.0,
            cycles: 15,
            amplitude: 90.0,
        },
    );
    scene.patches.push(board_carried_back_along_x(
        [5.0, 0.2, 0.55],
        [0.3, 0.45],
        Profile::Swing {
            start_s: 300.0,
            period_s: 19.0,
            cycles: 10,
            amplitude: 4.0,
        },
    ));
    Scenario {
        name: "hallway-hover".into(),
        seed: 3,
        duration_s: 500.0,
        truth_rate_hz: 50.0,
        trajectory: Trajectory::Hover {
            position_m: [0.0; 3],
            rpy_deg: [0.0, -10.0, 0.0],
            oscillation: gentle_hover(40.0),
        },
        scanners: hallway_scanners(),
        imu: Some(ImuConfig::default()),
        scene,
    }
}

/// A flight down a 26 m hallway: still for 10 s, 12 m forward in 12 s (peak 1.9 m/s), a 180 deg
/// turn in 4 s, 12 m back, then 5 s of hover; -10 deg pitch and gentle hover motions throughout.
/// The door swings 4 times (10 s each from t = 8 s).
pub(crate) fn hallway_flight() -> Scenario {
    Scenario {
        name: "hallway-flight".into(),
        seed: 4,
        duration_s: 43.0,
        truth_rate_hz: 50.0,
        trajectory: Trajectory::Flight {
            position_m: [0.0; 3],
            rpy_deg: [0.0, -10.0, 0.0],
            start_s: 10.0,
            leg_length_m: 12.0,
            leg_duration_s: 12.0,
            return_leg: true,
            turn_duration_s: 4.0,
            oscillation: gentle_hover(10.0),
        },
        scanners: hallway_scanners(),
        imu: Some(ImuConfig::default()),
        scene: hallway(
            -6.0,
            20.0,
            Profile::Swing {
                start_s: 8.0,
                period_s: 10.0,
                cycles: 4,
                amplitude: 90.0,
            },
        ),
    }
}

/// The paper's rig itself (sec. 4.3): the UTM-30LX level and the UST-20LX pitched 30 deg down
/// about the same axis. On a floor, an end wall or a box face its lines are parallel to the
/// level scanner's, so only the side walls give planes of two crossing lines.
pub(crate) fn paper_rig_scanners() -> Vec<ScannerConfig> {
    let mut scanners = hallway_scanners();
    scanners[1].mount_rpy_deg = [0.0, -30.0, 0.0];
    scanners
}

/// A bare corridor 30 m long (x = -3 .. 27), 2.2 m wide, with one 0.6 x 0.4 x 1 m cabinet
/// against the left wall at x = 12, walked with the paper's rig: still for 10 s, then 24 m
/// forward in 240 s (0.1 m/s on average, 0.19 m/s at most) with gentle hover motions, at -10 deg
/// pitch. Only the side walls make planes, so the motion along the corridor is unobservable
/// for most epochs: the test of a filter that must say so.
pub(crate) fn bare_corridor() -> Scenario {
    let mut scenario = walked_corridor("bare-corridor");
    scenario.scene.add_box(
        "cabinet",
        [12.0, -0.9, 0.7],
        [0.3, 0.2, 0.5],
        0.0,
        Motion::Static,
    );
    scenario
}

/// The bare corridor without its cabinet, and instead a 0.6 x 1.2 m board carried to and fro
/// along it beside the walk, square to the corridor: from x = 16 to 8 and back, six times, 40 s
/// each from t = 20 s (up to 0.63 m/s). Wherever the board is seen it is the only surface that
/// faces along the corridor, so nothing but the filter's prediction can tell that it moves.
pub(crate) fn board_corridor() -> Scenario {
    let mut scenario = walked_corridor("board-corridor");
    scenario.scene.patches.push(board_carried_back_along_x(
        [16.0, 0.55, 0.4],
        [0.3, 0.6],
        Profile::Swing {
            start_s: 20.0,
            period_s: 40.0,
            cycles: 6,
            amplitude: 8.0,
        },
    ));
    scenario
}

/// A board square to x, centred at `centre` with `half_extents_m` (across, up), carried
/// towards -x by `distance` metres.
fn board_carried_back_along_x(
    centre: [f64; 3],
    half_extents_m: [f64; 2],
    distance: Profile,
) -> Patch {
    Patch::new(
        "board",
        centre,
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        half_extents_m,
    )
    .with_motion(Motion::Translate {
        direction: [-1.0, 0.0, 0.0],
        distance_m: distance,
    })
}

/// The bare corridor's walls, rig and walk, with nothing in it.
fn walked_corridor(name: &str) -> Scenario {
    let (ceiling, floor) = (-1.3, 1.2);
    let (back_x, end_x) = (-3.0, 27.0);
    let scene = Scene {
        patches: vec![
            slab("floor", [back_x, end_x], [-1.1, 1.1], floor),
            slab("ceiling", [back_x, end_x], [-1.1, 1.1], ceiling),
            wall("left-wall", [back_x, -1.1], [end_x, -1.1], ceiling, floor),
            wall("right-wall", [back_x, 1.1], [end_x, 1.1], ceiling, floor),
            wall("end-wall", [end_x, -1.1], [end_x, 1.1], ceiling, floor),
            wall("back-wall", [back_x, -1.1], [back_x, 1.1], ceiling, floor),
        ],
    };
    Scenario {
        name: name.into(),
        seed: 5,
        duration_s: 260.0,
        truth_rate_hz: 50.0,
        trajectory: Trajectory::Flight {
            position_m: [0.0; 3],
            rpy_deg: [0.0, -10.0, 0.0],
            start_s: 10.0,
            leg_length_m: 24.0,
            leg_duration_s: 240.0,
            return_leg: false,
            turn_duration_s: 0.0,
            oscillation: gentle_hover(10.0),
        },
        scanners: paper_rig_scanners(),
        imu: Some(ImuConfig::default()),
        scene,
    }
}

/// A person walking: a 0.5 x 1.7 m board standing on the floor from `at`, facing the way it
/// walks (the horizontal `towards`), so that it moves along its own normal as the hallway's
/// board does: a plane that moves, not one that slides within itself.
pub(crate) fn walker(
    name: &str,
    at: [f64; 2],
    floor: f64,
    towards: [f64; 2],
    walk: Profile,
) -> Patch {
    let direction = Vector3::new(towards[0], towards[1], 0.0).normalize();
    Patch::new(
        name,
        tidy([at[0], at[1], floor - 0.85]),
        tidy(Vector3::z().cross(&direction).into()),
        [0.0, 0.0, 1.0],
        [0.25, 0.85],
    )
    .with_motion(Motion::Translate {
        direction: tidy(direction.into()),
        distance_m: walk,
    })
}

/// A 10 x 8 x 3 m room (x = -2.5 .. 7.5, y = -3 .. 5, floor 1.4 m below the start, ceiling
/// 1.6 m above), furnished: a 0.4 m pillar, a 1.9 m bookshelf against the left wall, a table, a
/// door in the right wall swinging into the room 0 -> 90 -> 0 deg seven times (15 s each from
/// t = 5 s) on a corridor, and a person walking 5 m down the left of the room, towards the
/// back wall, and back four times (22 s each from t = 20 s). The paper's rig: still for 10 s,
/// hovering (as hallway-hover) from 10 s, then from 60 s crossing 5.1 m of the room at
/// 0.25 m/s, 11 deg right of its heading, and hovering again at the far side until 120 s.
pub(crate) fn open_room() -> Scenario {
    let (ceiling, floor, door_top) = (-1.6, 1.4, -0.6);
    let (back, front, left, right) = (-2.5, 7.5, -3.0, 5.0);
    let doorway = [1.2, 2.1];
    let corridor = 6.8;
    let door = Patch::new(
        "door",
        tidy([
            (doorway[0] + doorway[1]) / 2.0,
            right,
            (door_top + floor) / 2.0,
        ]),
        [1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        tidy([(doorway[1] - doorway[0]) / 2.0, (floor - door_top) / 2.0]),
    )
    .with_motion(Motion::Rotate {
        pivot_m: [doorway[1], right, 0.0],
        axis: [0.0, 0.0, 1.0],
        angle_deg: Profile::Swing {
            start_s: 5.0,
            period_s: 15.0,
            cycles: 7,
            amplitude: 90.0,
        },
    });
    let mut scene = Scene {
        patches: [
            slab("floor", [back, front], [left, right], floor),
            slab("ceiling", [back, front], [left, right], ceiling),
            wall("back-wall", [back, left], [back, right], ceiling, floor),
            wall("front-wall", [front, left], [front, right], ceiling, floor),
            wall("left-wall", [back, left], [front, left], ceiling, floor),
        ]
        .into_iter()
        .chain(wall_with_doorway(
            right,
            [back, front],
            doorway,
            [ceiling, floor, door_top],
        ))
        .chain([
            wall(
                "corridor-wall",
                [-2.0, corridor],
                [5.0, corridor],
                ceiling,
                floor,
            ),
            slab("corridor-floor", [-2.0, 5.0], [right, corridor], floor),
            slab("table", [4.8, 6.4], [3.2, 4.0], floor - 0.75),
            door,
            walker(
                "person",
                [6.5, -2.0],
                floor,
                [-1.0, 0.0],
                Profile::Swing {
                    start_s: 20.0,
                    period_s: 22.0,
                    cycles: 4,
                    amplitude: 5.0,
                },
            ),
        ])
        .collect(),
    };
    let middle = (ceiling + floor) / 2.0;
    let height = (floor - ceiling) / 2.0;
    scene.add_box(
        "pillar",
        [3.5, -1.0, middle],
        [0.2, 0.2, height],
        0.0,
        Motion::Static,
    );
    scene.add_box(
        "bookshelf",
        [1.0, left + 0.2, floor - 0.95],
        [0.9, 0.2, 0.95],
        0.0,
        Motion::Static,
    );
    Scenario {
        name: "open-room".into(),
        seed: 6,
        duration_s: 120.0,
        truth_rate_hz: 50.0,
        trajectory: Trajectory::Waypoints {
            position_m: [0.0; 3],
            rpy_deg: [0.0, -10.0, 0.0],
            start_s: 60.0,
            waypoints_m: vec![[5.0, 1.0, 0.0]],
            speed_mps: 0.25,
            blend_s: 4.0,
            oscillation: gentle_hover(10.0),
        },
        scanners: paper_rig_scanners(),
        imu: Some(ImuConfig::default()),
        scene,
    }
}

/// A 20 x 12 x 4 m hall (x = -4 .. 16, y = -4 .. 8, floor 1.5 m below the start, ceiling 2.5 m
/// above) with two 0.5 m pillars, a counter along the right wall and a person walking 12 m up
/// the hall and back three times (40 s each from t = 15 s). The paper's rig, still for 10 s,
/// hovering from 10 s, then from 20 s twice round a 12 x 4 m loop about the pillars at 0.6 m/s,
/// turning 90 deg right at each corner over 4 s (up to 42 deg/s), back at the start by 131 s;
/// hovering to 150 s.
pub(crate) fn hall_walk() -> Scenario {
    let (ceiling, floor) = (-2.5, 1.5);
    let (back, front, left, right) = (-4.0, 16.0, -4.0, 8.0);
    let mut scene = Scene {
        patches: box_room([back, front], [left, right], [ceiling, floor])
            .into_iter()
            .chain([walker(
                "person",
                [0.0, 6.0],
                floor,
                [1.0, 0.0],
                Profile::Swing {
                    start_s: 15.0,
                    period_s: 40.0,
                    cycles: 3,
                    amplitude: 12.0,
                },
            )])
            .collect(),
    };
    let middle = (ceiling + floor) / 2.0;
    let height = (floor - ceiling) / 2.0;
    for (name, x) in [("pillar-1", 4.0), ("pillar-2", 8.0)] {
        scene.add_box(
            name,
            [x, 2.0, middle],
            [0.25, 0.25, height],
            0.0,
            Motion::Static,
        );
    }
    scene.add_box(
        "counter",
        [6.0, right - 0.3, floor - 0.5],
        [1.5, 0.3, 0.5],
        0.0,
        Motion::Static,
    );
    let lap = [
        [12.0, 0.0, 0.0],
        [12.0, 4.0, 0.0],
        [0.0, 4.0, 0.0],
        [0.0, 0.0, 0.0],
    ];
    Scenario {
        name: "hall-walk".into(),
        seed: 7,
        duration_s: 150.0,
        truth_rate_hz: 50.0,
        trajectory: Trajectory::Waypoints {
            position_m: [0.0; 3],
            rpy_deg: [0.0, -10.0, 0.0],
            start_s: 20.0,
            waypoints_m: [lap, lap].concat(),
            speed_mps: 0.6,
            blend_s: 4.0,
            oscillation: gentle_hover(10.0),
        },
        scanners: paper_rig_scanners(),
        imu: Some(ImuConfig::default()),
        scene,
    }
}

/// `scenario` flown with the rig of `config/default.toml` (the hallway rig: the pitched scanner
/// also rolled 40 deg) in place of its own scanners, named `NAME-rolled`.
pub(crate) fn with_rolled_rig(mut scenario: Scenario) -> Scenario {
    scenario.name = format!("{}-rolled", scenario.name);
    scenario.scanners = hallway_scanners();
    scenario
}
