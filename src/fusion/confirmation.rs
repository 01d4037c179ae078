//! Plane confirmation: above 1 Hz, a plane enters the solve only if it also matches a plane of
//! the epoch `plane_confirmation_s` back, under the filter's relative pose over that baseline.
//!
//! Two lines of different surfaces are coplanar whenever their extensions meet on the edge
//! between the surfaces, and a short line confirms that to a few degrees only: through an open
//! doorway the hallway hover builds a plane from a line on the room's wall and a line on the
//! hallway ceiling in a third of its epochs. Such a fictitious plane, and a door near the end
//! of its swing, moves with the body by less in 0.1 s than integrity can detect, but its error
//! does not telescope between epochs as plane noise does, so at 10 Hz it builds up unseen. Over
//! a second the same motion leaves the match gate, while real surfaces (walls, floor, cabinet
//! faces) still match; docs/accuracy.md, "Plane confirmation", has the measured shares. At 1 Hz
//! the previous epoch is already that far back and the test adds nothing.

use std::collections::VecDeque;

use crate::odometry::EpochPlanes;

/// The planes of the recent epochs, oldest first, as far back as the confirmation needs.
#[derive(Debug, Clone, Default)]
pub(super) struct RecentEpochs {
    epochs: VecDeque<EpochPlanes>,
    /// Storage of pruned epochs, reused so that remembering allocates nothing once grown.
    spare: Vec<EpochPlanes>,
}

impl RecentEpochs {
    /// Keeps a copy of `planes`, and of the older epochs only the newest one at least
    /// `baseline_s - tolerance_s` older than it (later epochs need nothing older).
    pub(super) fn remember(&mut self, planes: &EpochPlanes, baseline_s: f64, tolerance_s: f64) {
        let mut copy = self.spare.pop().unwrap_or_default();
        copy.clone_from(planes);
        self.epochs.push_back(copy);
        let old_enough =
            |epoch: &EpochPlanes| planes.t_ref - epoch.t_ref >= baseline_s - tolerance_s;
        while self.epochs.len() >= 2 && old_enough(&self.epochs[1]) {
            if let Some(pruned) = self.epochs.pop_front() {
                self.spare.push(pruned);
            }
        }
    }

    /// Index of the newest remembered epoch at least `baseline_s - tolerance_s` older than `t`.
    pub(super) fn keyframe_before(
        &self,
        t: f64,
        baseline_s: f64,
        tolerance_s: f64,
    ) -> Option<usize> {
        self.epochs
            .iter()
            .rposition(|epoch| t - epoch.t_ref >= baseline_s - tolerance_s)
    }

    /// The remembered epoch at `index` (from `keyframe_before`).
    pub(super) fn at(&self, index: usize) -> &EpochPlanes {
        &self.epochs[index]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(t_ref: f64) -> EpochPlanes {
        EpochPlanes {
            t_ref,
            ..EpochPlanes::default()
        }
    }

    #[test]
    fn the_keyframe_is_the_newest_epoch_a_baseline_back() {
        let mut recent = RecentEpochs::default();
        for k in 0..25 {
            recent.remember(&at(k as f64 * 0.1), 1.0, 0.05);
        }
        // Epoch 24 (2.4 s) is the newest; epoch 14 is 1.0 s before it, 15 only 0.9 s.
        let keyframe = recent.at(recent.keyframe_before(2.4, 1.0, 0.05).unwrap());
        assert!((keyframe.t_ref - 1.4).abs() < 1e-9, "{}", keyframe.t_ref);
        // Nothing older than that keyframe is kept.
        assert_eq!(recent.epochs.len(), 11);
    }

    #[test]
    fn no_keyframe_until_the_baseline_has_passed() {
        let mut recent = RecentEpochs::default();
        for k in 0..5 {
            recent.remember(&at(k as f64 * 0.1), 1.0, 0.05);
        }
        assert!(recent.keyframe_before(0.45, 1.0, 0.05).is_none());
        assert_eq!(recent.keyframe_before(0.96, 1.0, 0.05), Some(0));
    }
}
