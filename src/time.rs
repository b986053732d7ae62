//! Two clocks, two types: the host's monotonic clock ([`HostTime`]) and the PSD
//! controller's clock ([`CtrlTime`]). They are never mixed by accident: a controller stamp
//! becomes host time only through a [`ClockOffset`] measured by time sync.
//!
//! Host time is whole nanoseconds since the gateway started; arithmetic saturates, so no
//! stamp from the wire can overflow a computation.

use core::time::Duration;

/// A moment on the host's monotonic clock: nanoseconds since the gateway started (on the
/// rig), or since the simulation started (virtual time).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct HostTime(u64);

impl HostTime {
    pub const ZERO: Self = Self(0);
    /// The end of time: a deadline that never comes.
    pub const NEVER: Self = Self(u64::MAX);

    pub const fn from_nanos(ns: u64) -> Self {
        Self(ns)
    }
    /// From seconds; negative and NaN clamp to zero, huge values to [`HostTime::NEVER`].
    pub fn from_secs_f64(s: f64) -> Self {
        Self((s * 1e9).clamp(0.0, u64::MAX as f64) as u64)
    }
    pub const fn as_nanos(self) -> u64 {
        self.0
    }
    /// Seconds, for the planner and the world (which work in `f64` seconds).
    pub fn secs(self) -> f64 {
        self.0 as f64 * 1e-9
    }
    /// Time since `earlier` (zero if `earlier` is later).
    pub fn since(self, earlier: HostTime) -> Duration {
        Duration::from_nanos(self.0.saturating_sub(earlier.0))
    }
}

impl core::ops::Add<Duration> for HostTime {
    type Output = HostTime;
    fn add(self, d: Duration) -> HostTime {
        HostTime(self.0.saturating_add(u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)))
    }
}

impl core::ops::Sub<Duration> for HostTime {
    type Output = HostTime;
    fn sub(self, d: Duration) -> HostTime {
        HostTime(self.0.saturating_sub(u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)))
    }
}

impl core::fmt::Display for HostTime {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{:.6} s", self.secs())
    }
}

/// A stamp on the PSD controller's clock, µs (as the wire carries it).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct CtrlTime(pub u64);

impl CtrlTime {
    /// The midpoint of two stamps, without overflow.
    pub fn midpoint(self, other: CtrlTime) -> CtrlTime {
        CtrlTime(self.0 / 2 + other.0 / 2 + (self.0 % 2 + other.0 % 2) / 2)
    }
}

/// Host time minus controller time, ns, as measured by one time-sync round trip.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClockOffset(i128);

impl ClockOffset {
    /// From a round trip: the request left at `sent`, the reply (stamped `ctrl` by the
    /// controller on receipt) came back at `received`. The controller's stamp is taken to
    /// be the midpoint of the round trip.
    pub fn from_round_trip(sent: HostTime, ctrl: CtrlTime, received: HostTime) -> Self {
        let mid = (i128::from(sent.0) + i128::from(received.0)) / 2;
        Self(mid - i128::from(ctrl.0) * 1000)
    }

    /// Host time minus controller time, ns.
    pub fn as_nanos(self) -> i128 {
        self.0
    }

    /// A controller stamp as host time (clamped to the host clock's range).
    pub fn to_host(self, t: CtrlTime) -> HostTime {
        let ns = i128::from(t.0) * 1000 + self.0;
        HostTime(ns.clamp(0, i128::from(u64::MAX)) as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arithmetic_saturates() {
        assert_eq!(HostTime::NEVER + Duration::from_secs(1), HostTime::NEVER);
        assert_eq!(HostTime::ZERO - Duration::from_secs(1), HostTime::ZERO);
        assert_eq!(HostTime::from_nanos(5).since(HostTime::from_nanos(9)), Duration::ZERO);
        assert_eq!(HostTime::from_secs_f64(f64::NAN), HostTime::ZERO);
        assert_eq!(CtrlTime(u64::MAX).midpoint(CtrlTime(u64::MAX)), CtrlTime(u64::MAX));
        assert_eq!(CtrlTime(3).midpoint(CtrlTime(5)), CtrlTime(4));
    }

    #[test]
    fn round_trip_offset_maps_the_controller_clock() {
        // Controller clock = host clock + 1 s; a 2 ms round trip, stamped at its middle.
        let sent = HostTime::from_nanos(10_000_000);
        let received = HostTime::from_nanos(12_000_000);
        let off = ClockOffset::from_round_trip(sent, CtrlTime(1_011_000), received);
        assert_eq!(off.to_host(CtrlTime(1_011_000)), HostTime::from_nanos(11_000_000));
        assert_eq!(off.to_host(CtrlTime(0)), HostTime::ZERO, "before the host started: clamped");
        assert_eq!(off.to_host(CtrlTime(u64::MAX)), HostTime::NEVER);
    }
}
