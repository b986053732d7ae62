//! CAN backends: SocketCAN and SLCAN, one enum ([`CanLink`]) chosen by a URL ([`crate::config::CanUrl`]).

use bytes::BytesMut;
use flowgate_protocol::codec::{SlcanHostCodec, StreamError};
use flowgate_protocol::slcan::{self, Bitrate, Command, Line as _, Response};

use crate::config::CanUrl;
use crate::gateway::core::input::CanEvent;
use flowgate_protocol::CanFrame;
use futures_util::StreamExt;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::codec::Decoder;

#[cfg(feature = "lab")]
use super::memory::{MemoryBus, MemoryLink};

#[derive(Debug, thiserror::Error)]
pub enum CanError {
    #[error("CAN interface {interface}: {source} (does it exist and is it up? e.g. `ip link set up can0`)")]
    SocketCan { interface: String, source: std::io::Error },
    #[error("SLCAN adapter: {0}")]
    Serial(#[from] super::SerialError),
    #[error("SLCAN adapter at {path} did not accept `{command}`")]
    SlcanRefused { path: String, command: String },
    #[error("SLCAN adapter at {path} did not answer")]
    SlcanSilent { path: String },
    #[error("CAN link closed")]
    Closed,
    #[error("CAN interface went down")]
    InterfaceDown,
    #[error("CAN {what} did not finish within its deadline (adapter stalled?)")]
    Timeout { what: &'static str },
    #[error("CAN I/O: {0}")]
    Io(#[from] std::io::Error),
}

/// LAWICEL status flags (`F` reply): transmit FIFO full, error passive, bus error.
const SLCAN_TX_FULL: u8 = 0x02;
const SLCAN_ERROR_PASSIVE: u8 = 0x20;
const SLCAN_BUS_ERROR: u8 = 0x80;

/// What an SLCAN adapter's line means to the gateway: a frame, a garbled line, or nothing
/// (transmit acks and OKs carry nothing for the caller).
pub fn slcan_event(line: Result<Response, StreamError<slcan::SlcanError>>) -> Option<CanEvent> {
    match line {
        Ok(Response::Frame { frame, .. }) => Some(CanEvent::Frame(frame)),
        Ok(Response::Error) => Some(CanEvent::TransmitRefused),
        Ok(Response::StatusFlags(f)) => Some(CanEvent::AdapterStatus {
            bus_off: f & (SLCAN_BUS_ERROR | SLCAN_TX_FULL) == SLCAN_BUS_ERROR | SLCAN_TX_FULL,
            error_passive: f & SLCAN_ERROR_PASSIVE != 0,
        }),
        Ok(_) => None,
        Err(StreamError::Frame { .. } | StreamError::Overlong { .. }) => Some(CanEvent::Garbled),
    }
}

/// SocketCAN's error class bit for bus-off (linux/can/error.h, CAN_ERR_BUSOFF).
const CAN_ERR_BUSOFF: u32 = 0x0000_0040;

/// A CAN bus: send a frame, receive the next event. A closed set of backends, dispatched
/// by `match` so the per-cycle send and receive neither box a future nor allocate.
#[derive(Debug)]
pub enum CanLink {
    SocketCan(SocketCanLink),
    Slcan(SlcanLink),
    #[cfg(feature = "lab")]
    Memory(MemoryLink),
}

impl CanLink {
    /// Queue a frame for the bus. Returns once the kernel has it; it does not wait for the
    /// bytes to leave the wire (no `tcdrain`), which would stall the loop for the wire time.
    pub async fn send(&mut self, frame: CanFrame) -> Result<(), CanError> {
        match self {
            Self::SocketCan(l) => l.send(frame).await,
            Self::Slcan(l) => l.send(frame).await,
            #[cfg(feature = "lab")]
            Self::Memory(l) => l.send(frame),
        }
    }

    /// Ask the link for its controller's state. SLCAN answers with its status flags (an
    /// `AdapterStatus` event); SocketCAN reports state changes as error frames unasked.
    pub async fn poll_status(&mut self) -> Result<(), CanError> {
        match self {
            Self::Slcan(l) => l.write(&Command::StatusFlags).await,
            Self::SocketCan(_) => Ok(()),
            #[cfg(feature = "lab")]
            Self::Memory(_) => Ok(()),
        }
    }

    /// The next event. Cancel-safe: a dropped call loses nothing, so it can sit in `select!`.
    pub async fn recv(&mut self) -> Result<CanEvent, CanError> {
        match self {
            Self::SocketCan(l) => l.recv().await,
            Self::Slcan(l) => l.recv().await,
            #[cfg(feature = "lab")]
            Self::Memory(l) => l.recv().await,
        }
    }
}

/// Open the endpoint a URL names.
pub async fn open_can(url: &CanUrl) -> Result<CanLink, CanError> {
    Ok(match url {
        CanUrl::SocketCan { interface } => CanLink::SocketCan(SocketCanLink::open(interface)?),
        CanUrl::Slcan { path, bitrate, baud } => CanLink::Slcan(SlcanLink::open(path, *bitrate, *baud).await?),
        #[cfg(feature = "lab")]
        CanUrl::Memory => CanLink::Memory(MemoryBus::new().attach()),
    })
}

/// SocketCAN (`can0`, `vcan0`).
pub struct SocketCanLink {
    socket: socketcan::tokio::CanSocket,
    interface: String,
    /// The interface was reported down once: the next failure ends the link.
    reported_down: bool,
}

/// Whether a network interface is down or gone: its `IFF_UP` flag clear in sysfs, or no
/// such interface.
pub fn interface_down(interface: &str) -> bool {
    let flags = std::fs::read_to_string(format!("/sys/class/net/{interface}/flags"));
    match flags.ok().and_then(|f| u32::from_str_radix(f.trim().trim_start_matches("0x"), 16).ok()) {
        Some(flags) => flags & 1 == 0,
        None => true,
    }
}

impl SocketCanLink {
    pub fn open(interface: &str) -> Result<Self, CanError> {
        use socketcan::SocketOptions as _;
        let socket = socketcan::tokio::CanSocket::open(interface)
            .map_err(|source| CanError::SocketCan { interface: interface.to_string(), source })?;
        // Error frames (bus-off and the rest) are delivered only when asked for.
        socket
            .set_error_filter_accept_all()
            .map_err(|source| CanError::SocketCan { interface: interface.to_string(), source })?;
        Ok(Self { socket, interface: interface.to_string(), reported_down: false })
    }
}

impl std::fmt::Debug for SocketCanLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SocketCanLink")
    }
}

impl SocketCanLink {
    async fn send(&mut self, frame: CanFrame) -> Result<(), CanError> {
        Ok(self.socket.write_frame(frame.into()).await?)
    }
    async fn recv(&mut self) -> Result<CanEvent, CanError> {
        // A bus-off report or a failing socket may be the interface itself going away:
        // named as such, once; after that a failure ends the link (and it is reopened).
        let event = match self.socket.next().await {
            Some(Ok(f)) => match CanFrame::try_from(&f) {
                Ok(frame) => return Ok(CanEvent::Frame(frame)),
                Err(e) => Ok(CanEvent::ErrorFrame { bus_off: e.0 & CAN_ERR_BUSOFF != 0 }),
            },
            Some(Err(e)) => Err(CanError::Io(std::io::Error::other(e))),
            None => Err(CanError::Closed),
        };
        let suspect = !matches!(event, Ok(CanEvent::ErrorFrame { bus_off: false }));
        if suspect && !self.reported_down && interface_down(&self.interface) {
            self.reported_down = true;
            return Ok(CanEvent::InterfaceDown);
        }
        event
    }
}

/// An SLCAN (LAWICEL) USB-CAN adapter on a serial port. One owner of the port, no split
/// halves: reads and writes are never in flight together (the gateway's `select!` drops
/// the read before it writes), so no lock is needed.
pub struct SlcanLink {
    port: tokio_serial::SerialStream,
    rx: BytesMut,
    codec: SlcanHostCodec,
}

impl SlcanLink {
    /// Open the adapter, set the bitrate and open the channel.
    pub async fn open(path: &std::path::Path, bitrate: u32, baud: u32) -> Result<Self, CanError> {
        let port = super::open_serial(path, baud)?;
        let mut link = Self { port, rx: BytesMut::with_capacity(4096), codec: SlcanHostCodec::new() };
        let name = path.display().to_string();
        let bitrate = Bitrate::from_bps(bitrate).expect("checked when parsed");
        // Close first (an adapter left open refuses the bitrate); its answer does not matter.
        for (cmd, must_succeed) in
            [(Command::Close, false), (Command::SetBitrate(bitrate), true), (Command::Open, true)]
        {
            link.write(&cmd).await?;
            let answer = tokio::time::timeout(std::time::Duration::from_secs(1), async {
                loop {
                    match link.next_line().await? {
                        Ok(Response::Ok) => return Ok::<_, CanError>(true),
                        Ok(Response::Error) => return Ok(false),
                        _ => continue, // frames or noise before the answer
                    }
                }
            })
            .await
            .map_err(|_| CanError::SlcanSilent { path: name.clone() })??;
            if must_succeed && !answer {
                return Err(CanError::SlcanRefused { path: name, command: format!("{cmd:?}") });
            }
        }
        Ok(link)
    }

    async fn write(&mut self, command: &Command) -> Result<(), CanError> {
        let mut line = [0u8; slcan::MAX_LINE_LEN];
        let n = command.emit(&mut line).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        Ok(self.port.write_all(&line[..n]).await?)
    }

    /// The next line from the adapter, parsed or not. Cancel-safe: bytes land in `rx`
    /// only when a read completes.
    async fn next_line(&mut self) -> Result<Result<Response, StreamError<slcan::SlcanError>>, CanError> {
        loop {
            if let Some(line) = self.codec.decode(&mut self.rx)? {
                return Ok(line);
            }
            if self.port.read_buf(&mut self.rx).await? == 0 {
                return Err(CanError::Closed);
            }
        }
    }

    async fn send(&mut self, frame: CanFrame) -> Result<(), CanError> {
        self.write(&Command::Transmit(frame)).await
    }

    async fn recv(&mut self) -> Result<CanEvent, CanError> {
        loop {
            if let Some(event) = slcan_event(self.next_line().await?) {
                return Ok(event);
            }
        }
    }
}

impl std::fmt::Debug for SlcanLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SlcanLink")
    }
}
