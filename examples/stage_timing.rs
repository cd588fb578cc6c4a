// Scratch timing of single stages at 1280x720 (not committed).
use pipeline::optics::transfer::{Curve, Encoder};
use pipeline::optics::*;
use pipeline::stage::blur::Blurrer;
use std::sync::Arc;
use std::time::Instant;
fn main() {
    let (w, h) = (1280usize, 720usize);
    let p: [Vec<f32>; 3] = std::array::from_fn(|c| (0..w * h).map(|i| ((i * 7 + c) % 97) as f32 / 97.0).collect());
    let enc = Encoder::new(Curve::Srgb);
    let t = Instant::now();
    for _ in 0..5 {
        std::hint::black_box(pipeline::stage::noise::quantise(&p, w, h, 0, 0, &enc, 3.0, 1));
    }
    println!("quantise {:.1} ms", t.elapsed().as_secs_f64() * 200.0);
    let lin = pipeline::stage::Linearize::new(Curve::Srgb);
    let f = pipeline::frame::Frame::new(w, h, pipeline::frame::FrameData::Planar8(std::array::from_fn(|_| vec![123u8; w * h])));
    let t = Instant::now();
    for _ in 0..5 {
        std::hint::black_box(lin.apply(&f));
    }
    println!("linearize {:.1} ms", t.elapsed().as_secs_f64() * 200.0);
    for threads in [1, 2] {
        let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::PhaseCoded)));
        let mut b = Blurrer::new(cam, 9, threads, 1e-3).unwrap();
        let fr: Vec<Arc<pipeline::frame::Frame>> = (0..9)
            .map(|_| Arc::new(pipeline::frame::Frame { curve: Some(Curve::Identity), ..pipeline::frame::Frame::new(w, h, pipeline::frame::FrameData::Planar(p.clone())) }))
            .collect();
        b.blur_region(&fr, 0, 0, w, h);
        let t = Instant::now();
        for _ in 0..3 {
            std::hint::black_box(b.blur_region(&fr, 0, 0, w, h));
        }
        println!("ranks {:?} blur window of 9, {threads} threads", b.ranks());
        println!(
            "  : {:.1} ms ({:.1} ms per sub-frame), margin {}",
            t.elapsed().as_secs_f64() * 1000.0 / 3.0,
            t.elapsed().as_secs_f64() * 1000.0 / 27.0,
            b.margin
        );
    }
    let mut conv = pipeline::optics::fft::FftConv::new(800, 1350);
    let mut img = vec![0.5f32; 800 * 1350];
    let mut out = conv.zero_spectrum();
    let t = Instant::now();
    for _ in 0..10 {
        conv.forward(&mut img, &mut out);
    }
    println!("one forward 2D FFT 800x1350: {:.2} ms", t.elapsed().as_secs_f64() * 100.0);
}
