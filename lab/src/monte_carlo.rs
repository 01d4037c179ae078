//! Monte Carlo consistency (Bar-Shalom, Li and Kirubarajan, "Estimation with Applications to
//! Tracking and Navigation", sec. 5.4): N independent seeded runs of one scenario, the NEES
//! averaged over the runs at each comparison time, and that average compared with the
//! interval of `chi2(N dof) / N`.
//!
//! One run's time average is no yardstick for the states the odometry only dead-reckons
//! (absolute position, yaw): their errors are random walks, so one run's samples are strongly
//! correlated and their average is far from chi-square with `dof * K` degrees of freedom. The
//! run average at one time is a sum of independent terms, whatever the time correlation; so are
//! the runs' own time averages, whose spread gives the confidence interval of the mean.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::Serialize;
use statrs::distribution::{ContinuousCDF, StudentsT};

use crate::evaluate::{run_scenario_recorded, EvaluationError, NeesPart, NeesSample, RecordedRun};
use ladar_odometer::filter::{mean_nees_interval, FilterConfig};
use ladar_odometer::fusion::FusionSettings;
use ladar_sim::{Scenario, TriadErrors};

/// Where each run's IMU turn-on biases and scale factors come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum UnitErrors {
    /// The scenario's unit in every run: only the noise and the bias walks differ.
    AsScenario,
    /// A different unit per run, drawn from the filter's initial sigmas (`initial_sigma_*`):
    /// the truth then has the distribution the filter assumes, as a consistency test needs.
    DrawnFromFilterPrior,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MonteCarloSettings {
    pub runs: usize,
    /// Run k uses the scenario with seed `first_seed + k`.
    pub first_seed: u64,
    pub unit_errors: UnitErrors,
}

/// One `NeesPart` over all runs and comparison times.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NeesStatistic {
    pub part: NeesPart,
    pub dof: usize,
    /// Time average of the run-averaged NEES (`dof` for a consistent filter).
    pub mean: f64,
    /// 95 % interval of `mean` for `runs * times * dof` degrees of freedom. The comparison
    /// times of one run are correlated, so this interval is too narrow: `between_runs_interval`
    /// is the test of `mean`, `fraction_inside` that of the times.
    pub interval: [f64; 2],
    /// 95 % confidence interval of the expected time-averaged NEES, from the spread of the
    /// runs' own time averages (Student's t with `runs - 1` dof); `None` with fewer than two
    /// runs. The runs are independent, so unlike `interval` this one holds whatever the
    /// correlation between one run's times: a consistent filter has `dof` inside it in 95 % of
    /// studies.
    pub between_runs_interval: Option<[f64; 2]>,
    /// 95 % interval of the run average at one time, `chi2(runs * dof) / runs`.
    pub per_time_interval: [f64; 2],
    /// Fraction of the comparison times whose run average lies inside `per_time_interval`
    /// (0.95 for a consistent filter).
    pub fraction_inside: f64,
    /// Fraction above it: where the filter is optimistic.
    pub fraction_above: f64,
    /// Fraction below it: where the filter is conservative.
    pub fraction_below: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MonteCarloReport {
    pub scenario: String,
    pub settings: MonteCarloSettings,
    /// Comparison times per run (once a second after the stationary start).
    pub times: usize,
    pub from_s: f64,
    pub to_s: f64,
    /// In `NeesPart::ALL` order.
    pub nees: Vec<NeesStatistic>,
    /// Mean over the runs of each run's average NIS per degree of freedom.
    pub nis_per_dof_mean: f64,
    /// Root mean square over the runs of the horizontal position error at the end, m.
    pub horizontal_error_end_rms_m: f64,
    /// Mean over the runs of each run's velocity error std per NED axis, m/s.
    pub velocity_error_std_ned_mean: [f64; 3],
    /// Mean over the runs of each run's roll, pitch, yaw error std, mrad.
    pub attitude_error_std_mrad_mean: [f64; 3],
    /// Fused epochs, summed over the runs.
    pub fused_epochs: u64,
}

impl MonteCarloReport {
    pub fn part(&self, part: NeesPart) -> &NeesStatistic {
        &self.nees[part as usize]
    }
}

/// Why a Monte Carlo study could not run.
#[derive(Debug, thiserror::Error)]
pub enum MonteCarloError {
    #[error("{0}")]
    Evaluation(#[from] EvaluationError),
    #[error("a Monte Carlo study needs at least one run: set runs to 1 or more")]
    NoRuns,
    #[error("run {run} compared at {got} s where run 0 compared at {expected} s: the runs must share their timing, vary only the seed")]
    TimesDiffer { run: usize, expected: f64, got: f64 },
    #[error("scenario {0} has no IMU: the fusion needs one")]
    NoImu(String),
}

/// Runs the scenario `settings.runs` times through the fusion and averages the NEES over
/// the runs at each comparison time.
pub fn run_monte_carlo(
    scenario: &Scenario,
    fusion: &FusionSettings,
    settings: &MonteCarloSettings,
) -> Result<MonteCarloReport, MonteCarloError> {
    if settings.runs == 0 {
        return Err(MonteCarloError::NoRuns);
    }
    let runs = run_all(scenario, fusion, settings)?;
    let (series, reports): (Vec<_>, Vec<_>) = runs.into_iter().map(|r| (r.nees, r.report)).unzip();
    let times = common_times(&series)?;
    let runs = reports.len() as f64;
    let mean_of = |f: &dyn Fn(&crate::evaluate::AccuracyReport) -> f64| {
        reports.iter().map(f).sum::<f64>() / runs
    };
    Ok(MonteCarloReport {
        scenario: scenario.name.clone(),
        settings: *settings,
        times,
        from_s: reports[0].from_s,
        to_s: reports[0].to_s,
        nees: NeesPart::ALL
            .iter()
            .map(|&part| nees_statistic(&series, times, part))
            .collect(),
        nis_per_dof_mean: mean_of(&|r| r.nis_per_dof_mean),
        horizontal_error_end_rms_m: mean_of(&|r| r.horizontal_error_end_m.powi(2)).sqrt(),
        velocity_error_std_ned_mean: std::array::from_fn(|axis| {
            mean_of(&|r| r.velocity_error_std_ned[axis])
        }),
        attitude_error_std_mrad_mean: std::array::from_fn(|axis| {
            mean_of(&|r| r.attitude_error_std_mrad[axis])
        }),
        fused_epochs: reports.iter().map(|r| r.epochs.fused).sum(),
    })
}

/// Every run of the study, in seed order. The runs are independent and each is deterministic
/// in its seed, so they are spread over the machine's cores with the same result.
fn run_all(
    scenario: &Scenario,
    fusion: &FusionSettings,
    settings: &MonteCarloSettings,
) -> Result<Vec<RecordedRun>, MonteCarloError> {
    let workers = std::thread::available_parallelism()
        .map_or(1, usize::from)
        .min(settings.runs);
    let run = &|k: usize| -> Result<RecordedRun, MonteCarloError> {
        let seed = settings.first_seed + k as u64;
        let run_scenario = seeded(scenario, seed, settings.unit_errors, &fusion.filter)?;
        Ok(run_scenario_recorded(
            &run_scenario,
            fusion,
            &mut |_, _| {},
        )?)
    };
    let per_worker = settings.runs.div_ceil(workers);
    std::thread::scope(|scope| {
        let workers: Vec<_> = (0..workers)
            .map(|w| {
                let seeds = w * per_worker..((w + 1) * per_worker).min(settings.runs);
                scope.spawn(move || seeds.map(run).collect::<Vec<_>>())
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|worker| {
                worker
                    .join()
                    .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
            })
            .collect()
    })
}

/// The scenario with `seed` and, if asked, a unit drawn from the filter's prior. The unit is
/// drawn from its own stream, so the sensor noise of a seed is the same either way.
fn seeded(
    scenario: &Scenario,
    seed: u64,
    unit_errors: UnitErrors,
    filter: &FilterConfig,
) -> Result<Scenario, MonteCarloError> {
    let mut scenario = scenario.clone();
    scenario.seed = seed;
    if unit_errors == UnitErrors::AsScenario {
        return Ok(scenario);
    }
    let name = scenario.name.clone();
    let imu = scenario.imu.as_mut().ok_or(MonteCarloError::NoImu(name))?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(1);
    draw_unit(
        &mut imu.gyro,
        filter.initial_sigma_gyro_bias,
        filter.initial_sigma_gyro_scale,
        &mut rng,
    );
    draw_unit(
        &mut imu.accel,
        filter.initial_sigma_accel_bias,
        filter.initial_sigma_accel_scale,
        &mut rng,
    );
    Ok(scenario)
}

fn draw_unit(triad: &mut TriadErrors, bias_sigma: f64, scale_sigma: f64, rng: &mut ChaCha8Rng) {
    let mut normal = || -> f64 { rng.sample(StandardNormal) };
    triad.turn_on_bias = std::array::from_fn(|_| bias_sigma * normal());
    triad.scale_factor = std::array::from_fn(|_| scale_sigma * normal());
}

/// Comparison times all runs share (the shortest run's), checked to be the same times.
fn common_times(series: &[Vec<NeesSample>]) -> Result<usize, MonteCarloError> {
    let times = series.iter().map(Vec::len).min().unwrap_or(0);
    for (run, samples) in series.iter().enumerate() {
        for (sample, first) in samples.iter().zip(&series[0]).take(times) {
            if (sample.t - first.t).abs() > 1e-6 {
                return Err(MonteCarloError::TimesDiffer {
                    run,
                    expected: first.t,
                    got: sample.t,
                });
            }
        }
    }
    Ok(times)
}

/// Statistics of one part over `series` (runs of at least `times` samples each).
pub fn nees_statistic(series: &[Vec<NeesSample>], times: usize, part: NeesPart) -> NeesStatistic {
    let runs = series.len().max(1);
    let dof = part.dof();
    let per_time_interval = mean_nees_interval(dof, runs);
    let averages: Vec<f64> = (0..times)
        .map(|k| series.iter().map(|run| run[k].get(part)).sum::<f64>() / runs as f64)
        .collect();
    let fraction = |test: &dyn Fn(f64) -> bool| {
        averages.iter().filter(|&&a| test(a)).count() as f64 / times.max(1) as f64
    };
    let [low, high] = per_time_interval;
    let run_means: Vec<f64> = series
        .iter()
        .map(|run| run[..times].iter().map(|s| s.get(part)).sum::<f64>() / times.max(1) as f64)
        .collect();
    NeesStatistic {
        part,
        dof,
        mean: averages.iter().sum::<f64>() / times.max(1) as f64,
        interval: mean_nees_interval(dof, runs * times.max(1)),
        between_runs_interval: confidence_interval_of_mean(&run_means),
        per_time_interval,
        fraction_inside: fraction(&|a| (low..=high).contains(&a)),
        fraction_above: fraction(&|a| a > high),
        fraction_below: fraction(&|a| a < low),
    }
}

/// 95 % Student's t confidence interval of the mean of independent `values`.
fn confidence_interval_of_mean(values: &[f64]) -> Option<[f64; 2]> {
    let n = values.len();
    if n < 2 {
        return None;
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    let variance = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let t = StudentsT::new(0.0, 1.0, (n - 1) as f64)
        .ok()?
        .inverse_cdf(0.975);
    let half_width = t * (variance / n as f64).sqrt();
    Some([mean - half_width, mean + half_width])
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_distr::{ChiSquared, Distribution};

    /// Runs whose every part is an independent chi-square draw of its dof, times `scale`.
    fn synthetic(runs: usize, times: usize, scale: f64, seed: u64) -> Vec<Vec<NeesSample>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..runs)
            .map(|_| {
                (0..times)
                    .map(|k| NeesSample {
                        t: k as f64,
                        values: NeesPart::ALL.map(|part| {
                            scale * ChiSquared::new(part.dof() as f64).unwrap().sample(&mut rng)
                        }),
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn a_consistent_filter_lies_inside_about_95_percent_of_the_time() {
        let series = synthetic(30, 400, 1.0, 7);
        for part in NeesPart::ALL {
            let statistic = nees_statistic(&series, 400, part);
            assert!(
                (statistic.mean - part.dof() as f64).abs() < 0.05 * part.dof() as f64,
                "{statistic:?}"
            );
            assert!(
                statistic.mean >= statistic.interval[0] && statistic.mean <= statistic.interval[1],
                "{statistic:?}"
            );
            assert!(
                (0.92..=0.98).contains(&statistic.fraction_inside),
                "{statistic:?}"
            );
            let total =
                statistic.fraction_inside + statistic.fraction_above + statistic.fraction_below;
            assert!((total - 1.0).abs() < 1e-12);
        }
    }

    /// Runs of a consistent filter whose errors are correlated in time, as dead-reckoned
    /// states are: each error component is a stationary AR(1) process of unit variance with
    /// lag-one correlation `rho`, so each sample is chi-square but one run's samples are not
    /// independent.
    fn correlated(
        runs: usize,
        times: usize,
        rho: f64,
        rng: &mut ChaCha8Rng,
    ) -> Vec<Vec<NeesSample>> {
        let innovation = (1.0 - rho * rho).sqrt();
        (0..runs)
            .map(|_| {
                let mut errors = NeesPart::ALL.map(|part| -> Vec<f64> {
                    (0..part.dof())
                        .map(|_| rng.sample(StandardNormal))
                        .collect()
                });
                (0..times)
                    .map(|k| {
                        for component in errors.iter_mut().flatten() {
                            let w: f64 = rng.sample(StandardNormal);
                            *component = rho * *component + innovation * w;
                        }
                        NeesSample {
                            t: k as f64,
                            values: errors.each_ref().map(|e| e.iter().map(|v| v * v).sum()),
                        }
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn the_between_runs_interval_holds_when_one_runs_times_are_correlated() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let studies = 400;
        // Coverage: how often the study says "consistent" of a filter that is.
        let (mut between_covers, mut pooled_covers) = (0, 0);
        for _ in 0..studies {
            let statistic = nees_statistic(
                &correlated(10, 100, 0.98, &mut rng),
                100,
                NeesPart::Position,
            );
            let dof = statistic.dof as f64;
            let [low, high] = statistic.between_runs_interval.unwrap();
            between_covers += usize::from((low..=high).contains(&dof));
            let [low, high] = statistic.interval;
            pooled_covers += usize::from((low..=high).contains(&statistic.mean));
        }
        let between = between_covers as f64 / studies as f64;
        let pooled = pooled_covers as f64 / studies as f64;
        assert!(
            (0.91..=0.98).contains(&between),
            "between-runs coverage {between}"
        );
        assert!(
            pooled < 0.6,
            "pooled coverage {pooled}: the correlation should defeat it"
        );
    }

    #[test]
    fn the_between_runs_interval_needs_two_runs_and_excludes_a_scaled_nees() {
        let single = nees_statistic(&synthetic(1, 50, 1.0, 3), 50, NeesPart::Full);
        assert_eq!(single.between_runs_interval, None);
        let optimistic = nees_statistic(&synthetic(20, 100, 1.2, 4), 100, NeesPart::Full);
        let [low, _] = optimistic.between_runs_interval.unwrap();
        assert!(low > 9.0, "{optimistic:?}");
    }

    #[test]
    fn an_optimistic_or_conservative_filter_is_caught() {
        let optimistic = nees_statistic(&synthetic(30, 400, 1.5, 8), 400, NeesPart::Full);
        assert!(optimistic.mean > optimistic.interval[1]);
        assert!(optimistic.fraction_above > 0.9, "{optimistic:?}");
        let conservative = nees_statistic(&synthetic(30, 400, 0.6, 9), 400, NeesPart::Full);
        assert!(conservative.mean < conservative.interval[0]);
        assert!(conservative.fraction_below > 0.9, "{conservative:?}");
    }

    #[test]
    fn drawn_units_follow_the_filter_prior_and_leave_the_noise_seed() {
        let scenario = Scenario::builtin("hallway-hover").unwrap();
        let filter = FilterConfig::default();
        let drawn: Vec<Scenario> = (0..400)
            .map(|seed| seeded(&scenario, seed, UnitErrors::DrawnFromFilterPrior, &filter))
            .collect::<Result<_, _>>()
            .unwrap();
        assert!(drawn.iter().enumerate().all(|(k, s)| s.seed == k as u64));
        let sigma = |values: Vec<f64>| {
            (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
        };
        let accel_bias = sigma(
            drawn
                .iter()
                .flat_map(|s| s.imu.as_ref().unwrap().accel.turn_on_bias)
                .collect(),
        );
        let gyro_scale = sigma(
            drawn
                .iter()
                .flat_map(|s| s.imu.as_ref().unwrap().gyro.scale_factor)
                .collect(),
        );
        assert!((accel_bias / filter.initial_sigma_accel_bias - 1.0).abs() < 0.1);
        assert!((gyro_scale / filter.initial_sigma_gyro_scale - 1.0).abs() < 0.1);
        let kept = seeded(&scenario, 5, UnitErrors::AsScenario, &filter).unwrap();
        assert_eq!(kept.imu, scenario.imu);
    }
}
