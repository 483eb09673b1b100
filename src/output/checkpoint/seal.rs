//! The seal: a 512-byte user block before the HDF5 data that holds the length and a
//! hash of every byte after it, so a damaged checkpoint is refused before HDF5 reads it.

use decomposition::splitmix::mix;
use std::path::Path;

/// Bytes at the start of a checkpoint that HDF5 leaves alone (its user block), where
/// [`seal`] puts the checksum of the rest.
pub(super) const SEAL_BYTES: usize = 512;
/// What a seal starts with.
const SEAL_MAGIC: &[u8; 16] = b"mpmcg checkpoint";
/// Where a plain HDF5 file (no user block) starts.
const HDF5_SIGNATURE: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

/// The length and a hash of the bytes of `path` after its first [`SEAL_BYTES`], 8 at
/// a time (a short tail zero-padded), read in 1 MiB pieces (a checkpoint may be larger
/// than memory).
fn hash_after_seal(path: &Path) -> std::io::Result<(u64, u64)> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(path)?;
    f.seek(SeekFrom::Start(SEAL_BYTES as u64))?;
    let mut buf = vec![0u8; 1 << 20];
    let (mut len, mut h) = (0u64, mix(0x6d70_6d63_6773_6561));
    loop {
        // Fill the buffer (a read may return less), so that words never straddle reads.
        let mut n = 0;
        while n < buf.len() {
            match f.read(&mut buf[n..])? {
                0 => break,
                k => n += k,
            }
        }
        for c in buf[..n].chunks(8) {
            let mut w = [0u8; 8];
            w[..c.len()].copy_from_slice(c);
            h = mix(h ^ u64::from_le_bytes(w));
        }
        len += n as u64;
        if n < buf.len() {
            return Ok((len, mix(h ^ len)));
        }
    }
}

/// Rank 0, after the collective close: write into the user block the magic, the length
/// and the hash of everything after it ([`hash_after_seal`]). A restart checks it
/// before HDF5 parses anything: HDF5 itself crashes (SIGSEGV in `H5Aopen`) on some
/// damaged object headers, and took flipped bytes in attribute values (the time, the
/// step) as valid (`restart::mutated_checkpoints_never_panic`).
///
/// Public so that a checkpoint edited on purpose with HDF5 tools can be sealed again.
pub fn seal(path: &Path) -> std::io::Result<()> {
    use std::io::{Seek, SeekFrom, Write};
    let (len, hash) = hash_after_seal(path)?;
    let mut block = [0u8; 32];
    block[..16].copy_from_slice(SEAL_MAGIC);
    block[16..24].copy_from_slice(&len.to_le_bytes());
    block[24..].copy_from_slice(&hash.to_le_bytes());
    let mut f = std::fs::OpenOptions::new().write(true).open(path)?;
    f.seek(SeekFrom::Start(0))?;
    f.write_all(&block)
}

/// Check a checkpoint's seal before HDF5 opens it. A file that starts with the HDF5
/// signature has no user block (written before seals existed) and is let through, as
/// is one that is not HDF5 at all (HDF5's own message then says so).
pub(super) fn check_seal(path: &Path) -> Result<(), String> {
    use std::io::Read;
    let p = path.display();
    let cannot = |e: std::io::Error| format!("{p}: cannot read the checkpoint: {e}");
    let mut head = Vec::with_capacity(SEAL_BYTES + 8);
    std::fs::File::open(path)
        .map_err(cannot)?
        .take(SEAL_BYTES as u64 + 8)
        .read_to_end(&mut head)
        .map_err(cannot)?;
    if head.starts_with(HDF5_SIGNATURE) {
        return Ok(());
    }
    if !head.starts_with(SEAL_MAGIC) {
        if head.len() == SEAL_BYTES + 8 && head[SEAL_BYTES..].starts_with(HDF5_SIGNATURE) {
            return Err(format!(
                "{p}: corrupt checkpoint: the header that holds its checksum is damaged"
            ));
        }
        return Ok(());
    }
    if head.len() < SEAL_BYTES {
        return Err(format!(
            "{p}: corrupt checkpoint: {} bytes, shorter than its header (truncated)",
            head.len()
        ));
    }
    let word = |at: usize| u64::from_le_bytes(head[at..at + 8].try_into().expect("8 bytes"));
    let (len, hash) = hash_after_seal(path).map_err(cannot)?;
    if word(16) != len {
        return Err(format!(
            "{p}: corrupt checkpoint: {len} bytes after its header, {} when written (truncated or extended)",
            word(16)
        ));
    }
    if word(24) != hash {
        return Err(format!(
            "{p}: corrupt checkpoint: its bytes do not match the checksum written with them"
        ));
    }
    Ok(())
}
