//! Settings of the plane map (`[odometry.map]`, used with `[odometry] method = "map"`;
//! docs/design.md, 4.11 "Plane map").

use serde::{Deserialize, Serialize};

use crate::config::ConfigErrors;
use crate::filter::SurfaceAllowance;

/// How an epoch measures the motion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OdometryMethod {
    /// The paper's: planes of two lines seen at once, matched with the previous epoch's, the
    /// relative pose solved and fused against a clone of the previous pose.
    Pairs,
    /// Every line on a local map of surfaces carried with the filter's state.
    #[default]
    Map,
}

/// Keys of `[odometry.map]`. Every key has a default; unknown keys are refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapConfig {
    /// Most surfaces held; beyond it the one unseen longest leaves. Each costs three states in
    /// every update.
    pub max_surfaces: usize,
    /// A surface unseen for this long (s) leaves the map.
    pub forget_after_s: f64,
    /// A surface whose nearest seen point is further than this (m) leaves the map.
    pub max_range_m: f64,
    /// Chi-square gate (2 degrees of freedom: offset and tilt) of a line on a surface under
    /// the prediction; 18.42 is the 1 - 1e-4 point.
    pub association_gate_chi2: f64,
    /// A line counts as on a surface only within this (m) of the part of it already seen:
    /// two walls in one plane a door apart are two surfaces until a line joins them.
    pub extent_margin_m: f64,
    /// A surface's unevenness under a line's offset, m: lines on a real wall at different
    /// places and times disagree by that much more than their noise.
    pub roughness_m: f64,
    /// A surface's waviness under a line's tilt, degrees.
    pub waviness_deg: f64,
    /// Prior sigma of a new surface's normal, degrees, about the plane that placed it: vague,
    /// so that the lines that placed it decide it (with their correlation with the pose).
    pub new_surface_sigma_deg: f64,
    /// Prior sigma of a new surface's distance, m.
    pub new_surface_sigma_m: f64,
    /// A surface placed through one line (`level_lines`, `wall_lines`) cannot measure its turn
    /// about the line: a building's floor is level and its wall plumb to within this, degrees,
    /// in the navigation frame.
    pub building_sigma_deg: f64,
}

impl Default for MapConfig {
    fn default() -> Self {
        Self {
            max_surfaces: 30,
            forget_after_s: 20.0,
            max_range_m: 25.0,
            association_gate_chi2: 18.42,
            extent_margin_m: 0.5,
            roughness_m: 0.003,
            waviness_deg: 0.1,
            new_surface_sigma_deg: 5.0,
            new_surface_sigma_m: 1.0,
            building_sigma_deg: 0.17,
        }
    }
}

impl MapConfig {
    pub(crate) fn allowance(&self) -> SurfaceAllowance {
        SurfaceAllowance {
            roughness_m: self.roughness_m,
            waviness_rad: self.waviness_deg.to_radians(),
        }
    }

    pub(crate) fn check(&self, errors: &mut ConfigErrors) {
        let mut map = errors.table("odometry.map");
        let positive = "set it to a finite number above 0";
        let checks = [
            (
                "forget_after_s",
                self.forget_after_s,
                self.forget_after_s > 0.0,
                positive,
            ),
            (
                "max_range_m",
                self.max_range_m,
                self.max_range_m > 0.0,
                positive,
            ),
            (
                "association_gate_chi2",
                self.association_gate_chi2,
                self.association_gate_chi2 > 0.0,
                positive,
            ),
            (
                "extent_margin_m",
                self.extent_margin_m,
                self.extent_margin_m >= 0.0,
                "set it to 0 or more",
            ),
            (
                "roughness_m",
                self.roughness_m,
                self.roughness_m > 0.0,
                positive,
            ),
            (
                "waviness_deg",
                self.waviness_deg,
                self.waviness_deg > 0.0,
                positive,
            ),
            (
                "new_surface_sigma_deg",
                self.new_surface_sigma_deg,
                self.new_surface_sigma_deg > 0.0 && self.new_surface_sigma_deg <= 30.0,
                "set it above 0 and at most 30 degrees (the update linearises about it)",
            ),
            (
                "new_surface_sigma_m",
                self.new_surface_sigma_m,
                self.new_surface_sigma_m > 0.0,
                positive,
            ),
            (
                "building_sigma_deg",
                self.building_sigma_deg,
                self.building_sigma_deg > 0.0,
                positive,
            ),
        ];
        for (key, value, ok, fix) in checks {
            map.check(ok && value.is_finite(), key, value, fix);
        }
        map.check(
            (1..=200).contains(&self.max_surfaces),
            "max_surfaces",
            self.max_surfaces,
            "set it between 1 and 200",
        );
    }
}
