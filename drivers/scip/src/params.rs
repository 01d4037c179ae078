//! Typed VV and PP replies.

use std::fmt;

use crate::decoder::InfoLines;

/// PP reply: the scanner geometry. The daemon converts it to its own geometry type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Parameters {
    /// `MODL`: model name.
    pub model: String,
    /// `DMIN`/`DMAX`: valid distance range, mm.
    pub min_distance_mm: u32,
    pub max_distance_mm: u32,
    /// `ARES`: steps per full revolution.
    pub angular_resolution: u32,
    /// `AMIN`/`AMAX`: first and last measurable step.
    pub first_step: u16,
    pub last_step: u16,
    /// `AFRT`: step pointing straight ahead.
    pub front_step: u16,
    /// `SCAN`: motor speed, rpm.
    pub scan_rpm: u32,
}

/// A PP reply missing a key or holding a non-numeric value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParameterError {
    pub key: &'static str,
}

impl fmt::Display for ParameterError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "SCIP PP reply lacks a valid {} value: check the sensor firmware speaks SCIP 2.0",
            self.key
        )
    }
}

impl std::error::Error for ParameterError {}

fn number<T: std::str::FromStr>(
    info: &InfoLines<'_>,
    key: &'static str,
) -> Result<T, ParameterError> {
    info.get(key)
        .and_then(|v| v.trim().parse().ok())
        .ok_or(ParameterError { key })
}

impl Parameters {
    pub fn from_info(info: &InfoLines<'_>) -> Result<Self, ParameterError> {
        let params = Parameters {
            model: info
                .get("MODL")
                .ok_or(ParameterError { key: "MODL" })?
                .to_owned(),
            min_distance_mm: number(info, "DMIN")?,
            max_distance_mm: number(info, "DMAX")?,
            angular_resolution: number(info, "ARES")?,
            first_step: number(info, "AMIN")?,
            last_step: number(info, "AMAX")?,
            front_step: number(info, "AFRT")?,
            scan_rpm: number(info, "SCAN")?,
        };
        if params.angular_resolution == 0 {
            return Err(ParameterError { key: "ARES" });
        }
        if params.scan_rpm == 0 {
            return Err(ParameterError { key: "SCAN" });
        }
        if params.last_step < params.first_step {
            return Err(ParameterError { key: "AMAX" });
        }
        Ok(params)
    }

    /// Angle of `step`, radians, counter-clockwise from the front seen from above.
    pub fn step_angle(&self, step: u16) -> f64 {
        (f64::from(step) - f64::from(self.front_step)) * std::f64::consts::TAU
            / f64::from(self.angular_resolution)
    }

    /// Seconds per revolution.
    pub fn scan_period(&self) -> f64 {
        60.0 / f64::from(self.scan_rpm)
    }

    /// Seconds between adjacent steps.
    pub fn step_period(&self) -> f64 {
        self.scan_period() / f64::from(self.angular_resolution)
    }
}

/// VV reply.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Version {
    pub vendor: String,
    pub product: String,
    pub firmware: String,
    pub protocol: String,
    pub serial: String,
}

impl Version {
    pub fn from_info(info: &InfoLines<'_>) -> Self {
        let get = |key| info.get(key).unwrap_or_default().to_owned();
        Version {
            vendor: get("VEND"),
            product: get("PROD"),
            firmware: get("FIRM"),
            protocol: get("PROT"),
            serial: get("SERI"),
        }
    }
}
