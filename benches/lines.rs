//! Line extraction of one 1081-beam UTM-30LX scan in the hallway (target: under 30 us, no
//! allocation once the buffers have grown). `cargo bench --bench lines`

use divan::{black_box, AllocProfiler, Bencher};
use ladar_odometer::odometry::deskew::Deskewer;
use ladar_odometer::odometry::lines::{LineExtractor, LineParameters};
use ladar_odometer::odometry::synthetic::{cast_scan, crossed_mounts, hallway};
use ladar_odometer::sensors::ScannerGeometry;
use nalgebra::Isometry3;

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

#[divan::bench]
fn extract_lines_of_one_scan(bencher: Bencher) {
    let geometry = ScannerGeometry::UTM_30LX;
    let mount = crossed_mounts()[0];
    let scan = cast_scan(
        &hallway(),
        &geometry,
        &mount,
        &|_| Isometry3::identity(),
        0.0,
    );
    let mut beams = Vec::new();
    Deskewer::default().deskew(
        &scan,
        &geometry,
        &mount,
        &|_| Isometry3::identity(),
        &mut beams,
    );
    let parameters = LineParameters {
        breakpoint_lambda_rad: 10f64.to_radians(),
        breakpoint_noise_m: 0.03,
        split_distance_m: 0.05,
        min_points: 10,
        min_length_m: 0.3,
    };
    let mut extractor = LineExtractor::default();
    let mut segments = Vec::new();
    extractor.extract(&beams, &parameters, &mut segments);
    assert!(
        segments.len() >= 5,
        "hallway scan gave {} lines",
        segments.len()
    );
    bencher.bench_local(|| {
        extractor.extract(black_box(&beams), &parameters, &mut segments);
        black_box(segments.len())
    });
}
