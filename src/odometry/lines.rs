//! Line extraction per scan (paper section 2, after Borges and Aldon 2004): breakpoints on range
//! jumps, iterative end-point split, merge of collinear neighbours, split points moved to their
//! corners, then a total-least-squares fit in the scanner plane. Each line keeps the 3-D
//! body-frame moments its plane fit needs, regressed on where the beams meet the line.

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
    /// Sum of the squared distances, along each beam, from its reading to the fitted line:
    /// the ranging errors, with `points() - 2` degrees of freedom (`ranging_noise`).
    pub range_residual_ss: f64,
}

impl Segment {
    pub fn points(&self) -> usize {
        self.end - self.first
    }
}

/// Reusable buffers: extraction allocates nothing once they have grown to the scan size.
#[derive(Debug, Clone, Default)]
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
        self.settle_corners(beams, parameters);
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

/// Pieces whose lines cross at less than this sine (about 6 deg) meet on one bent surface, not
/// at a corner, and keep their split.
const MIN_CORNER_SINE: f64 = 0.1;
/// The noise margin around a corner stops growing below this sine (30 deg): beyond it the
/// margin would swallow a shallow corner's lines, while their points near the corner lie within
/// twice the noise of either line anyway.
const MARGIN_SINE_FLOOR: f64 = 0.5;
/// Fewest points that fix a piece's line away from its corner.
const MIN_CORNER_FIT_POINTS: usize = 3;
/// Settling a corner may take at most one in this many of a piece's points.
const MAX_SETTLED_SHARE: usize = 4;

impl LineExtractor {
    /// Moves the boundary between two pieces that meet at a split point to their corner. The
    /// split point is the sample farthest from the chord, and along a long wall that distance
    /// falls so slowly that the ranging noise can move it a dozen samples past the corner, where
    /// they tilt the shorter line (a 0.6 m cabinet face by 20-40 mrad, 6-10 sigma). Each
    /// piece's line is fitted on its half away from the boundary; each piece then keeps only
    /// the samples farther than `breakpoint_noise_m / sin(angle)` from the lines' intersection on
    /// its own side, since nearer ones could lie on either surface.
    fn settle_corners(&mut self, beams: &[Beam], parameters: &LineParameters) {
        for k in 1..self.pieces.len() {
            let (a, b) = (self.pieces[k - 1], self.pieces[k]);
            let too_short = |(first, end): (usize, usize)| end - first < parameters.min_points;
            if a.1 + 1 < b.0 || too_short(a) || too_short(b) {
                continue;
            }
            let Some(corner) = Corner::between(beams, a, b) else {
                continue;
            };
            let margin = parameters.breakpoint_noise_m / corner.sine.max(MARGIN_SINE_FLOOR);
            let mut end = a.0;
            while end < a.1 && corner.side(&beams[end]) > margin {
                end += 1;
            }
            let mut start = b.1;
            while start > b.0 && corner.side(&beams[start - 1]) < -margin {
                start -= 1;
            }
            // A wandering split point takes a fringe; a corner that would take more is
            // misplaced (a neighbour too crooked to fit), so the split stays.
            if (a.1 - end) * MAX_SETTLED_SHARE > a.1 - a.0
                || (start - b.0) * MAX_SETTLED_SHARE > b.1 - b.0
            {
                continue;
            }
            self.pieces[k - 1].1 = end;
            self.pieces[k].0 = start;
        }
    }
}

/// Where the lines of two neighbouring pieces cross, each fitted away from the other piece.
struct Corner {
    point: Vector2<f64>,
    /// The vector whose projection tells the sides apart: `(u_a - u_b) / (1 - u_a . u_b)`, with
    /// `u_a`, `u_b` the lines' directions from the corner into each piece, so that a sample on
    /// either line projects to its signed distance from the corner (positive on piece a).
    separator: Vector2<f64>,
    sine: f64,
}

impl Corner {
    fn between(beams: &[Beam], a: (usize, usize), b: (usize, usize)) -> Option<Self> {
        let half = |(first, end): (usize, usize)| ((end - first) / 2).max(MIN_CORNER_FIT_POINTS);
        let (half_a, half_b) = (half(a), half(b));
        if half_a > a.1 - a.0 || half_b > b.1 - b.0 {
            return None;
        }
        let (centre_a, direction_a) = fit_2d(beams, a.0, a.0 + half_a);
        let (centre_b, direction_b) = fit_2d(beams, b.1 - half_b, b.1);
        let cross = direction_b.perp(&direction_a);
        let sine = cross.abs();
        if sine < MIN_CORNER_SINE {
            return None;
        }
        let point = centre_a + direction_a * (direction_b.perp(&(centre_b - centre_a)) / cross);
        let into = |direction: Vector2<f64>, centre: Vector2<f64>| {
            direction * (centre - point).dot(&direction).signum()
        };
        let (into_a, into_b) = (into(direction_a, centre_a), into(direction_b, centre_b));
        let opening = 1.0 - into_a.dot(&into_b);
        if opening < MIN_CORNER_SINE {
            return None;
        }
        Some(Self {
            point,
            separator: (into_a - into_b) / opening,
            sine,
        })
    }

    /// Signed distance of a sample from the corner along its line: positive on piece a's side.
    fn side(&self, beam: &Beam) -> f64 {
        (beam.planar - self.point).dot(&self.separator)
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
    let normal_2d = Vector2::new(-direction_2d.y, direction_2d.x);
    // One pass over the abscissae, centred afterwards: the moment needs no centring, as the
    // 3-D offsets from the centroid sum to zero.
    let (mut low, mut high) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut sum, mut sum_of_squares) = (0.0, 0.0);
    let mut moment = Vector3::zeros();
    let mut range_residual_ss = 0.0;
    for beam in points {
        let on_line = where_beam_meets_line(beam, &centroid_2d, &normal_2d);
        range_residual_ss += (on_line - beam.planar).norm_squared();
        let t = direction_2d.dot(&(on_line - centroid_2d));
        low = low.min(t);
        high = high.max(t);
        sum += t;
        sum_of_squares += t * t;
        moment += (beam.body - centroid) * t;
    }
    let abscissa_spread = sum_of_squares - sum * sum / n;
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
        range_residual_ss,
    })
}

/// Where a reading's beam meets the fitted line: the 2-D `slid_along_beam`. Regressing the 3-D
/// points on the readings' own abscissae would tilt a line towards the beams by about
/// `12 sigma^2 sin(i) cos(i) / L^2` at incidence `i` (1-2 mrad on a 0.6 m cabinet face).
fn where_beam_meets_line(
    beam: &Beam,
    centre: &Vector2<f64>,
    normal: &Vector2<f64>,
) -> Vector2<f64> {
    let Some(ray) = beam.planar.try_normalize(0.0) else {
        return beam.planar;
    };
    let cosine = normal.dot(&ray);
    if cosine.abs() < super::MIN_SLIDE_COSINE {
        return beam.planar;
    }
    beam.planar - ray * (normal.dot(&(beam.planar - centre)) / cosine)
}
