//! Just enough HTTP/1.1 for the gateway's read-only pages (`/metrics`, the live view): one
//! GET per connection, a bounded request head parsed by `httparse` (hyper's parser), every
//! step under the caller's deadline. A whole HTTP stack would bring routing, keep-alive and
//! bodies that two read-only pages never use; the head is the only untrusted input.

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// The longest request head read.
const MAX_HEAD: usize = 8192;

/// What a client asked for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Asked {
    /// `GET path` (the query string cut off).
    Get(String),
    /// Another method: answered 405.
    Other,
}

/// Headers read at most (more: the request is refused as malformed).
const MAX_HEADERS: usize = 32;

/// Read a request head. `None`: the client closed, sent more than `MAX_HEAD` bytes before
/// its end, or sent something that is not an HTTP/1.x request head.
pub async fn read_request(stream: &mut TcpStream) -> std::io::Result<Option<Asked>> {
    let mut head = Vec::with_capacity(512);
    let mut buf = [0u8; 512];
    loop {
        let n = stream.read(&mut buf).await?;
        if n == 0 || head.len() + n > MAX_HEAD {
            return Ok(None);
        }
        head.extend_from_slice(&buf[..n]);
        let mut headers = [httparse::EMPTY_HEADER; MAX_HEADERS];
        let mut request = httparse::Request::new(&mut headers);
        match request.parse(&head) {
            Ok(httparse::Status::Partial) => continue,
            Err(_) => return Ok(None),
            Ok(httparse::Status::Complete(_)) => {
                return Ok(Some(match (request.method, request.path) {
                    (Some("GET"), Some(target)) => Asked::Get(target.split('?').next().unwrap_or("/").to_string()),
                    _ => Asked::Other,
                }));
            }
        }
    }
}

/// A whole reply, then close.
pub async fn reply(stream: &mut TcpStream, status: &str, kind: &str, body: &[u8]) -> std::io::Result<()> {
    let head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes()).await?;
    stream.write_all(body).await?;
    stream.shutdown().await
}

/// The answer to anything but GET.
pub async fn method_not_allowed(stream: &mut TcpStream) -> std::io::Result<()> {
    reply(stream, "405 Method Not Allowed", "text/plain", b"GET only (the gateway's pages are read-only)\n").await
}
