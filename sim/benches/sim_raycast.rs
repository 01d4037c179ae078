//! Ray-casting cost of one simulated revolution.
use ladar_sim::{Scenario, Simulator, Trajectory};

fn main() {
    divan::main();
}

fn still(mut scenario: Scenario) -> Scenario {
    scenario.trajectory = Trajectory::Stationary {
        position_m: [0.0; 3],
        rpy_deg: [0.0, -10.0, 0.0],
    };
    scenario
}

fn hallway() -> Scenario {
    Scenario::builtin("hallway-hover").expect("built-in scenario")
}

fn bench_scans(bencher: divan::Bencher, scenario: Scenario, period: f64) {
    let mut sim = Simulator::new(&scenario).expect("valid scenario");
    let mut t0 = 100.0;
    bencher.bench_local(|| {
        t0 += period;
        divan::black_box(sim.scan(0, t0))
    });
}

#[divan::bench]
fn hallway_hover_utm_scan(bencher: divan::Bencher) {
    bench_scans(bencher, hallway(), 0.025);
}

#[divan::bench]
fn hallway_still_utm_scan(bencher: divan::Bencher) {
    bench_scans(bencher, still(hallway()), 0.025);
}

#[divan::bench]
fn ten_static_patches_utm_scan(bencher: divan::Bencher) {
    let mut scenario = still(hallway());
    scenario.scene.patches.retain(|p| p.motion.is_static());
    scenario.scene.patches.truncate(10);
    bench_scans(bencher, scenario, 0.025);
}

#[divan::bench]
fn office_door_urg_scan(bencher: divan::Bencher) {
    let scenario = Scenario::builtin("office-door").expect("built-in scenario");
    bench_scans(bencher, scenario, 0.1);
}

#[divan::bench(sample_count = 20)]
fn hallway_hover_one_second_of_events(bencher: divan::Bencher) {
    let scenario = hallway();
    bencher.bench_local(|| {
        Simulator::new(&scenario)
            .expect("valid scenario")
            .events()
            .take_while(|e| e.time() <= 1.0)
            .count()
    });
}
