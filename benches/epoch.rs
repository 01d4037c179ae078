//! One odometry epoch: two 1081-beam UTM-30LX scans of the hallway, taken while moving, through
//! deskew, lines, planes, matching and both solves (target: median under 100 us). The
//! allocation columns come from divan's counting allocator. `cargo bench --bench epoch`

use divan::{black_box, AllocProfiler, Bencher};
use ladar_odometer::odometry::synthetic::{cast_scan, crossed_mounts, hallway};
use ladar_odometer::odometry::{EpochPlanes, Odometer, OdometryConfig, RelativePose, Vertical};
use ladar_odometer::sensors::{Scan, ScannerGeometry, ScannerSetup};
use nalgebra::{Isometry3, Vector3};

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

const GEOMETRY: ScannerGeometry = ScannerGeometry::UTM_30LX;
/// Epochs ten times a second; each epoch's reference time is the middle of its scans.
const EPOCH_PERIOD: f64 = 0.1;

/// Body pose in the world at time t: walking pace with a slow turn.
fn body_pose(t: f64) -> Isometry3<f64> {
    Isometry3::new(
        Vector3::new(0.5, 0.2, 0.05) * t,
        Vector3::new(0.02, -0.01, 0.2) * t,
    )
}

struct Epoch {
    scans: [Scan; 2],
    t_ref: f64,
}

fn epoch_at(t0: f64) -> Epoch {
    let scans =
        crossed_mounts().map(|mount| cast_scan(&hallway(), &GEOMETRY, &mount, &body_pose, t0));
    Epoch {
        scans,
        t_ref: t0 + GEOMETRY.scan_period() / 2.0,
    }
}

fn extract(odometer: &mut Odometer, epoch: &Epoch, out: &mut EpochPlanes) {
    let reference = body_pose(epoch.t_ref).inverse();
    let pose_at = |t: f64| reference * body_pose(t);
    let [a, b] = &epoch.scans;
    odometer.extract_into([a, b], epoch.t_ref, &pose_at, out);
}

fn setup() -> (Odometer, Epoch, Epoch, RelativePose) {
    let setups = crossed_mounts().map(|mount| ScannerSetup {
        geometry: GEOMETRY,
        mount,
        range_sigma_m: None,
    });
    let odometer = Odometer::new(setups, OdometryConfig::default()).unwrap();
    let (i, j) = (epoch_at(0.0), epoch_at(EPOCH_PERIOD));
    let between = body_pose(i.t_ref).inverse() * body_pose(j.t_ref);
    let prior = RelativePose {
        rotation: between.rotation,
        translation: between.translation.vector,
        ..RelativePose::stationary(0.01, 0.05)
    };
    (odometer, i, j, prior)
}

#[divan::bench]
fn full_epoch(bencher: Bencher) {
    let (mut odometer, i, j, prior) = setup();
    let mut previous = EpochPlanes::default();
    let mut current = EpochPlanes::default();
    extract(&mut odometer, &i, &mut previous);
    extract(&mut odometer, &j, &mut current);
    let solved = odometer.solve(&previous, &current, &prior);
    assert!(
        (6..=9).contains(&current.planes.len()),
        "{} planes",
        current.planes.len()
    );
    assert!(solved.relative_pose().is_some(), "{solved:?}");
    bencher.bench_local(|| {
        extract(&mut odometer, &j, &mut current);
        black_box(odometer.solve(&previous, &current, &prior))
    });
}

#[divan::bench]
fn extract_planes_of_both_scans(bencher: Bencher) {
    let (mut odometer, _, j, _) = setup();
    let mut current = EpochPlanes::default();
    extract(&mut odometer, &j, &mut current);
    bencher.bench_local(|| {
        extract(&mut odometer, &j, &mut current);
        black_box(current.planes.len())
    });
}

/// As the fusion extracts once the filter knows its vertical: single lines (level floors,
/// plumb walls) also make planes, at the cost of a pass over the other scan's beams for each
/// free level line.
#[divan::bench]
fn extract_planes_in_a_building(bencher: Bencher) {
    let (mut odometer, _, j, _) = setup();
    let reference = body_pose(j.t_ref).inverse();
    let pose_at = |t: f64| reference * body_pose(t);
    let vertical = Vertical {
        down: body_pose(j.t_ref)
            .rotation
            .inverse_transform_vector(&Vector3::z()),
        sigma_rad: 0.002,
    };
    let mut current = EpochPlanes::default();
    let [a, b] = &j.scans;
    bencher.bench_local(|| {
        odometer.extract_with_vertical_into([a, b], j.t_ref, &pose_at, vertical, &mut current);
        black_box(current.planes.len())
    });
}

#[divan::bench]
fn match_and_solve(bencher: Bencher) {
    let (mut odometer, i, j, prior) = setup();
    let mut previous = EpochPlanes::default();
    let mut current = EpochPlanes::default();
    extract(&mut odometer, &i, &mut previous);
    extract(&mut odometer, &j, &mut current);
    bencher.bench_local(|| black_box(odometer.solve(&previous, &current, &prior)));
}
