//! Stages: sources make frames, transforms turn items into items, sinks write them.
//!
//! A stage returns [`StageError::Input`] for a problem with one input (a video shorter than a
//! window, frames smaller than a patch): the runner then marks that input failed, tells the
//! stages downstream, and drops the rest of its items, so the sink discards its partial output
//! while the other inputs go on. Any other error stops the whole run.

pub mod blackhole;
pub mod coded_blur;
#[cfg(feature = "ffmpeg")]
pub mod decode;
pub mod frames;
pub mod input;
pub mod linearize;
pub mod noise;
pub mod patches;
pub mod scene;
pub mod sensor;
pub mod shards;
pub mod stills;
#[cfg(feature = "train")]
pub mod trainer;

pub use input::{input_key, InputList, Needs};

use crate::checks::ConfigError;
use crate::frame::Input;
use crate::item::Item;
use crossbeam_channel::Sender;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// The wiring part of a [`StageConfig`] impl: its role, its `inputs` field (transforms and
/// sinks), the kinds it accepts and produces, and for sinks its `dir` field.
macro_rules! wiring {
    (source, $out:ident) => {
        fn role(&self) -> $crate::stage::Role {
            $crate::stage::Role::Source
        }
        fn kinds(&self) -> ($crate::stage::Kind, $crate::stage::Kind) {
            ($crate::stage::Kind::$out, $crate::stage::Kind::$out)
        }
    };
    (transform, $in:ident -> $out:ident) => {
        fn role(&self) -> $crate::stage::Role {
            $crate::stage::Role::Transform
        }
        fn inputs(&self) -> &[String] {
            &self.inputs
        }
        fn kinds(&self) -> ($crate::stage::Kind, $crate::stage::Kind) {
            ($crate::stage::Kind::$in, $crate::stage::Kind::$out)
        }
    };
    (sink, $in:ident) => {
        fn role(&self) -> $crate::stage::Role {
            $crate::stage::Role::Sink
        }
        fn inputs(&self) -> &[String] {
            &self.inputs
        }
        fn kinds(&self) -> ($crate::stage::Kind, $crate::stage::Kind) {
            ($crate::stage::Kind::$in, $crate::stage::Kind::$in)
        }
        fn out_dir(&self) -> Option<&str> {
            Some(&self.dir)
        }
        fn set_out_dir(&mut self, dir: String) {
            self.dir = dir;
        }
    };
}
pub(crate) use wiring;

/// The stage kinds: `type = "..."` in a pipeline file, each a config in its own file of
/// `src/stage/` that implements [`StageConfig`] beside its runtime. A new kind is one file and
/// one line here.
macro_rules! registry {
    ($($(#[$m:meta])* $variant:ident($cfg:ty),)*) => {
        /// A stage's config as written, by its `type`.
        #[derive(Debug, Clone, Serialize, Deserialize)]
        #[serde(tag = "type", rename_all = "snake_case")]
        pub enum StageKind {
            $($(#[$m])* $variant($cfg),)*
        }

        impl StageKind {
            pub fn config(&self) -> &dyn StageConfig {
                match self {
                    $($(#[$m])* StageKind::$variant(c) => c,)*
                }
            }
            pub fn config_mut(&mut self) -> &mut dyn StageConfig {
                match self {
                    $($(#[$m])* StageKind::$variant(c) => c,)*
                }
            }
            /// The `type` written in the pipeline file (`coded_blur`).
            pub fn type_name(&self) -> String {
                match self {
                    $($(#[$m])* StageKind::$variant(_) => snake_case(stringify!($variant)),)*
                }
            }
        }
    };
}

/// `CodedBlur` -> `coded_blur`, as serde's `rename_all = "snake_case"` spells a variant.
fn snake_case(ident: &str) -> String {
    let mut out = String::new();
    for (i, c) in ident.chars().enumerate() {
        if c.is_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(c.to_ascii_lowercase());
    }
    out
}

registry! {
    #[cfg(feature = "ffmpeg")]
    Decode(decode::DecodeConfig),
    Stills(stills::StillsConfig),
    Scene(scene::SceneSourceConfig),
    Linearize(linearize::LinearizeConfig),
    CodedBlur(coded_blur::BlurConfig),
    Noise(noise::NoiseConfig),
    Sensor(sensor::SensorConfig),
    Patches(patches::PatchesConfig),
    Shards(shards::ShardsConfig),
    Frames(frames::FramesConfig),
    Blackhole(blackhole::BlackholeConfig),
    #[cfg(feature = "train")]
    Trainer(trainer::TrainerSinkConfig),
}

/// Where a stage sits in a chain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    Source,
    Transform,
    Sink,
}

impl Role {
    /// The table a stage of this role is written under.
    pub fn table(self) -> &'static str {
        match self {
            Role::Source => "sources",
            Role::Transform => "transforms",
            Role::Sink => "sinks",
        }
    }
}

/// What flows on an edge; checked before any thread starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Frames as their source made them: encoded values (8 or 16 bits, or float), no curve.
    EncodedFrames,
    /// The same values tagged with their transfer curve (`linearize`): whoever reads them gets
    /// linear light, converted by table where it is read (patch mode converts only its patches).
    TaggedFrames,
    Samples,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::EncodedFrames => "encoded frames",
            Kind::TaggedFrames => "frames tagged with their transfer curve (read as linear light)",
            Kind::Samples => "samples",
        }
    }
}

/// What a stage gets when it is built, besides its own config: the run's settings and what the
/// topology tells it (never another stage's config).
pub struct BuildContext<'a> {
    /// The stage's name (`blur` of `[transforms.blur]`).
    pub name: &'a str,
    pub seed: u64,
    /// This task's inputs (sources), each with its file if it has one.
    pub inputs: &'a [(Arc<Input>, Option<PathBuf>)],
    /// What the stages downstream need of each input (sources check it before decoding).
    pub needs: Needs,
    /// Patches to cut before blurring, when a patch stage follows the blur across per-pixel
    /// stages only ([`StageConfig::crop_selector`]).
    pub crop: Option<patches::Selector>,
    /// For a source: the parts of each frame the blur will read, when patches are cut first
    /// and nothing between moves pixels ([`crate::config::Plan::reads_for`]).
    pub reads: Option<patches::ReadRegions>,
    pub counters: Arc<Counters>,
    /// The output folder (sinks).
    pub out_dir: &'a Path,
    /// This task's index and the task count (sinks name their files by them).
    pub task: (usize, usize),
    /// Hash of the settings that decide the samples' content (sinks record it).
    pub settings: &'a str,
}

/// A built stage, ready to run on its thread.
pub enum Built {
    Source(Box<dyn Source>),
    Transform(Box<dyn Transform>),
    Sink(Box<dyn Sink>),
}

/// Inputs a sink already holds from earlier runs (skipped), and ones it holds damaged or made
/// with other settings (redone), with the reason.
#[derive(Debug, Default)]
pub struct Completed {
    pub keys: std::collections::BTreeSet<String>,
    pub redo: Vec<(String, String)>,
}

/// A stage's config: what it reads and writes, its checks and how it builds its runtime.
pub trait StageConfig: std::fmt::Debug {
    fn role(&self) -> Role;
    /// Names of the stages it reads from (empty for a source).
    fn inputs(&self) -> &[String] {
        &[]
    }
    /// The kind it accepts (ignored for a source) and the kind it produces.
    fn kinds(&self) -> (Kind, Kind);
    /// Every problem with its values, each named by its full key under `key`
    /// (`transforms.blur`).
    fn validate(&self, key: &str) -> Vec<ConfigError>;
    /// What it needs of each input upstream (frames per window, frame size).
    fn needs(&self) -> Needs {
        Needs::default()
    }
    /// Works pixel by pixel, so patches may be cut before it.
    fn per_pixel(&self) -> bool {
        false
    }
    /// A stage that can work on patches cut first (the blur) when a patch stage follows.
    fn takes_crop(&self) -> bool {
        false
    }
    /// The patches it cuts, if they may be cut before the blur instead.
    fn crop_selector(&self) -> Option<patches::Selector> {
        None
    }
    /// Leaves every pixel where it is (a source's frames may then be read only where the blur
    /// will read them).
    fn keeps_positions(&self) -> bool {
        false
    }
    /// A stage that takes a crop: its windows' length and stride and the kernel margin it reads
    /// around each patch.
    ///
    /// # Errors
    /// The kernels cannot be made (a config error `validate` reports too).
    fn crop_geometry(&self) -> crate::Result<Option<patches::CropGeometry>> {
        Ok(None)
    }
    /// Sub-frames each window images (the report's sub-frame count).
    fn subframes_per_window(&self) -> usize {
        0
    }
    /// A source's inputs.
    ///
    /// # Errors
    /// A path that does not exist, a pattern that matches nothing.
    fn list(&self) -> crate::Result<InputList> {
        Ok(InputList::Procedural(0))
    }
    /// A sink's output folder.
    fn out_dir(&self) -> Option<&str> {
        None
    }
    fn set_out_dir(&mut self, _dir: String) {}
    /// A sink's report name stem (`report`; a trainer writes its own report.json).
    fn report_stem(&self) -> &'static str {
        "report"
    }
    /// Whether a sink may write into `dir` for this task, checked before anything is written
    /// there (a folder holding another split of the inputs, say).
    ///
    /// # Errors
    /// Why not, as a usage error.
    fn admits(&self, _dir: &Path, _task: (usize, usize)) -> crate::Result<()> {
        Ok(())
    }
    /// What a sink already holds in `dir` from earlier runs.
    ///
    /// # Errors
    /// Its index of earlier work cannot be read.
    fn completed(&self, _dir: &Path, _task: (usize, usize), _settings: &str) -> crate::Result<Completed> {
        Ok(Completed::default())
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built>;
}

#[derive(Debug)]
pub enum StageError {
    /// One input cannot be processed; the error names it and what is wrong with it.
    Input(Arc<Input>, crate::frame::InputError),
    Fatal(crate::Error),
}

impl From<crate::Error> for StageError {
    fn from(e: crate::Error) -> Self {
        StageError::Fatal(e)
    }
}

pub type StageResult<T = ()> = Result<T, StageError>;

/// Counters the progress display and the report read.
#[derive(Debug, Default)]
pub struct Counters {
    pub frames: AtomicU64,
    pub windows: AtomicU64,
    pub samples: AtomicU64,
    /// Samples of inputs that finished (what the sink kept); `samples` also counts those of an
    /// input still running or failed later.
    pub samples_kept: AtomicU64,
    pub inputs_done: AtomicU64,
    pub inputs_failed: AtomicU64,
    pub inputs_total: AtomicU64,
    /// What each source measured of its inputs (path, size, frame rate, frame counts).
    pub inputs: std::sync::Mutex<Vec<InputReport>>,
    /// What the sink says of its own work, shown after the counts (the `trainer` sink: its
    /// step, loss and validation PSNR).
    pub status: std::sync::Mutex<String>,
}

/// One input as the report shows it.
#[derive(Debug, Clone, serde::Serialize)]
pub struct InputReport {
    pub path: String,
    #[serde(flatten)]
    pub info: crate::frame::InputInfo,
    pub frames_read: u64,
}

impl Counters {
    pub fn add(c: &AtomicU64, n: u64) {
        c.fetch_add(n, Ordering::Relaxed);
    }
    pub fn get(c: &AtomicU64) -> u64 {
        c.load(Ordering::Relaxed)
    }
    /// Records an input's facts once it has been read.
    pub fn input(&self, path: &str, info: &crate::frame::InputInfo, frames_read: u64) {
        self.inputs.lock().expect("inputs").push(InputReport { path: path.to_string(), info: info.clone(), frames_read });
    }
}

/// Sends items downstream; remembers when downstream has gone.
pub struct Emit<'a> {
    tx: &'a Sender<Item>,
    pub closed: bool,
    pub stop: &'a AtomicBool,
    /// Time spent blocked because downstream was full.
    pub waited: std::time::Duration,
}

impl<'a> Emit<'a> {
    pub fn new(tx: &'a Sender<Item>, stop: &'a AtomicBool) -> Emit<'a> {
        Emit { tx, closed: false, stop, waited: std::time::Duration::ZERO }
    }
    /// False when downstream has stopped (then the caller should return quietly).
    pub fn send(&mut self, item: Item) -> bool {
        if self.closed || self.stop.load(Ordering::Relaxed) {
            self.closed = true;
            return false;
        }
        let t = std::time::Instant::now();
        if self.tx.send(item).is_err() {
            self.closed = true;
        }
        self.waited += t.elapsed();
        !self.closed
    }
}

/// A transform: one item in, zero or more out.
pub trait Transform: Send {
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult;
    /// Runs once after upstream closes.
    fn finish(&mut self, _out: &mut Emit) -> StageResult {
        Ok(())
    }
    /// Settings the stage chose itself, for the run's report (`stages[].details`).
    fn details(&self) -> Option<serde_json::Value> {
        None
    }
}

/// A source: produces every item of every input, checking `stop` between frames.
pub trait Source: Send {
    fn run(&mut self, out: &mut Emit) -> crate::Result<()>;
}

/// A sink: consumes items; `finish` returns its summary for the report; `abort` removes
/// anything half-written after an error or Ctrl-C.
pub trait Sink: Send {
    fn consume(&mut self, item: Item) -> crate::Result<()>;
    fn finish(&mut self) -> crate::Result<serde_json::Value>;
    fn abort(&mut self);
    /// Inputs that failed: (path, reason).
    fn failures(&self) -> Vec<(String, String)>;
    /// False once the sink needs nothing more (a trainer that has done its steps): the run
    /// then stops its sources and finishes normally.
    fn wants_more(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn type_names_are_the_types_written_in_pipeline_files() {
        for text in [
            include_str!("../../pipelines/generate.toml"),
            include_str!("../../pipelines/train-stream.toml"),
            include_str!("../../pipelines/frames.toml"),
        ] {
            let t: toml::Table = toml::from_str(text).unwrap();
            // The kinds this build leaves out (`decode` without FFmpeg, `trainer` without burn).
            let built = |ty: &str| (ty != "decode" || cfg!(feature = "ffmpeg")) && (ty != "trainer" || cfg!(feature = "train"));
            for section in ["sources", "transforms", "sinks"] {
                for (_, v) in t[section].as_table().unwrap() {
                    if !built(v["type"].as_str().unwrap()) {
                        continue;
                    }
                    let kind: super::StageKind = v.clone().try_into().unwrap();
                    assert_eq!(kind.type_name(), v["type"].as_str().unwrap());
                }
            }
        }
    }
}

/// The "Adding a stage kind" example of docs/STRUCTURE.md, compiled as written there (build.rs
/// copies it out of the document), so the recipe a newcomer follows cannot go stale.
#[cfg(test)]
mod recipe {
    include!(concat!(env!("OUT_DIR"), "/stage_recipe.rs"));

    #[test]
    fn the_recipe_in_structure_md_compiles_and_is_a_samples_transform() {
        let c = FlipConfig { inputs: vec!["noise".into()] };
        assert!(c.validate("transforms.flip").is_empty());
        assert_eq!(c.role(), super::Role::Transform);
        assert_eq!(c.inputs(), ["noise".to_string()]);
        assert_eq!(c.kinds(), (super::Kind::Samples, super::Kind::Samples));
        let _: &dyn Transform = &Flip;
    }
}
