//! Input lists: files, folders (their files with wanted extensions) and file-name globs.

use std::path::{Path, PathBuf};

/// Expands the source's paths: files as given, folders to their files with the wanted
/// extensions, `*` and `?` in the file name as globs. Sorted, without duplicates.
///
/// # Errors
/// A path that does not exist or a glob that matches nothing, naming it.
pub fn expand_paths(paths: &[String], exts: &[&str]) -> Result<Vec<PathBuf>, crate::Error> {
    let mut out = Vec::new();
    for p in paths {
        let path = PathBuf::from(p);
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if name.contains(['*', '?']) {
            let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
            let rd = std::fs::read_dir(dir).map_err(|e| crate::Error::Io { path: dir.to_path_buf(), cause: e })?;
            let before = out.len();
            for e in rd.flatten() {
                let n = e.file_name().to_string_lossy().into_owned();
                if glob_match(&name, &n) && std::fs::metadata(e.path()).is_ok_and(|m| m.is_file()) {
                    out.push(e.path());
                }
            }
            if out.len() == before {
                return Err(crate::Error::Usage(format!("{p}: the pattern matches no file")));
            }
        } else if path.is_dir() {
            let rd = std::fs::read_dir(&path).map_err(|e| crate::Error::Io { path: path.clone(), cause: e })?;
            let before = out.len();
            for e in rd.flatten() {
                let ext = e.path().extension().map(|x| x.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
                // Regular files only (a link to one too): a FIFO or device named `x.mp4` would
                // block the decoder forever.
                if exts.contains(&ext.as_str()) && std::fs::metadata(e.path()).is_ok_and(|m| m.is_file()) {
                    out.push(e.path());
                }
            }
            if out.len() == before {
                return Err(crate::Error::Usage(format!("{p}: a folder with no file to read in it ({})", exts.join(", "))));
            }
        } else {
            if p != "-" && std::fs::metadata(&path).is_ok_and(|m| !m.is_file()) {
                return Err(crate::Error::Usage(format!("{p}: not a regular file (a FIFO or a device); give a file or a folder")));
            }
            out.push(path);
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}

/// Why `name` is not one plain file name (no `/`, no `..` or `.`, not absolute, not empty), or
/// `None` if it is.
pub fn not_plain(name: &str) -> Option<&'static str> {
    let mut comps = Path::new(name).components();
    let plain = matches!((comps.next(), comps.next()), (Some(std::path::Component::Normal(n)), None) if n == name);
    (!plain || name.contains(['/', '\\', '\0'])).then_some("not a plain file name inside its folder")
}

/// The file `name` inside `dir`, where `name` was read from a file the tool trusts less than its
/// command line (a manifest's shard list, a run folder's `latest.json`): it must be one plain
/// file name ([`not_plain`]) and, if it exists, not a symbolic link, so that nothing outside
/// `dir` is opened, sized or removed through it.
///
/// # Errors
/// [`crate::Error::Untrusted`] naming `file` (where the name was read), `field` and the name.
pub fn inside(dir: &Path, name: &str, file: &Path, field: &str) -> Result<PathBuf, crate::Error> {
    let refuse =
        |why: &'static str| crate::Error::Untrusted { file: file.to_path_buf(), field: field.to_string(), name: name.to_string(), why };
    if let Some(why) = not_plain(name) {
        return Err(refuse(why));
    }
    let p = dir.join(name);
    if std::fs::symlink_metadata(&p).is_ok_and(|m| m.file_type().is_symlink()) {
        return Err(refuse("a symbolic link; only files inside the folder are read"));
    }
    Ok(p)
}

/// Refuses to replace what an earlier run left at `out` (the files of `found` that exist) unless
/// `overwrite`: the rule `train` applies to run folders, for the outputs of `eval` and `deblur`.
///
/// # Errors
/// A usage error naming `out`, up to three of the files, and the two ways on.
pub fn refuse_replacing(out: &Path, found: &[PathBuf], overwrite: bool) -> Result<(), crate::Error> {
    let there: Vec<&PathBuf> = found.iter().filter(|p| std::fs::symlink_metadata(p).is_ok()).collect();
    if overwrite || there.is_empty() {
        return Ok(());
    }
    let mut names: Vec<String> = there.iter().take(3).map(|p| p.display().to_string()).collect();
    if there.len() > 3 {
        names.push(format!("and {} more", there.len() - 3));
    }
    Err(crate::Error::Usage(format!(
        "{}: an earlier run's output is there ({}); add --overwrite to replace it, or choose another output",
        out.display(),
        names.join(", ")
    )))
}

/// Whether `a` and `b` name the same file (the same device and inode; or the same path when
/// either does not exist).
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
        _ => a == b,
    }
}

/// Refuses a run that would write over one of its own inputs, `--overwrite` or not: the one rule
/// every command follows (an input is never replaced; what an earlier run wrote is replaced only
/// with `--overwrite`).
///
/// # Errors
/// A usage error naming the output and the input it is.
pub fn refuse_replacing_inputs(outputs: &[PathBuf], inputs: &[PathBuf]) -> Result<(), crate::Error> {
    for o in outputs {
        if let Some(i) = inputs.iter().find(|i| same_file(o, i)) {
            return Err(crate::Error::Usage(format!(
                "{}: writing there would replace the input {} (an input is never replaced, --overwrite or not); choose another output",
                o.display(),
                i.display()
            )));
        }
    }
    Ok(())
}

/// Reads `path` whole when it is a regular file of at most `max` bytes: a device (`/dev/zero`),
/// a FIFO or a file larger than anything of its kind is refused by name before a byte is read,
/// so a mistaken path can neither hang the command nor fill the memory.
///
/// # Errors
/// Missing or unreadable (an I/O error naming it); not a regular file, or too large
/// ([`crate::Error::File`] saying which, with `what` the kind of file expected).
pub fn read_regular(path: &Path, max: u64, what: &str) -> Result<Vec<u8>, crate::Error> {
    use std::io::Read;
    let io = |e| crate::Error::Io { path: path.to_path_buf(), cause: e };
    let meta = std::fs::metadata(path).map_err(io)?;
    if !meta.is_file() {
        return Err(crate::Error::File { path: path.to_path_buf(), why: format!("not a regular file; expected {what}") });
    }
    if meta.len() > max {
        return Err(crate::Error::File {
            path: path.to_path_buf(),
            why: format!("{} bytes, more than any {what} ({max} at most)", meta.len()),
        });
    }
    let mut v = Vec::with_capacity(meta.len() as usize);
    // `take` keeps the bound if the file grows while it is read.
    std::fs::File::open(path).map_err(io)?.take(max + 1).read_to_end(&mut v).map_err(io)?;
    if v.len() as u64 > max {
        return Err(crate::Error::File { path: path.to_path_buf(), why: format!("grew past {max} bytes while read; expected {what}") });
    }
    Ok(v)
}

/// The largest model file any command reads (a U-Net 64 in F32 is 59 MB).
pub const MAX_MODEL_BYTES: u64 = 1 << 30;
/// The largest settings file (TOML, JSON) any command reads.
pub const MAX_CONFIG_BYTES: u64 = 16 << 20;

fn glob_match(pat: &str, s: &str) -> bool {
    let (p, s): (Vec<char>, Vec<char>) = (pat.chars().collect(), s.chars().collect());
    fn go(p: &[char], s: &[char]) -> bool {
        match (p.first(), s.first()) {
            (None, None) => true,
            (Some('*'), _) => go(&p[1..], s) || (!s.is_empty() && go(p, &s[1..])),
            (Some('?'), Some(_)) => go(&p[1..], &s[1..]),
            (Some(a), Some(b)) if a == b => go(&p[1..], &s[1..]),
            _ => false,
        }
    }
    go(&p, &s)
}

/// A scratch folder for a unit test, made if missing: `pipeline-{name}-{pid}` under the system's
/// temporary folder (the test removes it).
#[cfg(test)]
pub(crate) fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pipeline-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_from_trusted_files_stay_inside_their_folder() {
        let dir = crate::io::paths::scratch_dir("inside");
        let from = dir.join("latest.json");
        assert_eq!(inside(&dir, "model-0000001.safetensors", &from, "model").unwrap(), dir.join("model-0000001.safetensors"));
        for bad in ["../victim.txt", "/etc/shadow", "a/b.tar", "..", ".", "", "./x.tar"] {
            let e = inside(&dir, bad, &from, "model").err().unwrap_or_else(|| panic!("{bad:?} accepted")).to_string();
            assert!(e.contains("latest.json") && e.contains("model") && e.contains(&format!("{bad:?}")), "{e}");
        }
        std::os::unix::fs::symlink("/etc/hostname", dir.join("link.tar")).unwrap();
        let e = inside(&dir, "link.tar", &from, "model").unwrap_err().to_string();
        assert!(e.contains("symbolic link"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn globs_match_file_names() {
        assert!(glob_match("*.mp4", "a.mp4") && !glob_match("*.mp4", "a.mkv") && glob_match("c?ip*", "clip_01.mov"));
    }
}
