//! FNV-1a, 64 bits: a stable content hash for cache and settings keys (not for security or for
//! integrity against a hostile writer), and the hash of the running executable.
use anyhow::{Context, Result};
use std::io::Read;

pub struct Fnv(pub u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 = (self.0 ^ x as u64).wrapping_mul(0x100_0000_01b3);
        }
    }

    pub fn f32s(&mut self, v: impl IntoIterator<Item = f32>) {
        for x in v {
            self.bytes(&x.to_bits().to_le_bytes());
        }
    }

    /// The hash as the 16 hex digits that keys and folder names carry.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// Add the running executable's bytes: a different build may round differently, so neither a
/// resume, a merge nor a cached reference mixes builds.
pub fn hash_exe(f: &mut Fnv) -> Result<()> {
    let exe = std::env::current_exe().context("finding the reframe executable")?;
    // Streamed: the binary is ~50 MB, which would otherwise show in the peak memory.
    let mut r = std::fs::File::open(&exe).with_context(|| format!("reading {}", exe.display()))?;
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = r
            .read(&mut buf)
            .with_context(|| format!("reading {}", exe.display()))?;
        if n == 0 {
            return Ok(());
        }
        f.bytes(&buf[..n]);
    }
}
