//! Temporal FIR low-pass filtering of every light's trajectory and power, by light id.
//!
//! Havran et al. 2005 filter each light's motion over the sphere and its power with a
//! perception-inspired low-pass FIR filter, because even a local change of the map moves every
//! light a little. For light id i the output is
//! `rgb = Σ_k w_k · rgb_i(t−k)` (and the same for the solid angle) and
//! `dir = normalise(Σ_k w_k · P_i(t−k) · dir_i(t−k))`, with normalised taps w_k (w_0 applies to
//! the newest frame) and P the light's luminance: the direction is the *power-weighted* mean
//! over the window, the temporal counterpart of placing a light at its region's energy
//! centroid. (Where all P are 0, the plain mean of the directions.)
//!
//! Why weighted: a light can change role from one frame to the next — with the row-by-row warp,
//! a point in the sun's row of the map slides from the sun to the sky beside it when the sun
//! dims or crosses the map's seam. An unweighted mean then sends most of the sun's power, still
//! in the power history, towards the sky for several frames, and the shadows it casts sweep.
//! Weighted, the light keeps pointing at the sun while the sun's power fades out of its window.
//! On the built-in sky with the sun in view this lowered the ground-shadow flicker from 0.0132 to
//! 0.0088 (docs/quality.md, "Temporal stability").
//!
//! Default taps: the binomial kernel [1, 6, 15, 20, 15, 6, 1]/64, a Gaussian of σ ≈ 1.22 frames.
//! At 30 frames/s its −3 dB point is ≈ 3.2 Hz and it attenuates 10 Hz by > 99%: temporal
//! contrast sensitivity peaks around 8–20 Hz (de Lange curves), so the band where flicker is most
//! visible is removed while slow lighting changes pass. Being symmetric, it delays by exactly
//! (7 − 1)/2 = 3 frames (100 ms at 30 frames/s); [`FirFilter::delay_frames`] reports the group
//! delay Σ k·w_k of any taps.
//!
//! An id that is missing from a frame (a smaller light count, say) loses its history; when it
//! returns, its history restarts from its first new value, so no stale position leaks in.

use crate::light::Light;
use glam::DVec3;

/// The default taps (binomial, 7 taps, delay 3 frames).
pub const DEFAULT_TAPS: [f64; 7] = [1.0, 6.0, 15.0, 20.0, 15.0, 6.0, 1.0];

/// Most taps accepted.
pub const MAX_TAPS: usize = 64;

/// A light's power for weighting its direction: Rec. 709 luminance, negative parts as 0.
fn luminance(rgb: [f64; 3]) -> f64 {
    (0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]).max(0.0)
}

#[derive(Clone, Copy, Debug, Default)]
struct Sample {
    dir: DVec3,
    rgb: [f64; 3],
    solid_angle: f64,
    /// [`luminance`] of `rgb`, the weight of `dir`: computed once, when the sample arrives.
    power: f64,
}

#[derive(Clone, Debug, Default)]
struct History {
    /// Ring of the last `taps.len()` samples; `head` is the newest.
    ring: Vec<Sample>,
    head: usize,
    /// Frame counter value when this id was last seen.
    last_seen: Option<u64>,
}

/// Per-id FIR filter over light lists.
#[derive(Clone, Debug)]
pub struct FirFilter {
    taps: Vec<f64>,
    histories: Vec<History>,
    frame: u64,
}

impl FirFilter {
    /// A filter with the given taps (newest first). They must be 1..=64 finite numbers with a
    /// positive sum; they are normalised to sum to 1.
    pub fn new(taps: &[f64]) -> Result<Self, String> {
        if taps.is_empty() || taps.len() > MAX_TAPS {
            return Err(format!("need 1..={MAX_TAPS} taps, got {}", taps.len()));
        }
        if let Some(bad) = taps.iter().find(|t| !t.is_finite()) {
            return Err(format!("tap {bad} is not a finite number"));
        }
        let sum: f64 = taps.iter().sum();
        if sum.is_nan() || sum <= 0.0 {
            return Err(format!("taps must have a positive sum, got {sum}"));
        }
        Ok(Self {
            taps: taps.iter().map(|t| t / sum).collect(),
            histories: Vec::new(),
            frame: 0,
        })
    }

    /// The filter with [`DEFAULT_TAPS`].
    pub fn with_default_taps() -> Self {
        Self::new(&DEFAULT_TAPS).unwrap_or_else(|_| unreachable!("default taps are valid"))
    }

    /// The normalised taps, newest first.
    pub fn taps(&self) -> &[f64] {
        &self.taps
    }

    /// Group delay at low frequencies, in frames: Σ k·w_k. (T−1)/2 for symmetric taps.
    pub fn delay_frames(&self) -> f64 {
        self.taps
            .iter()
            .enumerate()
            .map(|(k, w)| k as f64 * w)
            .sum()
    }

    /// Forgets all histories.
    pub fn reset(&mut self) {
        self.histories.clear();
    }

    /// Filters one frame's lights in place (matched by id).
    pub fn apply(&mut self, lights: &mut [Light]) {
        let frame = self.frame;
        self.frame += 1;
        let n = self.taps.len();
        for light in lights.iter_mut() {
            let id = light.id as usize;
            if id >= self.histories.len() {
                self.histories.resize_with(id + 1, History::default);
            }
            let rgb = light.rgb.map(f64::from);
            let sample = Sample {
                dir: DVec3::new(
                    light.dir[0].into(),
                    light.dir[1].into(),
                    light.dir[2].into(),
                ),
                rgb,
                solid_angle: light.solid_angle.into(),
                power: luminance(rgb),
            };
            let h = &mut self.histories[id];
            let continuing = frame > 0 && h.last_seen == Some(frame - 1);
            if !continuing {
                h.ring.clear();
                h.ring.resize(n, sample);
                h.head = 0;
            } else {
                h.head = (h.head + 1) % n;
                h.ring[h.head] = sample;
            }
            h.last_seen = Some(frame);

            let mut power_weighted_dir = DVec3::ZERO;
            let mut rgb = [0.0f64; 3];
            let mut solid_angle = 0.0;
            // Newest first: head, head − 1, …, 0, then n − 1, …, head + 1.
            let (recent, earlier) = h.ring.split_at(h.head + 1);
            let newest_first = || recent.iter().rev().chain(earlier.iter().rev());
            for (w, s) in self.taps.iter().zip(newest_first()) {
                power_weighted_dir += (*w * s.power) * s.dir;
                for c in 0..3 {
                    rgb[c] += w * s.rgb[c];
                }
                solid_angle += w * s.solid_angle;
            }
            // Without power in the window (or with an overflow), the plain mean of directions.
            let dir = power_weighted_dir
                .try_normalize()
                .or_else(|| {
                    let plain: DVec3 = self
                        .taps
                        .iter()
                        .zip(newest_first())
                        .map(|(w, s)| *w * s.dir)
                        .sum();
                    plain.try_normalize()
                })
                .unwrap_or(sample.dir);
            light.dir = [dir.x as f32, dir.y as f32, dir.z as f32];
            light.rgb = rgb.map(|c| c.max(0.0) as f32);
            light.solid_angle = solid_angle.max(0.0) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light(id: u32, dir: [f32; 3], power: f32) -> Light {
        Light {
            id,
            dir,
            rgb: [power; 3],
            solid_angle: 0.01,
        }
    }

    #[test]
    fn constant_input_stays_constant() {
        let mut f = FirFilter::with_default_taps();
        for _ in 0..20 {
            let mut lights = vec![
                light(0, [0.0, 1.0, 0.0], 5.0),
                light(3, [0.6, 0.0, 0.8], 2.0),
            ];
            f.apply(&mut lights);
            assert!((lights[0].rgb[0] - 5.0).abs() < 1e-5);
            assert!((lights[1].dir[0] - 0.6).abs() < 1e-6 && (lights[1].dir[2] - 0.8).abs() < 1e-6);
        }
    }

    #[test]
    fn step_passes_with_the_stated_delay() {
        let mut f = FirFilter::with_default_taps();
        assert_eq!(f.delay_frames(), 3.0);
        let mut out = Vec::new();
        for t in 0..20 {
            let power = if t < 10 { 0.0 } else { 1.0 };
            let mut lights = vec![light(1, [0.0, 1.0, 0.0], power)];
            f.apply(&mut lights);
            out.push(lights[0].rgb[0]);
        }
        // Symmetric taps: the output reaches half the step exactly `delay` frames after it,
        // rises monotonically and settles at the new value once all taps see it.
        let half = 10 + f.delay_frames() as usize;
        assert!(
            out[half - 1] < 0.5 && out[half] >= 0.5 && out[half + 1] > 0.5,
            "{out:?}"
        );
        assert!(out.windows(2).all(|w| w[1] >= w[0]));
        assert_eq!(out[9], 0.0);
        assert!((out[16] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn returning_id_restarts_from_its_new_value() {
        let mut f = FirFilter::with_default_taps();
        for _ in 0..10 {
            f.apply(&mut [light(7, [1.0, 0.0, 0.0], 1.0)]);
        }
        f.apply(&mut [light(2, [0.0, 1.0, 0.0], 1.0)]); // id 7 missing this frame
        let mut back = [light(7, [0.0, 0.0, 1.0], 9.0)];
        f.apply(&mut back);
        assert_eq!(back[0].dir, [0.0, 0.0, 1.0]);
        assert_eq!(back[0].rgb, [9.0; 3]);
    }

    #[test]
    fn direction_motion_is_smoothed_on_the_sphere() {
        let mut f = FirFilter::with_default_taps();
        let mut max_step = 0.0f32;
        let mut prev: Option<[f32; 3]> = None;
        for t in 0..30 {
            // The raw direction jitters by ±10° every frame.
            let a = if t % 2 == 0 { 0.17f32 } else { -0.17 };
            let mut l = [light(0, [a.sin(), a.cos(), 0.0], 1.0)];
            f.apply(&mut l);
            let d = l[0].dir;
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-5);
            if let (Some(p), true) = (prev, t > 8) {
                max_step = max_step.max((p[0] - d[0]).abs());
            }
            prev = Some(d);
        }
        assert!(max_step < 0.02, "residual jitter {max_step}");
    }

    /// A light that leaves a bright source for a dim place keeps pointing at the source while
    /// the source's power fades out of its window (the direction is power-weighted); a plain
    /// mean of the directions would swing it halfway within three frames.
    #[test]
    fn a_light_leaving_a_bright_source_keeps_its_direction_while_its_power_fades() {
        let mut f = FirFilter::with_default_taps();
        let sun = [0.0, 0.6, -0.8];
        let sky = [0.8, 0.6, 0.0];
        for _ in 0..10 {
            f.apply(&mut [light(4, sun, 1000.0)]);
        }
        let mut powers = Vec::new();
        for t in 0..7 {
            let mut l = [light(4, sky, 1.0)];
            f.apply(&mut l);
            let cos_to_sun: f32 = l[0].dir.iter().zip(sun).map(|(a, b)| a * b).sum();
            powers.push(l[0].rgb[0]);
            // While the sun's power is in the window it dominates the direction: in the
            // sixth frame only the oldest tap (1/64) still holds it, 16 against 0.98.
            if t < 5 {
                assert!(cos_to_sun > 0.9999, "frame {t}: {:?}", l[0].dir);
            } else if t == 5 {
                assert!(cos_to_sun > 0.99, "frame {t}: {:?}", l[0].dir);
            } else {
                let cos_to_sky: f32 = l[0].dir.iter().zip(sky).map(|(a, b)| a * b).sum();
                assert!(cos_to_sky > 0.9999, "frame {t}: {:?}", l[0].dir);
            }
        }
        assert!(powers.windows(2).all(|w| w[1] < w[0]), "{powers:?}");
        // All powers 0: the plain mean of the directions.
        let mut dark = FirFilter::with_default_taps();
        let mut l = [light(1, sky, 0.0)];
        dark.apply(&mut l);
        assert_eq!(l[0].dir, sky);
    }

    #[test]
    fn bad_taps_are_rejected() {
        assert!(FirFilter::new(&[]).is_err());
        assert!(FirFilter::new(&[1.0, f64::NAN]).is_err());
        assert!(FirFilter::new(&[1.0, -1.0]).is_err());
        assert!(FirFilter::new(&[1.0; 65]).is_err());
        assert_eq!(
            FirFilter::new(&[2.0, 2.0]).map(|f| f.taps().to_vec()),
            Ok(vec![0.5, 0.5])
        );
    }
}
