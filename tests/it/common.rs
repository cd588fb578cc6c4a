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

/// `pipeline run pipelines/{name} -o out --progress never` with `--set` for each of `sets`.
pub fn run_pipeline(name: &str, out: &Path, sets: &[&str]) -> Output {
    let mut c = bin();
    c.arg("run").arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines").join(name)).arg("-o").arg(out).args(["--progress", "never"]);
    for s in sets {
        c.args(["--set", s]);
    }
    c.output().expect("run pipeline")
}

/// A tiny training file (shallow-4, batch 2, `steps` steps, a checkpoint every 2) on `shards`
/// that writes to `out/run`; returns its path (`out/train.toml`).
#[cfg_attr(not(feature = "train"), allow(dead_code))]
pub fn tiny_train_config(shards: &Path, out: &Path, steps: usize) -> PathBuf {
    let path = out.join("train.toml");
    std::fs::write(
        &path,
        format!(
            "seed = 1\n[model]\ntype = \"shallow\"\nwidth = 4\n[data]\nshards = [{:?}]\nval_fraction = 0.25\nshuffle_buffer = 16\n[optim]\nsteps = {steps}\nbatch = 2\n[validate]\nevery = 4\nmax_samples = 4\n[output]\ndir = {:?}\ncheckpoint_every = 2\n",
            shards.display().to_string(),
            out.join("run").display().to_string()
        ),
    )
    .unwrap();
    path
}
