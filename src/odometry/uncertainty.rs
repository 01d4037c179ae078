//! Plane uncertainty (paper section 3.2, eqs 10-28), as a first-order propagation of the
//! ranging noise through the plane fit of eqs 8-9 instead of the paper's worst-case bounds.
//!
//! Take line 1 (the fitted line, centre `p0`, in-plane direction `a`) and the centre `p0'` of
//! line 2, and let `w` be the in-plane unit vector across line 1 towards `p0'`, at perpendicular
//! separation `s` and abscissa `t'` along `a`. Each reading errs along its beam, so it moves off
//! the plane by `e_k ~ N(0, (sigma b_k . n)^2)`. The plane of eq 8 is the one through `p0'`
//! that best fits line 1, so to first order its height over the true plane is
//! `c + alpha t + beta s'` with `c` the mean offset of line 1, `alpha` its slope and
//! `beta = (e' - c - alpha t') / s` (`e'` the mean offset of line 2). Then
//! `delta n = -(alpha a + beta w)` and `delta rho = c + p0 . delta n` (eq 9).
//! `beta`'s variance is eq 25 with the perpendicular separation and the incidence-weighted
//! sigma; `var(delta rho)` is eq 28 with the cross terms kept.

use super::deskew::Beam;
use super::lines::Segment;
use nalgebra::{Matrix3, Matrix3x2, Vector3};

/// Smallest share of the ranging noise assumed to fall along a plane's normal: beam-angle
/// jitter and texture still move grazing points off the plane.
const MIN_INCIDENCE_COSINE: f64 = 0.1;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneUncertainty {
    /// Covariance of the normal's error (rank 2, in the plane tangent to the normal), rad^2.
    pub normal_covariance: Matrix3<f64>,
    /// Total angular error of the normal, sqrt(trace), rad (the role of eq 25's e_n).
    pub sigma_normal: f64,
    /// Standard deviation of the distance, metres (eq 28).
    pub sigma_rho: f64,
}

/// One line of a plane pair with the beams it was fitted to and its scanner's ranging sigma.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LineSample<'a> {
    pub segment: &'a Segment,
    pub beams: &'a [Beam],
    pub range_sigma: f64,
}

impl LineSample<'_> {
    pub(super) fn beams(&self) -> &[Beam] {
        &self.beams[self.segment.first..self.segment.end]
    }

    /// Variance of one reading's offset from a plane of normal `n`.
    fn offset_variance(&self, beam: &Beam, n: &Vector3<f64>) -> f64 {
        let cosine = beam.direction.dot(n).abs().max(MIN_INCIDENCE_COSINE);
        (self.range_sigma * cosine).powi(2)
    }
}

/// Propagates the ranging noise into a plane fitted to every point of two crossing lines whose
/// centres nearly coincide (where eq 8, which uses only the second line's centre, degenerates).
/// The plane's height over the true one is `c + g . u` at in-plane offset `u` from the joint
/// centroid `centre`; `(c, g)` is the least-squares fit of the points' offsets, so its
/// covariance is `A^-1 B A^-1` with `A = sum x x^T`, `B = sum var_k x x^T`, `x = [1, u]`.
/// Then `delta n = -g` (in the tangent basis) and `delta rho = c + centre . delta n`.
pub(crate) fn joint_plane_uncertainty(
    line1: &LineSample,
    line2: &LineSample,
    n: &Vector3<f64>,
    centre: &Vector3<f64>,
) -> PlaneUncertainty {
    let basis = super::tangent_basis(n);
    let (a, b) = (basis.column(0).into_owned(), basis.column(1).into_owned());
    let mut design = Matrix3::zeros();
    let mut noise = Matrix3::zeros();
    for line in [line1, line2] {
        for beam in line.beams() {
            let offset = beam.body - centre;
            let x = Vector3::new(1.0, a.dot(&offset), b.dot(&offset));
            let outer = x * x.transpose();
            design += outer;
            noise += outer * line.offset_variance(beam, n);
        }
    }
    let Some(inverse) = design.try_inverse() else {
        return PlaneUncertainty {
            normal_covariance: Matrix3::from_element(f64::NAN),
            sigma_normal: f64::NAN,
            sigma_rho: f64::NAN,
        };
    };
    let plane = inverse * noise * inverse;
    let tilts = plane.fixed_view::<2, 2>(1, 1).into_owned();
    let normal_covariance = basis * tilts * basis.transpose();
    let rho_gradient = Vector3::new(1.0, -a.dot(centre), -b.dot(centre));
    PlaneUncertainty {
        normal_covariance,
        sigma_normal: normal_covariance.trace().sqrt(),
        sigma_rho: rho_gradient.dot(&(plane * rho_gradient)).sqrt(),
    }
}

/// Propagates the ranging noise of both lines into the plane `(n, rho = p0 . n)`.
pub(crate) fn plane_uncertainty(
    line1: &LineSample,
    line2: &LineSample,
    n: &Vector3<f64>,
) -> PlaneUncertainty {
    let p0 = line1.segment.centroid;
    let along = (line1.segment.direction - n * n.dot(&line1.segment.direction)).normalize();
    let offset = line2.segment.centroid - p0;
    let mut across = n.cross(&along);
    if across.dot(&offset) < 0.0 {
        across = -across;
    }
    let separation = across.dot(&offset);
    let abscissa = along.dot(&offset);

    let l1 = line1.segment.points() as f64;
    let (mut sum_w, mut sum_tw, mut sum_ttw, mut spread) = (0.0, 0.0, 0.0, 0.0);
    for beam in line1.beams() {
        let t = along.dot(&(beam.body - p0));
        let w = line1.offset_variance(beam, n);
        sum_w += w;
        sum_tw += t * w;
        sum_ttw += t * t * w;
        spread += t * t;
    }
    let l2 = line2.segment.points() as f64;
    let var_e2 = line2
        .beams()
        .iter()
        .map(|beam| line2.offset_variance(beam, n))
        .sum::<f64>()
        / (l2 * l2);

    // Covariance of the independent inputs (c, alpha, e').
    let inputs = Matrix3::new(
        sum_w / (l1 * l1),
        sum_tw / (l1 * spread),
        0.0,
        sum_tw / (l1 * spread),
        sum_ttw / (spread * spread),
        0.0,
        0.0,
        0.0,
        var_e2,
    );
    // (c, alpha, beta) from (c, alpha, e').
    let to_plane = Matrix3::new(
        1.0,
        0.0,
        0.0,
        0.0,
        1.0,
        0.0,
        -1.0 / separation,
        -abscissa / separation,
        1.0 / separation,
    );
    let plane = to_plane * inputs * to_plane.transpose();
    let tilts = plane.fixed_view::<2, 2>(1, 1).into_owned();
    let basis = Matrix3x2::from_columns(&[along, across]);
    let normal_covariance = basis * tilts * basis.transpose();
    let rho_gradient = Vector3::new(1.0, -along.dot(&p0), -across.dot(&p0));
    let var_rho = rho_gradient.dot(&(plane * rho_gradient));
    PlaneUncertainty {
        normal_covariance,
        sigma_normal: normal_covariance.trace().sqrt(),
        sigma_rho: var_rho.sqrt(),
    }
}
