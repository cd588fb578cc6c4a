//! PyTorch names for our networks: `state_dict` keys of `python/pipeline/models.py`'s `UNet(base)`
//! and `Shallow(width)`, both ways (the inverse derived from burn's names). `pipeline export` writes them; `--model` reads them back (a
//! model fine-tuned in PyTorch and saved with `safetensors.torch.save_file`).

use crate::model::weights::WeightsError;
use crate::{Error, Result};

/// A model file's error, naming it.
fn bad(name: &str) -> impl Fn(WeightsError) -> Error + '_ {
    move |e| Error::format(std::path::Path::new(name))(e)
}

pub use crate::model::weights::torch_name;

/// One tensor of a safetensors file.
pub(crate) struct Entry {
    pub name: String,
    pub dtype: String,
    pub shape: Vec<usize>,
    pub data: Vec<u8>,
}

pub(crate) fn read_safetensors(bytes: &[u8], name: &str) -> Result<(Vec<Entry>, serde_json::Value)> {
    let bad = bad(name);
    let n = u64::from_le_bytes(bytes.get(..8).ok_or_else(|| bad(WeightsError::NoHeader))?.try_into().expect("8 bytes")) as usize;
    let header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(bytes.get(8..8 + n).ok_or_else(|| bad(WeightsError::TruncatedHeader))?)
            .map_err(|e| bad(WeightsError::Header(e)))?;
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
            dtype: v["dtype"].as_str().unwrap_or("").into(),
            shape: v["shape"].as_array().map(|s| s.iter().filter_map(|d| d.as_u64().map(|d| d as usize)).collect()).unwrap_or_default(),
            data: data.get(a..b).ok_or_else(|| bad(WeightsError::OutOfRange { key: k.clone() }))?.to_vec(),
            name: k,
        });
    }
    Ok((out, meta))
}

fn safetensors_bytes(entries: &[Entry], meta: &serde_json::Map<String, serde_json::Value>) -> Vec<u8> {
    let mut header = serde_json::Map::new();
    header.insert("__metadata__".into(), serde_json::Value::Object(meta.clone()));
    let mut off = 0usize;
    for e in entries {
        header.insert(e.name.clone(), serde_json::json!({ "dtype": e.dtype, "shape": e.shape, "data_offsets": [off, off + e.data.len()] }));
        off += e.data.len();
    }
    let mut h = serde_json::to_vec(&header).expect("json");
    while !h.len().is_multiple_of(8) {
        h.push(b' ');
    }
    let mut out = (h.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(&h);
    entries.iter().for_each(|e| out.extend_from_slice(&e.data));
    out
}

/// A model file as `pipeline` loads it: F32 with its own (burn's) parameter names, whatever the
/// file holds (F16 or BF16 weights, PyTorch names); the bytes unchanged when they already are.
///
/// # Errors
/// As [`widen`] and [`from_torch`].
pub fn canonical(bytes: &[u8], name: &str) -> Result<Vec<u8>> {
    let wide = widen(bytes, name)?;
    let bytes = wide.as_deref().unwrap_or(bytes);
    Ok(from_torch(bytes, name)?.unwrap_or_else(|| bytes.to_vec()))
}

/// A model file whose half-precision tensors (F16, BF16) are widened to F32, the only type the
/// networks load; `None` when every tensor is F32 already. Shipped models are stored in F16
/// (half the bytes; a relative rounding of 2^-11, far below what changes an 8-bit output).
///
/// # Errors
/// Not safetensors, or a tensor whose byte count does not fit its type.
pub fn widen(bytes: &[u8], name: &str) -> Result<Option<Vec<u8>>> {
    let Ok((entries, meta)) = read_safetensors(bytes, name) else { return Ok(None) };
    if entries.iter().all(|e| e.dtype != "F16" && e.dtype != "BF16") {
        return Ok(None);
    }
    let mut out = Vec::with_capacity(entries.len());
    for e in entries {
        let is_f16 = match e.dtype.as_str() {
            "F16" => true,
            "BF16" => false,
            _ => {
                out.push(e);
                continue;
            }
        };
        if e.data.len() % 2 != 0 {
            let values = e.shape.iter().product();
            return Err(bad(name)(WeightsError::Size { key: e.name, bytes: e.data.len(), dtype: e.dtype, values }));
        }
        let data = e
            .data
            .chunks_exact(2)
            .flat_map(|c| {
                let bits = u16::from_le_bytes([c[0], c[1]]);
                let v = if is_f16 { half::f16::from_bits(bits).to_f32() } else { half::bf16::from_bits(bits).to_f32() };
                v.to_le_bytes()
            })
            .collect();
        out.push(Entry { dtype: "F32".into(), data, ..e });
    }
    Ok(Some(safetensors_bytes(&out, meta.as_object().unwrap_or(&serde_json::Map::new()))))
}

/// A model file's F32 tensors rounded to F16 (round to nearest even), for shipping; the loader
/// widens them back ([`widen`]). `half` is recorded in the metadata.
///
/// # Errors
/// Not safetensors; a weight beyond F16's range (65504), which rounding would make infinite.
pub fn narrow(bytes: &[u8], name: &str) -> Result<Vec<u8>> {
    let (entries, meta) = read_safetensors(bytes, name)?;
    let mut out = Vec::with_capacity(entries.len());
    for e in entries {
        if e.dtype != "F32" {
            out.push(e);
            continue;
        }
        let mut data = Vec::with_capacity(e.data.len() / 2);
        for c in e.data.chunks_exact(4) {
            let v = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
            let h = half::f16::from_f32(v);
            if h.is_infinite() && v.is_finite() {
                return Err(bad(name)(WeightsError::F16Range { key: e.name, value: v }));
            }
            data.extend_from_slice(&h.to_bits().to_le_bytes());
        }
        out.push(Entry { dtype: "F16".into(), data, ..e });
    }
    let mut m = meta.as_object().cloned().unwrap_or_default();
    m.insert("half".into(), "stored as F16; widened to F32 when loaded".into());
    Ok(safetensors_bytes(&out, &m))
}

/// Converts a model file's bytes to PyTorch names; adds each BatchNorm's `num_batches_tracked`.
///
/// # Errors
/// Not a model of ours (a name without a PyTorch counterpart), not safetensors.
pub fn to_torch(bytes: &[u8], name: &str) -> Result<(Vec<(String, Vec<usize>, String)>, Vec<u8>)> {
    let (entries, meta) = read_safetensors(bytes, name)?;
    let mut out = Vec::new();
    for e in entries {
        let t = torch_name(&e.name).ok_or_else(|| bad(name)(WeightsError::NoTorchName { key: e.name.clone() }))?;
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
    let written = safetensors_bytes(&out, &m);
    Ok((out.into_iter().map(|e| (e.name, e.shape, e.dtype)).collect(), written))
}

/// PyTorch name -> burn name for every parameter of a network of `arch`: the inverse of
/// [`torch_name`] over [`param_shapes`](crate::model::weights::param_shapes) (a test checks those
/// against burn's own names, so the two cannot drift apart).
fn burn_names(arch: crate::model::Arch) -> Result<std::collections::HashMap<String, String>> {
    Ok(crate::model::weights::param_shapes(arch).into_iter().filter_map(|(b, _)| torch_name(&b).map(|t| (t, b))).collect())
}

/// A model file written with PyTorch names (by `pipeline export`, or fine-tuned in PyTorch and
/// saved with `safetensors.torch.save_file`) turned back into the burn-named bytes `pipeline`
/// loads; `None` when the file already has burn names. The architecture comes from the
/// metadata, or from the first convolution's shape.
///
/// # Errors
/// A key that is not one of our networks', or no way to tell the architecture.
pub fn from_torch(bytes: &[u8], name: &str) -> Result<Option<Vec<u8>>> {
    // Not safetensors at all: the loader says why.
    let Ok((entries, meta)) = read_safetensors(bytes, name) else { return Ok(None) };
    if entries.iter().any(|e| e.name.starts_with("Unet.") || e.name.starts_with("Shallow.")) {
        return Ok(None);
    }
    let shape_of = |k: &str| entries.iter().find(|e| e.name == k).map(|e| e.shape.clone());
    let arch: crate::model::Arch = match meta.get("arch").and_then(|a| a.as_str()).and_then(|a| serde_json::from_str(a).ok()) {
        Some(a) => a,
        None => match (shape_of("inc.a.0.weight"), shape_of("blocks.0.0.weight")) {
            (Some(s), _) if shape_of("film.weight").is_some() => {
                let deep = (0..3).filter(|k| shape_of(&format!("ups.{k}.film.weight")).is_some()).count();
                crate::model::Arch::BurstUnet { base: s[0], levels: 1 + deep }
            }
            (Some(s), _) => crate::model::Arch::Unet { base: s[0] },
            (None, Some(s)) => crate::model::Arch::Shallow { width: s[0] },
            _ => return Err(bad(name)(WeightsError::NotPipeline)),
        },
    };
    let names = burn_names(arch)?;
    let mut out = Vec::new();
    for e in entries {
        if e.name.ends_with("num_batches_tracked") {
            continue;
        }
        let b = names.get(&e.name).cloned().ok_or_else(|| bad(name)(WeightsError::Extra { name: e.name.clone(), arch: arch.name() }))?;
        if !matches!(e.dtype.as_str(), "F32" | "F16" | "BF16") {
            return Err(bad(name)(WeightsError::Dtype { key: e.name, dtype: e.dtype }));
        }
        out.push(Entry { name: b, ..e });
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    let mut m = serde_json::Map::new();
    m.insert("arch".into(), serde_json::to_string(&arch).expect("json").into());
    m.insert("imported_from".into(), "pytorch state_dict".into());
    Ok(Some(safetensors_bytes(&out, &m)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[cfg(feature = "train")]
    fn the_parameter_list_is_burns() {
        use crate::model::Arch;
        use burn::store::{ModuleSnapshot, SafetensorsStore};
        for arch in [Arch::Unet { base: 4 }, Arch::burst(4), Arch::BurstUnet { base: 4, levels: 4 }, Arch::Shallow { width: 5 }] {
            let mut store = SafetensorsStore::from_bytes(None);
            crate::model::Net::new(arch, &burn::tensor::Device::flex()).save_into(&mut store).unwrap();
            let (entries, _) = read_safetensors(&store.get_bytes().unwrap(), "burn").unwrap();
            let mut burn: Vec<(String, Vec<usize>)> = entries.into_iter().map(|e| (e.name, e.shape)).collect();
            let mut ours = crate::model::weights::param_shapes(arch);
            burn.sort();
            ours.sort();
            assert_eq!(ours, burn, "{}", arch.name());
        }
    }

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
            ("Unet.film.beta", "film.bias"),
            ("Unet.up2.film.gamma", "ups.1.film.weight"),
            ("Shallow.blocks.8.conv.weight", "blocks.8.0.weight"),
            ("Shallow.blocks.0.bn.running_mean", "blocks.0.1.running_mean"),
            ("Shallow.out.weight", "out.weight"),
        ] {
            assert_eq!(torch_name(b).as_deref(), Some(t), "{b}");
        }
    }

    #[test]
    fn every_parameter_has_its_own_torch_name() {
        use crate::model::Arch;
        for (m, arch) in [
            (crate::model::infer::DEFAULT_MODEL, Arch::Unet { base: 32 }),
            (crate::model::infer::DEFAULT_BURST_MODEL, Arch::burst(32)),
            (include_bytes!("../../models/shallow32-coded/model.safetensors").as_slice(), Arch::Shallow { width: 32 }),
        ] {
            let (src, _) = read_safetensors(m, "m").unwrap();
            let inverse = burn_names(arch).unwrap();
            assert_eq!(inverse.len(), src.len(), "one torch name per parameter, none shared");
            for e in &src {
                assert_eq!(inverse.get(&torch_name(&e.name).unwrap()), Some(&e.name));
            }
        }
        // A key that is not ours (same length, so the header stays valid) is named.
        let mut torch = to_torch(crate::model::infer::DEFAULT_MODEL, "m").unwrap().1;
        let at = torch.windows(9).position(|w| w == b"outc.bias").unwrap();
        torch[at..at + 9].copy_from_slice(b"outc.zzzz");
        assert!(from_torch(&torch, "renamed").unwrap_err().to_string().contains("outc.zzzz"));
    }

    #[test]
    #[cfg(feature = "train")]
    fn half_precision_files_widen_back_within_f16_rounding_and_load() {
        // The shallow model is stored in F32.
        let src = include_bytes!("../../models/shallow32-coded/model.safetensors").as_slice();
        let half = narrow(src, "m").unwrap();
        assert!(half.len() < src.len() * 6 / 10, "{} bytes of {}", half.len(), src.len());
        assert!(widen(src, "m").unwrap().is_none(), "an F32 file passes through");
        let wide = widen(&half, "h").unwrap().expect("F16 widened");
        let (a, _) = read_safetensors(src, "a").unwrap();
        let (b, _) = read_safetensors(&wide, "b").unwrap();
        let f32s = |d: &[u8]| d.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect::<Vec<_>>();
        let mut worst = 0f32;
        for (x, y) in a.iter().zip(&b) {
            assert_eq!((&x.name, &x.shape, "F32"), (&y.name, &y.shape, y.dtype.as_str()));
            for (u, v) in f32s(&x.data).into_iter().zip(f32s(&y.data)) {
                // F16 keeps 11 significant bits; below 2^-14 it is subnormal (absolute 2^-24).
                worst = worst.max((u - v).abs() / u.abs().max(6.1e-5));
            }
        }
        assert!(worst > 0.0 && worst <= 1.0 / 2048.0, "worst relative rounding {worst}");
        let dev = burn::tensor::Device::flex();
        let (_, arch) = crate::model::checkpoint::load_model_bytes(&half, "half", &dev).unwrap();
        assert_eq!(arch, crate::model::Arch::Shallow { width: 32 });
        // A weight beyond F16's range is refused by name rather than stored as infinity.
        let (mut e, m) = read_safetensors(src, "m").unwrap();
        e[0].data[..4].copy_from_slice(&1e6f32.to_le_bytes());
        let big = safetensors_bytes(&e, m.as_object().unwrap());
        let err = narrow(&big, "big").unwrap_err().to_string();
        assert!(err.contains(&e[0].name) && err.contains("F16"), "{err}");
    }

    #[test]
    #[cfg(feature = "train")]
    fn an_exported_model_loads_back_with_the_same_weights() {
        let (_, torch) = to_torch(crate::model::infer::DEFAULT_MODEL, "embedded").unwrap();
        let back = from_torch(&torch, "t").unwrap().expect("torch names are converted");
        let dev = burn::tensor::Device::flex();
        let (a, arch_a) = crate::model::checkpoint::load_model_bytes(crate::model::infer::DEFAULT_MODEL, "a", &dev).unwrap();
        let (b, arch_b) = crate::model::checkpoint::load_model_bytes(&back, "b", &dev).unwrap();
        assert_eq!(arch_a, arch_b);
        let x = burn::tensor::Tensor::<4>::from_data(
            burn::tensor::TensorData::new((0..3 * 32 * 32).map(|i| (i % 97) as f32 / 97.0).collect::<Vec<_>>(), [1, 3, 32, 32]),
            &dev,
        );
        let (ya, yb) =
            (a.forward(x.clone()).into_data().try_to_vec::<f32>().unwrap(), b.forward(x).into_data().try_to_vec::<f32>().unwrap());
        assert_eq!(ya, yb);
        assert!(from_torch(crate::model::infer::DEFAULT_MODEL, "burn").unwrap().is_none(), "burn names pass through");
    }

    #[test]
    fn the_shipped_unet_exports_every_tensor_with_torch_names_and_the_same_data() {
        let (names, bytes) = to_torch(crate::model::infer::DEFAULT_MODEL, "embedded").unwrap();
        // 100 burn tensors plus one num_batches_tracked per BatchNorm (18 in a U-Net).
        assert_eq!(names.len(), 118);
        let find = |n: &str| names.iter().find(|(k, _, _)| k == n).unwrap_or_else(|| panic!("{n} missing"));
        assert_eq!(find("ups.0.up.weight").1, vec![256, 256, 2, 2]);
        assert_eq!(find("inc.a.0.weight").1, vec![32, 3, 3, 3]);
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
