//! Time alignment: maps a sensor's free-running tick counter (SCIP 24-bit milliseconds, Xsens
//! SampleTimeFine at 10 kHz) onto the host monotonic clock.
//!
//! A packet stamped with device time `x` is received at host time `y = a + (1 + d) x + l`
//! with an unknown offset `a`, a drift `d` of tens of ppm and a latency `l >= 0` (USB, serial,
//! scheduling) that is often small and sometimes large. The host time of the device instant is
//! the lower envelope of the `(x, y)` cloud, so the estimator keeps the least-delayed packet
//! of each `bin_s` of device time over a sliding window and fits a line through those minima
//! by least squares (the windowed minimum-delay fit of NTP-style clock filters). Latency
//! spikes, jitter and dropped packets only change which packet is the minimum of a bin.
//!
//! The counter is unwrapped with its modulus (2^24 for SCIP, 864,000,000 for the MTi-10/100
//! series, 2^32 for the MTi-1 and 600 series), taking each step as the signed difference closest to
//! zero, so small backward steps (Xsens frames stamped with the GNSS sample time) are kept as
//! such. A step the host clock contradicts by more than `max_jump_s` (a sensor reset, `RS`)
//! restarts the estimate and is counted.

use std::collections::VecDeque;

use thiserror::Error;

/// Parameters of one sensor clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ClockConfig {
    /// Counter ticks per second.
    pub tick_hz: f64,
    /// The counter wraps to 0 at this value.
    pub modulus: u64,
    /// Device-time width of one minimum-delay bin, s.
    pub bin_s: f64,
    /// Number of bins in the fitted window.
    pub window_bins: usize,
    /// Largest disagreement between device and host steps accepted as the same clock, s.
    pub max_jump_s: f64,
    /// Largest believable drift (crystal tolerance); fits beyond it are clamped.
    pub max_drift: f64,
    /// Completed bins needed before the drift is estimated (until then it is taken as 0).
    pub min_bins_for_drift: usize,
}

impl ClockConfig {
    /// Hokuyo SCIP 2.0: 24-bit millisecond counter.
    #[cfg(test)]
    pub(crate) fn scip() -> Self {
        Self::with_counter(1000.0, 1 << 24)
    }
    /// Xsens MTi-10/100 series (MTi-G-700/710): 10 kHz, wraps after one day.
    #[cfg(test)]
    pub(crate) fn xsens_100_series() -> Self {
        Self::with_counter(10_000.0, 864_000_000)
    }
    /// Xsens MTi-1 and 600 series: 10 kHz, wraps at 2^32.
    #[cfg(test)]
    pub(crate) fn xsens_600_series() -> Self {
        Self::with_counter(10_000.0, 1 << 32)
    }

    pub(crate) fn with_counter(tick_hz: f64, modulus: u64) -> Self {
        Self {
            tick_hz,
            modulus,
            bin_s: 1.0,
            window_bins: 30,
            max_jump_s: 1.0,
            max_drift: 500e-6,
            min_bins_for_drift: 5,
        }
    }
}

/// A clock configuration the estimator cannot work with.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[error("clock {key} = {value} is invalid: {fix}")]
pub(crate) struct ClockConfigError {
    pub key: &'static str,
    pub value: f64,
    pub fix: &'static str,
}

impl ClockConfig {
    pub(crate) fn validate(&self) -> Result<(), ClockConfigError> {
        let checks = [
            (
                "tick_hz",
                self.tick_hz,
                self.tick_hz > 0.0 && self.tick_hz.is_finite(),
                "set the counter rate in Hz",
            ),
            (
                "modulus",
                self.modulus as f64,
                (2..=1 << 62).contains(&self.modulus),
                "set the wrap value, 2 to 2^62",
            ),
            (
                "bin_s",
                self.bin_s,
                self.bin_s > 0.0 && self.bin_s.is_finite(),
                "set a positive bin width in s",
            ),
            (
                "window_bins",
                self.window_bins as f64,
                self.window_bins >= 2,
                "keep at least 2 bins",
            ),
            (
                "max_jump_s",
                self.max_jump_s,
                self.max_jump_s > 0.0,
                "set a positive jump limit in s",
            ),
            (
                "max_drift",
                self.max_drift,
                (0.0..0.1).contains(&self.max_drift),
                "set a drift limit below 0.1",
            ),
        ];
        match checks.iter().find(|(_, _, ok, _)| !ok) {
            Some(&(key, value, _, fix)) => Err(ClockConfigError { key, value, fix }),
            None => Ok(()),
        }
    }
}

/// The least-delayed packet of one bin: device time (relative to the first packet) and
/// `host - device`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Minimum {
    x: f64,
    y: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Bin {
    index: i64,
    minimum: Minimum,
}

/// Offset `host - device` at device time `x`: `offset + drift * x`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ClockFit {
    pub offset_s: f64,
    /// Host seconds per device second, minus one.
    pub drift: f64,
}

#[derive(Debug, Clone)]
pub(crate) struct ClockEstimator {
    config: ClockConfig,
    origin: Option<Origin>,
    bins: VecDeque<Bin>,
    fit: Option<ClockFit>,
    restarts: u64,
}

/// Unwrapping state: the last raw counter value, its unwrapped tick count (relative to the
/// first packet) and host time.
#[derive(Debug, Clone, Copy)]
struct Origin {
    last_raw: u64,
    last_ticks: i64,
    last_host: f64,
}

impl ClockEstimator {
    pub(crate) fn new(config: ClockConfig) -> Result<Self, ClockConfigError> {
        config.validate()?;
        Ok(Self {
            bins: VecDeque::with_capacity(config.window_bins + 1),
            config,
            origin: None,
            fit: None,
            restarts: 0,
        })
    }

    /// Takes one packet (raw counter value, host receive time in s) and returns the host time
    /// of its device instant under the updated fit; `None` (packet ignored) for a non-finite
    /// host time.
    pub(crate) fn observe(&mut self, raw_ticks: u64, host_s: f64) -> Option<f64> {
        if !host_s.is_finite() {
            return None;
        }
        let raw = raw_ticks % self.config.modulus;
        let ticks = match self.origin {
            None => 0,
            Some(origin) => {
                let ticks = origin.last_ticks + self.signed_step(origin.last_raw, raw);
                let device_step = (ticks - origin.last_ticks) as f64 / self.config.tick_hz;
                let host_step = host_s - origin.last_host;
                if (device_step - host_step).abs() > self.config.max_jump_s {
                    self.restart();
                    0
                } else {
                    ticks
                }
            }
        };
        self.origin = Some(Origin {
            last_raw: raw,
            last_ticks: ticks,
            last_host: host_s,
        });
        let x = ticks as f64 / self.config.tick_hz;
        self.add_minimum(Minimum { x, y: host_s - x });
        Some(self.host_time(x))
    }

    /// Host time of a device counter value near the latest packet (within half a wrap).
    /// `None` before the first packet.
    #[cfg(test)]
    pub(crate) fn map(&self, raw_ticks: u64) -> Option<f64> {
        let origin = self.origin?;
        let raw = raw_ticks % self.config.modulus;
        let ticks = origin.last_ticks + self.signed_step(origin.last_raw, raw);
        Some(self.host_time(ticks as f64 / self.config.tick_hz))
    }

    #[cfg(test)]
    pub(crate) fn fit(&self) -> Option<ClockFit> {
        self.fit
    }

    /// How many times the counter jumped against the host clock and the estimate restarted.
    pub(crate) fn restarts(&self) -> u64 {
        self.restarts
    }

    fn host_time(&self, x: f64) -> f64 {
        let fit = self.fit.unwrap_or(ClockFit {
            offset_s: 0.0,
            drift: 0.0,
        });
        x + fit.offset_s + fit.drift * x
    }

    fn signed_step(&self, from: u64, to: u64) -> i64 {
        wrapping_counter::signed_step(self.config.modulus, from, to)
    }

    fn restart(&mut self) {
        self.restarts += 1;
        self.bins.clear();
        self.fit = None;
    }

    fn add_minimum(&mut self, point: Minimum) {
        let index = (point.x / self.config.bin_s).floor() as i64;
        match self.bins.iter_mut().find(|bin| bin.index == index) {
            Some(bin) if point.y < bin.minimum.y => bin.minimum = point,
            Some(_) => {}
            None => {
                self.bins.push_back(Bin {
                    index,
                    minimum: point,
                });
                let newest = self.bins.iter().map(|b| b.index).max().unwrap_or(index);
                let window = self.config.window_bins as i64;
                self.bins.retain(|bin| bin.index > newest - window);
            }
        }
        self.fit = Some(self.least_squares());
    }

    /// Line through the minima of the completed bins (the newest bin's minimum is still
    /// settling: its first packet may be a late one). Until enough bins are complete the
    /// drift is 0 and the offset is the mean of the minima.
    fn least_squares(&self) -> ClockFit {
        let newest = self.bins.iter().map(|b| b.index).max().unwrap_or(0);
        let completed = self.bins.iter().filter(|b| b.index != newest).count();
        let used = |b: &&Bin| completed == 0 || b.index != newest;
        let n = self.bins.iter().filter(used).count() as f64;
        let mean_x = self
            .bins
            .iter()
            .filter(used)
            .map(|b| b.minimum.x)
            .sum::<f64>()
            / n;
        let mean_y = self
            .bins
            .iter()
            .filter(used)
            .map(|b| b.minimum.y)
            .sum::<f64>()
            / n;
        let (sxy, sxx) = self
            .bins
            .iter()
            .filter(used)
            .fold((0.0, 0.0), |(sxy, sxx), b| {
                let dx = b.minimum.x - mean_x;
                (sxy + dx * (b.minimum.y - mean_y), sxx + dx * dx)
            });
        let drift = if completed >= self.config.min_bins_for_drift && sxx > 0.0 {
            (sxy / sxx).clamp(-self.config.max_drift, self.config.max_drift)
        } else {
            0.0
        };
        ClockFit {
            offset_s: mean_y - drift * mean_x,
            drift,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::Exp;

    /// Device ticks starting `ticks_before_wrap` before the wrap, at `rate_hz`, received with
    /// exponential latency, some packets dropped; checks the mapping of every packet after a
    /// warm-up against the true host time of its tick.
    fn check(config: ClockConfig, rate_hz: f64, ticks_before_wrap: u64, seed: u64) -> f64 {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let latency = Exp::new(1.0 / 0.002).unwrap();
        let (offset, drift) = (1234.5, 50e-6);
        let host_of_device = |x: f64| offset + (1.0 + drift) * x;
        let mut estimator = ClockEstimator::new(config).unwrap();
        let start_ticks = config.modulus - ticks_before_wrap;
        let mut worst: f64 = 0.0;
        let packets = (120.0 * rate_hz) as usize;
        for k in 0..packets {
            let dropped_burst = (3000..3000 + (2.0 * rate_hz) as usize).contains(&k);
            if dropped_burst || rng.gen_bool(0.1) {
                continue;
            }
            let device_s = k as f64 / rate_hz + rng.gen_range(0.0..0.3 / rate_hz);
            let ticks_since_start = (device_s * config.tick_hz).floor() as u64;
            let raw = (start_ticks + ticks_since_start) % config.modulus;
            let tick_instant = ticks_since_start as f64 / config.tick_hz;
            let host = host_of_device(device_s) + rng.sample(latency);
            let mapped = estimator.observe(raw, host).unwrap();
            let truth = host_of_device(tick_instant);
            if device_s > 5.0 {
                worst = worst.max((mapped - truth).abs());
                let again = estimator.map(raw).unwrap();
                assert_eq!(again, mapped);
            }
        }
        assert_eq!(estimator.restarts(), 0);
        eprintln!("worst mapping error {:.1} us", worst * 1e6);
        let fit = estimator.fit().unwrap();
        assert!((fit.drift - drift).abs() < 20e-6, "drift {}", fit.drift);
        worst
    }

    #[test]
    fn scip_counter_through_its_wrap_maps_within_a_millisecond() {
        for seed in 0..3 {
            let worst = check(ClockConfig::scip(), 40.0, 20_000, seed);
            assert!(worst < 1e-3, "worst error {worst} s");
        }
    }

    #[test]
    fn xsens_counters_through_their_wraps_map_within_a_millisecond() {
        for config in [
            ClockConfig::xsens_100_series(),
            ClockConfig::xsens_600_series(),
        ] {
            let worst = check(config, 100.0, 300_000, 11);
            assert!(worst < 1e-3, "worst error {worst} s");
        }
    }

    #[test]
    fn a_counter_reset_restarts_the_estimate() {
        let mut estimator = ClockEstimator::new(ClockConfig::scip()).unwrap();
        for k in 0..100u64 {
            estimator.observe(5_000_000 + k * 25, 10.0 + k as f64 * 0.025);
        }
        let mapped = estimator.observe(0, 12.5).unwrap();
        assert_eq!(estimator.restarts(), 1);
        assert!((mapped - 12.5).abs() < 1e-9);
        assert!(ClockEstimator::new(ClockConfig::scip())
            .unwrap()
            .map(5)
            .is_none());
    }

    #[test]
    fn bad_configurations_and_host_times_are_refused() {
        let config = ClockConfig {
            tick_hz: 0.0,
            ..ClockConfig::scip()
        };
        let message = ClockEstimator::new(config).unwrap_err().to_string();
        assert!(
            message.starts_with("clock tick_hz = 0 is invalid"),
            "{message}"
        );
        let mut estimator = ClockEstimator::new(ClockConfig::scip()).unwrap();
        assert_eq!(estimator.observe(10, f64::NAN), None);
        assert!(estimator.map(10).is_none());
    }

    proptest::proptest! {
        #[test]
        fn any_packet_sequence_maps_to_finite_times(
            packets in proptest::collection::vec((0u64..u64::MAX, -1e6..1e6f64), 1..200)
        ) {
            let mut estimator = ClockEstimator::new(ClockConfig::xsens_600_series()).unwrap();
            for (raw, host) in packets {
                let mapped = estimator.observe(raw, host).unwrap();
                proptest::prop_assert!(mapped.is_finite());
            }
        }
    }

    #[test]
    fn a_small_backward_step_is_not_a_wrap() {
        let mut estimator = ClockEstimator::new(ClockConfig::xsens_100_series()).unwrap();
        let a = estimator.observe(1_000, 5.0).unwrap();
        let b = estimator.observe(600, 5.001).unwrap();
        // Unwrapped forward this would be a day later.
        assert!((b - a).abs() < 0.1, "{a} {b}");
        let mapped_back = estimator.map(1_000).unwrap() - estimator.map(600).unwrap();
        assert!((mapped_back - 0.04).abs() < 1e-9);
        assert_eq!(estimator.restarts(), 0);
    }
}
