//! The PSD controller for the setup tools: the gateway's own sans-I/O session
//! ([`PsdSession`]) driven over the serial line by a small shell whose every await has a
//! deadline. The preflight and the calibration talk to the controller exactly as the gateway
//! does: the same handshake, identity checks, sequence checks and clock mapping.

use std::path::PathBuf;
use std::time::Duration;

use flowgate_protocol::psd::{self, Info, Message, Packet, Sample, Schedule};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::{timeout_at, Instant};

use crate::config::SerialSection;
use crate::gateway::core::counter_window::Verdict;
use crate::gateway::core::psd_session::{PsdSession, SessionEvent, RETRY_AFTER, TRIES};
use crate::gateway::core::SetupError;
use crate::gateway::shell::link::{open_serial, SerialError};
use crate::time::HostTime;

/// How long one write to the line may take.
const WRITE_DEADLINE: Duration = Duration::from_millis(200);

#[derive(Debug, thiserror::Error)]
pub enum PsdClientError {
    #[error(transparent)]
    Serial(#[from] SerialError),
    #[error("serial port {port}: {source}")]
    Io { port: PathBuf, source: std::io::Error },
    #[error("serial port {port} closed (device unplugged?)")]
    Closed { port: PathBuf },
    #[error(transparent)]
    Setup(#[from] SetupError),
    #[error("PSD controller on {port}: {what}")]
    Timeout { port: PathBuf, what: String },
}

/// What the handshake found.
#[derive(Debug, Clone, Copy)]
pub struct Handshake {
    pub info: Info,
    /// The handshake's time-sync round trip.
    pub round_trip: Duration,
}

/// What the stream delivered since the last call, beside samples.
#[derive(Debug, Default, Clone, Copy)]
pub struct StreamTally {
    pub samples: u64,
    pub frame_ends: u64,
    /// Frames that did not decode (CRC, framing).
    pub bad_frames: u64,
    /// Packets lost in sequence gaps; duplicates and old (replayed) packets discarded.
    pub lost: u64,
    pub discarded: u64,
    /// Faults the controller reported.
    pub faults: u64,
}

/// A configured controller's serial session.
#[derive(Debug)]
pub struct PsdClient {
    port_path: PathBuf,
    port: tokio_serial::SerialStream,
    session: PsdSession,
    origin: Instant,
    outgoing: Vec<Packet>,
    pub tally: StreamTally,
}

impl PsdClient {
    /// Open the port (exclusively, as the gateway does).
    pub fn open(serial: &SerialSection, schedule: Schedule, counts: u16) -> Result<Self, PsdClientError> {
        let port = open_serial(&serial.port, serial.baud)?;
        Ok(Self {
            port_path: serial.port.clone(),
            port,
            session: PsdSession::new(schedule, counts),
            origin: Instant::now(),
            outgoing: Vec::new(),
            tally: StreamTally::default(),
        })
    }

    fn now(&self) -> HostTime {
        HostTime::from_nanos(self.origin.elapsed().as_nanos() as u64)
    }

    fn instant(&self, t: HostTime) -> Instant {
        let far = self.origin.elapsed() + Duration::from_secs(3600);
        self.origin + Duration::from_nanos(t.as_nanos()).min(far)
    }

    async fn flush(&mut self) -> Result<(), PsdClientError> {
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        for packet in std::mem::take(&mut self.outgoing) {
            let n = packet.encode(&mut wire).map_err(|e| PsdClientError::Io {
                port: self.port_path.clone(),
                source: std::io::Error::new(std::io::ErrorKind::InvalidInput, e),
            })?;
            match tokio::time::timeout(WRITE_DEADLINE, self.port.write_all(&wire[..n])).await {
                Ok(Ok(())) => {}
                Ok(Err(source)) => return Err(PsdClientError::Io { port: self.port_path.clone(), source }),
                Err(_) => {
                    return Err(PsdClientError::Timeout {
                        port: self.port_path.clone(),
                        what: format!("a write did not finish in {} ms", WRITE_DEADLINE.as_millis()),
                    })
                }
            }
        }
        Ok(())
    }

    /// Configure the controller and start its stream (Info, schedule, time sync, start), with
    /// the gateway's retries. Fails with the gateway's own setup errors.
    pub async fn configure(&mut self) -> Result<Handshake, PsdClientError> {
        let now = self.now();
        let out = &mut self.outgoing;
        self.session.connect(now, &mut |p| out.push(p));
        self.flush().await?;
        // Four requests, each tried TRIES times RETRY_AFTER apart, at most.
        let give_up = Instant::now() + RETRY_AFTER * u32::from(TRIES) * 4 + Duration::from_secs(1);
        loop {
            let deadline = self.instant(self.session.deadline()).min(give_up);
            match self.next_packet(deadline).await? {
                Some(packet) => {
                    let now = self.now();
                    let out = &mut self.outgoing;
                    match self.session.on_packet(now, &packet, &mut |p| out.push(p)) {
                        SessionEvent::Streaming => {
                            self.flush().await?;
                            let info = self.session.info().expect("Info precedes the stream");
                            let round_trip = self.session.round_trip().unwrap_or_default();
                            return Ok(Handshake { info, round_trip });
                        }
                        SessionEvent::Failed(e) => return Err(e.into()),
                        _ => {}
                    }
                }
                None if Instant::now() >= give_up => {
                    return Err(self.timeout("the handshake did not finish"));
                }
                None => {
                    let now = self.now();
                    let out = &mut self.outgoing;
                    if let Some(e) = self.session.tick(now, &mut |p| out.push(p)) {
                        return Err(e.into());
                    }
                }
            }
            self.flush().await?;
        }
    }

    fn timeout(&self, what: &str) -> PsdClientError {
        PsdClientError::Timeout { port: self.port_path.clone(), what: what.to_string() }
    }

    /// The next decoded packet, or `None` at `deadline`. Undecodable frames are counted.
    async fn next_packet(&mut self, deadline: Instant) -> Result<Option<Packet>, PsdClientError> {
        loop {
            while let Some(item) = self.session.next_item() {
                match item {
                    Ok(packet) => return Ok(Some(packet)),
                    Err(_) => self.tally.bad_frames += 1,
                }
            }
            let mut chunk = [0u8; 1024];
            match timeout_at(deadline, self.port.read(&mut chunk)).await {
                Err(_) => return Ok(None),
                Ok(Ok(0)) => return Err(PsdClientError::Closed { port: self.port_path.clone() }),
                Ok(Ok(n)) => self.session.feed(&chunk[..n]),
                Ok(Err(source)) => return Err(PsdClientError::Io { port: self.port_path.clone(), source }),
            }
        }
    }

    /// The next sample of the running stream, or `None` at `deadline`. Duplicates and old
    /// packets are discarded and gaps counted, as the gateway does; frame ends and faults
    /// are counted.
    pub async fn next_sample(&mut self, deadline: Instant) -> Result<Option<Sample>, PsdClientError> {
        loop {
            let Some(packet) = self.next_packet(deadline).await? else { return Ok(None) };
            let now = self.now();
            let out = &mut self.outgoing;
            if self.session.on_packet(now, &packet, &mut |p| out.push(p)) != SessionEvent::Pass {
                self.flush().await?;
                continue;
            }
            match self.session.sequence(packet.seq) {
                Verdict::Next | Verdict::Rebased => {}
                Verdict::Gap(n) => self.tally.lost += u64::from(n),
                Verdict::Repeat | Verdict::Old | Verdict::Jump => {
                    self.tally.discarded += 1;
                    continue;
                }
            }
            match packet.message {
                Message::Sample(s) => {
                    self.tally.samples += 1;
                    return Ok(Some(s));
                }
                Message::FrameEnd { .. } => self.tally.frame_ends += 1,
                Message::Fault { .. } => self.tally.faults += 1,
                _ => {}
            }
        }
    }

    /// Time syncs while streaming: `n` round trips, each awaited (at most `RETRY_AFTER`).
    /// Returns each round trip; samples meanwhile are counted and dropped.
    pub async fn round_trips(&mut self, n: usize) -> Result<Vec<Duration>, PsdClientError> {
        let mut trips = Vec::with_capacity(n);
        for _ in 0..n {
            let now = self.now();
            let out = &mut self.outgoing;
            self.session.sync_now(now, &mut |p| out.push(p));
            self.flush().await?;
            let deadline = Instant::now() + RETRY_AFTER;
            loop {
                let Some(packet) = self.next_packet(deadline).await? else {
                    return Err(
                        self.timeout(&format!("a time sync went unanswered for {} ms", RETRY_AFTER.as_millis()))
                    );
                };
                let now = self.now();
                let out = &mut self.outgoing;
                if let SessionEvent::Resynced { .. } = self.session.on_packet(now, &packet, &mut |p| out.push(p)) {
                    trips.push(self.session.round_trip().unwrap_or_default());
                    break;
                }
            }
        }
        Ok(trips)
    }

    /// Stop the stream and keep the line: `configure` starts it again (the calibration
    /// pauses while the user moves the LED, so no stale samples wait in the line).
    pub async fn pause(&mut self) -> Result<(), PsdClientError> {
        let out = &mut self.outgoing;
        self.session.stop(&mut |p| out.push(p));
        self.flush().await
    }

    /// Stop the stream (best effort: the controller may already be gone).
    pub async fn stop(mut self) {
        let out = &mut self.outgoing;
        self.session.stop(&mut |p| out.push(p));
        let _ = self.flush().await;
    }
}
