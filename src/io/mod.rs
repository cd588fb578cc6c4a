//! File formats and safe writing: atomic files, `.npy`, OpenEXR, PNG.

pub mod atomic;
pub mod exr;
pub mod font;
pub mod npy;
pub mod paths;
pub mod png;
pub mod tar;
#[cfg(feature = "ffmpeg")]
pub mod video;
pub mod wds;
pub mod yuv;

pub use atomic::{host, remove_stale, temp_name, temp_path, write_atomic};
