//! The report's drawing of the plane map (`odometry.method = "map"`): every surface the run
//! mapped, from above, where it was seen, coloured by how many lines it gave the filter. It
//! reads `epochs.jsonl`'s `map.surfaces`, the last record of each surface.

use super::chart::{Axes, ChartError, Mark, RGBColor, Series, BLUE, GREEN, GREY, ORANGE};
use super::html::Page;
use nalgebra::Vector3;
use serde_json::Value;
use std::collections::BTreeMap;

/// A surface whose normal is this close to vertical is a floor or a ceiling: not drawn.
const HORIZONTAL_NORMAL_Z: f64 = 0.7;

/// Colours by lines fused, fewest first: the bucket is the first whose bound the count is under.
const BY_LINES: [(&str, u64, RGBColor); 4] = [
    ("no line fused", 1, GREY),
    ("1-9 lines", 10, ORANGE),
    ("10-99 lines", 100, BLUE),
    ("100 lines or more", u64::MAX, GREEN),
];

/// A mapped wall as the run last recorded it.
#[derive(Debug, Clone, PartialEq)]
struct MappedWall {
    from: Vector3<f64>,
    to: Vector3<f64>,
    lines_fused: u64,
}

impl MappedWall {
    fn parse(surface: &Value) -> Option<(u64, Self)> {
        let vector = |key: &str| -> Option<Vector3<f64>> {
            let values: Vec<f64> = surface[key]
                .as_array()?
                .iter()
                .map(Value::as_f64)
                .collect::<Option<_>>()?;
            let v = Vector3::from_column_slice(values.get(..3)?);
            v.iter().all(|x| x.is_finite()).then_some(v)
        };
        let normal = vector("normal")?;
        let wall = Self {
            from: vector("seen_from")?,
            to: vector("seen_to")?,
            lines_fused: surface["lines_fused"].as_u64()?,
        };
        (normal.z.abs() < HORIZONTAL_NORMAL_Z).then_some((surface["id"].as_u64()?, wall))
    }
}

/// Every wall the run mapped, by id, as last recorded.
fn mapped_walls(epochs: &[Value]) -> BTreeMap<u64, MappedWall> {
    epochs
        .iter()
        .filter_map(|epoch| epoch["map"]["surfaces"].as_array())
        .flatten()
        .filter_map(MappedWall::parse)
        .collect()
}

/// The plane map from above, east to the right and north up, with `track` (east, north) beside
/// it, every position moved by `offset` as the top view's are; nothing when the run kept no
/// map.
pub(crate) fn plane_map_section(
    page: &mut Page,
    epochs: &[Value],
    track: Vec<(f64, f64)>,
    offset: &Vector3<f64>,
) -> Result<(), ChartError> {
    let walls = mapped_walls(epochs);
    if walls.is_empty() {
        return Ok(());
    }
    page.section(
        "Plane map",
        "Every wall the plane map held (odometry.method = \"map\"), from above, where the \
         platform saw it, coloured by how many lines it gave the filter; floors and ceilings \
         are left out. The estimated track runs through it.",
    );
    let mut series = vec![Series::new("estimate", GREY, Mark::Line).with_points(track)];
    for (k, (name, _, color)) in BY_LINES.iter().enumerate() {
        let segments = walls
            .values()
            .filter(|wall| bucket(wall.lines_fused) == k)
            .flat_map(|wall| [wall.from + offset, wall.to + offset])
            .map(|p| (p.y, p.x))
            .collect();
        series.push(Series::new(*name, *color, Mark::Segments).with_points(segments));
    }
    let axes = Axes {
        title: format!("{} walls mapped, east-north", walls.len()),
        x_label: "east (m)".into(),
        y_label: "north (m)".into(),
        log_y: false,
        equal: true,
    };
    page.chart("plane-map", &axes, &series)
}

fn bucket(lines_fused: u64) -> usize {
    BY_LINES
        .iter()
        .position(|(_, under, _)| lines_fused < *under)
        .unwrap_or(BY_LINES.len() - 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn surface(id: u64, normal: [f64; 3], lines_fused: u64) -> Value {
        json!({
            "id": id, "normal": normal, "distance": 2.0, "lines_fused": lines_fused,
            "seen_from": [2.0, -1.0, -0.5], "seen_to": [2.0, 1.0, 0.5],
        })
    }

    #[test]
    fn each_wall_is_drawn_once_as_last_seen_and_floors_are_left_out() {
        let epochs = [
            json!({"t": 1.0, "map": {"surfaces": [surface(3, [1.0, 0.0, 0.0], 4)]}}),
            json!({"t": 2.0, "outcome": "fused"}),
            json!({"t": 3.0, "map": {"surfaces": [
                surface(3, [1.0, 0.0, 0.0], 40),
                surface(5, [0.0, 0.0, 1.0], 400),
            ]}}),
        ];
        let walls = mapped_walls(&epochs);
        assert_eq!(walls.len(), 1);
        assert_eq!(walls[&3].lines_fused, 40);
        assert_eq!(bucket(0), 0);
        assert_eq!(bucket(9), 1);
        assert_eq!(bucket(40), 2);
        assert_eq!(bucket(100), 3);
    }

    #[test]
    fn a_run_without_a_map_draws_no_section() {
        let mut page = Page::new("no map");
        let epochs = [json!({"t": 1.0, "outcome": "fused"})];
        plane_map_section(&mut page, &epochs, vec![(0.0, 0.0)], &Vector3::zeros()).unwrap();
        assert!(!page.finish().contains("plane-map"));
    }
}
