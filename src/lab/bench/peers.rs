//! The bench's side of the wires: the scripted PSD controller, the CAN side (an SLCAN
//! adapter on a pty with a board behind it, or a SocketCAN interface), and the null gateway
//! that measures the floor of the same path.

use std::path::PathBuf;
use std::sync::mpsc;
use std::sync::Arc;
use std::time::Instant;

use bytes::{Bytes, BytesMut};
use flowgate_protocol::codec::{PsdCodec, SlcanAdapterCodec};
use flowgate_protocol::motor::{MotorMessage, NodeId};
use flowgate_protocol::psd::{self, Info, Message, Packet, Sample, SampleFlags};
use flowgate_protocol::slcan::{Command, Line, Response};
use flowgate_protocol::CanFrame;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::codec::Decoder;

/// A velocity command seen on the bus: when it became readable, and its seq.
pub type Stamped = (Instant, u8);

/// The scripted PSD controller on the master side of a pty.
pub struct Controller {
    pub port: tokio_serial::SerialStream,
    pub path: PathBuf,
    _keep: std::fs::File,
    rx: BytesMut,
    codec: PsdCodec,
    seq: u16,
    frame: u32,
    camera: flowgate_sim::calibration::CameraModel,
    out: Vec<u8>,
    /// The robot's swing runs on this clock, continuous across blocks and phases.
    origin: Instant,
}

impl Controller {
    pub fn new() -> Self {
        let (port, keep, path) = flowgate_sim::rig::pty().expect("pty");
        Self {
            port,
            path,
            _keep: keep,
            rx: BytesMut::new(),
            codec: PsdCodec::new(),
            seq: 0,
            frame: 0,
            camera: flowgate_sim::calibration::CameraModel::default(),
            out: Vec::with_capacity(3 * psd::MAX_WIRE_LEN),
            origin: Instant::now(),
        }
    }

    fn push(&mut self, m: Message) {
        let mut wire = [0u8; psd::MAX_WIRE_LEN];
        let n = Packet::new(self.seq, m).encode(&mut wire).expect("fits");
        self.seq = self.seq.wrapping_add(1);
        self.out.extend_from_slice(&wire[..n]);
    }

    fn clock_us() -> u64 {
        let since_epoch = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        (since_epoch.as_micros() % (1 << 40)) as u64
    }

    /// Answer the gateway's requests in `bytes` (info, time sync, acks for the rest).
    pub async fn serve(&mut self, bytes: &[u8]) {
        self.rx.extend_from_slice(bytes);
        while let Ok(Some(item)) = self.codec.decode(&mut self.rx) {
            let Ok(p) = item else { continue };
            let reply = match p.message {
                Message::GetInfo => Message::Info {
                    request_seq: p.seq,
                    info: Info { firmware: [0, 9, 0], psd_counts: [4096; 2], max_leds: 16, clock_hz: 1_000_000 },
                },
                Message::TimeSync { host_time_us } => {
                    Message::TimeSyncReply { request_seq: p.seq, host_time_us, t_ctrl_us: Self::clock_us() }
                }
                m => Message::Ack { seq: p.seq, msg_type: m.msg_type() as u8 },
            };
            self.out.clear();
            self.push(reply);
            self.port.write_all(&self.out).await.expect("psd write");
        }
    }

    /// One time-division frame: the robot's two LEDs, then the frame end, written in one
    /// go. Returns when the last byte is in the pty. The robot swings along x (0.2 m,
    /// period 4.2 s) so the planner never sees it stall.
    /// Write one frame; an error if the line does not take it within a second (the gateway
    /// gone, nobody reading the pty).
    pub async fn frame(&mut self) -> std::io::Result<()> {
        let t = self.origin.elapsed().as_secs_f64();
        let x = 0.2 * (t * 1.5).sin();
        let stamp = Self::clock_us();
        self.out.clear();
        for (slot, led, dx) in [(0u8, 1u8, 0.035), (1, 2, -0.035)] {
            let (rx, ry) = self.camera.project(crate::Point::new(x + dx, 0.0)).expect("in view");
            let sample = Sample {
                frame: self.frame,
                slot,
                led,
                t_ctrl_us: stamp,
                x: rx.round() as i32,
                y: ry.round() as i32,
                intensity: 3000,
                flags: SampleFlags(0),
            };
            self.push(Message::Sample(sample));
        }
        self.push(Message::FrameEnd { frame: self.frame, t_ctrl_us: stamp, samples: 2 });
        self.frame = self.frame.wrapping_add(1);
        tokio::time::timeout(std::time::Duration::from_secs(1), self.port.write_all(&self.out))
            .await
            .map_err(|_| std::io::Error::other("the PSD pty took no frame for 1 s: is the gateway reading?"))?
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
    pub fn slcan() -> Self {
        let (setup_tx, setup_rx) = mpsc::channel();
        let (cmd_tx, commands) = mpsc::channel();
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
                while let Ok(n) = rd.read(&mut chunk).await {
                    if n == 0 {
                        break;
                    }
                    let now = Instant::now();
                    buf.extend_from_slice(&chunk[..n]);
                    while let Ok(Some(item)) = codec.decode(&mut buf) {
                        let reply: &'static [u8] = match item {
                            Ok(Command::Transmit(f)) => {
                                if let Ok(MotorMessage::Velocity { seq, .. }) = MotorMessage::parse(&f) {
                                    if cmd_tx.send((now, seq)).is_err() {
                                        return;
                                    }
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
        }
    }

    /// A raw socket on a SocketCAN interface (vcan0, can0): a blocking reader thread stamps
    /// each velocity command as `read(2)` returns it.
    pub fn socketcan(interface: &str) -> std::io::Result<Self> {
        use socketcan::Socket as _;
        let socket = Arc::new(
            socketcan::CanSocket::open(interface)
                .map_err(|e| std::io::Error::new(e.kind(), format!("CAN interface {interface}: {e} (is it up?)")))?,
        );
        let (cmd_tx, commands) = mpsc::channel();
        let reader = Arc::clone(&socket);
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
            if let Ok(MotorMessage::Velocity { seq, .. }) = MotorMessage::parse(&frame) {
                if cmd_tx.send((now, seq)).is_err() {
                    return;
                }
            }
        });
        Ok(Self {
            endpoint: format!("socketcan:{interface}"),
            commands,
            to_bus: ToBus(Bus::SocketCan(socket)),
            _keep: None,
        })
    }

    /// A handle to speak on this bus as the board.
    pub fn board(&self) -> ToBus {
        self.to_bus.clone()
    }

    /// Forget commands already received.
    pub fn drain(&self) {
        while self.commands.try_recv().is_ok() {}
    }
}

impl ToBus {
    /// Put a message on the bus as the board.
    pub fn send(&self, m: MotorMessage) {
        let frame: CanFrame = m.to_frame().expect("valid");
        match &self.0 {
            Bus::Slcan(out) => {
                let mut line = [0u8; flowgate_protocol::slcan::MAX_LINE_LEN];
                let n = Response::Frame { frame, timestamp_ms: None }.emit(&mut line).expect("fits");
                let _ = out.send(Bytes::copy_from_slice(&line[..n]));
            }
            Bus::SocketCan(socket) => {
                use socketcan::Socket as _;
                let _ = socket.write_frame(&socketcan::CanFrame::from(frame));
            }
        }
    }
}

/// The floor: a "gateway" that does no work. It opens the same two endpoints the same way
/// (tokio-serial on the PSD pty; SLCAN on a pty, or a SocketCAN socket), and answers every
/// frame end with a fixed velocity command at once. What it measures is the pty, the
/// scheduler and the CAN transport on this machine, with flowgate taken out.
pub struct NullGateway {
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// Its thread's id, for its CPU time in /proc/self/task.
    pub tid: i32,
}

impl NullGateway {
    /// Start it and return once both endpoints are open.
    pub fn start(psd_path: PathBuf, can_endpoint: &str) -> std::io::Result<Self> {
        let can: crate::link::CanUrl = can_endpoint.parse().map_err(std::io::Error::other)?;
        let (ready_tx, ready_rx) = mpsc::channel::<std::io::Result<i32>>();
        let (stop, mut stopped) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
            rt.block_on(async move {
                let opened = async {
                    let psd = crate::link::open_serial(&psd_path, super::BAUD).map_err(std::io::Error::other)?;
                    let can = crate::link::open_can(&can).await.map_err(std::io::Error::other)?;
                    Ok::<_, std::io::Error>((psd, can))
                };
                let (mut psd, mut can) = match opened.await {
                    Ok(p) => p,
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                let _ = ready_tx.send(Ok(rustix::thread::gettid().as_raw_nonzero().get()));
                // Node 2: on a shared SocketCAN bus the gateway (node 1) must not take the
                // null gateway's commands for a second master on its own board's id.
                let node = NodeId::new(2).expect("2");
                let mut rx = BytesMut::with_capacity(4096);
                let mut codec = PsdCodec::new();
                let mut seq = 0u8;
                loop {
                    tokio::select! {
                        _ = &mut stopped => return,
                        n = psd.read_buf(&mut rx) => {
                            if !matches!(n, Ok(n) if n > 0) { return; }
                            while let Ok(Some(item)) = codec.decode(&mut rx) {
                                if let Ok(Packet { message: Message::FrameEnd { .. }, .. }) = item {
                                    let m = MotorMessage::Velocity { node, left: 0, right: 0, seq };
                                    seq = seq.wrapping_add(1);
                                    if can.send(m.to_frame().expect("valid")).await.is_err() { return; }
                                }
                            }
                        }
                        // Drain what the bus says (SLCAN acks) so its buffer never fills.
                        e = can.recv() => if e.is_err() { return },
                    }
                }
            });
        });
        match ready_rx.recv() {
            Ok(Ok(tid)) => Ok(Self { stop: Some(stop), thread: Some(thread), tid }),
            Ok(Err(e)) => Err(e),
            Err(_) => Err(std::io::Error::other("the null gateway's thread died")),
        }
    }
}

impl Drop for NullGateway {
    /// Stop and wait, so the ports are closed (and their locks released) for the gateway.
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
