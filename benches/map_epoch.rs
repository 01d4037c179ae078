//! One 10 Hz odometry epoch on the plane map (`odometry.method = "map"`): the hall walk with
//! the paper's rig, from 30 s in at the first epoch whose map holds 20 surfaces or more (30 at
//! most); the bench runs the IMU
//! samples of the tenth of a second up to the epoch and the two scans that close it (deskew,
//! lines, planes, association, the surfaces' test, the update of the state and the surfaces
//! together, placing and forgetting). Target: median under 200 us. `cargo bench --bench map_epoch`

use divan::{black_box, AllocProfiler, Bencher};
use ladar_odometer::fusion::{Fusion, FusionSettings};
use ladar_odometer::odometry::OdometryMethod;
use ladar_sim::{Scenario, SimEvent, Simulator};

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

/// Seconds flown at least before the epoch measured.
const WARM_S: f64 = 30.0;
/// Surfaces the map must hold before it.
const MIN_SURFACES: usize = 20;

/// The fusion `WARM_S` into the hall walk at 10 Hz, and the events of its next epoch.
fn warmed(method: OdometryMethod) -> (Fusion, Vec<SimEvent>) {
    let mut scenario = Scenario::builtin("hall-walk").unwrap();
    for scanner in &mut scenario.scanners {
        scanner.skip = 3;
    }
    let mut simulator = Simulator::new(&scenario).unwrap();
    let mut settings = FusionSettings::default();
    settings.filter.imu_mount_rpy_deg = simulator.imu().unwrap().mount_rpy_deg;
    settings.filter.stationary_start_s = 10.0;
    settings.fusion.epoch_rate_hz = 10.0;
    settings.odometry.method = method;
    let mut fusion = Fusion::new(settings, simulator.scanner_setups().unwrap()).unwrap();
    let mut probe: Option<Fusion> = None;
    let mut pending = Vec::new();
    while let Some(event) = simulator.next_event() {
        let mapping = method == OdometryMethod::Map;
        if event.time() < WARM_S || (mapping && fusion.mapped_surfaces() < MIN_SURFACES) {
            feed(&mut fusion, &event);
            continue;
        }
        let closed = feed(probe.get_or_insert_with(|| fusion.clone()), &event);
        pending.push(event);
        if closed {
            return (fusion, pending);
        }
    }
    panic!("no epoch after {WARM_S} s with {MIN_SURFACES} surfaces");
}

/// Pushes `event` into `fusion`; whether it closed an epoch.
fn feed(fusion: &mut Fusion, event: &SimEvent) -> bool {
    match event {
        SimEvent::Imu(sample) => {
            black_box(fusion.push_imu(*sample));
            false
        }
        SimEvent::Scan { scan, .. } => black_box(fusion.push_scan(scan.clone())).is_some(),
        SimEvent::Truth(_) => false,
    }
}

#[divan::bench(sample_count = 200, sample_size = 1)]
fn map_epoch_at_10_hz(bencher: Bencher) {
    let (fusion, events) = warmed(OdometryMethod::Map);
    let surfaces = fusion.mapped_surfaces();
    assert!((20..=40).contains(&surfaces), "{surfaces} surfaces mapped");
    run_epoch(bencher, &fusion, &events);
}

/// The same epoch with the paper's scan-to-scan pairs, for comparison: the two share the
/// deskew, line and plane extraction.
#[divan::bench(sample_count = 200, sample_size = 1)]
fn pairs_epoch_at_10_hz(bencher: Bencher) {
    let (fusion, events) = warmed(OdometryMethod::Pairs);
    run_epoch(bencher, &fusion, &events);
}

fn run_epoch(bencher: Bencher, fusion: &Fusion, events: &[SimEvent]) {
    bencher
        .with_inputs(|| fusion.clone())
        .bench_local_values(|mut fusion| {
            for event in events {
                feed(&mut fusion, event);
            }
        });
}
