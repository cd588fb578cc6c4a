//! Writes a file under a temporary name in the same folder, then renames it, so a reader never
//! sees half a file and an interrupted run leaves the old file (or none) in place.

use std::io::Write;
use std::path::{Path, PathBuf};

/// This machine's name (Slurm and Kubernetes runs share folders across machines: a process id
/// means something only on the machine that wrote it).
pub fn host() -> &'static str {
    static H: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    H.get_or_init(|| {
        let mut buf = [0u8; 256];
        // SAFETY: the buffer is valid for its length; gethostname writes a NUL-terminated name.
        let ok = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) } == 0;
        let n = buf.iter().position(|&b| b == 0).unwrap_or(0);
        let h: String = String::from_utf8_lossy(&buf[..if ok { n } else { 0 }])
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '.' { c } else { '_' })
            .collect();
        if h.is_empty() {
            "localhost".into()
        } else {
            h
        }
    })
}

/// The hidden name a file is written under before it is renamed to `name`:
/// `.{name}~{host}~{pid}.tmp`, plus `.{ext}` when a writer picks its format by extension
/// (FFmpeg). [`remove_stale`] recognises it.
pub fn temp_name(name: &str, ext: Option<&str>) -> String {
    let base = format!(".{name}~{}~{}.tmp", host(), std::process::id());
    match ext {
        Some(e) => format!("{base}.{e}"),
        None => base,
    }
}

/// The temporary name used while `path` is written.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(temp_name(&name, None))
}

/// The file name, host and process id of a temporary name made by [`temp_name`]:
/// `.{name}~{host}~{pid}.tmp`, optionally followed by `.{ext}`. Nothing else is recognised, so a
/// sweep never takes a user's own `.something.tmp` for one of ours.
fn temp_parts(name: &str) -> Option<(&str, &str, u32)> {
    let rest = name.strip_prefix('.')?;
    let i = rest.rfind(".tmp")?;
    let (head, tail) = (&rest[..i], &rest[i + 4..]);
    let ext_ok = tail.is_empty() || (tail.len() > 1 && tail.starts_with('.') && !tail[1..].contains(['.', '~']));
    if !ext_ok {
        return None;
    }
    let mut parts = head.rsplitn(3, '~');
    let (pid, h, base) = (parts.next()?, parts.next()?, parts.next()?);
    let pid_ok = !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit());
    let host_ok = !h.is_empty() && h.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '.' || c == '_');
    if !pid_ok || !host_ok || base.is_empty() {
        return None;
    }
    Some((base, h, pid.parse().ok()?))
}

/// Whether `name` has the form of a temporary made by [`temp_name`].
pub fn is_temp_name(name: &str) -> bool {
    temp_parts(name).is_some()
}

/// Host and process id of a temporary name made by [`temp_name`].
#[cfg(test)]
fn temp_owner(name: &str) -> Option<(String, u32)> {
    temp_parts(name).map(|(_, h, p)| (h.to_string(), p))
}

/// Whether process `pid` runs on this machine.
fn alive(pid: u32) -> bool {
    // SAFETY: signal 0 only checks that the process exists and may be signalled.
    let r = unsafe { libc::kill(pid as libc::pid_t, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

/// Removes the temporary files that killed runs left in `dir` and its folders down to `depth`
/// levels: only files of this machine whose process is gone (a live run's files and other
/// machines' are left alone). Returns what was removed.
pub fn remove_stale(dir: &Path, depth: usize) -> Vec<PathBuf> {
    let mut removed = Vec::new();
    let Ok(rd) = std::fs::read_dir(dir) else {
        return removed;
    };
    for e in rd.flatten() {
        let p = e.path();
        let Ok(ft) = e.file_type() else { continue };
        if ft.is_dir() {
            if depth > 0 {
                removed.extend(remove_stale(&p, depth - 1));
            }
            continue;
        }
        let name = e.file_name();
        if name.to_str().and_then(temp_parts).is_some_and(|(_, h, pid)| stale(h, pid)) && std::fs::remove_file(&p).is_ok() {
            removed.push(p);
        }
    }
    removed.sort();
    removed
}

/// Whether a temporary of `host`'s process `pid` was left by a run that is gone: this machine,
/// another process than this one, and not running.
fn stale(h: &str, pid: u32) -> bool {
    h == host() && pid != std::process::id() && !alive(pid)
}

/// Removes the temporaries that killed runs left for the files `targets` (each one's
/// `.{name}~{host}~{pid}.tmp[.ext]` in its own folder), and nothing else: for commands whose
/// output sits in a folder they do not own (`deblur a.png -o dir/b.png` owns `dir/b.png`, not
/// `dir`). Returns what was removed.
pub fn remove_stale_for(targets: &[PathBuf]) -> Vec<PathBuf> {
    let mut by_dir: std::collections::BTreeMap<PathBuf, std::collections::BTreeSet<String>> = Default::default();
    for t in targets {
        let (Some(dir), Some(name)) = (t.parent(), t.file_name()) else { continue };
        let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
        by_dir.entry(dir.to_path_buf()).or_default().insert(name.to_string_lossy().into_owned());
    }
    let mut removed = Vec::new();
    for (dir, names) in by_dir {
        let Ok(rd) = std::fs::read_dir(&dir) else { continue };
        for e in rd.flatten() {
            let n = e.file_name();
            let Some((base, h, pid)) = n.to_str().and_then(temp_parts) else { continue };
            let file = e.file_type().is_ok_and(|t| t.is_file() || t.is_symlink());
            if file && names.contains(base) && stale(h, pid) && std::fs::remove_file(e.path()).is_ok() {
                removed.push(e.path());
            }
        }
    }
    removed.sort();
    removed
}

/// Creates `path` as a new file for writing, never through a symbolic link: whatever a killed
/// run (or anyone) left at that temporary name is removed first (a link itself, not what it
/// points to), then the file is made with `O_CREAT | O_EXCL`, which refuses to follow a link
/// planted between the two steps.
///
/// # Errors
/// The file cannot be made.
pub fn create_new(path: &Path) -> std::io::Result<std::fs::File> {
    let _ = std::fs::remove_file(path);
    std::fs::OpenOptions::new().write(true).create_new(true).open(path)
}

/// Opens (creating it) a lock file, refusing a symbolic link at its name: a planted
/// `out/.manifest.json.lock -> /elsewhere/x` must not make the tool create `/elsewhere/x`.
///
/// # Errors
/// The file is a symbolic link or cannot be opened; the error names it.
pub fn open_lock(path: &Path) -> crate::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .custom_flags(libc::O_NOFOLLOW)
        .open(path)
        .map_err(|e| link_error(path, e))
}

/// Creates the folder `root.join(sub)` for the tool's own output: `root` as the user named it
/// (links in it are theirs), then each folder of `sub` in turn, refusing one that is a symbolic
/// link: a planted `out/reports -> /elsewhere` must not send files there.
///
/// # Errors
/// A folder of `sub` is a symbolic link or cannot be made; the error names it.
pub fn make_dir_in(root: &Path, sub: &Path) -> crate::Result<PathBuf> {
    std::fs::create_dir_all(root).map_err(|e| crate::Error::Io { path: root.to_path_buf(), cause: e })?;
    let mut p = root.to_path_buf();
    for c in sub.components() {
        p.push(c);
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => return Err(link_error(&p, std::io::Error::from_raw_os_error(libc::ELOOP))),
            Ok(m) if m.is_dir() => {}
            _ => match std::fs::create_dir(&p) {
                Err(e) if e.kind() != std::io::ErrorKind::AlreadyExists => return Err(crate::Error::Io { path: p, cause: e }),
                _ => {}
            },
        }
    }
    Ok(p)
}

/// Opens `path` for appending (made if missing), never through a symbolic link.
///
/// # Errors
/// It is a link or cannot be opened; the error names it.
pub fn open_append(path: &Path) -> crate::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new().create(true).append(true).custom_flags(libc::O_NOFOLLOW).open(path).map_err(|e| link_error(path, e))
}

/// An I/O error at `path`, worded for a symbolic link where that is the cause.
fn link_error(path: &Path, e: std::io::Error) -> crate::Error {
    if e.raw_os_error() == Some(libc::ELOOP) {
        return crate::Error::Io {
            path: path.to_path_buf(),
            cause: std::io::Error::other("a symbolic link where the tool writes its own file; remove it (links are not followed)"),
        };
    }
    crate::Error::Io { path: path.to_path_buf(), cause: e }
}

/// Calls `fill` with a buffered writer on a temporary file, flushes and syncs it, then renames
/// it to `path`. On any error the temporary file is removed and `path` is untouched.
///
/// # Errors
/// Creating, writing or renaming fails; the error names `path`.
pub fn write_atomic<F>(path: &Path, fill: F) -> crate::Result<()>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    let tmp = temp_path(path);
    let res = (|| {
        let f = create_new(&tmp)?;
        let mut w = std::io::BufWriter::new(f);
        fill(&mut w)?;
        let f = w.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(crate::Error::Io { path: path.to_path_buf(), cause: e });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = crate::io::paths::scratch_dir("atomic");
        let p = dir.join("a.bin");
        write_atomic(&p, |w| w.write_all(b"old")).unwrap();
        let err = write_atomic(&p, |w| {
            w.write_all(b"half")?;
            Err(std::io::Error::other("interrupted"))
        });
        assert!(err.is_err());
        assert_eq!(std::fs::read(&p).unwrap(), b"old");
        assert!(!temp_path(&p).exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn temporary_names_carry_their_owner() {
        let me = (host().to_string(), std::process::id());
        assert_eq!(temp_owner(&temp_name("train-a.tar", None)), Some(me.clone()));
        assert_eq!(temp_owner(&temp_name("out", Some("mp4"))), Some(me.clone()));
        assert_eq!(temp_owner(".x~node-7.cluster~123.tmp"), Some(("node-7.cluster".into(), 123)));
        // Only the exact pattern: older and foreign names are a user's files.
        for other in [
            "a.tmp",
            ".hidden",
            ".x.tar",
            "x~h~1.tmp",
            ".a.tmpfile",
            ".train-00000-0000.tar.4242.tmp",
            ".sharp.tmp-99.mp4",
            ".notes.txt.999999.tmp",
            ".~h~1.tmp",
            ".a~h~x1.tmp",
        ] {
            assert_eq!(temp_owner(other), None, "{other}");
        }
    }

    #[test]
    fn stale_temporaries_of_dead_processes_go_and_live_ones_stay() {
        let dir = std::env::temp_dir().join(format!("pipeline-stale-{}", std::process::id()));
        let sub = dir.join("k").join("sharp");
        std::fs::create_dir_all(&sub).unwrap();
        // A process that has exited: its id is free (until reused, which this test accepts).
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let dead_file = sub.join(format!(".000001.png~{}~{dead}.tmp", host()));
        let legacy = dir.join(format!(".train-00000-0000.tar~{}~{dead}.tmp", host()));
        let mine = temp_path(&dir.join("report.json"));
        let other_host = dir.join(format!(".a.tar~not-{}~{dead}.tmp", host()));
        let plain = dir.join("data.tar");
        for p in [&dead_file, &legacy, &mine, &other_host, &plain] {
            std::fs::write(p, b"x").unwrap();
        }
        let removed = remove_stale(&dir, 3);
        assert_eq!(removed, {
            let mut v = vec![legacy.clone(), dead_file.clone()];
            v.sort();
            v
        });
        assert!(mine.exists() && other_host.exists() && plain.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_sweep_for_named_targets_removes_only_their_temporaries() {
        let dir = crate::io::paths::scratch_dir("stale-for");
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let ours = dir.join(format!(".out.png~{}~{dead}.tmp", host()));
        let ours_video = dir.join(format!(".out.mkv~{}~{dead}.tmp.mkv", host()));
        let users = [dir.join(format!(".draft~{}~{dead}.tmp", host())), dir.join(".notes.txt.999999.tmp")];
        for p in users.iter().chain([&ours, &ours_video]) {
            std::fs::write(p, b"x").unwrap();
        }
        let removed = remove_stale_for(&[dir.join("out.png"), dir.join("out.mkv")]);
        assert_eq!(removed, vec![ours_video.clone(), ours.clone()]);
        assert!(users.iter().all(|p| p.exists()));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn locks_and_temporaries_never_follow_a_planted_link() {
        let dir = std::env::temp_dir().join(format!("pipeline-links-{}", std::process::id()));
        let outside = dir.join("outside");
        std::fs::create_dir_all(&outside).unwrap();
        let lock = dir.join(".manifest.json.lock");
        std::os::unix::fs::symlink(outside.join("x"), &lock).unwrap();
        let e = open_lock(&lock).unwrap_err().to_string();
        assert!(e.contains("symbolic link") && e.contains(".manifest.json.lock"), "{e}");
        // A link planted at the temporary name of a file: the write goes to the folder, not through it.
        let target = dir.join("report.json");
        std::os::unix::fs::symlink(outside.join("y"), temp_path(&target)).unwrap();
        write_atomic(&target, |w| w.write_all(b"{}")).unwrap();
        std::os::unix::fs::symlink(&outside, dir.join("reports")).unwrap();
        assert!(make_dir_in(&dir, Path::new("reports")).unwrap_err().to_string().contains("symbolic link"));
        assert!(make_dir_in(&dir, Path::new("reports/a")).unwrap_err().to_string().contains("symbolic link"));
        assert_eq!(make_dir_in(&dir, Path::new("train/sharp")).unwrap(), dir.join("train/sharp"));
        assert_eq!(std::fs::read_dir(&outside).unwrap().count(), 0, "nothing was made outside");
        assert_eq!(std::fs::read(&target).unwrap(), b"{}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
