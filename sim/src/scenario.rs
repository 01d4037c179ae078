//! A complete simulation setup (scene, trajectory, sensors, seed), by built-in name or TOML file.

use super::builtin;
use super::imu::{ImuConfig, TriadErrors};
use super::scanner::ScannerConfig;
use super::scene::Scene;
use super::trajectory::Trajectory;
use super::{random_corridor, random_room};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub const BUILTIN_NAMES: [&str; 8] = [
    "paper-sim",
    "office-door",
    "hallway-hover",
    "hallway-flight",
    "bare-corridor",
    "board-corridor",
    "open-room",
    "hall-walk",
];

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScenarioError {
    #[error("unknown scenario \"{0}\": choose one of paper-sim, office-door, hallway-hover, hallway-flight, bare-corridor, board-corridor, open-room, hall-walk, random-room-N or random-corridor-N (N any whole number), or give a .toml file")]
    UnknownName(String),
    #[error("cannot read scenario file {path}: {reason}")]
    Unreadable { path: String, reason: String },
    #[error("scenario file {source_name} is malformed{location}: {message}")]
    Malformed {
        source_name: String,
        location: String,
        message: String,
    },
    #[error("scenario \"{scenario}\" is invalid: {problem}")]
    Invalid { scenario: String, problem: String },
    #[error("cannot write scenario \"{scenario}\" as TOML: {reason}")]
    Unwritable { scenario: String, reason: String },
}

fn default_truth_rate() -> f64 {
    50.0
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    pub name: String,
    /// Seed of every random stream (range noise, dropouts, IMU noise and bias drift).
    #[serde(default)]
    pub seed: u64,
    /// Events are produced for times in `[0, duration_s]`.
    pub duration_s: f64,
    #[serde(default = "default_truth_rate")]
    pub truth_rate_hz: f64,
    pub trajectory: Trajectory,
    pub scanners: Vec<ScannerConfig>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imu: Option<ImuConfig>,
    pub scene: Scene,
}

/// `random-room-N` or `random-corridor-N`: the scene drawn from seed N.
fn drawn_from_a_seed(name: &str) -> Option<Scenario> {
    let seed = |prefix: &str| name.strip_prefix(prefix)?.parse().ok();
    seed(random_room::PREFIX)
        .map(random_room::random_room)
        .or_else(|| seed(random_corridor::PREFIX).map(random_corridor::random_corridor))
}

impl Scenario {
    pub fn builtin(name: &str) -> Result<Self, ScenarioError> {
        match name {
            "paper-sim" => Ok(builtin::paper_sim(builtin::PaperBias::None)),
            "office-door" => Ok(builtin::office_door()),
            "hallway-hover" => Ok(builtin::hallway_hover()),
            "hallway-flight" => Ok(builtin::hallway_flight()),
            "bare-corridor" => Ok(builtin::bare_corridor()),
            "board-corridor" => Ok(builtin::board_corridor()),
            "open-room" => Ok(builtin::open_room()),
            "hall-walk" => Ok(builtin::hall_walk()),
            _ => {
                drawn_from_a_seed(name).ok_or_else(|| ScenarioError::UnknownName(name.to_string()))
            }
        }
    }

    /// A built-in name, or a path to a `.toml` file (anything ending in `.toml` or naming an
    /// existing file) — what `simulate --scenario NAME|FILE` accepts.
    pub fn resolve(name_or_path: &str) -> Result<Self, ScenarioError> {
        let path = Path::new(name_or_path);
        if name_or_path.ends_with(".toml") || path.is_file() {
            Self::load(path)
        } else {
            Self::builtin(name_or_path)
        }
    }

    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let text = std::fs::read_to_string(path).map_err(|e| ScenarioError::Unreadable {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    pub fn from_toml_str(text: &str) -> Result<Self, ScenarioError> {
        Self::parse(text, "<string>")
    }

    fn parse(text: &str, source_name: &str) -> Result<Self, ScenarioError> {
        let scenario: Self = toml::from_str(text).map_err(|e| {
            let location = e
                .span()
                .map(|span| {
                    let before = &text[..span.start.min(text.len())];
                    let line = 1 + before.matches('\n').count();
                    format!(" at line {line}")
                })
                .unwrap_or_default();
            ScenarioError::Malformed {
                source_name: source_name.to_string(),
                location,
                message: e.message().replace('\n', " ").trim().to_string(),
            }
        })?;
        scenario.validate()?;
        Ok(scenario)
    }

    pub fn to_toml(&self) -> Result<String, ScenarioError> {
        toml::to_string(self).map_err(|e| ScenarioError::Unwritable {
            scenario: self.name.clone(),
            reason: e.to_string().replace('\n', " "),
        })
    }

    /// Checks everything the simulator relies on; the first problem found is reported.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let invalid = |problem: String| ScenarioError::Invalid {
            scenario: self.name.clone(),
            problem,
        };
        if !(self.duration_s >= 0.0 && self.duration_s.is_finite()) {
            return Err(invalid("duration_s must be zero or positive".into()));
        }
        if !(self.truth_rate_hz > 0.0 && self.truth_rate_hz.is_finite()) {
            return Err(invalid("truth_rate_hz must be positive".into()));
        }
        if let Some(problem) = self.trajectory.problem() {
            return Err(invalid(problem));
        }
        if self.imu.is_some() && !self.trajectory.is_smooth() {
            return Err(invalid(
                "a step trajectory with no ramp_s jumps, so no IMU can follow it: give it a ramp_s or remove the [imu] table".into(),
            ));
        }
        let problems = self
            .scanners
            .iter()
            .filter_map(ScannerConfig::problem)
            .chain(self.imu.as_ref().and_then(ImuConfig::problem))
            .chain(self.scene.patches.iter().filter_map(|p| p.problem()));
        match problems.into_iter().next() {
            Some(problem) => Err(invalid(problem)),
            None => Ok(()),
        }
    }

    /// The same scenario with every random error switched off: exact ranges (still quantised to
    /// 1 mm), no dropouts, an ideal IMU.
    pub fn without_noise(mut self) -> Self {
        for scanner in &mut self.scanners {
            scanner.range_sigma_m = 0.0;
            scanner.dropout_probability = 0.0;
        }
        if let Some(imu) = &mut self.imu {
            imu.gyro = TriadErrors::NONE;
            imu.accel = TriadErrors::NONE;
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_round_trips_through_toml() {
        for name in BUILTIN_NAMES {
            let scenario = Scenario::builtin(name).unwrap();
            scenario.validate().unwrap();
            let text = scenario.to_toml().unwrap();
            let back = Scenario::from_toml_str(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(back, scenario, "{name}");
        }
    }

    #[test]
    fn unknown_name_lists_the_choices() {
        let err = Scenario::builtin("foo").unwrap_err();
        assert_eq!(
            err.to_string(),
            "unknown scenario \"foo\": choose one of paper-sim, office-door, hallway-hover, hallway-flight, bare-corridor, board-corridor, open-room, hall-walk, random-room-N or random-corridor-N (N any whole number), or give a .toml file"
        );
        assert!(matches!(
            Scenario::resolve("foo"),
            Err(ScenarioError::UnknownName(_))
        ));
    }

    #[test]
    fn malformed_files_give_one_line_naming_the_problem() {
        let mut text = Scenario::builtin("office-door").unwrap().to_toml().unwrap();
        text = text.replacen("duration_s", "duraton_s", 1);
        let line = 1 + text
            .lines()
            .position(|l| l.starts_with("duraton_s"))
            .unwrap();
        let err = Scenario::from_toml_str(&text).unwrap_err().to_string();
        assert!(err.contains("unknown field `duraton_s`"), "{err}");
        assert!(err.contains(&format!("at line {line}:")), "{err}");
        assert!(!err.contains('\n'), "{err}");

        let err = Scenario::from_toml_str("name = 3").unwrap_err().to_string();
        assert!(
            err.starts_with("scenario file <string> is malformed at line 1"),
            "{err}"
        );
        assert!(!err.contains('\n'), "{err}");
    }

    #[test]
    fn missing_file_names_the_path() {
        let err = Scenario::resolve("/nonexistent/dir/x.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("cannot read scenario file /nonexistent/dir/x.toml"),
            "{err}"
        );
        assert!(!err.contains('\n'));
    }

    #[test]
    fn invalid_values_are_rejected_with_the_culprit() {
        let mut scenario = Scenario::builtin("office-door").unwrap();
        scenario.scene.patches[0].axis_v = scenario.scene.patches[0].axis_u;
        let err = Scenario::from_toml_str(&scenario.to_toml().unwrap()).unwrap_err();
        assert!(err
            .to_string()
            .contains(&format!("patch \"{}\"", scenario.scene.patches[0].name)));

        let mut paper = Scenario::builtin("paper-sim").unwrap();
        assert!(paper.imu.is_some() && paper.validate().is_ok());
        let set_ramp = |paper: &mut Scenario, seconds: f64| {
            let Trajectory::Step { ramp_s, .. } = &mut paper.trajectory else {
                panic!("paper-sim is a step");
            };
            *ramp_s = seconds;
        };
        set_ramp(&mut paper, 0.0);
        assert!(paper
            .validate()
            .unwrap_err()
            .to_string()
            .contains("remove the [imu] table"));
        set_ramp(&mut paper, -1.0);
        assert!(paper
            .validate()
            .unwrap_err()
            .to_string()
            .contains("ramp_s = -1 is invalid"));

        let mut custom = Scenario::builtin("paper-sim").unwrap();
        custom.scanners[0].geometry = None;
        assert!(custom
            .validate()
            .unwrap_err()
            .to_string()
            .contains("needs a [scanners.geometry]"));
    }

    #[test]
    fn bundled_scenario_files_match_the_builtins() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/scenarios");
        for name in BUILTIN_NAMES {
            let path = dir.join(format!("{name}.toml"));
            let from_file = Scenario::resolve(path.to_str().unwrap()).unwrap();
            assert_eq!(from_file, Scenario::builtin(name).unwrap(), "{name}");
        }
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_is_refused_cleanly(text in "\\PC{0,200}") {
            if let Err(err) = Scenario::from_toml_str(&text) {
                proptest::prop_assert!(!err.to_string().contains('\n'));
            }
        }

        #[test]
        fn damaged_scenario_files_are_refused_cleanly(cut in 0usize..2000, len in 1usize..40) {
            let text = Scenario::builtin("hallway-hover").unwrap().to_toml().unwrap();
            let start = cut.min(text.len() - 1);
            let end = (start + len).min(text.len());
            let damaged = format!("{}{}", &text[..start], &text[end..]);
            if let Err(err) = Scenario::from_toml_str(&damaged) {
                proptest::prop_assert!(!err.to_string().contains('\n'), "{}", err);
            }
        }
    }
}
