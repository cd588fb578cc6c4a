use super::*;

/// Takes `dir/.train.lock` for the life of the run: a second `pipeline train` into the same
/// folder is refused rather than left to overwrite the first one's checkpoints.
///
/// # Errors
/// The lock is held by another process (a usage error naming the folder), or cannot be made.
pub(super) fn lock_run_folder(dir: &Path) -> Result<std::fs::File> {
    let lp = dir.join(".train.lock");
    let f = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&lp)
        .map_err(|e| Error::Io { path: lp.clone(), cause: e })?;
    match f.try_lock() {
        Ok(()) => Ok(f),
        Err(std::fs::TryLockError::WouldBlock) => Err(Error::Usage(format!(
            "{}: another `pipeline train` is writing to this folder (it holds {}); wait for it to finish or choose another output.dir",
            dir.display(),
            lp.display()
        ))),
        Err(std::fs::TryLockError::Error(e)) => Err(Error::Io { path: lp, cause: e }),
    }
}

/// The files a training run writes in its folder.
pub(super) fn run_files(dir: &Path) -> Vec<PathBuf> {
    let fixed = ["latest.json", "report.json", "history.csv", "curves.png", "model.safetensors"];
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            let n = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            fixed.contains(&n.as_str())
                || (n.starts_with("model-") && n.ends_with(".safetensors"))
                || (n.starts_with("optim-") && n.ends_with(".bin"))
                || (n.starts_with("stream-") && n.ends_with(".json"))
        })
        .collect();
    v.sort();
    v
}

/// `--resume` continues the learning-rate schedule the run started with: a changed one would
/// jump (more `optim.steps` raises the cosine's rate again), so it is refused, naming the keys.
pub(super) fn schedule_unchanged(was: &serde_json::Value, now: &OptimConfig, dir: &Path) -> Result<()> {
    let now = serde_json::to_value(now).expect("json");
    let changed: Vec<String> = ["steps", "lr", "warmup_steps", "lr_min_factor", "schedule"]
        .iter()
        .filter(|k| was.get(**k).is_some() && was.get(**k) != now.get(**k))
        .map(|k| format!("optim.{k} {} -> {}", was[*k], now[*k]))
        .collect();
    if changed.is_empty() {
        return Ok(());
    }
    Err(Error::Usage(format!(
        "{}: --resume continues the run's learning-rate schedule, and this changes it ({}); resume without the change, or \
         train further on a new schedule with --set init={:?} and a fresh output.dir",
        dir.display(),
        changed.join(", "),
        dir.display().to_string()
    )))
}

/// A run that does not resume starts in a folder without one: refused when the folder holds a
/// run, unless `overwrite`, which removes that run's files first (so no old checkpoint is left
/// beside the new ones).
///
/// # Errors
/// The folder holds a run and `overwrite` is off (a usage error saying what to do instead).
pub(super) fn fresh_run_folder(dir: &Path, overwrite: bool) -> Result<()> {
    let files = run_files(dir);
    if files.is_empty() {
        return Ok(());
    }
    if !overwrite {
        let step = std::fs::read(dir.join("latest.json")).ok().and_then(|b| serde_json::from_slice::<Latest>(&b).ok()).map(|l| l.step);
        return Err(Error::Usage(format!(
            "{} holds a training run ({}{} files): add --resume to continue it, train a new model from it with --set init={:?} and a fresh \
             output.dir, or choose a fresh output.dir (--overwrite deletes that run)",
            dir.display(),
            step.map_or(String::new(), |s| format!("step {s}, ")),
            files.len(),
            dir.display().to_string()
        )));
    }
    for f in files {
        std::fs::remove_file(&f).map_err(|e| Error::Io { path: f, cause: e })?;
    }
    Ok(())
}
