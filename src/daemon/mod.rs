//! The task layer: tokio, serial ports, sockets, files and clocks.
//!
//! The modules here are the daemon's edges, each testable on its own: the configuration file,
//! the MAVLink messages, the link that carries them and the task that sends them, recordings and
//! the thread that writes them, the output files, and the systemd watchdog; then the sensor
//! tasks, the chunk queue and the fusion loop's pipeline that `run` and `replay` share, and the
//! emulated sensors `serve-emulators` offers.

pub(crate) mod chunk_queue;
pub mod config;
pub(crate) mod foxglove;
mod foxglove_schemas;
pub mod fusion_estimator;
pub(crate) mod health;
pub(crate) mod in_process;
pub(crate) mod latency;
pub(crate) mod link;
pub mod mavlink_out;
pub(crate) mod mavlink_task;
pub(crate) mod outcomes;
pub(crate) mod outputs;
pub mod pipeline;
pub mod readings;
pub(crate) mod recorder_thread;
pub mod recording;
pub mod replay;
pub(crate) mod ros;
pub mod run;
pub(crate) mod sensor_task;
pub mod serve;
pub mod simulate;
pub mod sink;
pub mod truth;
pub(crate) mod watchdog;
