//! Calibration: raw PSD counts to floor metres.
//!
//! The camera model is the simulator's and the rig's: `raw = distort(H · [x, y, 1])`, with
//! `H` a homography from floor metres to PSD counts and radial distortion
//! `r_d = r (1 + k1 (r / half)²)` about the PSD's centre. The gateway inverts it: undistort
//! (fixed-point iteration), then `H⁻¹`. `H` comes from the config, or is fitted by least
//! squares (normalised DLT, nalgebra SVD) from reference points measured on the rig.

use crate::Point;
use nalgebra::{DMatrix, Matrix3, Vector3};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    #[error("calibration needs at least 4 reference points, has {0}")]
    TooFewPoints(usize),
    #[error("reference points are degenerate (collinear or repeated): no homography fits them")]
    Degenerate,
    #[error("homography is singular or not finite")]
    Singular,
    #[error(
        "reference points are badly conditioned: a count of noise would move the fitted mapping by {noise_gain:.1} \
         counts within the square they span (limit {MAX_NOISE_GAIN}): spread them over the whole arena, corners and \
         centre included, not along a line"
    )]
    IllConditioned { noise_gain: f64 },
    #[error("the fit did not converge (RMS {rms_counts:.1} counts): are the floor coordinates in metres, and each in its place?")]
    NoConvergence { rms_counts: f64 },
}

/// Points needed to fit the homography and the distortion together (9 unknowns, 2
/// equations a point, and one point to spare).
pub const MIN_POINTS_WITH_DISTORTION: usize = 6;
/// The largest noise gain accepted (see [`Fit::noise_gain`]): a grid has about 0.5; points
/// near a line have tens to thousands.
pub const MAX_NOISE_GAIN: f64 = 3.0;

/// A calibration fitted to reference points, with how well it fits.
#[derive(Debug, Clone)]
pub struct Fit {
    pub calibration: Calibration,
    /// Floor metres -> undistorted counts, row-major, `h[2][2] = 1`.
    pub homography: [[f64; 3]; 3],
    pub k1: f64,
    /// Each point's floor error: where the fitted calibration puts its measured reading,
    /// minus where it is, m.
    pub residuals: Vec<[f64; 2]>,
    /// RMS of the floor errors, m.
    pub rms_m: f64,
    /// RMS reprojection error, counts.
    pub rms_counts: f64,
    /// How far a count of noise in the readings moves the fitted mapping, at worst over the
    /// square the points span (counts per count).
    pub noise_gain: f64,
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
    pub fn from_homography(h: [[f64; 3]; 3], k1: f64, counts: u16) -> Result<Self, CalibrationError> {
        let h = Matrix3::from_fn(|r, c| h[r][c]);
        let h_inv = h.try_inverse().filter(|m| m.iter().all(|v| v.is_finite())).ok_or(CalibrationError::Singular)?;
        Ok(Self { h, h_inv, k1, half_scale: f64::from(counts) / 2.0 })
    }

    /// Fit the homography to `(raw counts, floor metres)` pairs by least squares. Returns the
    /// calibration and the RMS reprojection error in counts.
    pub fn fit(points: &[([f64; 2], [f64; 2])], k1: f64, counts: u16) -> Result<(Self, f64), CalibrationError> {
        if points.len() < 4 {
            return Err(CalibrationError::TooFewPoints(points.len()));
        }
        let half = f64::from(counts) / 2.0;
        // Undistort the raw points first, then fit floor -> undistorted counts.
        let probe = Self { h: Matrix3::identity(), h_inv: Matrix3::identity(), k1, half_scale: half };
        let pairs: Vec<([f64; 2], [f64; 2])> =
            points.iter().map(|(raw, floor)| (*floor, probe.undistort(*raw))).collect();
        let h = dlt(&pairs).ok_or(CalibrationError::Degenerate)?;
        let h_arr =
            [[h[(0, 0)], h[(0, 1)], h[(0, 2)]], [h[(1, 0)], h[(1, 1)], h[(1, 2)]], [h[(2, 0)], h[(2, 1)], h[(2, 2)]]];
        let cal = Self::from_homography(h_arr, k1, counts).map_err(|_| CalibrationError::Degenerate)?;
        let sq: f64 = points
            .iter()
            .map(|(raw, floor)| {
                let p = cal.to_raw(Point::new(floor[0], floor[1])).unwrap_or((f64::INFINITY, 0.0));
                (p.0 - raw[0]).powi(2) + (p.1 - raw[1]).powi(2)
            })
            .sum();
        Ok((cal, (sq / points.len() as f64).sqrt()))
    }

    /// Fit the homography and the radial distortion `k1` together to `(raw counts, floor
    /// metres)` pairs: the linear fit (normalised DLT, `k1 = 0`) as a start, then
    /// Levenberg-Marquardt on the reprojection error in counts. Refuses too few points, a
    /// degenerate set, and a badly conditioned one.
    pub fn fit_with_distortion(points: &[([f64; 2], [f64; 2])], counts: u16) -> Result<Fit, CalibrationError> {
        if points.len() < MIN_POINTS_WITH_DISTORTION {
            return Err(CalibrationError::TooFewPoints(points.len()));
        }
        if points.iter().any(|(r, f)| !(r.iter().chain(f).all(|v| v.is_finite()))) {
            return Err(CalibrationError::Degenerate);
        }
        let half = f64::from(counts) / 2.0;
        let pairs: Vec<([f64; 2], [f64; 2])> = points.iter().map(|(raw, floor)| (*floor, *raw)).collect();
        let h0 = dlt(&pairs).ok_or(CalibrationError::Degenerate)?;
        // Parameters: h00..h21 (h22 = 1) and k1.
        let mut p = nalgebra::SVector::<f64, 9>::zeros();
        for i in 0..8 {
            p[i] = h0[(i / 3, i % 3)];
        }
        let residuals = |p: &nalgebra::SVector<f64, 9>| -> nalgebra::DVector<f64> {
            let mut r = nalgebra::DVector::zeros(2 * points.len());
            for (i, (raw, floor)) in points.iter().enumerate() {
                let [u, v] = project(p, *floor, half);
                r[2 * i] = u - raw[0];
                r[2 * i + 1] = v - raw[1];
            }
            r
        };
        let jacobian = |p: &nalgebra::SVector<f64, 9>| -> DMatrix<f64> {
            let mut j = DMatrix::zeros(2 * points.len(), 9);
            for c in 0..9 {
                let step = 1e-7 * p[c].abs().max(if c == 8 { 1e-3 } else { 1e-6 });
                let (mut hi, mut lo) = (*p, *p);
                hi[c] += step;
                lo[c] -= step;
                let d = (residuals(&hi) - residuals(&lo)) / (2.0 * step);
                j.set_column(c, &d);
            }
            j
        };
        let (p, cost) = levenberg_marquardt(p, &residuals, &jacobian);
        let rms_counts = (cost / points.len() as f64).sqrt();
        let noise_gain = noise_gain(&p, &jacobian(&p), span(points), half);
        if !noise_gain.is_finite() || noise_gain > MAX_NOISE_GAIN {
            return Err(CalibrationError::IllConditioned { noise_gain });
        }
        // A fit a count of noise cannot explain: wrong units or points swapped.
        if rms_counts.is_nan() || rms_counts >= half / 20.0 {
            return Err(CalibrationError::NoConvergence { rms_counts });
        }
        let h = [[p[0], p[1], p[2]], [p[3], p[4], p[5]], [p[6], p[7], 1.0]];
        let calibration = Self::from_homography(h, p[8], counts).map_err(|_| CalibrationError::Degenerate)?;
        let residuals: Vec<[f64; 2]> = points
            .iter()
            .map(|(raw, floor)| {
                calibration.to_floor(raw[0], raw[1]).map_or([f64::INFINITY; 2], |q| [q.re - floor[0], q.im - floor[1]])
            })
            .collect();
        let rms_m = (residuals.iter().map(|r| r[0] * r[0] + r[1] * r[1]).sum::<f64>() / points.len() as f64).sqrt();
        Ok(Fit { calibration, homography: h, k1: p[8], residuals, rms_m, rms_counts, noise_gain })
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

    /// An axis-aligned rectangle of floor the PSD sees, `[x_min, x_max, y_min, y_max]` (m):
    /// inside the quadrilateral the corners of its counts span (its sides straight without
    /// lens distortion, bowed a little with it). `None` if a corner maps to no floor point.
    pub fn inner_rect(&self) -> Option<[f64; 4]> {
        let h = self.half_scale;
        let c = |x: f64, y: f64| self.to_floor(x, y);
        let (a, b, cc, d) = (c(-h, -h)?, c(h, -h)?, c(h, h)?, c(-h, h)?);
        let xs = [a.re, b.re, cc.re, d.re];
        let ys = [a.im, b.im, cc.im, d.im];
        // The two smallest x are the left side's corners: the rectangle starts at the larger.
        let mut sx = xs;
        sx.sort_by(f64::total_cmp);
        let mut sy = ys;
        sy.sort_by(f64::total_cmp);
        let rect = [sx[1], sx[2], sy[1], sy[2]];
        (rect[0] < rect[1] && rect[2] < rect[3]).then_some(rect)
    }

    /// The floor the PSD sees, in words for an error message: the floor points at the
    /// corners of its counts (the calibrated arena is the quadrilateral they span, its
    /// sides bowed by the lens distortion).
    pub fn view_extent(&self) -> String {
        let h = self.half_scale;
        let corners: Vec<String> = [(-h, -h), (h, -h), (h, h), (-h, h)]
            .iter()
            .map(|&(x, y)| match self.to_floor(x, y) {
                Some(p) => format!("({:.3}, {:.3})", p.re, p.im),
                None => "(beyond the horizon)".into(),
            })
            .collect();
        format!("the PSD sees the floor within the corners {} m", corners.join(", "))
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

type Params = nalgebra::SVector<f64, 9>;

/// Levenberg-Marquardt from `p`: at most 200 steps, each trying up to 20 dampings, until a
/// step no longer improves the cost. The parameters and their squared residual.
fn levenberg_marquardt(
    mut p: Params,
    residuals: &dyn Fn(&Params) -> nalgebra::DVector<f64>,
    jacobian: &dyn Fn(&Params) -> DMatrix<f64>,
) -> (Params, f64) {
    let mut r = residuals(&p);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    for _ in 0..200 {
        let j = jacobian(&p);
        let jtj = j.transpose() * &j;
        let g = j.transpose() * &r;
        let mut improved = false;
        for _ in 0..20 {
            let mut a = jtj.clone();
            for d in 0..9 {
                a[(d, d)] += lambda * jtj[(d, d)].max(1e-12);
            }
            let Some(step) = a.lu().solve(&(-&g)) else { break };
            let candidate = p + nalgebra::SVector::<f64, 9>::from_iterator(step.iter().copied());
            let rc = residuals(&candidate);
            let c = rc.norm_squared();
            if c.is_finite() && c < cost {
                let gain = cost - c;
                (p, r, cost) = (candidate, rc, c);
                lambda = (lambda / 3.0).max(1e-12);
                improved = gain > 1e-12 * cost.max(1e-12);
                break;
            }
            lambda *= 4.0;
        }
        if !improved {
            break;
        }
    }
    (p, cost)
}

/// How much one count of noise on each reading moves the fitted model's prediction, at
/// worst over the square the floor points span (about their centre, side their larger
/// extent): the parameters' covariance `(JᵀJ)⁻¹` carried to an 11x11 grid over it. Points
/// along a line leave the square's far side unpinned: a large gain.
fn noise_gain(p: &nalgebra::SVector<f64, 9>, j: &DMatrix<f64>, square: ([f64; 2], f64), half: f64) -> f64 {
    let Some(cov) = (j.transpose() * j).try_inverse() else { return f64::INFINITY };
    let cov = nalgebra::SMatrix::<f64, 9, 9>::from_iterator(cov.iter().copied());
    let (centre, side) = square;
    let mut worst: f64 = 0.0;
    for i in 0..11 {
        for k in 0..11 {
            let q = [centre[0] + side * (f64::from(i) / 10.0 - 0.5), centre[1] + side * (f64::from(k) / 10.0 - 0.5)];
            let mut jq = nalgebra::SMatrix::<f64, 2, 9>::zeros();
            for c in 0..9 {
                let step = 1e-7 * p[c].abs().max(if c == 8 { 1e-3 } else { 1e-6 });
                let (mut a, mut b) = (*p, *p);
                a[c] += step;
                b[c] -= step;
                let (pa, pb) = (project(&a, q, half), project(&b, q, half));
                jq[(0, c)] = (pa[0] - pb[0]) / (2.0 * step);
                jq[(1, c)] = (pa[1] - pb[1]) / (2.0 * step);
            }
            let var = jq * cov * jq.transpose();
            worst = worst.max(var[(0, 0)].max(var[(1, 1)]));
        }
    }
    if worst.is_finite() {
        worst.sqrt()
    } else {
        f64::INFINITY
    }
}

/// The square the floor points span: its centre and side (their larger extent).
pub fn span(points: &[([f64; 2], [f64; 2])]) -> ([f64; 2], f64) {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for (_, f) in points {
        for a in 0..2 {
            lo[a] = lo[a].min(f[a]);
            hi[a] = hi[a].max(f[a]);
        }
    }
    ([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0], (hi[0] - lo[0]).max(hi[1] - lo[1]))
}

/// The forward model with parameters `p` (h00..h21, k1): floor metres to distorted counts.
fn project(p: &nalgebra::SVector<f64, 9>, floor: [f64; 2], half: f64) -> [f64; 2] {
    let (x, y) = (floor[0], floor[1]);
    let w = p[6] * x + p[7] * y + 1.0;
    let u = (p[0] * x + p[1] * y + p[2]) / w;
    let v = (p[3] * x + p[4] * y + p[5]) / w;
    let d = 1.0 + p[8] * (u * u + v * v) / (half * half);
    [u * d, v * d]
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
    use flowgate_sim::camera::CameraModel;

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

    /// Readings of `floor` points through `cam`, with seeded noise of `sigma` counts.
    fn measured(cam: &CameraModel, floor: &[Point], sigma: f64, seed: u64) -> Vec<([f64; 2], [f64; 2])> {
        let mut state = seed;
        let mut noise = move || {
            // A small LCG and Box-Muller: enough noise for a test, no dependency.
            let mut uniform = || {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (a, b) = (uniform(), uniform());
            sigma * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        floor
            .iter()
            .map(|p| {
                let (x, y) = cam.project(*p).unwrap();
                ([x + noise(), y + noise()], [p.re, p.im])
            })
            .collect()
    }

    /// The floor error of `cal` against the true camera, RMS over a dense grid, m.
    fn floor_rms(cal: &Calibration, cam: &CameraModel, half_width: f64) -> f64 {
        let n = 21;
        let mut sq = 0.0;
        for i in 0..n {
            for j in 0..n {
                let p = Point::new(
                    -half_width + 2.0 * half_width * f64::from(i) / f64::from(n - 1),
                    -half_width + 2.0 * half_width * f64::from(j) / f64::from(n - 1),
                );
                let (x, y) = cam.project(p).unwrap();
                sq += (cal.to_floor(x, y).unwrap() - p).norm_sqr();
            }
        }
        (sq / f64::from(n * n)).sqrt()
    }

    /// Homography and distortion together, from a 5x5 grid read with a count of noise:
    /// the floor is recovered to a fraction of a millimetre, and `k1` to its first digits.
    #[test]
    fn fits_homography_and_distortion() {
        let cam = CameraModel { k1: 0.03, ..CameraModel::default() };
        let grid: Vec<Point> =
            (-2..=2).flat_map(|i| (-2..=2).map(move |j| Point::new(0.3 * f64::from(i), 0.3 * f64::from(j)))).collect();
        let fit = Calibration::fit_with_distortion(&measured(&cam, &grid, 1.0, 7), 4096).unwrap();
        assert!((fit.k1 - 0.03).abs() < 0.003, "k1 {}", fit.k1);
        assert!(fit.rms_counts < 1.5, "{} counts", fit.rms_counts);
        let truth = floor_rms(&fit.calibration, &cam, 0.6);
        assert!(truth < 3e-4, "{truth} m RMS over the arena");
        assert!(fit.rms_m < 1e-3 && fit.residuals.len() == 25);
        assert!(fit.noise_gain < 1.0, "a grid is well conditioned: {}", fit.noise_gain);
    }

    #[test]
    fn refuses_a_badly_conditioned_set() {
        let cam = CameraModel { k1: 0.03, ..CameraModel::default() };
        // Nearly on one line: 1 mm off it.
        let line: Vec<Point> =
            (0..8).map(|i| Point::new(0.1 * f64::from(i) - 0.35, 0.001 * f64::from(i % 2))).collect();
        match Calibration::fit_with_distortion(&measured(&cam, &line, 0.5, 3), 4096) {
            Err(CalibrationError::IllConditioned { noise_gain }) => {
                assert!(noise_gain > 100.0 * MAX_NOISE_GAIN, "{noise_gain}")
            }
            other => panic!("{other:?}"),
        }
        let few: Vec<Point> = (0..5).map(|i| Point::new(0.1 * f64::from(i), 0.07 * f64::from(i * i))).collect();
        assert_eq!(
            Calibration::fit_with_distortion(&measured(&cam, &few, 0.5, 3), 4096).unwrap_err(),
            CalibrationError::TooFewPoints(5)
        );
        // Floor points in centimetres, not metres: no camera explains them.
        let grid: Vec<Point> =
            (-1..=1).flat_map(|i| (-1..=1).map(move |j| Point::new(0.3 * f64::from(i), 0.3 * f64::from(j)))).collect();
        let mut cm = measured(&cam, &grid, 0.5, 3);
        cm[4].1 = [cm[4].1[0] * 100.0 + 0.5, cm[4].1[1] * 100.0 + 0.5];
        assert!(Calibration::fit_with_distortion(&cm, 4096).is_err());
    }

    #[test]
    fn refuses_what_cannot_calibrate() {
        assert_eq!(
            Calibration::fit(&[([0.0, 0.0], [0.0, 0.0]); 3], 0.0, 4096).unwrap_err(),
            CalibrationError::TooFewPoints(3)
        );
        let line: Vec<_> = (0..6).map(|i| ([f64::from(i), 0.0], [f64::from(i) * 0.1, 0.0])).collect();
        assert_eq!(Calibration::fit(&line, 0.0, 4096).unwrap_err(), CalibrationError::Degenerate);
        assert_eq!(Calibration::from_homography([[0.0; 3]; 3], 0.0, 4096).unwrap_err(), CalibrationError::Singular);
    }
}
