//! Checkpoints: a model as safetensors (architecture, config and step in the metadata) plus
//! the optimizer state, `latest.json`, and loading a model file with its checks.

use crate::io::write_atomic;
use crate::model::{Arch, Net};
use crate::{Error, Result};
use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// What `latest.json` in the output folder says.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
        let latest: Latest = serde_json::from_slice(&bytes).map_err(|e| Error::File { path: lp.to_path_buf(), why: e.to_string() })?;
        let model = crate::io::paths::inside(dir, &latest.model, &lp, "model")?;
        let optimizer = crate::io::paths::inside(dir, &latest.optimizer, &lp, "optimizer")?;
        Ok(Some((latest, model, optimizer)))
    }
}

/// Collects the ids of the trainable parameters in traversal order.
pub(crate) struct IdCollector(Vec<u64>);

impl ModuleVisitor for IdCollector {
    fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
        self.0.push(p.id.val());
    }
}

/// Gives the parameters, in traversal order, the ids they had when the checkpoint was written:
/// the optimizer state is keyed by parameter id, and a model loaded from safetensors gets
/// fresh ids.
pub(crate) struct IdSetter {
    pub ids: Vec<u64>,
    pub next: usize,
}

impl ModuleMapper for IdSetter {
    fn map_float<const D: usize>(&mut self, mut p: Param<Tensor<D>>) -> Param<Tensor<D>> {
        if let Some(&id) = self.ids.get(self.next) {
            p.id = ParamId::from(id);
        }
        self.next += 1;
        p
    }
}

/// Saves the model (safetensors; architecture, seed and step in the metadata) and the optimizer state.
pub fn save_checkpoint(dir: &Path, model: &Net, optim_bytes: Vec<u8>, arch: &Arch, seed: u64, step: usize) -> Result<Latest> {
    let name = format!("model-{step:07}.safetensors");
    save_model(&dir.join(&name), model, arch, seed, step)?;
    let oname = format!("optim-{step:07}.bin");
    write_atomic(&dir.join(&oname), |w| w.write_all(&optim_bytes))?;
    let latest = Latest { step, model: name, optimizer: oname };
    let bytes = serde_json::to_vec_pretty(&latest).expect("json");
    write_atomic(&dir.join("latest.json"), |w| w.write_all(&bytes))?;
    Ok(latest)
}

/// Saves a model file (safetensors; architecture, seed and step in the metadata).
pub fn save_model(path: &Path, model: &Net, arch: &Arch, seed: u64, step: usize) -> Result<()> {
    let mut store = SafetensorsStore::from_file(path)
        .metadata("pipeline_version", env!("CARGO_PKG_VERSION"))
        .metadata("arch", serde_json::to_string(arch).expect("json"))
        .metadata("step", step.to_string())
        .metadata("seed", seed.to_string())
        .metadata("input", "[n, 3, h, w] encoded sRGB in [0, 1]; output = input + residual")
        .metadata("param_ids", {
            let mut c = IdCollector(Vec::new());
            model.visit(&mut c);
            serde_json::to_string(&c.0).expect("json")
        })
        .overwrite(true);
    model.save_into(&mut store).map_err(|e| Error::File { path: path.to_path_buf(), why: e.to_string() })?;
    // burn writes the file owner-only (0600); a checkpoint is meant to be shared like any output.
    {
        use std::os::unix::fs::PermissionsExt;
        let _ = std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o644));
    }
    Ok(())
}

/// Loads a model file written by `pipeline train` (or a model folder holding `model.safetensors`),
/// checking its architecture and that every weight is finite.
///
/// # Errors
/// A missing or truncated file, or weights of another architecture (named).
pub fn load_model(path: &Path, device: &Device) -> Result<(Net, Arch)> {
    // A folder stands for the model file `model_in` picks.
    let file;
    let path = if path.is_dir() {
        file = model_in(path)?;
        file.as_path()
    } else {
        path
    };
    let bytes = crate::io::paths::read_regular(path, crate::io::paths::MAX_MODEL_BYTES, "safetensors model file")?;
    load_model_bytes(&bytes, &path.display().to_string(), device)
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

/// As [`load_model`], from the bytes of a model file; `name` names it in errors.
///
/// # Errors
/// As [`load_model`].
pub fn load_model_bytes(bytes: &[u8], name: &str, device: &Device) -> Result<(Net, Arch)> {
    // Half-precision weights (the shipped models) are widened, and a model with PyTorch names
    // (exported, or fine-tuned in PyTorch) is renamed, first.
    let bytes = crate::model::torch::canonical(bytes, name)?;
    let path = Path::new(name);
    let arch = read_arch(&bytes).map_err(|e| Error::File { path: path.to_path_buf(), why: e.to_string() })?;
    let mut net = Net::new(arch, device);
    let mut store = SafetensorsStore::from_bytes(Some(bytes));
    let r = net
        .load_from(&mut store)
        .map_err(|e| Error::File { path: path.to_path_buf(), why: format!("not loadable as {} ({e})", arch.name()) })?;
    if !r.errors.is_empty() || !r.missing.is_empty() {
        return Err(Error::File {
            path: path.to_path_buf(),
            why: format!("weights do not fit {} ({} missing, {} errors)", arch.name(), r.missing.len(), r.errors.len()),
        });
    }
    // A model with NaN or infinite weights would write black frames: refuse it by name.
    struct Finite(usize);
    impl ModuleVisitor for Finite {
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            self.0 += p.val().into_data().try_to_vec::<f32>().map_or(0, |v| v.iter().filter(|x| !x.is_finite()).count());
        }
    }
    let mut bad = Finite(0);
    net.visit(&mut bad);
    if bad.0 > 0 {
        return Err(Error::File {
            path: path.to_path_buf(),
            why: format!("{} weights are not finite (NaN or infinite); the model cannot be used", bad.0),
        });
    }
    Ok((net, arch))
}

/// The JSON header of a safetensors file.
fn read_header(bytes: &[u8]) -> std::result::Result<serde_json::Value, String> {
    if bytes.len() < 8 {
        return Err("truncated: no safetensors header".into());
    }
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
    let header = bytes.get(8..8usize.saturating_add(n)).ok_or("truncated safetensors header")?;
    serde_json::from_slice(header).map_err(|e| format!("bad safetensors header ({e})"))
}

/// The `__metadata__` of a safetensors header.
pub fn read_meta(bytes: &[u8]) -> std::result::Result<serde_json::Value, String> {
    Ok(read_header(bytes)?["__metadata__"].clone())
}

/// The `arch` entry of a safetensors header's metadata, checked before anything is allocated
/// for it: within the sizes `pipeline train` accepts, and no larger than the weights the file
/// declares (a network of width `b` has at least one b-to-b 3x3 convolution, 9 b^2 weights).
pub fn read_arch(bytes: &[u8]) -> std::result::Result<Arch, String> {
    let header = read_header(bytes)?;
    let arch = header["__metadata__"]["arch"].as_str().ok_or("no `arch` in the metadata: not a pipeline model")?;
    let parsed: Arch = serde_json::from_str(arch).map_err(|e| format!("unknown arch {arch:?} ({e})"))?;
    let (b, max) = match parsed {
        Arch::Unet { base } | Arch::BurstUnet { base } => (base, 256),
        Arch::Shallow { width } => (width, 1024),
    };
    if b == 0 || b > max {
        return Err(format!("the metadata names {arch}, outside 1 to {max} filters"));
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
        return Err(format!("the metadata names {} (at least {} weights) but the file declares {declared}", parsed.name(), 9 * b * b));
    }
    Ok(parsed)
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
        assert!(e.contains("unet") && e.contains("outside 1 to 256"), "{e}");
        let e = read_arch(&file(r#"{"type":"shallow","width":200}"#, &[3, 3])).unwrap_err();
        assert!(e.contains("at least 360000 weights") && e.contains("declares 9"), "{e}");
        assert_eq!(read_arch(&file(r#"{"type":"shallow","width":2}"#, &[4, 9])).unwrap(), Arch::Shallow { width: 2 });
        assert_eq!(read_arch(crate::model::infer::DEFAULT_MODEL).unwrap(), Arch::Unet { base: 32 });
    }
}
