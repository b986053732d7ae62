//! The records of an MCAP file, read a piece at a time: memory stays bounded by the largest
//! record (at most [`MAX_RECORD_BYTES`], a chunk's compressed and uncompressed sizes checked
//! against it before anything is allocated), whatever the file's size or its bytes say.

use std::io::Read;

use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::McapError;

/// The largest record read, bytes: a chunk, stored or opened. The gateway writes chunks of
/// 256 KiB; a record claiming more than this is damage, not data.
pub const MAX_RECORD_BYTES: usize = 64 << 20;
/// How much is read from the file at once.
const READ_BYTES: usize = 64 << 10;

/// Records in file order, each chunk opened (its records in place of it) or, with
/// [`Chunks::AsStored`], as it is stored.
pub struct McapRecords<R> {
    source: R,
    reader: LinearReader,
    /// Bytes of the file read so far.
    read: u64,
    /// The footer was read: the file ends whole.
    footer: bool,
    failed: bool,
}

impl<R> std::fmt::Debug for McapRecords<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapRecords").field("read", &self.read).field("footer", &self.footer).finish_non_exhaustive()
    }
}

/// Whether chunks are opened.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Chunks {
    /// Each chunk's records in its place (CRCs checked).
    Opened,
    /// Each chunk as one record, not opened.
    AsStored,
}

impl<R: Read> McapRecords<R> {
    pub fn new(source: R, chunks: Chunks) -> Self {
        let options = LinearReaderOptions::default()
            // A file cut short (the gateway killed mid-write) is read up to where it stops.
            .with_skip_end_magic(true)
            .with_emit_chunks(chunks == Chunks::AsStored)
            .with_validate_chunk_crcs(true)
            // A chunk is opened and its CRC checked before any of its records is given: a
            // damaged chunk ends the reading at its start, never halfway through it.
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES);
        Self { source, reader: LinearReader::new_with_options(options), read: 0, footer: false, failed: false }
    }

    /// Bytes of the file read so far.
    pub fn bytes_read(&self) -> u64 {
        self.read
    }

    /// Whether the file's footer was read: it ends whole, not cut short.
    pub fn saw_footer(&self) -> bool {
        self.footer
    }

    /// The next record; `None` at the end of the file, or after an error.
    pub fn next_record(&mut self) -> Option<Result<Record<'static>, McapError>> {
        if self.failed {
            return None;
        }
        let next = self.advance();
        match &next {
            Some(Ok(Record::Footer(_))) => self.footer = true,
            Some(Err(_)) => self.failed = true,
            _ => {}
        }
        next
    }

    fn advance(&mut self) -> Option<Result<Record<'static>, McapError>> {
        loop {
            match self.reader.next_event()? {
                Err(e) => return Some(Err(e)),
                Ok(LinearReadEvent::Record { data, opcode }) => {
                    return Some(mcap::parse_record(opcode, data).map(Record::into_owned));
                }
                Ok(LinearReadEvent::ReadRequest(wanted)) => {
                    let into = self.reader.insert(wanted.clamp(1, READ_BYTES));
                    let n = loop {
                        match self.source.read(into) {
                            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                            Err(e) => return Some(Err(McapError::Io(e))),
                            Ok(n) => break n,
                        }
                    };
                    self.reader.notify_read(n);
                    self.read += n as u64;
                }
            }
        }
    }
}

impl<R: Read> Iterator for McapRecords<R> {
    type Item = Result<Record<'static>, McapError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_record()
    }
}
