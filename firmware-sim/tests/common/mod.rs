//! A host for the simulator's tests: opens the PSD pty like a gateway would and speaks the
//! protocol with the project's own codec.
#![allow(dead_code)]

use std::path::Path;
use std::time::Duration;

use flowgate_protocol::codec::{PsdCodec, StreamError};
use flowgate_protocol::psd::{self, Message, Packet};
use flowgate_sim::rig::{self, RigConfig, RigHandle};
use flowgate_sim::scenario::SimScenario;
use futures_util::{SinkExt, StreamExt};
use tokio::time::{timeout, Instant};
use tokio_serial::SerialPortBuilderExt;
use tokio_util::codec::Framed;

pub const WAIT: Duration = Duration::from_secs(3);

pub fn scenario(name: &str) -> SimScenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios").join(name);
    SimScenario::load(&path).unwrap()
}

pub async fn rig(config: RigConfig) -> RigHandle {
    rig::start(config).await.expect("rig starts")
}

pub struct Host {
    pub link: Framed<tokio_serial::SerialStream, PsdCodec>,
    seq: u16,
}

/// One frame as the host received it, with its arrival time.
pub type Arrival = (Instant, Result<Packet, StreamError<psd::Error>>);

impl Host {
    pub async fn open(path: &Path) -> Self {
        let port = tokio_serial::new(path.to_string_lossy(), 921_600).open_native_async().expect("open pty");
        Self { link: Framed::new(port, PsdCodec::new()), seq: 100 }
    }

    pub async fn send(&mut self, message: Message) -> u16 {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        self.link.send(Packet::new(seq, message)).await.unwrap();
        seq
    }

    pub async fn send_raw(&mut self, bytes: &[u8]) {
        use tokio::io::AsyncWriteExt;
        self.link.get_mut().write_all(bytes).await.unwrap();
    }

    /// The next frame (good or bad), within `WAIT`.
    pub async fn next(&mut self) -> Arrival {
        let item = timeout(WAIT, self.link.next()).await.expect("a frame within 3 s").expect("link open").unwrap();
        (Instant::now(), item)
    }

    /// The first good packet satisfying `pred`, skipping others, within `WAIT`.
    pub async fn until(&mut self, pred: impl Fn(&Message) -> bool) -> Packet {
        let deadline = Instant::now() + WAIT;
        loop {
            let item = tokio::time::timeout_at(deadline, self.link.next()).await.expect("expected packet within 3 s");
            if let Some(Ok(Ok(p))) = item {
                if pred(&p.message) {
                    return p;
                }
            }
        }
    }

    /// Like [`Host::request`], but on a lossy line: resend until answered (up to 20 times,
    /// 200 ms each), as a gateway does.
    pub async fn request_retry(&mut self, message: Message) -> Message {
        for _ in 0..20 {
            let seq = self.send(message).await;
            let deadline = Instant::now() + Duration::from_millis(200);
            while let Ok(Some(item)) = tokio::time::timeout_at(deadline, self.link.next()).await {
                if let Ok(Ok(p)) = item {
                    if matches!(p.message, Message::Ack { seq: s, .. } | Message::Nack { seq: s, .. } if s == seq) {
                        return p.message;
                    }
                }
            }
        }
        panic!("no answer to {message:?} after 20 tries");
    }

    /// Send a request and return the reply that names its seq (or answers it).
    pub async fn request(&mut self, message: Message) -> Message {
        let seq = self.send(message).await;
        self.until(|m| match m {
            Message::Ack { seq: s, .. } | Message::Nack { seq: s, .. } => *s == seq,
            Message::Info { request_seq: s, .. }
            | Message::Pong { request_seq: s, .. }
            | Message::TimeSyncReply { request_seq: s, .. } => *s == seq,
            _ => false,
        })
        .await
        .message
    }
}

/// A host on the simulator's SLCAN pty, with the project's own codec.
pub struct CanHost {
    pub link: Framed<tokio_serial::SerialStream, flowgate_protocol::codec::SlcanHostCodec>,
}

impl CanHost {
    /// Open the adapter's pty and open the channel at 1 Mbit/s.
    pub async fn open(path: &Path) -> Self {
        use flowgate_protocol::slcan::{Bitrate, Command, Response};
        let port = tokio_serial::new(path.to_string_lossy(), 921_600).open_native_async().expect("open pty");
        let mut host = Self { link: Framed::new(port, flowgate_protocol::codec::SlcanHostCodec::new()) };
        for cmd in [Command::Close, Command::SetBitrate(Bitrate::M1), Command::Open] {
            host.link.send(cmd).await.unwrap();
            loop {
                match timeout(WAIT, host.link.next()).await.expect("adapter answers").unwrap().unwrap() {
                    Ok(Response::Ok) => break,
                    Ok(Response::Error) => break, // Close while closed is refused by LAWICEL
                    _ => {}
                }
            }
        }
        host
    }

    pub async fn send(&mut self, m: flowgate_protocol::motor::MotorMessage) {
        use flowgate_protocol::slcan::Command;
        self.link.send(Command::Transmit(m.to_frame().unwrap())).await.unwrap();
    }

    /// Motor messages received within `window`, with their arrival times.
    pub async fn collect(&mut self, window: Duration) -> Vec<(Instant, flowgate_protocol::motor::MotorMessage)> {
        use flowgate_protocol::slcan::Response;
        let end = Instant::now() + window;
        let mut out = Vec::new();
        while let Ok(Some(item)) = tokio::time::timeout_at(end, self.link.next()).await {
            if let Ok(Ok(Response::Frame { frame, .. })) = item {
                if let Ok(m) = flowgate_protocol::motor::MotorMessage::parse(&frame) {
                    out.push((Instant::now(), m));
                }
            }
        }
        out
    }

    /// The first motor message satisfying `pred` within `WAIT`.
    pub async fn until(
        &mut self,
        pred: impl Fn(&flowgate_protocol::motor::MotorMessage) -> bool,
    ) -> flowgate_protocol::motor::MotorMessage {
        use flowgate_protocol::slcan::Response;
        let deadline = Instant::now() + WAIT;
        loop {
            let item =
                tokio::time::timeout_at(deadline, self.link.next()).await.expect("expected CAN frame within 3 s");
            if let Some(Ok(Ok(Response::Frame { frame, .. }))) = item {
                if let Ok(m) = flowgate_protocol::motor::MotorMessage::parse(&frame) {
                    if pred(&m) {
                        return m;
                    }
                }
            }
        }
    }
}
