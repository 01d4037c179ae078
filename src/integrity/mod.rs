//! Parity-space fault detection and exclusion with protection levels (sections 3.3 to 3.5).
