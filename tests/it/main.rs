//! Integration tests: one binary (links once), one module per capability.

mod bad_input;
mod common;
mod generate;
mod psf_cli;
#[cfg(feature = "train")]
mod train;
