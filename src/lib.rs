//! `pipeline`: motion deblurring with a spatiotemporally phase-coded camera
//! (Elmalem, Giryes and Marom). A ring phase mask in the aperture plus a focus sweep during the
//! exposure colours the blur of a moving point along its path (blue, green, red), so a network
//! can read the direction and extent of motion and undo it.
//!
//! - [`optics`]: the pupil, PSFs on the pixel grid, and the five cameras (pure math).
//! - [`io`]: atomic writes, `.npy`, OpenEXR, PNG.
//! - [`psfcmd`]: `pipeline psf`, which computes PSFs and writes them for people and tools.
//! - [`scene`], [`recon`], `figure`: synthetic scenes, the classical reconstructions of the other
//!   cameras, and the paper's comparison figures.
//! - `deblur`, `eval` (feature `train`): running and scoring the networks.

pub mod bench;
pub mod cli;
pub mod config;
#[cfg(feature = "train")]
pub mod deblur;
pub mod error;
#[cfg(all(feature = "train", feature = "ffmpeg"))]
pub mod eval;
#[cfg(feature = "train")]
pub mod figure;
pub mod frame;
pub mod graph;
pub mod imaging;
pub mod io;
pub mod metrics;
#[cfg(feature = "train")]
pub mod model;
pub mod optics;
pub mod plot;
pub mod provenance;
pub mod psfcmd;
pub mod recon;
pub mod rng;
pub mod scene;
pub mod signal;
pub mod stage;
#[cfg(feature = "train")]
pub mod train;

pub use error::{Error, Result};
