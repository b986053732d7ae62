//! One axis of a PCL-80K-like pulse generator: it ramps its pulse rate toward the
//! commanded target at a set acceleration, never beyond its rate limit, and counts the
//! pulses it emits.

/// An axis's ramp and limit, in pulses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisConfig {
    /// pulses/s².
    pub accel: f64,
    /// pulses/s.
    pub max_rate: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axis {
    config: AxisConfig,
    target: f64,
    rate: f64,
    /// Pulses emitted, fractional part kept so that no pulse is lost between steps.
    position: f64,
}

impl Axis {
    pub fn new(config: AxisConfig) -> Self {
        Self { config, target: 0.0, rate: 0.0, position: 0.0 }
    }
    pub fn config(&self) -> AxisConfig {
        self.config
    }
    pub fn set_config(&mut self, config: AxisConfig) {
        self.config = config;
        self.target = self.target.clamp(-config.max_rate, config.max_rate);
    }
    /// Set the target rate, clamped to the rate limit. Returns whether it was clamped.
    pub fn set_target(&mut self, rate: i32) -> bool {
        let r = f64::from(rate);
        self.target = r.clamp(-self.config.max_rate, self.config.max_rate);
        self.target != r
    }
    /// Stop at once, without a ramp.
    pub fn stop_now(&mut self) {
        self.target = 0.0;
        self.rate = 0.0;
    }
    /// The current (ramped) rate, pulses/s.
    pub fn rate(&self) -> f64 {
        self.rate
    }
    pub fn target(&self) -> f64 {
        self.target
    }
    /// Whole pulses emitted so far (the board's position counter).
    pub fn position(&self) -> i64 {
        self.position.floor() as i64
    }
    /// How long until the ramp reaches the target, s (0: there; `+inf`: no ramp set).
    pub fn ramp_left(&self) -> f64 {
        let gap = (self.target - self.rate).abs();
        if gap == 0.0 {
            0.0
        } else if self.config.accel > 0.0 {
            gap / self.config.accel
        } else {
            f64::INFINITY
        }
    }
    /// The rate `dt` from now along the ramp, pulses/s (the state is left as it is).
    pub fn rate_after(&self, dt: f64) -> f64 {
        let dt = dt.max(0.0);
        if dt >= self.ramp_left() {
            return self.target;
        }
        let change = self.config.accel * dt;
        self.rate + (self.target - self.rate).clamp(-change, change)
    }
    /// Advance by `dt`; returns the pulses emitted (fractional). Exact: the rate moves
    /// linearly at the ramp's acceleration until it reaches the target, then holds.
    pub fn step(&mut self, dt: f64) -> f64 {
        // `rate_after` spelled out with the ramp's end taken once: a step that reaches it
        // ends on the target, one that does not ends where the ramp has got to.
        let left = self.ramp_left();
        let (ramp, reached) = if dt >= left {
            (left, self.target)
        } else {
            let change = self.config.accel * dt;
            (dt, self.rate + (self.target - self.rate).clamp(-change, change))
        };
        let pulses = 0.5 * (self.rate + reached) * ramp + reached * (dt - ramp);
        self.rate = reached;
        self.position += pulses;
        pulses
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramps_to_target_and_counts_pulses() {
        let mut a = Axis::new(AxisConfig { accel: 1000.0, max_rate: 5000.0 });
        assert!(!a.set_target(1000));
        let mut pulses = 0.0;
        for _ in 0..2000 {
            pulses += a.step(1e-3);
        }
        assert_eq!(a.rate(), 1000.0);
        // 1 s ramp (500 pulses) then 1 s at 1000/s.
        assert!((pulses - 1500.0).abs() < 1e-6, "{pulses}");
        assert_eq!(a.position(), 1500);
        // The same in one step, and a ramp that ends inside a step: exact either way.
        let mut b = Axis::new(AxisConfig { accel: 1000.0, max_rate: 5000.0 });
        b.set_target(1000);
        assert!((b.step(2.0) - 1500.0).abs() < 1e-9);
        b.set_target(0);
        assert!((b.step(0.25) - (0.5 * (1000.0 + 750.0) * 0.25)).abs() < 1e-9);
        assert!((b.step(1.0) - 0.5 * 750.0 * 0.75).abs() < 1e-9, "ramps down to rest in 0.75 s");
        assert_eq!(b.rate(), 0.0);
        assert!(a.set_target(-9000));
        assert_eq!(a.target(), -5000.0);
        a.stop_now();
        assert_eq!(a.rate(), 0.0);
    }
}
