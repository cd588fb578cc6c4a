use super::*;

/// A `[n, c, h, w]` f32 tensor.
#[derive(Debug, Clone, PartialEq)]
pub struct T4 {
    pub n: usize,
    pub c: usize,
    pub h: usize,
    pub w: usize,
    pub d: Vec<f32>,
}

impl T4 {
    pub fn zeros(n: usize, c: usize, h: usize, w: usize) -> T4 {
        T4 { n, c, h, w, d: vec![0.0; n * c * h * w] }
    }
    pub fn new(n: usize, c: usize, h: usize, w: usize, d: Vec<f32>) -> T4 {
        assert_eq!(d.len(), n * c * h * w, "T4 data length");
        T4 { n, c, h, w, d }
    }
    pub(super) fn hw(&self) -> usize {
        self.h * self.w
    }
    pub(super) fn sample(&self, s: usize) -> &[f32] {
        let len = self.c * self.hw();
        &self.d[s * len..(s + 1) * len]
    }
    /// From a burn tensor (any device).
    #[cfg(feature = "train")]
    pub fn from_tensor(t: Tensor<4>) -> T4 {
        let [n, c, h, w] = t.dims();
        T4::new(n, c, h, w, values(t))
    }
    #[cfg(feature = "train")]
    pub fn to_tensor(&self, device: &burn::tensor::Device) -> Tensor<4> {
        Tensor::<4>::from_data(TensorData::new(self.d.clone(), [self.n, self.c, self.h, self.w]), device)
    }
}

#[cfg(feature = "train")]
pub(super) fn tensor<const D: usize>(v: &[f32], shape: [usize; D], device: &burn::tensor::Device) -> Tensor<D> {
    Tensor::<D>::from_data(TensorData::new(v.to_vec(), shape), device)
}

/// The values of a float tensor of any rank, row-major.
#[cfg(feature = "train")]
pub(super) fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32 tensor")
}

/// Channel concatenation `[a, b]` and its inverse.
pub(super) fn cat(a: &T4, b: &T4) -> T4 {
    let (ha, hb) = (a.c * a.hw(), b.c * b.hw());
    let mut d = Vec::with_capacity(a.d.len() + b.d.len());
    for s in 0..a.n {
        d.extend_from_slice(&a.d[s * ha..][..ha]);
        d.extend_from_slice(&b.d[s * hb..][..hb]);
    }
    T4::new(a.n, a.c + b.c, a.h, a.w, d)
}

pub(super) fn split(t: &T4, ca: usize) -> (T4, T4) {
    let hw = t.hw();
    let cb = t.c - ca;
    let (mut a, mut b) = (Vec::with_capacity(t.n * ca * hw), Vec::with_capacity(t.n * cb * hw));
    for s in 0..t.n {
        let x = t.sample(s);
        a.extend_from_slice(&x[..ca * hw]);
        b.extend_from_slice(&x[ca * hw..]);
    }
    (T4::new(t.n, ca, t.h, t.w, a), T4::new(t.n, cb, t.h, t.w, b))
}

pub(super) fn add_into(a: &mut T4, b: &T4) {
    a.d.par_iter_mut().zip(b.d.par_iter()).for_each(|(x, y)| *x += y);
}

/// Edge-replicating pad of `x` to `h x w` (bottom and right), as the U-Net pads its input.
pub(super) fn pad_edge(x: &T4, h: usize, w: usize) -> T4 {
    let mut y = T4::zeros(x.n, x.c, h, w);
    for p in 0..x.n * x.c {
        let src = &x.d[p * x.hw()..][..x.hw()];
        let dst = &mut y.d[p * h * w..][..h * w];
        for i in 0..h {
            let si = i.min(x.h - 1);
            for j in 0..w {
                dst[i * w + j] = src[si * x.w + j.min(x.w - 1)];
            }
        }
    }
    y
}

pub(super) fn crop(x: &T4, h: usize, w: usize) -> T4 {
    let mut d = Vec::with_capacity(x.n * x.c * h * w);
    for p in 0..x.n * x.c {
        for i in 0..h {
            d.extend_from_slice(&x.d[p * x.hw() + i * x.w..][..w]);
        }
    }
    T4::new(x.n, x.c, h, w, d)
}

pub(super) fn pad_zero(x: &T4, h: usize, w: usize) -> T4 {
    let mut y = T4::zeros(x.n, x.c, h, w);
    for p in 0..x.n * x.c {
        for i in 0..x.h {
            y.d[p * h * w + i * w..][..x.w].copy_from_slice(&x.d[p * x.hw() + i * x.w..][..x.w]);
        }
    }
    y
}
