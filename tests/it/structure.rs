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
