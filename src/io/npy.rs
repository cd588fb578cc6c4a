//! NumPy `.npy` (format 1.0) writer and reader for little-endian float32 arrays.

use std::io::Write;

/// Writes a C-order float32 array of `shape`.
pub fn write_f32(w: &mut dyn Write, shape: &[usize], data: &[f32]) -> std::io::Result<()> {
    assert_eq!(shape.iter().product::<usize>(), data.len(), "npy shape does not match the data");
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_s = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape_s}, }}");
    // Magic (6) + version (2) + length (2) + header + '\n' is a multiple of 64.
    let pad = 64 - (10 + header.len() + 1) % 64;
    header.push_str(&" ".repeat(pad % 64));
    header.push('\n');
    w.write_all(b"\x93NUMPY\x01\x00")?;
    w.write_all(&(header.len() as u16).to_le_bytes())?;
    w.write_all(header.as_bytes())?;
    for v in data {
        w.write_all(&v.to_le_bytes())?;
    }
    Ok(())
}

/// Why bytes were not read as a float32 `.npy` array.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum NpyError {
    #[error("not an .npy file (no \\x93NUMPY magic)")]
    NotNpy,
    #[error("truncated .npy header")]
    TruncatedHeader,
    #[error("unsupported .npy array {header}: only little-endian float32 ('<f4') in C order is read")]
    Unsupported { header: String },
    #[error("the .npy header has no readable shape: {header}")]
    Shape { header: String },
    #[error("{values} float32 values for shape {shape:?}")]
    Count { values: usize, shape: Vec<usize> },
}

/// Reads a float32 `.npy` written by [`write_f32`] (or NumPy): shape and data.
///
/// # Errors
/// Not `.npy`, another dtype or Fortran order, or a shape that does not fit the data.
pub fn read_f32(bytes: &[u8]) -> Result<(Vec<usize>, Vec<f32>), NpyError> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(NpyError::NotNpy);
    }
    // Version 1.0 has a 2-byte header length; 2.0 and 3.0 a 4-byte one.
    let (hlen, start): (usize, usize) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        _ if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        _ => return Err(NpyError::TruncatedHeader),
    };
    let header = bytes.get(start..start.saturating_add(hlen)).and_then(|h| std::str::from_utf8(h).ok()).ok_or(NpyError::TruncatedHeader)?;
    let header_text = || header.trim().to_string();
    if !header.contains("'<f4'") || header.contains("'fortran_order': True") {
        return Err(NpyError::Unsupported { header: header_text() });
    }
    let dims =
        header.split("'shape': (").nth(1).and_then(|s| s.split(')').next()).ok_or_else(|| NpyError::Shape { header: header_text() })?;
    let shape: Vec<usize> = dims
        .split(',')
        .filter(|t| !t.trim().is_empty())
        .map(|t| t.trim().parse().map_err(|_| NpyError::Shape { header: header_text() }))
        .collect::<Result<_, _>>()?;
    let body = &bytes[start + hlen..];
    let want = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
    if !body.len().is_multiple_of(4) || want != Some(body.len() / 4) {
        return Err(NpyError::Count { values: body.len() / 4, shape });
    }
    Ok((shape, body.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()))
}

#[cfg(test)]
mod tests {
    #[test]
    fn round_trip_and_64_byte_alignment() {
        let mut buf = Vec::new();
        let data: Vec<f32> = (0..24).map(|i| i as f32 * 0.5).collect();
        super::write_f32(&mut buf, &[2, 3, 4], &data).unwrap();
        let hlen = u16::from_le_bytes([buf[8], buf[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        let (shape, back) = super::read_f32(&buf).unwrap();
        assert_eq!(shape, vec![2, 3, 4]);
        assert_eq!(back, data);
    }

    #[test]
    fn other_arrays_are_refused_with_the_reason() {
        use super::NpyError;
        let mut buf = Vec::new();
        super::write_f32(&mut buf, &[2, 3], &[0.0; 6]).unwrap();
        assert_eq!(super::read_f32(&buf[..buf.len() - 4]).unwrap_err(), NpyError::Count { values: 5, shape: vec![2, 3] });
        assert_eq!(super::read_f32(b"PK\x03\x04 not npy").unwrap_err(), NpyError::NotNpy);
        let mut f8 = buf.clone();
        let at = f8.windows(3).position(|w| w == b"<f4").unwrap();
        f8[at + 2] = b'8';
        assert!(matches!(super::read_f32(&f8).unwrap_err(), NpyError::Unsupported { .. }));
    }
}
