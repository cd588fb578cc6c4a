use pipeline::optics::*;
fn main() {
    for kind in [CameraKind::PhaseCoded, CameraKind::FocusSweep, CameraKind::Parabolic, CameraKind::Flutter] {
        let cam = Camera::new(&OpticsConfig::default(), &CameraConfig::new(kind));
        for n in [7usize, 9, 13] {
            let w = cam.window(n).unwrap();
            let m = w.iter().map(|k| k.half_extent()).max().unwrap();
            for c in [0usize, 2] {
                let ks: Vec<Vec<f32>> = w.iter().map(|k| k.render(c, m)).collect();
                let gram: Vec<Vec<f64>> =
                    (0..n).map(|i| (0..n).map(|j| ks[i].iter().zip(&ks[j]).map(|(a, b)| *a as f64 * *b as f64).sum()).collect()).collect();
                let (vals, _) = lowrank::symmetric_eigen(&gram);
                let tot: f64 = vals.iter().sum();
                let rel: Vec<String> =
                    (1..=n).map(|r| format!("{:.0e}", (vals[r..].iter().map(|v| v.max(0.0)).sum::<f64>() / tot).sqrt())).collect();
                println!("{:?} N={n} c={c}: rel error by rank {}", kind, rel.join(" "));
            }
        }
    }
}
