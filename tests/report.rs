//! `replay --out DIR --report`: the page holds every figure with the series it names, each SVG
//! parses, and a real browser draws it without complaint and with the plots filled.

use ladar_odometer::daemon::fusion_estimator::FusionEstimator;
use ladar_odometer::daemon::replay::{self, ReplayOptions, BUNDLED_RECORDING};
use ladar_odometer::odometry::OdometryMethod;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Figures the bundled recording (simulated, with truth, from its start) must give, with the
/// series each must hold.
const EXPECTED: [(&str, &[&str]); 13] = [
    ("velocity-north", &["error", "+3 sigma", "-3 sigma"]),
    ("velocity-east", &["error", "+3 sigma", "-3 sigma"]),
    ("velocity-down", &["error", "+3 sigma", "-3 sigma"]),
    ("attitude-north", &["error", "+3 sigma", "-3 sigma"]),
    ("attitude-east", &["error", "+3 sigma", "-3 sigma"]),
    ("attitude-down", &["error", "+3 sigma", "-3 sigma"]),
    ("integrity-rotation", &["statistic", "threshold"]),
    ("integrity-displacement", &["statistic", "threshold"]),
    ("planes", &["seen", "matched", "used", "excluded"]),
    ("outcomes", &["reference", "fused"]),
    ("top-view", &["estimate", "truth", "wall"]),
    ("quality", &["quality"]),
    (
        "velocity-sigma",
        &[
            "sigma forward",
            "sigma right",
            "sigma down",
            "unusable above",
        ],
    ),
];

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ladar-report-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn report_of_bundled_recording(dir: &Path) -> String {
    let options = ReplayOptions {
        recording: Path::new(env!("CARGO_MANIFEST_DIR")).join(BUNDLED_RECORDING),
        out: Some(dir.to_path_buf()),
        report: true,
        ..ReplayOptions::default()
    };
    replay::replay(&options, |config, _| FusionEstimator::new(config)).unwrap();
    std::fs::read_to_string(dir.join("report.html")).unwrap()
}

/// `(id, series named, svg)` of each figure on the page.
fn figures(html: &str) -> Vec<(String, Vec<String>, String)> {
    html.split("<figure id=\"")
        .skip(1)
        .map(|part| {
            let (id, rest) = part.split_once('"').unwrap();
            let series = rest
                .split_once("data-series=\"")
                .and_then(|(_, s)| s.split_once('"'))
                .map(|(names, _)| names.split('|').map(str::to_owned).collect())
                .unwrap_or_default();
            let start = rest.find("<svg").unwrap();
            let end = rest.find("</svg>").unwrap() + "</svg>".len();
            (id.to_owned(), series, rest[start..end].to_owned())
        })
        .collect()
}

/// The texts of an SVG: axis labels, titles and legend entries.
fn texts<'a>(document: &'a roxmltree::Document) -> Vec<&'a str> {
    document
        .descendants()
        .filter_map(|node| node.text())
        .map(str::trim)
        .collect()
}

#[test]
fn the_report_holds_every_figure_and_each_svg_parses_with_its_series() {
    let dir = scratch("figures");
    let html = report_of_bundled_recording(&dir);
    let figures = figures(&html);
    for (id, expected) in EXPECTED {
        let (_, named, svg) = figures
            .iter()
            .find(|(figure, _, _)| figure == id)
            .unwrap_or_else(|| panic!("no figure {id}"));
        let document = roxmltree::Document::parse(svg)
            .unwrap_or_else(|e| panic!("figure {id} is not well-formed SVG: {e}"));
        let texts = texts(&document);
        for series in expected {
            assert!(named.iter().any(|n| n == series), "{id} names {named:?}");
            assert!(texts.contains(series), "{id} has no legend entry {series}");
        }
        let drawn = document
            .descendants()
            .filter(|n| matches!(n.tag_name().name(), "polyline" | "circle"))
            .count();
        assert!(drawn >= expected.len() - 1, "{id}: {drawn} shapes");
    }
    // The error series is long: every kept estimate after thinning, not a stub.
    let (_, _, velocity) = figures
        .iter()
        .find(|(id, _, _)| id == "velocity-north")
        .unwrap();
    let longest = roxmltree::Document::parse(velocity)
        .unwrap()
        .descendants()
        .filter_map(|n| n.attribute("points"))
        .map(|points| points.split_whitespace().count())
        .max()
        .unwrap();
    assert!(longest > 500, "{longest} points");
    assert!(
        html.contains("1306 of 1366"),
        "the summary table holds the autopilot view"
    );
    assert_truth_is_tum_for_evo(&dir.join("truth.tum"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Replayed on the plane map, the bundled recording's report draws the hallway's walls from
/// above, each as a segment where it was seen, coloured by the lines it gave.
#[test]
fn the_report_draws_the_plane_map_from_above() {
    let dir = scratch("plane-map");
    let options = ReplayOptions {
        recording: Path::new(env!("CARGO_MANIFEST_DIR")).join(BUNDLED_RECORDING),
        out: Some(dir.clone()),
        report: true,
        ..ReplayOptions::default()
    };
    replay::replay(&options, |config, _| {
        let mut config = config
            .cloned()
            .expect("the bundled recording carries its config");
        config.odometry.method = OdometryMethod::Map;
        FusionEstimator::new(Some(&config))
    })
    .unwrap();
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    let figures = figures(&html);
    let (_, named, svg) = figures
        .iter()
        .find(|(id, _, _)| id == "plane-map")
        .expect("a plane-map figure");
    assert!(named.iter().any(|n| n == "100 lines or more"), "{named:?}");
    let document = roxmltree::Document::parse(svg).unwrap();
    let segments = document
        .descendants()
        .filter(|n| n.tag_name().name() == "polyline")
        .filter_map(|n| n.attribute("points"))
        .filter(|points| points.split_whitespace().count() == 2)
        .count();
    // Both walls of the hallway at least, and the door or the board beside them.
    assert!(segments >= 3, "{segments} wall segments");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `truth.tum` is what `evo_ape tum truth.tum trajectory.tum` reads: `t x y z qx qy qz qw`,
/// time increasing, unit quaternions.
fn assert_truth_is_tum_for_evo(path: &Path) {
    let text = std::fs::read_to_string(path).unwrap();
    let rows: Vec<Vec<f64>> = text
        .lines()
        .map(|line| line.split(' ').map(|f| f.parse().unwrap()).collect())
        .collect();
    assert!(rows.len() > 3000, "{} truth rows", rows.len());
    for pair in rows.windows(2) {
        assert_eq!(pair[0].len(), 8);
        assert!(pair[1][0] > pair[0][0]);
        let norm: f64 = pair[0][4..].iter().map(|q| q * q).sum();
        assert!((norm - 1.0).abs() < 1e-6);
    }
}

/// `estimate.mcap` holds Foxglove's well-known schemas in JSON: the pose at the kept 20 Hz, each
/// scanner's scans with its angles, the planes of every epoch, and the mounts on `/tf`.
#[test]
fn estimate_mcap_carries_foxglove_schemas_with_pose_scans_and_planes() {
    let dir = scratch("foxglove");
    report_of_bundled_recording(&dir);
    let bytes = std::fs::read(dir.join("estimate.mcap")).unwrap();
    let mut per_topic: std::collections::BTreeMap<String, (String, usize)> = Default::default();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let schema = message.channel.schema.as_ref().unwrap();
        assert_eq!(schema.encoding, "jsonschema");
        assert_eq!(message.channel.message_encoding, "json");
        let value: serde_json::Value = serde_json::from_slice(&message.data).unwrap();
        match schema.name.as_str() {
            "foxglove.LaserScan" => {
                assert!(value["ranges"].as_array().unwrap().len() > 100);
                let (start, end) = (
                    value["start_angle"].as_f64().unwrap(),
                    value["end_angle"].as_f64().unwrap(),
                );
                assert!(
                    (start - end).abs() > 3.0,
                    "a UTM/UST scan spans 270 degrees"
                );
            }
            "foxglove.PoseInFrame" => assert_eq!(value["frame_id"], "ned"),
            "foxglove.SceneUpdate" => assert_eq!(value["entities"][0]["frame_id"], "body"),
            _ => {}
        }
        let entry = per_topic
            .entry(message.channel.topic.clone())
            .or_insert((schema.name.clone(), 0));
        entry.1 += 1;
    }
    let count = |topic: &str, schema: &str| {
        let (name, n) = per_topic.get(topic).cloned().unwrap_or_default();
        assert_eq!(name, schema, "{topic}: {per_topic:?}");
        n
    };
    assert!(count("/pose", "foxglove.PoseInFrame") > 1000);
    assert!(count("/tf", "foxglove.FrameTransform") > 1000);
    assert!(count("/scan/utm", "foxglove.LaserScan") > 200);
    assert!(count("/scan/ust", "foxglove.LaserScan") > 200);
    assert!(count("/planes", "foxglove.SceneUpdate") >= 70);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `integrity-check --report`: the histograms of the test statistic with and without a fault,
/// and the detection curves, each a parsed SVG holding its series.
#[test]
fn the_integrity_check_report_draws_both_histograms_and_the_detection_curves() {
    use ladar_odometer::integrity_check::{integrity_check, IntegrityCheckArgs};
    let report = integrity_check(&IntegrityCheckArgs {
        runs: 40,
        ..IntegrityCheckArgs::default()
    })
    .unwrap();
    assert_eq!(report.statistics.fault_free.len(), 40);
    assert_eq!(report.statistics.biased.len(), 40);
    // A plane moved by 0.1 m pushes the statistic up: the histograms differ where it matters.
    let median = |values: &[f64]| {
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        sorted[sorted.len() / 2]
    };
    assert!(median(&report.statistics.biased) > 3.0 * median(&report.statistics.fault_free));
    let html = ladar_odometer::report::integrity::render(&report).unwrap();
    let figures = figures(&html);
    let expected: [(&str, &[&str]); 3] = [
        (
            "statistic-histogram",
            &["fault-free", "plane moved 0.1 m", "threshold"],
        ),
        (
            "detection-translation",
            &["detected", "right plane excluded"],
        ),
        ("detection-rotation", &["detected", "right plane excluded"]),
    ];
    for (id, series) in expected {
        let (_, named, svg) = figures.iter().find(|(f, _, _)| f == id).unwrap();
        let document = roxmltree::Document::parse(svg).unwrap();
        let texts = texts(&document);
        for name in series {
            assert!(
                named.iter().any(|n| n == name) && texts.contains(name),
                "{id}: {name}"
            );
        }
    }
}

#[test]
fn report_without_out_is_one_line_naming_the_fix() {
    let options = ReplayOptions {
        recording: Path::new(env!("CARGO_MANIFEST_DIR")).join(BUNDLED_RECORDING),
        report: true,
        ..ReplayOptions::default()
    };
    let err = replay::replay(&options, |config, _| FusionEstimator::new(config))
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("--out") && !err.contains('\n'), "{err}");
}

const CHROMIUM: &str = "/usr/bin/chromium";

/// Headless Chromium, from Debian's packages (`.ci/run` installs it), draws the page: no
/// console error, and the plots' colours fill a real share of the screenshot.
#[test]
fn chromium_draws_the_report_without_errors_and_with_filled_plots() {
    if !Path::new(CHROMIUM).exists() {
        assert!(
            std::env::var_os("CI").is_none(),
            "{CHROMIUM} is missing: .ci/run installs Debian's chromium package"
        );
        eprintln!("skipped: {CHROMIUM} is not installed (apt-get install chromium)");
        return;
    }
    let dir = scratch("browser");
    report_of_bundled_recording(&dir);
    let screenshot = dir.join("report.png");
    let profile = dir.join("profile");
    let output = Command::new(CHROMIUM)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            "--enable-logging=stderr",
            "--v=0",
            "--window-size=1100,6000",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("--screenshot={}", screenshot.display()))
        .arg(format!("file://{}", dir.join("report.html").display()))
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "chromium failed: {log}");
    let console: Vec<&str> = log.lines().filter(|l| l.contains("CONSOLE")).collect();
    assert!(console.is_empty(), "console messages: {console:?}");
    let (width, height, pixels) = decode_png(&screenshot);
    assert_eq!((width, height), (1100, 6000));
    // The blue of the first axis's errors and estimates, and the orange and green of the others.
    for (name, colour) in [
        ("blue", [31, 119, 180]),
        ("orange", [255, 127, 14]),
        ("green", [44, 160, 44]),
    ] {
        let share = pixels
            .chunks_exact(3)
            .filter(|px| px.iter().zip(colour).all(|(a, b)| a.abs_diff(b) < 40))
            .count() as f64
            / f64::from(width * height);
        assert!(
            share > 2e-4,
            "{name} covers {share} of the screenshot: empty plots?"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// RGB pixels of a PNG.
fn decode_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buffer = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buffer).unwrap();
    let channels = info.color_type.samples();
    let rgb = buffer[..info.buffer_size()]
        .chunks_exact(channels)
        .flat_map(|px| [px[0], px[1], px[2]])
        .collect();
    (info.width, info.height, rgb)
}
