use std::time::Instant;
fn main() {
    let mut conv = pipeline::optics::fft::FftConv::new(800, 1350);
    let mut out = conv.zero_spectrum();
    let mut v = Vec::new();
    for _ in 0..15 {
        let mut img = vec![0.5f32; 800 * 1350];
        let t = Instant::now();
        conv.forward(&mut img, &mut out);
        let mut o = vec![0.0f32; 800 * 1350];
        conv.inverse(&mut out, &mut o);
        v.push(t.elapsed().as_secs_f64() * 1e3);
    }
    v.sort_by(f64::total_cmp);
    println!("forward+inverse 800x1350 median {:.2} ms (min {:.2})", v[7], v[0]);
}
