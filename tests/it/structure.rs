//! docs/STRUCTURE.md maps the code: every source file is named in it (a `mod.rs` by its folder).

#[test]
fn every_source_file_is_named_in_structure_md() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let map = std::fs::read_to_string(root.join("docs/STRUCTURE.md")).unwrap();
    fn walk(dir: &std::path::Path, out: &mut Vec<std::path::PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    let mut files = Vec::new();
    walk(&root.join("src"), &mut files);
    let missing: Vec<String> = files
        .iter()
        .filter_map(|p| {
            let rel = p.strip_prefix(root.join("src")).unwrap();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            // A folder's mod.rs: the folder is named (`src/model/`, `blur/`).
            let named = if name == "mod.rs" {
                let folder = rel.parent().unwrap().file_name().unwrap().to_string_lossy().into_owned();
                map.contains(&format!("{folder}/"))
            } else {
                map.contains(&format!("`{name}`")) || map.contains(&rel.display().to_string())
            };
            (!named).then(|| rel.display().to_string())
        })
        .collect();
    assert!(missing.is_empty(), "source files docs/STRUCTURE.md does not name: {missing:?}");
}

/// Every `.rs` file under `src/`, as paths relative to it.
fn sources() -> Vec<std::path::PathBuf> {
    fn walk(dir: &std::path::Path, root: &std::path::Path, out: &mut Vec<std::path::PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(&p, root, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p.strip_prefix(root).unwrap().to_path_buf());
            }
        }
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut out = Vec::new();
    walk(&root, &root, &mut out);
    out.sort();
    out
}

/// Files kept over 600 lines, each for its reason.
const LONG_FILES: &[(&str, &str)] =
    &[("optics/fft.rs", "the SIMD FFT kernels (AVX untangling, strip transposes): 531 lines of code, the rest their tests")];

#[test]
fn no_source_file_is_over_600_lines_but_the_named_kernels() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let long: Vec<String> = sources()
        .into_iter()
        .filter(|f| std::fs::read_to_string(root.join(f)).unwrap().lines().count() > 600)
        .map(|f| f.display().to_string())
        .filter(|f| !LONG_FILES.iter().any(|(n, _)| n == f))
        .collect();
    assert!(long.is_empty(), "over 600 lines: {long:?} (split along a seam, or name it in LONG_FILES with why)");
}

/// The module a file is (`stage/mod.rs` -> `stage`, `stage/shards.rs` -> `stage::shards`).
fn module_of(f: &std::path::Path) -> String {
    let s = f.with_extension("").display().to_string().replace('/', "::");
    s.strip_suffix("::mod").map(str::to_string).unwrap_or(if s == "lib" || s == "main" { String::new() } else { s })
}

#[test]
fn no_two_source_files_import_each_other_through_a_circle() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let files = sources();
    let modules: Vec<String> = files.iter().map(|f| module_of(f)).collect();
    // The file a path names: the longest module that is a prefix of it.
    let resolve = |path: &str| -> Option<usize> {
        let mut best: Option<usize> = None;
        for (i, m) in modules.iter().enumerate() {
            if !m.is_empty() && (path == m || path.starts_with(&format!("{m}::"))) && best.is_none_or(|b| modules[b].len() < m.len()) {
                best = Some(i);
            }
        }
        best
    };
    let mut edges: Vec<Vec<usize>> = vec![Vec::new(); files.len()];
    for (i, f) in files.iter().enumerate() {
        let text = std::fs::read_to_string(root.join(f)).unwrap();
        // Code only: no comments, no unit-test modules (`#[cfg(test)] mod x { ... }` to its
        // closing brace at the start of a line, or `mod tests;`).
        let mut code = String::new();
        let mut rest = text.as_str();
        while let Some(at) = rest.find("\n#[cfg(test)]\nmod ") {
            code.push_str(&rest[..at]);
            let after = &rest[at + 1..];
            let end = if after.lines().nth(1).is_some_and(|l| l.trim_end().ends_with(';')) {
                after.find(";\n").map_or(after.len(), |e| e + 1)
            } else {
                after.find("\n}\n").map_or(after.len(), |e| e + 2)
            };
            rest = &after[end..];
        }
        code.push_str(rest);
        let code: String = code.lines().filter(|l| !l.trim_start().starts_with("//")).collect::<Vec<_>>().join("\n");
        let me = &modules[i];
        let parent = me.rsplit_once("::").map_or(String::new(), |(p, _)| p.to_string());
        let mut refs: Vec<String> = Vec::new();
        for (j, _) in code.match_indices("crate::") {
            let rest: String = code[j + 7..].chars().take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':').collect();
            refs.push(rest.trim_end_matches(':').to_string());
        }
        if !f.ends_with("mod.rs") {
            for (j, _) in code.match_indices("super::") {
                let rest: String = code[j + 7..].chars().take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':').collect();
                let rest = rest.trim_end_matches(':');
                refs.push(if parent.is_empty() { rest.to_string() } else { format!("{parent}::{rest}") });
            }
        }
        for r in refs {
            let Some(t) = resolve(&r) else { continue };
            let them = &modules[t];
            // A module and its parents or children are one unit.
            let related = me.starts_with(&format!("{them}::")) || them.starts_with(&format!("{me}::")) || t == i;
            if !related && !edges[i].contains(&t) {
                edges[i].push(t);
            }
        }
    }
    // Cycles: a file that reaches itself again.
    let mut circles = Vec::new();
    for start in 0..files.len() {
        let (mut seen, mut stack) = (vec![false; files.len()], vec![(start, vec![start])]);
        while let Some((n, path)) = stack.pop() {
            for &t in &edges[n] {
                if t == start {
                    let names: Vec<String> = path.iter().map(|&k| files[k].display().to_string()).collect();
                    circles.push(names.join(" -> "));
                } else if !seen[t] && t > start {
                    seen[t] = true;
                    let mut p = path.clone();
                    p.push(t);
                    stack.push((t, p));
                }
            }
        }
    }
    assert!(circles.is_empty(), "import circles between source files:\n{}", circles.join("\n"));
}
