//! Shared by the daemon's integration tests: one rig (a level and a pitched scanner plus an
//! IMU) whose connections each test points at its own emulators.

use std::path::{Path, PathBuf};

/// A fresh directory per test process and name, so parallel tests never share files; removed
/// with what it holds when dropped, even by a failing test, so that runs do not fill /tmp.
pub struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub fn scratch(prefix: &str, name: &str) -> Scratch {
    sweep_stale(prefix);
    let dir = std::env::temp_dir().join(format!("ladar-{prefix}-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    Scratch(dir)
}

/// Removes what earlier test processes left under `ladar-{prefix}-{pid}...` in the temporary
/// directory: a test killed, or files several tests of one process share (a recording made
/// once), outlive the test that made them. Only where /proc tells which processes are gone.
pub fn sweep_stale(prefix: &str) {
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    if !Path::new("/proc/self").exists() {
        return;
    }
    let start = format!("ladar-{prefix}-");
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(pid) = name
            .strip_prefix(&start)
            .and_then(|rest| rest.split(['-', '.']).next()?.parse::<u32>().ok())
        else {
            continue;
        };
        if pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_dir_all(entry.path());
            let _ = std::fs::remove_file(entry.path());
        }
    }
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
