//! Helpers shared by the integration tests.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pipeline"))
}

/// A fresh, empty folder under the target directory for one test.
pub fn scratch(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

pub fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("run pipeline")
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Files in a folder, sorted.
pub fn files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

pub const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/mandelbrot-pan-240fps.mp4");

/// Runs the ffmpeg CLI (installed by .ci/setup.sh) to make a test clip.
pub fn ffmpeg(args: &[&str]) {
    let st = Command::new("ffmpeg").args(["-v", "error", "-y"]).args(args).status().expect("ffmpeg CLI (installed by .ci/setup.sh)");
    assert!(st.success(), "ffmpeg {args:?}");
}

/// A clip made once per test run under the target folder.
pub fn clip(name: &str, args: &[&str]) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("clips");
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join(name);
    // Tests run on several threads of one process and may ask for the same clip at once.
    static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp = dir.join(format!("tmp-{}-{n}-{name}", std::process::id()));
    let mut a: Vec<&str> = args.to_vec();
    let t = tmp.to_str().unwrap().to_string();
    a.push(&t);
    ffmpeg(&a);
    std::fs::rename(&tmp, &out).unwrap();
    out
}

/// Tar members of every shard in a folder, in shard order.
pub fn shard_members(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for f in files(dir).into_iter().filter(|f| f.ends_with(".tar")) {
        out.extend(pipeline::io::tar::read_all(std::fs::File::open(dir.join(f)).unwrap()).unwrap());
    }
    out
}

pub fn generate(out: &Path, inputs: &[&str], sets: &[&str]) -> Output {
    let mut c = bin();
    c.arg("generate").args(inputs).arg("-o").arg(out).args(["--progress", "never"]);
    for s in sets {
        c.args(["--set", s]);
    }
    c.output().expect("run pipeline")
}
