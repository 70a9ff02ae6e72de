//! Little-endian field access at fixed offsets. Callers check lengths first, so the
//! slice operations here never go out of bounds; they use `get` anyway so that a mistake
//! reads zeros instead of panicking on network input.

pub(crate) fn u8_at(b: &[u8], at: usize) -> u8 {
    b.get(at).copied().unwrap_or(0)
}

/// The two fields the manual gives high byte first (NEW's count, the enable mask).
pub(crate) fn u16_be(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([u8_at(b, at), u8_at(b, at + 1)])
}

/// `N` bytes at `at`, zeros if `b` is shorter.
fn bytes_at<const N: usize>(b: &[u8], at: usize) -> [u8; N] {
    b.get(at..at + N)
        .and_then(|s| s.try_into().ok())
        .unwrap_or([0; N])
}

pub(crate) fn u16_le(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes(bytes_at(b, at))
}

pub(crate) fn i16_le(b: &[u8], at: usize) -> i16 {
    u16_le(b, at) as i16
}

pub(crate) fn u32_le(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(bytes_at(b, at))
}

pub(crate) fn u64_le(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(bytes_at(b, at))
}

pub(crate) fn i32_le(b: &[u8], at: usize) -> i32 {
    u32_le(b, at) as i32
}

/// Writes at fixed offsets into a buffer the caller sized with `encoded_len`.
pub(crate) struct Writer<'a> {
    pub(crate) buf: &'a mut [u8],
}

impl Writer<'_> {
    pub(crate) fn put(&mut self, at: usize, bytes: &[u8]) {
        if let Some(s) = self.buf.get_mut(at..at + bytes.len()) {
            s.copy_from_slice(bytes);
        }
    }
    pub(crate) fn u8(&mut self, at: usize, v: u8) {
        self.put(at, &[v]);
    }
    pub(crate) fn u16(&mut self, at: usize, v: u16) {
        self.put(at, &v.to_le_bytes());
    }
    pub(crate) fn u32(&mut self, at: usize, v: u32) {
        self.put(at, &v.to_le_bytes());
    }
    pub(crate) fn i16s(&mut self, at: usize, v: &[i16; 8]) {
        for (i, x) in v.iter().enumerate() {
            self.put(at + 2 * i, &x.to_le_bytes());
        }
    }
    pub(crate) fn i32s(&mut self, at: usize, v: &[i32; 8]) {
        for (i, x) in v.iter().enumerate() {
            self.put(at + 4 * i, &x.to_le_bytes());
        }
    }
}

pub(crate) fn i16s(b: &[u8], at: usize) -> [i16; 8] {
    core::array::from_fn(|i| i16_le(b, at + 2 * i))
}

pub(crate) fn i32s(b: &[u8], at: usize) -> [i32; 8] {
    core::array::from_fn(|i| i32_le(b, at + 4 * i))
}
