//! `pipeline export`: a trained model as a safetensors file with PyTorch `state_dict` names, for
//! the networks in `benches/torch_models.py` (`UNet(base)`, `Shallow(width)`):
//! `model.load_state_dict(safetensors.torch.load_file(path))` then gives `pipeline deblur`'s
//! output (checked with torch locally; torch is not installed in CI).

use crate::{Error, Result};
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct ExportArgs {
    /// A model written by `pipeline train` (a `.safetensors` file or a model folder).
    pub model: PathBuf,
    /// Output `.safetensors` file.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Target naming: torch (PyTorch `state_dict` keys of benches/torch_models.py).
    #[arg(long, value_enum, default_value_t = ExportFormat::Torch)]
    pub format: ExportFormat,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    Torch,
}

/// The PyTorch name of a burn parameter of our networks: `Unet.down1.conv.a.conv.weight` ->
/// `downs.0.a.0.weight`, `...bn.gamma` -> `...1.weight`, `Unet.up2.up.weight` -> `ups.1.up.weight`.
pub fn torch_name(burn: &str) -> Option<String> {
    let (net, rest) = burn.split_once('.')?;
    let parts: Vec<&str> = rest.split('.').collect();
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < parts.len() {
        let p = parts[i];
        let next = parts.get(i + 1).copied();
        match (net, p) {
            ("Unet", d) if d.starts_with("down") => {
                out.push(format!("downs.{}", d[4..].parse::<usize>().ok()?.checked_sub(1)?));
                // `downK.conv.X`: torch's ModuleList holds the DoubleConv itself.
                if next == Some("conv") {
                    i += 1;
                }
            }
            ("Unet", u) if u.starts_with("up") && u.len() > 2 && u[2..].chars().all(|c| c.is_ascii_digit()) => {
                out.push(format!("ups.{}", u[2..].parse::<usize>().ok()?.checked_sub(1)?));
            }
            (_, "conv")
                if matches!(next, Some("weight") | Some("bias"))
                    && out.last().is_some_and(|l| l == "a" || l == "b" || l.parse::<usize>().is_ok()) =>
            {
                out.push("0".into())
            }
            (_, "bn") => out.push("1".into()),
            (_, "gamma") => out.push("weight".into()),
            (_, "beta") => out.push("bias".into()),
            (_, p) => out.push(p.into()),
        }
        i += 1;
    }
    Some(out.join("."))
}

/// One tensor of a safetensors file.
struct Entry {
    name: String,
    dtype: String,
    shape: Vec<usize>,
    data: Vec<u8>,
}

fn read_safetensors(bytes: &[u8], name: &str) -> Result<(Vec<Entry>, serde_json::Value)> {
    let bad = |m: &str| Error::Invalid(format!("{name}: {m}"));
    let n = u64::from_le_bytes(bytes.get(..8).ok_or_else(|| bad("truncated"))?.try_into().expect("8 bytes")) as usize;
    let header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(bytes.get(8..8 + n).ok_or_else(|| bad("truncated header"))?)
            .map_err(|e| bad(&format!("bad header ({e})")))?;
    let data = &bytes[8 + n..];
    let mut meta = serde_json::Value::Null;
    let mut out = Vec::new();
    for (k, v) in header {
        if k == "__metadata__" {
            meta = v;
            continue;
        }
        let off = &v["data_offsets"];
        let (a, b) = (off[0].as_u64().unwrap_or(0) as usize, off[1].as_u64().unwrap_or(0) as usize);
        out.push(Entry {
            name: k,
            dtype: v["dtype"].as_str().unwrap_or("").into(),
            shape: v["shape"].as_array().map(|s| s.iter().filter_map(|d| d.as_u64().map(|d| d as usize)).collect()).unwrap_or_default(),
            data: data.get(a..b).ok_or_else(|| bad("tensor data out of range"))?.to_vec(),
        });
    }
    Ok((out, meta))
}

fn write_safetensors(path: &Path, entries: &[Entry], meta: &serde_json::Map<String, serde_json::Value>) -> Result<()> {
    let mut header = serde_json::Map::new();
    header.insert("__metadata__".into(), serde_json::Value::Object(meta.clone()));
    let mut off = 0usize;
    for e in entries {
        header.insert(e.name.clone(), serde_json::json!({ "dtype": e.dtype, "shape": e.shape, "data_offsets": [off, off + e.data.len()] }));
        off += e.data.len();
    }
    let mut h = serde_json::to_vec(&header).expect("json");
    while h.len() % 8 != 0 {
        h.push(b' ');
    }
    crate::io::write_atomic(path, |w| {
        w.write_all(&(h.len() as u64).to_le_bytes())?;
        w.write_all(&h)?;
        entries.iter().try_for_each(|e| w.write_all(&e.data))
    })
}

/// Converts a model file's bytes to PyTorch names; adds each BatchNorm's `num_batches_tracked`.
///
/// # Errors
/// Not a model of ours (a name without a PyTorch counterpart), not safetensors.
pub fn to_torch(bytes: &[u8], name: &str) -> Result<(Vec<(String, Vec<usize>, String)>, Vec<u8>)> {
    let (entries, meta) = read_safetensors(bytes, name)?;
    let mut out = Vec::new();
    for e in entries {
        let t = torch_name(&e.name).ok_or_else(|| Error::Invalid(format!("{name}: {} has no PyTorch name", e.name)))?;
        if t.ends_with(".running_var") {
            let nbt = t.trim_end_matches("running_var").to_string() + "num_batches_tracked";
            out.push(Entry { name: nbt, dtype: "I64".into(), shape: vec![], data: 0i64.to_le_bytes().to_vec() });
        }
        out.push(Entry { name: t, ..e });
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    let mut m = serde_json::Map::new();
    m.insert("format".into(), "pt".into());
    if let Some(a) = meta.get("arch") {
        m.insert("arch".into(), a.clone());
    }
    m.insert("exported_by".into(), format!("pipeline {}", env!("CARGO_PKG_VERSION")).into());
    let tmp = std::env::temp_dir().join(format!("pipeline-export-{}.safetensors", std::process::id()));
    write_safetensors(&tmp, &out, &m)?;
    let written = std::fs::read(&tmp).map_err(|e| Error::Io { path: tmp.clone(), cause: e })?;
    let _ = std::fs::remove_file(&tmp);
    Ok((out.into_iter().map(|e| (e.name, e.shape, e.dtype)).collect(), written))
}

/// Runs `pipeline export`.
///
/// # Errors
/// The model cannot be read or is not ours; the output cannot be written.
pub fn command(a: ExportArgs) -> anyhow::Result<()> {
    let ExportFormat::Torch = a.format;
    let path = if a.model.is_dir() { a.model.join("model.safetensors") } else { a.model.clone() };
    let bytes = std::fs::read(&path).map_err(|e| Error::Io { path: path.clone(), cause: e })?;
    // Refuse what `deblur` would refuse (wrong architecture, non-finite weights).
    crate::model::checkpoint::load_model_bytes(&bytes, &path.display().to_string(), &burn::tensor::Device::flex())?;
    let (names, out) = to_torch(&bytes, &path.display().to_string())?;
    crate::io::write_atomic(&a.out, |w| w.write_all(&out))?;
    eprintln!("{} tensors with PyTorch names -> {}", names.len(), a.out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn burn_names_map_to_the_torch_modules() {
        for (b, t) in [
            ("Unet.inc.a.conv.weight", "inc.a.0.weight"),
            ("Unet.inc.b.bn.gamma", "inc.b.1.weight"),
            ("Unet.down1.conv.a.bn.beta", "downs.0.a.1.bias"),
            ("Unet.down4.conv.b.bn.running_var", "downs.3.b.1.running_var"),
            ("Unet.up1.up.weight", "ups.0.up.weight"),
            ("Unet.up4.conv.a.conv.weight", "ups.3.conv.a.0.weight"),
            ("Unet.outc.bias", "outc.bias"),
            ("Shallow.blocks.8.conv.weight", "blocks.8.0.weight"),
            ("Shallow.blocks.0.bn.running_mean", "blocks.0.1.running_mean"),
            ("Shallow.out.weight", "out.weight"),
        ] {
            assert_eq!(torch_name(b).as_deref(), Some(t), "{b}");
        }
    }

    #[test]
    fn the_shipped_unet_exports_every_tensor_with_torch_names_and_the_same_data() {
        let (names, bytes) = to_torch(crate::model::infer::DEFAULT_MODEL, "embedded").unwrap();
        // 100 burn tensors plus one num_batches_tracked per BatchNorm (18 in U-Net 16).
        assert_eq!(names.len(), 118);
        let find = |n: &str| names.iter().find(|(k, _, _)| k == n).unwrap_or_else(|| panic!("{n} missing"));
        assert_eq!(find("ups.0.up.weight").1, vec![128, 128, 2, 2]);
        assert_eq!(find("inc.a.0.weight").1, vec![16, 3, 3, 3]);
        assert_eq!(find("inc.a.1.num_batches_tracked").2, "I64");
        assert_eq!(find("outc.bias").1, vec![3]);
        assert!(names.iter().all(|(k, _, _)| !k.contains("gamma") && !k.contains("beta") && !k.starts_with("Unet")));
        // The data is carried over unchanged: the output conv's bias, in both files.
        let (src, _) = read_safetensors(crate::model::infer::DEFAULT_MODEL, "src").unwrap();
        let (dst, meta) = read_safetensors(&bytes, "dst").unwrap();
        let a = src.iter().find(|e| e.name == "Unet.outc.bias").unwrap();
        let b = dst.iter().find(|e| e.name == "outc.bias").unwrap();
        assert_eq!(a.data, b.data);
        assert_eq!(meta["format"], "pt");
    }
}
