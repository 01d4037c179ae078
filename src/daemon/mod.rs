//! The task layer: tokio, serial ports, sockets, files and clocks.
//!
//! The modules here are the daemon's edges, each testable on its own: the configuration file,
//! the MAVLink messages, the link that carries them and the task that sends them, recordings and
//! the thread that writes them, the output files, and the systemd watchdog; then the sensor
//! tasks, the chunk queue and the fusion loop's pipeline that `run` and `replay` share, and the
//! emulated sensors `serve-emulators` offers.

pub mod chunk_queue;
pub mod config;
pub mod foxglove;
mod foxglove_schemas;
pub mod fusion_estimator;
pub mod health;
pub mod in_process;
pub mod latency;
pub mod link;
pub mod mavlink_out;
pub mod mavlink_task;
pub mod outcomes;
pub mod outputs;
pub mod pipeline;
pub mod readings;
pub mod recorder_thread;
pub mod recording;
pub mod replay;
pub mod run;
pub mod sensor_task;
pub mod serve;
pub mod simulate;
pub mod sink;
pub mod truth;
pub mod watchdog;
