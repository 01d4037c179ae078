//! Property and bad-input tests of the geometry core on exact synthetic geometry.

use super::matching::Matcher;
use super::synthetic::{cast_scan, crossed_mounts, hallway, WorldPlane};
use super::*;
use crate::odometry::displacement::solve_displacement;
use crate::odometry::uncertainty::PlaneUncertainty;
use crate::sensors::{Mount, ScannerGeometry};
use nalgebra::{Isometry3, Translation3};
use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

const UTM: ScannerGeometry = ScannerGeometry::UTM_30LX;

fn odometer(config: OdometryConfig) -> Odometer {
    let setup = |mount| ScannerSetup {
        geometry: UTM,
        mount,
        range_sigma_m: None,
    };
    let [a, b] = crossed_mounts();
    Odometer::new([setup(a), setup(b)], config).unwrap()
}

/// Noise-free scans allow a split distance far below any noise level (no line then takes in
/// the first samples of the next wall at a shallow corner, and every fit is exact) and a tiny
/// ranging sigma (the coplanarity gate then refuses lines that only nearly share a plane).
fn exact() -> OdometryConfig {
    OdometryConfig {
        split_distance_m: 1e-6,
        range_sigma_m: 1e-6,
        ..OdometryConfig::default()
    }
}

fn odometer_default() -> Odometer {
    odometer(OdometryConfig::default())
}

fn pose(translation: [f64; 3], rpy_deg: [f64; 3]) -> Isometry3<f64> {
    let [r, p, y] = rpy_deg.map(f64::to_radians);
    Isometry3::from_parts(
        Translation3::from(Vector3::from(translation)),
        UnitQuaternion::from_euler_angles(r, p, y),
    )
}

fn scans_at(room: &[WorldPlane], body: Isometry3<f64>) -> [Scan; 2] {
    crossed_mounts().map(|mount| cast_scan(room, &UTM, &mount, &|_| body, 0.0))
}

fn extract_at(odometer: &mut Odometer, room: &[WorldPlane], body: Isometry3<f64>) -> EpochPlanes {
    let [a, b] = scans_at(room, body);
    odometer.extract([&a, &b], 0.0, &|_| Isometry3::identity())
}

/// Index of the room plane that `plane` (in the body frame of `body`) is, within `tolerance`.
fn room_plane_of(
    room: &[WorldPlane],
    body: &Isometry3<f64>,
    plane: &Plane,
    tolerance: f64,
) -> Option<usize> {
    room.iter().position(|w| {
        let normal = body.rotation.inverse() * w.normal;
        let rho = w.rho - w.normal.dot(&body.translation.vector);
        (normal - plane.normal).norm() < tolerance && (rho - plane.rho).abs() < tolerance
    })
}

/// C_j^i and dR of body j relative to body i.
fn relative(i: &Isometry3<f64>, j: &Isometry3<f64>) -> (UnitQuaternion<f64>, Vector3<f64>) {
    let between = i.inverse() * j;
    (between.rotation, between.translation.vector)
}

fn prior_from(
    i: &Isometry3<f64>,
    j: &Isometry3<f64>,
    sigma_rad: f64,
    sigma_m: f64,
) -> RelativePose {
    let (rotation, translation) = relative(i, j);
    RelativePose {
        rotation,
        translation,
        ..RelativePose::stationary(sigma_rad, sigma_m)
    }
}

fn small_pose() -> impl Strategy<Value = Isometry3<f64>> {
    (
        -0.3..0.3f64,
        -0.3..0.3f64,
        -0.2..0.2f64,
        -4.0..4.0f64,
        -4.0..4.0f64,
        -15.0..15.0f64,
    )
        .prop_map(|(x, y, z, r, p, yaw)| pose([x, y, z], [r, p, yaw]))
}

fn unit_vector() -> impl Strategy<Value = Vector3<f64>> {
    (0.0..std::f64::consts::TAU, -1.0..1.0f64).prop_map(|(azimuth, z)| {
        let horizontal = (1.0 - z * z).sqrt();
        Vector3::new(horizontal * azimuth.cos(), horizontal * azimuth.sin(), z)
    })
}

fn rotation_vector(max_rad: f64) -> impl Strategy<Value = Vector3<f64>> {
    (unit_vector(), 0.0..max_rad).prop_map(|(axis, angle)| axis * angle)
}

/// A plane with an isotropic, honest-looking uncertainty, for solver tests without extraction.
fn bare_plane(id: usize, normal: Vector3<f64>, rho: f64) -> Plane {
    let basis = tangent_basis(&normal);
    Plane {
        id,
        normal,
        rho,
        uncertainty: PlaneUncertainty {
            normal_covariance: basis * basis.transpose() * 1e-6,
            sigma_normal: 1e-3 * 2f64.sqrt(),
            sigma_rho: 3e-3,
        },
        lines: [
            planes::LineRef {
                scanner: 0,
                segment: id,
            },
            planes::LineRef {
                scanner: 1,
                segment: id,
            },
        ],
        crossing: true,
        confirmed: false,
        extent_m: 1.0,
        normal_assumed: false,
    }
}

/// Planes of both epochs for world planes `(n, rho)` seen from body i at the origin and body j
/// at `(c, dr)` relative to it, matched in order.
fn epoch_pair(
    world: &[(Vector3<f64>, f64)],
    c: &UnitQuaternion<f64>,
    dr: &Vector3<f64>,
) -> (Vec<Plane>, Vec<Plane>, Vec<PlaneMatch>) {
    let previous: Vec<Plane> = world
        .iter()
        .enumerate()
        .map(|(k, (n, rho))| bare_plane(k, *n, *rho))
        .collect();
    let current = world
        .iter()
        .enumerate()
        .map(|(k, (n, rho))| bare_plane(k, c.inverse() * n, rho - n.dot(dr)))
        .collect();
    let matches = (0..world.len())
        .map(|k| PlaneMatch {
            previous: k,
            current: k,
            distance_squared: 0.0,
        })
        .collect();
    (previous, current, matches)
}

fn rotation_parameters() -> rotation::RotationParameters {
    OdometryConfig::default().rotation_parameters()
}

// ---- lines -------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn every_line_lies_on_exactly_one_room_plane(body in small_pose()) {
        let room = hallway();
        let mut odometer = odometer(exact());
        extract_at(&mut odometer, &room, body);
        for k in 0..2 {
            prop_assert!(odometer.segments[k].len() >= 4);
            for segment in &odometer.segments[k] {
                let on = |beam: &Beam| {
                    let world = body.transform_point(&beam.body.into()).coords;
                    room.iter().position(|w| (w.normal.dot(&world) - w.rho).abs() < 1e-9)
                };
                let first = on(&odometer.beams[k][segment.first]);
                prop_assert!(first.is_some());
                for beam in &odometer.beams[k][segment.first..segment.end] {
                    prop_assert_eq!(on(beam), first);
                }
                prop_assert!(segment.points() >= 10 && segment.length >= 0.3);
            }
        }
    }
}

/// One scan of the first scanner from t = 0, every step from 0.
fn scan_at_rest(ranges_m: Vec<f64>) -> Scan {
    Scan {
        sensor: 0,
        t0: 0.0,
        first_step: 0,
        cluster: 1,
        ranges_m,
    }
}

#[test]
fn a_range_jump_breaks_a_straight_wall_into_two_lines() {
    let g = UTM;
    // A wall 2 m ahead across the front; a pillar 1 m ahead hides part of it.
    let ranges: Vec<f64> = (0..=1080)
        .map(|index| {
            let psi = g.step_azimuth(index as f64);
            if psi.cos() < 0.5 {
                0.0
            } else if (-0.3..0.3).contains(&psi) {
                1.0 / psi.cos()
            } else {
                2.0 / psi.cos()
            }
        })
        .collect();
    let scan = scan_at_rest(ranges);
    let mut beams = Vec::new();
    Deskewer::default().deskew(
        &scan,
        &g,
        &Mount::identity(),
        &|_| Isometry3::identity(),
        &mut beams,
    );
    let parameters = OdometryConfig::default().line_parameters(0.01);
    let mut segments = Vec::new();
    LineExtractor::default().extract(&beams, &parameters, &mut segments);
    assert_eq!(segments.len(), 3, "{segments:?}");
    for (segment, x) in segments.iter().zip([2.0, 1.0, 2.0]) {
        assert!(
            (segment.direction_2d.x).abs() < 1e-12,
            "lines run across the view"
        );
        assert!((segment.centroid_2d.x - x).abs() < 1e-12);
    }
}

/// A 0.6 m face seen at 40-60 deg incidence, between a long wall it meets in a concave corner
/// and a short side it meets in a convex one (the hallway's cabinet), as segments `(from, to)`
/// in the scan plane.
const CABINET: [([f64; 2], [f64; 2]); 3] = [
    ([-3.0, -1.1], [0.6, -1.1]),
    ([0.6, -1.1], [0.6, -0.5]),
    ([0.6, -0.5], [1.2, -0.5]),
];

/// The range along azimuth `psi` to the nearest of `segments`, and which one it hits.
fn cast_segments(segments: &[([f64; 2], [f64; 2])], psi: f64) -> Option<(f64, usize)> {
    let ray = nalgebra::Vector2::new(psi.cos(), psi.sin());
    segments
        .iter()
        .enumerate()
        .filter_map(|(k, (from, to))| {
            let (from, to) = (nalgebra::Vector2::from(*from), nalgebra::Vector2::from(*to));
            let along = to - from;
            let denominator = ray.perp(&along);
            let range = from.perp(&along) / denominator;
            let at = from.perp(&ray) / denominator;
            (denominator.abs() > 1e-12 && range > 0.0 && (0.0..=1.0).contains(&at))
                .then_some((range, k))
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
}

/// One UTM-30LX scan of `segments` with ranging noise `sigma`, as beams at rest, with the
/// segment each beam hit.
fn beams_of(
    segments: &[([f64; 2], [f64; 2])],
    sigma: f64,
    rng: &mut ChaCha8Rng,
    beams: &mut Vec<Beam>,
) -> Vec<usize> {
    let noise = Normal::new(0.0, sigma).unwrap();
    let hits: Vec<(f64, usize)> = (0..=1080)
        .map(|i| cast_segments(segments, UTM.step_azimuth(i as f64)).unwrap_or((0.0, usize::MAX)))
        .collect();
    let scan = scan_at_rest(
        hits.iter()
            .map(|(range, _)| match *range > 0.0 {
                true => range + noise.sample(rng),
                false => 0.0,
            })
            .collect(),
    );
    let identity = |_| Isometry3::identity();
    Deskewer::default().deskew(&scan, &UTM, &Mount::identity(), &identity, beams);
    let surfaces: Vec<usize> = hits
        .iter()
        .filter(|(range, _)| *range > 0.0)
        .map(|h| h.1)
        .collect();
    assert_eq!(surfaces.len(), beams.len(), "every reading is valid");
    surfaces
}

#[test]
fn the_short_face_of_a_corner_keeps_no_reading_of_the_long_wall() {
    let parameters = OdometryConfig::default().line_parameters(0.01);
    let (mut extractor, mut beams, mut segments) = (LineExtractor::default(), vec![], vec![]);
    for seed in 0..200 {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let surfaces = beams_of(&CABINET, 0.01, &mut rng, &mut beams);
        extractor.extract(&beams, &parameters, &mut segments);
        let on_face = |segment: &&Segment| {
            surfaces[segment.first..segment.end]
                .iter()
                .filter(|k| **k == 1)
                .count()
                * 2
                > segment.points()
        };
        let face = segments.iter().find(on_face).expect("the face's line");
        let strays = surfaces[face.first..face.end]
            .iter()
            .filter(|k| **k != 1)
            .count();
        assert!(
            strays <= 1,
            "seed {seed}: {strays} readings of the other surfaces"
        );
    }
}

/// Ranging noise at oblique incidence moves a reading along the line as well as off it; a
/// line regressed on the readings' own abscissae tilts towards the beams by about 1 mrad here.
#[test]
fn an_oblique_line_is_not_tilted_by_its_ranging_noise() {
    let face = &CABINET[1..2];
    let parameters = OdometryConfig::default().line_parameters(0.01);
    let (mut extractor, mut beams, mut segments) = (LineExtractor::default(), vec![], vec![]);
    let mut exact = || {
        beams_of(face, 0.0, &mut ChaCha8Rng::seed_from_u64(0), &mut beams);
        extractor.extract(&beams, &parameters, &mut segments);
        segments[0].direction
    };
    let truth = exact();
    let across = truth.cross(&Vector3::z());
    let runs = 1000;
    let tilts: Vec<f64> = (0..runs)
        .map(|seed| {
            beams_of(face, 0.01, &mut ChaCha8Rng::seed_from_u64(seed), &mut beams);
            extractor.extract(&beams, &parameters, &mut segments);
            let direction = segments[0].direction * segments[0].direction.dot(&truth).signum();
            direction.dot(&across)
        })
        .collect();
    let mean = tilts.iter().sum::<f64>() / runs as f64;
    let spread = (tilts.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / runs as f64).sqrt();
    let standard_error = spread / (runs as f64).sqrt();
    assert!(
        mean.abs() < 3.0 * standard_error,
        "tilt {mean:e} rad, standard error {standard_error:e}"
    );
}

// ---- planes -------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn planes_are_recovered_exactly_without_noise(body in small_pose()) {
        let room = hallway();
        let mut odometer = odometer(exact());
        let epoch = extract_at(&mut odometer, &room, body);
        // How many planes both scanners see depends on the pose (six at rest, see below).
        prop_assert!(epoch.planes.len() >= 2, "only {} planes", epoch.planes.len());
        let mut seen = Vec::new();
        for plane in &epoch.planes {
            let index = room_plane_of(&room, &body, plane, 1e-9);
            prop_assert!(index.is_some(), "plane {:?} is not a room plane", plane);
            prop_assert!(!seen.contains(&index), "room plane found twice");
            seen.push(index);
            prop_assert!(plane.rho > 0.0);
            prop_assert!(plane.uncertainty.sigma_normal > 0.0 && plane.uncertainty.sigma_rho > 0.0);
        }
    }
}

#[test]
fn hallway_gives_six_planes_and_none_is_confirmed_by_a_third_line() {
    let room = hallway();
    let body = Isometry3::identity();
    let epoch = extract_at(&mut odometer(exact()), &room, body);
    assert_eq!(epoch.planes.len(), 6);
    assert!(epoch.planes.iter().all(|p| p.crossing));
    let confirmed = OdometryConfig {
        require_third_line: true,
        ..exact()
    };
    let strict = extract_at(&mut odometer(confirmed), &room, body);
    // Each plane here is crossed by exactly two lines, so none is confirmed by a third.
    assert!(strict.planes.is_empty());
    assert!(epoch.planes.iter().all(|p| !p.confirmed));
}

// ---- uncertainty --------------------------------------------------------------------------

/// Seeded Monte Carlo: the predicted sigmas must be honest, neither optimistic nor wildly
/// pessimistic (0.8x to 3x of the measured scatter, per plane). Gross errors (beyond 6 predicted
/// sigmas) are not noise but segmentation failures (a line taking in the start of the next
/// surface at a shallow corner of the scan): they are counted and bounded separately.
#[test]
fn predicted_plane_sigmas_match_the_monte_carlo_scatter() {
    let room = hallway();
    let body = Isometry3::identity();
    let mut odometer = odometer(OdometryConfig::default());
    let exact = extract_at(&mut odometer, &room, body);
    let truth: Vec<usize> = exact
        .planes
        .iter()
        .map(|p| room_plane_of(&room, &body, p, 0.05).unwrap())
        .collect();
    assert!(truth.len() >= 5);
    let noise = Normal::new(0.0, 0.01).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let runs = 200;
    // Per room plane: measured and predicted squared errors of normal and distance, count.
    let mut stats = vec![[0.0; 5]; room.len()];
    let (mut planes, mut gross) = (0, 0);
    for _ in 0..runs {
        let mut scans = scans_at(&room, body);
        for scan in &mut scans {
            for r in &mut scan.ranges_m {
                *r += noise.sample(&mut rng);
            }
        }
        let epoch = odometer.extract([&scans[0], &scans[1]], 0.0, &|_| Isometry3::identity());
        for plane in &epoch.planes {
            planes += 1;
            let Some(k) = room_plane_of(&room, &body, plane, 0.2) else {
                gross += 1;
                continue;
            };
            let u = plane.uncertainty;
            let normal_error = (plane.normal - room[k].normal).norm();
            let rho_error = plane.rho - room[k].rho;
            if normal_error > 6.0 * u.sigma_normal || rho_error.abs() > 6.0 * u.sigma_rho {
                gross += 1;
                continue;
            }
            let s = &mut stats[k];
            s[0] += normal_error.powi(2);
            s[1] += u.sigma_normal.powi(2);
            s[2] += rho_error.powi(2);
            s[3] += u.sigma_rho.powi(2);
            s[4] += 1.0;
        }
    }
    println!("{gross} gross errors in {planes} planes");
    assert!(
        gross * 20 < planes,
        "{gross} gross errors in {planes} planes"
    );
    for &k in &truth {
        let [measured_n, predicted_n, measured_rho, predicted_rho, count] = stats[k];
        let ratio_n = (predicted_n / measured_n).sqrt();
        let ratio_rho = (predicted_rho / measured_rho).sqrt();
        println!("plane {k}: {count} of {runs}, predicted/measured sigma: normal {ratio_n:.2}, distance {ratio_rho:.2}");
        assert!(
            count >= 0.6 * runs as f64,
            "plane {k} found in {count} of {runs} runs"
        );
        assert!(
            (0.8..=3.0).contains(&ratio_n),
            "plane {k}: normal sigma ratio {ratio_n}"
        );
        assert!(
            (0.8..=3.0).contains(&ratio_rho),
            "plane {k}: distance sigma ratio {ratio_rho}"
        );
    }
}

// ---- deskew through the whole extraction ----------------------------------------------------

#[test]
fn planes_of_a_moving_body_are_exact_at_the_reference_time() {
    let room = hallway();
    // Walking pace with a fast turn: 0.5 rad/s moves the scan ends by 7 mm over one scan.
    let body_at = |t: f64| {
        Isometry3::new(
            Vector3::new(0.6, 0.2, 0.05) * t,
            Vector3::new(0.05, -0.03, 0.5) * t,
        )
    };
    let t_ref = UTM.scan_period() / 2.0;
    let scans = crossed_mounts().map(|mount| cast_scan(&room, &UTM, &mount, &body_at, 0.0));
    let reference = body_at(t_ref);
    let pose_at = |t: f64| reference.inverse() * body_at(t);
    // A scan plane that moves while it sweeps draws a slightly curved line on a wall (on the
    // wall all the same), so the split distance must allow for the curvature.
    let mut odometer = odometer(OdometryConfig {
        split_distance_m: 1e-3,
        ..exact()
    });
    let epoch = odometer.extract([&scans[0], &scans[1]], t_ref, &pose_at);
    assert!(epoch.planes.len() >= 5);
    for plane in &epoch.planes {
        // Sampling the pose every 16 beams leaves only the curvature of the motion.
        assert!(
            room_plane_of(&room, &reference, plane, 1e-7).is_some(),
            "{plane:?}"
        );
    }
    let mut plain = odometer_default();
    let stale = plain.extract([&scans[0], &scans[1]], t_ref, &|_| Isometry3::identity());
    let skewed = stale
        .planes
        .iter()
        .filter(|p| room_plane_of(&room, &reference, p, 1e-3).is_none())
        .count();
    assert!(skewed > 0, "without deskew the planes should be off");
}

// ---- matching -----------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn matching_pairs_the_same_room_planes(i in small_pose(), j in small_pose()) {
        let room = hallway();
        let mut odometer = odometer(exact());
        let previous = extract_at(&mut odometer, &room, i);
        let current = extract_at(&mut odometer, &room, j);
        let prior = prior_from(&i, &j, 0.01, 0.05);
        let mut matches = Vec::new();
        let gates = OdometryConfig::default().match_gates();
        Matcher::default().match_planes(&previous.planes, &current.planes, [&prior, &prior], &gates, &mut matches);
        let label_i: Vec<_> = previous.planes.iter().map(|p| room_plane_of(&room, &i, p, 1e-9)).collect();
        let label_j: Vec<_> = current.planes.iter().map(|p| room_plane_of(&room, &j, p, 1e-9)).collect();
        prop_assert!(label_i.iter().chain(&label_j).all(Option::is_some), "{:?} {:?} {:?} {:?}", label_i, label_j, previous.planes, current.planes);
        let common = label_i.iter().filter(|l| label_j.contains(l)).count();
        prop_assert_eq!(matches.len(), common);
        for m in &matches {
            prop_assert_eq!(label_i[m.previous], label_j[m.current]);
        }
    }
}

// ---- rotation and displacement on exact planes ----------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn rotation_is_recovered_from_a_rough_prior(
        normals in proptest::collection::vec(unit_vector(), 3..8),
        truth in rotation_vector(0.5),
        prior_error in rotation_vector(0.1),
    ) {
        let world: Vec<_> = normals.iter().map(|n| (*n, 3.0)).collect();
        let c = UnitQuaternion::from_scaled_axis(truth);
        let (previous, current, matches) = epoch_pair(&world, &c, &Vector3::zeros());
        let prior = UnitQuaternion::from_scaled_axis(prior_error) * c;
        match solve_rotation(&previous, &current, &matches, &prior, &[], &rotation_parameters()) {
            Ok(solution) => {
                let estimate = UnitQuaternion::from_scaled_axis(solution.x);
                prop_assert!(estimate.angle_to(&c) < 1e-9, "error {}", estimate.angle_to(&c));
                prop_assert!(solution.residuals.amax() < 1e-9);
                prop_assert_eq!(solution.system.rows(), 2 * normals.len());
            }
            // Random normals may all be (nearly) parallel: then refusing is right.
            Err(SolveError::UnderDetermined { .. }) => {
                let spread = normals.iter().map(|n| n.cross(&normals[0]).norm()).fold(0.0, f64::max);
                prop_assert!(spread < 0.01, "refused with spread {}", spread);
            }
            Err(e) => prop_assert!(false, "{}", e),
        }
    }

    #[test]
    fn displacement_is_recovered(
        normals in proptest::collection::vec(unit_vector(), 3..8),
        rotation in rotation_vector(0.3),
        dr in (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64),
    ) {
        let dr = Vector3::new(dr.0, dr.1, dr.2);
        let world: Vec<_> = normals.iter().map(|n| (*n, 4.0)).collect();
        let c = UnitQuaternion::from_scaled_axis(rotation);
        let (previous, current, matches) = epoch_pair(&world, &c, &dr);
        let information: Matrix3<f64> = normals.iter().map(|n| n * n.transpose()).sum();
        let eigen = information.symmetric_eigenvalues();
        prop_assume!(eigen.min() > 1e-3 * eigen.max());
        for rotation in [None, Some(&c)] {
            let solution = solve_displacement(&previous, &current, &matches, rotation, &Vector3::zeros(), &Matrix3::zeros(), &[]).unwrap();
            prop_assert!((solution.x - dr).norm() < 1e-9, "error {}", (solution.x - dr).norm());
            prop_assert_eq!(solution.system.rows(), normals.len());
        }
    }
}

/// The displacement `dr` solved in a hallway whose walls and floor are measured to a fraction
/// of a millimetre, with one more surface facing along it (normal `far_normal`, not
/// necessarily unit) measured to `sigma_far` m.
fn solve_hallway_with_a_coarse_surface_ahead(
    far_normal: Vector3<f64>,
    sigma_far: f64,
    dr: &Vector3<f64>,
) -> Result<Solution, SolveError> {
    let world = [
        (Vector3::y(), 1.5),
        (-Vector3::y(), 1.5),
        (Vector3::z(), 1.2),
        (far_normal.normalize(), 6.0),
    ];
    let (mut previous, mut current, matches) = epoch_pair(&world, &UnitQuaternion::identity(), dr);
    for planes in [&mut previous, &mut current] {
        for (k, plane) in planes.iter_mut().enumerate() {
            plane.uncertainty.sigma_rho = if k == 3 { sigma_far } else { 3e-4 };
        }
    }
    let none = Matrix3::zeros();
    solve_displacement(
        &previous,
        &current,
        &matches,
        None,
        &Vector3::zeros(),
        &none,
        &[],
    )
}

#[test]
fn a_far_wall_measured_to_centimetres_still_observes_the_motion_it_faces() {
    // Its information is 1e-4 of the floor's: a weighted observability test took the motion
    // along the hall for unobserved and handed the filter the prior there instead.
    let dr = Vector3::new(0.3, 0.01, -0.02);
    let solution = solve_hallway_with_a_coarse_surface_ahead(Vector3::x(), 0.03, &dr).unwrap();
    assert!((solution.x - dr).norm() < 1e-9);
    let sigma_along = solution.covariance[(0, 0)].sqrt();
    assert!(
        (sigma_along - 0.03 * 2f64.sqrt()).abs() < 1e-4,
        "{sigma_along}"
    );
}

#[test]
fn a_direction_left_free_is_the_one_the_weighted_rows_hold_least_of() {
    // A surface nearly parallel to the walls (10 mrad off) counts for nothing along the hall,
    // however precise; the free direction then must be square to what the precise rows
    // measure, or the fused directions would carry a share of whatever fills the free one.
    let dr = Vector3::new(0.3, 0.01, -0.02);
    let board = Vector3::new(0.01, 1.0, 0.0);
    let err = solve_hallway_with_a_coarse_surface_ahead(board, 0.05, &dr).unwrap_err();
    let SolveError::UnderDetermined { unobservable } = &err else {
        panic!("{err}")
    };
    assert_eq!(unobservable.len(), 1);
    assert!(unobservable[0].y.abs() < 1e-5, "{err}");
}

#[test]
fn two_walls_leave_the_vertical_unobservable() {
    let world = [
        (Vector3::x(), 2.0),
        (Vector3::y(), 1.5),
        (Vector3::new(1.0, 1.0, 0.0).normalize(), 3.0),
    ];
    let (previous, current, matches) = epoch_pair(
        &world,
        &UnitQuaternion::identity(),
        &Vector3::new(0.1, 0.2, 0.0),
    );
    let err = solve_displacement(
        &previous,
        &current,
        &matches,
        None,
        &Vector3::zeros(),
        &Matrix3::zeros(),
        &[],
    )
    .unwrap_err();
    let SolveError::UnderDetermined { unobservable } = &err else {
        panic!("{err}")
    };
    assert_eq!(unobservable.len(), 1);
    assert!((unobservable[0].z.abs() - 1.0).abs() < 1e-9, "{err}");
    // Rotation is fully observable from two non-parallel walls.
    let rotation = solve_rotation(
        &previous,
        &current,
        &matches,
        &UnitQuaternion::identity(),
        &[],
        &rotation_parameters(),
    );
    assert!(rotation.is_ok());
}

/// The directions a rotation solve from the identity finds unobservable (none if it solves).
fn unobservable_rotation(
    previous: &[Plane],
    current: &[Plane],
    matches: &[PlaneMatch],
) -> Vec<Vector3<f64>> {
    match solve_rotation(
        previous,
        current,
        matches,
        &UnitQuaternion::identity(),
        &[],
        &rotation_parameters(),
    ) {
        Err(SolveError::UnderDetermined { unobservable }) => unobservable,
        Err(err) => panic!("{err}"),
        Ok(_) => Vec::new(),
    }
}

#[test]
fn parallel_planes_leave_rotation_about_their_normal_unobservable() {
    let world = [(Vector3::x(), 2.0), (Vector3::x(), 5.0)];
    let (previous, current, matches) =
        epoch_pair(&world, &UnitQuaternion::identity(), &Vector3::zeros());
    let unobservable = unobservable_rotation(&previous, &current, &matches);
    assert_eq!(unobservable.len(), 1);
    assert!((unobservable[0].x.abs() - 1.0).abs() < 1e-9);
}

#[test]
fn a_plane_whose_normal_is_assumed_tells_the_displacement_but_no_rotation() {
    let world = [(Vector3::x(), 2.0), (Vector3::z(), 1.5)];
    let dr = Vector3::new(0.1, 0.0, -0.05);
    let (previous, mut current, matches) = epoch_pair(&world, &UnitQuaternion::identity(), &dr);
    current[1].normal_assumed = true;
    let unobservable = unobservable_rotation(&previous, &current, &matches);
    assert_eq!(unobservable.len(), 1, "the wall alone");
    let err = displacement::solve_displacement(
        &previous,
        &current,
        &matches,
        None,
        &Vector3::zeros(),
        &(Matrix3::identity() * 0.01),
        &[],
    )
    .unwrap_err();
    let SolveError::UnderDetermined { unobservable } = &err else {
        panic!("{err}")
    };
    assert_eq!(unobservable.len(), 1, "only along y: {err}");
    assert!((unobservable[0].y.abs() - 1.0).abs() < 1e-9);
}

#[test]
fn no_matches_is_under_determined_in_every_direction() {
    let none: [Plane; 0] = [];
    let err = solve_displacement(
        &none,
        &none,
        &[],
        None,
        &Vector3::zeros(),
        &Matrix3::zeros(),
        &[],
    )
    .unwrap_err();
    assert!(
        matches!(&err, SolveError::UnderDetermined { unobservable } if unobservable.len() == 3)
    );
    let err = solve_rotation(
        &none,
        &none,
        &[],
        &UnitQuaternion::identity(),
        &[],
        &rotation_parameters(),
    )
    .unwrap_err();
    assert!(
        matches!(&err, SolveError::UnderDetermined { unobservable } if unobservable.len() == 3)
    );
}

// ---- the whole epoch ------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]

    #[test]
    fn an_epoch_recovers_the_relative_pose(i in small_pose(), j in small_pose()) {
        let room = hallway();
        let mut odometer = odometer(exact());
        let previous = extract_at(&mut odometer, &room, i);
        let current = extract_at(&mut odometer, &room, j);
        let (c, dr) = relative(&i, &j);
        let mut prior = prior_from(&i, &j, 0.02, 0.1);
        prior.rotation = UnitQuaternion::from_euler_angles(0.01, -0.01, 0.02) * prior.rotation;
        prior.translation += Vector3::new(0.05, -0.05, 0.02);
        let epoch = odometer.solve(&previous, &current, &prior);
        let information: Matrix3<f64> = epoch.matches.iter().map(|m| {
            let n = previous.planes[m.previous].normal;
            n * n.transpose()
        }).sum();
        let eigen = information.symmetric_eigenvalues();
        let tolerance = crate::least_squares::PARALLEL_TOLERANCE;
        if eigen.min() <= tolerance * eigen.max() {
            // e.g. only floor, ceiling and the two side walls matched: no plane across the hall.
            let refused = matches!(epoch.displacement, Err(SolveError::UnderDetermined { .. }));
            prop_assert!(refused);
            return Ok(());
        }
        // The displacement's limit is on the weighted information: a direction only planes
        // measured far less well than the best observe may be refused, as weak, but what is
        // solved is exact, and the rotation always is.
        let Some(solved) = epoch.relative_pose() else {
            prop_assert!(epoch.rotation.is_ok());
            let refused = matches!(epoch.displacement, Err(SolveError::UnderDetermined { .. }));
            prop_assert!(refused, "{:?}", epoch.displacement);
            return Ok(());
        };
        prop_assert!(solved.rotation.angle_to(&c) < 1e-9);
        prop_assert!((solved.translation - dr).norm() < 1e-9);
    }
}

#[test]
fn a_moved_plane_biases_the_solution_until_it_is_excluded() {
    let room = hallway();
    let (i, j) = (
        pose([0.0; 3], [0.0; 3]),
        pose([0.1, 0.05, 0.0], [0.0, 0.0, 2.0]),
    );
    let mut odometer = odometer(exact());
    let previous = extract_at(&mut odometer, &room, i);
    // The front-left corner wall moves 5 cm towards the body between the epochs, like a door.
    let mut moved = room.clone();
    moved[6].rho -= 0.05;
    let current = extract_at(&mut odometer, &moved, j);
    let prior = prior_from(&i, &j, 0.01, 0.1);
    let epoch = odometer.solve(&previous, &current, &prior);
    let (_, dr) = relative(&i, &j);
    let door = epoch
        .matches
        .iter()
        .position(|m| room_plane_of(&room, &i, &previous.planes[m.previous], 1e-9) == Some(6))
        .expect("corner wall matched");
    let biased = epoch.displacement.as_ref().unwrap();
    assert!((biased.x - dr).norm() > 1e-3);
    let clean = odometer.resolve(&previous, &current, &epoch, &[door]);
    assert_eq!(clean.excluded, vec![door]);
    let solution = clean.displacement.as_ref().unwrap();
    assert!((solution.x - dr).norm() < 1e-9);
    assert!(!solution.system.plane_of_row.contains(&door));
    assert!(!clean
        .rotation
        .as_ref()
        .unwrap()
        .system
        .plane_of_row
        .contains(&door));
}

// ---- bad input ------------------------------------------------------------------------------

#[test]
fn an_empty_or_junk_scan_gives_no_planes_and_counts_the_drops() {
    let room = hallway();
    let [good, _] = scans_at(&room, Isometry3::identity());
    let mut junk = good.clone();
    for (k, r) in junk.ranges_m.iter_mut().enumerate() {
        *r = [f64::NAN, 0.0, 0.001, 100.0][k % 4];
    }
    let empty = Scan {
        ranges_m: Vec::new(),
        ..good.clone()
    };
    let mut odometer = odometer(OdometryConfig::default());
    for other in [&junk, &empty] {
        let epoch = odometer.extract([&good, other], 0.0, &|_| Isometry3::identity());
        assert!(epoch.planes.is_empty());
        assert_eq!(epoch.lines[1], 0);
        assert_eq!(epoch.readings[1], 0);
        assert_eq!(epoch.dropped[1].total() as usize, other.ranges_m.len());
        let solved = odometer.solve(&epoch, &epoch, &RelativePose::stationary(0.01, 0.1));
        assert!(solved.matches.is_empty());
        assert!(matches!(
            solved.displacement,
            Err(SolveError::UnderDetermined { .. })
        ));
    }
    let epoch = odometer.extract([&good, &junk], 0.0, &|_| Isometry3::identity());
    assert_eq!(epoch.dropped[1].not_a_number, 271);
    assert_eq!(epoch.dropped[1].zero, 270);
    assert_eq!(epoch.dropped[1].error_code, 270);
    assert_eq!(epoch.dropped[1].out_of_range, 270);
}

#[test]
fn config_defaults_roundtrip_and_unknown_keys_are_refused() {
    let config = OdometryConfig::default();
    let text = toml::to_string(&config).unwrap();
    assert_eq!(toml::from_str::<OdometryConfig>(&text).unwrap(), config);
    let partial: OdometryConfig = toml::from_str("range_sigma_m = 0.03").unwrap();
    assert_eq!(partial.range_sigma_m, 0.03);
    assert_eq!(partial.min_line_points, config.min_line_points);
    assert!(toml::from_str::<OdometryConfig>("range_sigma = 0.03").is_err());
    let bad = OdometryConfig {
        range_sigma_m: -1.0,
        ..config
    };
    let err = Odometer::new(
        [ScannerSetup {
            geometry: UTM,
            mount: Mount::identity(),
            range_sigma_m: None,
        }; 2],
        bad,
    )
    .unwrap_err();
    let message = err.to_string();
    assert!(
        message.contains("range_sigma_m") && !message.contains('\n'),
        "{message}"
    );
}

/// Wall lines are made while the filter's vertical is as vague as a start in motion leaves it,
/// and their planes carry that vagueness; level lines, whose normal is the vertical itself,
/// wait until it is known to 10 mrad.
#[test]
fn wall_lines_take_a_vague_vertical_into_their_planes_and_level_lines_wait_for_a_known_one() {
    let config = OdometryConfig::default();
    let vertical = |sigma_rad: f64| {
        Some(Vertical {
            down: Vector3::z(),
            sigma_rad,
        })
    };
    let walls = config.wall_line_parameters(vertical(0.05)).unwrap();
    assert!((walls.tilt_sigma_rad - 0.003f64.hypot(0.05)).abs() < 1e-12);
    let building = config.building_max_tilt_deg.to_radians();
    assert!((walls.building.max_tilt_rad - (building + 0.15)).abs() < 1e-12);
    assert!(config.level_line_parameters(vertical(0.05)).is_none());
    assert!(config.level_line_parameters(vertical(0.01)).is_some());
    assert!(config.wall_line_parameters(vertical(0.07)).is_none());
}

/// The paper's rig in `hallway()`: the scanner pitched 40 deg down draws the only line on the
/// floor (the one pitched 10 deg meets the end wall first), so the floor is a level line's
/// plane.
fn paper_rig_in_the_hallway() -> (Odometer, [Scan; 2]) {
    let mounts = [
        Mount::from_rpy_deg([0.0, -10.0, 0.0], [0.05, 0.0, -0.05]),
        Mount::from_rpy_deg([0.0, -40.0, 0.0], [0.05, 0.0, 0.05]),
    ];
    let setups = mounts.map(|mount| ScannerSetup {
        geometry: UTM,
        mount,
        range_sigma_m: None,
    });
    let scans =
        mounts.map(|mount| cast_scan(&hallway(), &UTM, &mount, &|_| Isometry3::identity(), 0.0));
    (
        Odometer::new(setups, OdometryConfig::default()).unwrap(),
        scans,
    )
}

#[test]
fn a_level_line_the_keyframe_refuses_stays_among_the_unscreened_planes() {
    let (mut odometer, [a, b]) = paper_rig_in_the_hallway();
    let vertical = Some(Vertical {
        down: Vector3::z(),
        sigma_rad: 0.002,
    });
    let floor = |plane: &Plane| plane.normal_assumed && plane.normal.z > 0.99;
    let mut extract = |admit: &mut dyn FnMut(&Plane) -> bool| {
        let mut out = EpochPlanes::default();
        let still = |_: f64| Isometry3::identity();
        odometer.extract_admitted_into([&a, &b], 0.0, &still, vertical, admit, &mut out);
        out
    };
    let admitted = extract(&mut |_| true);
    assert_eq!(admitted.planes.iter().filter(|p| floor(p)).count(), 1);
    assert_eq!(admitted.refused, 0);
    assert!(admitted.unscreened.is_empty());

    let refused = extract(&mut |plane| !floor(plane));
    assert!(!refused.planes.iter().any(floor));
    assert_eq!(refused.refused, 1);
    // The next epochs are confirmed against these: without the floor there, a floor refused
    // once would be refused for good.
    assert_eq!(
        by_geometry(&refused.unscreened),
        by_geometry(&admitted.planes)
    );
}

/// The planes without their ids, in order of distance and normal.
fn by_geometry(planes: &[Plane]) -> Vec<Plane> {
    let mut sorted: Vec<Plane> = planes.iter().map(|p| Plane { id: 0, ..*p }).collect();
    let key = |p: &Plane| [p.rho, p.normal.x, p.normal.y, p.normal.z];
    sorted.sort_by(|a, b| {
        key(a)
            .iter()
            .zip(key(b))
            .map(|(x, y)| x.total_cmp(&y))
            .find(|order| order.is_ne())
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    sorted
}
