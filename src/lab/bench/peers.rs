//! The bench's side of the wires: the scripted PSD controller, and the CAN side (an SLCAN
//! adapter on a pty with a board behind it, or a SocketCAN interface).

use std::os::unix::fs::OpenOptionsExt as _;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rustix::event::{PollFd, PollFlags};
use rustix::time::Timespec;

use bytes::{Bytes, BytesMut};
use flowgate_protocol::canopen;
use flowgate_protocol::codec::{PsdCodec, SlcanAdapterCodec};
use flowgate_protocol::motor::MotorMessage;
use flowgate_protocol::psd::{self, Info, Message, Packet, Sample, SampleFlags};
use flowgate_protocol::slcan::{Command, Line as _, Response};
use flowgate_protocol::CanFrame;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::codec::Decoder;

/// A velocity command seen on the bus: when it became readable, and its seq (for CiA 402
/// drives, a count of commands).
pub type Stamped = (Instant, u8);

/// What the bench takes as a cycle's command on the bus, and what it answers as a drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Commands {
    /// A PCL-80K-like board's velocity frame.
    Board,
    /// CiA 402 drives: a cycle's command is complete with the right drive's RPDO1 (the
    /// left's goes first). Every SDO write to either drive is answered at once, as a drive
    /// answers its configuration.
    Cia402 { left: canopen::NodeId, right: canopen::NodeId },
}

impl Commands {
    /// Whether `frame` completes a cycle's command (and its seq), and a drive's answer to it.
    fn read(&self, frame: &CanFrame, count: &mut u8) -> (Option<u8>, Option<CanFrame>) {
        match *self {
            Self::Board => match MotorMessage::parse(frame) {
                Ok(MotorMessage::Velocity { seq, .. }) => (Some(seq), None),
                _ => (None, None),
            },
            Self::Cia402 { left, right } => match canopen::CanOpenMessage::parse(frame) {
                Ok(canopen::CanOpenMessage::Pdo {
                    direction: canopen::PdoDirection::Receive, number: 1, node, ..
                }) if node == right => {
                    *count = count.wrapping_add(1);
                    (Some(*count), None)
                }
                Ok(canopen::CanOpenMessage::SdoRequest {
                    node,
                    request: canopen::SdoRequest::Download { index, sub, .. },
                }) if node == left || node == right => {
                    let answer = canopen::CanOpenMessage::SdoResponse {
                        node,
                        response: canopen::SdoResponse::Downloaded { index, sub },
                    };
                    (None, answer.to_frame())
                }
                _ => (None, None),
            },
        }
    }
}

/// The scripted PSD controller on the master side of a pty: the bench writes its frames
/// when they are due ([`Controller::frame`]), and its own thread answers the gateway's
/// requests (time syncs above all) as they arrive, whichever target the bench is pacing,
/// as a real controller does.
pub struct Controller {
    line: Arc<PsdLine>,
    pub path: PathBuf,
    _slave: std::fs::File,
    frame: u32,
    camera: flowgate_sim::camera::CameraModel,
    /// The robot's swing runs on this clock, continuous across blocks and phases.
    origin: Instant,
    stop: Arc<AtomicBool>,
    responder: Option<std::thread::JoinHandle<()>>,
}

/// The pty's master side, written by the bench (frames) and the responder (replies): each
/// write of packets is whole, under the lock, with one packet sequence for both.
struct PsdLine {
    master: std::fs::File,
    writer: Mutex<Writer>,
}

struct Writer {
    seq: u16,
    out: Vec<u8>,
}

/// How long one write may wait for the pty to take it: the gateway gone, nobody reading.
const WRITE_DEADLINE: Duration = Duration::from_secs(1);
/// How often the responder looks whether it should stop.
const RESPONDER_POLL: Duration = Duration::from_millis(50);

impl PsdLine {
    /// Encode `messages` with the next sequence numbers and write them in one go; an error
    /// if the pty takes nothing for [`WRITE_DEADLINE`].
    fn send(&self, messages: &[Message]) -> std::io::Result<()> {
        let mut w = self.writer.lock().map_err(|_| std::io::Error::other("PSD line writer poisoned"))?;
        let Writer { seq, out } = &mut *w;
        out.clear();
        for &m in messages {
            let mut wire = [0u8; psd::MAX_WIRE_LEN];
            let n = Packet::new(*seq, m).encode(&mut wire).expect("fits");
            *seq = seq.wrapping_add(1);
            out.extend_from_slice(&wire[..n]);
        }
        let mut at = 0;
        while at < out.len() {
            match rustix::io::write(&self.master, &out[at..]) {
                Ok(n) => at += n,
                Err(rustix::io::Errno::AGAIN) => {
                    let mut fds = [PollFd::new(&self.master, PollFlags::OUT)];
                    let deadline = Timespec { tv_sec: WRITE_DEADLINE.as_secs() as _, tv_nsec: 0 };
                    if rustix::event::poll(&mut fds, Some(&deadline))? == 0 {
                        return Err(std::io::Error::other(
                            "the PSD pty took no bytes for 1 s: is the gateway reading?",
                        ));
                    }
                }
                Err(rustix::io::Errno::INTR) => {}
                Err(e) => return Err(e.into()),
            }
        }
        Ok(())
    }

    /// Answer requests until `stop`: info, time sync, acks for the rest.
    fn respond(&self, stop: &AtomicBool) {
        let mut rx = BytesMut::new();
        let mut codec = PsdCodec::controller();
        let mut chunk = [0u8; 4096];
        let tick = Timespec { tv_sec: 0, tv_nsec: RESPONDER_POLL.as_nanos() as _ };
        while !stop.load(Ordering::Relaxed) {
            let mut fds = [PollFd::new(&self.master, PollFlags::IN)];
            match rustix::event::poll(&mut fds, Some(&tick)) {
                Ok(0) | Err(rustix::io::Errno::INTR) => continue,
                Ok(_) => {}
                Err(e) => return eprintln!("bench: waiting on the PSD pty failed: {e}"),
            }
            match rustix::io::read(&self.master, &mut chunk) {
                Ok(n) if n > 0 => rx.extend_from_slice(&chunk[..n]),
                // EIO: no process has the slave open (between the gateway's opens).
                Ok(_) | Err(rustix::io::Errno::AGAIN | rustix::io::Errno::INTR | rustix::io::Errno::IO) => {
                    std::thread::sleep(Duration::from_millis(1));
                    continue;
                }
                Err(e) => return eprintln!("bench: reading the PSD pty failed: {e}"),
            }
            while let Ok(Some(item)) = codec.decode(&mut rx) {
                let Ok(p) = item else { continue };
                let reply = match p.message {
                    Message::GetInfo => Message::Info {
                        request_seq: p.seq,
                        info: Info { firmware: [0, 9, 0], psd_counts: [4096; 2], max_leds: 16, clock_hz: 1_000_000 },
                    },
                    Message::TimeSync { host_time_us } => {
                        Message::TimeSyncReply { request_seq: p.seq, host_time_us, t_ctrl_us: clock_us() }
                    }
                    m => Message::Ack { seq: p.seq, msg_type: m.msg_type() as u8 },
                };
                if let Err(e) = self.send(&[reply]) {
                    return eprintln!("bench: answering the gateway failed: {e}");
                }
            }
        }
    }
}

/// The controller's clock: µs, wrapping at 2^40 as its stamps do.
fn clock_us() -> u64 {
    let since_epoch = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
    (since_epoch.as_micros() % (1 << 40)) as u64
}

impl Controller {
    /// A new pty: the master here (non-blocking), the slave's path for the gateway, kept
    /// open (raw) so the line stays up between the gateway's opens; and the responder.
    pub fn new() -> std::io::Result<Self> {
        use rustix::pty::{grantpt, openpt, ptsname, unlockpt, OpenptFlags};
        let master = openpt(OpenptFlags::RDWR | OpenptFlags::NOCTTY | OpenptFlags::CLOEXEC)?;
        grantpt(&master)?;
        unlockpt(&master)?;
        rustix::io::ioctl_fionbio(&master, true)?;
        let path = PathBuf::from(ptsname(&master, Vec::new())?.into_string().map_err(std::io::Error::other)?);
        let slave = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(rustix::fs::OFlags::NOCTTY.bits() as i32)
            .open(&path)?;
        let mut termios = rustix::termios::tcgetattr(&slave)?;
        termios.make_raw();
        rustix::termios::tcsetattr(&slave, rustix::termios::OptionalActions::Now, &termios)?;
        let line = Arc::new(PsdLine {
            master: std::fs::File::from(master),
            writer: Mutex::new(Writer { seq: 0, out: Vec::with_capacity(3 * psd::MAX_WIRE_LEN) }),
        });
        let stop = Arc::new(AtomicBool::new(false));
        let responder = {
            let (line, stop) = (Arc::clone(&line), Arc::clone(&stop));
            std::thread::Builder::new().name("bench-psd-responder".into()).spawn(move || line.respond(&stop))?
        };
        Ok(Self {
            line,
            path,
            _slave: slave,
            frame: 0,
            camera: flowgate_sim::camera::CameraModel::default(),
            origin: Instant::now(),
            stop,
            responder: Some(responder),
        })
    }

    /// One time-division frame: the robot's two LEDs, then the frame end, written in one
    /// go. Returns when the last byte is in the pty, or an error if the line takes none of
    /// it for a second (the gateway gone). The robot swings along x (0.2 m, peak speed
    /// 0.1 m/s, within what its wheels can do, so every pose is plausible) and never stalls.
    pub fn frame(&mut self) -> std::io::Result<()> {
        let t = self.origin.elapsed().as_secs_f64();
        let x = 0.2 * (t * 0.5).sin();
        let stamp = clock_us();
        let mut messages = [Message::FrameEnd { frame: self.frame, t_ctrl_us: stamp, samples: 2 }; 3];
        for (k, (slot, led, dx)) in [(0u8, 1u8, 0.035), (1, 2, -0.035)].into_iter().enumerate() {
            let (rx, ry) = self.camera.project(crate::Point::new(x + dx, 0.0)).expect("in view");
            messages[k] = Message::Sample(Sample {
                frame: self.frame,
                slot,
                led,
                t_ctrl_us: stamp,
                x: rx.round() as i32,
                y: ry.round() as i32,
                intensity: 3000,
                flags: SampleFlags(0),
            });
        }
        self.frame = self.frame.wrapping_add(1);
        self.line.send(&messages)
    }
}

impl Drop for Controller {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.responder.take() {
            let _ = t.join();
        }
    }
}

/// The CAN bus as the bench sees it: commands stamped the moment they are readable, and a
/// way to speak as the motor board.
pub struct CanSide {
    /// The endpoint the gateway (or the null gateway) is configured with.
    pub endpoint: String,
    pub commands: mpsc::Receiver<Stamped>,
    to_bus: ToBus,
    _keep: Option<std::fs::File>,
    /// The SLCAN reader polls instead of sleeping while this is true (see [`CanSide::poll`]).
    polling: Option<tokio::sync::watch::Sender<bool>>,
}

/// A handle for speaking on the bus as the motor board.
#[derive(Clone)]
pub struct ToBus(Bus);

#[derive(Clone)]
enum Bus {
    Slcan(tokio::sync::mpsc::UnboundedSender<Bytes>),
    SocketCan(Arc<socketcan::CanSocket>),
}

impl CanSide {
    /// A scripted SLCAN adapter with a board behind it, on a new pty, served by its own
    /// thread and runtime so each command is stamped the moment its line is readable.
    pub fn slcan(kind: Commands) -> Self {
        let (setup_tx, setup_rx) = mpsc::channel();
        let (cmd_tx, commands) = mpsc::channel();
        let (polling, mut poll_rx) = tokio::sync::watch::channel(false);
        std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
            rt.block_on(async move {
                let (adapter, keep, path) = flowgate_sim::rig::pty().expect("pty");
                let (mut rd, mut wr) = tokio::io::split(adapter);
                let (out_tx, mut out_rx) = tokio::sync::mpsc::unbounded_channel::<Bytes>();
                setup_tx.send((path, keep, out_tx.clone())).expect("bench alive");
                let writer = tokio::spawn(async move {
                    while let Some(bytes) = out_rx.recv().await {
                        if wr.write_all(&bytes).await.is_err() {
                            break;
                        }
                    }
                });
                let mut buf = BytesMut::new();
                let mut codec = SlcanAdapterCodec::new();
                let mut chunk = [0u8; 4096];
                let mut count = 0u8;
                loop {
                    let poll = *poll_rx.borrow_and_update();
                    let n = tokio::select! {
                        n = rd.read(&mut chunk) => n,
                        changed = poll_rx.changed() => match changed {
                            Ok(()) => continue,
                            Err(_) => break,
                        },
                        // Polling: one yield, and the runtime asks the kernel without blocking.
                        () = async { if poll { tokio::task::yield_now().await } else { std::future::pending().await } } => continue,
                    };
                    let Ok(n @ 1..) = n else { break };
                    let now = Instant::now();
                    buf.extend_from_slice(&chunk[..n]);
                    while let Ok(Some(item)) = codec.decode(&mut buf) {
                        let reply: &'static [u8] = match item {
                            Ok(Command::Transmit(f)) => {
                                let (seq, answer) = kind.read(&f, &mut count);
                                if let Some(seq) = seq {
                                    if cmd_tx.send((now, seq)).is_err() {
                                        return;
                                    }
                                }
                                if let Some(answer) = answer {
                                    let _ = out_tx.send(Bytes::from_static(b"z\r"));
                                    let _ = out_tx.send(slcan_line(answer));
                                    continue;
                                }
                                b"z\r"
                            }
                            Ok(_) => b"\r",
                            Err(_) => b"\x07",
                        };
                        let _ = out_tx.send(Bytes::from_static(reply)); // no allocation per line
                    }
                }
                writer.abort();
            });
        });
        let (path, keep, out) = setup_rx.recv().expect("CAN thread starts");
        Self {
            endpoint: format!("slcan:{}?bitrate={}", path.display(), super::CAN_BITRATE),
            commands,
            to_bus: ToBus(Bus::Slcan(out)),
            _keep: Some(keep),
            polling: Some(polling),
        }
    }

    /// A raw socket on a SocketCAN interface (vcan0, can0): a blocking reader thread stamps
    /// each velocity command as `read(2)` returns it.
    pub fn socketcan(interface: &str, kind: Commands) -> std::io::Result<Self> {
        use socketcan::Socket as _;
        let socket = Arc::new(
            socketcan::CanSocket::open(interface)
                .map_err(|e| std::io::Error::new(e.kind(), format!("CAN interface {interface}: {e} (is it up?)")))?,
        );
        let (cmd_tx, commands) = mpsc::channel();
        let reader = Arc::clone(&socket);
        let mut count = 0u8;
        std::thread::spawn(move || loop {
            let f = match reader.read_frame() {
                Ok(f) => f,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    // The commands after this count as lost: say why.
                    eprintln!("bench: reading the CAN socket failed: {e}");
                    return;
                }
            };
            let now = Instant::now();
            let Ok(frame) = CanFrame::try_from(&f) else { continue };
            let (seq, answer) = kind.read(&frame, &mut count);
            if let Some(seq) = seq {
                if cmd_tx.send((now, seq)).is_err() {
                    return;
                }
            }
            if let Some(answer) = answer {
                let _ = reader.write_frame(&socketcan::CanFrame::from(answer));
            }
        });
        Ok(Self {
            endpoint: format!("socketcan:{interface}"),
            commands,
            to_bus: ToBus(Bus::SocketCan(socket)),
            _keep: None,
            polling: None,
        })
    }

    /// A handle to speak on this bus as the board.
    pub fn board(&self) -> ToBus {
        self.to_bus.clone()
    }

    /// Poll for commands instead of sleeping between them (`true`), as a hardware receiver
    /// never sleeps; or sleep (`false`). SLCAN only: the SocketCAN reader always blocks.
    pub fn poll(&self, on: bool) {
        if let Some(p) = &self.polling {
            p.send_replace(on);
        }
    }

    /// Forget commands already received.
    pub fn drain(&self) {
        while self.commands.try_recv().is_ok() {}
    }
}

/// A received frame as the adapter hands it to the host.
fn slcan_line(frame: CanFrame) -> Bytes {
    let mut line = [0u8; flowgate_protocol::slcan::MAX_LINE_LEN];
    let n = Response::Frame { frame, timestamp_ms: None }.emit(&mut line).expect("fits");
    Bytes::copy_from_slice(&line[..n])
}

impl ToBus {
    /// Put a message on the bus as the board.
    pub fn send(&self, m: MotorMessage) {
        self.send_frame(m.to_frame().expect("valid"));
    }

    /// Put a frame on the bus (as a drive).
    pub fn send_frame(&self, frame: CanFrame) {
        match &self.0 {
            Bus::Slcan(out) => {
                let _ = out.send(slcan_line(frame));
            }
            Bus::SocketCan(socket) => {
                use socketcan::Socket as _;
                let _ = socket.write_frame(&socketcan::CanFrame::from(frame));
            }
        }
    }
}
