//! Shared by the daemon's integration tests: one rig (a level and a pitched scanner plus an
//! IMU) whose connections each test points at its own emulators.

use std::path::PathBuf;

/// A fresh directory per test process and name, so parallel tests never share files.
pub fn scratch(prefix: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ladar-{prefix}-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A port nobody listens on at the moment of asking.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

pub fn rig_config(front: &str, pitched: &str, imu: &str) -> String {
    format!(
        r#"
[[scanner]]
name = "front"
connection = "{front}"
rpy_deg = [0.0, 0.0, 0.0]
translation_m = [0.1, 0.0, 0.0]
range_sigma_m = 0.01

[[scanner]]
name = "pitched"
connection = "{pitched}"
rpy_deg = [0.0, 20.0, 0.0]
translation_m = [0.1, 0.0, -0.1]
range_sigma_m = 0.01

[imu]
connection = "{imu}"
rate_hz = 100
"#
    )
}
