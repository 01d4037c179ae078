//! config/default.toml and every example in config/examples/ load, and default.toml says what
//! the code does: each key it sets equals the code's default.

#[allow(dead_code)]
mod support;

use ladar_odometer::daemon::config::{Config, ImuOutput, ImuSeries, ScanStream};
use ladar_odometer::fusion::FusionSettings;
use std::path::{Path, PathBuf};

fn repository(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// Key files live on the target; a test key stands in.
fn load(path: &Path, key_file: &Path) -> Config {
    let text = std::fs::read_to_string(path).unwrap().replace(
        "/etc/ladar-odometer/mavlink.key",
        &key_file.to_string_lossy(),
    );
    Config::parse(&text, path).unwrap_or_else(|e| panic!("{e}"))
}

/// One file per test: tests run in parallel, and one rewriting a shared file while another
/// reads it shows the reader an empty key.
fn key_file(test: &str) -> PathBuf {
    support::sweep_stale("config-key");
    let name = format!("ladar-config-key-{}-{test}", std::process::id());
    let path = std::env::temp_dir().join(name);
    std::fs::write(&path, "ab".repeat(32)).unwrap();
    path
}

#[test]
fn default_toml_sets_the_code_defaults() {
    let config = load(&repository("config/default.toml"), &key_file("default"));
    // The fusion tables, key by key (imu_mount_rpy_deg comes from [imu], zero here).
    let code = FusionSettings::default();
    let file = config.fusion_settings();
    assert_eq!(file.fusion, code.fusion);
    assert_eq!(file.odometry, code.odometry);
    assert_eq!(file.integrity, code.integrity);
    assert_eq!(file.filter, code.filter);

    // The daemon's own defaults: what a file that leaves the key out gets.
    let minimal = Config::parse(
        "[[scanner]]\nname = \"a\"\nconnection = \"serial:/dev/a\"\nrpy_deg = [0.0, 0.0, 0.0]\n\
         translation_m = [0.0, 0.0, 0.0]\nrange_sigma_m = 0.01\n\
         [[scanner]]\nname = \"b\"\nconnection = \"serial:/dev/b\"\nrpy_deg = [0.0, -30.0, 0.0]\n\
         translation_m = [0.0, 0.0, 0.0]\nrange_sigma_m = 0.01\n\
         [imu]\nconnection = \"serial:/dev/imu\"\n\
         [mavlink]\nprofile = \"px4\"\nconnection = \"udpout:127.0.0.1:14550\"\n",
        Path::new("minimal.toml"),
    )
    .unwrap();
    for (file, code) in config.scanners.iter().zip(&minimal.scanners) {
        assert_eq!((file.stream, file.cluster), (code.stream, code.cluster));
        assert_eq!((file.first_step, file.last_step), (None, None));
    }
    assert_eq!(config.scanners[0].stream, ScanStream::Md);
    assert_eq!(config.imu.name, minimal.imu.name);
    assert_eq!(config.imu.rpy_deg, Some([0.0; 3]));
    assert_eq!(minimal.imu.rpy_deg.unwrap_or_default(), [0.0; 3]);
    assert_eq!(config.imu.translation_m, minimal.imu.translation_m);
    assert_eq!(config.imu.output, minimal.imu.output);
    assert_eq!(config.imu.output, ImuOutput::Rate);
    assert_eq!(config.imu.rate_hz, minimal.imu.rate_hz);
    assert_eq!(config.imu.series, minimal.imu.series);
    assert_eq!(config.imu.series, ImuSeries::Auto);
    let (file, code) = (config.mavlink.unwrap(), minimal.mavlink.unwrap());
    assert_eq!(file.system_id, code.system_id);
    assert_eq!(file.component_id, code.component_id);
    assert_eq!((file.rate_hz, file.signing), (None, None));
    assert_eq!(config.recording, minimal.recording);
    assert_eq!(config.output, minimal.output);
}

#[test]
fn every_example_loads_and_the_issue_rigs_are_there() {
    let key_file = key_file("examples");
    let mut names = Vec::new();
    for entry in std::fs::read_dir(repository("config/examples")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let config = load(&path, &key_file);
            assert!(
                config.fusion_settings().validate().is_ok(),
                "{}",
                path.display()
            );
            names.push(path.file_name().unwrap().to_string_lossy().into_owned());
        }
    }
    names.sort();
    for wanted in [
        "px4-utm30lx-ust20lx-mti-g-710.toml",
        "ardupilot-two-urg04lx.toml",
    ] {
        assert!(
            names.iter().any(|n| n == wanted),
            "{wanted} missing: {names:?}"
        );
    }
}

/// The names systemd/99-ladar-odometer.rules gives: those of its rules, and those of the
/// rules it shows commented out for the user to fill in with a serial number.
fn udev_names() -> Vec<String> {
    let rules = std::fs::read_to_string(repository("systemd/99-ladar-odometer.rules")).unwrap();
    rules
        .lines()
        .map(|line| line.strip_prefix('#').unwrap_or(line))
        .filter(|rule| rule.starts_with("SUBSYSTEM=="))
        .filter_map(|rule| {
            let name = rule.split("SYMLINK+=\"").nth(1)?;
            Some(name[..name.find('"')?].to_string())
        })
        .collect()
}

/// A udev name matches the device it makes: `hokuyo%n` is hokuyo0, hokuyo1, ...
fn udev_makes(name: &str, device: &str) -> bool {
    match name.strip_suffix("%n") {
        Some(stem) => device
            .strip_prefix(stem)
            .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit())),
        None => device == name,
    }
}

/// Every sensor device a shipped configuration opens is one the udev rules name, so that
/// copying a file and the rules gives a daemon that finds its sensors.
#[test]
fn every_sensor_device_in_the_configs_is_named_by_the_udev_rules() {
    use ladar_odometer::daemon::config::SensorConnection;
    let names = udev_names();
    assert!(names.iter().any(|n| n == "xsens"), "{names:?}");
    assert!(names.iter().any(|n| n == "hokuyo_front"), "{names:?}");
    assert!(udev_makes("hokuyo%n", "hokuyo1") && !udev_makes("hokuyo%n", "hokuyo_utm"));
    let mut files: Vec<PathBuf> = std::fs::read_dir(repository("config/examples"))
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .collect();
    files.push(repository("config/default.toml"));
    let key = key_file("udev");
    let mut checked = 0;
    for file in &files {
        let config = load(file, &key);
        let connections = config
            .scanners
            .iter()
            .map(|s| (s.name.clone(), s.connection()))
            .chain([(config.imu.name.clone(), config.imu.connection())]);
        for (sensor, connection) in connections {
            let SensorConnection::Serial { path, .. } = connection else {
                continue;
            };
            let device = path
                .strip_prefix("/dev")
                .unwrap_or_else(|_| panic!("{}: {sensor} is not under /dev", file.display()))
                .to_string_lossy()
                .into_owned();
            assert!(
                names.iter().any(|name| udev_makes(name, &device)),
                "{}: sensor `{sensor}` opens {}, which no rule in systemd/99-ladar-odometer.rules names",
                file.display(),
                path.display()
            );
            checked += 1;
        }
    }
    assert!(checked >= 10, "{checked}");
}

/// The backpack's mounts as cartographer_ros's backpack_2d.urdf gives them in ROS frames (FLU),
/// turned to FRD by the half turn about x on both sides, F R F and F t.
#[test]
// The URDF's own numbers: 3.14 and 3.1416 there, not pi.
#[allow(clippy::approx_constant)]
fn the_cartographer_backpack_mounts_are_its_urdfs_in_frd() {
    use ladar_odometer::sensors::Mount;
    use nalgebra::{Matrix3, Rotation3, Vector3};
    let config = load(
        &repository("config/examples/cartographer-backpack-2d.toml"),
        &key_file("backpack"),
    );
    let f = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    // (rpy in radians, xyz), as the URDF's joints write them.
    let urdf = [
        ([0.0, 0.0, 0.0], [0.1251, 0.0937, 0.05262]),
        ([0.0, -1.57, 3.14], [0.1251, 0.0937, 0.17772]),
        ([0.0, 0.0, 3.1416], [0.0, 0.0, 0.0]),
    ];
    let mounts = config
        .scanners
        .iter()
        .map(|s| (s.rpy_deg.unwrap(), s.translation_m.unwrap()))
        .chain([(config.imu.rpy_deg.unwrap(), config.imu.translation_m)]);
    for (([r, p, y], xyz), (rpy_deg, translation_m)) in urdf.into_iter().zip(mounts) {
        let want = f * Rotation3::from_euler_angles(r, p, y).matrix() * f;
        let got = Mount::from_rpy_deg(rpy_deg, translation_m);
        let error = (got.rotation.to_rotation_matrix().matrix() - want)
            .abs()
            .max();
        // The IMU's yaw is written 180 deg, the URDF's 3.1416 rad.
        assert!(error < 1e-4, "{rpy_deg:?}: {error}");
        assert!((got.translation - f * Vector3::from(xyz)).norm() < 1e-12);
    }
    // The vertical scanner's forward beam points up, which is -z in FRD.
    let vertical = Mount::from_rpy_deg(config.scanners[1].rpy_deg.unwrap(), [0.0; 3]);
    assert!((vertical.to_body(&Vector3::x()) - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-3);
}
