//! Test fixtures of the single-line planes (`level_lines`, `wall_lines`): a fitted line and a
//! beam as the extraction would give them, placed by hand in the body frame.

use nalgebra::{Matrix3, Vector2, Vector3};

use super::deskew::Beam;
use super::lines::Segment;

/// A 40-point line of `length` through `centroid` along `direction`, its points spread over
/// 10 m^2 of squared abscissa.
pub(crate) fn line(centroid: Vector3<f64>, direction: Vector3<f64>, length: f64) -> Segment {
    Segment {
        first: 0,
        end: 40,
        centroid_2d: Vector2::zeros(),
        direction_2d: Vector2::x(),
        length,
        centroid,
        direction: direction.normalize(),
        abscissa_spread: 10.0,
        scatter: Matrix3::zeros(),
        range_residual_ss: 0.0,
    }
}

/// A beam ending at `body`.
pub(crate) fn beam(body: Vector3<f64>) -> Beam {
    Beam {
        planar: Vector2::zeros(),
        body,
        direction: body.normalize(),
        azimuth: 0.0,
        range: body.norm(),
        time: 0.0,
    }
}
