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

/// Reads every regular member: (name, bytes), in order.
///
/// # Errors
/// A truncated archive or a bad header checksum.
pub fn read_all(mut r: impl Read) -> Result<Vec<(String, Vec<u8>)>, String> {
    let mut out = Vec::new();
    let mut h = [0u8; 512];
    loop {
        if r.read_exact(&mut h).is_err() {
            return Err("truncated tar (no end blocks)".into());
        }
        if h.iter().all(|&b| b == 0) {
            return Ok(out);
        }
        let stored =
            std::str::from_utf8(&h[148..154]).ok().and_then(|s| u32::from_str_radix(s.trim(), 8).ok()).ok_or("bad checksum field")?;
        let mut c = h;
        c[148..156].copy_from_slice(b"        ");
        if c.iter().map(|&b| b as u32).sum::<u32>() != stored {
            return Err("tar header checksum mismatch".into());
        }
        let name = String::from_utf8_lossy(&h[..100]).trim_end_matches('\0').to_string();
        let size = u64::from_str_radix(std::str::from_utf8(&h[124..135]).map_err(|e| e.to_string())?.trim(), 8)
            .map_err(|e| e.to_string())? as usize;
        let mut data = vec![0u8; size];
        r.read_exact(&mut data).map_err(|_| format!("truncated member {name}"))?;
        let mut pad = vec![0u8; (512 - size % 512) % 512];
        r.read_exact(&mut pad).map_err(|_| format!("truncated member {name}"))?;
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
}
