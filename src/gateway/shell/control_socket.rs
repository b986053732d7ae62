//! The control socket: a unix socket (mode 0660: its owner and group only) where
//! `flowgate ctl` and other local tools send one JSON request per line and read one JSON
//! reply per line. It is the only way to command motion.
//!
//! Each connection is its own task, served at most once per [`MIN_INTERVAL`]; requests
//! reach the gateway loop through a small bounded queue, so a flood of requests waits on its
//! own connection and never on the control loop.
//! Every request is answered: malformed, oversized and unknown ones with a clear error and no
//! effect.

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{mpsc, oneshot, Semaphore};

use crate::gateway::core::operator::{Request, Status};

/// Longest request line accepted, bytes.
pub const MAX_REQUEST: usize = 4096;
/// Connections served at once; more wait to be accepted.
const MAX_CLIENTS: usize = 8;
/// Requests queued for the loop; a client beyond this waits for room.
pub const QUEUE: usize = 16;
/// How long a client waits for the loop's answer.
pub const ANSWER_DEADLINE: Duration = Duration::from_secs(2);
/// The least time between two requests of one connection: operators and their scripts ask
/// at human rates, and a flooding client waits on its own connection (at most 100 requests
/// a second each, 800 in all), never taking the control loop's time.
pub const MIN_INTERVAL: Duration = Duration::from_millis(10);

/// Who asked: a process on the control socket (its peer credentials), or ROS 2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Peer {
    Socket { uid: u32, gid: u32, pid: Option<i32> },
    Ros2,
}

impl std::fmt::Display for Peer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Peer::Socket { uid, gid, pid } => {
                write!(f, "uid {uid} gid {gid}")?;
                if let Some(pid) = pid {
                    write!(f, " pid {pid}")?;
                }
                Ok(())
            }
            Peer::Ros2 => f.write_str("ROS 2"),
        }
    }
}

/// A request on its way to the loop, with where its answer goes.
#[derive(Debug)]
pub struct Command {
    pub request: Request,
    pub peer: Peer,
    pub reply: oneshot::Sender<Reply>,
}

/// One reply line.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Reply {
    pub ok: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub status: Option<Status>,
}

impl Reply {
    pub fn error(why: impl Into<String>) -> Self {
        Self { ok: false, error: Some(why.into()), status: None }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ControlSocketError {
    #[error(
        "control socket {path}: {source} (does its folder exist and may the gateway write there? `[operator] socket`)"
    )]
    Bind { path: String, source: std::io::Error },
    #[error("control socket {path}: {path} exists and is not a socket; refusing to replace it")]
    NotASocket { path: String },
    #[error("control socket group `{group}` is not in /etc/group (`[operator] group`)")]
    UnknownGroup { group: String },
    #[error("control socket {path}: cannot give it to group `{group}`: {source}")]
    Chown { path: String, group: String, source: std::io::Error },
}

/// The group id of `name`, from /etc/group.
fn group_id(name: &str) -> Option<u32> {
    let text = std::fs::read_to_string("/etc/group").ok()?;
    text.lines().find_map(|line| {
        let mut f = line.split(':');
        (f.next()? == name).then(|| f.nth(1)?.parse().ok()).flatten()
    })
}

/// A bound control socket; removed when dropped.
#[derive(Debug)]
pub struct ControlSocket {
    path: PathBuf,
    listener: Option<UnixListener>,
}

impl Drop for ControlSocket {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

impl ControlSocket {
    /// Bind `path` with mode 0660 (and `group`'s gid, if given). A stale socket from an
    /// earlier run is replaced; any other file there is refused.
    pub fn bind(path: &Path, group: Option<&str>) -> Result<Self, ControlSocketError> {
        let name = path.display().to_string();
        if let Ok(meta) = std::fs::symlink_metadata(path) {
            use std::os::unix::fs::FileTypeExt;
            if !meta.file_type().is_socket() {
                return Err(ControlSocketError::NotASocket { path: name });
            }
            let _ = std::fs::remove_file(path);
        }
        let listener =
            UnixListener::bind(path).map_err(|source| ControlSocketError::Bind { path: name.clone(), source })?;
        let socket = Self { path: path.to_path_buf(), listener: Some(listener) };
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))
            .map_err(|source| ControlSocketError::Bind { path: name.clone(), source })?;
        if let Some(group) = group {
            let gid = group_id(group).ok_or_else(|| ControlSocketError::UnknownGroup { group: group.into() })?;
            std::os::unix::fs::chown(path, None, Some(gid)).map_err(|source| ControlSocketError::Chown {
                path: name,
                group: group.into(),
                source,
            })?;
        }
        Ok(socket)
    }

    /// Serve connections, sending their requests to `loop_tx`. Runs until the loop's
    /// receiver is gone.
    pub async fn serve(mut self, loop_tx: mpsc::Sender<Command>) {
        let Some(listener) = self.listener.take() else { return };
        let slots = Arc::new(Semaphore::new(MAX_CLIENTS));
        loop {
            let Ok(permit) = slots.clone().acquire_owned().await else { return };
            let Ok((stream, _)) = listener.accept().await else { continue };
            let tx = loop_tx.clone();
            if tx.is_closed() {
                return;
            }
            tokio::spawn(async move {
                let _permit = permit;
                let _ = connection(stream, tx).await;
            });
        }
    }
}

/// One client: lines in, replies out, until it hangs up.
async fn connection(stream: UnixStream, tx: mpsc::Sender<Command>) -> std::io::Result<()> {
    let peer = stream.peer_cred().map(|c| Peer::Socket { uid: c.uid(), gid: c.gid(), pid: c.pid() })?;
    let (read, mut write) = stream.into_split();
    let mut read = BufReader::new(read);
    let mut line = Vec::with_capacity(256);
    let mut next = tokio::time::Instant::now();
    loop {
        line.clear();
        tokio::time::sleep_until(next).await;
        next = tokio::time::Instant::now() + MIN_INTERVAL;
        // Read at most one byte past the limit: enough to know the line is too long.
        let n = (&mut read).take(MAX_REQUEST as u64 + 1).read_until(b'\n', &mut line).await?;
        if n == 0 {
            return Ok(());
        }
        let reply = if line.len() > MAX_REQUEST {
            // Skip the rest of the oversized line before answering.
            let mut rest = Vec::new();
            if !line.ends_with(b"\n") {
                read.read_until(b'\n', &mut rest).await?;
            }
            Reply::error(format!("request longer than {MAX_REQUEST} bytes: ignored"))
        } else {
            match serde_json::from_slice::<Request>(&line) {
                Err(e) => Reply::error(format!("malformed request: {e}")),
                Ok(request) => ask(&tx, request, peer).await,
            }
        };
        let mut text = serde_json::to_string(&reply).unwrap_or_else(|_| "{\"ok\":false}".into());
        text.push('\n');
        write.write_all(text.as_bytes()).await?;
    }
}

async fn ask(tx: &mpsc::Sender<Command>, request: Request, peer: Peer) -> Reply {
    let (reply, answer) = oneshot::channel();
    if tx.send(Command { request, peer, reply }).await.is_err() {
        return Reply::error("the gateway is shutting down");
    }
    match tokio::time::timeout(ANSWER_DEADLINE, answer).await {
        Ok(Ok(reply)) => reply,
        _ => Reply::error("the gateway did not answer in time"),
    }
}
