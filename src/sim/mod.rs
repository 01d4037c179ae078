//! Ray-cast scanners, IMU and moving scene with ground truth.
