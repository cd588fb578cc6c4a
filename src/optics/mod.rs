//! The physical model: pupil, PSFs and cameras. Plain math: no IO, no threads beyond the
//! kernel builder's scoped workers, no channels.
//!
//! - [`psf`]: the pupil with its phase rings, the intensity PSF per colour on the pixel grid.
//! - [`camera`]: the five computed cameras and the measured one, each turning a window of N
//!   sub-frames into N kernels; [`measured`]: PSF stacks read from `.npy`.
//! - [`config`]: `[optics]` and `[camera]` with the paper's defaults.

pub mod calibrate;
pub mod camera;
pub mod config;
pub mod fft;
pub mod lowrank;
pub mod measured;
pub mod psf;
pub mod request;
pub mod transfer;

pub use camera::{CacheStats, Camera, SubframeKernel};
pub use config::{Axis, CameraConfig, CameraKind, Dispersion, OpticsConfig, PsfAxis, PsiSchedule, Ring, Spectrum};
pub use psf::{Lens, Psf};
