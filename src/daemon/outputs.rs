//! The files `run` and `replay` write with `--out DIR` (docs/design.md, "Output files"):
//! `trajectory.tum`,
//! `epochs.jsonl` and `mavlink.tlog`. Each writer is buffered; `finish` flushes and reports the
//! first write error, which would otherwise be lost in a drop. `replay` adds `truth.tum` (here),
//! `estimate.mcap` (`daemon::foxglove`) and, with `--report`, `report.html` (`crate::report`).

use crate::estimate::Estimate;
use crate::sensors::TruthSample;
use nalgebra::{UnitQuaternion, Vector3};
use serde::Serialize;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

pub(crate) const TRAJECTORY_FILE: &str = "trajectory.tum";
pub(crate) const EPOCHS_FILE: &str = "epochs.jsonl";
pub(crate) const TLOG_FILE: &str = "mavlink.tlog";
/// Written by `replay --out` when the recording carries `/truth`.
pub(crate) const TRUTH_FILE: &str = "truth.tum";
/// Drawn by `replay --report` beside the other three.
pub(crate) const REPORT_FILE: &str = "report.html";

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("cannot create output directory {path}: {source} (choose a writable --out)")]
    CreateDir { path: PathBuf, source: io::Error },
    #[error("cannot write {path}: {source} (check free space and permissions)")]
    Write { path: PathBuf, source: io::Error },
    #[error("cannot serialise an epoch record for {path}: {source}")]
    Serialise {
        path: PathBuf,
        source: serde_json::Error,
    },
}

/// A buffered file that remembers its path for error messages.
struct NamedWriter {
    path: PathBuf,
    out: BufWriter<File>,
}

impl NamedWriter {
    fn create(path: PathBuf) -> Result<Self, OutputError> {
        match File::create(&path) {
            Ok(file) => Ok(Self {
                out: BufWriter::new(file),
                path,
            }),
            Err(source) => Err(OutputError::Write { path, source }),
        }
    }

    fn write_all(&mut self, bytes: &[u8]) -> Result<(), OutputError> {
        self.out
            .write_all(bytes)
            .map_err(|source| self.error(source))
    }

    fn flush(&mut self) -> Result<(), OutputError> {
        self.out.flush().map_err(|source| self.error(source))
    }

    fn error(&self, source: io::Error) -> OutputError {
        OutputError::Write {
            path: self.path.clone(),
            source,
        }
    }
}

/// One TUM line: `t x y z qx qy qz qw`, position NED, attitude body->NED.
pub(crate) fn tum_line(estimate: &Estimate) -> String {
    tum_record(estimate.t, &estimate.position, &estimate.attitude)
}

fn tum_record(t: f64, p: &Vector3<f64>, attitude: &UnitQuaternion<f64>) -> String {
    let q = attitude.quaternion();
    format!(
        "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}\n",
        t, p.x, p.y, p.z, q.i, q.j, q.k, q.w
    )
}

/// `truth.tum` beside `trajectory.tum`, in the same format, for evo (`evo_ape tum truth.tum
/// trajectory.tum --align`): the simulator's truth is in its scene's frame, which the alignment
/// takes out.
pub(crate) fn write_truth(dir: &Path, truth: &[TruthSample]) -> Result<(), OutputError> {
    let mut file = NamedWriter::create(dir.join(TRUTH_FILE))?;
    for sample in truth {
        file.write_all(tum_record(sample.t, &sample.p, &sample.q).as_bytes())?;
    }
    file.flush()
}

/// `mavlink.tlog` framing: each message behind the big-endian microseconds of its send time.
pub(crate) fn tlog_record(time_us: u64, frame: &[u8]) -> Vec<u8> {
    let mut record = Vec::with_capacity(8 + frame.len());
    record.extend_from_slice(&time_us.to_be_bytes());
    record.extend_from_slice(frame);
    record
}

/// The three output files of one run.
pub(crate) struct Outputs {
    trajectory: NamedWriter,
    epochs: NamedWriter,
    tlog: NamedWriter,
}

impl Outputs {
    /// Creates `dir` if needed and the three files in it, replacing earlier ones.
    pub(crate) fn create(dir: &Path) -> Result<Self, OutputError> {
        std::fs::create_dir_all(dir).map_err(|source| OutputError::CreateDir {
            path: dir.to_path_buf(),
            source,
        })?;
        Ok(Self {
            trajectory: NamedWriter::create(dir.join(TRAJECTORY_FILE))?,
            epochs: NamedWriter::create(dir.join(EPOCHS_FILE))?,
            tlog: NamedWriter::create(dir.join(TLOG_FILE))?,
        })
    }

    pub(crate) fn trajectory(&mut self, estimate: &Estimate) -> Result<(), OutputError> {
        self.trajectory.write_all(tum_line(estimate).as_bytes())
    }

    /// One odometry epoch as one JSON line. The record's shape belongs to the fusion (time,
    /// planes seen/matched/used, excluded ids, statistics, thresholds, MDB, motion, covariances,
    /// status); any `Serialize` value, including a `serde_json::Value`, is accepted.
    pub(crate) fn epoch<T: Serialize>(&mut self, record: &T) -> Result<(), OutputError> {
        let mut line = serde_json::to_vec(record).map_err(|source| OutputError::Serialise {
            path: self.epochs.path.clone(),
            source,
        })?;
        line.push(b'\n');
        self.epochs.write_all(&line)
    }

    /// One MAVLink frame exactly as sent. `time_us` is wall-clock microseconds since the UNIX
    /// epoch, which is what MAVProxy, Mission Planner and pymavlink read from a tlog.
    pub(crate) fn mavlink(&mut self, time_us: u64, frame: &[u8]) -> Result<(), OutputError> {
        self.tlog.write_all(&tlog_record(time_us, frame))
    }

    /// Flushes all three files.
    pub(crate) fn flush(&mut self) -> Result<(), OutputError> {
        self.trajectory.flush()?;
        self.epochs.flush()?;
        self.tlog.flush()
    }

    pub(crate) fn finish(mut self) -> Result<(), OutputError> {
        self.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::mavlink_out::{heartbeat, DEFAULT_COMPONENT_ID};
    use crate::estimate::IntegrityStatus;
    use mavlink::dialects::ardupilotmega::MavMessage;
    use mavlink::dialects::ardupilotmega::MavState;
    use mavlink::{MavHeader, MavlinkReader, MavlinkVersion};
    use nalgebra::Matrix3;

    fn estimate(t: f64) -> Estimate {
        Estimate {
            t,
            position: Vector3::new(1.5, -2.0, -0.25),
            velocity: Vector3::zeros(),
            attitude: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
            angular_rate: Vector3::zeros(),
            position_covariance: Matrix3::identity(),
            velocity_covariance: Matrix3::identity(),
            velocity_attitude_covariance: Matrix3::zeros(),
            attitude_covariance: Matrix3::identity(),
            gyro_bias: Vector3::zeros(),
            accel_bias: Vector3::zeros(),
            reset_counter: 0,
            last_reset: None,
            integrity: Some(IntegrityStatus::Ok),
            since_last_fused: 0.0,
            degraded: false,
            converged: true,
        }
    }

    fn scratch_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("ladar-outputs-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn tum_line_is_t_position_then_quaternion_xyzw() {
        let fields: Vec<f64> = tum_line(&estimate(12.5))
            .split_whitespace()
            .map(|f| f.parse().unwrap())
            .collect();
        let q = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3);
        let expected = [12.5, 1.5, -2.0, -0.25, q.i, q.j, q.k, q.w];
        for (got, want) in fields.iter().zip(expected) {
            assert!((got - want).abs() < 1e-6, "{fields:?}");
        }
        assert_eq!(fields.len(), 8);
    }

    #[test]
    fn writes_three_files_that_read_back() {
        let dir = scratch_dir("all");
        let mut out = Outputs::create(&dir).unwrap();
        out.trajectory(&estimate(1.0)).unwrap();
        out.trajectory(&estimate(2.0)).unwrap();
        out.epoch(&serde_json::json!({"t": 1.0, "status": "ok", "planes_used": 5}))
            .unwrap();
        out.epoch(&IntegrityStatus::Excluded { planes: vec![2, 7] })
            .unwrap();
        let mut frames = Vec::new();
        for sequence in 0..3u8 {
            let header = MavHeader {
                system_id: 1,
                component_id: DEFAULT_COMPONENT_ID,
                sequence,
            };
            let mut frame = Vec::new();
            mavlink::write_v2_msg(&mut frame, header, &heartbeat(MavState::MAV_STATE_ACTIVE))
                .unwrap();
            out.mavlink(1_000_000 + u64::from(sequence), &frame)
                .unwrap();
            frames.push(frame);
        }
        out.finish().unwrap();

        let tum = std::fs::read_to_string(dir.join(TRAJECTORY_FILE)).unwrap();
        assert_eq!(tum.lines().count(), 2);
        let epochs = std::fs::read_to_string(dir.join(EPOCHS_FILE)).unwrap();
        let lines: Vec<serde_json::Value> = epochs
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(lines[0]["planes_used"], 5);
        assert_eq!(lines[1]["status"], "excluded");
        assert_eq!(lines[1]["planes"], serde_json::json!([2, 7]));

        let tlog = std::fs::read(dir.join(TLOG_FILE)).unwrap();
        let mut rest = &tlog[..];
        for (sequence, frame) in frames.iter().enumerate() {
            let time = u64::from_be_bytes(rest[..8].try_into().unwrap());
            assert_eq!(time, 1_000_000 + sequence as u64);
            let mut reader = MavlinkReader::new(&rest[8..]);
            let (header, message) = reader
                .read_message::<MavMessage>(MavlinkVersion::V2)
                .unwrap();
            assert_eq!(header.sequence as usize, sequence);
            assert!(matches!(message, MavMessage::HEARTBEAT(_)));
            assert_eq!(&rest[8..8 + frame.len()], &frame[..]);
            rest = &rest[8 + frame.len()..];
        }
        assert!(rest.is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_unwritable_directory_is_one_line_naming_it() {
        let blocker = scratch_dir("blocker");
        std::fs::write(&blocker, b"a file, not a directory").unwrap();
        let err = Outputs::create(&blocker.join("out"))
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("--out") && !err.contains('\n'), "{err}");
        std::fs::remove_file(&blocker).unwrap();
    }
}
