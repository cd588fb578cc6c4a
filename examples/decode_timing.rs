use std::time::Instant;
fn main() {
    let p = std::path::Path::new("/tmp/hd240.mp4");
    let mut r = pipeline::io::video::VideoReader::open(p).unwrap();
    let t = Instant::now();
    let mut n = 0;
    while let Some(_f) = r.next_frame().unwrap() {
        n += 1;
    }
    println!("decode+convert {n} frames: {:.2} ms/frame", t.elapsed().as_secs_f64() * 1e3 / n as f64);
}
