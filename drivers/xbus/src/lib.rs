//! Xsens Xbus / MTData2, sans-IO: bytes in, frames out. (Filled by the drivers issue.)
