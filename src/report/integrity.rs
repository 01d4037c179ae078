//! `integrity-check --report FILE`: the study as a page. The displacement test statistic of the
//! fault-free pairs and of pairs with a plane moved (paper Figs. 6 and 7), the detection rate
//! against bias size, and the per-plane figures that say whether the predicted noise is right.

use super::chart::{Axes, ChartError, Mark, Series, BLUE, GREY, ORANGE, RED};
use super::html::Page;
use crate::integrity_check::{DetectionRow, IntegrityCheckReport};

/// Histogram bins of the statistic over its threshold, from 0 to `HISTOGRAM_TOP`; larger
/// values fall in the last bin, so that a fault's long tail still counts.
const HISTOGRAM_BINS: usize = 40;
const HISTOGRAM_TOP: f64 = 4.0;

pub fn render(report: &IntegrityCheckReport) -> Result<String, ChartError> {
    let mut page = Page::new(&format!(
        "ladar-odometer integrity check: {}",
        report.scenario
    ));
    summary(&mut page, report);
    histograms(&mut page, report)?;
    detection(&mut page, "translation", "bias (m)", &report.translation)?;
    detection(&mut page, "rotation", "bias (deg)", &report.rotation)?;
    planes(&mut page, report);
    Ok(page.finish())
}

fn summary(page: &mut Page, report: &IntegrityCheckReport) {
    page.section(
        "Summary",
        "Pairs of epochs simulated on the scenario, the false alarms measured against the \
         configured probability, and the detection of a plane moved or turned between the two \
         epochs.",
    );
    let alarms = &report.false_alarms;
    let rows = vec![
        vec!["pairs per case".into(), report.runs.to_string()],
        vec!["seed".into(), report.seed.to_string()],
        vec![
            "false alarms (measured / configured)".into(),
            format!("{:.4} / {:.4}", alarms.rate, alarms.configured),
        ],
        vec![
            "untestable fault-free pairs".into(),
            alarms.untestable.to_string(),
        ],
        vec![
            "missed-detection probability".into(),
            format!("{}", report.missed_detection_probability),
        ],
    ];
    page.table(&["", "value"], &rows);
}

fn histograms(page: &mut Page, report: &IntegrityCheckReport) -> Result<(), ChartError> {
    let statistics = &report.statistics;
    page.section(
        "Test statistic with and without a fault",
        &format!(
            "The displacement test's statistic over its threshold, every matched plane in the \
             solve, for the fault-free pairs (paper Fig. 6) and for pairs with one plane moved \
             by {} m (Fig. 7). The test fires right of 1; values beyond {HISTOGRAM_TOP} are \
             counted in the last bin.",
            statistics.bias_m
        ),
    );
    let clean = histogram(&statistics.fault_free);
    let biased = histogram(&statistics.biased);
    let top = clean.iter().chain(&biased).map(|p| p.1).fold(0.0, f64::max);
    let series = [
        Series::new("fault-free", BLUE, Mark::Line).with_points(clean),
        Series::new(
            format!("plane moved {} m", statistics.bias_m),
            RED,
            Mark::Line,
        )
        .with_points(biased),
        Series::new("threshold", GREY, Mark::Bound).with_points(vec![(1.0, 0.0), (1.0, top)]),
    ];
    let axes = Axes {
        x_label: "statistic / threshold".into(),
        ..Axes::over_time("displacement test statistic", "share of pairs")
    };
    page.chart("statistic-histogram", &axes, &series)
}

/// Share of `values` per bin, as a step line: (left edge, share), (right edge, share), ...
fn histogram(values: &[f64]) -> Vec<(f64, f64)> {
    if values.is_empty() {
        return Vec::new();
    }
    let width = HISTOGRAM_TOP / HISTOGRAM_BINS as f64;
    let mut counts = [0usize; HISTOGRAM_BINS];
    for value in values.iter().filter(|v| v.is_finite()) {
        let bin = ((value / width).max(0.0) as usize).min(HISTOGRAM_BINS - 1);
        counts[bin] += 1;
    }
    counts
        .iter()
        .enumerate()
        .flat_map(|(bin, &n)| {
            let share = n as f64 / values.len() as f64;
            let left = bin as f64 * width;
            [(left, share), (left + width, share)]
        })
        .collect()
}

fn detection(
    page: &mut Page,
    kind: &str,
    unit: &str,
    rows: &[DetectionRow],
) -> Result<(), ChartError> {
    page.section(
        &format!("Detection against {kind} bias"),
        "The share of faulty pairs the test flagged, and the share in which exactly the moved \
         plane was excluded.",
    );
    let share = |n: usize, row: &DetectionRow| n as f64 / row.pairs.max(1) as f64;
    let detected = rows.iter().map(|r| (r.bias, r.rate)).collect();
    let excluded = rows
        .iter()
        .map(|r| (r.bias, share(r.excluded_right_plane, r)))
        .collect();
    let series = [
        Series::new("detected", BLUE, Mark::Line).with_points(detected),
        Series::new("right plane excluded", ORANGE, Mark::Line).with_points(excluded),
    ];
    let axes = Axes {
        x_label: unit.into(),
        ..Axes::over_time(format!("detection rate, {kind}"), "share of pairs")
    };
    page.chart(&format!("detection-{kind}"), &axes, &series)
}

fn planes(page: &mut Page, report: &IntegrityCheckReport) {
    page.section(
        "Planes",
        "Per plane: how often it was matched, and the displacement rows' predicted against \
         measured sigma (equal when the noise model is right), with the mean minimum detectable \
         bias; an infinite MDB means the plane alone observes a direction, so no test can catch \
         a fault on it.",
    );
    let rows: Vec<Vec<String>> = report
        .planes
        .iter()
        .map(|p| {
            vec![
                p.plane.clone(),
                format!("{:.2}", p.seen),
                format!("{:.4}", p.displacement.predicted_sigma),
                format!("{:.4}", p.displacement.measured_sigma),
                format!("{:.3}", p.displacement.mdb),
            ]
        })
        .collect();
    page.table(
        &[
            "plane",
            "seen",
            "predicted sigma (m)",
            "measured sigma (m)",
            "MDB (m)",
        ],
        &rows,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_shares_sum_to_one_and_the_tail_lands_in_the_last_bin() {
        let values = [0.05, 0.5, 0.5, 100.0];
        let steps = histogram(&values);
        let total: f64 = steps.iter().step_by(2).map(|p| p.1).sum();
        assert!((total - 1.0).abs() < 1e-12);
        assert_eq!(steps.last().unwrap().1, 0.25);
        assert_eq!(steps[0].1, 0.25);
    }
}
