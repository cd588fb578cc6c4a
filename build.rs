//! Records the git commit the binary was built from (empty outside a git checkout), for the
//! reports every command writes; copies the stage recipe of docs/STRUCTURE.md for its test.

fn main() {
    let commit = std::process::Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default();
    println!("cargo:rustc-env=PIPELINE_GIT_COMMIT={commit}");
    for p in [".git/HEAD", ".git/refs/heads", ".git/packed-refs"] {
        if std::path::Path::new(p).exists() {
            println!("cargo:rerun-if-changed={p}");
        }
    }
    // The "Adding a stage kind" example of docs/STRUCTURE.md, for the test that compiles it
    // (src/stage/mod.rs, `mod recipe`), so the recipe cannot go stale.
    let doc = std::fs::read_to_string("docs/STRUCTURE.md").unwrap_or_default();
    let code = doc
        .split("## Adding a stage kind")
        .nth(1)
        .and_then(|s| s.split("```rust").nth(1))
        .and_then(|s| s.split("```").next())
        .unwrap_or("");
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR").expect("OUT_DIR")).join("stage_recipe.rs");
    std::fs::write(out, code).expect("write the stage recipe");
    println!("cargo:rerun-if-changed=docs/STRUCTURE.md");
    println!("cargo:rerun-if-changed=build.rs");
}
