//! The command line: the top-level clap definition and dispatch to `src/commands/`. `main.rs`
//! only calls [`run`].

use crate::commands;
use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "pipeline",
    version,
    about = "Motion deblurring with a spatiotemporally phase-coded camera",
    long_about = "Motion deblurring with a spatiotemporally phase-coded camera (Elmalem, Giryes and Marom).\n\n\
A ring phase mask in the lens aperture plus a focus sweep during the exposure makes the blur of a \
moving point change colour along its path (blue, then green, then red), so a network can read the \
direction and extent of motion and undo it. `pipeline` models that camera and the cameras it is \
compared with, makes coded-blur training data from high-frame-rate video, and trains the paper's \
networks on it.",
    after_help = "Examples:\n  pipeline psf --camera phase_coded --psi 0:8:33 --out psfs.npy     the coded camera's PSFs\n  pipeline generate clip.mp4 -o out/                                training pairs as WebDataset shards\n  pipeline run pipelines/stills.toml -o out/stills                  the same from still images\n  pipeline train --config pipelines/train.toml                      train the U-Net on them\n  pipeline deblur coded.mp4 -o sharp.mp4                            deblur a video or an image folder\n  pipeline eval clip.mp4 -o eval-out/                               the paper's Table 1 on your footage\n  pipeline figure spoke -o fig5.png                                 the comparison figures\n  pipeline validate pipelines/*.toml                                check configs\n\nEvery command has --help with its own examples.\n\nExit codes: 0 all done; 1 some input or step failed (named); 2 usage or configuration error;\n130 interrupted (SIGINT or SIGTERM): finished work is kept and the message says how to continue."
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Compute a camera's PSFs; print a table and write .npy, .exr or a .png strip.
    #[command(
        after_help = "Examples:\n  pipeline psf --psi 0:8:9 --out strip.png            lens PSF of the coded camera at 9 psi values\n  pipeline psf --psi 0,4,8 --out psfs.npy             (3, H, W, 3) float32, R G B, each channel sums to 1\n  pipeline psf --camera parabolic --window 9 --out k.png   the 9 sub-frame kernels of one exposure\n  pipeline psf --config optics.toml --psi 0:8:33      [optics] and [camera] tables from a file"
    )]
    Psf(crate::commands::psf::PsfArgs),
    /// Measure a PSF stack from captures of a point source, for the `measured` camera.
    Calibrate(crate::commands::calibrate::CalibrateArgs),
    /// Make coded-blur training data from videos with the default generate pipeline.
    #[command(
        after_help = "Examples:\n  pipeline generate clip.mp4 -o out/                       patches in WebDataset shards\n  pipeline generate clips/ -o out/ --set transforms.blur.camera.type=conventional\n  pipeline generate a.mp4 b.mkv -o out/ --shard-index 0 --shard-count 2\n  ffmpeg -i in.mov -f nut - | pipeline generate - -o out/   a stream on standard input\n\nThe default pipeline is pipelines/generate.toml (embedded); see it for every key."
    )]
    Generate(crate::commands::generate::GenerateArgs),
    /// Run a pipeline file.
    #[command(
        after_help = "Examples:\n  pipeline run pipelines/stills.toml -o out/stills               clips rendered from photographs\n  pipeline run pipelines/frames.toml --set 'sources.video.paths=[\"clip.mp4\"]'   GoPro folder layout\n  pipeline run pipelines/train-stream.toml                       train straight from the generator\n\nA pipeline is [sources.x], [transforms.y] (inputs = [\"x\"]) and [sinks.z]; pipeline validate\nchecks one without running it."
    )]
    Run(crate::commands::generate::RunArgs),
    /// Train the U-Net or the shallow model on generated shards (Huber loss, Adam).
    #[cfg(feature = "train")]
    #[command(
        after_help = "Examples:\n  pipeline train --config pipelines/train.toml                       a run into output.dir\n  pipeline train --config pipelines/train.toml --resume              continue it where it stopped\n  pipeline train --config pipelines/train.toml --set 'init=\"runs/unet16\"' --set optim.steps=2000 \\\n    --set 'output.dir=\"runs/more\"'                                   train further, on a new schedule\n  pipeline train --config pipelines/train-shallow.toml --set 'output.dir=\"runs/shallow\"'\n  pipeline train --config pipelines/train.toml --set 'model.type=\"burst_unet\"' --set model.base=32 \\\n    --set 'init=\"models/unet32-coded\"' --set 'data.shards=[\"burst/*.tar\"]'   a burst model\n\nWrites checkpoints (model-STEP.safetensors + optimizer state), latest.json, report.json and\ncurves.png to output.dir, a folder of the run's own. --resume continues the same schedule\n(a changed optim.steps or lr is refused); init starts a new one from a trained model."
    )]
    Train(crate::commands::train::TrainArgs),
    /// Train a model: not in this build (burn, the `train` feature); `cargo build --release
    /// --features train` adds it.
    #[cfg(not(feature = "train"))]
    #[command(disable_help_flag = true)]
    Train {
        #[arg(trailing_var_arg = true, allow_hyphen_values = true, hide = true)]
        args: Vec<String>,
    },
    /// Deblur a video (same size and frame rate) or a folder of images (same names and formats).
    #[cfg(feature = "infer")]
    #[command(
        after_help = "Examples:\n  pipeline deblur coded.mp4 -o sharp.mp4                  the shipped default model\n  pipeline deblur shaky.jpg -o sharp.jpg --camera conventional   ordinary motion blur\n  pipeline deblur coded.png -o burst/ --burst 9 --model runs/burst   nine sharp frames, in time order\n  pipeline deblur coded.mkv -o sharp.mkv --lossless       FFV1, lossless RGB\n  pipeline deblur frames/ -o sharp/ --model runs/unet16/model-0000300.safetensors\n\nThe output's kind follows its extension: a video from a video, an image or a folder (no\nextension) from one image, a folder from a folder of images; anything else is a usage error.\nParent folders are created. Writes OUTPUT and OUTPUT.report.json (a folder: OUTPUT/report.json)\nwith frames, size, frame rate and frames/s. Audio is not copied. An output an earlier run wrote\nis not replaced without --overwrite (exit 2); an interrupted folder run is finished by rerunning it.\nImages keep their format (PNG grey, alpha, 16 bits; OpenEXR float); memory is the tile's forward pass\nplus about 6 bytes per pixel; images over 16384x16384 pixels are refused by name (exit 1).\n\nWhich input: the default model undoes the blur of the phase-coded camera (the coloured streaks of\n`pipeline generate` or the prototype); on an ordinary photo or video it makes things worse. For\nordinary motion blur use the model trained on the conventional camera: --camera conventional."
    )]
    Deblur(crate::commands::deblur::DeblurArgs),
    /// Score a model the way the paper's Table 1 does: windows of N = 7..13 frames from your
    /// videos, noise sigma 0..3, PSNR/SSIM (RGB and Y) of the deblurred frame and of the blurred
    /// input against the sharp middle frame.
    #[cfg(all(feature = "infer", feature = "ffmpeg"))]
    #[command(
        after_help = "Examples:\n  pipeline eval clip.mp4 -o eval-out/                         the shipped model, coded camera\n  pipeline eval clips/ --model models/unet32-conventional --camera conventional -o eval-conv/\n  pipeline eval clip.mp4 --set eval.crop=256 --set 'eval.windows=[9]'\n\nWrites eval.json (every window, the means, the config), eval.md (Table 1 and per-sigma\ntables) and examples/*.png (blurred | deblurred | sharp). Keys: pipelines/eval.toml (embedded).\nA folder holding an earlier eval.json is not written into without --overwrite (exit 2)."
    )]
    Eval(crate::commands::eval::EvalArgs),
    /// Draw one of the paper's comparison figures (conventional, fluttered shutter, parabolic
    /// motion and the coded camera) as a labelled PNG.
    #[cfg(feature = "infer")]
    #[command(
        after_help = "Figures:\n  psf-strip   Fig. 2: a moving point through a conventional camera, a focus sweep without the\n              mask, and the coded camera (blue -> green -> red along the path)\n  dots        Fig. 3: moving dots through all four cameras, with noise\n  spectrum    Fig. 4: (x, t) slice of a moving point's PSF, its 2-D Fourier amplitude and phase\n  spoke       Fig. 5: rotating spoke target, captures and reconstructions (flutter least squares,\n              parabolic Lucy-Richardson, the shipped U-Nets); FILE.md and FILE.json with PSNR/SSIM\n\nExamples:\n  pipeline figure psf-strip -o fig2.png\n  pipeline figure spoke -o fig5.png --sigma 3 --travel 16"
    )]
    Figure(crate::commands::figure::FigureArgs),
    /// Check pipeline files and report every error, each naming its key.
    #[command(
        after_help = "Examples:\n  pipeline validate pipelines/*.toml\n  pipeline validate my.toml --set transforms.blur.window=11\n\nExit code 0 when every file is valid, 2 otherwise (every error of every file is printed)."
    )]
    Validate(crate::commands::validate::ValidateArgs),
    /// Write a trained model with PyTorch state_dict names (python/pipeline/models.py's UNet and
    /// Shallow), for fine-tuning or deployment in PyTorch.
    #[cfg(feature = "infer")]
    #[command(
        after_help = "Examples:\n  pipeline export models/unet32-coded -o unet32-coded.pt.safetensors\n  pipeline export trained-in-torch.safetensors --format burn --half -o models/mine/model.safetensors\n\nIn Python: model = UNet(32); model.load_state_dict(safetensors.torch.load_file(\"unet32-coded.pt.safetensors\"))"
    )]
    Export(crate::commands::export::ExportArgs),
    /// Measure speed (medians of repeats); not part of the tests.
    #[command(
        subcommand,
        after_help = "Examples:\n  pipeline bench generate                  beside ffmpeg decode-only on the same clip\n  pipeline bench train --batch 8 --quick   beside PyTorch CPU when torch is installed\n  pipeline bench deblur\n  pipeline bench psf --camera phase_coded\n\nEach prints its baseline measured in the same run, and JSON on stdout."
    )]
    Bench(crate::commands::bench::BenchCommand),
}

/// The default generate pipeline, embedded (see [`commands::generate`]).
pub use commands::generate::GENERATE_TOML;

/// Keeps memory the process frees for its next allocations (glibc; elsewhere nothing). Every
/// training step and every generated window frees and allocates again buffers of the same
/// sizes (activations of 4 to 34 MB, frames); glibc handed each back to the kernel (`munmap`
/// and heap trimming) and the next step paid the page faults again: about a fifth of a
/// training step's time on the 2-core machine of `pipeline bench train` (shallow-32 11.6 to 14.6
/// patches/s, U-Net 16 23.8 to 28, U-Net 32 8.3 to 9.8), about 7% of whole-frame generation.
/// The peak is unchanged: what is kept is at most what was already in use at once.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes the allocator's settings and takes its own lock.
    unsafe {
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, libc::c_int::MAX);
    }
}

/// Runs a parsed command line.
///
/// # Errors
/// Whatever the command reports; the binary prints it with its cause chain.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    keep_freed_memory();
    match cli.command {
        Command::Psf(a) => commands::psf::command(a),
        Command::Calibrate(a) => commands::calibrate::command(a),
        Command::Generate(a) => commands::generate::generate(a),
        Command::Run(a) => commands::generate::run(a),
        Command::Validate(a) => commands::validate::command(a),
        #[cfg(feature = "train")]
        Command::Train(a) => commands::train::command(a),
        #[cfg(not(feature = "train"))]
        Command::Train { .. } => Err(crate::Error::Usage(
            "this pipeline was built without training (burn, half the dependencies and two thirds of the build time, is the `train` feature): \
             cargo build --release --features train, then target/release/pipeline train ..."
                .into(),
        )
        .into()),
        #[cfg(feature = "infer")]
        Command::Deblur(a) => commands::deblur::command(a),
        #[cfg(all(feature = "infer", feature = "ffmpeg"))]
        Command::Eval(a) => commands::eval::command(a),
        #[cfg(feature = "infer")]
        Command::Figure(a) => commands::figure::command(a),
        #[cfg(feature = "infer")]
        Command::Export(a) => commands::export::command(a),
        Command::Bench(c) => commands::bench::command(c),
    }
}
