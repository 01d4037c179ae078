//! `replay --report`: one self-contained HTML page to look at a run, with the paper's plots
//! (velocity and attitude errors inside their reported bounds, the integrity statistics against
//! their thresholds), the planes and epoch outcomes, a top view against truth, and what the
//! autopilot was told. The SVG charts are inline and there is no script, so the file opens
//! anywhere, offline, and can be mailed as it is.

pub(crate) mod chart;
mod epochs;
mod html;
pub mod integrity;
mod plane_map;

use crate::daemon::mavlink_out::QualityPolicy;
use crate::daemon::replay::ReplaySummary;
use crate::daemon::truth::nearest_in_time;
use crate::estimate::Estimate;
use crate::sensors::TruthSample;
use chart::{Axes, ChartError, Mark, Series, BLUE, GREEN, GREY, ORANGE, PURPLE, RED};
use epochs::EpochView;
use html::Page;
use nalgebra::{UnitQuaternion, Vector3};

/// Everything a run's report is drawn from.
pub struct RunReport<'a> {
    /// What was replayed, for the heading.
    pub title: &'a str,
    /// Estimates, in time order (the replay keeps them at 20 Hz).
    pub estimates: &'a [Estimate],
    /// `/truth` of a simulated recording; empty otherwise.
    pub truth: &'a [TruthSample],
    /// The lines of `epochs.jsonl`.
    pub epochs: &'a [serde_json::Value],
    pub policy: &'a QualityPolicy,
    pub summary: &'a ReplaySummary,
    /// The estimates share truth's origin and north (a replay from the recording's start):
    /// NED errors and the top view against truth mean something.
    pub shares_truth_frame: bool,
}

const AXES_NED: [&str; 3] = ["north", "east", "down"];
const AXES_BODY: [&str; 3] = ["forward", "right", "down"];
const AXIS_COLORS: [chart::RGBColor; 3] = [BLUE, ORANGE, GREEN];

impl RunReport<'_> {
    pub fn render(&self) -> Result<String, ChartError> {
        let mut page = Page::new(&format!("ladar-odometer: {}", self.title));
        page.summary(self.summary);
        self.velocity_section(&mut page)?;
        self.attitude_section(&mut page)?;
        let epochs = EpochView::new(self.epochs);
        epochs.integrity_section(&mut page)?;
        epochs.planes_section(&mut page)?;
        self.top_view_section(&mut page, &epochs)?;
        plane_map::plane_map_section(&mut page, self.epochs, self.track(), &self.truth_offset())?;
        self.autopilot_section(&mut page)?;
        Ok(page.finish())
    }

    fn truth_at(&self, t: f64) -> Option<&TruthSample> {
        nearest_in_time(self.truth, t, |sample| sample.t)
    }

    fn velocity_section(&self, page: &mut Page) -> Result<(), ChartError> {
        page.section(
            "Velocity error",
            "Each axis against its reported 3-sigma bounds (paper Fig. 14). From the recording's \
             start the axes are north, east, down; a replay started later compares body axes, as \
             the autopilot does. Without truth, the estimate itself is drawn inside its bounds.",
        );
        let body = !self.shares_truth_frame;
        let names = if body { AXES_BODY } else { AXES_NED };
        for axis in 0..3 {
            let mut value = Vec::new();
            let (mut upper, mut lower) = (Vec::new(), Vec::new());
            for e in self.estimates {
                let (velocity, covariance) = if body {
                    (e.body_velocity(), e.body_velocity_covariance())
                } else {
                    (e.velocity, e.velocity_covariance)
                };
                let truth = match (self.truth.is_empty(), self.truth_at(e.t)) {
                    (true, _) => Vector3::zeros(),
                    (false, Some(truth)) if body => truth.q.inverse_transform_vector(&truth.v),
                    (false, Some(truth)) => truth.v,
                    (false, None) => continue,
                };
                let centre = if self.truth.is_empty() {
                    velocity[axis]
                } else {
                    0.0
                };
                let bound = 3.0 * covariance[(axis, axis)].sqrt();
                value.push((e.t, velocity[axis] - truth[axis]));
                upper.push((e.t, centre + bound));
                lower.push((e.t, centre - bound));
            }
            let label = if self.truth.is_empty() {
                "velocity"
            } else {
                "error"
            };
            let series = bounded(label, AXIS_COLORS[axis], value, upper, lower);
            let axes = Axes::over_time(format!("velocity {label}, {}", names[axis]), "m/s");
            page.chart(&format!("velocity-{}", names[axis]), &axes, &series)?;
        }
        Ok(())
    }

    fn attitude_section(&self, page: &mut Page) -> Result<(), ChartError> {
        page.section(
            "Attitude error",
            "The rotation from the estimated to the true attitude, about the north, east and down \
             axes (the filter's attitude error), against its reported 3-sigma bounds.",
        );
        if self.truth.is_empty() || !self.shares_truth_frame {
            page.note("No truth in this frame: a recording without /truth, or a replay started later, whose north is its own.");
            return Ok(());
        }
        for axis in 0..3 {
            let mut value = Vec::new();
            let (mut upper, mut lower) = (Vec::new(), Vec::new());
            for e in self.estimates {
                let Some(truth) = self.truth_at(e.t) else {
                    continue;
                };
                let error = attitude_error(&e.attitude, &truth.q) * 1e3;
                let bound = 3e3 * e.attitude_covariance[(axis, axis)].sqrt();
                value.push((e.t, error[axis]));
                upper.push((e.t, bound));
                lower.push((e.t, -bound));
            }
            let series = bounded("error", AXIS_COLORS[axis], value, upper, lower);
            let axes = Axes::over_time(format!("attitude error about {}", AXES_NED[axis]), "mrad");
            page.chart(&format!("attitude-{}", AXES_NED[axis]), &axes, &series)?;
        }
        Ok(())
    }

    /// The estimates' positions from the true start point when the run shares the truth's frame
    /// (a simulated recording replayed from its start), as they are otherwise.
    fn truth_offset(&self) -> Vector3<f64> {
        match (self.shares_truth_frame, self.estimates.first()) {
            (true, Some(first)) => self
                .truth_at(first.t)
                .map_or(Vector3::zeros(), |truth| truth.p - first.position),
            _ => Vector3::zeros(),
        }
    }

    /// The estimated track, east and north, from the true start point where there is one.
    fn track(&self) -> Vec<(f64, f64)> {
        let offset = self.truth_offset();
        self.estimates
            .iter()
            .map(|e| e.position + offset)
            .map(|p| (p.y, p.x))
            .collect()
    }

    fn top_view_section(&self, page: &mut Page, epochs: &EpochView) -> Result<(), ChartError> {
        page.section(
            "Top view",
            "The estimated track and the true one, east to the right and north up, both from the \
             true start point; and the walls (non-horizontal planes) of one epoch, cut at the \
             platform's height, used in blue and excluded in red.",
        );
        let offset = self.truth_offset();
        let mut series = vec![Series::new("estimate", BLUE, Mark::Line).with_points(self.track())];
        if self.shares_truth_frame && !self.truth.is_empty() {
            let truth = self.truth.iter().map(|s| (s.p.y, s.p.x)).collect();
            series.push(Series::new("truth", GREY, Mark::Line).with_points(truth));
        }
        let shown = epochs.showcase().and_then(|epoch| {
            let estimate = self.estimate_at(epoch.t)?;
            Some((epoch, estimate))
        });
        if let Some((epoch, estimate)) = shown {
            let (used, excluded) = epoch.walls(&estimate.attitude, &(estimate.position + offset));
            series.push(Series::new("wall", BLUE, Mark::Dots).with_points(used));
            series.push(Series::new("excluded wall", RED, Mark::Dots).with_points(excluded));
            page.note(&format!(
                "Walls of the epoch at t = {:.2} s, the one with the most planes used.",
                epoch.t
            ));
        }
        let axes = Axes {
            title: "track, east-north".into(),
            x_label: "east (m)".into(),
            y_label: "north (m)".into(),
            log_y: false,
            equal: true,
        };
        page.chart("top-view", &axes, &series)
    }

    fn estimate_at(&self, t: f64) -> Option<&Estimate> {
        nearest_in_time(self.estimates, t, |e| e.t).filter(|e| (e.t - t).abs() < 0.25)
    }

    fn autopilot_section(&self, page: &mut Page) -> Result<(), ChartError> {
        page.section(
            "What the autopilot was told",
            "ODOMETRY's quality (-1 failed, 0 not to be used, 1-100 usable) and the body-velocity \
             sigmas it carried. Above the dashed limit the quality is 0 whatever else holds.",
        );
        let quality = self
            .estimates
            .iter()
            .map(|e| (e.t, f64::from(self.policy.quality(e))))
            .collect();
        let axes = Axes::over_time("ODOMETRY quality", "quality");
        page.chart(
            "quality",
            &axes,
            &[Series::new("quality", PURPLE, Mark::Line).with_points(quality)],
        )?;
        let mut series: Vec<Series> = (0..3)
            .map(|axis| {
                let points = self
                    .estimates
                    .iter()
                    .map(|e| (e.t, e.body_velocity_covariance()[(axis, axis)].sqrt()))
                    .collect();
                Series::new(
                    format!("sigma {}", AXES_BODY[axis]),
                    AXIS_COLORS[axis],
                    Mark::Line,
                )
                .with_points(points)
            })
            .collect();
        let limit = self.policy.unusable_sigma_mps;
        let span = [self.estimates.first(), self.estimates.last()];
        series.push(
            Series::new("unusable above", RED, Mark::Bound)
                .with_points(span.iter().flatten().map(|e| (e.t, limit)).collect()),
        );
        let axes = Axes {
            log_y: true,
            ..Axes::over_time("body velocity sigma sent", "m/s")
        };
        page.chart("velocity-sigma", &axes, &series)
    }
}

/// A value between its upper and lower bounds, as three series. The bounds are cut where they
/// reach beyond most of their run (the wide priors of a start), so that the scale shows the
/// value against its usual bounds; the value itself is never cut.
fn bounded(
    label: &str,
    color: chart::RGBColor,
    value: Vec<(f64, f64)>,
    upper: Vec<(f64, f64)>,
    lower: Vec<(f64, f64)>,
) -> [Series; 3] {
    let values = || value.iter().map(|p| p.1).filter(|v| v.is_finite());
    let low = values().fold(quantile(&lower, 0.05), f64::min);
    let high = values().fold(quantile(&upper, 0.95), f64::max);
    let margin = 0.1 * (high - low);
    let cut = |bound: Vec<(f64, f64)>| {
        bound
            .into_iter()
            .map(|(t, b)| (t, b.clamp(low - margin, high + margin)))
            .collect()
    };
    [
        Series::new(label, color, Mark::Line).with_points(value),
        Series::new("+3 sigma", GREY, Mark::Bound).with_points(cut(upper)),
        Series::new("-3 sigma", GREY, Mark::Bound).with_points(cut(lower)),
    ]
}

/// The `q` quantile of the finite values of a series (0 when it has none).
fn quantile(series: &[(f64, f64)], q: f64) -> f64 {
    let mut values: Vec<f64> = series
        .iter()
        .map(|p| p.1)
        .filter(|v| v.is_finite())
        .collect();
    values.sort_by(f64::total_cmp);
    let index = ((values.len() as f64 - 1.0) * q).round().max(0.0) as usize;
    values.get(index).copied().unwrap_or(0.0)
}

/// The filter's attitude error: the rotation vector taking the estimate to the truth, in NED.
fn attitude_error(estimate: &UnitQuaternion<f64>, truth: &UnitQuaternion<f64>) -> Vector3<f64> {
    (truth * estimate.inverse()).scaled_axis()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn attitude_error_is_the_global_rotation_from_estimate_to_truth() {
        let estimate = UnitQuaternion::from_euler_angles(0.1, -0.2, 1.0);
        let small = Vector3::new(0.002, -0.001, 0.003);
        let truth = UnitQuaternion::from_scaled_axis(small) * estimate;
        assert!((attitude_error(&estimate, &truth) - small).norm() < 1e-12);
    }

    #[test]
    fn wide_bounds_are_cut_to_the_run_but_the_value_never() {
        let times = 0..100;
        let value = times
            .clone()
            .map(|t| (f64::from(t), if t == 50 { 2.0 } else { 0.0 }))
            .collect();
        let wide_at_start = |sign: f64| {
            times
                .clone()
                .map(|t| (f64::from(t), sign * if t < 3 { 100.0 } else { 1.0 }))
                .collect()
        };
        let [value, upper, lower] = bounded(
            "error",
            BLUE,
            value,
            wide_at_start(1.0),
            wide_at_start(-1.0),
        );
        assert!(value.points.contains(&(50.0, 2.0)));
        let reach = |s: &Series| s.points.iter().map(|p| p.1.abs()).fold(0.0, f64::max);
        assert!(reach(&upper) < 3.0 && reach(&lower) < 3.0);
        assert_eq!(upper.points[50].1, 1.0);
    }
}
