//! Hokuyo SCIP 2.0, sans-IO: bytes in, replies out. (Filled by the drivers issue.)
