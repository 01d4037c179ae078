//! The lines of an epoch as the plane map measures with them (docs/design.md, 4.11): each
//! line's centroid and direction in the body frame at the epoch's reference time, the one way
//! its noise moves it, and how its beams' times spread about that time, which tells how far a
//! velocity error deskewed it.

use nalgebra::Vector3;

use super::deskew::Beam;
use super::lines::Segment;
use crate::filter::MapLine;

/// One scan's lines with what placing them needs: its beams, its ranging sigma and the normal
/// of its scan plane in the body frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ScanOfLines<'a> {
    pub segments: &'a [Segment],
    pub beams: &'a [Beam],
    pub range_sigma_m: f64,
    pub scan_normal: Vector3<f64>,
}

impl ScanOfLines<'_> {
    /// Line `segment` as the map measures with it, at reference time `t_ref`.
    pub(crate) fn map_line(&self, segment: usize, t_ref: f64) -> MapLine {
        let line = &self.segments[segment];
        let beams = &self.beams[line.first..line.end];
        let n = beams.len() as f64;
        let mean_time = beams.iter().map(|b| b.time).sum::<f64>() / n;
        let (moment, spread) = beams.iter().fold((0.0, 0.0), |(m, s), beam| {
            let along = (beam.body - line.centroid).dot(&line.direction);
            (m + along * (beam.time - mean_time), s + along * along)
        });
        MapLine {
            centroid: line.centroid,
            direction: line.direction,
            length_m: line.length,
            across: self.scan_normal.cross(&line.direction).normalize(),
            centroid_sigma_m: self.range_sigma_m / n.sqrt(),
            direction_sigma_rad: self.range_sigma_m / line.abscissa_spread.max(f64::EPSILON).sqrt(),
            time_offset_s: mean_time - t_ref,
            time_slope_s_per_m: if spread > 0.0 { moment / spread } else { 0.0 },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::odometry::lines::{LineExtractor, LineParameters};
    use nalgebra::Vector2;

    #[test]
    fn a_line_carries_its_noise_square_to_it_and_its_beams_timing() {
        // A wall 2 m ahead seen by a level scanner sweeping from right to left over 10 ms.
        let beams: Vec<Beam> = (0..41)
            .map(|k| {
                let y = 1.0 - 0.05 * f64::from(k);
                let body = Vector3::new(2.0, y, 0.0);
                Beam {
                    planar: Vector2::new(2.0, y),
                    body,
                    direction: body.normalize(),
                    azimuth: y.atan2(2.0),
                    range: body.norm(),
                    time: 10.0 + 0.00025 * f64::from(k),
                }
            })
            .collect();
        let mut segments = Vec::new();
        let parameters = LineParameters {
            breakpoint_lambda_rad: 0.17,
            breakpoint_noise_m: 0.03,
            split_distance_m: 0.05,
            min_points: 10,
            min_length_m: 0.3,
        };
        LineExtractor::default().extract(&beams, &parameters, &mut segments);
        assert_eq!(segments.len(), 1);
        let scan = ScanOfLines {
            segments: &segments,
            beams: &beams,
            range_sigma_m: 0.01,
            scan_normal: Vector3::z(),
        };
        let line = scan.map_line(0, 10.004);
        assert!(
            line.across.cross(&Vector3::x()).norm() < 1e-9,
            "{}",
            line.across
        );
        assert!((line.centroid_sigma_m - 0.01 / 41f64.sqrt()).abs() < 1e-12);
        assert!((line.time_offset_s - 0.001).abs() < 1e-9);
        // 0.25 ms per 5 cm, the line running the way the sweep does or against it.
        assert!((line.time_slope_s_per_m.abs() - 0.005).abs() < 1e-9);
        let sign = -line.direction.y.signum();
        assert!((line.time_slope_s_per_m - sign * 0.005).abs() < 1e-9);
    }
}
