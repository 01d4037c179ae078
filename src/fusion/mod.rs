//! Pure wiring of IMU samples and scans, in time order, through the core and the filter
//! (docs/design.md, "Layout"): no I/O, no clock, no tokio; the same inputs give the same outputs
//! bit for bit.
//!
//! `Fusion` pairs the latest scan of each scanner into an odometry epoch at the configured rate
//! (`epoch`), deskews them with the filter's pose history, extracts planes, matches them with
//! the previous epoch's under the filter's relative-pose prior, solves, runs integrity and fuses
//! the relative pose against the clone of the pose at the previous epoch.

mod anchor;
mod building_vertical;
mod checks_over_second;
pub(crate) mod clock;
pub(crate) mod config;
mod confirmation;
mod deskew_basis;
mod epoch;
mod level_drift;
mod map_epoch;
mod plane_map;
pub mod record;
mod shared_noise;
mod witnesses;

pub(crate) use config::FusionConfig;
pub use config::{FusionError, FusionSettings};
pub(crate) use record::{EpochOutcome, EpochRecord};

use crate::estimate::{Estimate, IntegrityStatus};
use crate::filter::config::PAPER_EPOCH_S;
use crate::filter::state::VEL;
use crate::filter::{Eskf, FilterPhase, ImuOutcome};
use crate::integrity::IntegrityMonitor;
use crate::odometry::{EpochPlanes, Odometer, OdometryMethod};
use crate::sensors::{ImuSample, Scan, ScannerSetup};
use nalgebra::Vector3;

/// Two epochs' unobserved displacement directions are the same one within about 25 degrees:
/// the body turns little in an epoch, and the pairs' free directions follow the walls.
const STILL_UNOBSERVED_COSINE: f64 = 0.9;

/// A source whose staleness the daemon's watchdog reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Sensor {
    Imu,
    Scanner(usize),
}

/// Counts of input the fusion set aside.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct FusionCounters {
    /// Scans naming a scanner other than 0 or 1.
    pub unknown_scanner: u64,
    /// Scans with a non-finite start time.
    pub bad_scan_time: u64,
    /// Scan pairs further apart than `max_scan_skew_s`.
    pub skewed_pairs: u64,
    pub epochs: u64,
}

/// The previous epoch: its planes and whether the filter holds a clone of its pose.
#[derive(Debug, Clone)]
struct Reference {
    planes: EpochPlanes,
    cloned: bool,
    /// The velocity its scans were deskewed with.
    deskew: deskew_basis::DeskewBasis,
    /// How the planes entered the relative pose that ended at this epoch, if one was solved.
    noise_maps: Vec<shared_noise::PlaneNoiseMap>,
    /// Its planes matched to the epoch before and kept by integrity.
    matched: Vec<usize>,
}

#[derive(Clone)]
pub struct Fusion {
    config: FusionConfig,
    filter: Eskf,
    odometer: Odometer,
    monitor: IntegrityMonitor,
    scanners: [ScannerSetup; 2],
    /// Newest scan of each scanner not yet used in a pair.
    pending: [Option<Scan>; 2],
    /// Mid-scan time of each scanner's newest scan.
    last_scan: [Option<f64>; 2],
    stale: [bool; 2],
    imu_stale: bool,
    first_imu: Option<f64>,
    /// Reference time of the latest scan pair, epoch or not.
    last_pair: Option<f64>,
    reference: Option<Reference>,
    /// Storage for the current epoch's planes, swapped with the reference's.
    current: EpochPlanes,
    /// The plane map's bookkeeping (`odometry.method = "map"`).
    plane_map: plane_map::PlaneMap,
    /// Reference time of the last epoch on the plane map.
    last_map_epoch: Option<f64>,
    /// Epochs back to the plane confirmation's baseline.
    recent: confirmation::RecentEpochs,
    /// Level planes followed from epoch to epoch, to leave out those whose height wanders.
    level_drift: level_drift::LevelDrift,
    integrity: Option<IntegrityStatus>,
    /// Directions fused on the word of a lone plane nothing could check yet: until they are
    /// checked the estimate is not converged.
    provisional: witnesses::Provisional,
    /// The last second of each lone direction's checks, for epochs too short to tell alone.
    checks_over_second: checks_over_second::ChecksOverSecond,
    /// Whether the filter was converged at the last epoch: losing it is a restart, which
    /// forgets the provisional directions with the state.
    filter_converged: bool,
    /// The directions the last pairs' epoch left unobserved, if it fused.
    last_fused_unobserved: Option<Vec<[f64; 3]>>,
    propagated: u64,
    counters: FusionCounters,
}

impl Fusion {
    pub fn new(settings: FusionSettings, scanners: [ScannerSetup; 2]) -> Result<Self, FusionError> {
        settings.validate()?;
        let filter = Eskf::new(settings.filter_config())?;
        Ok(Self {
            plane_map: plane_map::PlaneMap::new(settings.odometry.map.clone()),
            last_map_epoch: None,
            odometer: Odometer::new(scanners, settings.odometry)?,
            monitor: IntegrityMonitor::new(settings.integrity)?,
            filter,
            config: settings.fusion,
            scanners,
            pending: [None, None],
            last_scan: [None; 2],
            stale: [false; 2],
            imu_stale: false,
            first_imu: None,
            last_pair: None,
            reference: None,
            current: EpochPlanes::default(),
            recent: confirmation::RecentEpochs::default(),
            level_drift: level_drift::LevelDrift::default(),
            integrity: None,
            provisional: witnesses::Provisional::default(),
            checks_over_second: checks_over_second::ChecksOverSecond::default(),
            filter_converged: false,
            last_fused_unobserved: None,
            propagated: 0,
            counters: FusionCounters::default(),
        })
    }

    /// Feeds one IMU sample (host time, in time order with the scans). Returns an estimate
    /// every `estimate_decimation` propagated samples once the filter is aligned.
    pub fn push_imu(&mut self, sample: ImuSample) -> Option<Estimate> {
        let outcome = self.filter.push_imu(&sample);
        if self.first_imu.is_none() && sample.time().is_finite() {
            self.first_imu = Some(sample.time());
        }
        if !matches!(
            outcome,
            ImuOutcome::Propagated | ImuOutcome::Aligned | ImuOutcome::Gap { .. }
        ) || self.filter.phase() == FilterPhase::Aligning
        {
            return None;
        }
        self.propagated += 1;
        if !self
            .propagated
            .is_multiple_of(u64::from(self.config.estimate_decimation))
        {
            return None;
        }
        Some(self.estimate())
    }

    /// Feeds one complete scan (its `sensor` picks the scanner). Returns the record of the
    /// odometry epoch it completed, if it completed one.
    pub fn push_scan(&mut self, scan: Scan) -> Option<EpochRecord> {
        if scan.sensor >= 2 {
            self.counters.unknown_scanner += 1;
            return None;
        }
        if !scan.t0.is_finite() {
            self.counters.bad_scan_time += 1;
            return None;
        }
        let sensor = scan.sensor;
        self.last_scan[sensor] = Some(self.mid_scan_time(&scan));
        self.pending[sensor] = Some(scan);
        let (Some(first), Some(second)) = (&self.pending[0], &self.pending[1]) else {
            return None;
        };
        let t_ref = self.mid_scan_time(first);
        if (self.mid_scan_time(second) - t_ref).abs() > self.config.max_scan_skew_s {
            self.counters.skewed_pairs += 1;
            // The older scan can only get further from any future partner.
            let older = usize::from(self.mid_scan_time(second) < t_ref);
            self.pending[older] = None;
            return None;
        }
        let scans = [self.pending[0].take()?, self.pending[1].take()?];
        if !self.epoch_due(t_ref) {
            return None;
        }
        self.counters.epochs += 1;
        let method = self.odometer.config().method;
        Some(if method == OdometryMethod::Map && self.on_the_map() {
            self.last_map_epoch = Some(t_ref);
            self.reference = None;
            self.run_map_epoch(&scans, t_ref)
        } else {
            let record = self.run_epoch(&scans, t_ref);
            let settled = self.observability_settled(&record);
            if method == OdometryMethod::Map
                && settled
                && self.ready_for_the_map()
                && self.map_keeps_what_the_pairs_observe(&record)
            {
                self.seed_map(t_ref);
            }
            record
        })
    }

    /// Whether the plane map measures this epoch: the filter has converged and the map holds
    /// surfaces (a restart clears them, as forgetting them all empties it: the pairs then start
    /// again).
    fn on_the_map(&self) -> bool {
        self.filter.converged() && !self.filter.surfaces().is_empty()
    }

    /// Whether the pairs may hand over to the plane map (`seed_map`). The filter must have
    /// converged with nothing it fused waiting for a check (`witnesses::Provisional`): the map
    /// never checks what the pairs held in doubt, and a rolled rig started in motion that
    /// handed over holding a direction stayed unusable for the whole run (`random-room-5`).
    /// And the velocity must predict the displacement over an epoch, and at faster rates over
    /// the paper's second, along every axis as surely as the map's own prediction must know a
    /// lone surface's offset to check it (`map_epoch::LONE_CHECK_SIGMA_M`, 2 cm): surfaces
    /// placed under a looser one are placed loosely. In `random-room-9` started 31.2 s in, the
    /// map placed at 0.6 m/s of vertical sigma could measure nothing vertical for the rest of
    /// the run; and with a sure match (`witnesses::SURE_MATCH_SIGMA_M`, 0.1 m) as the bar
    /// until stop 51, the hall walk with ranges three times noisier than configured (seed 116)
    /// handed over 0.13 m/s off at a sigma of 0.076 m/s along the hall, and its updates
    /// (1.2-1.9 NIS per degree of freedom) then taught the pitch 12 mrad off and sent the
    /// velocity 0.67 m/s off at 0.034. A second, not the epoch, since the map measures against
    /// surfaces placed seconds before: held to one 10 Hz epoch, `hallway-flight` started in
    /// motion handed over with 0.55 m/s of sigma along the hallway and a velocity 1.9 m/s off
    /// along it, which the map's first updates then took for known to 0.23 m/s.
    /// The caller also asks that the pairs' epoch was not the first to observe a direction
    /// (`observability_settled`) and that the map keeps every direction it observed
    /// (`map_keeps_what_the_pairs_observe`).
    fn ready_for_the_map(&self) -> bool {
        let surely_placed = || {
            let velocity = self
                .filter
                .covariance()
                .fixed_view::<3, 3>(VEL, VEL)
                .into_owned();
            let largest_sigma = velocity.symmetric_eigenvalues().max().max(0.0).sqrt();
            let horizon_s = self.config.epoch_interval_s().max(PAPER_EPOCH_S);
            largest_sigma * horizon_s <= map_epoch::LONE_CHECK_SIGMA_M
        };
        self.filter.converged() && self.provisional.is_empty() && surely_placed()
    }

    /// Whether the pairs' epoch `record` fused and observed no direction the fused epoch before
    /// it left unobserved; remembers what it left unobserved for the next. Once a direction is first observed, the velocity along it is corrected but
    /// what drives its error (the tilt, the accelerometer's bias) is not yet; handed over then,
    /// the map, which measures positions, took that error for known: `hallway-flight` started
    /// 31.2 s in handed over as its end wall first came into view and sent a velocity 0.1 m/s
    /// off at 1 cm/s sigma. A direction that stays unobserved is the map's to hold
    /// (`Eskf::held_along`), so a bare corridor still hands over.
    fn observability_settled(&mut self, record: &EpochRecord) -> bool {
        let fused = record.outcome == EpochOutcome::Fused;
        let now = &record.unobservable_displacement;
        let still_unobserved = |before: &[f64; 3]| {
            let before = Vector3::from(*before);
            now.iter()
                .any(|d| Vector3::from(*d).dot(&before).abs() >= STILL_UNOBSERVED_COSINE)
        };
        let settled = fused
            && self
                .last_fused_unobserved
                .as_ref()
                .is_some_and(|before| before.iter().all(still_unobserved));
        self.last_fused_unobserved = fused.then(|| now.clone());
        settled
    }

    /// How many surfaces the plane map holds (`odometry.method = "map"`).
    pub fn mapped_surfaces(&self) -> usize {
        self.filter.surfaces().len()
    }

    /// The watchdog's verdict on a source; a stale source marks the estimates degraded.
    pub(crate) fn mark_stale(&mut self, sensor: Sensor, stale: bool) {
        match sensor {
            Sensor::Imu => self.imu_stale = stale,
            Sensor::Scanner(k) if k < 2 => self.stale[k] = stale,
            Sensor::Scanner(_) => {}
        }
    }

    /// Replaces a scanner's geometry and mount (its PP was re-read). The previous epoch's
    /// planes stay valid: they are in the body frame.
    pub(crate) fn set_scanner(
        &mut self,
        index: usize,
        setup: ScannerSetup,
    ) -> Result<(), FusionError> {
        if index >= 2 {
            return Err(FusionError::NoSuchScanner(index));
        }
        let mut scanners = self.scanners;
        scanners[index] = setup;
        self.odometer = Odometer::new(scanners, self.odometer.config().clone())?;
        self.scanners = scanners;
        self.pending[index] = None;
        Ok(())
    }

    /// The filter's current estimate with the fusion's integrity verdict and degradation.
    pub fn estimate(&self) -> Estimate {
        let mut estimate = self.filter.estimate();
        estimate.integrity = self.integrity.clone();
        estimate.converged &= self.provisional.is_empty();
        estimate.degraded |= self.imu_stale || self.stale.iter().any(|&s| s) || self.scans_stale();
        estimate
    }

    /// What an odometry epoch publishes at once, without waiting for the next IMU sample: the
    /// estimate at the newest IMU time with the epoch's update and integrity verdict applied.
    /// `None` while the filter is still aligning (it has no estimate yet).
    pub(crate) fn epoch_estimate(&self) -> Option<Estimate> {
        let aligned = self.filter.phase() != FilterPhase::Aligning;
        (aligned && self.filter.time().is_some()).then(|| self.estimate())
    }

    pub fn filter(&self) -> &Eskf {
        &self.filter
    }

    #[cfg(test)]
    pub(crate) fn counters(&self) -> FusionCounters {
        self.counters
    }

    /// Reference time of a scan: the time of its middle reading.
    fn mid_scan_time(&self, scan: &Scan) -> f64 {
        let geometry = &self.scanners[scan.sensor].geometry;
        scan.time_of(scan.ranges_m.len() / 2, geometry)
    }

    /// Whether a scanner has been silent for `scan_stale_s` on the IMU's time.
    fn scans_stale(&self) -> bool {
        let Some(now) = self.filter.time() else {
            return false;
        };
        let since_start = self.first_imu.unwrap_or(now);
        self.last_scan
            .iter()
            .any(|last| now - last.unwrap_or(since_start) > self.config.scan_stale_s)
    }

    /// One epoch per `1 / epoch_rate_hz`, within half a pair interval so a rate equal to the
    /// scan rate takes every pair.
    fn epoch_due(&mut self, t_ref: f64) -> bool {
        let pair_interval = self.last_pair.map_or(0.0, |last| t_ref - last);
        self.last_pair = Some(t_ref);
        let previous = self
            .reference
            .as_ref()
            .map(|r| r.planes.t_ref)
            .or(self.last_map_epoch);
        previous.is_none_or(|previous| {
            t_ref - previous >= self.config.epoch_interval_s() - 0.5 * pair_interval
        })
    }
}

#[cfg(test)]
mod tests;
