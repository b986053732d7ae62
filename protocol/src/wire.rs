//! Little-endian field cursors shared by the message parsers. Every read is bounds-checked
//! and reports a short buffer as `None`, so parsers cannot index out of range.

pub(crate) struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }

    pub(crate) fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let bytes = self.buf.get(self.pos..self.pos + N)?;
        self.pos += N;
        bytes.try_into().ok()
    }

    pub(crate) fn u8(&mut self) -> Option<u8> {
        self.take::<1>().map(|b| b[0])
    }
    pub(crate) fn u16(&mut self) -> Option<u16> {
        self.take().map(u16::from_le_bytes)
    }
    pub(crate) fn u32(&mut self) -> Option<u32> {
        self.take().map(u32::from_le_bytes)
    }
    pub(crate) fn i32(&mut self) -> Option<i32> {
        self.take().map(i32::from_le_bytes)
    }
    pub(crate) fn u64(&mut self) -> Option<u64> {
        self.take().map(u64::from_le_bytes)
    }
    /// A signed 24-bit little-endian integer, sign-extended.
    pub(crate) fn i24(&mut self) -> Option<i32> {
        self.take::<3>().map(|b| i32::from_le_bytes([b[0], b[1], b[2], 0]) << 8 >> 8)
    }
    /// An unsigned 24-bit little-endian integer.
    pub(crate) fn u24(&mut self) -> Option<u32> {
        self.take::<3>().map(|b| u32::from_le_bytes([b[0], b[1], b[2], 0]))
    }
    pub(crate) fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }
}

pub(crate) struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Writer<'a> {
    pub(crate) fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    pub(crate) fn put(&mut self, bytes: &[u8]) -> Option<()> {
        self.buf.get_mut(self.pos..self.pos + bytes.len())?.copy_from_slice(bytes);
        self.pos += bytes.len();
        Some(())
    }
    pub(crate) fn u8(&mut self, v: u8) -> Option<()> {
        self.put(&[v])
    }
    pub(crate) fn u16(&mut self, v: u16) -> Option<()> {
        self.put(&v.to_le_bytes())
    }
    pub(crate) fn u32(&mut self, v: u32) -> Option<()> {
        self.put(&v.to_le_bytes())
    }
    pub(crate) fn i32(&mut self, v: i32) -> Option<()> {
        self.put(&v.to_le_bytes())
    }
    pub(crate) fn u64(&mut self, v: u64) -> Option<()> {
        self.put(&v.to_le_bytes())
    }
    /// The low 24 bits of `v`; the caller has checked the range.
    pub(crate) fn i24(&mut self, v: i32) -> Option<()> {
        self.put(&v.to_le_bytes()[..3])
    }
    pub(crate) fn u24(&mut self, v: u32) -> Option<()> {
        self.put(&v.to_le_bytes()[..3])
    }
    pub(crate) fn len(&self) -> usize {
        self.pos
    }
}
