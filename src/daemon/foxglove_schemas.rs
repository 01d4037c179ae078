//! Foxglove's well-known message schemas, as the JSON schemas `estimate.mcap` carries (message
//! encoding `json`). Each covers the fields this project writes, named and typed as Foxglove
//! defines them, so that Foxglove opens the file with its own panels and no configuration.

const TIME: &str = r#"{"type":"object","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}}}"#;
const VECTOR3: &str = r#"{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}}"#;
const QUATERNION: &str = r#"{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}"#;
const COLOR: &str = r#"{"type":"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"type":"number"},"a":{"type":"number"}}}"#;

fn pose() -> String {
    format!(
        r#"{{"type":"object","properties":{{"position":{VECTOR3},"orientation":{QUATERNION}}}}}"#
    )
}

/// `foxglove.PoseInFrame`: the estimated pose.
pub(crate) fn pose_in_frame() -> String {
    format!(
        r#"{{"title":"foxglove.PoseInFrame","type":"object","properties":{{"timestamp":{TIME},"frame_id":{{"type":"string"}},"pose":{}}}}}"#,
        pose()
    )
}

/// `foxglove.FrameTransform`: navigation to body, body to each scanner.
pub(crate) fn frame_transform() -> String {
    format!(
        r#"{{"title":"foxglove.FrameTransform","type":"object","properties":{{"timestamp":{TIME},"parent_frame_id":{{"type":"string"}},"child_frame_id":{{"type":"string"}},"translation":{VECTOR3},"rotation":{QUATERNION}}}}}"#
    )
}

/// `foxglove.LaserScan`: one scanner's readings in its own frame.
pub(crate) fn laser_scan() -> String {
    format!(
        r#"{{"title":"foxglove.LaserScan","type":"object","properties":{{"timestamp":{TIME},"frame_id":{{"type":"string"}},"pose":{},"start_angle":{{"type":"number"}},"end_angle":{{"type":"number"}},"ranges":{{"type":"array","items":{{"type":"number"}}}},"intensities":{{"type":"array","items":{{"type":"number"}}}}}}}}"#,
        pose()
    )
}

/// `foxglove.SceneUpdate` with cube entities: the planes of an epoch.
pub(crate) fn scene_update() -> String {
    let cube = format!(
        r#"{{"type":"object","properties":{{"pose":{},"size":{VECTOR3},"color":{COLOR}}}}}"#,
        pose()
    );
    let entity = format!(
        r#"{{"type":"object","properties":{{"timestamp":{TIME},"frame_id":{{"type":"string"}},"id":{{"type":"string"}},"lifetime":{{"type":"object","properties":{{"sec":{{"type":"integer"}},"nsec":{{"type":"integer"}}}}}},"frame_locked":{{"type":"boolean"}},"cubes":{{"type":"array","items":{cube}}}}}}}"#
    );
    format!(
        r#"{{"title":"foxglove.SceneUpdate","type":"object","properties":{{"deletions":{{"type":"array","items":{{"type":"object"}}}},"entities":{{"type":"array","items":{entity}}}}}}}"#
    )
}

/// `foxglove.Log`: the integrity monitor's verdicts other than "ok", and resets.
pub(crate) fn log() -> String {
    format!(
        r#"{{"title":"foxglove.Log","type":"object","properties":{{"timestamp":{TIME},"level":{{"type":"integer","enum":[0,1,2,3,4,5]}},"message":{{"type":"string"}},"name":{{"type":"string"}},"file":{{"type":"string"}},"line":{{"type":"integer","minimum":0}}}}}}"#
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_schema_is_json_with_its_foxglove_title() {
        for (schema, title) in [
            (pose_in_frame(), "foxglove.PoseInFrame"),
            (frame_transform(), "foxglove.FrameTransform"),
            (laser_scan(), "foxglove.LaserScan"),
            (scene_update(), "foxglove.SceneUpdate"),
            (log(), "foxglove.Log"),
        ] {
            let value: serde_json::Value = serde_json::from_str(&schema).unwrap();
            assert_eq!(value["title"], title);
            assert_eq!(value["type"], "object");
        }
    }
}
