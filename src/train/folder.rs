use super::*;

/// Takes `dir/.train.lock` for the life of the run: a second `pipeline train` into the same
/// folder is refused rather than left to overwrite the first one's checkpoints.
///
/// # Errors
/// The lock is held by another process (a usage error naming the folder), or cannot be made.
pub(super) fn lock_run_folder(dir: &Path) -> Result<std::fs::File> {
    let lp = dir.join(".train.lock");
    let f = crate::io::open_lock(&lp)?;
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

/// Whether `n` (a file in a run folder) is one a training run writes. A `report.json` counts only
/// when it is a training report: `generate` writes one too.
fn is_run_file(dir: &Path, n: &str) -> bool {
    let fixed = ["latest.json", "history.csv", "curves.png", "model.safetensors"];
    fixed.contains(&n)
        || (n == "report.json" && is_train_report(&dir.join(n)))
        || (n.starts_with("model-") && n.ends_with(".safetensors"))
        || (n.starts_with("optim-") && n.ends_with(".bin"))
        || (n.starts_with("stream-") && n.ends_with(".json"))
}

/// A training run's `report.json` (it names the architecture and the metrics' convention).
fn is_train_report(p: &Path) -> bool {
    let small = std::fs::symlink_metadata(p).is_ok_and(|m| m.is_file() && m.len() < 256 << 20);
    small
        && std::fs::read(p)
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .is_some_and(|v| v.get("arch").is_some() && v.get("metrics_convention").is_some())
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).into_iter().flatten().flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

/// The files a training run writes in its folder.
pub(super) fn run_files(dir: &Path) -> Vec<PathBuf> {
    names(dir).into_iter().filter(|n| is_run_file(dir, n)).map(|n| dir.join(n)).collect()
}

/// A run's folder is its own: one that holds what a training run does not write (a generate
/// folder's shards, manifest and report; anything else but config files) is refused, with or
/// without `--overwrite`, before anything is written in it.
///
/// # Errors
/// A usage error naming the folder and up to three of the other files.
pub(super) fn own_folder(dir: &Path) -> Result<()> {
    if std::fs::symlink_metadata(dir).is_ok_and(|m| !m.is_dir()) {
        return Err(Error::Usage(format!("{} (output.dir) is a file, not a folder; name a folder for the run", dir.display())));
    }
    let other: Vec<String> = names(dir)
        .into_iter()
        .filter(|n| !is_run_file(dir, n) && n != ".train.lock" && !n.ends_with(".toml") && !crate::io::atomic::is_temp_name(n))
        .collect();
    if other.is_empty() {
        return Ok(());
    }
    let mut shown: Vec<&str> = other.iter().take(3).map(String::as_str).collect();
    let more = if other.len() > 3 { format!(" and {} more", other.len() - 3) } else { String::new() };
    shown.sort();
    Err(Error::Usage(format!(
        "{} (output.dir) holds files a training run does not write ({}{more}): a run needs a folder of its own, which it makes if missing; \
         choose another output.dir",
        dir.display(),
        shown.join(", ")
    )))
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
