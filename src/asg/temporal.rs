//! Temporal FIR filtering of fitted ASG lobes, by lobe id, with the lights' taps — so that a
//! lobe set describes the same moment as the lights of its seq.
//!
//! The lights are filtered by [`crate::decompose::filter::FirFilter`] and lag the frames by its
//! delay (3 frames with the default binomial taps); the SH and wavelet sets are filtered with the
//! same taps ([`crate::set_filter`]) and exactly so, since they are linear in the frame. A fit
//! is not linear in the frame, but a warm-started fit keeps lobe i on the same feature from
//! frame to frame (its temporal loss L_T, [`super::fit`]), so lobe i has a trajectory that can be
//! filtered like light i's. Steps of [`LobeFilter::apply`] for the lobes of one frame:
//!
//! 1. **Align.** A lobe (z, x, λ, μ) is the same function as (z, −x, λ, μ) and as (z, ±y, μ, λ)
//!    (y = z × x): the fit may hand over any of them. Each lobe takes the one of the four whose
//!    tangent is nearest to the same lobe's tangent in the previous frame, so the tangents
//!    and bandwidths that are averaged belong together (a lobe with λ ≈ μ whose fit swapped
//!    its axes would otherwise be averaged into a rounder one).
//! 2. **State.** Each lobe becomes twelve numbers that a weighted sum can average:
//!    its energy E = c·∫g dω per channel (W/m², like a light's rgb), and q·z, q·x, q·ln λ,
//!    q·ln μ and q, with q the luminance of E (plus [`WEIGHT_FLOOR`]).
//! 3. **Filter.** The states go through the set filter of [`crate::set_filter`]: the window of
//!    the last `taps` frames, frames the stage skipped filled in by linear interpolation, a
//!    new lobe count or a restarted frame count starting the window afresh (the first output
//!    is then the set itself), and the output Σ_k w_k s(t−k) with the normalised taps w.
//! 4. **Back to lobes.** Energy Ē = Σ w E; axis z̄ = normalise(Σ w q z) and tangent x̄ = Σ w q x
//!    made ⟂ z̄: the *power-weighted* mean over the window, as the lights' directions are
//!    ([`crate::decompose::filter`]: a lobe whose power fades does not drag the direction
//!    where it was bright); bandwidths the power-weighted geometric means
//!    λ̄ = exp(Σ w q ln λ / Σ w q) (scale parameters; always within the window's range); and
//!    the amplitude c̄ = Ē / ∫ḡ dω, so the lobe carries the filtered energy exactly.
//!
//! What holds (tested below): a constant set comes out unchanged, whatever representation the
//! fit picks each frame; the total energy of the output is Σ_k w_k of the inputs' totals
//! (exactly, like the lights'); a lobe turning along a great circle at a constant rate with
//! constant power comes out where it was [`LobeFilter::delay_frames`] frames earlier (symmetric
//! taps), the lights' delay. Off a great circle a mean of unit vectors leans towards the
//! rotation's axis by a second-order amount, as the lights' does: 1.5·10⁻⁴ rad (0.009°) for a
//! lobe 45° from that axis turning 0.02 rad per frame.
//! Where the axes in the window cancel (a lobe jumping to the opposite side of the sphere), the
//! lobe is left as fitted.

use super::{integral, Asg};
use crate::set_filter::StageFilter;
use glam::DVec3;

/// Numbers per lobe in the filtered state: E (3), q·z (3), q·x (3), q·ln λ, q·ln μ, q.
const STATE_LEN: usize = 12;

/// Added to each lobe's luminance before it weights the lobe's direction and shape, so that a
/// black frame's lobes (q = 0) still have a direction: the plain tap-weighted mean. Far below
/// any real lobe's power (W/m²), and its square is still a normal f64.
pub const WEIGHT_FLOOR: f64 = 1e-100;

/// `lobe` in the representation whose tangent is nearest to `reference` (step 1).
fn aligned(lobe: &Asg, reference: DVec3) -> Asg {
    let (x, y, z) = lobe.frame();
    let (along_x, along_y) = (x.dot(reference), y.dot(reference));
    let (tangent, lambda, mu) = if along_x.abs() >= along_y.abs() {
        (x * along_x.signum(), lobe.lambda, lobe.mu)
    } else {
        (y * along_y.signum(), lobe.mu, lobe.lambda)
    };
    Asg {
        axis: lobe.axis,
        tangent: tangent.to_array(),
        bitangent: z.cross(tangent).to_array(),
        lambda,
        mu,
        rgb: lobe.rgb,
    }
}

/// The lobe's state (step 2).
fn state(lobe: &Asg) -> [f64; STATE_LEN] {
    let energy = lobe.integral();
    // The lights' weight: Rec. 709 luminance, negative parts as 0.
    let q = crate::decompose::luminance_f64(energy).max(0.0) + WEIGHT_FLOOR;
    let (x, _, z) = lobe.frame();
    [
        energy[0],
        energy[1],
        energy[2],
        q * z.x,
        q * z.y,
        q * z.z,
        q * x.x,
        q * x.y,
        q * x.z,
        q * lobe.lambda.ln(),
        q * lobe.mu.ln(),
        q,
    ]
}

/// The lobe of a filtered state (step 4); `None` where the axes cancelled.
fn lobe_of(s: &[f64]) -> Option<Asg> {
    let q = s[11];
    let axis = DVec3::new(s[3], s[4], s[5]);
    let tangent = DVec3::new(s[6], s[7], s[8]);
    // Axes that (nearly) cancel give a direction made of rounding: keep the fitted lobe.
    if axis.length() <= 1e-9 * q {
        return None;
    }
    let (lambda, mu) = ((s[9] / q).exp(), (s[10] / q).exp());
    let shape_integral = integral(lambda, mu);
    let rgb = [s[0], s[1], s[2]].map(|e| e / shape_integral);
    Asg::new(axis, tangent, lambda, mu, rgb)
}

/// The ASG stage's filter in time. See the module documentation.
#[derive(Clone, Debug)]
pub struct LobeFilter {
    filter: StageFilter<f64>,
    /// The tangents of the last frame's lobes as aligned (step 1), the references of the next
    /// frame's.
    previous_tangents: Vec<DVec3>,
    /// Scratch: the states of one frame.
    states: Vec<f64>,
}

impl LobeFilter {
    /// Filtering with `taps` (newest first; checked and normalised as the lights' filter does:
    /// 1..=64 finite, non-negative numbers, not all 0), or not at all (`None`). A single tap
    /// is no filter: the lobes pass as fitted, bit for bit (not rebuilt from their states).
    pub fn new(taps: Option<&[f64]>) -> Result<Self, String> {
        let filter = StageFilter::new(taps)?;
        Ok(Self {
            filter: if taps.is_some_and(|t| t.len() == 1) {
                StageFilter::new(None)?
            } else {
                filter
            },
            previous_tangents: Vec::new(),
            states: Vec::new(),
        })
    }

    /// Whether the lobes are filtered.
    pub fn is_filtering(&self) -> bool {
        self.filter.is_filtering()
    }

    /// The delay in frames (0 without a filter).
    pub fn delay_frames(&self) -> f64 {
        self.filter.delay_frames()
    }

    /// The number in the feed of the frame whose lobes come next (frames counted by the feed:
    /// a gap is frames the stage skipped).
    pub fn set_next_number(&mut self, number: u64) {
        self.filter.set_next_number(number);
    }

    /// Replaces `lobes`, the fit of the next frame, by the filtered lobes (steps in the module
    /// documentation). Lobe i of the output is lobe i of the input filtered in time, in the
    /// representation aligned with the previous frame's.
    pub fn apply(&mut self, lobes: &mut [Asg]) {
        if !self.is_filtering() {
            return;
        }
        if self.previous_tangents.len() == lobes.len() {
            for (lobe, &reference) in lobes.iter_mut().zip(&self.previous_tangents) {
                *lobe = aligned(lobe, reference);
            }
        }
        self.previous_tangents.clear();
        self.previous_tangents
            .extend(lobes.iter().map(|l| DVec3::from_array(l.tangent)));
        self.states.clear();
        self.states.extend(lobes.iter().flat_map(state));
        self.filter.apply(&mut self.states);
        for (lobe, s) in lobes.iter_mut().zip(self.states.chunks_exact(STATE_LEN)) {
            if let Some(filtered) = lobe_of(s) {
                *lobe = filtered;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decompose::filter::DEFAULT_TAPS;

    fn lobe(axis: DVec3, tangent: DVec3, lambda: f64, mu: f64, rgb: [f64; 3]) -> Asg {
        Asg::new(axis, tangent, lambda, mu, rgb).unwrap()
    }

    fn filter() -> LobeFilter {
        LobeFilter::new(Some(&DEFAULT_TAPS)).unwrap()
    }

    /// Directions spread over the sphere (a Fibonacci set).
    fn directions(n: usize) -> Vec<DVec3> {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let phi = golden * i as f64;
                DVec3::new(r * phi.cos(), r * phi.sin(), z)
            })
            .collect()
    }

    /// Largest difference of two lobes as functions, relative to the first's peak.
    fn function_difference(a: &Asg, b: &Asg) -> f64 {
        let peak = a.rgb.iter().fold(0.0f64, |m, c| m.max(c.abs()));
        directions(2000)
            .into_iter()
            .chain([DVec3::from_array(a.axis)])
            .map(|v| {
                let (ea, eb) = (a.eval(v), b.eval(v));
                (0..3).map(|c| (ea[c] - eb[c]).abs()).fold(0.0, f64::max)
            })
            .fold(0.0, f64::max)
            / peak
    }

    /// The angle between two unit vectors (atan2: acos loses half the digits near 0).
    fn angle(a: [f64; 3], b: [f64; 3]) -> f64 {
        let (a, b) = (DVec3::from_array(a), DVec3::from_array(b));
        a.cross(b).length().atan2(a.dot(b))
    }

    fn sun_and_sky() -> Vec<Asg> {
        vec![
            lobe(
                DVec3::new(0.3, 0.4, 0.8),
                DVec3::X,
                900.0,
                2500.0,
                [5e3, 4e3, 3e3],
            ),
            lobe(DVec3::Z, DVec3::Y, 1.5, 0.7, [0.4, 0.6, 1.0]),
        ]
    }

    #[test]
    fn a_constant_set_comes_out_unchanged_whatever_representation_the_fit_picks() {
        let mut f = filter();
        let set = sun_and_sky();
        for t in 0..20 {
            // The same functions, handed over as (x, λ, μ), (y, μ, λ), (−x, λ, μ), (−y, μ, λ).
            let mut lobes: Vec<Asg> = set
                .iter()
                .map(|l| {
                    let (x, y, z) = l.frame();
                    match t % 4 {
                        0 => *l,
                        1 => lobe(z, y, l.mu, l.lambda, l.rgb),
                        2 => lobe(z, -x, l.lambda, l.mu, l.rgb),
                        _ => lobe(z, -y, l.mu, l.lambda, l.rgb),
                    }
                })
                .collect();
            f.apply(&mut lobes);
            for (got, want) in lobes.iter().zip(&set) {
                let d = function_difference(want, got);
                assert!(d < 1e-12, "frame {t}: the lobe changed by {d:e}");
                // One representation throughout: the first frame's.
                assert!(angle(got.tangent, want.tangent) < 1e-9, "frame {t}");
                assert!((got.lambda / want.lambda - 1.0).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn a_turning_lobe_comes_out_delayed_by_the_lights_delay() {
        let mut f = filter();
        assert_eq!(f.delay_frames(), 3.0);
        let omega = 0.02; // radians per frame
                          // Along a great circle (the rotation's axis ⟂ the lobe's), its tangent along the
                          // rotation's axis: the mean of the window's unit vectors then points exactly at the
                          // middle one. (Off such a circle the mean leans towards the rotation's axis by a
                          // second-order amount: below.)
        let turn = DVec3::new(0.2, 1.0, 0.1).normalize();
        let start = turn.any_orthonormal_vector();
        // Off a great circle: 45° from the rotation's axis, tangent anywhere.
        let small_circle = (start + turn).normalize();
        let at = |t: f64, axis: DVec3, tangent: DVec3| {
            let rotation = glam::DQuat::from_axis_angle(turn, omega * t);
            // λ grows geometrically: it passes delayed as well. (The power stays constant: it
            // weights the mean direction, so a ramp of power would pull it towards the newer
            // frames.)
            let l = lobe(
                rotation * axis,
                rotation * tangent,
                40.0 * (0.01 * t).exp(),
                90.0,
                [1.0, 1.0, 1.0],
            );
            let scale = 100.0 / integral(l.lambda, l.mu);
            Asg {
                rgb: [scale, 0.5 * scale, 0.25 * scale],
                ..l
            }
        };
        let lobes_at = |t: f64| [at(t, start, turn), at(t, small_circle, DVec3::X)];
        let mut worst_off_circle = 0.0f64;
        for t in 0..30 {
            let mut lobes = lobes_at(t as f64);
            f.apply(&mut lobes);
            if t >= 6 {
                let [want, want_off] = lobes_at(t as f64 - 3.0);
                let [got, got_off] = lobes;
                assert!(angle(got.axis, want.axis) < 1e-9, "frame {t}: axis");
                assert!(
                    angle(got.tangent, want.tangent) < 1e-9,
                    "frame {t}: tangent"
                );
                assert!(
                    (got.lambda / want.lambda - 1.0).abs() < 1e-9,
                    "frame {t}: λ"
                );
                let (eg, ew) = (got.integral(), want.integral());
                assert!((eg[1] / ew[1] - 1.0).abs() < 1e-12, "frame {t}: energy");
                worst_off_circle = worst_off_circle
                    .max(angle(got_off.axis, want_off.axis))
                    .max(angle(got_off.tangent, want_off.tangent));
            }
        }
        // The lean: the window's vectors, spread over ±3ω about the middle one, average to a
        // part ⟂ the rotation's axis shorter by Σ w_k (1 − cos δ_k) ≈ 0.75ω² (δ_k = (k − 3)ω,
        // Σ w_k δ_k² = 1.5ω² for the binomial taps), which tilts a vector 45° from that axis
        // by ≈ 0.375ω².
        assert!(
            worst_off_circle > 1e-6 && worst_off_circle < 0.5 * omega * omega,
            "off the great circle: {worst_off_circle:e} rad"
        );
    }

    #[test]
    fn the_total_energy_is_filtered_exactly() {
        let taps: Vec<f64> = DEFAULT_TAPS.iter().map(|w| w / 64.0).collect();
        let mut f = filter();
        let frames: Vec<Vec<Asg>> = (0..25)
            .map(|t| {
                let t = t as f64;
                (0..5)
                    .map(|i| {
                        let i = i as f64;
                        lobe(
                            DVec3::new((t * 0.3 + i).sin(), (t * 0.2 - i).cos(), 0.5 + i),
                            DVec3::new(1.0, i, -t),
                            2.0 + (t * 0.7 + i).sin().abs() * 300.0,
                            5.0 + i * 40.0,
                            [1.0 + (t + i).cos().abs(), 2.0, 0.5 + 0.1 * t],
                        )
                    })
                    .collect()
            })
            .collect();
        let total = |lobes: &[Asg]| -> [f64; 3] {
            lobes.iter().fold([0.0; 3], |s, l| {
                let e = l.integral();
                [s[0] + e[0], s[1] + e[1], s[2] + e[2]]
            })
        };
        for t in 0..frames.len() {
            let mut lobes = frames[t].clone();
            f.apply(&mut lobes);
            let got = total(&lobes);
            // The window before frame 0 holds frame 0 (the filter's start).
            let mut want = [0.0; 3];
            for (k, w) in taps.iter().enumerate() {
                let e = total(&frames[t.saturating_sub(k)]);
                for c in 0..3 {
                    want[c] += w * e[c];
                }
            }
            for c in 0..3 {
                assert!(
                    (got[c] / want[c] - 1.0).abs() < 1e-12,
                    "frame {t}: {got:?} vs {want:?}"
                );
            }
        }
    }

    #[test]
    fn skipped_frames_keep_the_delay_of_an_energy_ramp() {
        let at = |t: u64| {
            let mut l = sun_and_sky();
            for lobe in &mut l {
                lobe.rgb = lobe.rgb.map(|c| c * (1.0 + 0.1 * t as f64));
            }
            l
        };
        let (mut every, mut some) = (filter(), filter());
        for t in 0..20u64 {
            let mut a = at(t);
            every.set_next_number(t);
            every.apply(&mut a);
            if t >= 6 {
                // A linear ramp of energy passes delayed by 3 frames.
                for (got, want) in a.iter().zip(&at(t - 3)) {
                    let (eg, ew) = (got.integral(), want.integral());
                    assert!((eg[0] / ew[0] - 1.0).abs() < 1e-12, "frame {t}: energy");
                }
            }
            if t % 3 != 1 {
                let mut b = at(t);
                some.set_next_number(t);
                some.apply(&mut b);
                for (x, y) in a.iter().zip(&b) {
                    assert!(function_difference(x, y) < 1e-12, "frame {t}");
                }
            }
        }
    }

    #[test]
    fn a_new_lobe_count_or_no_taps_passes_the_fit_unchanged() {
        let mut f = filter();
        let mut one = vec![sun_and_sky()[1]];
        for _ in 0..5 {
            f.apply(&mut one);
        }
        let mut two = sun_and_sky();
        // Both far from the one-lobe history: a filter that did not restart would blend them.
        two[1].rgb = [9.0, 9.0, 9.0];
        let want = two.clone();
        f.apply(&mut two);
        for (got, want) in two.iter().zip(&want) {
            assert!(function_difference(want, got) < 1e-12);
        }
        for taps in [None, Some(&[3.0][..])] {
            let mut off = LobeFilter::new(taps).unwrap();
            assert!(!off.is_filtering());
            assert_eq!(off.delay_frames(), 0.0);
            let mut lobes = sun_and_sky();
            off.apply(&mut lobes);
            assert_eq!(lobes, sun_and_sky());
        }
        assert!(LobeFilter::new(Some(&[-1.0])).is_err());
        assert!(LobeFilter::new(Some(&[1.0, -1.0])).is_err());
    }

    #[test]
    fn black_lobes_keep_a_direction_and_a_fading_lobe_keeps_its_bright_direction() {
        let mut f = filter();
        // Black: zero amplitude, the axis the plain mean of the window's (here constant).
        let black = lobe(DVec3::Y, DVec3::X, 3.0, 4.0, [0.0; 3]);
        let mut lobes = vec![black];
        f.apply(&mut lobes);
        f.apply(&mut lobes);
        assert!(angle(lobes[0].axis, black.axis) < 1e-12);
        assert_eq!(lobes[0].rgb, [0.0; 3]);
        // A bright lobe that goes out and moves: the direction stays with the bright samples.
        let mut f = filter();
        let bright = lobe(DVec3::Z, DVec3::X, 500.0, 500.0, [1e4; 3]);
        for _ in 0..7 {
            f.apply(&mut [bright]);
        }
        let mut faded = vec![lobe(DVec3::X, DVec3::Y, 2.0, 2.0, [1e-3; 3])];
        f.apply(&mut faded);
        assert!(
            angle(faded[0].axis, bright.axis) < 1e-4,
            "{:?}",
            faded[0].axis
        );
    }
}
