//! `estimate.mcap`: a run as Foxglove shows it without configuration. The estimated pose
//! (`/pose`, and `/tf` from `ned` to `body`), each scanner's readings in its mounted frame
//! (`/scan/NAME`), the planes of each epoch as thin boxes in the body frame (`/planes`, blue
//! when used, red when excluded) and the integrity monitor's verdicts (`/integrity`), all in
//! Foxglove's well-known schemas with JSON encoding.

use super::foxglove_schemas as schemas;
use super::outputs::OutputError;
use crate::estimate::Estimate;
use crate::sensors::{Mount, Scan, ScannerGeometry};
use mcap::records::MessageHeader;
use mcap::{WriteOptions, Writer};
use nalgebra::{UnitQuaternion, Vector3};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

pub(crate) const FOXGLOVE_FILE: &str = "estimate.mcap";

/// Side of the box drawn for a plane, m: a plane has no edges, so the box shows where it lies
/// and how it is turned.
const PLANE_SIDE_M: f64 = 3.0;
/// Foxglove's log levels.
const LOG_INFO: u8 = 2;
const LOG_WARNING: u8 = 3;

struct Channels {
    pose: u16,
    transform: u16,
    planes: u16,
    integrity: u16,
    scans: Vec<u16>,
}

/// A scanner as drawn: its frame's name, mount and geometry once known.
struct Scanner {
    frame: String,
    mount: Mount,
    geometry: Option<ScannerGeometry>,
}

pub(crate) struct FoxgloveWriter {
    path: PathBuf,
    writer: Writer<BufWriter<File>>,
    channels: Channels,
    scanners: Vec<Scanner>,
    mounts_published: bool,
    sequence: u32,
}

impl FoxgloveWriter {
    /// `scanners`: each scanner's name and mount, in configuration order.
    pub(crate) fn create(dir: &Path, scanners: &[(String, Mount)]) -> Result<Self, OutputError> {
        let path = dir.join(FOXGLOVE_FILE);
        let fail = |e: mcap::McapError| write_error(&path, e);
        let file = File::create(&path).map_err(|source| OutputError::Write {
            path: path.clone(),
            source,
        })?;
        let mut writer = WriteOptions::new()
            .profile("")
            .create(BufWriter::new(file))
            .map_err(fail)?;
        let mut channel = |topic: &str, name: &str, schema: String| -> Result<u16, OutputError> {
            let id = writer
                .add_schema(name, "jsonschema", schema.as_bytes())
                .map_err(fail)?;
            writer
                .add_channel(id, topic, "json", &BTreeMap::new())
                .map_err(fail)
        };
        let channels = Channels {
            pose: channel("/pose", "foxglove.PoseInFrame", schemas::pose_in_frame())?,
            transform: channel("/tf", "foxglove.FrameTransform", schemas::frame_transform())?,
            planes: channel("/planes", "foxglove.SceneUpdate", schemas::scene_update())?,
            integrity: channel("/integrity", "foxglove.Log", schemas::log())?,
            scans: scanners
                .iter()
                .map(|(name, _)| {
                    channel(
                        &format!("/scan/{name}"),
                        "foxglove.LaserScan",
                        schemas::laser_scan(),
                    )
                })
                .collect::<Result<_, _>>()?,
        };
        Ok(Self {
            scanners: scanners
                .iter()
                .map(|(name, mount)| Scanner {
                    frame: name.clone(),
                    mount: *mount,
                    geometry: None,
                })
                .collect(),
            path,
            writer,
            channels,
            mounts_published: false,
            sequence: 0,
        })
    }

    pub(crate) fn geometry(&mut self, scanner: usize, geometry: ScannerGeometry) {
        if let Some(s) = self.scanners.get_mut(scanner) {
            s.geometry = Some(geometry);
        }
    }

    /// The scan as `foxglove.LaserScan` in its scanner's frame, stamped at its first reading;
    /// invalid readings (NaN) become null, which Foxglove leaves out.
    pub(crate) fn scan(&mut self, scan: &Scan) -> Result<(), OutputError> {
        let Some(scanner) = self.scanners.get(scan.sensor) else {
            return Ok(());
        };
        let (Some(geometry), Some(&channel)) =
            (scanner.geometry, self.channels.scans.get(scan.sensor))
        else {
            return Ok(());
        };
        let last = scan.ranges_m.len().saturating_sub(1);
        let t = scan.time_of(0, &geometry);
        let message = json!({
            "timestamp": stamp(t),
            "frame_id": scanner.frame,
            "pose": pose(&Vector3::zeros(), &UnitQuaternion::identity()),
            "start_angle": geometry.step_azimuth(scan.step_of(0)),
            "end_angle": geometry.step_azimuth(scan.step_of(last)),
            "ranges": scan.ranges_m,
            "intensities": [],
        });
        self.write(channel, t, &message)
    }

    /// The pose on `/pose` and `/tf`; with the first, each scanner's mount on `/tf`.
    pub(crate) fn estimate(&mut self, estimate: &Estimate) -> Result<(), OutputError> {
        let t = estimate.t;
        if !self.mounts_published {
            self.mounts_published = true;
            let mounts: Vec<Value> = self
                .scanners
                .iter()
                .map(|s| transform(t, "body", &s.frame, &s.mount.translation, &s.mount.rotation))
                .collect();
            for message in mounts {
                self.write(self.channels.transform, t, &message)?;
            }
        }
        let pose_message = json!({
            "timestamp": stamp(t),
            "frame_id": "ned",
            "pose": pose(&estimate.position, &estimate.attitude),
        });
        self.write(self.channels.pose, t, &pose_message)?;
        let body = transform(t, "ned", "body", &estimate.position, &estimate.attitude);
        self.write(self.channels.transform, t, &body)
    }

    /// An epoch's line of `epochs.jsonl`: its planes on `/planes`, its verdict on `/integrity`.
    pub(crate) fn epoch(&mut self, line: &Value) -> Result<(), OutputError> {
        let Some(t) = line["t"].as_f64() else {
            return Ok(());
        };
        let excluded: Vec<u64> = line["excluded_planes"]
            .as_array()
            .map_or_else(Vec::new, |ids| {
                ids.iter().filter_map(Value::as_u64).collect()
            });
        let cubes: Vec<Value> = line["plane_geometry"]
            .as_array()
            .map_or_else(Vec::new, |planes| {
                planes
                    .iter()
                    .enumerate()
                    .filter_map(|(id, plane)| plane_cube(plane, excluded.contains(&(id as u64))))
                    .collect()
            });
        let update = json!({
            "deletions": [],
            "entities": [{
                "timestamp": stamp(t),
                "frame_id": "body",
                "id": "planes",
                "lifetime": {"sec": 0, "nsec": 0},
                "frame_locked": false,
                "cubes": cubes,
            }],
        });
        self.write(self.channels.planes, t, &update)?;
        let status = line["status"]["status"].as_str().unwrap_or("none");
        if status != "ok" {
            let level = if excluded.is_empty() {
                LOG_INFO
            } else {
                LOG_WARNING
            };
            let outcome = line["outcome"].as_str().unwrap_or("unknown");
            let log = json!({
                "timestamp": stamp(t),
                "level": level,
                "message": format!("epoch {outcome}, integrity {status}, excluded planes {excluded:?}"),
                "name": "integrity",
                "file": "",
                "line": 0,
            });
            self.write(self.channels.integrity, t, &log)?;
        }
        Ok(())
    }

    pub(crate) fn finish(mut self) -> Result<(), OutputError> {
        self.writer
            .finish()
            .map(|_| ())
            .map_err(|e| write_error(&self.path, e))
    }

    fn write(&mut self, channel_id: u16, t: f64, message: &Value) -> Result<(), OutputError> {
        self.sequence = self.sequence.wrapping_add(1);
        let time = (t.max(0.0) * 1e9) as u64;
        let header = MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: time,
            publish_time: time,
        };
        let bytes = serde_json::to_vec(message).map_err(|source| OutputError::Serialise {
            path: self.path.clone(),
            source,
        })?;
        self.writer
            .write_to_known_channel(&header, &bytes)
            .map_err(|e| write_error(&self.path, e))
    }
}

/// A plane `n . p = rho` as a thin box centred on the point nearest the body, its thin side
/// along the normal.
fn plane_cube(plane: &Value, excluded: bool) -> Option<Value> {
    let normal = plane["normal"].as_array()?;
    let component = |i: usize| normal.get(i).and_then(Value::as_f64);
    let n = Vector3::new(component(0)?, component(1)?, component(2)?);
    let rho = plane["rho"].as_f64()?;
    let centre = n * rho;
    let turn = UnitQuaternion::rotation_between(&Vector3::z(), &n).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    });
    let color = if excluded {
        json!({"r": 0.85, "g": 0.15, "b": 0.15, "a": 0.6})
    } else {
        json!({"r": 0.12, "g": 0.47, "b": 0.71, "a": 0.4})
    };
    Some(json!({
        "pose": pose(&centre, &turn),
        "size": {"x": PLANE_SIDE_M, "y": PLANE_SIDE_M, "z": 0.01},
        "color": color,
    }))
}

fn stamp(t: f64) -> Value {
    let t = t.max(0.0);
    let sec = t.floor();
    json!({"sec": sec as u64, "nsec": (((t - sec) * 1e9) as u64).min(999_999_999)})
}

fn pose(position: &Vector3<f64>, attitude: &UnitQuaternion<f64>) -> Value {
    let q = attitude.quaternion();
    json!({
        "position": {"x": position.x, "y": position.y, "z": position.z},
        "orientation": {"x": q.i, "y": q.j, "z": q.k, "w": q.w},
    })
}

fn transform(
    t: f64,
    parent: &str,
    child: &str,
    translation: &Vector3<f64>,
    rotation: &UnitQuaternion<f64>,
) -> Value {
    let q = rotation.quaternion();
    json!({
        "timestamp": stamp(t),
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": translation.x, "y": translation.y, "z": translation.z},
        "rotation": {"x": q.i, "y": q.j, "z": q.k, "w": q.w},
    })
}

fn write_error(path: &Path, error: mcap::McapError) -> OutputError {
    OutputError::Write {
        path: path.to_path_buf(),
        source: std::io::Error::other(error),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plane_box_lies_on_its_plane_with_its_thin_side_along_the_normal() {
        let n = Vector3::new(0.0, 0.6, 0.8);
        let cube = plane_cube(&json!({"normal": [0.0, 0.6, 0.8], "rho": 2.0}), false).unwrap();
        let p = &cube["pose"]["position"];
        let centre = Vector3::new(
            p["x"].as_f64().unwrap(),
            p["y"].as_f64().unwrap(),
            p["z"].as_f64().unwrap(),
        );
        assert!((centre.dot(&n) - 2.0).abs() < 1e-12);
        let o = &cube["pose"]["orientation"];
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            o["w"].as_f64().unwrap(),
            o["x"].as_f64().unwrap(),
            o["y"].as_f64().unwrap(),
            o["z"].as_f64().unwrap(),
        ));
        assert!((q * Vector3::z() - n).norm() < 1e-12);
    }

    #[test]
    fn stamps_split_seconds_and_nanoseconds() {
        assert_eq!(stamp(12.25), json!({"sec": 12, "nsec": 250_000_000}));
        assert_eq!(stamp(-1.0), json!({"sec": 0, "nsec": 0}));
    }
}
