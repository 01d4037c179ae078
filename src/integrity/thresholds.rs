//! Test thresholds from the risk budgets (eqs 39-40): the gamma of each per-plane test, the
//! global chi-square threshold and the multiples that turn them into detectable biases.
//!
//! Budget split (Bonferroni): a scope (one solve, or one of the two solves of an epoch) is given
//! a false-alarm probability `P`. Half goes to the global chi-square test on the parity vector,
//! half is shared equally by the `n` per-plane tests, each at `P / (2 n)`. By the union bound the
//! scope is flagged with probability at most `P` when nothing is wrong; because the tests are
//! strongly correlated the actual rate lies between `P / 2` and `P`.
//!
//! Exception: a parity space of one dimension. Then the global test and every plane's test are
//! the same statistic `|p|` (each plane sees the one parity component), so splitting the budget
//! would spend it `n + 1` times on one event and the scope would be flagged with probability
//! only `P / (2 n)`; that single test gets the whole budget `P` instead ([`Thresholds::sole`]).

use statrs::function::erf::erfc_inv;
use statrs::function::gamma::{gamma_ur, ln_gamma};

/// Thresholds are precomputed up to this many degrees of freedom or tests (2M - 3 for 65 planes);
/// larger parity spaces are computed on demand.
const CACHED: usize = 128;

/// The thresholds of one scope, precomputed so that a test costs no quantile evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct Thresholds {
    false_alarm: f64,
    /// `z_(1-Pmd)`: a test at threshold gamma detects noncentrality `gamma + z_(1-Pmd)` with
    /// probability at least `1 - Pmd` (exactly, ignoring the far tail, for one row a plane;
    /// conservatively for more rows, whose orthogonal components only add to the statistic).
    pub missed_detection_quantile: f64,
    /// `z_(1-Pmd/2)`: noise sigmas added to a protection level so that an undetected fault of
    /// MDB size stays inside it with probability at least `1 - Pmd`.
    pub noise_quantile: f64,
    global: Vec<f64>,
    /// Threshold on `|p|` when the parity space has one dimension.
    sole: f64,
    /// Per-plane thresholds for one to four rows (a plane's, or a mapped surface's two lines),
    /// by number of tests.
    per_plane: [Vec<f64>; 4],
}

impl Thresholds {
    pub fn new(false_alarm: f64, missed_detection: f64) -> Self {
        let global = (1..=CACHED)
            .map(|dof| chi_square_upper_quantile(dof, false_alarm / 2.0))
            .collect();
        let per_plane = [1, 2, 3, 4].map(|dof| {
            (1..=CACHED)
                .map(|tests| plane_threshold(false_alarm, dof, tests))
                .collect()
        });
        Self {
            false_alarm,
            per_plane,
            missed_detection_quantile: normal_upper_quantile(missed_detection),
            noise_quantile: normal_upper_quantile(missed_detection / 2.0),
            global,
            sole: normal_upper_quantile(false_alarm / 2.0),
        }
    }

    /// Threshold of the global test: `|p|^2` of the whitened parity vector with `dof` components.
    pub(crate) fn global(&self, dof: usize) -> f64 {
        match self.global.get(dof.wrapping_sub(1)) {
            Some(&threshold) => threshold,
            None => chi_square_upper_quantile(dof, self.false_alarm / 2.0),
        }
    }

    /// Threshold on `|p|`, the global test and every plane's test at once, when the parity
    /// space has one dimension: the whole scope budget, two-sided.
    pub fn sole(&self) -> f64 {
        self.sole
    }

    /// Threshold (eq 39's gamma) on one plane's normalised residual, the square root of its
    /// chi-square statistic with `plane_dof` testable rows, when `tests` planes are tested.
    pub(crate) fn per_plane(&self, plane_dof: usize, tests: usize) -> f64 {
        let cached = self.per_plane.get(plane_dof.wrapping_sub(1));
        match cached.and_then(|by_tests| by_tests.get(tests.wrapping_sub(1))) {
            Some(&threshold) => threshold,
            None => plane_threshold(self.false_alarm, plane_dof, tests),
        }
    }
}

fn plane_threshold(false_alarm: f64, plane_dof: usize, tests: usize) -> f64 {
    let alpha = false_alarm / (2.0 * tests.max(1) as f64);
    chi_square_upper_quantile(plane_dof, alpha).sqrt()
}

/// `z` with `P(N(0,1) > z) = alpha`.
pub(crate) fn normal_upper_quantile(alpha: f64) -> f64 {
    std::f64::consts::SQRT_2 * erfc_inv(2.0 * alpha)
}

/// `x` with `P(chi2_dof > x) = alpha`, accurate deep into the tail (Newton on the log of the
/// survival function rather than on `1 - alpha`, which rounds to 1 for tiny `alpha`).
pub fn chi_square_upper_quantile(dof: usize, alpha: f64) -> f64 {
    match dof {
        0 => 0.0,
        1 => normal_upper_quantile(alpha / 2.0).powi(2),
        2 => -2.0 * alpha.ln(),
        _ => newton_chi_square(dof as f64, alpha),
    }
}

fn newton_chi_square(k: f64, alpha: f64) -> f64 {
    let target = alpha.ln();
    let log_norm = 0.5 * k * std::f64::consts::LN_2 + ln_gamma(0.5 * k);
    // Wilson-Hilferty gives a start within a few percent.
    let c = 2.0 / (9.0 * k);
    let mut x = (k * (1.0 - c + normal_upper_quantile(alpha) * c.sqrt()).powi(3)).max(1e-3);
    let (mut low, mut high) = (0.0_f64, f64::INFINITY);
    for _ in 0..200 {
        let survival = gamma_ur(0.5 * k, 0.5 * x);
        let excess = survival.ln() - target;
        if excess > 0.0 {
            low = x;
        } else {
            high = x;
        }
        let log_pdf = (0.5 * k - 1.0) * x.ln() - 0.5 * x - log_norm;
        // d ln S / dx = -pdf / S
        let next = x + excess * survival / log_pdf.exp();
        let next = if next.is_finite() && next > low && next < high {
            next
        } else if high.is_finite() {
            0.5 * (low + high)
        } else {
            2.0 * x
        };
        if (next - x).abs() <= 1e-13 * x {
            return next;
        }
        x = next;
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, rel: f64) -> bool {
        (a - b).abs() <= rel * b.abs()
    }

    #[test]
    fn normal_quantiles_match_tables() {
        assert!(close(
            normal_upper_quantile(0.025),
            1.959_963_984_540_054,
            1e-12
        ));
        assert!(close(
            normal_upper_quantile(1e-3),
            3.090_232_306_167_813,
            1e-12
        ));
        // The paper's gamma 4.4 for 1e-5 two-sided is z(5e-6) = 4.4172.
        assert!(close(
            normal_upper_quantile(5e-6),
            4.417_173_413_469_02,
            1e-10
        ));
    }

    #[test]
    fn chi_square_quantiles_match_tables_and_closed_forms() {
        assert!(close(
            chi_square_upper_quantile(3, 0.05),
            7.814_727_903_251_178,
            1e-10
        ));
        assert!(close(
            chi_square_upper_quantile(10, 1e-3),
            29.588_298_445_074_3,
            1e-10
        ));
        assert!(close(
            chi_square_upper_quantile(15, 0.5),
            14.338_859_510_956_03,
            1e-10
        ));
        assert!(close(
            chi_square_upper_quantile(1, 0.05),
            3.841_458_820_694_124,
            1e-12
        ));
        for dof in 3..60 {
            for alpha in [0.3, 1e-2, 1e-6, 1e-15, 1e-100] {
                let x = chi_square_upper_quantile(dof, alpha);
                let back = gamma_ur(dof as f64 / 2.0, x / 2.0);
                assert!(close(back, alpha, 1e-9), "dof {dof} alpha {alpha}: {back}");
            }
        }
    }

    #[test]
    fn one_parity_dimension_spends_the_whole_budget_on_its_one_test() {
        let t = Thresholds::new(1e-3, 1e-3);
        assert!(close(t.sole(), normal_upper_quantile(5e-4), 1e-12));
        assert!(t.sole() < t.per_plane(1, 4));
        assert!(t.sole().powi(2) < t.global(1));
    }

    #[test]
    fn per_plane_thresholds_split_the_budget() {
        let t = Thresholds::new(1e-3, 1e-3);
        // One row: two-sided normal at 1e-3 / 2 / 5 tests.
        assert!(close(t.per_plane(1, 5), normal_upper_quantile(5e-5), 1e-12));
        // Two rows: sqrt(-2 ln alpha).
        assert!(close(
            t.per_plane(2, 5),
            (-2.0 * 1e-4_f64.ln()).sqrt(),
            1e-12
        ));
        assert!(close(
            t.global(7),
            chi_square_upper_quantile(7, 5e-4),
            1e-15
        ));
        assert!(close(
            t.global(300),
            chi_square_upper_quantile(300, 5e-4),
            1e-15
        ));
        assert!(close(
            t.missed_detection_quantile,
            3.090_232_306_167_813,
            1e-12
        ));
    }
}
