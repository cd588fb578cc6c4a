//! `pipeline validate`: checks settings files of every kind `pipeline` reads (pipelines,
//! training, eval, deblur and optics files) and reports every error, each naming its key.

use crate::optics::request::OpticsFile;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct ValidateArgs {
    /// Pipeline files.
    #[arg(required = true)]
    pub pipelines: Vec<PathBuf>,
    /// key.path=value overrides, as for `run`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
}

/// Checks a TOML file of any kind `pipeline` reads: a training file (`[model]`), an optics
/// file (`[optics]`/`[camera]` only) or a pipeline; says what it is.
pub fn describe(table: toml::Table, origin: &crate::config::Origin) -> crate::Result<String> {
    let origin_name = origin.name.as_str();
    #[cfg(all(feature = "infer", feature = "ffmpeg"))]
    if table.contains_key("eval") {
        let f = crate::commands::eval::EvalFile::from_table(table, origin_name)?;
        return Ok(format!("eval file: N {:?}, sigma {:?}, camera {}", f.eval.windows, f.eval.sigmas, f.camera.kind.name()));
    }
    #[cfg(feature = "infer")]
    if table.contains_key("deblur") {
        let f = crate::commands::deblur::DeblurFile::from_table(table, origin_name)?;
        return Ok(format!("deblur file: tiles {} px, overlap {}", f.deblur.tile, f.deblur.overlap));
    }
    #[cfg(feature = "train")]
    if table.contains_key("model") {
        let (cfg, mut errs) = crate::config::deserialize_all::<crate::train::TrainConfig>(&table);
        if let Some(c) = &cfg {
            errs.extend(c.validate());
        }
        match cfg {
            Some(cfg) if errs.is_empty() => return Ok(format!("training file: {}, {} steps", cfg.model.name(), cfg.optim.steps)),
            _ => return Err(origin.errors(errs)),
        }
    }
    if !table.contains_key("sources") && (table.contains_key("optics") || table.contains_key("camera")) {
        let f: OpticsFile = toml::Value::Table(table).try_into().map_err(crate::Error::toml(origin_name, None))?;
        let mut errs = f.optics.validate("optics");
        if let Some(c) = &f.camera {
            errs.extend(c.validate("camera"));
        }
        if !errs.is_empty() {
            return Err(crate::Error::Config(errs));
        }
        return Ok(format!("optics file: Airy radius {:.2} px", f.optics.airy_radius_ref_px()));
    }
    let plan = crate::config::plan_from(table, origin)?;
    Ok(plan.stages.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>().join(" -> "))
}

/// Runs `pipeline validate`.
///
/// # Errors
/// Whatever the command reports (exit codes in `main.rs`).
pub fn command(a: ValidateArgs) -> anyhow::Result<()> {
    let ValidateArgs { pipelines, sets } = a;
    let mut bad = 0;
    for p in &pipelines {
        let origin = crate::config::Origin::new(&p.display().to_string(), None, &sets);
        match crate::config::load(p, &sets).and_then(|t| describe(t, &origin)) {
            Ok(what) => println!("{}: ok ({what})", p.display()),
            Err(e) => {
                bad += 1;
                for line in e.to_string().lines() {
                    println!("{}: {line}", p.display());
                }
            }
        }
    }
    if bad > 0 {
        return Err(crate::Error::Config(vec![crate::checks::ConfigError {
            key: "validate".into(),
            message: format!("{bad} of {} pipeline files have errors", pipelines.len()),
        }])
        .into());
    }
    Ok(())
}
