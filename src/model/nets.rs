//! The networks as burn modules (feature `train`): fresh weights for training, checkpoints
//! through burn's safetensors store, the reference the fast CPU path is tested against, and the
//! GPU backends. [`UNet`] and [`Shallow`] are described in [`super`].

use super::{time_features, Arch, MIDDLE, TIME_FEATURES};
use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, Initializer, PaddingConfig2d};
use burn::tensor::activation::{leaky_relu, relu};
use burn::tensor::ops::PadMode;
use burn::tensor::{Device, Tensor};

fn conv3(cin: usize, cout: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([cin, cout], [3, 3]).with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1)).with_bias(false).init(device)
}

/// Conv 3x3 (no bias) + BatchNorm, followed by an activation in `forward`.
#[derive(Module, Debug)]
pub struct ConvBn {
    pub(in crate::model) conv: Conv2d,
    pub(in crate::model) bn: BatchNorm,
}

impl ConvBn {
    fn new(cin: usize, cout: usize, device: &Device) -> ConvBn {
        ConvBn { conv: conv3(cin, cout, device), bn: BatchNormConfig::new(cout).init(device) }
    }
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.bn.forward(self.conv.forward(x))
    }
}

/// Two ConvBn + LeakyReLU.
#[derive(Module, Debug)]
pub struct DoubleConv {
    pub(in crate::model) a: ConvBn,
    pub(in crate::model) b: ConvBn,
}

impl DoubleConv {
    fn new(cin: usize, cout: usize, device: &Device) -> DoubleConv {
        DoubleConv { a: ConvBn::new(cin, cout, device), b: ConvBn::new(cout, cout, device) }
    }
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let x = leaky_relu(self.a.forward(x), 0.01);
        leaky_relu(self.b.forward(x), 0.01)
    }
}

#[derive(Module, Debug)]
pub struct Down {
    pub(in crate::model) pool: MaxPool2d,
    pub(in crate::model) conv: DoubleConv,
}

impl Down {
    fn new(cin: usize, cout: usize, device: &Device) -> Down {
        Down { pool: MaxPool2dConfig::new([2, 2]).init(), conv: DoubleConv::new(cin, cout, device) }
    }
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.conv.forward(self.pool.forward(x))
    }
}

#[derive(Module, Debug)]
pub struct Up {
    pub(in crate::model) up: ConvTranspose2d,
    pub(in crate::model) conv: DoubleConv,
    /// A burst U-Net's time conditioning of this level's input, on the levels below the last
    /// (the last level's is [`UNet::film`]).
    pub(in crate::model) film: Option<Film>,
}

impl Up {
    /// `cin` channels come from below (upsampled to `cin`), `skip` from the same scale.
    fn new(cin: usize, skip: usize, cout: usize, device: &Device) -> Up {
        Up {
            up: ConvTranspose2dConfig::new([cin, cin], [2, 2]).with_stride([2, 2]).init(device),
            conv: DoubleConv::new(cin + skip, cout, device),
            film: None,
        }
    }
    /// With a time conditioning of the concatenation (a burst U-Net's timed levels).
    fn forward_film(&self, x: Tensor<4>, skip: Tensor<4>, film: Option<(&Film, &[f32])>) -> Tensor<4> {
        let x = Tensor::cat(vec![skip, self.up.forward(x)], 1);
        let x = match film {
            Some((f, ts)) => f.forward(x, ts),
            None => x,
        };
        self.conv.forward(x)
    }
}

/// Time conditioning (FiLM): each channel of a feature map scaled and shifted by linear
/// functions of the time's features, `x * (1 + f(t) G) + f(t) B`. Both start at zero, so a burst
/// network starts as the single-frame network whose weights it was given, at every time.
#[derive(Module, Debug)]
pub struct Film {
    /// `[TIME_FEATURES, channels]`.
    pub gamma: burn::module::Param<Tensor<2>>,
    /// `[TIME_FEATURES, channels]`.
    pub beta: burn::module::Param<Tensor<2>>,
}

impl Film {
    fn new(channels: usize, device: &Device) -> Film {
        let zeros = || burn::module::Param::from_tensor(Tensor::<2>::zeros([TIME_FEATURES, channels], device));
        Film { gamma: zeros(), beta: zeros() }
    }

    /// `x` (`[n, c, h, w]`) at the times `ts` (one per sample).
    fn forward(&self, x: Tensor<4>, ts: &[f32]) -> Tensor<4> {
        let [n, c, _, _] = x.dims();
        assert_eq!(ts.len(), n, "one time per sample");
        let f: Vec<f32> = ts.iter().flat_map(|&t| time_features(t)).collect();
        let f = Tensor::<2>::from_data(burn::tensor::TensorData::new(f, [n, TIME_FEATURES]), &x.device());
        let scale = f.clone().matmul(self.gamma.val()).add_scalar(1.0).reshape([n, c, 1, 1]);
        let shift = f.matmul(self.beta.val()).reshape([n, c, 1, 1]);
        x * scale + shift
    }
}

/// The paper's U-Net with a residual connection from input to output.
#[derive(Module, Debug)]
pub struct UNet {
    pub(in crate::model) inc: DoubleConv,
    pub(in crate::model) down1: Down,
    pub(in crate::model) down2: Down,
    pub(in crate::model) down3: Down,
    pub(in crate::model) down4: Down,
    pub(in crate::model) up1: Up,
    pub(in crate::model) up2: Up,
    pub(in crate::model) up3: Up,
    pub(in crate::model) up4: Up,
    pub(in crate::model) outc: Conv2d,
    /// The burst U-Net's time conditioning of the last level's input (skip and upsampled
    /// features, `2 base` channels); `None` in a single-frame U-Net.
    pub(in crate::model) film: Option<Film>,
}

impl UNet {
    pub fn new(base: usize, device: &Device) -> UNet {
        let b = base;
        UNet {
            inc: DoubleConv::new(3, b, device),
            down1: Down::new(b, 2 * b, device),
            down2: Down::new(2 * b, 4 * b, device),
            down3: Down::new(4 * b, 8 * b, device),
            down4: Down::new(8 * b, 8 * b, device),
            up1: Up::new(8 * b, 8 * b, 4 * b, device),
            up2: Up::new(4 * b, 4 * b, 2 * b, device),
            up3: Up::new(2 * b, 2 * b, b, device),
            up4: Up::new(b, b, b, device),
            outc: Conv2dConfig::new([b, 3], [1, 1]).init(device),
            film: None,
        }
    }

    /// The burst U-Net: the same, with its last `levels` decoder levels told the time.
    pub fn new_burst(base: usize, levels: usize, device: &Device) -> UNet {
        UNet::new(base, device).with_films(levels, device)
    }

    /// The same U-Net with a time conditioning, at zero, added to each of its last `levels`
    /// decoder levels that has none (the ones it has keep their weights).
    fn with_films(mut self, levels: usize, device: &Device) -> UNet {
        let channels = |u: &Up| u.conv.a.conv.weight.val().dims()[1];
        for (k, u) in [&mut self.up1, &mut self.up2, &mut self.up3].into_iter().enumerate() {
            if k + levels >= crate::model::DECODER_LEVELS && u.film.is_none() {
                u.film = Some(Film::new(channels(u), device));
            }
        }
        if levels >= 1 && self.film.is_none() {
            self.film = Some(Film::new(channels(&self.up4), device));
        }
        self
    }

    /// How many decoder levels are told the time (0: a single-frame U-Net).
    pub fn timed_levels(&self) -> usize {
        [&self.up1, &self.up2, &self.up3].iter().filter(|u| u.film.is_some()).count() + usize::from(self.film.is_some())
    }

    /// Deblurred `[n, 3, h, w]` for any h, w (a burst U-Net: at the middle of the exposure).
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let n = x.dims()[0];
        self.forward_at(x, &vec![MIDDLE; n])
    }

    /// Deblurred `[n, 3, h, w]`, sample i at time `ts[i]` (ignored by a single-frame U-Net).
    pub fn forward_at(&self, x: Tensor<4>, ts: &[f32]) -> Tensor<4> {
        let [_, _, h, w] = x.dims();
        let (ph, pw) = ((16 - h % 16) % 16, (16 - w % 16) % 16);
        let xp = if ph + pw > 0 { x.clone().pad((0, pw, 0, ph), PadMode::Edge) } else { x.clone() };
        let x1 = self.inc.forward(xp);
        let x2 = self.down1.forward(x1.clone());
        let x3 = self.down2.forward(x2.clone());
        let x4 = self.down3.forward(x3.clone());
        let x5 = self.down4.forward(x4.clone());
        fn at<'a>(f: &'a Option<Film>, ts: &'a [f32]) -> Option<(&'a Film, &'a [f32])> {
            f.as_ref().map(|f| (f, ts))
        }
        let y = self.up1.forward_film(x5, x4, at(&self.up1.film, ts));
        let y = self.up2.forward_film(y, x3, at(&self.up2.film, ts));
        let y = self.up3.forward_film(y, x2, at(&self.up3.film, ts));
        let y = self.up4.forward_film(y, x1, at(&self.film, ts));
        let r = self.outc.forward(y);
        let n = r.dims()[0];
        let r = if ph + pw > 0 { r.slice([0..n, 0..3, 0..h, 0..w]) } else { r };
        x + r
    }
}

/// The shallow ablation model.
#[derive(Module, Debug)]
pub struct Shallow {
    pub(in crate::model) blocks: Vec<ConvBn>,
    pub(in crate::model) out: Conv2d,
}

impl Shallow {
    pub fn new(width: usize, device: &Device) -> Shallow {
        let blocks = (0..9).map(|i| ConvBn::new(if i == 0 { 3 } else { width }, width, device)).collect();
        Shallow { blocks, out: Conv2dConfig::new([width, 3], [3, 3]).with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1)).init(device) }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut y = x.clone();
        for b in &self.blocks {
            y = relu(b.forward(y));
        }
        x + self.out.forward(y)
    }
}

/// Either network.
#[derive(Module, Debug)]
#[allow(clippy::large_enum_variant)] // one network per process: boxing would buy nothing
pub enum Net {
    Unet(UNet),
    Shallow(Shallow),
}

/// Forces lazily initialised parameters to draw their values now.
struct Materialize;

impl burn::module::ModuleVisitor for Materialize {
    fn visit_float<const D: usize>(&mut self, p: &burn::module::Param<Tensor<D>>) {
        let _ = p.val();
    }
}

/// burn's random generator is shared by the whole process and parameters draw from it lazily,
/// at first use: every network this crate builds takes this lock, (optionally) seeds, builds
/// and materialises its parameters, so no other draw can fall in between.
static INIT: std::sync::Mutex<()> = std::sync::Mutex::new(());

impl Net {
    /// A network with random initial weights (from burn's unseeded generator).
    pub fn new(arch: Arch, device: &Device) -> Net {
        let _guard = INIT.lock().unwrap_or_else(|e| e.into_inner());
        Net::build(arch, device)
    }

    /// A network whose initial weights are a function of `seed` alone, whatever else the
    /// process does at the same time.
    pub fn seeded(arch: Arch, device: &Device, seed: u64) -> Net {
        let _guard = INIT.lock().unwrap_or_else(|e| e.into_inner());
        device.seed(seed);
        Net::build(arch, device)
    }

    fn build(arch: Arch, device: &Device) -> Net {
        let net = match arch {
            Arch::Unet { base } => Net::Unet(UNet::new(base, device)),
            Arch::BurstUnet { base, levels } => Net::Unet(UNet::new_burst(base, levels, device)),
            Arch::Shallow { width } => Net::Shallow(Shallow::new(width, device)),
        };
        net.visit(&mut Materialize);
        net
    }

    /// The number of trained weights: burn's `num_params` also counts BatchNorm's running
    /// statistics, which are not weights.
    pub fn trainable_params(&self) -> usize {
        let mut n = 0;
        crate::model::fast::FastNet::from_net(self).params(&mut |p, _| n += p.len());
        n
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        match self {
            Net::Unet(m) => m.forward(x),
            Net::Shallow(m) => m.forward(x),
        }
    }

    /// Sample i at time `ts[i]` (a single-frame network ignores the times).
    pub fn forward_at(&self, x: Tensor<4>, ts: &[f32]) -> Tensor<4> {
        match self {
            Net::Unet(m) => m.forward_at(x, ts),
            Net::Shallow(m) => m.forward(x),
        }
    }

    /// Whether the network takes the time.
    pub fn is_burst(&self) -> bool {
        matches!(self, Net::Unet(UNet { film: Some(_), .. }))
    }

    /// A burst U-Net told the time on its last `levels` decoder levels, made from a U-Net
    /// told it on fewer (or a single-frame one): its weights, and the new time conditioning at
    /// zero (so at every time it gives what the U-Net gave).
    ///
    /// # Panics
    /// If `self` is not a U-Net, or is told the time on more levels than `levels`.
    pub fn into_burst(self, levels: usize, device: &Device) -> Net {
        match self {
            Net::Unet(m) if m.timed_levels() <= levels => Net::Unet(m.with_films(levels, device)),
            _ => panic!("into_burst: not a U-Net told the time on at most {levels} levels"),
        }
    }

    /// The same network with its last layer set to zero: the identity map (the residual
    /// connection passes the input through). Used to start training from "no change".
    pub fn zero_last_layer(self, device: &Device) -> Net {
        let zero = |c: Conv2d| -> Conv2d {
            let [cout, cin, kh, kw] = c.weight.val().dims();
            let mut cfg = Conv2dConfig::new([cin, cout], [kh, kw]).with_initializer(Initializer::Zeros);
            if kh == 3 {
                cfg = cfg.with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1));
            }
            cfg.init(device)
        };
        match self {
            Net::Unet(mut m) => {
                m.outc = zero(m.outc);
                Net::Unet(m)
            }
            Net::Shallow(mut m) => {
                m.out = zero(m.out);
                Net::Shallow(m)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dev() -> Device {
        Device::flex()
    }

    fn image(n: usize, h: usize, w: usize, seed: u64) -> Tensor<4> {
        let v: Vec<f32> = (0..n * 3 * h * w).map(|i| crate::rng::unit(crate::rng::hash(&[seed, i as u64])) as f32).collect();
        Tensor::<4>::from_data(burn::tensor::TensorData::new(v, [n, 3, h, w]), &dev())
    }

    #[test]
    fn convolution_macs_match_pytorch_hooks_and_the_parameter_count() {
        // Reference MACs at 128 x 128: forward hooks on python/pipeline/models.py's networks in
        // PyTorch 2.15 (weights x output pixels per Conv2d, x input pixels per ConvTranspose2d).
        for (arch, macs) in
            [(Arch::Unet { base: 16 }, 505_937_920), (Arch::Unet { base: 32 }, 2_008_023_040), (Arch::Shallow { width: 32 }, 1_236_271_104)]
        {
            let (m, weights) = arch.conv_macs(128, 128);
            assert_eq!(m, macs, "{}", arch.name());
            // The rest of the parameters are BatchNorm's (2 per channel) and the biases.
            let rest = match arch {
                Arch::Unet { base } => 139 * base + 3,
                Arch::Shallow { width } => 18 * width + 3,
                Arch::BurstUnet { .. } => unreachable!("not in the list"),
            };
            assert_eq!(Net::new(arch, &dev()).trainable_params(), weights + rest, "{}", arch.name());
        }
    }

    #[test]
    fn unet_keeps_the_shape_for_any_size() {
        let m = UNet::new(4, &dev());
        for (h, w) in [(16, 16), (37, 23), (5, 50)] {
            assert_eq!(m.forward(image(2, h, w, 1)).dims(), [2, 3, h, w]);
        }
        let s = Shallow::new(4, &dev());
        assert_eq!(s.forward(image(1, 9, 13, 2)).dims(), [1, 3, 9, 13]);
    }

    #[test]
    fn zero_last_layer_makes_the_identity() {
        for arch in [Arch::Unet { base: 4 }, Arch::Shallow { width: 4 }] {
            let m = Net::new(arch, &dev()).zero_last_layer(&dev());
            let x = image(1, 20, 24, 3);
            let y = m.forward(x.clone());
            let (a, b) = (x.into_data().try_to_vec::<f32>().unwrap(), y.into_data().try_to_vec::<f32>().unwrap());
            assert!(a.iter().zip(&b).all(|(p, q)| (p - q).abs() < 1e-6), "{arch:?}");
        }
    }

    #[test]
    fn the_paper_unet_has_about_14_8_million_parameters() {
        let n = UNet::new(64, &dev()).num_params();
        assert!((14_000_000..16_000_000).contains(&n), "{n}");
        // The shallow model has about 2% of that (paper: "just 2% of the weights").
        let s = Shallow::new(32, &dev()).num_params();
        assert!((s as f64 / n as f64) < 0.03, "{s} vs {n}");
    }

    #[test]
    fn the_parameter_count_leaves_out_batchnorms_running_statistics() {
        // U-Net 16: 928,083 values in its file, of which 1,984 are BatchNorm's running mean and
        // variance (two per channel of each of its 992 BatchNorm channels).
        let net = Net::new(Arch::Unet { base: 16 }, &dev());
        assert_eq!(net.num_params(), 928_083);
        assert_eq!(net.trainable_params(), 926_099);
    }
}
