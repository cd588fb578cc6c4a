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
                if glob_match(&name, &n) {
                    out.push(e.path());
                }
            }
            if out.len() == before {
                return Err(crate::Error::Invalid(format!("{p}: the pattern matches no file")));
            }
        } else if path.is_dir() {
            let rd = std::fs::read_dir(&path).map_err(|e| crate::Error::Io { path: path.clone(), cause: e })?;
            for e in rd.flatten() {
                let ext = e.path().extension().map(|x| x.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
                if exts.contains(&ext.as_str()) {
                    out.push(e.path());
                }
            }
        } else {
            out.push(path);
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn globs_match_file_names() {
        assert!(glob_match("*.mp4", "a.mp4") && !glob_match("*.mp4", "a.mkv") && glob_match("c?ip*", "clip_01.mov"));
    }
}
