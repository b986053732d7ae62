//! Calibration: raw PSD counts to floor metres.
//!
//! The camera model is the simulator's and the rig's: `raw = distort(H · [x, y, 1])`, with
//! `H` a homography from floor metres to PSD counts and radial distortion
//! `r_d = r (1 + k1 (r / half)²)` about the PSD's centre. The gateway inverts it: undistort
//! (fixed-point iteration), then `H⁻¹`. `H` comes from the config, or is fitted by least
//! squares (normalised DLT, nalgebra SVD) from reference points measured on the rig.

use nalgebra::{DMatrix, Matrix3, Vector3};
use num_complex::Complex64 as Point;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibError {
    #[error("calibration needs at least 4 reference points, has {0}")]
    TooFewPoints(usize),
    #[error("reference points are degenerate (collinear or repeated): no homography fits them")]
    Degenerate,
    #[error("homography is singular or not finite")]
    Singular,
}

/// The mapping from raw PSD counts to the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Floor -> undistorted counts.
    h: Matrix3<f64>,
    /// Undistorted counts -> floor.
    h_inv: Matrix3<f64>,
    k1: f64,
    half_scale: f64,
}

impl Calibration {
    /// From a homography (floor metres -> counts, row-major), distortion `k1` and the PSD's
    /// full-scale counts.
    pub fn from_homography(h: [[f64; 3]; 3], k1: f64, counts: u16) -> Result<Self, CalibError> {
        let h = Matrix3::from_fn(|r, c| h[r][c]);
        let h_inv = h.try_inverse().filter(|m| m.iter().all(|v| v.is_finite())).ok_or(CalibError::Singular)?;
        Ok(Self { h, h_inv, k1, half_scale: f64::from(counts) / 2.0 })
    }

    /// Fit the homography to `(raw counts, floor metres)` pairs by least squares. Returns the
    /// calibration and the RMS reprojection error in counts.
    pub fn fit(points: &[([f64; 2], [f64; 2])], k1: f64, counts: u16) -> Result<(Self, f64), CalibError> {
        if points.len() < 4 {
            return Err(CalibError::TooFewPoints(points.len()));
        }
        let half = f64::from(counts) / 2.0;
        // Undistort the raw points first, then fit floor -> undistorted counts.
        let probe = Self { h: Matrix3::identity(), h_inv: Matrix3::identity(), k1, half_scale: half };
        let pairs: Vec<([f64; 2], [f64; 2])> =
            points.iter().map(|(raw, floor)| (*floor, probe.undistort(*raw))).collect();
        let h = dlt(&pairs).ok_or(CalibError::Degenerate)?;
        let h_arr =
            [[h[(0, 0)], h[(0, 1)], h[(0, 2)]], [h[(1, 0)], h[(1, 1)], h[(1, 2)]], [h[(2, 0)], h[(2, 1)], h[(2, 2)]]];
        let cal = Self::from_homography(h_arr, k1, counts).map_err(|_| CalibError::Degenerate)?;
        let sq: f64 = points
            .iter()
            .map(|(raw, floor)| {
                let p = cal.to_raw(Point::new(floor[0], floor[1])).unwrap_or((f64::INFINITY, 0.0));
                (p.0 - raw[0]).powi(2) + (p.1 - raw[1]).powi(2)
            })
            .sum();
        Ok((cal, (sq / points.len() as f64).sqrt()))
    }

    fn undistort(&self, raw: [f64; 2]) -> [f64; 2] {
        if self.k1 == 0.0 {
            return raw;
        }
        // r_d = r_u (1 + k1 r_u²/half²): iterate r_u = r_d / (1 + k1 r_u²/half²).
        let (mut u, mut v) = (raw[0], raw[1]);
        for _ in 0..8 {
            let d = 1.0 + self.k1 * (u * u + v * v) / (self.half_scale * self.half_scale);
            (u, v) = (raw[0] / d, raw[1] / d);
        }
        [u, v]
    }

    /// Floor position of a raw PSD reading; `None` if it maps to infinity.
    pub fn to_floor(&self, raw_x: f64, raw_y: f64) -> Option<Point> {
        let [u, v] = self.undistort([raw_x, raw_y]);
        let p = self.h_inv * Vector3::new(u, v, 1.0);
        (p.z.abs() > 1e-12).then(|| Point::new(p.x / p.z, p.y / p.z)).filter(|p| p.re.is_finite() && p.im.is_finite())
    }

    /// Whether the PSD sees a floor point: its reading lies within the sensor's counts. The
    /// calibrated arena is this set.
    pub fn in_view(&self, floor: Point) -> bool {
        self.to_raw(floor).is_some_and(|(x, y)| x.abs() < self.half_scale && y.abs() < self.half_scale)
    }

    /// Raw reading (distorted counts) of a floor point: the forward model.
    pub fn to_raw(&self, floor: Point) -> Option<(f64, f64)> {
        let p = self.h * Vector3::new(floor.re, floor.im, 1.0);
        if p.z.abs() < 1e-12 {
            return None;
        }
        let (u, v) = (p.x / p.z, p.y / p.z);
        let d = 1.0 + self.k1 * (u * u + v * v) / (self.half_scale * self.half_scale);
        Some((u * d, v * d))
    }
}

/// Normalised direct linear transform: the homography taking `from` to `to` in each pair.
fn dlt(pairs: &[([f64; 2], [f64; 2])]) -> Option<Matrix3<f64>> {
    let normaliser = |pts: &mut dyn Iterator<Item = [f64; 2]>| -> Matrix3<f64> {
        let pts: Vec<[f64; 2]> = pts.collect();
        let n = pts.len() as f64;
        let (cx, cy) = pts.iter().fold((0.0, 0.0), |(x, y), p| (x + p[0] / n, y + p[1] / n));
        let mean_d = pts.iter().map(|p| ((p[0] - cx).powi(2) + (p[1] - cy).powi(2)).sqrt()).sum::<f64>() / n;
        let s = if mean_d > 0.0 { std::f64::consts::SQRT_2 / mean_d } else { 1.0 };
        Matrix3::new(s, 0.0, -s * cx, 0.0, s, -s * cy, 0.0, 0.0, 1.0)
    };
    let t_from = normaliser(&mut pairs.iter().map(|p| p.0));
    let t_to = normaliser(&mut pairs.iter().map(|p| p.1));
    let mut a = DMatrix::<f64>::zeros(2 * pairs.len().max(5), 9);
    for (i, (f, t)) in pairs.iter().enumerate() {
        let f = t_from * Vector3::new(f[0], f[1], 1.0);
        let t = t_to * Vector3::new(t[0], t[1], 1.0);
        let (x, y, u, v) = (f.x, f.y, t.x, t.y);
        let r0 = [-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u];
        let r1 = [0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v];
        for c in 0..9 {
            a[(2 * i, c)] = r0[c];
            a[(2 * i + 1, c)] = r1[c];
        }
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    // The smallest singular value's vector; a second zero one means the points are degenerate.
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]));
    let (smallest, next) = (svd.singular_values[order[0]], svd.singular_values[order[1]]);
    if next < 1e-9 * svd.singular_values.max() || !(smallest.is_finite()) {
        return None;
    }
    let h = v_t.row(order[0]);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let h = t_to.try_inverse()? * hn * t_from;
    (h[(2, 2)].abs() > 1e-15).then(|| h / h[(2, 2)])
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowgate_sim::calibration::CameraModel;

    fn grid() -> Vec<Point> {
        (-2..=2).flat_map(|i| (-2..=2).map(move |j| Point::new(0.15 * f64::from(i), 0.12 * f64::from(j)))).collect()
    }

    /// The gateway's inverse undoes the simulator's camera model, distortion included.
    #[test]
    fn inverts_the_camera_model() {
        for k1 in [0.0, 0.04] {
            let cam = CameraModel { k1, ..CameraModel::default() };
            let cal = Calibration::from_homography(cam.homography, k1, cam.counts).unwrap();
            for p in grid() {
                let (x, y) = cam.project(p).unwrap();
                let back = cal.to_floor(x, y).unwrap();
                assert!((back - p).norm() < 1e-9, "k1 {k1}: {p} -> {back}");
            }
        }
    }

    /// Least squares from measured points (rounded to whole counts, as the PSD reports)
    /// recovers the mapping to well under a millimetre.
    #[test]
    fn fits_reference_points() {
        let cam = CameraModel { k1: 0.02, ..CameraModel::default() };
        let points: Vec<([f64; 2], [f64; 2])> = grid()
            .into_iter()
            .map(|p| {
                let (x, y) = cam.project(p).unwrap();
                ([x.round(), y.round()], [p.re, p.im])
            })
            .collect();
        let (cal, rms) = Calibration::fit(&points, 0.02, 4096).unwrap();
        assert!(rms < 0.5, "rms {rms} counts");
        for p in grid() {
            let (x, y) = cam.project(p).unwrap();
            assert!((cal.to_floor(x, y).unwrap() - p).norm() < 2e-4);
        }
    }

    #[test]
    fn refuses_what_cannot_calibrate() {
        assert_eq!(
            Calibration::fit(&[([0.0, 0.0], [0.0, 0.0]); 3], 0.0, 4096).unwrap_err(),
            CalibError::TooFewPoints(3)
        );
        let line: Vec<_> = (0..6).map(|i| ([f64::from(i), 0.0], [f64::from(i) * 0.1, 0.0])).collect();
        assert_eq!(Calibration::fit(&line, 0.0, 4096).unwrap_err(), CalibError::Degenerate);
        assert_eq!(Calibration::from_homography([[0.0; 3]; 3], 0.0, 4096).unwrap_err(), CalibError::Singular);
    }
}
