//! The filter's watch on its own consistency. A filter that has lost track does not say so in
//! its covariance: it goes on reporting small sigmas while its innovations grow, its gate
//! refuses every epoch, or its speed leaves what any airframe can do. Each of these is a
//! symptom the filter can see without truth; on any of them it restarts its navigation state
//! (`Eskf::reinitialise`) rather than tell the autopilot a wrong velocity is good.

use std::collections::VecDeque;
use std::fmt;

use super::config::{FilterConfig, PAPER_EPOCH_S};
use super::consistency::chi_square_cdf;

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

/// The NIS of the last `window` fused relative poses (at least about `window - 1` paper epochs
/// from the first to the last) and the refusals in a row.
///
/// Once the estimate has converged the window spans time, not a count: at 10 Hz ten epochs
/// are a second, and the NIS of neighbouring epochs, which share their planes and the deskew
/// of their scans, is not independent over so short a span. Ten of them summed 76 on 26
/// degrees of freedom in the bare corridor 170 s into a run, past the 1e-6 bound, with the
/// velocity inside a third of its sigma, and the restart cost forty seconds of usable estimate
/// and left the attitude 0.13-0.19 rad off. Before it has converged a burst of surprises is
/// what a lost start looks like, and the count stays ten: random room 123 started in motion at
/// 10 Hz summed 70 on 20 in its first 2.5 s, then settled into updates that agreed with a
/// velocity running off at 0.7 m/s^2, which a window of seconds let through as converged.
#[derive(Debug, Clone)]
pub(crate) struct DivergenceGuard {
    window: usize,
    /// Time, NIS and degrees of freedom of each fused relative pose in the window.
    recent: VecDeque<(f64, f64, usize)>,
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

    /// Takes the NIS of the relative-pose update at `t`; `accepted` is the gate's verdict and
    /// `converged` the filter's (the window spans time only once it holds).
    pub(crate) fn after_update(
        &mut self,
        t: f64,
        nis: f64,
        dof: usize,
        accepted: bool,
        converged: bool,
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
        self.recent.push_back((t, nis, dof));
        // Half an epoch short of `window - 1`, so that at the paper's rate the window is
        // `window` epochs however their times jitter.
        let span_s = if converged {
            (self.window as f64 - 1.5).max(0.0) * PAPER_EPOCH_S
        } else {
            0.0
        };
        let spans = |from: Option<&(f64, f64, usize)>| from.is_some_and(|f| t - f.0 >= span_s);
        while self.recent.len() > self.window && spans(self.recent.get(1)) {
            self.recent.pop_front();
        }
        if self.recent.len() < self.window || !spans(self.recent.front()) {
            return None;
        }
        let (nis, dof) = self
            .recent
            .iter()
            .fold((0.0, 0), |(n, d), &(_, nis, dof)| (n + nis, d + dof));
        // The distribution at the NIS rather than the quantile at the probability: one series
        // instead of a bisection of them, which the map's many rows made a tenth of an epoch.
        (chi_square_cdf(nis, dof) > WINDOW_PROBABILITY)
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
        for k in 0..1000 {
            assert_eq!(guard.after_update(f64::from(k), 6.0, 6, true, true), None);
        }
    }

    #[test]
    fn a_window_of_large_innovations_trips_it() {
        let mut guard = guard();
        let tripped = (0..20).find_map(|k| guard.after_update(f64::from(k), 25.0, 6, true, true));
        assert!(
            matches!(tripped, Some(Divergence::Innovations { dof, .. }) if dof == 60),
            "{tripped:?}"
        );
    }

    /// At 10 Hz a second of neighbouring epochs that agree with the converged filter less well
    /// than their sigmas say is no divergence; ten seconds of them are, and so is the same
    /// second before it has converged.
    #[test]
    fn at_faster_epochs_the_window_spans_as_many_seconds_once_converged() {
        let at_10_hz = |k: u32| f64::from(k) * 0.1;
        let burst = |converged: bool| {
            let mut guard = guard();
            for k in 0..100 {
                assert_eq!(
                    guard.after_update(at_10_hz(k), 2.5, 3, true, converged),
                    None
                );
            }
            (100..110).find_map(|k| guard.after_update(at_10_hz(k), 9.0, 3, true, converged))
        };
        assert_eq!(burst(true), None);
        assert!(matches!(
            burst(false),
            Some(Divergence::Innovations { dof: 30, .. })
        ));
        let mut guard = guard();
        let tripped = (0..300).find_map(|k| guard.after_update(at_10_hz(k), 9.0, 3, true, true));
        assert!(
            matches!(tripped, Some(Divergence::Innovations { dof, .. }) if dof >= 250),
            "{tripped:?}"
        );
    }

    #[test]
    fn refusals_in_a_row_trip_it_and_one_acceptance_resets_the_count() {
        let mut guard = guard();
        let limit = FilterConfig::default().divergence_refused_in_row;
        for _ in 1..limit {
            assert_eq!(guard.after_update(0.0, 2.0, 6, false, true), None);
        }
        assert_eq!(guard.after_update(0.0, 2.0, 6, true, true), None);
        for _ in 1..limit {
            assert_eq!(guard.after_update(0.0, 2.0, 6, false, true), None);
        }
        assert_eq!(
            guard.after_update(0.0, 2.0, 6, false, true),
            Some(Divergence::RefusedInRow { count: limit })
        );
    }

    #[test]
    fn an_update_with_nothing_observable_says_nothing() {
        let mut guard = guard();
        for k in 0..100 {
            assert_eq!(guard.after_update(f64::from(k), 0.0, 0, false, true), None);
        }
    }

    #[test]
    fn speeds_beyond_the_limit_trip_it() {
        let guard = guard();
        assert_eq!(guard.check_speed(3.0), None);
        assert!(guard.check_speed(40.0).is_some());
    }
}
