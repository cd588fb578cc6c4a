//! The CPU fast path: the same two networks as `model::Net` (burn), forward and backward written out
//! as shifted copies (im2col for the widest layers) + matrix products (the `gemm` crate) on all
//! cores (rayon).
//!
//! Why it exists: burn 0.22's CPU backend (flex) computes a convolution's weight gradient with a
//! nearly scalar loop for small batches and its input gradient through a col2im scatter, so a
//! training step ran 6 to 11 times slower than PyTorch on the same CPU. This module is the one
//! boundary around that work-around: `FastNet::from_net` copies a burn `Net`'s weights and
//! running statistics in, `FastNet::write_into` copies them back (feature `train`), so burn keeps
//! the module definitions, safetensors checkpoints and the GPU backends; inference builds the
//! network from a model file's weights alone ([`FastNet::from_weights`]), without burn. When burn's CPU convolutions catch
//! up, deleting this file (and the `Engine::Fast` arms that call it) is the whole change.
//!
//! Layout: `[n, c, h, w]` row-major f32, as burn's. Convolutions are stride 1 with zero
//! padding `k / 2` (k = 1 or 3); the input gradient is the forward convolution of the output
//! gradient with the weights flipped and transposed, so forward and backward share one kernel.
//!
//! Determinism: work is split into units (sample x band of rows) whose shape depends only on the
//! tensor sizes, never on the thread count; per-unit partial weight gradients are summed in unit
//! order, and per-channel statistics are summed in a fixed order in f64. The same seed gives the
//! same weights with any number of threads.
//!
//! Files: `tensor.rs` (the `[n, c, h, w]` tensor and its copies: pad, crop, cat, split),
//! `kernels.rs` (matrix products, shifted bands, convolutions and their gradients, pooling; all the raw
//! pointer work), `layers.rs` (convolution, conv + BatchNorm + activation, the transposed
//! convolution, each with its backward pass), `winograd.rs` (Winograd F(2x2, 3x3) convolutions
//! for the forward pass and the input gradient), `net.rs` (the U-Net and the shallow model),
//! `optim.rs` (Huber loss and Adam) and `tests.rs` (each against burn).

mod kernels;
mod layers;
mod net;
mod optim;
mod tensor;
#[cfg(all(test, feature = "train"))]
mod tests;
mod winograd;

#[cfg(feature = "train")]
use super::Net;
#[cfg(feature = "train")]
use burn::module::Param;
#[cfg(feature = "train")]
use burn::nn::conv::{Conv2d, ConvTranspose2d};
#[cfg(feature = "train")]
use burn::nn::BatchNorm;
#[cfg(feature = "train")]
use burn::tensor::{Tensor, TensorData};
use kernels::*;
use layers::*;
use rayon::prelude::*;
use std::sync::Arc;
use tensor::*;

pub use kernels::{conv_backward_input, conv_backward_weight, conv_forward};
pub use layers::{Conv, ConvBnAct};
pub use net::FastNet;
pub use optim::{huber, train_step, Adam, AdamStateError};
pub use tensor::T4;
pub use winograd::{conv3x3 as winograd_conv3x3, weights as winograd_weights, worth_it as winograd_worth_it};
