//! The report's reading of `epochs.jsonl`: what each epoch saw, tested and did. It reads the
//! JSON lines rather than the fusion's types, so that it draws what a user's file holds.

use super::chart::{
    Axes, ChartError, Mark, RGBColor, Series, BLUE, GREEN, GREY, ORANGE, PURPLE, RED,
};
use super::html::Page;
use nalgebra::{UnitQuaternion, Vector3};
use serde_json::Value;
use std::collections::BTreeMap;

/// Half the length of a wall drawn in the top view, m: a plane has no edges, so the drawing
/// shows where it is and which way it runs, no more.
const WALL_HALF_LENGTH_M: f64 = 2.5;
/// A plane whose normal is this close to vertical is a floor or a ceiling, not a wall.
const HORIZONTAL_NORMAL_Z: f64 = 0.7;

/// Points of a chart, (x, y).
type Points = Vec<(f64, f64)>;
/// Which of an epoch's tests a chart draws.
type TestOf = fn(&EpochRow) -> Option<Test>;
/// Which of an epoch's counts a chart draws.
type CountOf = fn(&EpochRow) -> usize;

/// One solve's test: the statistic, its threshold, and whether it fired.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Test {
    chi_square: f64,
    threshold: f64,
    detected: bool,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct EpochRow {
    pub t: f64,
    outcome: String,
    reason: Option<String>,
    planes: usize,
    matched: usize,
    used: usize,
    excluded: Vec<usize>,
    rotation: Option<Test>,
    displacement: Option<Test>,
    /// Each plane's unit normal (body axes) and distance, by id.
    geometry: Vec<(Vector3<f64>, f64)>,
}

impl EpochRow {
    fn parse(line: &Value) -> Option<Self> {
        let count = |key: &str| line[key].as_u64().unwrap_or(0) as usize;
        Some(Self {
            t: line["t"].as_f64()?,
            outcome: line["outcome"].as_str().unwrap_or("unknown").to_owned(),
            reason: line["reason"].as_str().map(str::to_owned),
            planes: count("planes"),
            matched: count("matched"),
            used: count("used"),
            excluded: line["excluded_planes"]
                .as_array()
                .map_or_else(Vec::new, |ids| {
                    ids.iter()
                        .filter_map(Value::as_u64)
                        .map(|id| id as usize)
                        .collect()
                }),
            rotation: test(&line["integrity"]["rotation"]["test"]),
            displacement: test(&line["integrity"]["displacement"]["test"]),
            geometry: line["plane_geometry"]
                .as_array()
                .map_or_else(Vec::new, |planes| planes.iter().filter_map(plane).collect()),
        })
    }

    /// The walls of this epoch at the platform's height, in (east, north) points: used, then
    /// excluded. `attitude` and `position` are the platform's at the epoch.
    pub(crate) fn walls(
        &self,
        attitude: &UnitQuaternion<f64>,
        position: &Vector3<f64>,
    ) -> (Points, Points) {
        let (mut used, mut excluded) = (Vec::new(), Vec::new());
        for (id, (normal, rho)) in self.geometry.iter().enumerate() {
            let n = attitude * normal;
            let horizontal = Vector3::new(n.x, n.y, 0.0);
            if n.z.abs() > HORIZONTAL_NORMAL_Z || horizontal.norm() < 1e-6 {
                continue;
            }
            // The plane n . (x - p) = rho cut at the platform's height: n_h . d = rho.
            let foot = position + horizontal * (rho / horizontal.norm_squared());
            let along = Vector3::new(-horizontal.y, horizontal.x, 0.0).normalize();
            let target = if self.excluded.contains(&id) {
                &mut excluded
            } else {
                &mut used
            };
            let steps = (2.0 * WALL_HALF_LENGTH_M / 0.1) as i32;
            target.extend((0..=steps).map(|k| {
                let point = foot + along * (f64::from(k) * 0.1 - WALL_HALF_LENGTH_M);
                (point.y, point.x)
            }));
        }
        (used, excluded)
    }
}

fn test(value: &Value) -> Option<Test> {
    Some(Test {
        chi_square: value["chi_square"].as_f64()?,
        threshold: value["chi_square_threshold"].as_f64()?,
        detected: value["detected"].as_bool().unwrap_or(false),
    })
}

fn plane(value: &Value) -> Option<(Vector3<f64>, f64)> {
    let normal = value["normal"].as_array()?;
    let component = |i: usize| normal.get(i).and_then(Value::as_f64);
    Some((
        Vector3::new(component(0)?, component(1)?, component(2)?),
        value["rho"].as_f64()?,
    ))
}

/// All epochs of a run.
pub(crate) struct EpochView {
    rows: Vec<EpochRow>,
}

/// Outcomes in the order the charts stack them, worst at the top.
const OUTCOMES: [(&str, RGBColor); 5] = [
    ("reference", GREY),
    ("fused", GREEN),
    ("not_fused", ORANGE),
    ("rejected_by_gate", PURPLE),
    ("update_failed", RED),
];

impl EpochView {
    pub(crate) fn new(lines: &[Value]) -> Self {
        Self {
            rows: lines.iter().filter_map(EpochRow::parse).collect(),
        }
    }

    /// The epoch with the most planes used (the first of equals): the one worth drawing.
    pub(crate) fn showcase(&self) -> Option<&EpochRow> {
        self.rows
            .iter()
            .filter(|row| !row.geometry.is_empty())
            .rev()
            .max_by_key(|row| row.used)
    }

    pub(crate) fn integrity_section(&self, page: &mut Page) -> Result<(), ChartError> {
        page.section(
            "Integrity",
            "The parity-space test statistic of each solve against its threshold (paper Fig. 10). \
             Red marks an epoch whose test fired; the monitor then excluded planes or refused the \
             epoch.",
        );
        let solves: [(&str, TestOf); 2] = [
            ("rotation", |row| row.rotation),
            ("displacement", |row| row.displacement),
        ];
        for (name, of) in solves {
            let tests: Vec<(f64, Test)> = self
                .rows
                .iter()
                .filter_map(|row| of(row).map(|test| (row.t, test)))
                .collect();
            let points =
                |pick: fn(&Test) -> f64| tests.iter().map(|(t, x)| (*t, pick(x))).collect();
            let fired = tests
                .iter()
                .filter(|(_, test)| test.detected)
                .map(|(t, test)| (*t, test.chi_square))
                .collect();
            let series = [
                Series::new("statistic", BLUE, Mark::Line).with_points(points(|x| x.chi_square)),
                Series::new("threshold", GREY, Mark::Bound).with_points(points(|x| x.threshold)),
                Series::new("fired", RED, Mark::Dots).with_points(fired),
            ];
            let axes = Axes {
                log_y: true,
                ..Axes::over_time(format!("{name} test"), "chi-square")
            };
            page.chart(&format!("integrity-{name}"), &axes, &series)?;
        }
        Ok(())
    }

    pub(crate) fn planes_section(&self, page: &mut Page) -> Result<(), ChartError> {
        page.section(
            "Planes and epoch outcomes",
            "Planes built per epoch, matched with the previous epoch, used in the fused solves and \
             excluded by the integrity monitor; then how each epoch ended.",
        );
        let counts: [(&str, RGBColor, CountOf); 4] = [
            ("seen", GREY, |row| row.planes),
            ("matched", BLUE, |row| row.matched),
            ("used", GREEN, |row| row.used),
            ("excluded", RED, |row| row.excluded.len()),
        ];
        let series: Vec<Series> = counts
            .iter()
            .map(|(name, color, of)| {
                let points = self
                    .rows
                    .iter()
                    .map(|row| (row.t, of(row) as f64))
                    .collect();
                Series::new(*name, *color, Mark::Line).with_points(points)
            })
            .collect();
        page.chart(
            "planes",
            &Axes::over_time("planes per epoch", "planes"),
            &series,
        )?;
        let outcomes: Vec<Series> = OUTCOMES
            .iter()
            .enumerate()
            .map(|(level, (name, color))| {
                let points = self
                    .rows
                    .iter()
                    .filter(|row| row.outcome == *name)
                    .map(|row| (row.t, level as f64))
                    .collect();
                Series::new(*name, *color, Mark::Dots).with_points(points)
            })
            .collect();
        let axes = Axes::over_time("epoch outcome", "0 reference ... 4 update failed");
        page.chart("outcomes", &axes, &outcomes)?;
        page.table(&["outcome", "reason", "epochs"], &self.outcome_counts());
        Ok(())
    }

    /// Epochs per outcome and reason, most frequent first.
    fn outcome_counts(&self) -> Vec<Vec<String>> {
        let mut counts: BTreeMap<(String, String), usize> = BTreeMap::new();
        for row in &self.rows {
            let reason = row.reason.clone().unwrap_or_default();
            *counts.entry((row.outcome.clone(), reason)).or_default() += 1;
        }
        let mut rows: Vec<_> = counts.into_iter().collect();
        rows.sort_by_key(|row| std::cmp::Reverse(row.1));
        rows.into_iter()
            .map(|((outcome, reason), n)| vec![outcome, reason, n.to_string()])
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn epoch(t: f64, used: usize) -> Value {
        json!({
            "t": t, "outcome": "fused", "planes": 5, "matched": 4, "used": used,
            "excluded_planes": [1],
            "integrity": {"rotation": {"test": {"chi_square": 3.0, "chi_square_threshold": 9.0, "detected": false}}},
            "plane_geometry": [
                {"normal": [1.0, 0.0, 0.0], "rho": 2.0},
                {"normal": [0.0, 1.0, 0.0], "rho": 1.5},
                {"normal": [0.0, 0.0, 1.0], "rho": 1.0}
            ]
        })
    }

    #[test]
    fn walls_are_cut_at_the_platform_height_and_floors_left_out() {
        let view = EpochView::new(&[epoch(1.0, 3), epoch(2.0, 4)]);
        let row = view.showcase().unwrap();
        assert_eq!(row.t, 2.0);
        let heading_east = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let (used, excluded) = row.walls(&heading_east, &Vector3::new(10.0, 20.0, -1.0));
        // Forward is east: the wall 2 m ahead runs north-south at east = 22.
        assert!(
            used.iter().all(|(east, _)| (east - 22.0).abs() < 1e-9),
            "{used:?}"
        );
        // The right-hand wall (south, 1.5 m) is the excluded one: north = 8.5.
        assert!(
            excluded.iter().all(|(_, north)| (north - 8.5).abs() < 1e-9),
            "{excluded:?}"
        );
        assert!(!used.is_empty() && !excluded.is_empty());
    }

    #[test]
    fn a_line_without_time_is_skipped_and_missing_fields_are_zero() {
        let view = EpochView::new(&[json!({"outcome": "fused"}), json!({"t": 1.0})]);
        assert_eq!(view.rows.len(), 1);
        assert_eq!(view.rows[0].planes, 0);
        assert_eq!(view.rows[0].rotation, None);
    }
}
