//! How the PSD camera sees the floor: a homography from floor metres to the PSD's image
//! plane, radial lens distortion, and the conversion to raw counts. The simulator maps
//! floor -> raw; the gateway fits and applies the inverse.

use crate::Point;
use serde::Deserialize;

/// The camera model. `raw = distort(H · [x, y, 1])`, in PSD counts about the centre.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraModel {
    /// Row-major 3x3 homography from floor metres to undistorted counts.
    pub homography: [[f64; 3]; 3],
    /// Radial distortion `k1`: `r_d = r (1 + k1 (r / half_scale)²)`; 0 = none.
    #[serde(default)]
    pub k1: f64,
    /// Full-scale counts of the PSD on each axis; positions beyond ±counts/2 are out of view.
    #[serde(default = "default_counts")]
    pub counts: u16,
}

fn default_counts() -> u16 {
    4096
}

impl Default for CameraModel {
    /// A camera about 2400 counts per metre, a little rotated and tilted, no distortion:
    /// the floor within about ±0.8 m is in view (the paper's workspace is about ±0.4 m).
    fn default() -> Self {
        Self {
            homography: [[2400.0, 70.0, 10.0], [-60.0, 2480.0, -12.0], [0.012, -0.006, 1.0]],
            k1: 0.0,
            counts: default_counts(),
        }
    }
}

impl CameraModel {
    /// Raw PSD position (counts, not yet quantised) of a floor point; `None` when the point
    /// is behind the camera's plane (the homography's w <= 0).
    pub fn project(&self, p: Point) -> Option<(f64, f64)> {
        let h = &self.homography;
        let w = h[2][0] * p.re + h[2][1] * p.im + h[2][2];
        if w <= 1e-9 {
            return None;
        }
        let u = (h[0][0] * p.re + h[0][1] * p.im + h[0][2]) / w;
        let v = (h[1][0] * p.re + h[1][1] * p.im + h[1][2]) / w;
        let half = f64::from(self.counts) / 2.0;
        let r2 = (u * u + v * v) / (half * half);
        let d = 1.0 + self.k1 * r2;
        Some((u * d, v * d))
    }

    /// Whether a raw position lies on the PSD.
    pub fn in_view(&self, raw: (f64, f64)) -> bool {
        let half = f64::from(self.counts) / 2.0;
        raw.0.abs() < half && raw.1.abs() < half
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_like_homography_scales() {
        let cam = CameraModel {
            homography: [[4000.0, 0.0, 0.0], [0.0, 4000.0, 0.0], [0.0, 0.0, 1.0]],
            k1: 0.0,
            counts: 4096,
        };
        assert_eq!(cam.project(Point::new(0.1, -0.2)), Some((400.0, -800.0)));
        assert!(cam.in_view((400.0, -800.0)));
        assert!(!cam.in_view((2100.0, 0.0)));
    }

    #[test]
    fn distortion_pushes_points_outward() {
        let mut cam = CameraModel::default();
        let plain = cam.project(Point::new(0.3, 0.2)).unwrap();
        cam.k1 = 0.05;
        let bent = cam.project(Point::new(0.3, 0.2)).unwrap();
        assert!(bent.0.abs() > plain.0.abs() && bent.1.abs() > plain.1.abs());
    }
}
