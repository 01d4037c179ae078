//! The task layer: tokio, serial ports, sockets, files and clocks.
