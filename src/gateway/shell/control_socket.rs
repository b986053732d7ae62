//! The control socket: a unix socket (mode 0660: its owner and group only) where
//! `flowgate ctl` and other local tools send one JSON request per line and read one JSON
//! reply per line. It is the only way to command motion.
//!
//! Nobody on it can deny the operator's stop:
//! - every connection is accepted at once. At most [`MAX_CLIENTS`] are held; a new one
//!   beyond that closes the one idle longest, so held connections never keep out the next;
//! - a connection that sends nothing for [`IDLE_TIMEOUT`], or leaves a line unfinished (or a
//!   reply unread) for [`LINE_DEADLINE`], is closed;
//! - each connection is served at most once per [`MIN_INTERVAL`], so a flood waits on its own
//!   connection; requests reach the loop through a bounded queue, and `stop` and `estop`
//!   through one of their own ([`RequestSender`]), so no queue of other requests delays them;
//! - every request carries its deadline ([`ANSWER_DEADLINE`] from its arrival): one the loop
//!   takes after its client was told it failed is dropped and counted, never carried out
//!   late. `stop` and `estop` are obeyed whenever they arrive.
//!
//! Every request is answered: malformed, oversized and unknown ones with a clear error and no
//! effect.

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde::Serialize;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{mpsc, oneshot};
use tokio::task::AbortHandle;
use tokio::time::{timeout, timeout_at, Instant};

use crate::gateway::core::operator::{non_finite_as_null, Reply, Request};

/// Longest request line accepted, bytes.
pub const MAX_REQUEST: usize = 4096;
/// Connections held at once; a new one beyond this closes the one idle longest.
pub const MAX_CLIENTS: usize = 8;
/// Connections held however busy the others are: beyond [`MAX_CLIENTS`] only while every
/// held one waits on the loop's answer (bounded by [`ANSWER_DEADLINE`]); a connection beyond
/// this is told so and closed.
pub const MAX_CONNECTIONS: usize = 4 * MAX_CLIENTS;
/// Requests queued for the loop; a client beyond this waits for room (within its deadline).
pub const QUEUE: usize = 16;
/// `stop` and `estop` queued for the loop, apart from the rest.
const URGENT_QUEUE: usize = 16;
/// How long a request may take from its arrival to the loop's answer; past it the client is
/// told the request failed, and the loop drops it unless it is `stop` or `estop`.
pub const ANSWER_DEADLINE: Duration = Duration::from_secs(2);
/// A connection that sends nothing for this long is closed.
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a request line may take once its first byte arrived, and a reply to be taken.
pub const LINE_DEADLINE: Duration = Duration::from_secs(1);
/// The least time between two requests of one connection: operators and their scripts ask
/// at human rates, and a flooding client waits on its own connection (at most 100 requests
/// a second each), never taking the control loop's time.
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

/// A request on its way to the loop, with where its answer goes and until when its client
/// waits for it.
#[derive(Debug)]
pub struct Command {
    pub request: Request,
    /// The vehicle it is for, by name (`None`: as the core takes a request without one).
    pub vehicle: Option<String>,
    pub peer: Peer,
    pub deadline: Instant,
    pub reply: oneshot::Sender<Reply>,
}

impl Command {
    /// Its client was told it failed: the loop must not carry it out (`stop` and `estop`
    /// excepted, which are obeyed whenever they arrive).
    pub fn expired(&self, now: Instant) -> bool {
        now > self.deadline && !self.request.always_obeyed()
    }
}

/// Where requests go: the control socket, ROS 2 and tests ask through it alike.
#[derive(Debug, Clone)]
pub struct RequestSender {
    queue: mpsc::Sender<Command>,
    urgent: mpsc::Sender<Command>,
}

/// The loop's end of [`RequestSender`].
#[derive(Debug)]
pub struct RequestReceiver {
    queue: mpsc::Receiver<Command>,
    urgent: mpsc::Receiver<Command>,
}

/// A request channel: [`QUEUE`] requests deep, and `stop` and `estop` apart.
pub fn request_channel() -> (RequestSender, RequestReceiver) {
    let (queue_tx, queue) = mpsc::channel(QUEUE);
    let (urgent_tx, urgent) = mpsc::channel(URGENT_QUEUE);
    (RequestSender { queue: queue_tx, urgent: urgent_tx }, RequestReceiver { queue, urgent })
}

impl RequestReceiver {
    /// The next request, `stop` and `estop` first. Cancel-safe. `None` once every sender is
    /// gone.
    pub async fn recv(&mut self) -> Option<Command> {
        tokio::select! {
            biased;
            Some(urgent) = self.urgent.recv() => Some(urgent),
            queued = self.queue.recv() => queued,
        }
    }
}

impl RequestSender {
    /// Ask the loop and wait for its answer, within [`ANSWER_DEADLINE`] of now. A request
    /// not answered by then is reported failed and will not be carried out later (`stop`
    /// and `estop` excepted: they are obeyed whenever the loop takes them).
    pub async fn ask(&self, request: Request, peer: Peer) -> Reply {
        self.ask_for(None, request, peer).await
    }

    /// The same for one vehicle, by name (`None`: as [`RequestSender::ask`]).
    pub async fn ask_for(&self, vehicle: Option<String>, request: Request, peer: Peer) -> Reply {
        let deadline = Instant::now() + ANSWER_DEADLINE;
        let urgent = request.always_obeyed();
        let (reply, answer) = oneshot::channel();
        let command = Command { request, vehicle, peer, deadline, reply };
        let queue = if urgent { &self.urgent } else { &self.queue };
        let late = |what: &str| {
            let secs = ANSWER_DEADLINE.as_secs_f64();
            if urgent {
                Reply::error(format!(
                    "the gateway {what} within {secs} s: it is obeyed as soon as the gateway takes it; check `status`"
                ))
            } else {
                Reply::error(format!("the gateway {what} within {secs} s: the request expired and was not carried out"))
            }
        };
        match timeout_at(deadline, queue.send(command)).await {
            Ok(Ok(())) => {}
            Ok(Err(_)) => return Reply::error("the gateway is shutting down: the request was not carried out"),
            Err(_) => return late("did not take the request"),
        }
        match timeout_at(deadline, answer).await {
            Ok(Ok(reply)) => reply,
            Ok(Err(_)) => Reply::error("the gateway is shutting down: the request was not carried out"),
            Err(_) => late("did not answer"),
        }
    }

    /// Whether the loop is gone.
    pub fn is_closed(&self) -> bool {
        self.queue.is_closed()
    }
}

/// A request line, and the vehicle it names (`"vehicle": "NAME"` beside `cmd`). A command
/// (`drive`, `wheels`) may carry Python's `NaN`, `Infinity` or `-Infinity`, which JSON has
/// no words for: read as not finite, so that it stops the robot by its name rather than going
/// unread as malformed.
fn parse_request(line: &[u8]) -> Result<(Option<String>, Request), serde_json::Error> {
    let text = std::str::from_utf8(line).ok();
    // First a request that names its vehicle: a request without fields would take the
    // name as a field it ignores.
    if let Some(addressed) = text.and_then(addressed) {
        return addressed;
    }
    let error = match serde_json::from_slice::<Request>(line) {
        Ok(request) => return Ok((None, request)),
        Err(e) => e,
    };
    let Some(lenient) = text.and_then(non_finite_as_null) else { return Err(error) };
    let parsed = addressed(&lenient).unwrap_or_else(|| serde_json::from_str::<Request>(&lenient).map(|r| (None, r)));
    match parsed {
        Ok((vehicle, request)) if request.is_command() => Ok((vehicle, request)),
        _ => Err(error),
    }
}

/// A request object that names its vehicle: the name, and the request without it (`None`:
/// not an object naming one).
fn addressed(text: &str) -> Option<Result<(Option<String>, Request), serde_json::Error>> {
    let serde_json::Value::Object(mut fields) = serde_json::from_str::<serde_json::Value>(text).ok()? else {
        return None;
    };
    let vehicle = match fields.remove("vehicle")? {
        serde_json::Value::String(name) => name,
        _ => return Some(Err(serde::de::Error::custom("`vehicle` must be a vehicle's name"))),
    };
    Some(serde_json::from_value(serde_json::Value::Object(fields)).map(|request| (Some(vehicle), request)))
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
}

/// What the socket did to its clients, for the report and the metrics.
#[derive(Debug, Default)]
pub struct ClientCounts {
    /// Connections accepted.
    pub accepted: AtomicU64,
    /// Closed to make room for a new one (the one idle longest).
    pub evicted: AtomicU64,
    /// Closed for silence ([`IDLE_TIMEOUT`]) or a line or reply left unfinished
    /// ([`LINE_DEADLINE`]).
    pub timed_out: AtomicU64,
    /// Refused: [`MAX_CONNECTIONS`] held, every one waiting on the loop.
    pub refused: AtomicU64,
}

/// The connections held, each with when it was last active and whether it waits on the
/// loop (and so may not be closed to make room).
#[derive(Debug, Default)]
struct Clients {
    next_id: u64,
    held: Vec<Client>,
}

#[derive(Debug)]
struct Client {
    id: u64,
    active_at: Instant,
    waiting_on_loop: bool,
    task: Option<AbortHandle>,
}

/// What to do with a new connection.
enum Admission {
    Admit(u64),
    Refuse,
}

impl Clients {
    /// Make room for a new connection: beyond [`MAX_CLIENTS`], close the one idle longest
    /// (none waiting on the loop); beyond [`MAX_CONNECTIONS`], refuse it.
    fn admit(&mut self, now: Instant, counts: &ClientCounts) -> Admission {
        if self.held.len() >= MAX_CLIENTS {
            let idlest =
                self.held.iter().enumerate().filter(|(_, c)| !c.waiting_on_loop).min_by_key(|(_, c)| c.active_at);
            if let Some((at, _)) = idlest {
                let evicted = self.held.swap_remove(at);
                if let Some(task) = evicted.task {
                    task.abort();
                }
                counts.evicted.fetch_add(1, Ordering::Relaxed);
            }
        }
        if self.held.len() >= MAX_CONNECTIONS {
            counts.refused.fetch_add(1, Ordering::Relaxed);
            return Admission::Refuse;
        }
        self.next_id += 1;
        self.held.push(Client { id: self.next_id, active_at: now, waiting_on_loop: false, task: None });
        counts.accepted.fetch_add(1, Ordering::Relaxed);
        Admission::Admit(self.next_id)
    }

    fn get(&mut self, id: u64) -> Option<&mut Client> {
        self.held.iter_mut().find(|c| c.id == id)
    }

    fn leave(&mut self, id: u64) {
        self.held.retain(|c| c.id != id);
    }
}

/// A connection's place among [`Clients`]; it leaves when dropped (the task ended or was
/// aborted).
struct Seat {
    id: u64,
    clients: Arc<Mutex<Clients>>,
}

impl Seat {
    fn set(&self, waiting_on_loop: bool) {
        let mut clients = self.clients.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(c) = clients.get(self.id) {
            c.waiting_on_loop = waiting_on_loop;
            c.active_at = Instant::now();
        }
    }
}

impl Drop for Seat {
    fn drop(&mut self) {
        self.clients.lock().unwrap_or_else(std::sync::PoisonError::into_inner).leave(self.id);
    }
}

impl ControlSocket {
    /// Serve connections, sending their requests to `loop_tx`, until the loop is gone.
    pub async fn serve(mut self, loop_tx: RequestSender, counts: Arc<ClientCounts>) {
        let Some(listener) = self.listener.take() else { return };
        let clients = Arc::new(Mutex::new(Clients::default()));
        loop {
            let stream = match listener.accept().await {
                Ok((stream, _)) => stream,
                Err(e) => {
                    // Out of descriptors or memory: wait a little rather than spin.
                    tracing::warn!("control socket: accepting a connection: {e}");
                    tokio::time::sleep(MIN_INTERVAL).await;
                    continue;
                }
            };
            if loop_tx.is_closed() {
                return;
            }
            let admission =
                clients.lock().unwrap_or_else(std::sync::PoisonError::into_inner).admit(Instant::now(), &counts);
            let Admission::Admit(id) = admission else {
                tokio::spawn(refuse(stream));
                continue;
            };
            let seat = Seat { id, clients: clients.clone() };
            let task = tokio::spawn(connection(stream, loop_tx.clone(), seat, counts.clone()));
            if let Some(c) = clients.lock().unwrap_or_else(std::sync::PoisonError::into_inner).get(id) {
                c.task = Some(task.abort_handle());
            }
        }
    }
}

/// Tell a connection beyond [`MAX_CONNECTIONS`] why it is closed.
async fn refuse(mut stream: UnixStream) {
    let reply =
        Reply::error(format!("{MAX_CONNECTIONS} connections held, every one waiting on the gateway: try again"));
    let mut text = serde_json::to_string(&reply).unwrap_or_else(|_| "{\"ok\":false}".into());
    text.push('\n');
    let _ = timeout(LINE_DEADLINE, stream.write_all(text.as_bytes())).await;
}

/// Why a connection ended.
enum Ending {
    /// The client hung up.
    HungUp,
    /// Silent for [`IDLE_TIMEOUT`], or a line or reply unfinished for [`LINE_DEADLINE`].
    TimedOut,
    Io,
}

/// One client: lines in, replies out, until it hangs up, falls silent or stalls.
async fn connection(stream: UnixStream, tx: RequestSender, seat: Seat, counts: Arc<ClientCounts>) {
    if let Ending::TimedOut = serve_lines(stream, &tx, &seat).await {
        counts.timed_out.fetch_add(1, Ordering::Relaxed);
    }
}

async fn serve_lines(stream: UnixStream, tx: &RequestSender, seat: &Seat) -> Ending {
    let Ok(cred) = stream.peer_cred() else { return Ending::Io };
    let peer = Peer::Socket { uid: cred.uid(), gid: cred.gid(), pid: cred.pid() };
    let (read, mut write) = stream.into_split();
    let mut read = BufReader::new(read);
    let mut line = Vec::with_capacity(256);
    let mut next = Instant::now();
    loop {
        line.clear();
        tokio::time::sleep_until(next).await;
        next = Instant::now() + MIN_INTERVAL;
        // The first byte within the idle timeout, the rest of the line within its deadline.
        match timeout(IDLE_TIMEOUT, read.fill_buf()).await {
            Err(_) => return Ending::TimedOut,
            Ok(Err(_)) => return Ending::Io,
            Ok(Ok([])) => return Ending::HungUp,
            Ok(Ok(_)) => {}
        }
        let line_deadline = Instant::now() + LINE_DEADLINE;
        // Read at most one byte past the limit: enough to know the line is too long.
        let mut limited = (&mut read).take(MAX_REQUEST as u64 + 1);
        match timeout_at(line_deadline, limited.read_until(b'\n', &mut line)).await {
            Err(_) => return Ending::TimedOut,
            Ok(Err(_)) => return Ending::Io,
            Ok(Ok(_)) => {}
        }
        let reply = if line.len() > MAX_REQUEST {
            // Skip the rest of the oversized line before answering.
            if !line.ends_with(b"\n") {
                if let Err(ending) = skip_line(&mut read, line_deadline).await {
                    return ending;
                }
            }
            Reply::error(format!("request longer than {MAX_REQUEST} bytes: ignored"))
        } else if !line.ends_with(b"\n") {
            // The client hung up mid-line: nothing to answer.
            return Ending::HungUp;
        } else {
            match parse_request(&line) {
                Err(e) => Reply::error(format!("malformed request: {e}")),
                Ok((vehicle, request)) => {
                    seat.set(true);
                    let reply = tx.ask_for(vehicle, request, peer).await;
                    seat.set(false);
                    reply
                }
            }
        };
        let mut text = serde_json::to_string(&reply).unwrap_or_else(|_| "{\"ok\":false}".into());
        text.push('\n');
        match timeout(LINE_DEADLINE, write.write_all(text.as_bytes())).await {
            Err(_) => return Ending::TimedOut,
            Ok(Err(_)) => return Ending::Io,
            Ok(Ok(())) => {}
        }
    }
}

/// Read and drop the rest of an oversized line, in bounded pieces, by `deadline`.
async fn skip_line(read: &mut BufReader<tokio::net::unix::OwnedReadHalf>, deadline: Instant) -> Result<(), Ending> {
    loop {
        let step = async {
            let buf = read.fill_buf().await?;
            if buf.is_empty() {
                return Ok(true);
            }
            let (n, done) = match buf.iter().position(|&b| b == b'\n') {
                Some(at) => (at + 1, true),
                None => (buf.len(), false),
            };
            read.consume(n);
            Ok::<bool, std::io::Error>(done)
        };
        match timeout_at(deadline, step).await {
            Err(_) => return Err(Ending::TimedOut),
            Ok(Err(_)) => return Err(Ending::Io),
            Ok(Ok(true)) => return Ok(()),
            Ok(Ok(false)) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::AsyncBufReadExt;

    /// A socket in a new folder, served, with a loop that answers `status` with `ok`.
    async fn served(name: &str) -> (PathBuf, Arc<ClientCounts>) {
        let dir = std::env::temp_dir().join(format!("flowgate-cs-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("control.sock");
        let socket = ControlSocket::bind(&path, None).unwrap();
        let (tx, mut rx) = request_channel();
        let counts = Arc::new(ClientCounts::default());
        tokio::spawn(socket.serve(tx, counts.clone()));
        tokio::spawn(async move {
            while let Some(cmd) = rx.recv().await {
                let _ = cmd.reply.send(Reply { ok: true, error: None, status: None });
            }
        });
        (path, counts)
    }

    async fn status(stream: &mut UnixStream) -> std::io::Result<String> {
        stream.write_all(b"{\"cmd\":\"status\"}\n").await?;
        let mut line = String::new();
        BufReader::new(stream).read_line(&mut line).await?;
        Ok(line)
    }

    /// A request names its vehicle beside `cmd`, whatever else it carries (a request with
    /// no fields of its own would otherwise read the name as a field it ignores); without
    /// one it is as before; a name that is not text is refused.
    #[test]
    fn a_request_names_its_vehicle() {
        let parse = |line: &str| parse_request(line.as_bytes());
        assert_eq!(parse(r#"{"cmd":"arm","vehicle":"v2"}"#).unwrap(), (Some("v2".into()), Request::Arm));
        assert_eq!(parse(r#"{"cmd":"arm"}"#).unwrap(), (None, Request::Arm));
        let (vehicle, request) = parse(r#"{"vehicle":"a","cmd":"drive","v":NaN,"w":0}"#).unwrap();
        assert_eq!(vehicle.as_deref(), Some("a"));
        assert!(matches!(request, Request::Drive { v, .. } if v.is_nan()), "{request:?}");
        assert!(parse(r#"{"cmd":"arm","vehicle":2}"#).unwrap_err().to_string().contains("a vehicle's name"));
        assert!(parse(r#"{"cmd":"goal","vehicle":"a"}"#).is_err(), "a goal without goals");
    }

    #[tokio::test]
    async fn a_new_connection_closes_the_one_idle_longest_beyond_the_cap() {
        let (path, counts) = served("evict").await;
        let mut held = Vec::new();
        for _ in 0..MAX_CLIENTS {
            let mut s = UnixStream::connect(&path).await.unwrap();
            // Each answered once, so each is held and idle from then on, the first idlest.
            assert_eq!(status(&mut s).await.unwrap(), "{\"ok\":true}\n");
            held.push(s);
        }
        let mut late = UnixStream::connect(&path).await.unwrap();
        assert_eq!(status(&mut late).await.unwrap(), "{\"ok\":true}\n");
        // The first, idle longest, was closed for it; the rest still answer.
        let mut rest = Vec::new();
        assert_eq!(held[0].read_to_end(&mut rest).await.unwrap(), 0);
        assert_eq!(status(&mut held[1]).await.unwrap(), "{\"ok\":true}\n");
        assert_eq!(counts.evicted.load(Ordering::Relaxed), 1);
    }

    #[tokio::test(start_paused = true)]
    async fn silent_and_half_open_connections_time_out() {
        let (path, counts) = served("idle").await;
        let mut silent = UnixStream::connect(&path).await.unwrap();
        let mut half = UnixStream::connect(&path).await.unwrap();
        half.write_all(b"{\"cmd\":").await.unwrap();
        let started = Instant::now();
        let mut rest = Vec::new();
        assert_eq!(half.read_to_end(&mut rest).await.unwrap(), 0);
        let half_open_for = started.elapsed();
        assert_eq!(silent.read_to_end(&mut rest).await.unwrap(), 0);
        let silent_for = started.elapsed();
        assert!(half_open_for >= LINE_DEADLINE && half_open_for < IDLE_TIMEOUT, "{half_open_for:?}");
        assert!(silent_for >= IDLE_TIMEOUT && silent_for < IDLE_TIMEOUT + LINE_DEADLINE, "{silent_for:?}");
        assert_eq!(counts.timed_out.load(Ordering::Relaxed), 2);
    }

    #[tokio::test(start_paused = true)]
    async fn a_request_whose_client_gave_up_is_dropped_but_a_stop_is_not() {
        let (tx, mut rx) = request_channel();
        let peer = Peer::Socket { uid: 0, gid: 0, pid: None };
        // Nobody takes requests: the client is told the reset failed, after its deadline.
        let reply = tx.ask(Request::Reset, peer).await;
        assert!(!reply.ok);
        assert_eq!(
            reply.error.as_deref(),
            Some("the gateway did not answer within 2 s: the request expired and was not carried out")
        );
        let estop = tokio::spawn({
            let tx = tx.clone();
            async move { tx.ask(Request::EStop, peer).await }
        });
        tokio::time::sleep(ANSWER_DEADLINE * 2).await;
        assert!(!estop.await.unwrap().ok);
        // The loop, back at last, takes the estop first, and only the estop may be carried out.
        let first = rx.recv().await.unwrap();
        assert_eq!(first.request, Request::EStop);
        assert!(!first.expired(Instant::now()));
        let second = rx.recv().await.unwrap();
        assert_eq!(second.request, Request::Reset);
        assert!(second.expired(Instant::now()));
    }

    #[tokio::test]
    async fn stop_and_estop_pass_a_full_queue() {
        let (tx, mut rx) = request_channel();
        let peer = Peer::Ros2;
        let mut waiting = Vec::new();
        for _ in 0..QUEUE + 4 {
            let tx = tx.clone();
            waiting.push(tokio::spawn(async move { tx.ask(Request::Status, peer).await }));
        }
        tokio::task::yield_now().await;
        let estop = tokio::spawn({
            let tx = tx.clone();
            async move { tx.ask(Request::EStop, peer).await }
        });
        // Wait until the estop is queued, then take: it comes before every status.
        while rx.urgent.is_empty() {
            tokio::task::yield_now().await;
        }
        let first = rx.recv().await.unwrap();
        assert_eq!(first.request, Request::EStop);
        first.reply.send(Reply { ok: true, error: None, status: None }).unwrap();
        assert!(estop.await.unwrap().ok);
    }
}
