//! Filter consistency: NEES against truth, NIS of innovations, and the chi-square quantiles the
//! innovation gate and the consistency tests compare them with.

#[cfg(test)]
use nalgebra::{SMatrix, SVector, Vector3};

#[cfg(test)]
use crate::sensors::TruthSample;

/// A normalised squared error and its degrees of freedom.
#[cfg(test)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Normalised {
    pub value: f64,
    pub dof: usize,
}

/// Normalised estimation error squared of position, velocity and attitude against truth,
/// `e^T P^-1 e` with the filter's 9x9 covariance of those blocks (global attitude error,
/// `Log(q_true q_est^-1)`). `None` when the covariance is not positive definite.
#[cfg(test)]
pub(crate) fn nees(
    position: &Vector3<f64>,
    velocity: &Vector3<f64>,
    attitude: &nalgebra::UnitQuaternion<f64>,
    covariance: &SMatrix<f64, 9, 9>,
    truth: &TruthSample,
) -> Option<Normalised> {
    let mut error = SVector::<f64, 9>::zeros();
    error
        .fixed_rows_mut::<3>(0)
        .copy_from(&(truth.p - position));
    error
        .fixed_rows_mut::<3>(3)
        .copy_from(&(truth.v - velocity));
    error
        .fixed_rows_mut::<3>(6)
        .copy_from(&(truth.q * attitude.inverse()).scaled_axis());
    let value = covariance.cholesky()?.solve(&error).dot(&error);
    Some(Normalised { value, dof: 9 })
}

/// Normalised innovation squared `y^T S^-1 y`. `None` when `S` is not positive definite.
#[cfg(test)]
pub(crate) fn nis<const N: usize>(
    innovation: &SVector<f64, N>,
    covariance: &SMatrix<f64, N, N>,
) -> Option<f64> {
    Some(covariance.cholesky()?.solve(innovation).dot(innovation))
}

/// 95 % interval of the average of `count` independent NEES values of `dof` degrees of
/// freedom each: `chi2(count * dof) / count`.
pub fn mean_nees_interval(dof: usize, count: usize) -> [f64; 2] {
    let count = count.max(1);
    [0.025, 0.975].map(|p| chi_square_quantile(p, dof * count) / count as f64)
}

/// The chance of a NIS beyond which an update surprises the filter.
const SURPRISE_PROBABILITY: f64 = 0.95;

/// Whether an update's NIS lies past the 95 % point its degrees of freedom make likely: the
/// filter's prediction disagreed with the measurement, so its convergence
/// (`eskf/relative_pose_update.rs`) is not to be settled on it.
pub(crate) fn surprises(nis: f64, dof: usize) -> bool {
    surprises_one_of(nis, dof, 1.0)
}

/// As `surprises`, for one of `updates` that together span a second: each is held to the
/// chance of a surprise among all of them, so that ten 10 Hz updates surprise as often as one
/// 1 Hz update does. A direction held in doubt (`fusion::witnesses`) is released only after
/// 2 s of lone planes agreeing with it at every epoch, unsurprised. Held to the 95 % point
/// each, 11 % of `hallway-hover`'s 10 Hz updates after a start 72 s in surprised the filter,
/// and a direction its checks had confirmed from 4 s on (`Check::ConfirmedOverSecond`) was
/// held until 14 s, the velocity known to 2 mm/s all along.
pub(crate) fn surprises_one_of(nis: f64, dof: usize, updates: f64) -> bool {
    let probability = SURPRISE_PROBABILITY.powf(1.0 / updates.max(1.0));
    dof > 0 && nis > chi_square_quantile(probability, dof)
}

/// `x` such that a chi-square variable with `dof` degrees of freedom is below `x` with
/// `probability`. Infinite for probability 1 (a disabled gate).
pub(crate) fn chi_square_quantile(probability: f64, dof: usize) -> f64 {
    if probability >= 1.0 {
        return f64::INFINITY;
    }
    if dof == 0 || probability <= 0.0 {
        return 0.0;
    }
    let k = dof as f64;
    let (mut low, mut high) = (0.0, k + 20.0 * (2.0 * k).sqrt() + 100.0);
    for _ in 0..200 {
        let mid = 0.5 * (low + high);
        if chi_square_cdf(mid, dof) < probability {
            low = mid;
        } else {
            high = mid;
        }
    }
    0.5 * (low + high)
}

pub(crate) fn chi_square_cdf(x: f64, dof: usize) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    regularized_lower_gamma(dof as f64 / 2.0, x / 2.0)
}

/// `P(a, x)` by its series below `a + 1` and Lentz's continued fraction above (Numerical
/// Recipes 6.2); accurate to ~1e-14, ample for gates and test intervals.
fn regularized_lower_gamma(a: f64, x: f64) -> f64 {
    let log_prefactor = a * x.ln() - x - ln_gamma(a);
    if x < a + 1.0 {
        let (mut term, mut sum, mut n) = (1.0 / a, 1.0 / a, a);
        while term.abs() > sum.abs() * 1e-16 {
            n += 1.0;
            term *= x / n;
            sum += term;
        }
        sum * log_prefactor.exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..1000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            d = if d.abs() < tiny { tiny } else { d };
            c = b + an / c;
            c = if c.abs() < tiny { tiny } else { c };
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-16 {
                break;
            }
        }
        1.0 - log_prefactor.exp() * h
    }
}

/// Lanczos approximation (g = 7, n = 9), relative error below 1e-15 for `a > 0`.
fn ln_gamma(a: f64) -> f64 {
    const COEFFICIENTS: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    let x = a - 1.0;
    let t = x + 7.5;
    let series = COEFFICIENTS[1..]
        .iter()
        .enumerate()
        .fold(COEFFICIENTS[0], |sum, (i, c)| {
            sum + c / (x + i as f64 + 1.0)
        });
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + series.ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ten_updates_a_second_surprise_as_often_as_one() {
        // The 95 % point of 6 degrees of freedom is 12.6; for one of ten, the 99.5 % point, 18.5.
        assert!(surprises(15.0, 6));
        assert!(!surprises_one_of(15.0, 6, 10.0));
        assert!(surprises_one_of(20.0, 6, 10.0));
        assert_eq!(surprises_one_of(15.0, 6, 1.0), surprises(15.0, 6));
        let alone = chi_square_quantile(0.95, 6);
        let tenth = chi_square_quantile(0.95f64.powf(0.1), 6);
        assert!(
            (alone - 12.59).abs() < 0.01 && (tenth - 18.5).abs() < 0.1,
            "{alone} {tenth}"
        );
    }

    #[test]
    fn quantiles_match_tables() {
        // Standard table values.
        let cases = [
            (0.95, 1, 3.841_458_8),
            (0.95, 3, 7.814_727_9),
            (0.99, 6, 16.811_893_8),
            (0.999, 2, 13.815_510_6),
            (0.025, 9, 2.700_389_5),
            (0.975, 9, 19.022_767_8),
            (0.975, 900, 985.032_0),
        ];
        for (p, dof, expected) in cases {
            let x = chi_square_quantile(p, dof);
            assert!((x - expected).abs() < 1e-4 * expected, "{p} {dof}: {x}");
        }
        assert_eq!(chi_square_quantile(1.0, 3), f64::INFINITY);
    }

    #[test]
    fn nis_is_the_mahalanobis_norm() {
        let s = SMatrix::<f64, 2, 2>::new(4.0, 0.0, 0.0, 1.0);
        let y = SVector::<f64, 2>::new(2.0, 1.0);
        assert!((nis(&y, &s).unwrap() - 2.0).abs() < 1e-12);
        assert!(nis(&y, &SMatrix::<f64, 2, 2>::zeros()).is_none());
    }
}
