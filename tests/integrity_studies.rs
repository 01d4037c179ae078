//! Seeded Monte Carlo studies of the plane sigmas and the integrity tests (small N in debug);
//! the figures of docs/figures.md come from the `#[ignore]`d runs in release.

use ladar_odometer::study::paper_sigma_table;

#[test]
#[ignore]
fn print_sigma_table() {
    let runs = std::env::var("RUNS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(1000);
    let table = paper_sigma_table(runs, 1).unwrap();
    println!("{table}");
}

#[test]
#[ignore]
fn print_integrity_check() {
    let runs = std::env::var("RUNS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(1000);
    let scenario = std::env::var("SCENARIO").unwrap_or("paper-sim".into());
    let report =
        ladar_odometer::study::integrity_check(&ladar_odometer::study::IntegrityCheckArgs {
            scenario,
            runs,
            ..Default::default()
        })
        .unwrap();
    println!("{report}");
}

#[test]
#[ignore]
fn print_paper_figures() {
    let runs = std::env::var("RUNS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(1000);
    println!("{}", ladar_odometer::study::paper_figures(runs, 1).unwrap());
}
