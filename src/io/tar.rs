//! Deterministic ustar writing and reading, for WebDataset shards: fixed mtime (0), owner
//! (0/0, no names), mode 0644 and member order, so a rerun writes identical bytes.

use std::io::{Read, Write};

fn octal(field: &mut [u8], v: u64) {
    let digits = field.len() - 1;
    let s = format!("{v:0digits$o}");
    field[..digits].copy_from_slice(&s.as_bytes()[s.len() - digits..]);
    field[digits] = 0;
}

/// Appends one regular file member.
///
/// # Errors
/// Writing fails, or the name is longer than 100 bytes.
pub fn append(w: &mut dyn Write, name: &str, data: &[u8]) -> std::io::Result<()> {
    if name.len() > 100 {
        return Err(std::io::Error::other(format!("tar member name {name:?} is longer than 100 bytes")));
    }
    let mut h = [0u8; 512];
    h[..name.len()].copy_from_slice(name.as_bytes());
    octal(&mut h[100..108], 0o644);
    octal(&mut h[108..116], 0);
    octal(&mut h[116..124], 0);
    octal(&mut h[124..136], data.len() as u64);
    octal(&mut h[136..148], 0);
    h[156] = b'0';
    h[257..263].copy_from_slice(b"ustar\0");
    h[263..265].copy_from_slice(b"00");
    h[148..156].copy_from_slice(b"        ");
    let sum: u32 = h.iter().map(|&b| b as u32).sum();
    let s = format!("{sum:06o}\0 ");
    h[148..156].copy_from_slice(s.as_bytes());
    w.write_all(&h)?;
    w.write_all(data)?;
    let pad = (512 - data.len() % 512) % 512;
    w.write_all(&vec![0u8; pad])
}

/// Ends the archive with two zero blocks.
pub fn finish(w: &mut dyn Write) -> std::io::Result<()> {
    w.write_all(&[0u8; 1024])
}

/// Why an archive was not read. `after` counts the members read before the fault.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TarError {
    /// The archive ends before its two zero blocks (a shard cut short while written or copied).
    #[error("truncated tar after {after} members (no end blocks)")]
    Truncated { after: usize, source: std::io::Error },
    #[error("member {after}: the header's checksum field is not octal")]
    ChecksumField { after: usize },
    #[error("member {after}: the header checksum does not match (not a tar, or damaged)")]
    Checksum { after: usize },
    #[error("member {name}: the size field is not octal")]
    SizeField { name: String },
    #[error("member {name}: truncated ({size} bytes declared)")]
    TruncatedMember { name: String, size: usize, source: std::io::Error },
}

/// Reads every regular member: (name, bytes), in order.
///
/// # Errors
/// A truncated archive or a bad header.
pub fn read_all(mut r: impl Read) -> Result<Vec<(String, Vec<u8>)>, TarError> {
    let mut out = Vec::new();
    let mut h = [0u8; 512];
    loop {
        let after = out.len();
        r.read_exact(&mut h).map_err(|source| TarError::Truncated { after, source })?;
        if h.iter().all(|&b| b == 0) {
            return Ok(out);
        }
        let octal = |field: &[u8]| std::str::from_utf8(field).ok().and_then(|s| u64::from_str_radix(s.trim_matches(['\0', ' ']), 8).ok());
        let stored = octal(&h[148..154]).ok_or(TarError::ChecksumField { after })?;
        let mut c = h;
        c[148..156].copy_from_slice(b"        ");
        if c.iter().map(|&b| b as u64).sum::<u64>() != stored {
            return Err(TarError::Checksum { after });
        }
        let name = String::from_utf8_lossy(&h[..100]).trim_end_matches('\0').to_string();
        let Some(size) = octal(&h[124..135]).map(|s| s as usize) else {
            return Err(TarError::SizeField { name });
        };
        let mut data = vec![0u8; size];
        let truncated = |source| TarError::TruncatedMember { name: name.clone(), size, source };
        r.read_exact(&mut data).map_err(truncated)?;
        let mut pad = vec![0u8; (512 - size % 512) % 512];
        r.read_exact(&mut pad).map_err(truncated)?;
        if h[156] == b'0' || h[156] == 0 {
            out.push((name, data));
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn round_trip_is_byte_stable() {
        let mut a = Vec::new();
        super::append(&mut a, "k_000001.lq.png", b"hello").unwrap();
        super::append(&mut a, "k_000001.json", &[7u8; 600]).unwrap();
        super::finish(&mut a).unwrap();
        assert_eq!(a.len() % 512, 0);
        let m = super::read_all(&a[..]).unwrap();
        assert_eq!(m[0], ("k_000001.lq.png".to_string(), b"hello".to_vec()));
        assert_eq!(m[1].1.len(), 600);
        let mut b = Vec::new();
        super::append(&mut b, "k_000001.lq.png", b"hello").unwrap();
        super::append(&mut b, "k_000001.json", &[7u8; 600]).unwrap();
        super::finish(&mut b).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn a_cut_or_damaged_archive_says_where() {
        let mut a = Vec::new();
        super::append(&mut a, "k_000001.lq.png", &[1u8; 700]).unwrap();
        super::append(&mut a, "k_000001.json", b"{}").unwrap();
        super::finish(&mut a).unwrap();
        let cut = super::read_all(&a[..a.len() - 1024]).unwrap_err();
        assert!(matches!(cut, super::TarError::Truncated { after: 2, .. }), "{cut}");
        let cut = super::read_all(&a[..1000]).unwrap_err();
        assert!(matches!(&cut, super::TarError::TruncatedMember { name, size: 700, .. } if name == "k_000001.lq.png"), "{cut}");
        let mut bad = a.clone();
        bad[512 + 1024 + 3] ^= 1;
        assert!(matches!(super::read_all(&bad[..]).unwrap_err(), super::TarError::Checksum { after: 1 }));
    }
}
