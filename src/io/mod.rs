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

pub use atomic::{
    create_new, host, make_dir_in, open_append, open_lock, remove_stale, remove_stale_for, temp_name, temp_path, write_atomic,
};
