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

    /// Floats, two at a time as one 64-bit word per step (the scene's texels and positions,
    /// hundreds of millions of values, hashed byte by byte took a second or more); an odd last
    /// value alone.
    pub fn f32s(&mut self, v: impl IntoIterator<Item = f32>) {
        let mut v = v.into_iter();
        while let Some(a) = v.next() {
            let w = match v.next() {
                Some(b) => a.to_bits() as u64 | (b.to_bits() as u64) << 32,
                None => a.to_bits() as u64,
            };
            self.0 = (self.0 ^ w).wrapping_mul(0x100_0000_01b3);
        }
    }

    /// The hash as the 16 hex digits that keys and folder names carry.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// Add the running executable's identity: a different build may round differently, so neither
/// a resume, a merge nor a cached reference mixes builds. The identity is the CRC-32 of its
/// bytes (`crc32fast`, SIMD: the ~50 MB binary hashed byte by byte with FNV cost 0.13 s of
/// every run) and its length, read once per process.
pub fn hash_exe(f: &mut Fnv) -> Result<()> {
    static EXE: std::sync::OnceLock<(u32, u64)> = std::sync::OnceLock::new();
    let (crc, len) = match EXE.get() {
        Some(&v) => v,
        None => {
            let exe = std::env::current_exe().context("finding the reframe executable")?;
            // Streamed: read whole, the ~50 MB binary would show in the peak memory.
            let mut r =
                std::fs::File::open(&exe).with_context(|| format!("reading {}", exe.display()))?;
            let (mut h, mut len) = (crc32fast::Hasher::new(), 0u64);
            let mut buf = vec![0u8; 1 << 16];
            loop {
                let n = r
                    .read(&mut buf)
                    .with_context(|| format!("reading {}", exe.display()))?;
                if n == 0 {
                    break;
                }
                h.update(&buf[..n]);
                len += n as u64;
            }
            *EXE.get_or_init(|| (h.finalize(), len))
        }
    };
    f.bytes(&crc.to_le_bytes());
    f.bytes(&len.to_le_bytes());
    Ok(())
}
