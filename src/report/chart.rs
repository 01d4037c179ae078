//! SVG charts for the report, drawn with plotters into strings so that the HTML carries them
//! inline and needs nothing beside it.

use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::Shift;
use plotters::prelude::*;
pub(crate) use plotters::style::RGBColor;

/// Chart size in SVG pixels: wide enough for a 500 s run to show single epochs.
const WIDTH: u32 = 960;
const HEIGHT: u32 = 280;
/// More points than this per series only make the file heavier: a screen has fewer columns.
const MAX_POINTS: usize = 2 * WIDTH as usize;

pub(crate) const BLUE: RGBColor = RGBColor(31, 119, 180);
pub(crate) const ORANGE: RGBColor = RGBColor(255, 127, 14);
pub(crate) const GREEN: RGBColor = RGBColor(44, 160, 44);
pub(crate) const RED: RGBColor = RGBColor(214, 39, 40);
pub(crate) const PURPLE: RGBColor = RGBColor(148, 103, 189);
pub(crate) const GREY: RGBColor = RGBColor(127, 127, 127);

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Mark {
    Line,
    /// A thin line for bounds such as +-3 sigma.
    Bound,
    Dots,
    /// Separate segments: each two points in turn are one.
    Segments,
}

#[derive(Debug, Clone)]
pub(crate) struct Series {
    pub name: String,
    pub color: RGBColor,
    pub mark: Mark,
    pub points: Vec<(f64, f64)>,
}

impl Series {
    pub(crate) fn new(name: impl Into<String>, color: RGBColor, mark: Mark) -> Self {
        Self {
            name: name.into(),
            color,
            mark,
            points: Vec::new(),
        }
    }

    pub(crate) fn with_points(mut self, points: Vec<(f64, f64)>) -> Self {
        self.points = points;
        self
    }
}

/// What the axes show.
#[derive(Debug, Clone)]
pub(crate) struct Axes {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    /// Logarithmic y axis (only positive values are drawn).
    pub log_y: bool,
    /// Same scale on both axes, for maps.
    pub equal: bool,
}

impl Axes {
    pub(crate) fn over_time(title: impl Into<String>, y_label: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            x_label: "time (s)".into(),
            y_label: y_label.into(),
            log_y: false,
            equal: false,
        }
    }
}

#[derive(Debug, thiserror::Error)]
#[error("cannot draw the chart \"{chart}\": {reason}")]
pub struct ChartError {
    chart: String,
    reason: String,
}

/// One chart as an SVG document, or `None` when no series has a point to draw.
pub(crate) fn svg(axes: &Axes, series: &[Series]) -> Result<Option<String>, ChartError> {
    let drawable: Vec<Series> = series
        .iter()
        .map(|s| drawable(s, axes.log_y))
        .filter(|s| !s.points.is_empty())
        .collect();
    let Some((x_range, y_range)) = extent(&drawable, axes) else {
        return Ok(None);
    };
    let mut text = String::new();
    draw(&mut text, axes, &drawable, x_range, y_range).map_err(|reason| ChartError {
        chart: axes.title.clone(),
        reason,
    })?;
    Ok(Some(text))
}

fn draw(
    text: &mut String,
    axes: &Axes,
    series: &[Series],
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
) -> Result<(), String> {
    let height = if axes.equal { 2 * HEIGHT } else { HEIGHT };
    let root = SVGBackend::with_string(text, (WIDTH, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    if axes.log_y {
        let chart = builder(&root, axes)
            .build_cartesian_2d(x, y.log_scale())
            .map_err(|e| e.to_string())?;
        plot(chart, axes, series)?;
    } else {
        let chart = builder(&root, axes)
            .build_cartesian_2d(x, y)
            .map_err(|e| e.to_string())?;
        plot(chart, axes, series)?;
    }
    root.present().map_err(|e| e.to_string())
}

fn builder<'a, 'b>(
    root: &'a DrawingArea<SVGBackend<'b>, Shift>,
    axes: &Axes,
) -> ChartBuilder<'a, 'b, SVGBackend<'b>> {
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(&axes.title, ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(64);
    builder
}

fn plot<'b, X, Y>(
    mut chart: ChartContext<'b, SVGBackend<'b>, Cartesian2d<X, Y>>,
    axes: &Axes,
    series: &[Series],
) -> Result<(), String>
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .x_desc(&axes.x_label)
        .y_desc(&axes.y_label)
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(|e| e.to_string())?;
    for s in series {
        let color = s.color;
        let drawn = match s.mark {
            Mark::Line => {
                chart.draw_series(LineSeries::new(s.points.clone(), color.stroke_width(1)))
            }
            Mark::Bound => chart.draw_series(LineSeries::new(
                s.points.clone(),
                color.mix(0.5).stroke_width(1),
            )),
            Mark::Dots => {
                chart.draw_series(s.points.iter().map(|&p| Circle::new(p, 2, color.filled())))
            }
            Mark::Segments => chart.draw_series(
                s.points
                    .chunks_exact(2)
                    .map(|ends| PathElement::new(ends.to_vec(), color.stroke_width(2))),
            ),
        }
        .map_err(|e| e.to_string())?;
        drawn.label(s.name.as_str()).legend(move |(x, y)| {
            PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
        });
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())
}

/// The series' finite points (positive on a log axis), thinned to what a screen can show while
/// keeping each bucket's extremes, so that a spike is never thinned away.
fn drawable(series: &Series, log_y: bool) -> Series {
    let points: Vec<(f64, f64)> = series
        .points
        .iter()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite() && (!log_y || *y > 0.0))
        .collect();
    let bucket = points.len().div_ceil(MAX_POINTS / 2).max(1);
    // Segments are pairs of points: thinning would join ends of different ones.
    let whole = match series.mark {
        Mark::Dots => points.len() <= MAX_POINTS,
        Mark::Segments => true,
        Mark::Line | Mark::Bound => false,
    };
    let thinned = if bucket == 1 || whole {
        points
    } else {
        points.chunks(bucket).flat_map(extremes).collect()
    };
    Series {
        points: thinned,
        ..series.clone()
    }
}

/// The lowest and highest point of a bucket, in time order.
fn extremes(bucket: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let by_y = |a: &&(f64, f64), b: &&(f64, f64)| a.1.total_cmp(&b.1);
    let (Some(low), Some(high)) = (bucket.iter().min_by(by_y), bucket.iter().max_by(by_y)) else {
        return Vec::new();
    };
    let mut pair = vec![*low, *high];
    pair.sort_by(|a, b| a.0.total_cmp(&b.0));
    pair.dedup();
    pair
}

type Extent = (std::ops::Range<f64>, std::ops::Range<f64>);

fn extent(series: &[Series], axes: &Axes) -> Option<Extent> {
    let points = series.iter().flat_map(|s| s.points.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in points {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 {
        return None;
    }
    let y = if axes.log_y {
        let log = padded(y0.log10(), y1.log10());
        10f64.powf(log.start)..10f64.powf(log.end)
    } else {
        padded(y0, y1)
    };
    let x = padded(x0, x1);
    if !axes.equal {
        return Some((x, y));
    }
    // Twice as tall as wide on screen after the label areas: near enough to 1:2 in data.
    let half = (x.end - x.start).max(2.0 * (y.end - y.start)) / 2.0;
    let (xc, yc) = ((x.start + x.end) / 2.0, (y.start + y.end) / 2.0);
    Some((xc - half..xc + half, yc - half / 2.0..yc + half / 2.0))
}

/// A range around `[low, high]` with a margin, never empty.
fn padded(low: f64, high: f64) -> std::ops::Range<f64> {
    let span = (high - low).max(1e-9 * high.abs().max(1.0));
    let margin = 0.05 * span;
    (low - margin)..(high + margin)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thinning_keeps_a_single_spike() {
        let mut points: Vec<(f64, f64)> = (0..100_000).map(|i| (i as f64, 0.0)).collect();
        points[54_321].1 = 7.0;
        let series = Series::new("spiky", BLUE, Mark::Line).with_points(points);
        let thinned = drawable(&series, false);
        assert!(
            thinned.points.len() <= MAX_POINTS + 2,
            "{}",
            thinned.points.len()
        );
        assert!(thinned.points.contains(&(54_321.0, 7.0)));
    }

    #[test]
    fn a_chart_without_finite_points_is_not_drawn() {
        let series = Series::new("nan", BLUE, Mark::Line).with_points(vec![(0.0, f64::NAN)]);
        let chart = svg(&Axes::over_time("empty", "m"), &[series]).unwrap();
        assert!(chart.is_none());
    }

    #[test]
    fn a_log_axis_drops_what_it_cannot_show() {
        let series = Series::new("sigma", BLUE, Mark::Line).with_points(vec![
            (0.0, 0.0),
            (1.0, 0.1),
            (2.0, 0.2),
        ]);
        let axes = Axes {
            log_y: true,
            ..Axes::over_time("sigma", "m/s")
        };
        let chart = svg(&axes, &[series]).unwrap().unwrap();
        assert!(
            chart.starts_with("<svg") && chart.contains("<polyline"),
            "{chart}"
        );
    }
}
