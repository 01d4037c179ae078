//! The real estimator behind `run` and `replay`: the pure `Fusion`, built once both scanners
//! have reported their geometry (their PP replies), since the odometer needs it.

use super::config::Config;
use super::pipeline::{EpochCounts, Estimator, Outcome};
use crate::estimate::{Estimate, IntegrityStatus};
use crate::fusion::{EpochOutcome, EpochRecord, Fusion, FusionSettings, Sensor};
use crate::sensors::{ImuSample, Mount, Scan, ScannerGeometry, ScannerSetup};

/// What the fusion needs from the configuration for one scanner, geometry aside.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ScannerMount {
    mount: Mount,
    range_sigma_m: f64,
}

pub struct FusionEstimator {
    settings: FusionSettings,
    mounts: [ScannerMount; 2],
    /// Sensor number of the IMU: scanners come first (`pipeline::sensor_specs`).
    imu_sensor: usize,
    geometries: [Option<ScannerGeometry>; 2],
    fusion: Option<Fusion>,
    /// Samples and scans that arrived before both geometries were known.
    pub waiting_for_geometry: u64,
    /// Geometries the fusion refused (already validated at start-up, so a device reporting
    /// nonsense in its PP reply).
    pub refused_geometries: u64,
    /// Scanners already named in a WARN for ranging worse than configured.
    named_noisier: [bool; 2],
}

impl FusionEstimator {
    /// The first two `[[scanner]]` sections are the fusion's scanners 0 and 1. Without a
    /// configuration (a raw dump of one port) the defaults apply and mounts are identity.
    pub fn new(config: Option<&Config>) -> Self {
        let settings = config.map(Config::fusion_settings).unwrap_or_default();
        warn_above_the_honest_rate(settings.fusion.epoch_rate_hz);
        let mount = |k: usize| {
            let scanner = config.and_then(|c| c.scanners.get(k));
            ScannerMount {
                mount: scanner.map_or_else(Mount::identity, |s| s.mount()),
                range_sigma_m: scanner.map_or(settings.odometry.range_sigma_m, |s| s.range_sigma_m),
            }
        };
        Self {
            mounts: [mount(0), mount(1)],
            imu_sensor: config.map_or(usize::MAX, |c| c.scanners.len()),
            settings,
            geometries: [None, None],
            fusion: None,
            waiting_for_geometry: 0,
            refused_geometries: 0,
            named_noisier: [false; 2],
        }
    }

    pub fn fusion(&self) -> Option<&Fusion> {
        self.fusion.as_ref()
    }

    fn setup(&self, scanner: usize, geometry: ScannerGeometry) -> ScannerSetup {
        ScannerSetup {
            geometry,
            mount: self.mounts[scanner].mount,
            range_sigma_m: Some(self.mounts[scanner].range_sigma_m),
        }
    }

    fn build_when_complete(&mut self) {
        let [Some(first), Some(second)] = self.geometries else {
            return;
        };
        let setups = [self.setup(0, first), self.setup(1, second)];
        match Fusion::new(self.settings.clone(), setups) {
            Ok(fusion) => self.fusion = Some(fusion),
            Err(error) => {
                self.refused_geometries += 1;
                tracing::error!(%error, "cannot start the fusion with the scanners' geometry");
            }
        }
    }
}

impl Estimator for FusionEstimator {
    type Epoch = EpochRecord;

    fn geometry(&mut self, scanner: usize, geometry: ScannerGeometry) {
        if scanner >= 2 {
            return;
        }
        self.geometries[scanner] = Some(geometry);
        let setup = self.setup(scanner, geometry);
        match self.fusion.as_mut() {
            Some(fusion) => {
                if let Err(error) = fusion.set_scanner(scanner, setup) {
                    self.refused_geometries += 1;
                    tracing::error!(%error, scanner, "scanner geometry refused");
                }
            }
            None => self.build_when_complete(),
        }
    }

    fn imu(&mut self, sample: ImuSample) -> Option<Estimate> {
        match self.fusion.as_mut() {
            Some(fusion) => fusion.push_imu(sample),
            None => {
                self.waiting_for_geometry += 1;
                None
            }
        }
    }

    fn scan(&mut self, scan: Scan) -> Option<EpochRecord> {
        let Some(fusion) = self.fusion.as_mut() else {
            self.waiting_for_geometry += 1;
            return None;
        };
        let record = fusion.push_scan(scan)?;
        let configured = self.mounts.map(|m| m.range_sigma_m);
        for k in newly_noisier(&mut self.named_noisier, configured, record.range_sigma_m) {
            let (measured, configured) = (record.range_sigma_m[k], configured[k]);
            tracing::warn!(
                scanner = k,
                "scanner {k}'s ranges scatter {measured:.3} m about its lines, more than its \
                 range_sigma_m = {configured}: its planes are weighed by the scatter; set \
                 range_sigma_m = {measured:.3} if that is its noise, or clean its window"
            );
        }
        Some(record)
    }

    fn epoch_estimate(&self) -> Option<Estimate> {
        self.fusion.as_ref().and_then(Fusion::epoch_estimate)
    }

    fn sensor_stale(&mut self, sensor: usize, stale: bool, _t: f64) {
        let Some(fusion) = self.fusion.as_mut() else {
            return;
        };
        let which = if sensor == self.imu_sensor {
            Sensor::Imu
        } else {
            Sensor::Scanner(sensor)
        };
        fusion.mark_stale(which, stale);
    }

    fn epoch_counts(epoch: &EpochRecord) -> EpochCounts {
        EpochCounts {
            planes: epoch.planes,
            detected: matches!(
                epoch.status,
                Some(IntegrityStatus::Excluded { .. } | IntegrityStatus::DetectedNotIsolable)
            ),
            excluded: epoch.excluded_planes.len(),
            outcome: match (&epoch.outcome, &epoch.status) {
                (EpochOutcome::Reference, _) => Outcome::Reference,
                (EpochOutcome::Fused, _) => Outcome::Fused,
                (EpochOutcome::RejectedByGate, _) => Outcome::RejectedByGate,
                (EpochOutcome::UpdateFailed { .. }, _) => Outcome::Failed,
                (EpochOutcome::NotFused, Some(IntegrityStatus::UnderDetermined)) => {
                    Outcome::UnderDetermined
                }
                (EpochOutcome::NotFused, Some(IntegrityStatus::DetectedNotIsolable)) => {
                    Outcome::NotIsolable
                }
                (EpochOutcome::NotFused, _) => Outcome::NotFused,
            },
            failure: match &epoch.outcome {
                EpochOutcome::UpdateFailed { reason } => Some(reason.clone()),
                _ => None,
            },
        }
    }
}

/// A scanner whose lines scatter this many times its configured sigma is named in a WARN.
const NOISIER_RATIO: f64 = 1.5;

/// The scanners whose ranging sigma `used` is first seen `NOISIER_RATIO` times `configured`
/// or more; `named` remembers them, so that each is named once.
fn newly_noisier(named: &mut [bool; 2], configured: [f64; 2], used: [f64; 2]) -> Vec<usize> {
    (0..2)
        .filter(|&k| {
            let first = !named[k] && used[k] >= NOISIER_RATIO * configured[k];
            named[k] |= first;
            first
        })
        .collect()
}

/// The fastest epoch rate whose estimate the honesty studies have shown consistent, Hz.
const HONEST_UP_TO_HZ: f64 = 1.0;

/// Faster epochs are allowed (the plane map's figures are measured at 10 Hz too), but at 10 Hz
/// a hover's sideways sigma on the pairs is too small by a third. Along a bare corridor, two
/// runs of twenty on the map still send velocities off by 3.7-3.8 of their sigmas as usable,
/// and in one drawn corridor of sixty a walker turning before the end wall is taken for static
/// (docs/autopilot.md, "Above 1 Hz"). The user must hear it.
fn warn_above_the_honest_rate(epoch_rate_hz: f64) {
    if epoch_rate_hz > HONEST_UP_TO_HZ {
        tracing::warn!(
            epoch_rate_hz,
            "fusion.epoch_rate_hz above {HONEST_UP_TO_HZ} Hz is not yet honest in a hover or, on \
             the plane map, along a corridor (docs/autopilot.md, \"Above 1 Hz\"): set it to 1 \
             for flight"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::newly_noisier;
    use crate::filter::eskf::FilterPhase;
    use crate::fusion::{EpochOutcome, Fusion, FusionSettings};
    use ladar_sim::{Scenario, SimEvent, Simulator};

    #[test]
    fn an_epoch_publishes_its_update_at_the_newest_imu_time() {
        let mut scenario = Scenario::builtin("hallway-hover").unwrap();
        scenario.duration_s = 4.0;
        let mut settings = FusionSettings::default();
        settings.odometry.accept_parallel_lines = true;
        let mut simulator = Simulator::new(&scenario).unwrap();
        let mut fusion = Fusion::new(settings, simulator.scanner_setups().unwrap()).unwrap();
        let (mut last_imu_estimate, mut fused) = (None, 0);
        for event in simulator.events() {
            let scan = match event {
                SimEvent::Imu(sample) => {
                    last_imu_estimate = fusion.push_imu(sample).or(last_imu_estimate);
                    continue;
                }
                SimEvent::Scan { scan, .. } => scan,
                SimEvent::Truth(_) => continue,
            };
            let Some(record) = fusion.push_scan(scan) else {
                continue;
            };
            let Some(estimate) = fusion.epoch_estimate() else {
                assert_eq!(fusion.filter().phase(), FilterPhase::Aligning);
                continue;
            };
            let before = last_imu_estimate.as_ref().unwrap();
            assert_eq!(estimate.t, before.t, "no waiting for the next IMU sample");
            if record.status.is_some() {
                assert_eq!(estimate.integrity, record.status);
            }
            if record.outcome == EpochOutcome::Fused {
                fused += 1;
                assert_ne!(estimate.position, before.position, "the update is in it");
            }
        }
        assert!(fused >= 1, "{fused} epochs fused");
    }

    #[test]
    fn a_scanner_ranging_worse_than_configured_is_named_once() {
        let mut named = [false; 2];
        let configured = [0.01, 0.01];
        assert!(newly_noisier(&mut named, configured, [0.012, 0.01]).is_empty());
        assert_eq!(newly_noisier(&mut named, configured, [0.012, 0.03]), [1]);
        assert!(newly_noisier(&mut named, configured, [0.012, 0.03]).is_empty());
        assert_eq!(newly_noisier(&mut named, configured, [0.02, 0.03]), [0]);
    }
}
