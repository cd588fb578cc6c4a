//! `pipeline`: motion deblurring with a spatiotemporally phase-coded camera
//! (Elmalem, Giryes and Marom). A ring phase mask in the aperture plus a focus sweep during the
//! exposure colours the blur of a moving point along its path (blue, green, red), so a network
//! can read the direction and extent of motion and undo it.
//!
//! - [`optics`]: the pupil, PSFs on the pixel grid, and the five cameras (pure math).
//! - [`io`]: atomic writes, `.npy`, OpenEXR, PNG.
//! - [`stage`]: one file per pipeline stage (config, checks, runtime); [`config`] the topology,
//!   [`graph`] the threads and channels; [`imaging`] what a camera does to a window.
//! - [`model`], [`train`] (feature `train`): the networks, their fast CPU path, training.
//! - [`commands`]: one file per command (psf, generate/run/validate, train, deblur, eval,
//!   figure, bench); [`cli`] parses and dispatches.
//! - [`scene`], [`recon`]: synthetic scenes and the classical reconstructions of the other cameras.

// Numeric kernels index several arrays in step (planes, channels, taps): an index loop says so
// more plainly than zipped iterators; and they take their sizes as plain arguments.
#![allow(clippy::needless_range_loop, clippy::too_many_arguments, clippy::type_complexity)]

pub mod checks;
pub mod cli;
pub mod commands;
pub mod config;
pub mod error;
pub mod frame;
pub mod graph;
pub mod imaging;
pub mod io;
pub mod metrics;
#[cfg(feature = "train")]
pub mod model;
pub mod optics;
pub mod plot;
pub mod progress;
pub mod provenance;
pub mod recon;
pub mod rng;
pub mod sample;
pub mod scene;
pub mod signal;
pub mod stage;
#[cfg(feature = "train")]
pub mod train;

pub use error::{Error, Result};
