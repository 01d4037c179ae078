//! One odometry epoch on the plane map (`odometry.method = "map"`; docs/design.md, 4.11):
//! deskew and extract the lines and planes, put each line on the mapped surface it lies on,
//! test the surfaces against the prediction and exclude one that moved, fuse the lines, place
//! new surfaces from the planes whose lines lie on none, and forget the surfaces out of reach.

use nalgebra::Vector3;
use serde::Serialize;

use super::plane_map::{Association, Standing, SurfaceRecord, Trust};
use super::record::{EpochOutcome, EpochRecord, UpdateSummary};
use super::witnesses::{Check, CheckedLone, Evidence, LoneCheck};
use super::Fusion;
use crate::estimate::IntegrityStatus;
use crate::filter::config::PAPER_EPOCH_S;
use crate::filter::state::VEL;
use crate::filter::{FilterPhase, LineOnSurface, MapLine, Observability, Pose};
use crate::integrity::blocks::{test_surfaces, Block, MapIntegrity, StackedInnovation};
use crate::least_squares::{directions_below, facing, PARALLEL_TOLERANCE};
use crate::odometry::planes::LineRef;
use crate::odometry::EpochPlanes;
use crate::sensors::Scan;

/// What the map did in one epoch, for epochs.jsonl.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapEpoch {
    /// Lines offered, and how many lay on a mapped surface, on two at once, or were fused.
    pub lines: usize,
    pub on_surfaces: usize,
    pub ambiguous: usize,
    pub fused: usize,
    /// Surfaces placed, excluded (they moved, or were never one surface) and forgotten.
    pub placed: Vec<u64>,
    pub excluded: Vec<u64>,
    /// Surfaces not fused because each alone faced a direction and its standing did not let
    /// it (a wall from one line not yet corroborated).
    pub unchecked: Vec<u64>,
    /// Surfaces dropped because a line fitted them from behind: they moved past the body, or
    /// the line lay on the far face of what they are a face of.
    pub seen_from_behind: Vec<u64>,
    pub forgotten: Vec<u64>,
    pub integrity: Option<MapIntegrity>,
    /// The map after the epoch.
    pub surfaces: Vec<SurfaceRecord>,
}

/// The prediction's sigma of a lone surface's offset (m) at or below which it checks the
/// surface: a surface moving with the body then stands out from the prediction within an epoch
/// of walking pace at 1 Hz (0.1 m against four sigmas of 2 cm).
pub(super) const LONE_CHECK_SIGMA_M: f64 = 0.02;

/// Whether `normal` faces a direction none of `others` faces: more than a tenth of it lies
/// where their normals together hold less than a twentieth of a surface's facing.
fn faces_alone(normal: &Vector3<f64>, others: &[Vector3<f64>]) -> bool {
    let eigen = facing(others).symmetric_eigen();
    let unfaced: f64 = (0..3)
        .filter(|&k| eigen.eigenvalues[k] < 0.05)
        .map(|k| normal.dot(&eigen.eigenvectors.column(k)).powi(2))
        .sum();
    unfaced > 0.1
}

/// The epoch's lines `on` (surface, line index) their surfaces.
fn lines_on(lines: &[EpochLine], on: &[(u64, usize)]) -> Vec<LineOnSurface> {
    on.iter()
        .map(|&(surface, k)| LineOnSurface {
            line: lines[k].line,
            surface,
        })
        .collect()
}

/// The epoch's verdict as the estimate carries it: not isolable, excluded, nothing to fuse,
/// or fine.
fn integrity_status(
    integrity: Option<&MapIntegrity>,
    excluded: &[u64],
    fused: &[(u64, usize)],
) -> IntegrityStatus {
    match integrity {
        Some(i) if !i.usable() => IntegrityStatus::DetectedNotIsolable,
        _ if !excluded.is_empty() => IntegrityStatus::Excluded {
            planes: excluded.iter().map(|&id| id as usize).collect(),
        },
        _ if fused.is_empty() => IntegrityStatus::UnderDetermined,
        _ => IntegrityStatus::Ok,
    }
}

/// An epoch's tested lines sorted by what the lone surfaces among them may tell
/// (`Fusion::leave_out_unchecked_lone`).
struct LoneSurfaces {
    /// The (surface, line) pairs to fuse.
    kept: Vec<(u64, usize)>,
    /// Surfaces alone in facing a direction whose standing did not let them.
    left_out: Vec<u64>,
    /// Each lone surface kept (navigation normal) with the prediction's check of it.
    checks: Vec<(Vector3<f64>, Check)>,
}

/// A line of the epoch with where it lies.
struct EpochLine {
    at: LineRef,
    line: MapLine,
    on: Association,
}

impl Fusion {
    /// Places the surfaces of the epoch the pairs just fused, the one at which the filter
    /// converged, so that the next epoch measures on the map (`odometry.method = "map"` starts
    /// and restarts on the pairs: until the velocity is known, a line fits any parallel surface
    /// within metres, and a start in motion measured on the map took lines for the wrong walls
    /// and fused nothing for twenty seconds; the pairs match planes by their shape alone).
    pub(super) fn seed_map(&mut self, t_ref: f64) {
        let Some(reference) = self.reference.take() else {
            return;
        };
        if let Some(pose) = self.filter.pose_at_or_after(t_ref) {
            let lines = self.epoch_lines(t_ref);
            self.place_surfaces(&reference.planes, &lines, &pose);
        }
        self.reference = Some(reference);
    }

    /// Whether the surfaces `seed_map` would place from the pairs' epoch `record` face every
    /// direction that epoch observed, counting only those the map lets face a direction alone
    /// (not `Standing::Corroborated`) and seen at the epoch before too (matched, and kept by
    /// integrity). Handed over sooner, the map gave up what the pairs saw: in the hall walk the
    /// end wall, a wall from one line, could not alone face the hall's length on the map, which
    /// left it unfaced for 20 s until a second surface came into view (17 % of the epochs at
    /// 1 Hz). A plane seen once may not be seen again: in the open room a shelf's slanted face,
    /// new at the hand-over epoch, faced the room's length enough to pass, and the map left
    /// that length unfaced for 7 s.
    ///
    /// Only at the paper's 1 Hz or slower. Above it the pairs' sideways sigma is too small
    /// (docs/autopilot.md, "Above 1 Hz"), and the map is the honest odometer: kept on the pairs
    /// until 31-53 s, the open room started in motion at 10 Hz read 0.961 inside 3 sigma
    /// vertically, where the map handed over early reads 0.988.
    pub(super) fn map_keeps_what_the_pairs_observe(&self, record: &EpochRecord) -> bool {
        if self.config.epoch_interval_s() < PAPER_EPOCH_S {
            return true;
        }
        let Some(reference) = self.reference.as_ref() else {
            return false;
        };
        let trust = self.trust(&reference.planes);
        let trusted: Vec<Vector3<f64>> = reference
            .planes
            .planes
            .iter()
            .enumerate()
            .filter(|(k, plane)| {
                reference.matched.contains(k) && trust.standing(plane) != Standing::Corroborated
            })
            .map(|(_, plane)| plane.normal)
            .collect();
        let unobserved_by_pairs: Vec<Vector3<f64>> = record
            .unobservable_displacement
            .iter()
            .map(|d| Vector3::from(*d))
            .collect();
        unfaced_by(&trusted).iter().all(|unfaced| {
            unobserved_by_pairs
                .iter()
                .any(|d| d.dot(unfaced).abs() >= super::STILL_UNOBSERVED_COSINE)
        })
    }

    pub(super) fn run_map_epoch(&mut self, scans: &[Scan; 2], t_ref: f64) -> EpochRecord {
        let mut current = std::mem::take(&mut self.current);
        self.extract(scans, t_ref, &mut current);
        let mut record = super::epoch::planes_record(&current);
        let pose = match self.filter.phase() {
            FilterPhase::Aligning => None,
            _ => self.filter.pose_at_or_after(t_ref),
        };
        if let Some(pose) = pose {
            record.map = Some(self.map_epoch(&current, &pose, &mut record));
        }
        record.level_surfaces = self.level_from_building(&current.planes);
        self.current = current;
        record
    }

    fn map_epoch(
        &mut self,
        current: &EpochPlanes,
        pose: &Pose,
        record: &mut EpochRecord,
    ) -> MapEpoch {
        let t_ref = current.t_ref;
        self.plane_map.sync(self.filter.surfaces());
        let (lines, on) = self.associated_lines(pose, t_ref);
        let integrity = self.test_map_lines(&lines, &on, t_ref);
        let excluded = integrity
            .as_ref()
            .map_or_else(Vec::new, |i| i.excluded.clone());
        let usable = integrity.as_ref().is_none_or(MapIntegrity::usable);
        let tested: Vec<(u64, usize)> = on
            .iter()
            .copied()
            .filter(|(id, _)| usable && !excluded.contains(id))
            .collect();
        let LoneSurfaces {
            kept: fused,
            left_out: unchecked,
            checks,
        } = self.leave_out_unchecked_lone(&lines, &tested, t_ref);
        let unfaced = self.unfaced(&fused);
        // Before the update: what the filter knew along each lone direction before it learnt it.
        let lone = self.lone_checks(&checks, pose);
        self.fuse_map_lines(&lines, &fused, &unfaced, pose, record);
        let fused_any = record.outcome == EpochOutcome::Fused;
        if fused_any {
            self.settle_lone_surfaces(&lone, &unfaced, pose, record);
        }
        record.provisional_directions = self.provisional.len();
        self.note_sightings(&lines, &tested, &fused, pose, fused_any);
        for &id in &excluded {
            self.plane_map.remove(&mut self.filter, id);
        }
        self.integrity = Some(integrity_status(integrity.as_ref(), &excluded, &fused));
        record.status = self.integrity.clone();
        record.unobservable_displacement = unfaced
            .iter()
            .map(|d| pose.q.inverse_transform_vector(d).into())
            .collect();
        let placed = self.place_surfaces(current, &lines, pose);
        let position = self.filter.state().p;
        MapEpoch {
            lines: lines.len(),
            on_surfaces: on.len(),
            ambiguous: lines
                .iter()
                .filter(|l| l.on == Association::Ambiguous)
                .count(),
            fused: if fused_any { fused.len() } else { 0 },
            placed,
            excluded,
            unchecked,
            seen_from_behind: self.plane_map.seen_from_behind().to_vec(),
            forgotten: self.plane_map.forget(&mut self.filter, &position, t_ref),
            integrity,
            surfaces: self.plane_map.records(&self.filter),
        }
    }

    /// The epoch's lines with the surface each lies on, and the (surface, line) pairs of those
    /// on one, by surface.
    fn associated_lines(&mut self, pose: &Pose, t_ref: f64) -> (Vec<EpochLine>, Vec<(u64, usize)>) {
        let mut lines = self.epoch_lines(t_ref);
        let offered: Vec<MapLine> = lines.iter().map(|l| l.line).collect();
        let associations = self
            .plane_map
            .associate(&mut self.filter, &offered, pose, t_ref);
        for (line, on) in lines.iter_mut().zip(associations) {
            line.on = on;
        }
        // A surface merged away above may still be named by a line associated before.
        let held = |id: u64| self.filter.surfaces().iter().any(|s| s.id == id);
        let mut on: Vec<(u64, usize)> = lines
            .iter()
            .enumerate()
            .filter_map(|(k, l)| match l.on {
                Association::On(id) if held(id) => Some((id, k)),
                _ => None,
            })
            .collect();
        on.sort_by_key(|&(id, _)| id);
        (lines, on)
    }

    /// Every line of the epoch's two scans, as the map measures with it.
    fn epoch_lines(&self, t_ref: f64) -> Vec<EpochLine> {
        (0..2)
            .flat_map(|scanner| {
                let scan = self.odometer.scan_of_lines(scanner);
                (0..scan.segments.len()).map(move |segment| EpochLine {
                    at: LineRef { scanner, segment },
                    line: scan.map_line(segment, t_ref),
                    on: Association::Free,
                })
            })
            .collect()
    }

    /// The surfaces' test against the prediction, with the exclusion of one that moved.
    fn test_map_lines(
        &mut self,
        lines: &[EpochLine],
        on: &[(u64, usize)],
        t_ref: f64,
    ) -> Option<MapIntegrity> {
        if on.is_empty() || !self.config.exclusion {
            return None;
        }
        let allowance = self.plane_map.allowance();
        let stack = self
            .filter
            .stack_lines(&lines_on(lines, on), t_ref, &allowance)?;
        let mut blocks: Vec<Block> = Vec::new();
        for (row, &(surface, _)) in on.iter().enumerate() {
            match blocks.last_mut() {
                Some(block) if block.surface == surface => block.rows.end = 2 * row + 2,
                _ => blocks.push(Block {
                    surface,
                    rows: 2 * row..2 * row + 2,
                }),
            }
        }
        let limits = self.monitor.config();
        Some(test_surfaces(
            &StackedInnovation {
                innovation: &stack.innovation,
                covariance: &stack.covariance,
                cross: &stack.cross,
                prior: &stack.prior,
            },
            &blocks,
            self.monitor.thresholds(),
            limits.max_exclusions,
        ))
    }

    fn fuse_map_lines(
        &mut self,
        lines: &[EpochLine],
        fused: &[(u64, usize)],
        unfaced: &[Vector3<f64>],
        pose: &Pose,
        record: &mut EpochRecord,
    ) {
        if fused.is_empty() {
            record.outcome = EpochOutcome::NotFused;
            return;
        }
        let on = lines_on(lines, fused);
        let allowance = self.plane_map.allowance();
        let t_ref = pose.t;
        (record.outcome, record.update) = match self
            .filter
            .update_map_lines(&on, t_ref, &allowance, unfaced)
        {
            Ok(update) if update.accepted => {
                (EpochOutcome::Fused, Some(UpdateSummary::from(&update)))
            }
            Ok(update) => (
                EpochOutcome::RejectedByGate,
                Some(UpdateSummary::from(&update)),
            ),
            Err(error) => (
                EpochOutcome::UpdateFailed {
                    reason: error.to_string(),
                },
                None,
            ),
        };
        record.used = fused.len();
    }

    /// Notes where each surface tested was seen, and whether its lines were fused.
    fn note_sightings(
        &mut self,
        lines: &[EpochLine],
        tested: &[(u64, usize)],
        fused: &[(u64, usize)],
        pose: &Pose,
        fused_any: bool,
    ) {
        let mut ids: Vec<u64> = tested.iter().map(|&(id, _)| id).collect();
        ids.dedup();
        for id in ids {
            let seen: Vec<MapLine> = tested
                .iter()
                .filter(|(s, _)| *s == id)
                .map(|&(_, k)| lines[k].line)
                .collect();
            let counted = fused_any && fused.iter().any(|(s, _)| *s == id);
            self.plane_map.seen(id, &seen, pose, counted);
        }
    }

    /// New surfaces from the epoch's planes whose lines lie on no mapped surface, each fitted
    /// to its lines.
    fn place_surfaces(
        &mut self,
        current: &EpochPlanes,
        lines: &[EpochLine],
        pose: &Pose,
    ) -> Vec<u64> {
        let index_of = |at: LineRef| lines.iter().position(|l| l.at == at);
        let trust = self.trust(current);
        let mut placed = Vec::new();
        for plane in &current.planes {
            let members: Option<Vec<usize>> = plane
                .distinct_lines()
                .iter()
                .map(|&at| index_of(at))
                .collect();
            let Some(members) = members else { continue };
            if members.iter().any(|&k| lines[k].on != Association::Free) {
                continue;
            }
            let own: Vec<MapLine> = members.iter().map(|&k| lines[k].line).collect();
            placed.extend(
                self.plane_map
                    .place(&mut self.filter, plane, &own, pose, &trust),
            );
        }
        placed
    }

    /// How far a surface placed from `planes` is believed before it has shown more.
    fn trust(&self, planes: &EpochPlanes) -> Trust {
        Trust {
            min_extent_m: self.monitor.config().lone_plane_min_extent_m,
            building: self.odometer.config().building(planes.down),
        }
    }

    /// Leaves out the lines of each surface that alone faces a direction (no other surface
    /// tested faces it) unless its standing lets it (`Standing`). Alone, a surface cannot be
    /// tested against another. A `Checked` one is checked by the prediction where it knows the
    /// offset of its first line to `lone_check_sigma_m`; where it does not, and its own lines
    /// show it is a surface (`PlaneMap::shows_itself`), it is fused on its own word, and its
    /// direction held in doubt (`witnesses::Provisional`) until later epochs check it, as the
    /// pairs hold a lone plane's: left out instead, the cabinet that
    /// alone faces along a bare corridor could never be believed once the walk had left the
    /// velocity along it vague, and the map's along-track error was twice the pairs'.
    fn leave_out_unchecked_lone(
        &mut self,
        lines: &[EpochLine],
        tested: &[(u64, usize)],
        t_ref: f64,
    ) -> LoneSurfaces {
        let epoch = self.filter.map_epoch(t_ref);
        // Each surface tested (`tested` is by surface) with its first line and its normal.
        let mut surfaces: Vec<(u64, usize, Vector3<f64>)> = Vec::new();
        for &(id, k) in tested {
            if surfaces.last().is_some_and(|s| s.0 == id) {
                continue;
            }
            if let Some(surface) = self.filter.surfaces().iter().find(|s| s.id == id) {
                surfaces.push((id, k, surface.normal));
            }
        }
        let checked_by_prediction = |id: u64, k: usize| {
            epoch
                .as_ref()
                .and_then(|epoch| {
                    self.filter
                        .offset_prediction_sigma(&lines[k].line, id, epoch)
                })
                .is_some_and(|sigma| sigma <= self.lone_check_sigma_m(id, t_ref))
        };
        let mut left_out = Vec::new();
        let mut checks = Vec::new();
        for &(id, k, normal) in &surfaces {
            let others: Vec<Vector3<f64>> = surfaces
                .iter()
                .filter(|other| other.0 != id)
                .map(|other| other.2)
                .collect();
            match self.plane_map.standing(id) {
                Some(Standing::Static) => {}
                _ if !faces_alone(&normal, &others) => {}
                Some(Standing::Checked) if checked_by_prediction(id, k) => {
                    checks.push((normal, Check::Confirmed));
                }
                Some(Standing::Checked) if self.may_teach(id, t_ref) => {
                    checks.push((normal, Check::Taught));
                }
                _ => left_out.push(id),
            }
        }
        let kept = tested
            .iter()
            .copied()
            .filter(|(id, _)| !left_out.contains(id))
            .collect();
        LoneSurfaces {
            kept,
            left_out,
            checks,
        }
    }

    /// The lone surfaces' `checks` (navigation normals) as the pairs' witnesses put them, in
    /// `pose`'s body axes, with the velocity covariance the filter has now, before the update.
    fn lone_checks(&self, checks: &[(Vector3<f64>, Check)], pose: &Pose) -> CheckedLone {
        let turn = pose.q.to_rotation_matrix().into_inner();
        let velocity = self
            .filter
            .covariance()
            .fixed_view::<3, 3>(VEL, VEL)
            .into_owned();
        CheckedLone {
            rotation: Vec::new(),
            displacement: checks
                .iter()
                .map(|(normal, check)| LoneCheck {
                    direction: pose.q.inverse_transform_vector(normal),
                    check: *check,
                    evidence: Evidence::default(),
                })
                .collect(),
            speed_covariance: turn.transpose() * velocity * turn,
        }
    }

    /// After an update that fused the map's lines: holds in doubt the directions lone
    /// surfaces taught the filter on their own word, and lets go of those checked since
    /// (`witnesses::Provisional`). `unfaced`: the directions no fused surface faced.
    fn settle_lone_surfaces(
        &mut self,
        lone: &CheckedLone,
        unfaced: &[Vector3<f64>],
        pose: &Pose,
        record: &EpochRecord,
    ) {
        let unfaced_body: Vec<Vector3<f64>> = unfaced
            .iter()
            .map(|d| pose.q.inverse_transform_vector(d))
            .collect();
        let faced = Observability::from_unobservable(&unfaced_body);
        let interval_s = self.config.epoch_interval_s();
        let surprised = record.update.is_some_and(|u| u.surprising(interval_s));
        self.provisional
            .after_fusion(lone, [None, Some(faced)], &pose.q, surprised, pose.t);
    }

    /// Whether surface `id`, alone in facing a direction the prediction cannot check, may be
    /// fused on its own word: its lines show it is a surface (`PlaneMap::shows_itself`), and
    /// above 1 Hz it is the plane confirmation's baseline old. A mover shows by how far it
    /// went since its surface was placed: at 10 Hz the board carried along `board-corridor`,
    /// its surface placed anew each epoch, taught the corridor's length at the end of its
    /// swing, and nothing else facing along the corridor, the estimate stayed in doubt
    /// (quality 0) for the rest of the walk: usable in 3252 of 7801 messages in seed 109.
    fn may_teach(&self, id: u64, t_ref: f64) -> bool {
        let old_enough = self
            .config
            .confirmation_baseline_s()
            .is_none_or(|baseline_s| {
                self.plane_map
                    .age_s(id, t_ref)
                    .is_some_and(|age_s| age_s >= baseline_s)
            });
        old_enough && self.plane_map.shows_itself(id)
    }

    /// The prediction's sigma of surface `id`'s offset at or below which it checks the surface
    /// alone: `LONE_CHECK_SIGMA_M` once the surface is the plane confirmation's baseline old,
    /// and in proportion to its age before. A mover shows by how far it went since its surface
    /// was placed, and the prediction's doubt grows with that time too: at 10 Hz a board carried
    /// at 0.5 m/s goes 5 cm an epoch, within the doubt of a velocity known to 0.1 m/s, and its
    /// surface, placed anew each epoch, matched its next sighting and gave the body the board's
    /// speed. At 1 Hz (no confirmation) every surface tested is an epoch old.
    fn lone_check_sigma_m(&self, id: u64, t_ref: f64) -> f64 {
        match self.config.confirmation_baseline_s() {
            Some(baseline_s) => {
                let age_s = self.plane_map.age_s(id, t_ref).unwrap_or(0.0);
                LONE_CHECK_SIGMA_M * (age_s / baseline_s).clamp(0.0, 1.0)
            }
            None => LONE_CHECK_SIGMA_M,
        }
    }

    /// Directions (navigation axes) that none of the surfaces `fused` faces.
    fn unfaced(&self, fused: &[(u64, usize)]) -> Vec<Vector3<f64>> {
        let normals: Vec<Vector3<f64>> = self
            .filter
            .surfaces()
            .iter()
            .filter(|s| fused.iter().any(|(id, _)| *id == s.id))
            .map(|s| s.normal)
            .collect();
        unfaced_by(&normals)
    }
}

/// The directions `normals` leave unobserved, judged on the normals as the pairs' solves judge
/// their planes (`least_squares::PARALLEL_TOLERANCE`).
fn unfaced_by(normals: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    directions_below(&facing(normals), PARALLEL_TOLERANCE)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_corridor_leaves_its_length_unfaced() {
        let walls = [Vector3::y(), -Vector3::y(), Vector3::z()];
        let free = unfaced_by(&walls);
        assert_eq!(free.len(), 1);
        assert!(free[0].x.abs() > 0.999);
    }

    #[test]
    fn a_surface_faces_alone_what_no_other_faces() {
        let walls = [Vector3::y(), -Vector3::y(), Vector3::z()];
        assert!(faces_alone(&Vector3::x(), &walls));
        assert!(!faces_alone(&Vector3::y(), &walls));
        // A wall turned 30 degrees faces the corridor's length by a quarter of it.
        let turned = Vector3::new(0.5, 0.75f64.sqrt(), 0.0);
        assert!(faces_alone(&turned, &walls));
        // Turned 15 degrees, by a fifteenth: the walls face it enough.
        let slight = Vector3::new(15f64.to_radians().sin(), 15f64.to_radians().cos(), 0.0);
        assert!(!faces_alone(&slight, &walls));
        assert!(!faces_alone(&-Vector3::x(), &[Vector3::x()]));
    }
}
