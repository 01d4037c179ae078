//! The `ladar-odometer` command line: thin, everything it does lives in `daemon`.

use clap::{CommandFactory, Parser, Subcommand, ValueEnum};
use ladar_odometer::daemon::fusion_estimator::FusionEstimator;
use ladar_odometer::daemon::replay::{self, ReplayOptions};
use ladar_odometer::daemon::run::{self, RunOptions};
use ladar_odometer::daemon::serve;
use ladar_odometer::odometry::OdometryMethod;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use tokio_util::sync::CancellationToken;

#[derive(Parser)]
#[command(
    version,
    about = "LADAR/IMU odometry for small UAVs flying without GNSS"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// `[odometry] method`, as `replay --method` names it.
#[derive(Clone, Copy, ValueEnum)]
enum Method {
    Pairs,
    Map,
}

impl From<Method> for OdometryMethod {
    fn from(method: Method) -> Self {
        match method {
            Method::Pairs => OdometryMethod::Pairs,
            Method::Map => OdometryMethod::Map,
        }
    }
}

#[derive(Subcommand)]
enum Command {
    /// Run the daemon on the sensors of a configuration file.
    Run {
        /// The configuration (config/default.toml documents every key).
        #[arg(long, value_name = "FILE")]
        config: PathBuf,
        /// Record every sensor byte to this MCAP file (overrides [recording] path).
        #[arg(long, value_name = "FILE.mcap")]
        record: Option<PathBuf>,
        /// Write trajectory.tum, epochs.jsonl and mavlink.tlog here (overrides [output] dir).
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
    /// Replay a recording (MCAP, or a raw dump of one port) through the same pipeline.
    Replay {
        /// Defaults to the bundled data/hallway-hover.mcap.
        recording: Option<PathBuf>,
        /// Replay with this configuration instead of the recorded one; a ROS recording needs
        /// one whose [[scanner]] and [imu] tables name their topics (docs/ros-data.md).
        #[arg(long, value_name = "FILE")]
        config: Option<PathBuf>,
        /// Write trajectory.tum, epochs.jsonl and mavlink.tlog here.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Pace the replay at the recorded times.
        #[arg(long)]
        realtime: bool,
        /// Send the MAVLink stream too, e.g. udpout:127.0.0.1:14550.
        #[arg(long, value_name = "ADDR")]
        mavlink: Option<String>,
        /// Keep what is complete in a truncated or damaged recording.
        #[arg(long)]
        tolerant: bool,
        /// Start the fusion this many seconds into the recording, as a daemon started then
        /// would (a start in motion); the summary then compares body-frame velocities only.
        #[arg(long, value_name = "S", default_value_t = 0.0)]
        start: f64,
        /// Replay only this many seconds from the start.
        #[arg(long, value_name = "S")]
        duration: Option<f64>,
        /// Also draw report.html into the --out directory: errors against truth inside their
        /// bounds, integrity tests, planes, epoch outcomes, a top view, what the autopilot saw.
        #[arg(long, requires = "out")]
        report: bool,
        /// Measure the motion by this odometer instead of the configured one ([odometry]
        /// method): the paper's scan-to-scan pairs, or the plane map.
        #[arg(long, value_enum, value_name = "METHOD")]
        method: Option<Method>,
    },
    /// Simulate a scenario (built-in name or TOML file) into a recording, each sensor behind its
    /// driver's emulator exactly as a live run records it, with /truth.
    Simulate {
        /// A built-in scenario (paper-sim, office-door, hallway-hover, hallway-flight,
        /// bare-corridor, board-corridor, open-room, hall-walk, random-room-N or
        /// random-corridor-N: a room or a corridor drawn from seed N) or a scenario file like
        /// those in data/scenarios.
        #[arg(long, value_name = "NAME|FILE")]
        scenario: String,
        /// The recording to write.
        #[arg(long, value_name = "FILE.mcap")]
        out: PathBuf,
    },
    /// Monte Carlo study of the integrity monitor on a scenario or your own rig's scenario file:
    /// predicted vs measured sigma per plane, false-alarm rate, detection rate against bias
    /// size, minimum detectable biases. This is how to choose thresholds for a mount.
    IntegrityCheck {
        /// A built-in scenario or a scenario file (your rig's scanners and room).
        #[arg(long, value_name = "NAME|FILE", default_value = "paper-sim")]
        scenario: String,
        /// Monte Carlo runs: more runs, narrower intervals, longer wait.
        #[arg(long, default_value_t = 1000)]
        runs: usize,
        /// Seed of the first run; the same seed gives the same tables.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Print JSON instead of tables.
        #[arg(long)]
        json: bool,
        /// Configured false-alarm probability (integrity.false_alarm_probability).
        #[arg(long, value_name = "P")]
        false_alarm_probability: Option<f64>,
        /// Configured missed-detection probability (integrity.missed_detection_probability).
        #[arg(long, value_name = "P")]
        missed_detection_probability: Option<f64>,
        /// Also draw the study as one HTML page: the test statistic with and without a fault
        /// (paper Figs. 6 and 7), detection rate against bias size, the planes' noise figures.
        #[arg(long, value_name = "FILE.html")]
        report: Option<PathBuf>,
    },
    /// Serve emulated sensors (SCIP and Xbus on ptys, SCIP on TCP where the configuration says
    /// tcp:) in real time, so that `run` can be exercised with no hardware.
    ServeEmulators {
        /// The sensors of this configuration, standing still in a box room.
        #[arg(
            long,
            conflicts_with = "scenario",
            required_unless_present = "scenario"
        )]
        config: Option<PathBuf>,
        /// Or a scenario's rig flying through its scene (built-in name or TOML file).
        #[arg(long, value_name = "NAME|FILE")]
        scenario: Option<String>,
        /// With --scenario: serve the scanners on TCP, the first at this port (e.g. 10940).
        #[arg(long, value_name = "PORT", requires = "scenario")]
        tcp_port: Option<u16>,
        /// Host to listen on with --tcp-port.
        #[arg(long, default_value = "127.0.0.1", requires = "tcp_port")]
        tcp_host: String,
        /// With --scenario: begin this many seconds into it, as if the emulators had been
        /// serving that long (a daemon started in flight).
        #[arg(long, value_name = "S", default_value_t = 0.0, requires = "scenario")]
        start: f64,
        /// Write a configuration pointing at the emulators, for `run --config`.
        #[arg(long, value_name = "FILE")]
        write_config: Option<PathBuf>,
    },
    /// Print the shell completion script for SHELL, e.g.
    /// `ladar-odometer completions bash > /etc/bash_completion.d/ladar-odometer`.
    Completions {
        /// The shell to complete in.
        shell: clap_complete::Shell,
    },
    /// Write the man pages, ladar-odometer(1) and one per command, into DIR, e.g.
    /// /usr/local/share/man/man1.
    Manpage {
        /// The directory for the pages, created if missing.
        dir: PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    init_tracing();
    let outcome = match cli.command {
        Command::Run {
            config,
            record,
            out,
        } => run_daemon(RunOptions {
            config,
            record,
            out,
        }),
        Command::Replay {
            recording,
            config,
            out,
            realtime,
            mavlink,
            tolerant,
            start,
            duration,
            report,
            method,
        } => replay_recording(
            recording,
            config,
            out,
            ReplayWindow {
                realtime,
                start,
                duration,
            },
            mavlink,
            tolerant,
            (report, method.map(OdometryMethod::from)),
        ),
        Command::Simulate { scenario, out } => simulate(&scenario, &out),
        Command::IntegrityCheck {
            scenario,
            runs,
            seed,
            json,
            false_alarm_probability,
            missed_detection_probability,
            report,
        } => integrity_check(
            scenario,
            runs,
            seed,
            json,
            false_alarm_probability,
            missed_detection_probability,
            report,
        ),
        Command::ServeEmulators {
            config,
            scenario,
            tcp_port,
            tcp_host,
            start,
            write_config,
        } => serve_emulators(
            config,
            scenario.map(|name| (name, start)),
            tcp_port.map(|p| (tcp_host, p)),
            write_config,
        ),
        Command::Completions { shell } => completions(shell),
        Command::Manpage { dir } => write_man_pages(&dir).map(|pages| {
            for page in pages {
                println!("{}", page.display());
            }
        }),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("ladar-odometer: {message}");
            ExitCode::FAILURE
        }
    }
}

/// The script is built in memory first: a closed stdout is then an error, not a panic.
fn completions(shell: clap_complete::Shell) -> Result<(), String> {
    use std::io::Write;
    let mut script = Vec::new();
    clap_complete::generate(shell, &mut Cli::command(), "ladar-odometer", &mut script);
    std::io::stdout()
        .write_all(&script)
        .map_err(|e| format!("cannot write the {shell} completions to stdout: {e}"))
}

/// Writes ladar-odometer.1 and ladar-odometer-COMMAND.1 into `dir`; returns their paths.
fn write_man_pages(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let failed = |e: std::io::Error| {
        format!(
            "cannot write the man pages into {}: {e} (give a writable directory, or run with sudo)",
            dir.display()
        )
    };
    std::fs::create_dir_all(dir).map_err(failed)?;
    let command = Cli::command();
    let mut pages = vec![dir.join("ladar-odometer.1")];
    pages.extend(
        command
            .get_subcommands()
            .map(|sub| dir.join(format!("ladar-odometer-{}.1", sub.get_name()))),
    );
    clap_mangen::generate_to(command, dir).map_err(failed)?;
    Ok(pages)
}

/// Journald-friendly: no colours unless on a terminal, level from RUST_LOG (default info).
fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr)
        .init();
}

fn runtime() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the async runtime: {e}"))
}

/// Cancels `token` on SIGINT or SIGTERM.
async fn cancel_on_signal(token: CancellationToken) {
    use tokio::signal::unix::{signal, SignalKind};
    let Ok(mut term) = signal(SignalKind::terminate()) else {
        return;
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term.recv() => {}
    }
    token.cancel();
}

fn run_daemon(options: RunOptions) -> Result<(), String> {
    runtime()?.block_on(async {
        let cancel = CancellationToken::new();
        tokio::spawn(cancel_on_signal(cancel.clone()));
        let report = run::run(
            options,
            |config, _| FusionEstimator::new(Some(config)),
            cancel,
        )
        .await
        .map_err(|e| e.to_string())?;
        tracing::info!(
            chunks = report.chunks,
            dropped = report.dropped_chunks,
            unrecorded = report.unrecorded_chunks,
            "stopped"
        );
        tracing::info!("epochs: {}", report.outcomes);
        for latency in [report.fused_latency, report.latency].into_iter().flatten() {
            tracing::info!("{latency}");
        }
        if report.mavlink_dropped > 0 {
            tracing::warn!(dropped = report.mavlink_dropped, "MAVLink messages dropped");
        }
        Ok(())
    })
}

/// When and how fast a replay runs.
struct ReplayWindow {
    realtime: bool,
    start: f64,
    duration: Option<f64>,
}

fn replay_recording(
    recording: Option<PathBuf>,
    config: Option<PathBuf>,
    out: Option<PathBuf>,
    window: ReplayWindow,
    mavlink: Option<String>,
    tolerant: bool,
    (report, method): (bool, Option<OdometryMethod>),
) -> Result<(), String> {
    let seconds = |value: f64, what: &str| {
        if value.is_finite() && value >= 0.0 {
            Ok(value)
        } else {
            Err(format!(
                "replay --{what} {value} is invalid: give a number of seconds, 0 or more"
            ))
        }
    };
    let options = ReplayOptions {
        recording: replay::resolve_recording(recording).map_err(|e| e.to_string())?,
        config,
        out,
        realtime: window.realtime,
        mavlink,
        tolerant,
        // A bar redrawn between log lines garbles both: who asks for logs gets them plain.
        progress: std::env::var_os("RUST_LOG").is_none(),
        start_s: seconds(window.start, "start")?,
        duration_s: window
            .duration
            .map(|d| seconds(d, "duration"))
            .transpose()?,
        report,
    };
    let (summary, _) = replay::replay(&options, |config, _| {
        let mut config = config.cloned();
        if let (Some(config), Some(method)) = (&mut config, method) {
            config.odometry.method = method;
        }
        FusionEstimator::new(config.as_ref())
    })
    .map_err(|e| e.to_string())?;
    print!("{summary}");
    Ok(())
}

fn simulate(scenario: &str, out: &std::path::Path) -> Result<(), String> {
    let summary =
        ladar_odometer::daemon::simulate::simulate(scenario, out).map_err(|e| e.to_string())?;
    println!(
        "simulated {:.1} s into {}: {} scans, {} IMU samples, {} truth samples, {} chunks",
        summary.duration_s,
        out.display(),
        summary.scans,
        summary.imu_samples,
        summary.truth_samples,
        summary.chunks
    );
    Ok(())
}

fn integrity_check(
    scenario: String,
    runs: usize,
    seed: u64,
    json: bool,
    false_alarm_probability: Option<f64>,
    missed_detection_probability: Option<f64>,
    report_path: Option<PathBuf>,
) -> Result<(), String> {
    use ladar_odometer::integrity_check::{
        integrity_check_with_progress, pairs_to_run, IntegrityCheckArgs,
    };
    let mut args = IntegrityCheckArgs {
        scenario,
        runs,
        seed,
        json,
        ..IntegrityCheckArgs::default()
    };
    if let Some(p) = false_alarm_probability {
        args.integrity.false_alarm_probability = p;
    }
    if let Some(p) = missed_detection_probability {
        args.integrity.missed_detection_probability = p;
    }
    args.integrity.validate().map_err(|e| e.to_string())?;
    // The default draw target is stderr and draws nothing unless it is a terminal.
    let bar = indicatif::ProgressBar::new(pairs_to_run(&args) as u64);
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{bar:40} {pos}/{len} simulated pairs {elapsed_precise} eta {eta}",
    ) {
        bar.set_style(style);
    }
    let report = integrity_check_with_progress(&args, &mut |done, _| bar.set_position(done as u64))
        .map_err(|e| e.to_string())?;
    bar.finish_and_clear();
    println!("{}", report.render(json));
    if let Some(path) = report_path {
        let html = ladar_odometer::report::integrity::render(&report).map_err(|e| e.to_string())?;
        std::fs::write(&path, html).map_err(|e| {
            format!(
                "cannot write {}: {e} (choose a writable --report path)",
                path.display()
            )
        })?;
    }
    Ok(())
}

fn serve_emulators(
    config: Option<PathBuf>,
    scenario: Option<(String, f64)>,
    scanner_tcp: Option<(String, u16)>,
    write_config: Option<PathBuf>,
) -> Result<(), String> {
    let source = match (&config, &scenario) {
        (Some(path), _) => serve::Source::Config(path),
        (None, Some((_, start))) if !(start.is_finite() && *start >= 0.0) => {
            return Err(format!(
                "serve-emulators --start {start} is invalid: give a number of seconds, 0 or more"
            ))
        }
        (None, Some((name, start_s))) => serve::Source::Scenario {
            name,
            start_s: *start_s,
            scanner_tcp: scanner_tcp
                .as_ref()
                .map(|(host, port)| (host.as_str(), *port)),
        },
        (None, None) => return Err("give --config FILE or --scenario NAME".into()),
    };
    runtime()?.block_on(async {
        let cancel = CancellationToken::new();
        tokio::spawn(cancel_on_signal(cancel.clone()));
        serve::serve_until_cancelled(source, write_config.as_deref(), cancel)
            .await
            .map_err(|e| e.to_string())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn subcommands() -> Vec<String> {
        Cli::command()
            .get_subcommands()
            .map(|sub| sub.get_name().to_string())
            .collect()
    }

    #[test]
    fn every_option_and_argument_has_help() {
        let command = Cli::command();
        for sub in command.get_subcommands() {
            assert!(sub.get_about().is_some(), "{} has no help", sub.get_name());
            for arg in sub.get_arguments() {
                let id = arg.get_id().as_str();
                if id == "help" {
                    continue;
                }
                assert!(
                    arg.get_help().is_some(),
                    "{} {id} has no --help text",
                    sub.get_name()
                );
            }
        }
    }

    #[test]
    fn completions_know_every_command() {
        for shell in [clap_complete::Shell::Bash, clap_complete::Shell::Zsh] {
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "ladar-odometer", &mut script);
            let script = String::from_utf8(script).unwrap();
            for name in subcommands() {
                assert!(script.contains(&name), "{shell}: no {name}");
            }
            assert!(script.contains("--tolerant"), "{shell}");
        }
    }

    #[test]
    fn man_pages_cover_every_command_and_its_options() {
        let dir = std::env::temp_dir().join(format!("ladar-man-{}", std::process::id()));
        let pages = write_man_pages(&dir).unwrap();
        assert_eq!(pages.len(), 1 + subcommands().len());
        let main = std::fs::read_to_string(&pages[0]).unwrap();
        assert!(main.starts_with(".ie") || main.contains(".TH"), "{main}");
        // roff escapes every hyphen.
        let roff = |text: &str| text.replace('-', "\\-");
        for name in subcommands() {
            assert!(
                main.contains(&roff(&name)),
                "ladar-odometer.1 lists no {name}"
            );
            let page = dir.join(format!("ladar-odometer-{name}.1"));
            assert!(page.exists(), "{}", page.display());
        }
        let replay = std::fs::read_to_string(dir.join("ladar-odometer-replay.1")).unwrap();
        assert!(replay.contains("tolerant"), "{replay}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
