//! Hand-held shake (the `hand` motion): a piece of a long trajectory of the camera, as a random
//! walk of the velocity with inertia, jitter and impulsive jerks at the sub-frame scale (Boracchi
//! and Foi, "Modeling the performance of image restoration from motion blur", IEEE TIP 2012; the
//! recorded hand shake of Köhler et al., ECCV 2012, is large and jerky at 1/25 s). Each window is
//! cut from a trajectory `span` sub-frames long at a random place, so a jerk can fall anywhere in
//! it, and scaled so its spread (the distance between its two farthest positions) or its path
//! length is drawn from `extent_px`: unlike `shake`, whose extent is a path length with most
//! windows slow, the default covers spreads to 60 px uniformly.

use crate::checks::Checker;
use crate::rng::Rng;
use serde::{Deserialize, Serialize};

/// What `extent_px` of a hand shake sets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Measure {
    /// The distance between the path's two farthest positions (how far the image moved).
    Spread,
    /// The length of the path (how far it travelled, back and forth included).
    Length,
}

/// `[sources.x.motion.hand]`: the `hand` motion's trajectories.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HandConfig {
    /// Extent range in pixels over a window of 9 frames; other window lengths scale it by
    /// (N - 1) / 8, as a fixed speed at 240 fps would.
    pub extent_px: [f64; 2],
    /// Extents are `lo + (hi - lo) u^power`, `u` uniform in [0, 1] (1: uniform in the range).
    pub extent_power: f64,
    /// What the extent measures.
    pub measure: Measure,
    /// Velocity kept from one sub-frame to the next, [least, most]: near 1 a smooth drift, lower
    /// a tremor.
    pub inertia: [f64; 2],
    /// Chance per sub-frame of a jerk: an impulse to the velocity.
    pub jerk_rate: f64,
    /// A jerk's size, in multiples of the velocity's typical size.
    pub jerk_strength: f64,
    /// Sub-frames of trajectory simulated for each window (the window is cut from it).
    pub span: usize,
}

impl Default for HandConfig {
    fn default() -> Self {
        HandConfig {
            extent_px: [0.0, 60.0],
            extent_power: 1.0,
            measure: Measure::Spread,
            inertia: [0.7, 0.97],
            jerk_rate: 0.03,
            jerk_strength: 4.0,
            span: 96,
        }
    }
}

impl HandConfig {
    pub(crate) fn validate(&self, c: &mut Checker, key: &str) {
        c.range(&format!("{key}.extent_px[0]"), self.extent_px[0], 0.0, 1000.0);
        c.range(&format!("{key}.extent_px[1]"), self.extent_px[1], self.extent_px[0], 1000.0);
        c.range(&format!("{key}.extent_power"), self.extent_power, 0.1, 10.0);
        c.range(&format!("{key}.inertia[0]"), self.inertia[0], 0.0, 0.999);
        c.range(&format!("{key}.inertia[1]"), self.inertia[1], self.inertia[0], 0.999);
        c.range(&format!("{key}.jerk_rate"), self.jerk_rate, 0.0, 1.0);
        c.range(&format!("{key}.jerk_strength"), self.jerk_strength, 0.0, 100.0);
        c.range_usize(&format!("{key}.span"), self.span, 2, 100_000);
    }

    /// The `n` positions of one window, centred on its middle frame, and the extent drawn
    /// (already scaled by `scale`, (N - 1) / 8).
    pub fn path(&self, n: usize, scale: f64, rng: &mut Rng) -> (Vec<(f64, f64)>, f64) {
        let [lo, hi] = self.extent_px;
        let extent = (lo + (hi - lo) * rng.uniform().powf(self.extent_power)) * scale;
        let inertia = rng.range(self.inertia[0], self.inertia[1]);
        // Jitter sized so the velocity's stationary spread is 1 whatever the inertia.
        let jitter = (1.0 - inertia * inertia).sqrt();
        let span = self.span.max(n);
        let a = rng.range(0.0, std::f64::consts::TAU);
        let mut v = (a.cos(), a.sin());
        let mut p = Vec::with_capacity(span);
        p.push((0.0, 0.0));
        for _ in 1..span {
            v = (inertia * v.0 + jitter * rng.normal(), inertia * v.1 + jitter * rng.normal());
            if rng.uniform() < self.jerk_rate {
                let b = rng.range(0.0, std::f64::consts::TAU);
                v = (v.0 + self.jerk_strength * b.cos(), v.1 + self.jerk_strength * b.sin());
            }
            let last = p[p.len() - 1];
            p.push((last.0 + v.0, last.1 + v.1));
        }
        let start = rng.below(span - n + 1);
        let window = &p[start..start + n];
        let size = match self.measure {
            Measure::Spread => spread(window),
            Measure::Length => window.windows(2).map(|w| dist(w[0], w[1])).sum(),
        };
        let k = if size > 1e-9 { extent / size } else { 0.0 };
        let mid = window[n / 2];
        (window.iter().map(|q| ((q.0 - mid.0) * k, (q.1 - mid.1) * k)).collect(), extent)
    }
}

fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()
}

/// The distance between the two farthest of `points`: how far a path spreads the image.
pub fn spread(points: &[(f64, f64)]) -> f64 {
    let mut best = 0.0f64;
    for (i, &a) in points.iter().enumerate() {
        for &b in &points[i + 1..] {
            best = best.max(dist(a, b));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_window_has_the_drawn_spread_or_length_and_rests_at_its_middle() {
        let cfg = HandConfig::default();
        let mut rng = Rng::new(7);
        for _ in 0..200 {
            let (p, e) = cfg.path(9, 1.0, &mut rng);
            assert_eq!(p.len(), 9);
            assert!((0.0..=60.0).contains(&e));
            assert!((spread(&p) - e).abs() < 1e-6 * e.max(1.0), "spread {} drawn {e}", spread(&p));
            assert_eq!(p[4], (0.0, 0.0));
        }
        let cfg = HandConfig { measure: Measure::Length, ..HandConfig::default() };
        let (p, e) = cfg.path(13, 1.5, &mut rng);
        let len: f64 = p.windows(2).map(|w| dist(w[0], w[1])).sum();
        assert!((len - e).abs() < 1e-6 * e.max(1.0) && e <= 90.0);
    }

    #[test]
    fn spreads_cover_the_range_uniformly_by_default() {
        let cfg = HandConfig::default();
        let mut rng = Rng::new(3);
        let e: Vec<f64> = (0..2000).map(|_| cfg.path(9, 1.0, &mut rng).1).collect();
        let large = e.iter().filter(|&&x| x >= 20.0).count() as f64 / e.len() as f64;
        // Two thirds of the range is 20 px and more.
        assert!((0.62..0.71).contains(&large), "{large}");
    }

    #[test]
    fn jerks_bend_the_path() {
        // With jerks and little inertia, the path turns: its length exceeds its spread.
        let cfg = HandConfig { inertia: [0.5, 0.5], jerk_rate: 0.3, ..HandConfig::default() };
        let mut rng = Rng::new(11);
        let (mut len, mut spr) = (0.0, 0.0);
        for _ in 0..50 {
            let (p, _) = cfg.path(9, 1.0, &mut rng);
            len += p.windows(2).map(|w| dist(w[0], w[1])).sum::<f64>();
            spr += spread(&p);
        }
        assert!(len > 1.3 * spr, "length {len} spread {spr}");
    }
}
