//! An in-process CAN bus, for tests of the gateway process without a CAN interface
//! (`can = "memory"` in a test's config). Built only with the lab tools: the deployed
//! gateway has no such endpoint.

use std::sync::{Arc, Mutex};

use flowgate_protocol::CanFrame;
use tokio::sync::broadcast;

use super::CanError;
use crate::gateway::core::input::CanEvent;

/// An in-process CAN bus for unit tests: every attached link sees every other's frames.
#[derive(Clone)]
pub struct MemoryBus {
    tx: broadcast::Sender<(usize, CanFrame)>,
    next_id: Arc<Mutex<usize>>,
}

impl std::fmt::Debug for MemoryBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("MemoryBus")
    }
}

impl Default for MemoryBus {
    fn default() -> Self {
        Self::new()
    }
}

impl MemoryBus {
    pub fn new() -> Self {
        Self { tx: broadcast::channel(1024).0, next_id: Arc::new(Mutex::new(0)) }
    }
    /// A new node on the bus.
    pub fn attach(&self) -> MemoryLink {
        let mut id = self.next_id.lock().expect("not poisoned");
        *id += 1;
        MemoryLink { id: *id, tx: self.tx.clone(), rx: self.tx.subscribe() }
    }
}

pub struct MemoryLink {
    id: usize,
    tx: broadcast::Sender<(usize, CanFrame)>,
    rx: broadcast::Receiver<(usize, CanFrame)>,
}

impl std::fmt::Debug for MemoryLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("MemoryLink")
    }
}

impl MemoryLink {
    pub fn send(&mut self, frame: CanFrame) -> Result<(), CanError> {
        let _ = self.tx.send((self.id, frame));
        Ok(())
    }
    pub async fn recv(&mut self) -> Result<CanEvent, CanError> {
        loop {
            match self.rx.recv().await {
                Ok((from, f)) if from != self.id => return Ok(CanEvent::Frame(f)),
                Ok(_) => continue,
                Err(broadcast::error::RecvError::Lagged(_)) => return Ok(CanEvent::Garbled),
                Err(broadcast::error::RecvError::Closed) => return Err(CanError::Closed),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowgate_protocol::CanId;

    #[tokio::test]
    async fn memory_bus_delivers_to_others_only() {
        let bus = MemoryBus::new();
        let (mut a, mut b) = (bus.attach(), bus.attach());
        let f = CanFrame::new(CanId::Standard(0x101), &[1]).unwrap();
        a.send(f).unwrap();
        assert_eq!(b.recv().await.unwrap(), CanEvent::Frame(f));
        b.send(f).unwrap();
        assert_eq!(a.recv().await.unwrap(), CanEvent::Frame(f));
    }
}
