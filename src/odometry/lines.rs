//! Line extraction per scan (paper section 2, after Borges and Aldon 2004): breakpoints on range
//! jumps, iterative end-point split, merge of collinear neighbours, then a total-least-squares
//! fit in the scanner plane. Each line keeps the 3-D body-frame moments its plane fit needs.

use super::deskew::Beam;
use nalgebra::{Matrix3, Vector2, Vector3};

/// Segmentation parameters (see `OdometryConfig` for their meaning and defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineParameters {
    /// Borges-Aldon lambda: the shallowest incidence angle still accepted on one surface.
    pub breakpoint_lambda_rad: f64,
    /// Ranging noise allowance added to the adaptive breakpoint distance (3 sigma).
    pub breakpoint_noise_m: f64,
    /// Largest distance of a point from its segment's chord before the segment is split.
    pub split_distance_m: f64,
    pub min_points: usize,
    pub min_length_m: f64,
}

/// One fitted line: beams `first..end` of its scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub first: usize,
    pub end: usize,
    /// Centroid and unit direction in the scanner plane.
    pub centroid_2d: Vector2<f64>,
    pub direction_2d: Vector2<f64>,
    /// Extent along the direction, metres.
    pub length: f64,
    /// Centroid of the deskewed body-frame points (`p0` of eq 8).
    pub centroid: Vector3<f64>,
    /// Unit direction in the body frame: regression of the 3-D points on the in-plane abscissa.
    pub direction: Vector3<f64>,
    /// Sum of squared abscissae about the centroid; sets how well the line's slope is known.
    pub abscissa_spread: f64,
    /// Centred scatter of the body-frame points, sum of (p - p0)(p - p0)^T.
    pub scatter: Matrix3<f64>,
}

impl Segment {
    pub fn points(&self) -> usize {
        self.end - self.first
    }
}

/// Reusable buffers: extraction allocates nothing once they have grown to the scan size.
#[derive(Debug, Default)]
pub struct LineExtractor {
    pending: Vec<(usize, usize)>,
    pieces: Vec<(usize, usize)>,
}

impl LineExtractor {
    /// Fills `out` (cleared first) with the lines of one scan's beams, in beam order.
    pub fn extract(&mut self, beams: &[Beam], parameters: &LineParameters, out: &mut Vec<Segment>) {
        out.clear();
        self.pieces.clear();
        let mut cluster_start = 0;
        let mut breakpoint = Breakpoint::new(parameters);
        for n in 1..=beams.len() {
            if n == beams.len() || breakpoint.between(&beams[n - 1], &beams[n]) {
                self.split(beams, cluster_start, n, parameters);
                cluster_start = n;
            }
        }
        self.pieces.sort_unstable();
        self.merge_collinear(beams, parameters);
        for &(first, end) in &self.pieces {
            if let Some(segment) = fit_segment(beams, first, end, parameters) {
                out.push(segment);
            }
        }
    }

    /// Iterative end-point fit. The point of largest deviation is dropped from both halves: with
    /// exact data it is the sample next to a corner and may belong to either wall.
    fn split(&mut self, beams: &[Beam], first: usize, end: usize, parameters: &LineParameters) {
        self.pending.clear();
        self.pending.push((first, end));
        while let Some((a, b)) = self.pending.pop() {
            if b - a < parameters.min_points.max(2) {
                continue;
            }
            let (worst, distance) = farthest_from_chord(beams, a, b);
            if distance > parameters.split_distance_m {
                self.pending.push((a, worst));
                self.pending.push((worst + 1, b));
            } else {
                self.pieces.push((a, b));
            }
        }
    }

    /// Rejoins neighbours separated only by a split point when one line fits them both.
    fn merge_collinear(&mut self, beams: &[Beam], parameters: &LineParameters) {
        let mut kept = 0;
        for i in 0..self.pieces.len() {
            let piece = self.pieces[i];
            if kept > 0 {
                let last = self.pieces[kept - 1];
                if last.1 + 1 >= piece.0
                    && max_deviation_from_fit(beams, last.0, piece.1) <= parameters.split_distance_m
                {
                    self.pieces[kept - 1].1 = piece.1;
                    continue;
                }
            }
            self.pieces[kept] = piece;
            kept += 1;
        }
        self.pieces.truncate(kept);
    }
}

/// Borges and Aldon's adaptive breakpoint: a jump longer than a surface seen at incidence lambda
/// could produce, plus the noise allowance. The angular factor is cached, as consecutive beams
/// are nearly always one step apart.
struct Breakpoint {
    lambda: f64,
    noise_m: f64,
    step: f64,
    factor: f64,
}

impl Breakpoint {
    fn new(parameters: &LineParameters) -> Self {
        Self {
            lambda: parameters.breakpoint_lambda_rad,
            noise_m: parameters.breakpoint_noise_m,
            step: f64::NAN,
            factor: 0.0,
        }
    }

    fn between(&mut self, previous: &Beam, next: &Beam) -> bool {
        let step = (next.azimuth - previous.azimuth).abs();
        if step >= self.lambda {
            return true;
        }
        if self.step.is_nan() || (step - self.step).abs() > 1e-9 * step {
            self.step = step;
            self.factor = step.sin() / (self.lambda - step).sin();
        }
        let limit = previous.range * self.factor + self.noise_m;
        (next.planar - previous.planar).norm_squared() > limit * limit
    }
}

fn farthest_from_chord(beams: &[Beam], a: usize, b: usize) -> (usize, f64) {
    let start = beams[a].planar;
    let chord = beams[b - 1].planar - start;
    let length = chord.norm();
    let mut worst = (a, 0.0);
    if length == 0.0 {
        return worst;
    }
    for (k, beam) in beams.iter().enumerate().take(b - 1).skip(a + 1) {
        let d = chord.perp(&(beam.planar - start)).abs() / length;
        if d > worst.1 {
            worst = (k, d);
        }
    }
    worst
}

/// Total least squares in 2-D: centroid and unit direction (principal axis of the scatter).
fn fit_2d(beams: &[Beam], a: usize, b: usize) -> (Vector2<f64>, Vector2<f64>) {
    let n = (b - a) as f64;
    let centroid = beams[a..b]
        .iter()
        .fold(Vector2::zeros(), |s, beam| s + beam.planar)
        / n;
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for beam in &beams[a..b] {
        let d = beam.planar - centroid;
        sxx += d.x * d.x;
        syy += d.y * d.y;
        sxy += d.x * d.y;
    }
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    (centroid, Vector2::new(angle.cos(), angle.sin()))
}

fn max_deviation_from_fit(beams: &[Beam], a: usize, b: usize) -> f64 {
    let (centroid, direction) = fit_2d(beams, a, b);
    beams[a..b]
        .iter()
        .map(|beam| direction.perp(&(beam.planar - centroid)).abs())
        .fold(0.0, f64::max)
}

fn fit_segment(beams: &[Beam], a: usize, b: usize, parameters: &LineParameters) -> Option<Segment> {
    if b - a < parameters.min_points.max(2) {
        return None;
    }
    let points = &beams[a..b];
    let n = points.len() as f64;
    let (sum_2d, sum_3d) = points
        .iter()
        .fold((Vector2::zeros(), Vector3::zeros()), |(s2, s3), beam| {
            (s2 + beam.planar, s3 + beam.body)
        });
    let (centroid_2d, centroid) = (sum_2d / n, sum_3d / n);
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    let mut scatter = Matrix3::zeros();
    for beam in points {
        let d = beam.planar - centroid_2d;
        sxx += d.x * d.x;
        syy += d.y * d.y;
        sxy += d.x * d.y;
        let d3 = beam.body - centroid;
        scatter += d3 * d3.transpose();
    }
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let direction_2d = Vector2::new(angle.cos(), angle.sin());
    let (mut low, mut high) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut moment = Vector3::zeros();
    let mut abscissa_spread = 0.0;
    for beam in points {
        let t = direction_2d.dot(&(beam.planar - centroid_2d));
        low = low.min(t);
        high = high.max(t);
        moment += (beam.body - centroid) * t;
        abscissa_spread += t * t;
    }
    let length = high - low;
    if length < parameters.min_length_m {
        return None;
    }
    Some(Segment {
        first: a,
        end: b,
        centroid_2d,
        direction_2d,
        length,
        centroid,
        direction: moment.try_normalize(0.0)?,
        abscissa_spread,
        scatter,
    })
}
