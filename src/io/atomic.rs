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

/// Host and process id of a temporary name made by [`temp_name`], or by versions before it
/// (`.{name}.{pid}.tmp`, `.{stem}.tmp-{pid}.{ext}`, this host).
fn temp_owner(name: &str) -> Option<(String, u32)> {
    let rest = name.strip_prefix('.')?;
    if let Some(i) = rest.rfind(".tmp") {
        let (head, tail) = (&rest[..i], &rest[i + 4..]);
        if tail.is_empty() || (tail.starts_with('.') && !tail[1..].contains(['.', '~'])) {
            let mut parts = head.rsplitn(3, '~');
            if let (Some(pid), Some(h), Some(_)) = (parts.next(), parts.next(), parts.next()) {
                return pid.parse().ok().map(|p| (h.to_string(), p));
            }
            // Before host names: `.{name}.{pid}.tmp`.
            if tail.is_empty() {
                let pid = head.rsplit('.').next()?;
                return pid.parse().ok().map(|p| (host().to_string(), p));
            }
        }
        // `.{stem}.tmp-{pid}.{ext}` (deblur before host names).
        let t = tail.strip_prefix('-')?;
        return t.split('.').next()?.parse().ok().map(|p| (host().to_string(), p));
    }
    None
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
        let Some((h, pid)) = name.to_str().and_then(temp_owner) else { continue };
        if h == host() && pid != std::process::id() && !alive(pid) && std::fs::remove_file(&p).is_ok() {
            removed.push(p);
        }
    }
    removed.sort();
    removed
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
        let f = std::fs::File::create(&tmp)?;
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
        let dir = std::env::temp_dir().join(format!("pipeline-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
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
        assert_eq!(temp_owner(".train-00000-0000.tar.4242.tmp"), Some((host().into(), 4242)));
        assert_eq!(temp_owner(".sharp.tmp-99.mp4"), Some((host().into(), 99)));
        for other in ["a.tmp", ".hidden", ".x.tar", "x~h~1.tmp", ".a.tmpfile"] {
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
        let legacy = dir.join(format!(".train-00000-0000.tar.{dead}.tmp"));
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
}
