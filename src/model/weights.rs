//! A model file's weights without burn: the safetensors header and tensors read directly (F32,
//! F16 or BF16; burn's names or the PyTorch names of `pipeline export`), checked the way
//! `model::checkpoint` (feature `train`) checks them, for the CPU inference path ([`FastNet`]).
//! `deblur`, `eval` and `figure` load models through this, so the default build needs no burn.
//!
//! [`FastNet`]: crate::model::fast::FastNet

use crate::model::Arch;
use crate::{Error, Result};
use std::collections::HashMap;
use std::path::Path;

/// Why a file was not read as a model: each rule a safetensors model file must keep. The
/// message names the tensor or the metadata entry; `serde_json`'s error is kept where it is one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WeightsError {
    #[error("truncated: no safetensors header")]
    NoHeader,
    #[error("truncated safetensors header")]
    TruncatedHeader,
    #[error("bad safetensors header ({0})")]
    Header(serde_json::Error),
    #[error("the safetensors header is not a table")]
    NotTable,
    #[error("no `arch` in the metadata: not a pipeline model")]
    NoArch,
    #[error(
        "no `arch` in the metadata, and neither a U-Net (inc.a.0.weight) nor a shallow model (blocks.0.0.weight): not a pipeline model"
    )]
    NotPipeline,
    #[error("unknown arch {arch:?} ({cause})")]
    UnknownArch { arch: String, cause: serde_json::Error },
    #[error("the metadata names {arch}, outside 1 to {max} filters")]
    Width { arch: String, max: usize },
    #[error("the metadata names a burst U-Net told the time on {levels} decoder levels, outside 1 to 4")]
    Levels { levels: usize },
    #[error("the metadata names {arch} (at least {least} weights) but the file declares {declared}")]
    Declared { arch: String, least: usize, declared: u128 },
    #[error("{key} is missing: the weights do not fit {arch}")]
    Missing { key: String, arch: String },
    #[error("{key} has shape {got:?}, {arch} needs {want:?}")]
    Shape { key: String, got: Vec<usize>, want: Vec<usize>, arch: String },
    #[error("{key}: tensor data out of range (truncated file?)")]
    OutOfRange { key: String },
    #[error("{key}: is {dtype}, expected F32, F16 or BF16")]
    Dtype { key: String, dtype: String },
    #[error("{key}: {bytes} bytes of {dtype} for {values} values")]
    Size { key: String, bytes: usize, dtype: String, values: usize },
    #[error("{count} weights are not finite (NaN or infinite); the model cannot be used")]
    NotFinite { count: usize },
    #[error("{name} is not a parameter of {arch}")]
    Extra { name: String, arch: String },
    #[error("{key} holds {value}, beyond F16's range")]
    F16Range { key: String, value: f32 },
    #[error("{key} has no PyTorch name: not a parameter of pipeline's networks")]
    NoTorchName { key: String },
}

type Checked<T> = std::result::Result<T, WeightsError>;

/// The JSON header of a safetensors file.
pub(crate) fn read_header(bytes: &[u8]) -> Checked<serde_json::Value> {
    if bytes.len() < 8 {
        return Err(WeightsError::NoHeader);
    }
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
    let header = bytes.get(8..8usize.saturating_add(n)).ok_or(WeightsError::TruncatedHeader)?;
    serde_json::from_slice(header).map_err(WeightsError::Header)
}

/// The `__metadata__` of a safetensors header.
pub fn read_meta(bytes: &[u8]) -> Checked<serde_json::Value> {
    Ok(read_header(bytes)?["__metadata__"].clone())
}

/// An `arch` string of a model's metadata.
fn parse_arch(arch: &str) -> Checked<Arch> {
    serde_json::from_str(arch).map_err(|cause| WeightsError::UnknownArch { arch: arch.into(), cause })
}

/// The `arch` entry of a safetensors header's metadata, checked before anything is allocated
/// for it: within the sizes `pipeline train` accepts, and no larger than the weights the file
/// declares (a network of width `b` has at least one b-to-b 3x3 convolution, 9 b^2 weights).
pub fn read_arch(bytes: &[u8]) -> Checked<Arch> {
    let header = read_header(bytes)?;
    let parsed = parse_arch(header["__metadata__"]["arch"].as_str().ok_or(WeightsError::NoArch)?)?;
    check_size(parsed, &header).map(|()| parsed)
}

/// `arch`'s width within what `pipeline train` accepts and within the weights `header` declares.
fn check_size(arch: Arch, header: &serde_json::Value) -> Checked<()> {
    let (b, max) = match arch {
        Arch::Unet { base } => (base, 256),
        Arch::BurstUnet { base, levels } if (1..=crate::model::DECODER_LEVELS).contains(&levels) => (base, 256),
        Arch::BurstUnet { levels, .. } => return Err(WeightsError::Levels { levels }),
        Arch::Shallow { width } => (width, 1024),
    };
    if b == 0 || b > max {
        return Err(WeightsError::Width { arch: arch.name(), max });
    }
    let declared: u128 = header
        .as_object()
        .map(|o| {
            o.iter()
                .filter(|(k, _)| *k != "__metadata__")
                .filter_map(|(_, t)| t["shape"].as_array().map(|s| s.iter().map(|d| d.as_u64().unwrap_or(0) as u128).product::<u128>()))
                .sum()
        })
        .unwrap_or(0);
    if 9 * (b as u128) * (b as u128) > declared {
        return Err(WeightsError::Declared { arch: arch.name(), least: 9 * b * b, declared });
    }
    Ok(())
}

/// The architecture of a file without one in its metadata (a PyTorch `state_dict` saved with
/// `safetensors.torch.save_file`), from its first convolution's shape.
fn arch_from_torch_shapes(header: &serde_json::Value) -> Option<Arch> {
    let shape0 = |k: &str| header.get(k)?["shape"].as_array()?.first()?.as_u64().map(|d| d as usize);
    match (shape0("inc.a.0.weight"), shape0("blocks.0.0.weight")) {
        (Some(b), _) if header.get("film.weight").is_some() => {
            let deep = (0..3).filter(|k| header.get(format!("ups.{k}.film.weight")).is_some()).count();
            Some(Arch::BurstUnet { base: b, levels: 1 + deep })
        }
        (Some(b), _) => Some(Arch::Unet { base: b }),
        (None, Some(w)) => Some(Arch::Shallow { width: w }),
        _ => None,
    }
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
            // A ConvBn's convolution (`... .conv.weight`); `upK.conv.a` is a DoubleConv.
            (_, "conv") if matches!(next, Some("weight") | Some("bias")) => out.push("0".into()),
            (_, "bn") => out.push("1".into()),
            (_, "gamma") => out.push("weight".into()),
            (_, "beta") => out.push("bias".into()),
            (_, p) => out.push(p.into()),
        }
        i += 1;
    }
    Some(out.join("."))
}

/// Every trained tensor of a network of `arch` with its shape, under burn's names (the names of
/// `pipeline train`'s files; [`torch_name`] gives the PyTorch ones), in a fixed order.
pub fn param_shapes(arch: Arch) -> Vec<(String, Vec<usize>)> {
    let mut out = Vec::new();
    let mut conv_bn = |out: &mut Vec<(String, Vec<usize>)>, p: &str, cin: usize, cout: usize| {
        out.push((format!("{p}.conv.weight"), vec![cout, cin, 3, 3]));
        for s in ["gamma", "beta", "running_mean", "running_var"] {
            out.push((format!("{p}.bn.{s}"), vec![cout]));
        }
    };
    match arch {
        Arch::Unet { base: b } | Arch::BurstUnet { base: b, .. } => {
            let double = |out: &mut Vec<_>, conv_bn: &mut dyn FnMut(&mut Vec<_>, &str, usize, usize), p: &str, cin, cout| {
                conv_bn(out, &format!("{p}.a"), cin, cout);
                conv_bn(out, &format!("{p}.b"), cout, cout);
            };
            double(&mut out, &mut conv_bn, "Unet.inc", 3, b);
            for (k, (i, o)) in [(b, 2 * b), (2 * b, 4 * b), (4 * b, 8 * b), (8 * b, 8 * b)].into_iter().enumerate() {
                double(&mut out, &mut conv_bn, &format!("Unet.down{}.conv", k + 1), i, o);
            }
            for (k, (cin, skip, cout)) in
                [(8 * b, 8 * b, 4 * b), (4 * b, 4 * b, 2 * b), (2 * b, 2 * b, b), (b, b, b)].into_iter().enumerate()
            {
                out.push((format!("Unet.up{}.up.weight", k + 1), vec![cin, cin, 2, 2]));
                out.push((format!("Unet.up{}.up.bias", k + 1), vec![cin]));
                double(&mut out, &mut conv_bn, &format!("Unet.up{}.conv", k + 1), cin + skip, cout);
            }
            out.push(("Unet.outc.weight".into(), vec![3, b, 1, 1]));
            out.push(("Unet.outc.bias".into(), vec![3]));
            // FiLM on the timed levels' concatenated inputs, the last level's first.
            for (i, c) in [16 * b, 8 * b, 4 * b, 2 * b].into_iter().enumerate().rev() {
                if i + arch.timed_levels() >= crate::model::DECODER_LEVELS {
                    let p = crate::model::film_name(i);
                    out.push((format!("{p}.gamma"), vec![crate::model::TIME_FEATURES, c]));
                    out.push((format!("{p}.beta"), vec![crate::model::TIME_FEATURES, c]));
                }
            }
        }
        Arch::Shallow { width: c } => {
            for i in 0..9 {
                conv_bn(&mut out, &format!("Shallow.blocks.{i}"), if i == 0 { 3 } else { c }, c);
            }
            out.push(("Shallow.out.weight".into(), vec![3, c, 3, 3]));
            out.push(("Shallow.out.bias".into(), vec![3]));
        }
    }
    out
}

/// The weights of one model file, widened to F32 and under burn's names, every one checked
/// against the architecture's shape and for being finite.
pub struct Weights {
    pub arch: Arch,
    tensors: HashMap<String, Vec<f32>>,
}

impl Weights {
    /// Reads a model file, or a model folder (`model.safetensors`, or the later checkpoint a
    /// training folder's `latest.json` names).
    ///
    /// # Errors
    /// As [`Weights::from_bytes`]; an unreadable file.
    pub fn read(path: &Path) -> Result<Weights> {
        let (bytes, name) = read_model_file(path)?;
        Weights::from_bytes(&bytes, &name)
    }

    /// The weights of a model file's bytes; `name` names it in errors.
    ///
    /// # Errors
    /// Not safetensors; no architecture; a missing, misshapen, extra or non-finite weight (named).
    pub fn from_bytes(bytes: &[u8], name: &str) -> Result<Weights> {
        Weights::check(bytes).map_err(|cause| Error::Format { path: name.into(), cause: Box::new(cause.into()) })
    }

    fn check(bytes: &[u8]) -> Checked<Weights> {
        let header = read_header(bytes)?;
        let obj = header.as_object().ok_or(WeightsError::NotTable)?;
        let arch = match header["__metadata__"]["arch"].as_str() {
            Some(a) => parse_arch(a)?,
            None => arch_from_torch_shapes(&header).ok_or(WeightsError::NotPipeline)?,
        };
        check_size(arch, &header)?;
        let data = &bytes[8 + u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize..];
        let want = param_shapes(arch);
        // A file's name for each wanted tensor: burn's, or the PyTorch one.
        let torch = !obj.keys().any(|k| k.starts_with("Unet.") || k.starts_with("Shallow."));
        let mut tensors = HashMap::with_capacity(want.len());
        let mut bad_values = 0usize;
        for (burn, shape) in &want {
            let key = if torch { torch_name(burn).expect("every parameter has a PyTorch name") } else { burn.clone() };
            let t = obj.get(&key).ok_or_else(|| WeightsError::Missing { key: key.clone(), arch: arch.name() })?;
            let got: Vec<usize> =
                t["shape"].as_array().map(|s| s.iter().filter_map(|d| d.as_u64()).map(|d| d as usize).collect()).unwrap_or_default();
            if &got != shape {
                return Err(WeightsError::Shape { key, got, want: shape.clone(), arch: arch.name() });
            }
            let off = &t["data_offsets"];
            let (a, b) = (off[0].as_u64().unwrap_or(u64::MAX) as usize, off[1].as_u64().unwrap_or(0) as usize);
            let raw = data.get(a..b).ok_or_else(|| WeightsError::OutOfRange { key: key.clone() })?;
            let values = decode(raw, t["dtype"].as_str().unwrap_or(""), shape.iter().product(), &key)?;
            bad_values += values.iter().filter(|v| !v.is_finite()).count();
            tensors.insert(burn.clone(), values);
        }
        if bad_values > 0 {
            return Err(WeightsError::NotFinite { count: bad_values });
        }
        // A tensor the network does not have means the file is of another network.
        let known = obj.len() - usize::from(obj.contains_key("__metadata__"));
        let batches = obj.keys().filter(|k| k.ends_with("num_batches_tracked")).count();
        if known - batches != want.len() {
            let extra = obj.keys().find(|k| *k != "__metadata__" && !k.ends_with("num_batches_tracked") && !tensors_has(&want, k, torch));
            return Err(WeightsError::Extra { name: extra.map_or("a tensor", |s| s.as_str()).into(), arch: arch.name() });
        }
        Ok(Weights { arch, tensors })
    }

    /// The values of burn's parameter `name`, taken out (each is used once).
    pub(crate) fn take(&mut self, name: &str) -> Vec<f32> {
        self.tensors.remove(name).unwrap_or_else(|| panic!("{name}: not a parameter of {}", self.arch.name()))
    }
}

fn tensors_has(want: &[(String, Vec<usize>)], key: &str, torch: bool) -> bool {
    want.iter().any(|(b, _)| if torch { torch_name(b).as_deref() == Some(key) } else { b == key })
}

/// `n` values of `dtype` (F32, F16 or BF16, little-endian) as f32.
fn decode(raw: &[u8], dtype: &str, n: usize, key: &str) -> Checked<Vec<f32>> {
    let size = match dtype {
        "F32" => 4,
        "F16" | "BF16" => 2,
        other => return Err(WeightsError::Dtype { key: key.into(), dtype: other.into() }),
    };
    if raw.len() != n * size {
        return Err(WeightsError::Size { key: key.into(), bytes: raw.len(), dtype: dtype.into(), values: n });
    }
    Ok(match dtype {
        "F32" => raw.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect(),
        "F16" => raw.chunks_exact(2).map(|c| half::f16::from_bits(u16::from_le_bytes([c[0], c[1]])).to_f32()).collect(),
        _ => raw.chunks_exact(2).map(|c| half::bf16::from_bits(u16::from_le_bytes([c[0], c[1]])).to_f32()).collect(),
    })
}

/// What `latest.json` in a training folder says.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Latest {
    pub step: usize,
    pub model: String,
    pub optimizer: String,
}

impl Latest {
    /// Reads `dir/latest.json`, or `None` where there is none. The file names it holds must be
    /// plain names of files in `dir` (not links): the paths of the model and optimizer files.
    ///
    /// # Errors
    /// An unreadable or malformed `latest.json`, or a name that leads outside `dir` (named).
    pub fn read(dir: &Path) -> Result<Option<(Latest, std::path::PathBuf, std::path::PathBuf)>> {
        let lp = dir.join("latest.json");
        let bytes = match std::fs::read(&lp) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(Error::Io { path: lp, cause: e }),
        };
        let latest: Latest =
            serde_json::from_slice(&bytes).map_err(|e| Error::Format { path: lp.to_path_buf(), cause: Box::new(e.into()) })?;
        let model = crate::io::paths::inside(dir, &latest.model, &lp, "model")?;
        let optimizer = crate::io::paths::inside(dir, &latest.optimizer, &lp, "optimizer")?;
        Ok(Some((latest, model, optimizer)))
    }
}

/// The bytes of a model file, or of the file a model folder stands for ([`model_in`]), with its
/// path for error messages; a regular file within the size bound only.
///
/// # Errors
/// An unreadable or oversized file, a malformed `latest.json`.
pub fn read_model_file(path: &Path) -> Result<(Vec<u8>, String)> {
    let file = if path.is_dir() { model_in(path)? } else { path.to_path_buf() };
    let bytes = crate::io::paths::read_regular(&file, crate::io::paths::MAX_MODEL_BYTES, "safetensors model file")?;
    Ok((bytes, file.display().to_string()))
}

/// The model file a folder stands for: its `model.safetensors` (a shipped model, or the
/// averaged model of a finished run), unless the folder is a `pipeline train` output folder
/// whose `latest.json` names a later checkpoint (a run resumed after it was written).
///
/// # Errors
/// An unreadable or malformed `latest.json`, or one naming a file outside `dir`.
pub fn model_in(dir: &Path) -> Result<std::path::PathBuf> {
    let main = dir.join("model.safetensors");
    let Some((latest, model, _)) = Latest::read(dir)? else {
        return Ok(main);
    };
    let main_step = std::fs::read(&main).ok().and_then(|b| read_meta(&b).ok()).and_then(|m| m["step"].as_str()?.parse::<usize>().ok());
    Ok(match main_step {
        Some(s) if s >= latest.step => main,
        _ => model,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A safetensors file of one tensor of `shape` with `arch` in its metadata.
    fn file(arch: &str, shape: &[usize]) -> Vec<u8> {
        let n: usize = shape.iter().product();
        let header = serde_json::json!({
            "__metadata__": { "arch": arch },
            "w": { "dtype": "F32", "shape": shape, "data_offsets": [0, 4 * n] },
        })
        .to_string();
        let mut b = (header.len() as u64).to_le_bytes().to_vec();
        b.extend(header.as_bytes());
        b.extend(vec![0u8; 4 * n]);
        b
    }

    #[test]
    fn an_architecture_larger_than_its_file_is_refused_before_allocation() {
        // A 100-byte file claiming a U-Net of base 100000 (it aborted the process before).
        let e = read_arch(&file(r#"{"type":"unet","base":100000}"#, &[1])).unwrap_err();
        assert!(matches!(&e, WeightsError::Width { arch, max: 256 } if arch.contains("unet")), "{e}");
        let e = read_arch(&file(r#"{"type":"shallow","width":200}"#, &[3, 3])).unwrap_err();
        assert!(matches!(e, WeightsError::Declared { least: 360000, declared: 9, .. }), "{e}");
        assert_eq!(read_arch(&file(r#"{"type":"shallow","width":2}"#, &[4, 9])).unwrap(), Arch::Shallow { width: 2 });
        assert_eq!(read_arch(crate::model::infer::DEFAULT_MODEL).unwrap(), Arch::Unet { base: 32 });
    }
}

#[cfg(test)]
mod loading {
    use super::*;
    use crate::model::fast::{FastNet, T4};
    use crate::model::torch::{read_safetensors, to_torch};

    fn shallow() -> &'static [u8] {
        include_bytes!("../../models/shallow32-coded/model.safetensors")
    }

    fn image() -> T4 {
        T4::new(1, 3, 24, 40, (0..3 * 24 * 40).map(|i| (i % 89) as f32 / 89.0).collect())
    }

    #[test]
    fn every_shipped_kind_loads_with_its_architecture_and_torch_names_give_the_same_network() {
        let models = [
            (crate::model::infer::DEFAULT_MODEL, Arch::Unet { base: 32 }),
            (crate::model::infer::DEFAULT_BURST_MODEL, Arch::burst(32)),
            (shallow(), Arch::Shallow { width: 32 }),
        ];
        for (bytes, arch) in models {
            let w = Weights::from_bytes(bytes, "m").unwrap();
            assert_eq!(w.arch, arch);
            let y = FastNet::from_weights(w).forward(&image());
            let (_, torch) = to_torch(bytes, "m").unwrap();
            let yt = FastNet::from_weights(Weights::from_bytes(&torch, "t").unwrap()).forward(&image());
            assert_eq!(y.d, yt.d, "{}", arch.name());
        }
    }

    #[cfg(feature = "train")]
    #[test]
    fn the_network_is_the_one_burn_loads() {
        let dev = burn::tensor::Device::flex();
        for bytes in [crate::model::infer::DEFAULT_BURST_MODEL, shallow()] {
            let (net, _) = crate::model::checkpoint::load_model_bytes(bytes, "m", &dev).unwrap();
            let a = FastNet::from_net(&net).forward_at(&image(), &[0.2]);
            let b = FastNet::from_weights(Weights::from_bytes(bytes, "m").unwrap()).forward_at(&image(), &[0.2]);
            assert_eq!(a.d, b.d);
        }
    }

    /// `shallow()` with tensor `name`'s header entry edited by `edit` (same data).
    fn edited(name: &str, edit: impl Fn(&mut serde_json::Value)) -> Vec<u8> {
        let b = shallow();
        let n = u64::from_le_bytes(b[..8].try_into().unwrap()) as usize;
        let mut header: serde_json::Value = serde_json::from_slice(&b[8..8 + n]).unwrap();
        edit(&mut header[name]);
        if header[name].is_null() {
            header.as_object_mut().unwrap().remove(name);
        }
        let h = header.to_string();
        let mut out = (h.len() as u64).to_le_bytes().to_vec();
        out.extend(h.as_bytes());
        out.extend(&b[8 + n..]);
        out
    }

    #[test]
    fn a_missing_misshapen_extra_or_non_finite_weight_is_named() {
        let err = |b: &[u8]| Weights::from_bytes(b, "m.safetensors").err().expect("refused").to_string();
        let e = err(&edited("Shallow.out.bias", |v| *v = serde_json::Value::Null));
        assert!(e.contains("Shallow.out.bias is missing") && e.contains("m.safetensors"), "{e}");
        let e = err(&edited("Shallow.out.bias", |v| v["shape"] = serde_json::json!([1, 3])));
        assert!(e.contains("Shallow.out.bias has shape [1, 3]"), "{e}");
        let e = err(&edited("Shallow.out.bias", |v| v["dtype"] = "I32".into()));
        assert!(e.contains("I32"), "{e}");
        let extra = edited("Shallow.out.bias", |_| {});
        let mut with_extra = extra.clone();
        let n = u64::from_le_bytes(extra[..8].try_into().unwrap()) as usize;
        let mut header: serde_json::Value = serde_json::from_slice(&extra[8..8 + n]).unwrap();
        header["Shallow.extra"] = header["Shallow.out.bias"].clone();
        let h = header.to_string();
        with_extra.clear();
        with_extra.extend((h.len() as u64).to_le_bytes());
        with_extra.extend(h.as_bytes());
        with_extra.extend(&extra[8 + n..]);
        assert!(err(&with_extra).contains("Shallow.extra is not a parameter of shallow-32"));
        // NaN weights: the first tensor's first value.
        let (entries, _) = read_safetensors(shallow(), "m").unwrap();
        let first = &entries.iter().min_by_key(|e| e.name.clone()).unwrap().name;
        let b = shallow();
        let n = u64::from_le_bytes(b[..8].try_into().unwrap()) as usize;
        let header: serde_json::Value = serde_json::from_slice(&b[8..8 + n]).unwrap();
        let at = 8 + n + header[first]["data_offsets"][0].as_u64().unwrap() as usize;
        let mut nan = b.to_vec();
        nan[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(err(&nan).contains("1 weights are not finite"), "{}", err(&nan));
        assert!(err(&b[..b.len() - 10]).contains("out of range"));
    }
}
