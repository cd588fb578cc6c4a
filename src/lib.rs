//! `pipeline`: motion deblurring with a spatiotemporally phase-coded camera
//! (Elmalem, Giryes and Marom). A ring phase mask in the aperture plus a focus sweep during the
//! exposure colours the blur of a moving point along its path (blue, green, red), so a network
//! can read the direction and extent of motion and undo it.
//!
//! - [`optics`]: the pupil, PSFs on the pixel grid, and the five cameras (pure math).
//! - [`io`]: atomic writes, `.npy`, OpenEXR, PNG.
//! - [`stage`]: one file per pipeline stage (config, checks, runtime); [`config`] the topology,
//!   [`graph`] the threads and channels; [`imaging`] what a camera does to a window.
//! - `model` (feature `infer`, default): the networks, their fast CPU path, model files;
//!   `train` (feature `train`, with burn): training.
//! - [`commands`]: one file per command (psf, generate/run/validate, train, deblur, eval,
//!   figure, bench); [`cli`] parses and dispatches.
//! - [`render`] (what the rendered sources draw: motions, synthetic scenes, textures), [`recon`]: the
//!   classical reconstructions of the other cameras.

// Numeric kernels index several arrays in step (planes, channels, taps): an index loop says so
// more plainly than zipped iterators. (A kernel that takes its sizes as plain arguments says so
// where it is, with a local `too_many_arguments` allow.)
#![allow(clippy::needless_range_loop, clippy::type_complexity)]

/// `eprintln!` that never panics (it shadows the standard one in this crate): a closed stderr
/// (`pipeline generate ... 2>&1 | head -c1`) loses the messages, not the work.
macro_rules! eprintln {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($t)*);
    }};
}

/// `println!` that never panics (it shadows the standard one in this crate): when stdout is a
/// pipe its reader closed (`pipeline psf ... | head -1`), there is no one left to read the
/// result, and the process ends with 0, as ripgrep does.
macro_rules! println {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout(), $($t)*) {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                std::process::exit(0);
            }
        }
    }};
}

pub mod checks;
pub mod cli;
pub mod commands;
pub mod config;
pub mod error;
pub mod frame;
pub mod graph;
pub mod imaging;
pub mod io;
pub mod item;
pub mod metrics;
#[cfg(feature = "infer")]
pub mod model;
pub mod optics;
pub mod plot;
pub mod progress;
pub mod provenance;
pub mod recon;
pub mod render;
pub mod rng;
pub mod sample;
pub mod signal;
pub mod stage;
#[cfg(feature = "train")]
pub mod train;

pub use error::{Error, Result};
