//! Minimal OpenEXR writer: single part, scanline, no compression, 32-bit float R, G, B.
//! Linear light goes in unchanged, which is what EXR readers expect.

use std::io::Write;

fn attr(out: &mut Vec<u8>, name: &str, ty: &str, value: &[u8]) {
    out.extend_from_slice(name.as_bytes());
    out.push(0);
    out.extend_from_slice(ty.as_bytes());
    out.push(0);
    out.extend_from_slice(&(value.len() as i32).to_le_bytes());
    out.extend_from_slice(value);
}

/// Writes planar linear RGB (`planes[c][y * width + x]`, c = R, G, B) as float EXR.
pub fn write_rgb_f32(w: &mut dyn Write, width: usize, height: usize, planes: [&[f32]; 3]) -> std::io::Result<()> {
    for p in planes {
        assert_eq!(p.len(), width * height);
    }
    let mut h = Vec::new();
    h.extend_from_slice(&[0x76, 0x2f, 0x31, 0x01]);
    h.extend_from_slice(&2i32.to_le_bytes());
    // Channels are stored in alphabetical order: B, G, R.
    let mut ch = Vec::new();
    for name in ["B", "G", "R"] {
        ch.extend_from_slice(name.as_bytes());
        ch.push(0);
        ch.extend_from_slice(&2i32.to_le_bytes()); // FLOAT
        ch.extend_from_slice(&[0, 0, 0, 0]); // pLinear + reserved
        ch.extend_from_slice(&1i32.to_le_bytes());
        ch.extend_from_slice(&1i32.to_le_bytes());
    }
    ch.push(0);
    attr(&mut h, "channels", "chlist", &ch);
    attr(&mut h, "compression", "compression", &[0]);
    let mut bx = Vec::new();
    for v in [0i32, 0, width as i32 - 1, height as i32 - 1] {
        bx.extend_from_slice(&v.to_le_bytes());
    }
    attr(&mut h, "dataWindow", "box2i", &bx);
    attr(&mut h, "displayWindow", "box2i", &bx);
    attr(&mut h, "lineOrder", "lineOrder", &[0]);
    attr(&mut h, "pixelAspectRatio", "float", &1f32.to_le_bytes());
    attr(&mut h, "screenWindowCenter", "v2f", &[0u8; 8]);
    attr(&mut h, "screenWindowWidth", "float", &1f32.to_le_bytes());
    h.push(0);
    let line_bytes = 8 + 3 * width * 4;
    let table_start = h.len();
    for y in 0..height {
        h.extend_from_slice(&((table_start + 8 * height + y * line_bytes) as u64).to_le_bytes());
    }
    w.write_all(&h)?;
    let mut line = Vec::with_capacity(line_bytes);
    for y in 0..height {
        line.clear();
        line.extend_from_slice(&(y as i32).to_le_bytes());
        line.extend_from_slice(&((3 * width * 4) as i32).to_le_bytes());
        for c in [2usize, 1, 0] {
            for v in &planes[c][y * width..(y + 1) * width] {
                line.extend_from_slice(&v.to_le_bytes());
            }
        }
        w.write_all(&line)?;
    }
    Ok(())
}
