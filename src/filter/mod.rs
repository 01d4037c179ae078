//! Strapdown mechanisation and the error-state EKF (section 4.3, DESIGN.md 4.9).
