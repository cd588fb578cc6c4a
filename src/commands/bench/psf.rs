use super::*;

/// Result of `bench psf`.
#[derive(Debug, serde::Serialize)]
pub struct PsfBench {
    pub camera: &'static str,
    pub window: usize,
    pub repeats: usize,
    pub kernel_px: usize,
    pub cold_ms_median: f64,
    pub cached_us_median: f64,
    pub cold_ms_all: Vec<f64>,
}

/// Builds the kernels of one window with a fresh camera (cold) and again from its cache.
pub fn psf(kind: CameraKind, window: usize, repeats: usize) -> PsfBench {
    let optics = OpticsConfig::default();
    let (mut cold, mut cached) = (Vec::new(), Vec::new());
    let mut kernel_px = 0;
    for _ in 0..repeats.max(1) {
        let cam = Camera::new(&optics, &CameraConfig::new(kind));
        let t = Instant::now();
        let w = cam.window(window).expect("default schedule fits any window");
        cold.push(t.elapsed().as_secs_f64() * 1e3);
        kernel_px = w[0].psf.size;
        let t = Instant::now();
        for _ in 0..100 {
            std::hint::black_box(cam.window(window).expect("cached"));
        }
        cached.push(t.elapsed().as_secs_f64() * 1e6 / 100.0);
    }
    let cold_all = cold.clone();
    PsfBench {
        camera: kind.name(),
        window,
        repeats: repeats.max(1),
        kernel_px,
        cold_ms_median: median(&mut cold),
        cached_us_median: median(&mut cached),
        cold_ms_all: cold_all,
    }
}
