//! Plane extraction (paper section 3.1, eqs 8-9): a line of one scanner plus the centre of a
//! coplanar line of the other. The normal is that of eq 8's plane through the first line and
//! the second line's centre, the distance the mean of eq 9 over the first line. Each line serves
//! one plane at most.
//! Where eq 8 degenerates (the second line's centre on or near the first line, as on a wall
//! beside two co-located scanners pitched about one axis), two lines that cross still define
//! the plane, fitted to all their points.

use super::deskew::Beam;
use super::level_lines::Overshoot;
use super::lines::Segment;
use super::uncertainty::{
    joint_plane_uncertainty, plane_uncertainty, LineSample, PlaneUncertainty,
};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PlaneParameters {
    /// Smallest distance of line 2's centre from line 1 (eq 8 degenerates when it lies on it).
    pub min_separation_m: f64,
    /// How many predicted sigmas line 2 may tilt out of the plane and still count as coplanar.
    pub coplanarity_gate_sigmas: f64,
    /// Keep only planes that a third line confirms (guards against fictitious planes, Fig. 3).
    pub require_third_line: bool,
    /// Which planes of two lines are kept: pairs too close to parallel (or meeting too far away)
    /// for the coplanarity test to mean anything, and in a building sloping ones.
    pub surfaces: Surfaces,
    /// Planes whose normal is known worse than this (rad) are dropped: they add little and their
    /// error is no longer linear in the noise.
    pub max_sigma_normal_rad: f64,
}

impl PlaneParameters {
    /// Whether a plane of crossing lines whose normal is known to `sigma_normal` (rad) is kept.
    fn fits_the_building(&self, normal: &Vector3<f64>, sigma_normal: f64) -> bool {
        self.surfaces.admits(normal, sigma_normal, true)
    }
}

/// Which planes of two lines are kept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Surfaces {
    /// Only those of crossing lines: two parallel lines are coplanar whatever they lie on.
    Crossing,
    /// Every one, crossing or parallel, as the paper does.
    All,
    /// In a building seen with the filter's vertical known to `vertical_sigma_rad`, only level
    /// and plumb ones. Parallel lines must be within the building's own tilt: the fictitious
    /// planes they make join a wall line to a floor line and lean between the two. Crossing
    /// lines prove less than it seems, since two lines that meet are coplanar whatever
    /// surfaces they lie on: a wall line and a short line on a box beside it meet where the
    /// box's face meets the wall, and while the platform hovered their plane stood in every
    /// epoch, 33 deg off level (`random-room-75`); its small turns as the platform bobbed taught
    /// a start in motion a gyro bias 15 sigmas off. They must be within the building's tilt
    /// widened by three sigmas of the vertical and of the plane's normal. A level plane of
    /// parallel lines must show that a level surface carries them: the other scanner's beams
    /// pass over (or under) the nearer line (`level_overshoot`), as they pass a level line
    /// alone. Where the two scanners are pitched about one axis, their lines on every face
    /// square to the body's x axis are level and parallel, and a wall line behind the platform
    /// and a line on a pillar's face in front of it, at one height, made a ceiling 0.9 m up
    /// in every epoch of a hover (`random-room-134`); once the platform moved, its tilt taught
    /// the filter a gyro bias 3 mrad/s off, and the velocity ran to 5 m/s with a 0.3 m/s
    /// sigma. There the flatter scanner's beams end on the pillar's face.
    Building {
        building: Building,
        vertical_sigma_rad: f64,
        level_overshoot: Overshoot,
    },
}

impl Surfaces {
    fn admits(&self, normal: &Vector3<f64>, sigma_normal: f64, crossing: bool) -> bool {
        match *self {
            Self::Crossing => crossing,
            Self::All => true,
            Self::Building {
                building,
                vertical_sigma_rad,
                ..
            } => {
                let building = if crossing {
                    building
                        .judged_by(vertical_sigma_rad)
                        .judged_by(sigma_normal)
                } else {
                    building.at_most(PARALLEL_PAIR_MAX_TILT_RAD)
                };
                building.is_level(normal) || building.is_plumb(normal)
            }
        }
    }

    /// Whether a plane of the parallel lines `pair` with `normal` may stand: one that is level
    /// in a building only if the other scanner's beams overshoot the nearer line.
    fn carries_parallel(
        &self,
        scans: &[ScanLines; 2],
        pair: [LineRef; 2],
        normal: &Vector3<f64>,
    ) -> bool {
        let Self::Building {
            building,
            level_overshoot,
            ..
        } = self
        else {
            return true;
        };
        if !building.is_level(normal) {
            return true;
        }
        let down = building.down;
        let centroid = |line: LineRef| scans[line.scanner].segments[line.segment].centroid;
        let reach = |line: LineRef| {
            let c = centroid(line);
            (c - down * c.dot(&down)).norm()
        };
        let near = if reach(pair[0]) <= reach(pair[1]) {
            pair[0]
        } else {
            pair[1]
        };
        level_overshoot.passes(&scans[1 - near.scanner], &down, &centroid(near))
    }
}

/// How far from level or plumb a plane of two parallel lines may lean, rad (1 deg, or the
/// building's tilt if less). Two parallel lines are coplanar whatever they lie on, and the
/// fictitious plane of a floor line and a line a little higher further out leans by the height
/// between them over the distance. With the paper's rig in the open room such a plane stood in
/// most epochs of the hover, 30 mrad off level and 3.6 cm off the floor, inside the building's
/// 3 deg, its distance to 0.3 mm. Its normal moved between epochs by more than its sigma, so it
/// never matched, and having taken the floor's lines it left no level-line floor in their
/// place: the vertical went unobserved in 18 % of the epochs (1 % with this limit). A floor or
/// wall the two lines really share leans no more than the building does.
const PARALLEL_PAIR_MAX_TILT_RAD: f64 = std::f64::consts::PI / 180.0;

/// A building's vertical (`down`, body axes) and how far its floors and walls may tilt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Building {
    pub down: Vector3<f64>,
    pub max_tilt_rad: f64,
}

impl Building {
    /// The building as judged by a vertical known to `sigma_rad`: a floor or a wall may look
    /// tipped by up to three of its sigmas more.
    pub(crate) fn judged_by(self, sigma_rad: f64) -> Self {
        Self {
            max_tilt_rad: self.max_tilt_rad + 3.0 * sigma_rad,
            ..self
        }
    }

    /// The building with its tilt limited to `max_tilt_rad`.
    fn at_most(self, max_tilt_rad: f64) -> Self {
        Self {
            max_tilt_rad: self.max_tilt_rad.min(max_tilt_rad),
            ..self
        }
    }

    pub(crate) fn is_level(&self, normal: &Vector3<f64>) -> bool {
        normal.dot(&self.down).abs() >= self.max_tilt_rad.cos()
    }

    pub(crate) fn is_plumb(&self, normal: &Vector3<f64>) -> bool {
        normal.dot(&self.down).abs() <= self.max_tilt_rad.sin()
    }
}

/// A line of scanner `scanner`: index `segment` into that scanner's lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LineRef {
    pub scanner: usize,
    pub segment: usize,
}

/// A plane in the body frame at the epoch's reference time: `normal . p = rho`, `rho > 0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Index of the plane in its epoch.
    pub id: usize,
    /// Unit normal, pointing from the body origin towards the plane.
    pub normal: Vector3<f64>,
    /// Distance from the body origin, metres.
    pub rho: f64,
    pub uncertainty: PlaneUncertainty,
    /// The fitted line (eq 8's Line1) and the line whose centre closes the plane (Line2).
    pub lines: [LineRef; 2],
    /// Whether the two lines cross at an angle the coplanarity test resolves. Two parallel
    /// lines are always coplanar, so such a plane may be fictitious (Fig. 3) and pairs that
    /// cross are preferred when lines compete.
    pub crossing: bool,
    /// Whether a third line lies in the plane within its noise.
    pub confirmed: bool,
    /// Length of its longer line, m: a lower bound on the surface's extent. A door, a person or
    /// a carried board is narrower than a wall.
    pub extent_m: f64,
    /// Whether the normal is the building's vertical rather than measured (a level plane from
    /// one line, `level_lines`): it tells the displacement along it, and nothing of a rotation.
    pub normal_assumed: bool,
}

impl Plane {
    /// A plane through one line whose normal a building sets, not a measurement
    /// (`level_lines`, `wall_lines`): numbered when it is pushed.
    pub(crate) fn through_one_line(
        line: LineRef,
        normal: Vector3<f64>,
        rho: f64,
        uncertainty: PlaneUncertainty,
        extent_m: f64,
    ) -> Self {
        Self {
            id: 0,
            normal,
            rho,
            uncertainty,
            lines: [line; 2],
            crossing: false,
            confirmed: false,
            extent_m,
            normal_assumed: true,
        }
    }

    /// Its lines, once each: a plane through one line names it twice.
    pub(crate) fn distinct_lines(&self) -> &[LineRef] {
        if self.lines[0] == self.lines[1] {
            &self.lines[..1]
        } else {
            &self.lines
        }
    }
}

/// The lines of one scan with the beams they index and the scanner's ranging sigma.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ScanLines<'a> {
    pub segments: &'a [Segment],
    pub beams: &'a [Beam],
    pub range_sigma: f64,
}

impl<'a> ScanLines<'a> {
    /// The beams within `half_width_rad` of the level unit `bearing` from the body origin, as
    /// (level part of the end point, depth along `down`): what the scan meets in that bearing,
    /// which tells a single line's surface (`level_lines`, `wall_lines`).
    pub(crate) fn beams_in_bearing(
        &self,
        down: Vector3<f64>,
        bearing: Vector3<f64>,
        half_width_rad: f64,
    ) -> impl Iterator<Item = (Vector3<f64>, f64)> + 'a {
        let within = half_width_rad.cos();
        self.beams.iter().filter_map(move |beam| {
            let depth = beam.body.dot(&down);
            let level = beam.body - down * depth;
            let distance = level.norm();
            (distance > f64::EPSILON && level.dot(&bearing) >= within * distance)
                .then_some((level, depth))
        })
    }

    fn sample(&self, segment: usize) -> LineSample<'a> {
        LineSample {
            segment: &self.segments[segment],
            beams: self.beams,
            range_sigma: self.range_sigma,
        }
    }
}

/// Reusable candidate buffers.
#[derive(Debug, Clone, Default)]
pub(crate) struct PlaneExtractor {
    candidates: Vec<Plane>,
    used: [Vec<bool>; 2],
}

impl PlaneExtractor {
    /// Fills `out` (cleared first) with the planes found from the two scanners' lines that
    /// `admit` accepts; returns how many it refused whose lines were still free (their lines go
    /// to the next pairs). Only then is `unscreened` filled with the planes found without the
    /// test; it is left empty when nothing was refused, as they would be `out`.
    pub(crate) fn extract(
        &mut self,
        scans: [ScanLines; 2],
        parameters: &PlaneParameters,
        admit: &mut dyn FnMut(&Plane) -> bool,
        out: &mut Vec<Plane>,
        unscreened: &mut Vec<Plane>,
    ) -> usize {
        self.find_candidates(&scans, parameters);
        let refused = self.assign(&scans, parameters, admit, out);
        unscreened.clear();
        if refused > 0 {
            self.assign(&scans, parameters, &mut |_| true, unscreened);
        }
        refused
    }

    /// Every pair of lines that makes a plane, best first: crossing pairs, then by sigma.
    fn find_candidates(&mut self, scans: &[ScanLines; 2], parameters: &PlaneParameters) {
        self.candidates.clear();
        for i in 0..scans[0].segments.len() {
            for j in 0..scans[1].segments.len() {
                let a = LineRef {
                    scanner: 0,
                    segment: i,
                };
                let b = LineRef {
                    scanner: 1,
                    segment: j,
                };
                let spread = |r: LineRef| scans[r.scanner].segments[r.segment].abscissa_spread;
                let pair = if spread(a) >= spread(b) {
                    [a, b]
                } else {
                    [b, a]
                };
                if let Some(plane) = plane_from_pair(scans, pair, parameters) {
                    self.candidates.push(plane);
                }
            }
        }
        self.candidates.sort_unstable_by(|p, q| {
            (!p.crossing, p.uncertainty.sigma_normal)
                .partial_cmp(&(!q.crossing, q.uncertainty.sigma_normal))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
    }

    /// Gives each line to the best admitted candidate that wants it; returns the candidates
    /// refused whose lines were still free.
    fn assign(
        &mut self,
        scans: &[ScanLines; 2],
        parameters: &PlaneParameters,
        admit: &mut dyn FnMut(&Plane) -> bool,
        out: &mut Vec<Plane>,
    ) -> usize {
        out.clear();
        for (used, scan) in self.used.iter_mut().zip(scans) {
            used.clear();
            used.resize(scan.segments.len(), false);
        }
        let mut refused = 0;
        for candidate in &self.candidates {
            if candidate
                .lines
                .iter()
                .any(|l| self.used[l.scanner][l.segment])
            {
                continue;
            }
            if !admit(candidate) {
                refused += 1;
                continue;
            }
            for l in candidate.lines {
                self.used[l.scanner][l.segment] = true;
            }
            let mut plane = *candidate;
            plane.confirmed = has_third_line(&plane, scans, parameters);
            if plane.confirmed || !parameters.require_third_line {
                plane.id = out.len();
                out.push(plane);
            }
        }
        refused
    }
}

fn plane_from_pair(
    scans: &[ScanLines; 2],
    pair: [LineRef; 2],
    parameters: &PlaneParameters,
) -> Option<Plane> {
    let line1 = scans[pair[0].scanner].sample(pair[0].segment);
    let line2 = scans[pair[1].scanner].sample(pair[1].segment);
    let (s1, s2) = (line1.segment, line2.segment);
    let v0 = s1.centroid - s2.centroid;
    // Eq 8's plane holds line 1 and line 2's centre. Its normal is taken from line 1's
    // direction, which the line fit keeps free of errors in variables; the SVD of eq 8 weighs
    // every direction alike, and ranging noise along oblique beams tilts it (a 2 mm distance
    // bias on a 0.6 m cabinet face a metre away).
    let across = s1.direction.cross(&v0);
    let separation = across.norm();
    if separation < parameters.min_separation_m {
        return plane_from_crossing_lines(&line1, &line2, pair, parameters);
    }
    let mut normal = across / separation;
    if !passes_rough_coplanarity(&line1, &line2, &normal, separation, parameters) {
        return None;
    }
    let mut rho = s1.centroid.dot(&normal);
    if rho < 0.0 {
        normal = -normal;
        rho = -rho;
    }
    let uncertainty = plane_uncertainty(&line1, &line2, &normal);
    let sigma_normal = uncertainty.sigma_normal;
    if sigma_normal.is_nan() || sigma_normal > parameters.max_sigma_normal_rad {
        return plane_from_crossing_lines(&line1, &line2, pair, parameters);
    }
    let tilt_gate = parameters.coplanarity_gate_sigmas * slope_sigma(&line2, &uncertainty);
    if s2.direction.dot(&normal).abs() > tilt_gate {
        return None;
    }
    // Two lines, one in each scan plane, are coplanar exactly when they meet on the line the
    // scan planes share; lines both parallel to it are coplanar whatever surfaces they lie on
    // (a wall ahead and the floor: Fig. 3's fictitious plane), and lines close to that are
    // coplanar within their noise and meet tens of metres away. Only a pair crossing at a
    // clear angle shows by its coplanarity that it lies on one surface.
    let crossing = s1.direction.cross(&s2.direction).norm() > tilt_gate.max(MIN_CROSSING_SINE)
        && meeting_sigma(&line1, &line2) <= MAX_MEETING_SIGMA_M;
    if !parameters.surfaces.admits(&normal, sigma_normal, crossing)
        || !crossing && !parameters.surfaces.carries_parallel(scans, pair, &normal)
    {
        return None;
    }
    Some(Plane {
        id: 0,
        normal,
        rho,
        uncertainty,
        lines: pair,
        crossing,
        confirmed: false,
        extent_m: s1.length.max(s2.length),
        normal_assumed: false,
    })
}

/// How well (m, one sigma) the two lines' carriers must be placed where they come closest for
/// their meeting to show that they lie on one surface. Two scan planes share a line, and a line
/// of each meets it somewhere; a short line on a box and a wall line 6 m away meet it at one
/// point within their noise as readily as two lines of one surface, and with the paper's rig
/// such pairs made planes 5-20 deg from any surface in most furnished rooms (`random-room-N`).
/// Over 15 scenes 7 in 10 of the planes 6 deg or more off their surface fail this, and 1 in 20
/// of the true ones, which then stay as walls and floors (docs/autopilot.md).
const MAX_MEETING_SIGMA_M: f64 = 0.1;

/// Sigma (m) of the gap between two lines' carriers where they come closest: each carrier's
/// offset there is its centroid's error plus its slope's error times the run from the centroid.
fn meeting_sigma(line1: &LineSample, line2: &LineSample) -> f64 {
    let (s1, s2) = (line1.segment, line2.segment);
    let cosine = s1.direction.dot(&s2.direction);
    let gap = s1.centroid - s2.centroid;
    let (along1, along2) = (s1.direction.dot(&gap), s2.direction.dot(&gap));
    let determinant = 1.0 - cosine * cosine;
    let run1 = (cosine * along2 - along1) / determinant;
    let run2 = (along2 - cosine * along1) / determinant;
    let carrier_variance = |line: &LineSample, run: f64| {
        let segment = line.segment;
        line.range_sigma.powi(2)
            * (1.0 / segment.points() as f64 + run * run / segment.abscissa_spread)
    };
    (carrier_variance(line1, run1) + carrier_variance(line2, run2)).sqrt()
}

/// Lines crossing at less than this (sine of the angle, 10 deg) are too close to parallel to
/// define a plane by their directions alone, or to show by their coplanarity that they lie on
/// one surface.
const MIN_CROSSING_SINE: f64 = 0.17;

/// Eq 8 needs the second line's centre off the first line. Two co-located scanners pitched
/// about one axis both scan the point where that axis meets a wall, so on a wall beside them
/// their lines cross at (nearly) their centres. Two crossing lines still define the plane: it is
/// fitted to all their points, and each line must lie in it within its noise.
fn plane_from_crossing_lines(
    line1: &LineSample,
    line2: &LineSample,
    pair: [LineRef; 2],
    parameters: &PlaneParameters,
) -> Option<Plane> {
    let (s1, s2) = (line1.segment, line2.segment);
    if s1.direction.cross(&s2.direction).norm() < MIN_CROSSING_SINE {
        return None;
    }
    let (l1, l2) = (s1.points() as f64, s2.points() as f64);
    let centre = (s1.centroid * l1 + s2.centroid * l2) / (l1 + l2);
    let (d1, d2) = (s1.centroid - centre, s2.centroid - centre);
    let scatter = s1.scatter + d1 * d1.transpose() * l1 + s2.scatter + d2 * d2.transpose() * l2;
    let eigen = SymmetricEigen::new(scatter);
    let first_normal: Vector3<f64> = eigen
        .eigenvectors
        .column(eigen.eigenvalues.imin())
        .into_owned();
    let (mut normal, mut rho) = refit_along_beams(&[line1, line2], &first_normal, &centre)?;
    if rho < 0.0 {
        normal = -normal;
        rho = -rho;
    }
    let uncertainty = joint_plane_uncertainty(line1, line2, &normal, &centre);
    if uncertainty.sigma_normal.is_nan()
        || uncertainty.sigma_normal > parameters.max_sigma_normal_rad
        || !parameters.fits_the_building(&normal, uncertainty.sigma_normal)
    {
        return None;
    }
    let plane = Plane {
        id: 0,
        normal,
        rho,
        uncertainty,
        lines: pair,
        crossing: true,
        confirmed: false,
        extent_m: s1.length.max(s2.length),
        normal_assumed: false,
    };
    [line1, line2]
        .iter()
        .all(|line| lies_in(&plane, line, parameters.coplanarity_gate_sigmas))
        .then_some(plane)
}

/// Refits a plane through `centre` by least squares of the readings' offsets on their position
/// in it, each reading slid along its beam onto the first plane. The first plane, the smallest
/// eigenvector of the points' scatter, weighs every direction alike, but ranging noise moves a
/// reading along its beam, so at oblique incidence it tilts that plane towards the beams (a 2 mm
/// distance bias on a 0.6 m cabinet face a metre away). The readings' slid positions carry no
/// noise, so this fit has none of that bias, and it is the fit `joint_plane_uncertainty`
/// describes.
fn refit_along_beams(
    lines: &[&LineSample; 2],
    first_normal: &Vector3<f64>,
    centre: &Vector3<f64>,
) -> Option<(Vector3<f64>, f64)> {
    let basis = super::tangent_basis(first_normal);
    let (a, b) = (basis.column(0).into_owned(), basis.column(1).into_owned());
    let mut design = Matrix3::zeros();
    let mut moment = Vector3::zeros();
    for beam in lines.iter().flat_map(|line| line.beams()) {
        let height = first_normal.dot(&(beam.body - centre));
        let slid = super::slid_along_beam(beam, height, first_normal);
        let x = Vector3::new(1.0, a.dot(&(slid - centre)), b.dot(&(slid - centre)));
        design += x * x.transpose();
        moment += x * height;
    }
    let [offset, tilt_a, tilt_b] = design.try_inverse().map(|inverse| inverse * moment)?.into();
    let normal = (first_normal - a * tilt_a - b * tilt_b).normalize();
    Some((normal, (centre + first_normal * offset).dot(&normal)))
}

/// Whether a line lies in a plane within `gate` sigmas, in offset and in tilt.
fn lies_in(plane: &Plane, line: &LineSample, gate: f64) -> bool {
    let s = line.segment;
    let offset = s.centroid.dot(&plane.normal) - plane.rho;
    let lever = s.centroid - plane.normal * plane.rho;
    let offset_variance = line.range_sigma.powi(2) / s.points() as f64
        + plane.uncertainty.sigma_rho.powi(2)
        + lever.dot(&(plane.uncertainty.normal_covariance * lever));
    offset.abs() <= gate * offset_variance.sqrt()
        && s.direction.dot(&plane.normal).abs() <= gate * slope_sigma(line, &plane.uncertainty)
}

/// Cheap pre-test with a generous gate, so that only plausible pairs pay for the uncertainty.
fn passes_rough_coplanarity(
    line1: &LineSample,
    line2: &LineSample,
    normal: &Vector3<f64>,
    separation: f64,
    parameters: &PlaneParameters,
) -> bool {
    let (s1, s2) = (line1.segment, line2.segment);
    let var1 = line1.range_sigma.powi(2);
    let var2 = line2.range_sigma.powi(2);
    let tilt_variance = var2 / s2.abscissa_spread
        + var1 / s1.abscissa_spread
        + (var1 / s1.points() as f64 + var2 / s2.points() as f64) / separation.powi(2);
    s2.direction.dot(normal).abs()
        <= 2.0 * parameters.coplanarity_gate_sigmas * tilt_variance.sqrt()
}

/// Predicted sigma of the angle between a line and a plane it lies in.
fn slope_sigma(line: &LineSample, plane: &PlaneUncertainty) -> f64 {
    let d = line.segment.direction;
    let own = line.range_sigma.powi(2) / line.segment.abscissa_spread;
    (own + d.dot(&(plane.normal_covariance * d))).sqrt()
}

fn has_third_line(plane: &Plane, scans: &[ScanLines; 2], parameters: &PlaneParameters) -> bool {
    let gate = parameters.coplanarity_gate_sigmas;
    scans.iter().enumerate().any(|(scanner, scan)| {
        (0..scan.segments.len()).any(|segment| {
            let here = LineRef { scanner, segment };
            if plane.lines.contains(&here) {
                return false;
            }
            lies_in(plane, &scan.sample(segment), gate)
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::odometry::single_line_fixtures::{beam, line};

    fn sample(segment: &Segment) -> LineSample<'_> {
        LineSample {
            segment,
            beams: &[],
            range_sigma: 0.01,
        }
    }

    #[test]
    fn lines_crossing_within_their_segments_meet_where_the_scans_place_them() {
        let wall = line(
            Vector3::new(3.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.2),
            2.0,
        );
        let other = line(
            Vector3::new(3.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, -0.4),
            1.5,
        );
        let sigma = meeting_sigma(&sample(&wall), &sample(&other));
        // Each carrier's centroid to 1 cm over 40 points, no run from it.
        assert!(
            (sigma - 0.01 * (2.0f64 / 40.0).sqrt()).abs() < 1e-9,
            "{sigma}"
        );
    }

    #[test]
    fn a_short_line_meeting_a_wall_line_far_off_cannot_show_they_share_a_surface() {
        let wall = line(
            Vector3::new(4.0, 2.0, 0.0),
            Vector3::new(0.2, -1.0, 0.0),
            2.6,
        );
        let mut short = line(Vector3::new(-2.0, -2.6, 1.1), Vector3::y(), 0.36);
        // Ten readings over 0.36 m: the slope is known to 0.01 / sqrt(0.11) = 30 mrad.
        short.end = 10;
        short.abscissa_spread = 10.0 * 0.36 * 0.36 / 12.0;
        let sigma = meeting_sigma(&sample(&wall), &sample(&short));
        // The carriers come closest 34.6 m along the short line (30.6 m along the wall line):
        // 30 mrad over 34.6 m is 1.05 m.
        assert!((sigma - 1.057).abs() < 0.01, "{sigma}");
        assert!(sigma > MAX_MEETING_SIGMA_M);
    }

    fn in_a_building(vertical_sigma_rad: f64) -> PlaneParameters {
        PlaneParameters {
            min_separation_m: 0.1,
            coplanarity_gate_sigmas: 3.0,
            require_third_line: false,
            surfaces: Surfaces::Building {
                building: Building {
                    down: Vector3::z(),
                    max_tilt_rad: 3f64.to_radians(),
                },
                vertical_sigma_rad,
                level_overshoot: Overshoot {
                    margin_m: 0.3,
                    bearing_half_width_rad: 10f64.to_radians(),
                },
            },
            max_sigma_normal_rad: 0.1,
        }
    }

    fn tipped_from_level(angle_deg: f64) -> Vector3<f64> {
        let angle = angle_deg.to_radians();
        Vector3::new(angle.sin(), 0.0, angle.cos())
    }

    #[test]
    fn in_a_building_only_level_and_plumb_planes_are_kept_as_the_vertical_and_the_plane_allow() {
        let settled = in_a_building(0.002);
        assert!(settled.fits_the_building(&tipped_from_level(2.0), 0.002));
        assert!(settled.fits_the_building(&tipped_from_level(88.0), 0.002));
        assert!(!settled.fits_the_building(&tipped_from_level(5.0), 0.002));
        // A plane whose normal is known to 2 deg may look 5 deg off and be a floor.
        assert!(settled.fits_the_building(&tipped_from_level(5.0), 2f64.to_radians()));
        // A start in motion knows its vertical to 3 deg: 11.6 deg are allowed, not 33.
        let in_motion = in_a_building(0.052);
        assert!(in_motion.fits_the_building(&tipped_from_level(11.0), 0.002));
        assert!(!in_motion.fits_the_building(&tipped_from_level(57.0), 0.002));
        let outdoors = PlaneParameters {
            surfaces: Surfaces::Crossing,
            ..settled
        };
        assert!(outdoors.fits_the_building(&tipped_from_level(33.0), 0.002));
    }

    #[test]
    fn a_plane_of_parallel_lines_must_be_level_or_plumb_within_a_degree() {
        let surfaces = in_a_building(0.002).surfaces;
        let admits = |angle_deg: f64| surfaces.admits(&tipped_from_level(angle_deg), 0.002, false);
        assert!(admits(0.5) && admits(89.5));
        // A floor line 1.2 m ahead joined to a line at a wall's foot 4.5 m out, 13 cm higher.
        assert!(!admits((0.13f64 / 4.5).atan().to_degrees()));
        assert!(!admits(88.0));
        // Crossing lines show they share one surface: the building's 3 deg hold for them.
        assert!(surfaces.admits(&tipped_from_level(2.0), 0.002, true));
    }

    #[test]
    fn a_level_plane_of_parallel_lines_stands_only_if_the_other_beams_pass_the_nearer_line() {
        // Body axes, z down: scanner 1's line 2 m ahead and scanner 0's 8 m ahead, both 1.2 m
        // below and along y. A floor carries them if scanner 0's beams in the nearer line's
        // bearing reach on to the far one; if they end on a face at the nearer line, the two
        // lines lie on two upright faces at one height.
        let far = [line(Vector3::new(8.0, 0.0, 1.2), Vector3::y(), 3.0)];
        let near = [line(Vector3::new(2.0, 0.0, 1.2), Vector3::y(), 1.0)];
        let fan = |x: f64, z: f64| -> Vec<Beam> {
            (-5..=5)
                .map(|k| beam(Vector3::new(x, f64::from(k) * 0.1, z)))
                .collect()
        };
        let on_the_floor = fan(8.0, 1.2);
        let on_a_face = fan(2.0, 0.3);
        let scans = |beams| {
            [(&far, beams), (&near, &[][..])].map(|(segments, beams)| ScanLines {
                segments,
                beams,
                range_sigma: 0.01,
            })
        };
        let surfaces = in_a_building(0.002).surfaces;
        let pair = [0, 1].map(|scanner| LineRef {
            scanner,
            segment: 0,
        });
        let floor = Vector3::z();
        assert!(surfaces.carries_parallel(&scans(&on_the_floor), pair, &floor));
        let blocked = scans(&on_a_face);
        assert!(!surfaces.carries_parallel(&blocked, pair, &floor));
        // Only level planes need it: a plumb one is judged as before.
        assert!(surfaces.carries_parallel(&blocked, pair, &Vector3::x()));
    }
}
