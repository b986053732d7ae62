//! Foxglove live: the recording's channels (src/gateway/shell/recording.rs), the same
//! messages with the same schemas, served over the Foxglove WebSocket protocol
//! (`foxglove.websocket.v1`) by the Foxglove SDK's server, so Foxglove connects to a
//! running gateway as it opens a recording (`[operator] foxglove`, `demo --foxglove`).
//!
//! Read-only: the server offers no client publishing, services or parameters. The telemetry
//! writer thread logs each message as it encodes it for the recording; the loop never
//! waits on a client (the SDK queues per client and drops for a slow one).

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer};

/// The live server and its channels.
pub struct Live {
    context: Arc<Context>,
    channels: BTreeMap<String, Arc<RawChannel>>,
    server: foxglove::WebSocketServerHandle,
}

impl std::fmt::Debug for Live {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Live").field("port", &self.server.port()).field("channels", &self.channels.len()).finish()
    }
}

impl Live {
    /// Listen on `addr` (port 0: any free port).
    pub async fn start(addr: SocketAddr) -> Result<Self, foxglove::FoxgloveError> {
        let context = Context::new();
        let server = WebSocketServer::new()
            .name(format!("flowgate {}", env!("CARGO_PKG_VERSION")))
            .bind(addr.ip().to_string(), addr.port())
            .context(&context)
            .start()
            .await?;
        Ok(Self { context, channels: BTreeMap::new(), server })
    }

    /// The port it listens on.
    pub fn port(&self) -> u16 {
        self.server.port()
    }

    /// Advertise a channel with its schema and message encoding.
    pub fn add_channel(
        &mut self,
        topic: &str,
        schema: Schema,
        message_encoding: &str,
    ) -> Result<(), foxglove::FoxgloveError> {
        let channel = ChannelBuilder::new(topic)
            .message_encoding(message_encoding)
            .schema(schema)
            .context(&self.context)
            .build_raw()?;
        self.channels.insert(topic.to_string(), channel);
        Ok(())
    }

    /// Send a message to the clients subscribed to `topic`, stamped `log_time` (ns since
    /// the Unix epoch).
    pub fn log(&self, topic: &str, log_time: u64, data: &[u8]) {
        if let Some(channel) = self.channels.get(topic) {
            channel.log_with_meta(data, PartialMetadata { log_time: Some(log_time) });
        }
    }

    /// Close every client's connection and stop listening.
    pub fn stop(self) {
        let _ = self.server.stop();
    }
}
