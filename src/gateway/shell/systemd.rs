//! The systemd service manager's notification protocol (`sd_notify(3)`), sent with the
//! `sd-notify` crate: one datagram per message to the unix socket named by `NOTIFY_SOCKET`.
//! Here: the environment checked at start (a clear error for a bad one), the watchdog's
//! pace, and what to say when.
//!
//! - `READY=1` once the controller streams: the gateway is up and may be armed.
//! - `STATUS=...` with the safety state, on every change (`systemctl status` shows it).
//! - `WATCHDOG=1` from the control loop itself, at a quarter of `WATCHDOG_USEC`: a wedged
//!   loop stops sending, and systemd kills and restarts the gateway, which comes back Idle
//!   (no automatic re-arm: an operator arms it again).
//! - `STOPPING=1` when an orderly stop of the service begins.
//!
//! Without `NOTIFY_SOCKET` (not started by systemd) there is nothing to tell, and nothing is
//! sent. A failed send is counted, never fatal: the watchdog is systemd's to judge.

use std::time::{Duration, Instant};

use sd_notify::NotifyState;

/// The gateway's line to systemd.
#[derive(Debug)]
pub struct Notifier {
    /// `NOTIFY_SOCKET`, checked: an absolute path, or `@name` in Linux's abstract namespace.
    socket: String,
    /// How often to send `WATCHDOG=1` (a quarter of systemd's interval), if it asked.
    watchdog_every: Option<Duration>,
    next_watchdog: Instant,
    ready: bool,
    /// Sends that failed (socket gone, buffer full).
    pub failed: u64,
}

/// A `NOTIFY_SOCKET` or `WATCHDOG_USEC` that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum NotifyError {
    #[error("NOTIFY_SOCKET={0}: expected an absolute path or @abstract name")]
    BadSocket(String),
    #[error("WATCHDOG_USEC={0}: expected a positive number of microseconds")]
    BadWatchdog(String),
}

impl Notifier {
    /// From the environment systemd sets; `None` when not run under systemd (or when the
    /// watchdog and socket are meant for another process: `WATCHDOG_PID`).
    pub fn from_env() -> Result<Option<Self>, NotifyError> {
        let get = |k: &str| std::env::var_os(k).map(|v| v.to_string_lossy().into_owned());
        Self::new(get("NOTIFY_SOCKET"), get("WATCHDOG_USEC"), get("WATCHDOG_PID"), std::process::id())
    }

    fn new(
        socket: Option<String>,
        watchdog_usec: Option<String>,
        watchdog_pid: Option<String>,
        pid: u32,
    ) -> Result<Option<Self>, NotifyError> {
        let Some(socket) = socket.filter(|s| !s.is_empty()) else { return Ok(None) };
        if !(socket.starts_with('/') || socket.len() > 1 && socket.starts_with('@')) {
            return Err(NotifyError::BadSocket(socket));
        }
        let for_us = watchdog_pid.is_none_or(|p| p.trim().parse::<u32>() == Ok(pid));
        let watchdog_every = match watchdog_usec.filter(|_| for_us) {
            None => None,
            Some(v) => match v.trim().parse::<u64>() {
                Ok(us) if us > 0 => Some(Duration::from_micros(us) / 4),
                _ => return Err(NotifyError::BadWatchdog(v)),
            },
        };
        Ok(Some(Self { socket, watchdog_every, next_watchdog: Instant::now(), ready: false, failed: 0 }))
    }

    /// Send one message (the crate reads `NOTIFY_SOCKET` again, which [`Notifier::new`]
    /// checked; a message a few times a second at most, never per sample).
    fn send(&mut self, message: &[NotifyState<'_>]) {
        if let Err(e) = sd_notify::notify(message) {
            // Said once, counted always: a watchdog that cannot be fed is systemd's to judge.
            if self.failed == 0 {
                tracing::warn!("systemd notification to {} not delivered: {e} (further failures counted)", self.socket);
            }
            self.failed += 1;
        }
    }

    /// The controller streams: the gateway is ready (once).
    pub fn ready(&mut self, state: &str) {
        if !std::mem::replace(&mut self.ready, true) {
            self.send(&[NotifyState::Ready, NotifyState::Status(state)]);
        }
    }

    /// The safety state changed.
    pub fn status(&mut self, state: &str) {
        self.send(&[NotifyState::Status(state)]);
    }

    /// An orderly stop of the service has begun.
    pub fn stopping(&mut self) {
        self.send(&[NotifyState::Stopping]);
    }

    /// The loop went round at `now`: feed the watchdog if it is due. Cheap when it is not
    /// (one comparison): called on every turn of the loop.
    pub fn alive(&mut self, now: Instant) {
        if let Some(every) = self.watchdog_every {
            if now >= self.next_watchdog {
                self.next_watchdog = now + every;
                self.send(&[NotifyState::Watchdog]);
            }
        }
    }

    /// When the loop must wake to feed the watchdog, if it sleeps that long.
    pub fn next_due(&self) -> Option<Instant> {
        self.watchdog_every.map(|_| self.next_watchdog)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn notifier(socket: &str, usec: Option<&str>, pid: Option<&str>) -> Result<Option<Notifier>, NotifyError> {
        Notifier::new(Some(socket.into()), usec.map(Into::into), pid.map(Into::into), 42)
    }

    #[test]
    fn nothing_without_systemd() {
        assert!(Notifier::new(None, Some("1000000".into()), None, 42).unwrap().is_none());
        assert!(Notifier::new(Some(String::new()), None, None, 42).unwrap().is_none());
    }

    #[test]
    fn the_environment_is_checked() {
        assert!(matches!(notifier("relative/path", None, None), Err(NotifyError::BadSocket(_))));
        assert!(matches!(notifier("/run/x", Some("0"), None), Err(NotifyError::BadWatchdog(_))));
        assert!(matches!(notifier("/run/x", Some("soon"), None), Err(NotifyError::BadWatchdog(_))));
        let n = notifier("/run/x", Some("2000000"), None).unwrap().unwrap();
        assert_eq!(n.watchdog_every, Some(Duration::from_millis(500)), "a quarter of the interval");
        let other = notifier("/run/x", Some("2000000"), Some("7")).unwrap().unwrap();
        assert_eq!(other.watchdog_every, None, "the watchdog is another process's");
        assert!(notifier("@flowgate", None, None).unwrap().is_some());
        assert!(matches!(notifier("@", None, None), Err(NotifyError::BadSocket(_))));
    }

    /// On a real datagram socket, as systemd listens (the crate takes the socket from the
    /// environment: no other test of this binary reads `NOTIFY_SOCKET`).
    #[test]
    fn messages_arrive_and_the_watchdog_is_paced() {
        use std::os::unix::net::UnixDatagram;
        let dir = std::env::temp_dir().join(format!("flowgate-notify-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("notify");
        let _ = std::fs::remove_file(&path);
        let listener = UnixDatagram::bind(&path).unwrap();
        std::env::set_var("NOTIFY_SOCKET", &path);
        listener.set_nonblocking(true).unwrap();
        let mut n = notifier(path.to_str().unwrap(), Some("400000"), None).unwrap().unwrap();
        let recv = || {
            let mut buf = [0u8; 256];
            let len = listener.recv(&mut buf).unwrap();
            String::from_utf8(buf[..len].to_vec()).unwrap()
        };
        n.ready("idle");
        n.ready("idle");
        assert_eq!(recv(), "READY=1\nSTATUS=idle\n");
        let t0 = Instant::now();
        n.alive(t0);
        n.alive(t0 + Duration::from_millis(99));
        assert_eq!(recv(), "WATCHDOG=1\n");
        assert_eq!(n.next_due(), Some(t0 + Duration::from_millis(100)));
        n.alive(t0 + Duration::from_millis(100));
        assert_eq!(recv(), "WATCHDOG=1\n");
        n.status("armed");
        n.stopping();
        assert_eq!((recv(), recv()), ("STATUS=armed\n".into(), "STOPPING=1\n".into()));
        assert!(listener.recv(&mut [0u8; 16]).is_err(), "nothing else: one READY, two watchdogs");
        assert_eq!(n.failed, 0);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
