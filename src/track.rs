//! Tracking: the robot's pose from its two LEDs, and each obstacle's position and velocity
//! from a constant-velocity Kalman filter, predicted to the moment a command acts (delay
//! compensation). Time is an argument everywhere.

use crate::Point;

use crate::geometry::Length;
use crate::planner::ObstacleEstimate;

mod dead_reckoning;
mod obstacles;
mod pose;
pub use dead_reckoning::{ramp, DeadReckoning};
pub use obstacles::{ObstacleTracks, Predicted};
pub use pose::{PoseAt, PoseTrack};

/// The robot's pose: centre and heading (rad from +x, counter-clockwise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub position: Point,
    pub heading: f64,
}

/// The estimated state at the moment the command will act.
#[derive(Debug, Clone, Copy)]
pub struct Estimate<'a> {
    /// The robot's centre.
    pub position: Point,
    /// Its heading as a unit vector: what the wheel speeds and the supervisor turn by,
    /// carried from the LEDs' axis through the dead reckoning without an angle (the angle,
    /// [`Estimate::pose`], is for displays and records).
    pub facing: Point,
    /// The wheels' rim speeds now, as the ramps have brought them toward the commands, m/s:
    /// left, right.
    pub wheels: [f64; 2],
    /// The obstacles as the planner plans on them (predicted to now, or as last measured).
    pub obstacles: &'a [ObstacleEstimate],
    /// The obstacles predicted to now whatever the planner plans on: the supervisor's.
    pub predicted: &'a [ObstacleEstimate],
    /// Measured sensing-to-actuation delay, s.
    pub delay: f64,
}

impl Estimate<'_> {
    /// The robot's pose, its heading as an angle in `(-π, π]`.
    pub fn pose(&self) -> Pose {
        Pose { position: self.position, heading: self.facing.arg() }
    }
}

/// How the tracker estimates the state the command will act on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingSettings {
    pub predict_robot: bool,
    /// The wheels' acceleration ramp (the boards'), m/s²: dead reckoning follows it.
    pub wheel_accel: f64,
    pub predict_obstacles: bool,
    pub kalman: KalmanConfig,
    /// How long an obstacle may go unseen before its filter's prediction is no longer
    /// trusted and it is planned on as the region it may have reached, s.
    pub occluded_after: f64,
    /// The fastest any obstacle on the rig moves, m/s: how fast an unseen one's region grows.
    pub max_obstacle_speed: f64,
}

impl TrackingSettings {
    /// The region an obstacle last estimated by `kf` may occupy at `t`, if it has been
    /// unseen long enough to be judged so: its last estimated footprint, grown by how far it
    /// can have gone at the top obstacle speed since. A sound bound whatever it did unseen,
    /// where its filter's extrapolation is only a guess.
    fn occluded_region(&self, kf: &ConstantVelocityKf, radius: f64, t: f64) -> Option<ObstacleEstimate> {
        let unseen = t - kf.time();
        (unseen > self.occluded_after).then(|| {
            let (center, _) = kf.predict(kf.time());
            ObstacleEstimate {
                center,
                velocity: Point::default(),
                radius: radius + self.max_obstacle_speed * unseen,
                position_sd: kf.uncertainty(kf.time()).0,
                velocity_sd: 0.0,
                drift: Point::default(),
                spread: self.max_obstacle_speed,
                keep: 0.0,
            }
        })
    }
}

/// Why two LED positions cannot be the robot's pose.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Implausible {
    #[error("the robot's LEDs are {measured:.3} m apart, mounted {mounted:.3} m")]
    LedSpacing { measured: f64, mounted: f64 },
    #[error("the robot moved {moved:.3} m, it can {reach:.3} m")]
    Jump { moved: f64, reach: f64 },
    /// A reflection of one LED onto the far side of the other keeps their spacing and moves
    /// the centre by half the spacing's change, but turns the heading about.
    #[error("the robot turned {turned:.2} rad, it can {reach:.2} rad")]
    Turn { turned: f64, reach: f64 },
}

/// How long a pose refused after a stop must stand still to be taken, s: longer than a
/// reflection on the floor lasts while the robot passes it.
pub const SETTLE: f64 = 2.0;

/// What a robot pose is checked against: how far and how fast the robot can move between
/// two poses, and how far a measured pose may be off that.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseReach {
    /// The centre's top speed, m/s (the wheels' rim speed limit).
    pub speed: f64,
    /// The top turn rate, rad/s (both wheels at their limit, opposite ways).
    pub turn_rate: f64,
    /// How far each LED may be off, m.
    pub tolerance: f64,
}

/// Where the robot's LEDs sit along its heading, measured from its centre (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LedGeometry {
    /// Distance of the front LED ahead of the centre.
    pub front: f64,
    /// Distance of the rear LED behind the centre.
    pub rear: f64,
}

impl LedGeometry {
    /// The pose from the two LED positions; `None` if they coincide (no heading).
    pub fn pose(&self, front: Point, rear: Point) -> Option<Pose> {
        self.locate(front, rear).map(|(position, facing)| Pose { position, heading: facing.arg() })
    }
    /// The robot's centre from the two LED positions and its heading as a unit vector (the
    /// LEDs' axis); `None` if they coincide.
    pub fn locate(&self, front: Point, rear: Point) -> Option<(Point, Point)> {
        let axis = front - rear;
        let len = axis.length();
        if len.is_nan() || len <= 0.0 {
            return None;
        }
        Some((rear + axis * (self.rear / (self.front + self.rear)), axis / len))
    }
    /// Where the LEDs of a robot at `position` facing along the unit vector `facing` are.
    pub fn leds(&self, position: Point, facing: Point) -> (Point, Point) {
        (position + facing * self.front, position - facing * self.rear)
    }
}

/// Kalman filter settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KalmanConfig {
    /// Standard deviation of a position measurement, m.
    pub measurement_noise: f64,
    /// Spectral density of the unmodelled acceleration, m²/s³.
    pub process_noise: f64,
}

impl Default for KalmanConfig {
    fn default() -> Self {
        Self { measurement_noise: 0.003, process_noise: 0.05 }
    }
}

/// A constant-velocity Kalman filter on one point: state `[x, y, vx, vy]`.
///
/// The model, its noise and the measurements treat `x` and `y` alike and apart, and the
/// filter starts them alike, so the 4×4 covariance is the same 2×2 one (position and
/// velocity along one axis) on each axis, with nothing between the axes: it is kept as
/// that one `AxisCovariance`, and an update is a few scalar operations.
#[derive(Debug, Clone, Copy)]
pub struct ConstantVelocityKf {
    config: KalmanConfig,
    t: f64,
    position: Point,
    velocity: Point,
    /// `velocity` smoothed over [`DRIFT_TIME_CONSTANT`].
    drift: Point,
    p: AxisCovariance,
}

/// The time constant of an obstacle's drift (its velocity smoothed), s: long enough that
/// the filter's sample-to-sample wander (some cm/s at the default process noise) averages
/// out, short enough to follow a turn within a couple of seconds.
pub const DRIFT_TIME_CONSTANT: f64 = 1.0;

/// The covariance of one axis's position and velocity (m², m²/s, m²/s²), the same for
/// both axes.
#[derive(Debug, Clone, Copy, PartialEq)]
struct AxisCovariance {
    pp: f64,
    pv: f64,
    vv: f64,
}

impl AxisCovariance {
    /// Carried `dt` ahead through the constant-velocity model, with the process noise of
    /// spectral density `q` (white acceleration) over it.
    fn predicted(self, dt: f64, q: f64) -> Self {
        let Self { pp, pv, vv } = self;
        Self {
            pp: pp + dt * (2.0 * pv + dt * vv) + dt * dt * dt / 3.0 * q,
            pv: pv + dt * vv + dt * dt / 2.0 * q,
            vv: vv + dt * q,
        }
    }
}

impl ConstantVelocityKf {
    /// A filter started at a first measurement `z` taken at `t`, velocity unknown.
    pub fn new(config: KalmanConfig, t: f64, z: Point) -> Self {
        let r = config.measurement_noise.powi(2);
        Self {
            config,
            t,
            position: z,
            velocity: Point::default(),
            drift: Point::default(),
            p: AxisCovariance { pp: r, pv: 0.0, vv: 0.25 },
        }
    }

    /// Fold in a measurement `z` taken at `t` (measurements must come in time order; an
    /// older one is ignored and `false` returned).
    pub fn update(&mut self, t: f64, z: Point) -> bool {
        let dt = t - self.t;
        if dt < 0.0 || !z.re.is_finite() || !z.im.is_finite() {
            return false;
        }
        let p = self.p.predicted(dt, self.config.process_noise);
        // The innovation's variance, and the gains for position and velocity.
        let s = p.pp + self.config.measurement_noise.powi(2);
        if !(s > 0.0 && s.is_finite()) {
            return false;
        }
        let (kp, kv) = (p.pp / s, p.pv / s);
        self.position += self.velocity * dt;
        self.t = t;
        let innovation = z - self.position;
        self.position += innovation * kp;
        self.velocity += innovation * kv;
        self.drift += (self.velocity - self.drift) * (dt / DRIFT_TIME_CONSTANT).min(1.0);
        self.p = AxisCovariance { pp: (1.0 - kp) * p.pp, pv: (1.0 - kp) * p.pv, vv: p.vv - kv * p.pv };
        true
    }

    /// Position and velocity predicted to time `t` (no state change).
    pub fn predict(&self, t: f64) -> (Point, Point) {
        let dt = t - self.t;
        (self.position + self.velocity * dt, self.velocity)
    }

    /// The obstacle of this radius as this filter predicts it at `t`, with its
    /// uncertainty and drift.
    pub fn estimate(&self, radius: f64, t: f64) -> ObstacleEstimate {
        let (center, velocity) = self.predict(t);
        let (position_sd, velocity_sd) = self.uncertainty(t);
        ObstacleEstimate {
            center,
            velocity,
            radius,
            position_sd,
            velocity_sd,
            drift: self.drift,
            spread: 0.0,
            keep: 0.0,
        }
    }

    /// The velocity smoothed over [`DRIFT_TIME_CONSTANT`], m/s.
    pub fn drift(&self) -> Point {
        self.drift
    }

    /// Time of the last measurement.
    pub fn time(&self) -> f64 {
        self.t
    }

    /// The position's covariance `[xx, xy, yy]` (m²) predicted to `t`: how far the planner
    /// may trust the predicted centre.
    pub fn position_covariance(&self, t: f64) -> [f64; 3] {
        let pp = self.covariance_at(t).pp;
        [pp, 0.0, pp]
    }

    /// One standard deviation of the position (m) and of the velocity (m/s) predicted to
    /// `t` (the same along every direction).
    pub fn uncertainty(&self, t: f64) -> (f64, f64) {
        let p = self.covariance_at(t);
        (p.pp.max(0.0).sqrt(), p.vv.max(0.0).sqrt())
    }

    fn covariance_at(&self, t: f64) -> AxisCovariance {
        self.p.predicted((t - self.t).max(0.0), self.config.process_noise)
    }
}

/// Everything tracking knows of the robot and the obstacles: the robot's [`PoseTrack`] and
/// the [`ObstacleTracks`]. Measurements go in with their time of validity;
/// [`Tracker::estimate`] gives the state at the moment a command will act. Used by the
/// gateway core and by the offline runner alike. Allocation-free after construction.
#[derive(Debug, Clone)]
pub struct Tracker {
    pose: PoseTrack,
    obstacles: ObstacleTracks,
}

/// The state a command will act on, with the time its pose was measured.
#[derive(Debug, Clone, Copy)]
pub struct Tracked<'a> {
    pub estimate: Estimate<'a>,
    /// When the pose it starts from was valid, s.
    pub pose_valid_at: f64,
    /// The smallest estimated gap between the robot's centre and an obstacle's footprint, m.
    pub clearance: Option<f64>,
}

impl Tracker {
    /// A tracker for the robot's LEDs and obstacles of these radii (at most
    /// [`MAX_OBSTACLES`](crate::planner::MAX_OBSTACLES); more are ignored, which the config
    /// refuses at load).
    pub fn new(settings: TrackingSettings, geometry: LedGeometry, radii: &[f64]) -> Self {
        Self { pose: PoseTrack::new(settings, geometry), obstacles: ObstacleTracks::new(settings, radii) }
    }

    /// The robot's pose track.
    pub fn pose(&self) -> &PoseTrack {
        &self.pose
    }
    pub fn pose_mut(&mut self) -> &mut PoseTrack {
        &mut self.pose
    }
    /// The obstacles' tracks.
    pub fn obstacles(&self) -> &ObstacleTracks {
        &self.obstacles
    }
    pub fn obstacles_mut(&mut self) -> &mut ObstacleTracks {
        &mut self.obstacles
    }

    /// Each tracked obstacle as the planner sees it at `t` ([`ObstacleTracks::at`]).
    pub fn obstacles_at(&self, t: f64) -> impl Iterator<Item = (ObstacleEstimate, [f64; 3])> + '_ {
        self.obstacles.at(t)
    }

    /// The robot's two LEDs, valid at `t_valid` ([`PoseTrack::observe`]).
    pub fn observe_robot(&mut self, t_valid: f64, front: Point, rear: Point) -> bool {
        self.pose.observe(t_valid, front, rear)
    }

    /// Whether the robot's two LEDs at `t_valid` can be its pose ([`PoseTrack::plausible`]).
    pub fn plausible(&mut self, t_valid: f64, front: Point, rear: Point, reach: PoseReach) -> Result<(), Implausible> {
        self.pose.plausible(t_valid, front, rear, reach)
    }

    /// Obstacle `k` seen at `p`, valid at `t_valid` ([`ObstacleTracks::observe`]).
    pub fn observe_obstacle(&mut self, k: usize, t_valid: f64, p: Point) -> bool {
        self.obstacles.observe(k, t_valid, p)
    }

    /// Where obstacle `k` was last measured (None: never, or its track was dropped).
    pub fn last_measured(&self, k: usize) -> Option<Point> {
        self.obstacles.last_measured(k)
    }

    /// When obstacle `k` was last measured, s (None: never, or its track was dropped).
    pub fn obstacle_time(&self, k: usize) -> Option<f64> {
        self.obstacles.time(k)
    }

    /// The obstacles with a track, in the order [`Tracker::estimate`] lists them.
    pub fn tracked(&self) -> impl Iterator<Item = usize> + '_ {
        self.obstacles.tracked()
    }

    /// Where obstacle `k`'s filter puts it at `t` (None: no track).
    pub fn obstacle_prediction(&self, k: usize, t: f64) -> Option<Point> {
        self.obstacles.prediction(k, t)
    }

    /// Whether obstacle `k` is tracked but unseen long enough to be planned on as a region.
    pub fn obstacle_occluded(&self, k: usize, t: f64) -> bool {
        self.obstacles.occluded(k, t)
    }

    /// Drop obstacle `k`'s track ([`ObstacleTracks::drop_track`]).
    pub fn drop_obstacle(&mut self, k: usize) {
        self.obstacles.drop_track(k);
    }

    /// How many obstacles it tracks (seen or not).
    pub fn obstacle_count(&self) -> usize {
        self.obstacles.count()
    }

    /// When the robot's last pose was valid, s.
    pub fn pose_time(&self) -> Option<f64> {
        self.pose.time()
    }

    /// Forget the robot's pose (after a stop, so a stale one is never driven on).
    pub fn forget_pose(&mut self) {
        self.pose.forget();
    }

    /// The robot's wheels were stopped at once (an emergency stop).
    pub fn halted(&mut self, t: f64) {
        self.pose.halted(t);
    }

    /// The robot was commanded these wheel speeds at `t` (for dead reckoning).
    pub fn commanded(&mut self, t: f64, left: f64, right: f64) {
        self.pose.commanded(t, left, right);
    }

    /// The state at `t`, when the command will act: the pose dead-reckoned from its time of
    /// validity, the obstacles predicted by their filters, and the sensing-to-actuation delay
    /// (age of the pose plus the period the command holds). `None` before any pose.
    pub fn estimate(&mut self, t: f64, sample_time: f64, wheel_base: f64) -> Option<Tracked<'_>> {
        estimate(&mut self.pose, &mut self.obstacles, [&[], &[]], t, sample_time, wheel_base)
    }
}

/// The state at `t` of the vehicle `pose` tracks among `obstacles` and `others` (other
/// vehicles, [`ObstacleTracks::predict_with`]), when its command will act
/// ([`Tracker::estimate`]).
pub fn estimate<'o>(
    pose: &mut PoseTrack,
    obstacles: &'o mut ObstacleTracks,
    others: [&[ObstacleEstimate]; 2],
    t: f64,
    sample_time: f64,
    wheel_base: f64,
) -> Option<Tracked<'o>> {
    let at = pose.at(t, sample_time, wheel_base)?;
    let seen = obstacles.predict_with(t, at.position, others);
    Some(Tracked {
        estimate: Estimate {
            position: at.position,
            facing: at.facing,
            wheels: at.wheels,
            obstacles: seen.obstacles,
            predicted: seen.predicted,
            delay: t - at.valid_at + sample_time,
        },
        pose_valid_at: at.valid_at,
        clearance: seen.clearance,
    })
}

/// A first-order low-pass filter on a point (cut-off `hz`; 0 passes through).
#[derive(Debug, Clone, Copy)]
pub struct LowPass {
    hz: f64,
    state: Option<Point>,
}

impl LowPass {
    pub fn new(hz: f64) -> Self {
        Self { hz, state: None }
    }
    /// Filter `x` after `dt` seconds.
    pub fn filter(&mut self, x: Point, dt: f64) -> Point {
        if self.hz <= 0.0 {
            return x;
        }
        let alpha = 1.0 - (-std::f64::consts::TAU * self.hz * dt).exp();
        let y = match self.state {
            Some(y) => y + (x - y) * alpha,
            None => x,
        };
        self.state = Some(y);
        y
    }
}

#[cfg(test)]
mod tests;
