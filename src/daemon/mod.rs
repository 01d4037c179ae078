//! The task layer: tokio, serial ports, sockets, files and clocks.
//!
//! The modules here are the daemon's edges, each testable on its own: the configuration file,
//! the MAVLink messages and the link that carries them, recordings, and the output files.

pub mod config;
pub mod link;
pub mod mavlink_out;
pub mod mavlink_task;
pub mod outputs;
pub mod recorder_thread;
pub mod recording;
