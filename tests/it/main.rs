//! Integration tests: one binary (links once), one module per capability.

mod bad_input;
mod burst;
mod common;
#[cfg(feature = "train")]
mod deblur;
mod decode;
#[cfg(feature = "train")]
mod eval;
#[cfg(feature = "train")]
mod figure;
mod first_hour;
mod generate;
mod measured;
mod panics;
mod path_safety;
mod psf_cli;
mod shared_output;
#[cfg(feature = "train")]
mod still;
mod structure;
#[cfg(feature = "train")]
mod train;
mod user_files;
