//! Checkpoints: a model as safetensors (architecture, config and step in the metadata) plus
//! the optimizer state, `latest.json`, and loading a model file with its checks.

use crate::io::write_atomic;
use crate::model::{Arch, Net};
use crate::{Error, Result};
use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::{Device, Tensor};
use std::path::Path;

pub use crate::model::weights::{model_in, read_arch, read_meta, Latest};

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
    model.save_into(&mut store).map_err(|e| Error::Serialise { what: path.display().to_string(), source: Box::new(e) })?;
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
    let (bytes, name) = crate::model::weights::read_model_file(path)?;
    load_model_bytes(&bytes, &name, device)
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
    let arch = read_arch(&bytes).map_err(Error::format(path))?;
    let mut net = Net::new(arch, device);
    let mut store = SafetensorsStore::from_bytes(Some(bytes));
    let r = net.load_from(&mut store).map_err(|e| Error::Unloadable {
        path: path.to_path_buf(),
        why: format!("not loadable as {}", arch.name()),
        source: Box::new(e),
    })?;
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
