//! The client of the control socket: one request line out, one [`Reply`] back, each way it
//! can fail said in words. `flowgate ctl`, the benchmark and the tests all speak to a
//! gateway through it.
//!
//! ```no_run
//! use flowgate::gateway::shell::control_client::ControlClient;
//! use flowgate::gateway::core::operator::{Request, StateName};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let mut gateway = ControlClient::connect("/run/flowgate/control.sock".as_ref())?;
//! gateway.request(&Request::Arm)?;
//! let status = gateway.status()?;
//! assert_eq!(status.state.name, StateName::Armed);
//! # Ok(()) }
//! ```

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::gateway::core::operator::{Reply, Request, Status};

/// How long a client waits for a reply: longer than the gateway's own deadline for
/// answering a request it has taken (`control_socket::ANSWER_DEADLINE`).
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(5);

/// Why a request got no answer, or a refusal.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("control socket {path}: {source} (is the gateway running? may you use it?)")]
    Connect { path: PathBuf, source: std::io::Error },
    #[error("sending the request to {path}: {source}")]
    Send { path: PathBuf, source: std::io::Error },
    #[error(
        "the gateway closed the connection without answering (shutting down, or it closed this connection to \
         make room for another): check with `flowgate ctl status`"
    )]
    Closed,
    #[error("no reply within {} s: the gateway is stalled or gone ({fate}); check with `flowgate ctl status`", .after.as_secs())]
    NoReply { after: Duration, fate: &'static str },
    #[error("reading the gateway's reply: {0}")]
    Read(std::io::Error),
    #[error("the gateway's reply is not one: {error}: {line}")]
    Malformed { line: String, error: serde_json::Error },
    #[error("refused: {0}")]
    Refused(String),
    #[error("the gateway answered `{0}` without its status")]
    NoStatus(&'static str),
}

/// One connection to a gateway's control socket.
#[derive(Debug)]
pub struct ControlClient {
    path: PathBuf,
    stream: BufReader<UnixStream>,
    timeout: Duration,
}

impl ControlClient {
    /// Connect, waiting at most [`REPLY_TIMEOUT`] for each reply.
    pub fn connect(path: &Path) -> Result<Self, ClientError> {
        Self::connect_with(path, REPLY_TIMEOUT)
    }

    pub fn connect_with(path: &Path, timeout: Duration) -> Result<Self, ClientError> {
        let connect = |source| ClientError::Connect { path: path.to_owned(), source };
        let stream = UnixStream::connect(path).map_err(connect)?;
        stream.set_read_timeout(Some(timeout)).map_err(connect)?;
        stream.set_write_timeout(Some(timeout)).map_err(connect)?;
        Ok(Self { path: path.to_owned(), stream: BufReader::new(stream), timeout })
    }

    /// Send `request`; its reply, refused or not.
    pub fn ask(&mut self, request: &Request) -> Result<Reply, ClientError> {
        self.ask_for(None, request)
    }

    /// Send `request` for `vehicle` (by name; `None`: as [`ControlClient::ask`]).
    pub fn ask_for(&mut self, vehicle: Option<&str>, request: &Request) -> Result<Reply, ClientError> {
        let mut line = match vehicle {
            None => serde_json::to_string(request).expect("a request serialises"),
            Some(name) => {
                let mut message = serde_json::to_value(request).expect("a request serialises");
                if let serde_json::Value::Object(fields) = &mut message {
                    fields.insert("vehicle".into(), name.into());
                }
                message.to_string()
            }
        };
        line.push('\n');
        let sent = self.stream.get_mut().write_all(line.as_bytes());
        sent.map_err(|source| ClientError::Send { path: self.path.clone(), source })?;
        let mut reply = String::new();
        match self.stream.read_line(&mut reply) {
            Ok(0) => Err(ClientError::Closed),
            Ok(_) => serde_json::from_str(&reply)
                .map_err(|error| ClientError::Malformed { line: reply.trim_end().to_owned(), error }),
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {
                let fate = if request.always_obeyed() {
                    "a stop is obeyed whenever the gateway takes it"
                } else {
                    "the request expires unanswered and is not carried out"
                };
                Err(ClientError::NoReply { after: self.timeout, fate })
            }
            Err(e) => Err(ClientError::Read(e)),
        }
    }

    /// Send `request`; a refusal is an error.
    pub fn request(&mut self, request: &Request) -> Result<Reply, ClientError> {
        let reply = self.ask(request)?;
        if reply.ok {
            Ok(reply)
        } else {
            Err(ClientError::Refused(reply.error.unwrap_or_else(|| "(no reason given)".into())))
        }
    }

    /// The gateway's status now.
    pub fn status(&mut self) -> Result<Status, ClientError> {
        self.request(&Request::Status)?.status.ok_or(ClientError::NoStatus("status"))
    }

    /// The status with the stages' statistics since the last window; with `reset`, a new
    /// window starts after this answer.
    pub fn stats(&mut self, reset: bool) -> Result<Status, ClientError> {
        self.request(&Request::Stats { reset })?.status.ok_or(ClientError::NoStatus("stats"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gateway::core::operator::StateName;
    use crate::gateway::core::{State, StopReason};
    use std::os::unix::net::UnixListener;

    /// A gateway that answers each line with the next of `replies`, then takes one more
    /// and closes without answering it.
    fn gateway(name: &str, replies: Vec<String>) -> PathBuf {
        let path = std::env::temp_dir().join(format!("flowgate-client-{name}-{}.sock", std::process::id()));
        let _ = std::fs::remove_file(&path);
        let listener = UnixListener::bind(&path).unwrap();
        std::thread::spawn(move || {
            let (stream, _) = listener.accept().unwrap();
            let mut stream = BufReader::new(stream);
            for reply in replies {
                let mut line = String::new();
                stream.read_line(&mut line).unwrap();
                stream.get_mut().write_all(reply.as_bytes()).unwrap();
            }
            let _ = stream.read_line(&mut String::new());
        });
        path
    }

    #[test]
    fn a_status_reads_back_as_it_was_sent() {
        let state = State::Fault(StopReason::HeartbeatLost { node: 2 });
        let status = Status {
            state: state.into(),
            last_stop: Some(StopReason::HeartbeatLost { node: 2 }.to_string()),
            goals: vec![],
            pose: Some([0.1, -0.2, 1.5]),
            obstacles: vec![],
            absent: vec![3],
            cycles: 7,
            latency_us: None,
            stages: None,
            vehicles: vec![],
        };
        let line = serde_json::to_string(&Reply { ok: true, error: None, status: Some(status.clone()) }).unwrap();
        assert!(line.contains(&format!("\"state\":\"{state}\"")), "the wire keeps the state's text: {line}");
        let path = gateway("status", vec![line + "\n"]);
        let read = ControlClient::connect(&path).unwrap().status().unwrap();
        assert_eq!(read, status);
        assert_eq!(read.state.name, StateName::Fault);
        assert!(read.state.is_terminal());
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn a_refusal_a_close_and_garbage_are_errors_in_words() {
        let refusal = serde_json::to_string(&Reply::error("not armed (state idle): arm first")).unwrap() + "\n";
        let path = gateway("refused", vec![refusal, "{\"ok\":tru\n".into()]);
        let mut client = ControlClient::connect(&path).unwrap();
        let refused = client.request(&Request::Start).unwrap_err();
        assert_eq!(refused.to_string(), "refused: not armed (state idle): arm first");
        assert!(matches!(client.ask(&Request::Status), Err(ClientError::Malformed { .. })));
        assert!(matches!(client.ask(&Request::Status), Err(ClientError::Closed)));
        let _ = std::fs::remove_file(&path);
        assert!(ControlClient::connect(&path).unwrap_err().to_string().contains("is the gateway running?"));
    }
}
