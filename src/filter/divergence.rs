//! The filter's watch on its own consistency. A filter that has lost track does not say so in
//! its covariance: it goes on reporting small sigmas while its innovations grow, its gate
//! refuses every epoch, or its speed leaves what any airframe can do. Each of these is a
//! symptom the filter can see without truth; on any of them it restarts its navigation state
//! (`Eskf::reinitialise`) rather than tell the autopilot a wrong velocity is good.

use std::collections::VecDeque;
use std::fmt;

use super::chi_square_quantile;
use super::config::FilterConfig;

/// Probability of the windowed-NIS test: a consistent filter trips it once in a million
/// windows, so a trip is a lost filter, not bad luck.
const WINDOW_PROBABILITY: f64 = 1.0 - 1e-6;

/// What made the guard decide the filter had lost track.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Divergence {
    /// The relative poses fused over the last window disagreed with the filter far beyond
    /// their covariances.
    Innovations { nis: f64, dof: usize },
    /// The gate refused this many relative poses in a row.
    RefusedInRow { count: u32 },
    /// The estimated speed is beyond what the platform can fly.
    ImpossibleSpeed { mps: f64 },
}

impl fmt::Display for Divergence {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Innovations { nis, dof } => write!(
                f,
                "odometry innovations inconsistent (windowed NIS {nis:.0} over {dof} dof)"
            ),
            Self::RefusedInRow { count } => {
                write!(f, "{count} odometry epochs in a row refused by the gate")
            }
            Self::ImpossibleSpeed { mps } => write!(f, "impossible speed {mps:.1} m/s"),
        }
    }
}

/// The NIS of the last `window` fused relative poses and the refusals in a row.
#[derive(Debug, Clone)]
pub(crate) struct DivergenceGuard {
    window: usize,
    recent: VecDeque<(f64, usize)>,
    refused_in_row: u32,
    max_refused_in_row: u32,
    max_speed_mps: f64,
}

impl DivergenceGuard {
    pub(crate) fn new(config: &FilterConfig) -> Self {
        Self {
            window: config.divergence_window as usize,
            recent: VecDeque::with_capacity(config.divergence_window as usize),
            refused_in_row: 0,
            max_refused_in_row: config.divergence_refused_in_row,
            max_speed_mps: config.max_speed_mps,
        }
    }

    /// Forgets the history (after a restart, the old innovations say nothing of the new state).
    pub(crate) fn clear(&mut self) {
        self.recent.clear();
        self.refused_in_row = 0;
    }

    /// Takes one relative-pose update's NIS; `accepted` is the gate's verdict.
    pub(crate) fn after_update(
        &mut self,
        nis: f64,
        dof: usize,
        accepted: bool,
    ) -> Option<Divergence> {
        if dof == 0 {
            return None;
        }
        if !accepted {
            self.refused_in_row += 1;
            return (self.refused_in_row >= self.max_refused_in_row).then_some(
                Divergence::RefusedInRow {
                    count: self.refused_in_row,
                },
            );
        }
        // A refused epoch's NIS is an outlier the gate already kept out; only the accepted
        // ones say whether the filter agrees with what it fuses.
        self.refused_in_row = 0;
        if self.recent.len() == self.window {
            self.recent.pop_front();
        }
        self.recent.push_back((nis, dof));
        if self.recent.len() < self.window {
            return None;
        }
        let (nis, dof) = self
            .recent
            .iter()
            .fold((0.0, 0), |(n, d), &(nis, dof)| (n + nis, d + dof));
        (nis > chi_square_quantile(WINDOW_PROBABILITY, dof))
            .then_some(Divergence::Innovations { nis, dof })
    }

    pub(crate) fn check_speed(&self, speed_mps: f64) -> Option<Divergence> {
        (speed_mps > self.max_speed_mps).then_some(Divergence::ImpossibleSpeed { mps: speed_mps })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn guard() -> DivergenceGuard {
        DivergenceGuard::new(&FilterConfig::default())
    }

    #[test]
    fn consistent_innovations_never_trip_the_window() {
        let mut guard = guard();
        for _ in 0..1000 {
            assert_eq!(guard.after_update(6.0, 6, true), None);
        }
    }

    #[test]
    fn a_window_of_large_innovations_trips_it() {
        let mut guard = guard();
        let tripped = (0..20).find_map(|_| guard.after_update(25.0, 6, true));
        assert!(
            matches!(tripped, Some(Divergence::Innovations { dof, .. }) if dof == 60),
            "{tripped:?}"
        );
    }

    #[test]
    fn refusals_in_a_row_trip_it_and_one_acceptance_resets_the_count() {
        let mut guard = guard();
        let limit = FilterConfig::default().divergence_refused_in_row;
        for _ in 1..limit {
            assert_eq!(guard.after_update(2.0, 6, false), None);
        }
        assert_eq!(guard.after_update(2.0, 6, true), None);
        for _ in 1..limit {
            assert_eq!(guard.after_update(2.0, 6, false), None);
        }
        assert_eq!(
            guard.after_update(2.0, 6, false),
            Some(Divergence::RefusedInRow { count: limit })
        );
    }

    #[test]
    fn an_update_with_nothing_observable_says_nothing() {
        let mut guard = guard();
        for _ in 0..100 {
            assert_eq!(guard.after_update(0.0, 0, false), None);
        }
    }

    #[test]
    fn speeds_beyond_the_limit_trip_it() {
        let guard = guard();
        assert_eq!(guard.check_speed(3.0), None);
        assert!(guard.check_speed(40.0).is_some());
    }
}
