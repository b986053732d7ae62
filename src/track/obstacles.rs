//! Every obstacle's track: a constant-velocity Kalman filter per obstacle LED, predicted
//! to the moment a command acts, and planned on as the region it may have reached once it
//! has been unseen too long.

use super::{ConstantVelocityKf, TrackingSettings};
use crate::geometry::Length;
use crate::planner::{ObstacleEstimate, MAX_OBSTACLES};
use crate::Point;

/// The obstacles' tracks. Allocation-free after construction.
#[derive(Debug, Clone)]
pub struct ObstacleTracks {
    settings: TrackingSettings,
    radii: [f64; MAX_OBSTACLES],
    count: usize,
    filters: [Option<ConstantVelocityKf>; MAX_OBSTACLES],
    /// Each obstacle's last measured position (planned on when prediction is off).
    measured: [Point; MAX_OBSTACLES],
    /// The tracked obstacles as the planner plans on them, then room for what a caller
    /// appends after them (other vehicles).
    estimates: [ObstacleEstimate; MAX_OBSTACLES],
    /// The same obstacles, always predicted to the estimate's time.
    predicted: [ObstacleEstimate; MAX_OBSTACLES],
}

/// The obstacles at one moment, as [`ObstacleTracks::predict`] left them.
#[derive(Debug, Clone, Copy)]
pub struct Predicted<'a> {
    /// As the planner plans on them (predicted, or as last measured).
    pub obstacles: &'a [ObstacleEstimate],
    /// Predicted, whatever the planner plans on: the supervisor's.
    pub predicted: &'a [ObstacleEstimate],
    /// The smallest gap between the given position and an obstacle's footprint, m.
    pub clearance: Option<f64>,
}

impl ObstacleTracks {
    /// Tracks for obstacles of these radii (at most [`MAX_OBSTACLES`]; more are ignored,
    /// which the config refuses at load).
    pub fn new(settings: TrackingSettings, radii: &[f64]) -> Self {
        let count = radii.len().min(MAX_OBSTACLES);
        let mut r = [0.0; MAX_OBSTACLES];
        r[..count].copy_from_slice(&radii[..count]);
        let none = ObstacleEstimate::exact(Point::default(), Point::default(), 0.0);
        Self {
            settings,
            radii: r,
            count,
            filters: [None; MAX_OBSTACLES],
            measured: [Point::default(); MAX_OBSTACLES],
            estimates: [none; MAX_OBSTACLES],
            predicted: [none; MAX_OBSTACLES],
        }
    }

    /// Each tracked obstacle as the planner sees it at `t` (predicted, when prediction is
    /// on), with its position covariance; reads only, for recordings and displays.
    pub fn at(&self, t: f64) -> impl Iterator<Item = (ObstacleEstimate, [f64; 3])> + '_ {
        let predict = self.settings.predict_obstacles;
        self.filters[..self.count].iter().enumerate().filter_map(move |(k, kf)| {
            let kf = kf.as_ref()?;
            let at = if predict { t } else { kf.time() };
            if let Some(region) = self.settings.occluded_region(kf, self.radii[k], t) {
                return Some((region, kf.position_covariance(kf.time())));
            }
            let estimate = kf.estimate(self.radii[k], at);
            let center = if predict { estimate.center } else { self.measured[k] };
            Some((ObstacleEstimate { center, ..estimate }, kf.position_covariance(at)))
        })
    }

    /// Obstacle `k` seen at `p`, valid at `t_valid`. Returns whether its filter took it
    /// (an older measurement than the filter's last, or a non-finite one, is refused).
    pub fn observe(&mut self, k: usize, t_valid: f64, p: Point) -> bool {
        if k >= self.count {
            return false;
        }
        let taken = match &mut self.filters[k] {
            Some(kf) => kf.update(t_valid, p),
            None if p.re.is_finite() && p.im.is_finite() => {
                self.filters[k] = Some(ConstantVelocityKf::new(self.settings.kalman, t_valid, p));
                true
            }
            None => false,
        };
        if taken {
            self.measured[k] = p;
        }
        taken
    }

    /// Where obstacle `k` was last measured (None: never, or its track was dropped).
    pub fn last_measured(&self, k: usize) -> Option<Point> {
        self.filters.get(k)?.as_ref().map(|_| self.measured[k])
    }

    /// When obstacle `k` was last measured, s (None: never, or its track was dropped).
    pub fn time(&self, k: usize) -> Option<f64> {
        self.filters.get(k).copied().flatten().map(|kf| kf.time())
    }

    /// The obstacles with a track, in the order [`ObstacleTracks::predict`] lists them:
    /// the `n`th estimate is obstacle `tracked().nth(n)`.
    pub fn tracked(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.count).filter(|&k| self.filters[k].is_some())
    }

    /// Where obstacle `k`'s filter puts it at `t` (None: no track).
    pub fn prediction(&self, k: usize, t: f64) -> Option<Point> {
        self.filters.get(k).copied().flatten().map(|kf| kf.predict(t).0)
    }

    /// Whether obstacle `k` is tracked but unseen long enough to be planned on as a region.
    pub fn occluded(&self, k: usize, t: f64) -> bool {
        self.time(k).is_some_and(|seen| t - seen > self.settings.occluded_after)
    }

    /// Drop obstacle `k`'s track: it left the view, or an operator's reset forgot it. It is
    /// absent until seen again, when a new track starts from its first sample.
    pub fn drop_track(&mut self, k: usize) {
        if let Some(f) = self.filters.get_mut(k) {
            *f = None;
        }
    }

    /// How many obstacles it tracks (seen or not).
    pub fn count(&self) -> usize {
        self.count
    }

    /// Every tracked obstacle at `t`, predicted by its filter (or, unseen too long, the
    /// region it may have reached), and the least gap from `position` to one.
    pub fn predict(&mut self, t: f64, position: Point) -> Predicted<'_> {
        self.predict_with(t, position, [&[], &[]])
    }

    /// The same, followed by `others` (other vehicles: as the planner plans on them, as the
    /// supervisor judges them; as many of each, and with the tracked obstacles at most
    /// [`MAX_OBSTACLES`], as the rig's load checks).
    pub fn predict_with(&mut self, t: f64, position: Point, others: [&[ObstacleEstimate]; 2]) -> Predicted<'_> {
        let mut n = 0;
        let mut clearance: Option<f64> = None;
        let predict = self.settings.predict_obstacles;
        for k in 0..self.count {
            let Some(kf) = &self.filters[k] else { continue };
            if let Some(region) = self.settings.occluded_region(kf, self.radii[k], t) {
                self.predicted[n] = region;
                self.estimates[n] = region;
            } else {
                let now = kf.estimate(self.radii[k], t);
                self.predicted[n] = now;
                // Without prediction the planner takes the last measurement as it stands (the
                // paper's E3); the supervisor always judges the predicted one.
                // Its uncertainty is the predicted one either way: where the obstacle is now
                // is that uncertain, whatever centre the planner takes.
                self.estimates[n] = if predict { now } else { ObstacleEstimate { center: self.measured[k], ..now } };
            }
            n += 1;
            let gap = (self.estimates[n - 1].center - position).length() - self.estimates[n - 1].radius;
            clearance = Some(clearance.map_or(gap, |c| c.min(gap)));
        }
        let [seen, supervised] = others;
        for (o, s) in seen.iter().zip(supervised).take(MAX_OBSTACLES - n) {
            (self.estimates[n], self.predicted[n]) = (*o, *s);
            n += 1;
            let gap = (o.center - position).length() - o.radius;
            clearance = Some(clearance.map_or(gap, |c| c.min(gap)));
        }
        Predicted { obstacles: &self.estimates[..n], predicted: &self.predicted[..n], clearance }
    }
}
