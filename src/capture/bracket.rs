//! HDR from an ordinary camera: merging exposure brackets, and recovering the camera response
//! from them (Debevec & Malik, "Recovering High Dynamic Range Radiance Maps from Photographs",
//! SIGGRAPH 1997).
//!
//! # Merge ([`merge_brackets`])
//!
//! Every bracket k has code values v_k (normalised, [0, 1]) and an effective exposure
//! T_k = t_k · gain_k. Per pixel and channel:
//! 1. the radiance seen by bracket k is L_k = X(v_k) · wb · scale / T_k (see [`super::response`]);
//! 2. its weight is w = T_k · hat(v) with hat(v) = min(v − dark, saturated − v), so codes at or
//!    below `dark` (noise, black level) or at or above `saturated` (clipped) get no weight.
//!    Debevec & Malik use the hat alone; the factor T_k makes it the noise-optimal weight for
//!    photon (shot) noise, whose variance in L_k falls as 1/T_k (Granados et al., "Optimal HDR
//!    reconstruction with linear digital cameras", CVPR 2010): without it, read noise in the
//!    short exposures, amplified by 1/T_k, dominates the dark parts of the scene;
//! 3. L = Σ w_k L_k / Σ w_k. If no bracket has weight, the pixel is too bright for the
//!    shortest exposure (then its L_k is used: a lower bound) or too dark for the longest
//!    (then the longest exposure's L_k is used).
//!
//! # Response recovery ([`recover_response`])
//!
//! Codes are quantised to n levels z = 0 … n−1. With g(z) = ln X(z) (the log inverse response),
//! every sample pixel i seen in bracket j gives g(Z_ij) = ln E_i + ln T_j. Debevec & Malik's
//! `gsolve` finds g and the ln E_i by weighted linear least squares:
//! - data rows w(Z_ij)·(g(Z_ij) − ln E_i) = w(Z_ij)·ln T_j for every sample and bracket;
//! - one row g(n/2) = 0 fixing the scale (the curve is relative: X = 1 at mid code);
//! - smoothness rows λ·w(z)·(g(z−1) − 2g(z) + g(z+1)) = 0 for z = 1 … n−2;
//!
//! with Debevec & Malik's hat weight w(z) = min(z, n−1−z) (so clipped and black samples carry no
//! data; the smoothness rows use w(z) + 1 so the end codes stay tied to their neighbours). In the
//! normal equations each ln E_i is coupled only to the codes of its own sample, so it is
//! eliminated in closed form (the Schur complement: each sample adds a small outer product to
//! the n×n block of g), and the n×n system is solved by a dense Cholesky factorisation in f64,
//! its large columns on rayon's threads, the three channels side by side: O(n³ + N·J²) for J
//! brackets instead of O((n + N)³). Samples are chosen per bracket at evenly
//! spaced quantiles of its code values, so every part of the code range is covered. Each
//! channel is solved on its own (so each channel's curve is 1 at mid code; the colour balance
//! between channels is the `white_balance` of the config).

use super::pixel_format::CodeImage;
use super::response::{Linearizer, Radiometry, ResponseCurve, ResponseModel};
use rayon::prelude::*;

/// Errors of merging and calibration; messages name the bracket or setting at fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BracketError {
    #[error("no brackets given")]
    Empty,
    #[error("bracket {index} is {width}x{height}, bracket 1 is {first_width}x{first_height}")]
    SizeMismatch {
        index: usize,
        width: u32,
        height: u32,
        first_width: u32,
        first_height: u32,
    },
    #[error(
        "bracket {index}: exposure {exposure} (exposure time × gain) must be a finite positive number"
    )]
    Exposure { index: usize, exposure: f64 },
    #[error(
        "bracket {longer} (exposure {longer_exposure} s) is darker than bracket {shorter} \
         ({shorter_exposure} s): mean code {longer_mean:.4} against {shorter_mean:.4}; are \
         the exposures listed in the order of the images?"
    )]
    Order {
        shorter: usize,
        shorter_exposure: f64,
        shorter_mean: f64,
        longer: usize,
        longer_exposure: f64,
        longer_mean: f64,
    },
    #[error("{0}")]
    Settings(String),
    #[error("response recovery failed: {0}")]
    Solve(String),
}

/// One exposure of a bracket set.
#[derive(Clone, Debug)]
pub struct Bracket {
    pub image: CodeImage,
    /// Exposure time in seconds.
    pub exposure_s: f64,
    /// Linear gain (1 = unity).
    pub gain: f64,
}

/// Code-value limits of the merge weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MergeLimits {
    /// Codes at or below are noise (no weight).
    pub dark: f32,
    /// Codes at or above are clipped (no weight).
    pub saturated: f32,
}

impl Default for MergeLimits {
    fn default() -> Self {
        Self {
            dark: 0.02,
            saturated: 0.98,
        }
    }
}

impl MergeLimits {
    /// Checks 0 ≤ dark < saturated ≤ 1.
    pub fn check(&self) -> Result<(), String> {
        if !(self.dark >= 0.0 && self.dark < self.saturated && self.saturated <= 1.0) {
            return Err(format!(
                "dark = {} and saturated = {} must satisfy 0 <= dark < saturated <= 1",
                self.dark, self.saturated
            ));
        }
        Ok(())
    }

    #[inline]
    fn weight(&self, v: f32) -> f32 {
        (v - self.dark).min(self.saturated - v).max(0.0)
    }
}

fn check_brackets(brackets: &[Bracket]) -> Result<(), BracketError> {
    let first = brackets.first().ok_or(BracketError::Empty)?;
    for (i, b) in brackets.iter().enumerate() {
        if (b.image.width, b.image.height) != (first.image.width, first.image.height)
            || b.image.pixels.len() != first.image.pixels.len()
        {
            return Err(BracketError::SizeMismatch {
                index: i + 1,
                width: b.image.width,
                height: b.image.height,
                first_width: first.image.width,
                first_height: first.image.height,
            });
        }
        let exposure = b.exposure_s * b.gain;
        if !(exposure.is_finite() && exposure > 0.0) {
            return Err(BracketError::Exposure {
                index: i + 1,
                exposure,
            });
        }
    }
    Ok(())
}

/// Merges a bracket set into one radiance image (see the module docs). `radiometry`'s
/// white balance and scale are used; its exposure and gain are replaced by each bracket's.
pub fn merge_brackets(
    brackets: &[Bracket],
    model: &ResponseModel,
    code_max: f32,
    radiometry: &Radiometry,
    limits: MergeLimits,
) -> Result<Vec<[f32; 3]>, BracketError> {
    check_brackets(brackets)?;
    limits.check().map_err(BracketError::Settings)?;
    let lins: Vec<Linearizer> = brackets
        .iter()
        .map(|b| {
            let r = Radiometry {
                exposure_s: b.exposure_s,
                gain: b.gain,
                ..*radiometry
            };
            Linearizer::new(model, code_max, &r)
        })
        .collect();
    let exposure = |k: usize| brackets[k].exposure_s * brackets[k].gain;
    let shortest = (0..brackets.len())
        .min_by(|&a, &b| exposure(a).total_cmp(&exposure(b)))
        .unwrap_or(0);
    let longest = (0..brackets.len())
        .max_by(|&a, &b| exposure(a).total_cmp(&exposure(b)))
        .unwrap_or(0);
    let n = brackets[0].image.pixels.len();
    let mut out = vec![[0.0f32; 3]; n];
    for (i, px) in out.iter_mut().enumerate() {
        for c in 0..3 {
            let (mut num, mut den) = (0.0f32, 0.0f32);
            for (b, lin) in brackets.iter().zip(&lins) {
                let v = b.image.pixels[i][c];
                let w = limits.weight(v) * (b.exposure_s * b.gain) as f32;
                if w > 0.0 {
                    num += w * lin.apply(c, v);
                    den += w;
                }
            }
            px[c] = if den > 0.0 {
                num / den
            } else {
                let short_v = brackets[shortest].image.pixels[i][c];
                let k = if short_v >= limits.saturated {
                    shortest
                } else {
                    longest
                };
                lins[k].apply(c, brackets[k].image.pixels[i][c])
            };
        }
    }
    Ok(out)
}

/// Reads an 8- or 16-bit PNG (one bracket of an ordinary camera) as normalised code values.
pub fn read_bracket_image(path: &std::path::Path) -> Result<CodeImage, super::CaptureError> {
    let err = |message: String| super::CaptureError::Format {
        path: path.to_path_buf(),
        message,
    };
    let file = crate::read_file::open_regular_file(path, "an image").map_err(|source| {
        super::CaptureError::Io {
            path: path.to_path_buf(),
            source,
        }
    })?;
    let reader = image::ImageReader::new(std::io::BufReader::new(file));
    let decoder = reader
        .with_guessed_format()
        .map_err(|e| err(e.to_string()))?
        .into_decoder()
        .map_err(|e| err(e.to_string()))?;
    // The size first: a small file can declare a huge image.
    let (width, height) = image::ImageDecoder::dimensions(&decoder);
    // Codes are what a camera wrote; a floating-point image (Radiance .hdr, float TIFF) is
    // radiance already, and its values above 1 were clamped to 1 without a word.
    let colour = image::ImageDecoder::color_type(&decoder);
    if matches!(colour, image::ColorType::Rgb32F | image::ColorType::Rgba32F) {
        return Err(err(format!(
            "is a floating-point image ({colour:?}): brackets are the camera's 8- or 16-bit \
             codes (PNG); an HDR image needs no response recovery"
        )));
    }
    if u64::from(width) * u64::from(height) > super::image_file::MAX_PIXELS {
        return Err(err(format!(
            "image is too large ({width}x{height}; at most {} pixels are read)",
            super::image_file::MAX_PIXELS
        )));
    }
    let img = image::DynamicImage::from_decoder(decoder)
        .map_err(|e| err(e.to_string()))?
        .into_rgb32f();
    let (width, height) = img.dimensions();
    let mut values = img.into_raw();
    for v in &mut values {
        *v = v.clamp(0.0, 1.0);
    }
    // The f32 image's own buffer as RGB triples, not a copy of it (a copy took another
    // 1.6 GB for a 16384 × 8192 PNG; an audit); copied only should its allocation not be
    // whole triples.
    let pixels: Vec<[f32; 3]> = bytemuck::allocation::try_cast_vec(values)
        .unwrap_or_else(|(_, values)| values.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect());
    if pixels.len() != width as usize * height as usize {
        return Err(err(
            "decoder returned the wrong number of pixels".to_string()
        ));
    }
    Ok(CodeImage {
        width,
        height,
        pixels,
    })
}

/// The largest smoothness weight λ of [`recover_response`].
pub const MAX_LAMBDA: f64 = 1e6;

/// Settings of [`recover_response`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveSettings {
    /// Quantisation levels of the curve (256 for 8-bit cameras).
    pub levels: usize,
    /// Smoothness weight λ.
    pub lambda: f64,
    /// Sample pixels (spread over the brackets).
    pub samples: usize,
}

impl Default for SolveSettings {
    fn default() -> Self {
        Self {
            levels: 256,
            lambda: 100.0,
            samples: 300,
        }
    }
}

/// A [`SolveSettings`] field out of its range: the field's name (that of its
/// `calibrate-response` option too), its value and the range.
#[derive(Debug, Clone, PartialEq)]
pub struct SettingProblem {
    pub field: &'static str,
    pub value: String,
    pub requirement: String,
}

impl std::fmt::Display for SettingProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} = {} {}", self.field, self.value, self.requirement)
    }
}

impl SolveSettings {
    /// The ranges [`recover_response`] needs, checked without brackets (so a command can
    /// refuse them before it reads any image).
    pub fn check(&self) -> Result<(), SettingProblem> {
        let problem = |field, value: String, requirement: String| SettingProblem {
            field,
            value,
            requirement,
        };
        if !(4..=4096).contains(&self.levels) {
            return Err(problem(
                "levels",
                self.levels.to_string(),
                "must be in 4..=4096".into(),
            ));
        }
        // λ = 0 leaves the curve free at codes no sample has (a singular system); past 10⁶ the
        // smoothness rows swamp the data rows in f64 (1e300 made the system singular too).
        if !(self.lambda > 0.0 && self.lambda <= MAX_LAMBDA) {
            return Err(problem(
                "lambda",
                self.lambda.to_string(),
                format!("must be in (0, {MAX_LAMBDA:e}]"),
            ));
        }
        if !(2..=5000).contains(&self.samples) {
            return Err(problem(
                "samples",
                self.samples.to_string(),
                "must be in 2..=5000".into(),
            ));
        }
        Ok(())
    }
}

/// Recovers a camera's response curve from brackets of a static scene (Debevec & Malik's
/// gsolve per channel). Gains are folded into the exposures.
pub fn recover_response(
    brackets: &[Bracket],
    settings: SolveSettings,
) -> Result<ResponseCurve, BracketError> {
    check_brackets(brackets)?;
    if brackets.len() < 2 {
        return Err(BracketError::Settings(
            "response recovery needs at least 2 brackets with different exposures".into(),
        ));
    }
    settings
        .check()
        .map_err(|p| BracketError::Settings(p.to_string()))?;
    let n = settings.levels;
    let first_exposure = brackets[0].exposure_s * brackets[0].gain;
    if brackets
        .iter()
        .all(|b| (b.exposure_s * b.gain - first_exposure).abs() <= 1e-9 * first_exposure)
    {
        return Err(BracketError::Settings(format!(
            "response recovery needs brackets with different exposures; every bracket's \
             exposure × gain is {first_exposure} s"
        )));
    }
    if brackets[0].image.pixels.is_empty() {
        return Err(BracketError::Settings("the brackets have no pixels".into()));
    }
    // Two brackets of different exposures with the same pixels cannot both be right (one
    // image given twice) unless none of them is between black and clipped: the solve found no
    // consistent curve and blamed the data or λ.
    let has_data =
        |b: &Bracket| (b.image.pixels.iter()).any(|p| p.iter().any(|&c| c > 0.0 && c < 1.0));
    for (i, a) in brackets.iter().enumerate().filter(|(_, b)| has_data(b)) {
        if let Some(j) =
            (i + 1..brackets.len()).find(|&j| brackets[j].image.pixels == a.image.pixels)
        {
            return Err(BracketError::Settings(format!(
                "brackets {} and {} (exposures {} s and {} s) have the same pixels: the same \
                 image given twice? Each exposure needs its own image",
                i + 1,
                j + 1,
                a.exposure_s,
                brackets[j].exposure_s
            )));
        }
    }
    check_exposure_order(brackets)?;
    let picks = sample_pixels(brackets, settings.samples);
    let ln_t: Vec<f64> = brackets
        .iter()
        .map(|b| (b.exposure_s * b.gain).ln())
        .collect();
    let top = (n - 1) as f64;
    // Debevec & Malik's hat: 0 at both ends, so clipped and black samples carry no data
    let weight = |z: usize| z.min(n - 1 - z) as f64;
    let code = |b: &Bracket, p: usize, c: usize| {
        let v = f64::from(b.image.pixels[p][c]).clamp(0.0, 1.0);
        (v * top).round() as usize
    };
    let solve_channel = |c: usize| -> Result<Vec<f64>, BracketError> {
        let channel = ["red", "green", "blue"][c];
        // A sample clipped or black in every bracket carries no data in this channel (all its
        // weights are 0) and would leave its unknown log irradiance free: the system singular.
        let samples: Vec<usize> = picks
            .iter()
            .copied()
            .filter(|&p| brackets.iter().any(|b| weight(code(b, p, c)) > 0.0))
            .collect();
        if samples.len() < 2 {
            return Err(BracketError::Solve(format!(
                "the {channel} channel has fewer than 2 sample pixels that are neither black nor \
                 clipped in some bracket: the brackets need a wider range of exposures, or \
                 more sample pixels"
            )));
        }
        // g(n/2) = 0 fixes the scale (the rest of the system does not change when a constant
        // is added to g and every ln E): that unknown is left out of the normal equations,
        // which fixes it exactly, where gsolve's row of weight 1 for it was lost in rounding
        // beside smoothness rows of weight λ²·n². Code z's unknown is row `unknown(z)` of the
        // m = n − 1 left; terms of g(n/2) are 0 and dropped.
        let (fixed, m) = (n / 2, n - 1);
        let unknown = |z: usize| match z.cmp(&fixed) {
            std::cmp::Ordering::Less => Some(z),
            std::cmp::Ordering::Equal => None,
            std::cmp::Ordering::Greater => Some(z - 1),
        };
        // The normal equations of g alone: the rows that hold only g (the smoothness rows) ...
        let mut ata = vec![0.0f64; m * m];
        let mut atb = vec![0.0f64; m];
        let mut add_row = |entries: &[(usize, f64)], rhs: f64| {
            for (i, a) in entries.iter().filter_map(|&(z, a)| Some((unknown(z)?, a))) {
                atb[i] += a * rhs;
                for (j, b) in entries.iter().filter_map(|&(z, b)| Some((unknown(z)?, b))) {
                    ata[i * m + j] += a * b;
                }
            }
        };
        for z in 1..n - 1 {
            let w = settings.lambda * (weight(z) + 1.0);
            add_row(&[(z - 1, w), (z, -2.0 * w), (z + 1, w)], 0.0);
        }
        // ... and each sample's data rows with its ln E eliminated (the Schur complement).
        // Sample i's rows w·(g(Z_ij) − ln E_i) = w·ln T_j add w² to its own diagonal entry
        // d_i and −w² at (Z_ij, ln E_i); eliminating ln E_i leaves the g block plus the
        // outer product of those entries divided by d_i, and the matching right-hand side.
        let mut coupling: Vec<(usize, f64)> = Vec::with_capacity(brackets.len());
        for &p in &samples {
            coupling.clear();
            let (mut d, mut rhs_e) = (0.0f64, 0.0f64);
            for (b, &lt) in brackets.iter().zip(&ln_t) {
                let z = code(b, p, c);
                let w2 = weight(z).powi(2);
                if w2 == 0.0 {
                    continue;
                }
                d += w2;
                rhs_e -= w2 * lt;
                if let Some(k) = unknown(z) {
                    ata[k * m + k] += w2;
                    atb[k] += w2 * lt;
                    coupling.push((k, -w2));
                }
            }
            for &(i, bi) in &coupling {
                atb[i] -= bi * rhs_e / d;
                for &(j, bj) in &coupling {
                    ata[i * m + j] -= bi * bj / d;
                }
            }
        }
        let g = cholesky_solve(&mut ata, &atb, m).map(|mut g| {
            g.insert(fixed, 0.0);
            g
        });
        let g = g.ok_or_else(|| {
            BracketError::Solve(format!(
                "the {channel} channel's system is singular (too little data: more sample \
                 pixels or a wider range of exposures; or a smoothness weight lambda above \
                 its {})",
                settings.lambda
            ))
        })?;
        let values: Vec<f64> = g.iter().map(|&g| g.exp()).collect();
        if values.iter().any(|v| !v.is_finite()) {
            return Err(BracketError::Solve("the solution overflowed".into()));
        }
        Ok(values)
    };
    // The three channels are independent systems: solved side by side on rayon's threads.
    let mut solved = (0..3usize)
        .into_par_iter()
        .map(solve_channel)
        .collect::<Result<Vec<_>, _>>()?
        .into_iter();
    let values: [Vec<f64>; 3] = std::array::from_fn(|_| solved.next().unwrap_or_default());
    let codes = (0..n).map(|z| z as f64 / top).collect();
    ResponseCurve::new(codes, values).map_err(BracketError::Solve)
}

/// The sample pixels of [`recover_response`]: `samples` spread over the brackets, each
/// bracket's at evenly spaced quantiles of its mean code; sorted, without repeats.
fn sample_pixels(brackets: &[Bracket], samples: usize) -> Vec<usize> {
    let pixels = brackets[0].image.pixels.len();
    let per = samples.div_ceil(brackets.len()).max(1);
    let mut picks: Vec<usize> = Vec::new();
    for b in brackets {
        let mut order: Vec<(f32, usize)> = (b.image.pixels.iter())
            .enumerate()
            .map(|(i, p)| ((p[0] + p[1] + p[2]) / 3.0, i))
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0));
        for k in 0..per {
            let q = (k as f64 + 0.5) / per as f64;
            picks.push(order[((q * pixels as f64) as usize).min(pixels - 1)].1);
        }
    }
    picks.sort_unstable();
    picks.dedup();
    picks
}

/// The smallest ratio of the longest to the shortest exposure (× gain) that says anything
/// about a response curve: brackets closer than this (about 1/7 stop) are the same picture.
pub const MIN_EXPOSURE_SPAN: f64 = 1.1;

/// Checks that the brackets can be what their exposures say: they span at least
/// [`MIN_EXPOSURE_SPAN`], and a longer exposure is never darker (its mean code lower by more
/// than half a code of 8 bits) than a shorter one. Exposures listed in another order than the
/// images gave a decreasing curve, and two nearly equal ones a flat curve, both written without
/// a word.
fn check_exposure_order(brackets: &[Bracket]) -> Result<(), BracketError> {
    let exposure = |b: &Bracket| b.exposure_s * b.gain;
    let mut order: Vec<usize> = (0..brackets.len()).collect();
    order.sort_by(|&a, &b| exposure(&brackets[a]).total_cmp(&exposure(&brackets[b])));
    let (shortest, longest) = (order[0], order[order.len() - 1]);
    let span = exposure(&brackets[longest]) / exposure(&brackets[shortest]);
    if span < MIN_EXPOSURE_SPAN {
        return Err(BracketError::Settings(format!(
            "the exposures span only {span:.6}× (bracket {} at {} s to bracket {} at {} s): \
             brackets this close say nothing about the curve; shoot them 1–2 stops apart",
            shortest + 1,
            exposure(&brackets[shortest]),
            longest + 1,
            exposure(&brackets[longest])
        )));
    }
    let mean_code = |b: &Bracket| {
        let sum: f64 = (b.image.pixels.iter())
            .map(|p| f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2]))
            .sum();
        sum / (3 * b.image.pixels.len()) as f64
    };
    let means: Vec<f64> = brackets.iter().map(mean_code).collect();
    for pair in order.windows(2) {
        let (shorter, longer) = (pair[0], pair[1]);
        if exposure(&brackets[longer]) > exposure(&brackets[shorter])
            && means[longer] < means[shorter] - 0.5 / 255.0
        {
            return Err(BracketError::Order {
                shorter: shorter + 1,
                shorter_exposure: exposure(&brackets[shorter]),
                shorter_mean: means[shorter],
                longer: longer + 1,
                longer_exposure: exposure(&brackets[longer]),
                longer_mean: means[longer],
            });
        }
    }
    Ok(())
}

/// Solves A x = b for symmetric positive definite A (row-major m×m, its lower triangle
/// overwritten by the Cholesky factor L). `None` if A is not positive definite.
///
/// Row-oriented (Cholesky–Crout): column j of L is `L[i][j] = (A[i][j] − L[i][..j]·L[j][..j]) /
/// L[j][j]` for the rows i below j, each a dot product of two contiguous row prefixes; the rows
/// of a column are independent, so a large column's rows are shared out over rayon's threads
/// (the result does not depend on how: each entry is one thread's dot product).
fn cholesky_solve(a: &mut [f64], b: &[f64], m: usize) -> Option<Vec<f64>> {
    /// Below this much work (rows × length of their dot products) a column stays on the
    /// calling thread.
    const PARALLEL_WORK: usize = 1 << 15;
    for j in 0..m {
        let (above, below) = a.split_at_mut((j + 1) * m);
        let row_j = &mut above[j * m..];
        let d = row_j[j] - dot(&row_j[..j], &row_j[..j]);
        if !(d.is_finite() && d > 0.0) {
            return None;
        }
        let d = d.sqrt();
        row_j[j] = d;
        let row_j = &row_j[..j];
        let column = |row_i: &mut [f64]| row_i[j] = (row_i[j] - dot(&row_i[..j], row_j)) / d;
        if (m - j - 1) * j >= PARALLEL_WORK {
            below.par_chunks_mut(m).for_each(column);
        } else {
            below.chunks_mut(m).for_each(column);
        }
    }
    let mut y = b.to_vec();
    for i in 0..m {
        y[i] = (y[i] - dot(&a[i * m..i * m + i], &y[..i])) / a[i * m + i];
    }
    for i in (0..m).rev() {
        for k in i + 1..m {
            y[i] -= a[k * m + i] * y[k];
        }
        y[i] /= a[i * m + i];
    }
    Some(y)
}

/// The dot product of two slices of equal length, in four interleaved partial sums (which
/// the compiler keeps in vector registers; a single running sum has to be added in order).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let rest: f64 = (a4.remainder().iter().zip(b4.remainder()))
        .map(|(x, y)| x * y)
        .sum();
    let mut sums = [0.0f64; 4];
    for (x, y) in a4.zip(b4) {
        for k in 0..4 {
            sums[k] += x[k] * y[k];
        }
    }
    (sums[0] + sums[1]) + (sums[2] + sums[3]) + rest
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(pixels: Vec<[f32; 3]>) -> CodeImage {
        CodeImage {
            width: pixels.len() as u32,
            height: 1,
            pixels,
        }
    }

    #[test]
    fn cholesky_solves_a_known_system() {
        let mut a = vec![4.0, 2.0, 2.0, 3.0];
        let x = cholesky_solve(&mut a, &[2.0, 1.0], 2).unwrap();
        assert!((x[0] - 0.5).abs() < 1e-12 && x[1].abs() < 1e-12, "{x:?}");
        let mut singular = vec![1.0, 1.0, 1.0, 1.0];
        assert!(cholesky_solve(&mut singular, &[1.0, 1.0], 2).is_none());
    }

    /// A system large enough for the columns shared out over threads (m = 400): the solution
    /// satisfies A x = b to round-off.
    #[test]
    fn cholesky_solves_a_large_system() {
        let m = 400;
        let mut state = 1u64;
        let mut random = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let r: Vec<f64> = (0..m * m).map(|_| random()).collect();
        // A = R Rᵀ + I: symmetric positive definite
        let mut a = vec![0.0; m * m];
        for i in 0..m {
            for j in 0..m {
                a[i * m + j] = dot(&r[i * m..(i + 1) * m], &r[j * m..(j + 1) * m])
                    + f64::from(u8::from(i == j));
            }
        }
        let b: Vec<f64> = (0..m).map(|_| random()).collect();
        let x = cholesky_solve(&mut a.clone(), &b, m).unwrap();
        let worst = (0..m)
            .map(|i| (dot(&a[i * m..(i + 1) * m], &x) - b[i]).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-9, "residual {worst}");
    }

    /// Brackets of a synthetic scene of `w`×`h` radiances from 0.02 to 3 taken at `exposures`
    /// through a gamma-2.2 curve, its green and blue channels bent a little differently.
    fn graded_brackets((w, h): (u32, u32), exposures: &[f64]) -> Vec<Bracket> {
        let scene: Vec<f64> = (0..w * h)
            .map(|i| 0.02 + 3.0 * f64::from(i % 97) / 97.0 * f64::from(i % 13 + 1) / 13.0)
            .collect();
        (exposures.iter())
            .map(|&t| Bracket {
                image: CodeImage {
                    width: w,
                    height: h,
                    pixels: (scene.iter())
                        .map(|&x| {
                            let v = ((x * t).min(1.0).powf(1.0 / 2.2)) as f32;
                            [v, (v * 0.9).min(1.0), v.powf(1.1)]
                        })
                        .collect(),
                },
                exposure_s: t,
                gain: 1.0,
            })
            .collect()
    }

    /// The log irradiances eliminated from the normal equations (what `recover_response`
    /// solves) give the curve of the full system of g and ln E (Debevec & Malik's gsolve
    /// as written), assembled and solved here directly.
    #[test]
    fn eliminating_the_log_irradiances_gives_the_full_systems_curve() {
        let brackets = graded_brackets((40, 30), &[0.1, 0.4, 1.6]);
        let settings = SolveSettings {
            levels: 64,
            lambda: 10.0,
            samples: 90,
        };
        let curve = recover_response(&brackets, settings).unwrap();

        // The same samples as recover_response.
        let n = settings.levels;
        let top = (n - 1) as f64;
        let picks = sample_pixels(&brackets, settings.samples);
        let weight = |z: usize| z.min(n - 1 - z) as f64;
        let code = |b: &Bracket, p: usize, c: usize| {
            (f64::from(b.image.pixels[p][c]).clamp(0.0, 1.0) * top).round() as usize
        };
        for c in 0..3 {
            let samples: Vec<usize> = (picks.iter().copied())
                .filter(|&p| brackets.iter().any(|b| weight(code(b, p, c)) > 0.0))
                .collect();
            let m = n + samples.len();
            let mut ata = vec![0.0; m * m];
            let mut atb = vec![0.0; m];
            let mut add_row = |entries: &[(usize, f64)], rhs: f64| {
                for &(i, a) in entries {
                    atb[i] += a * rhs;
                    for &(j, b) in entries {
                        ata[i * m + j] += a * b;
                    }
                }
            };
            for (s, &p) in samples.iter().enumerate() {
                for b in &brackets {
                    let z = code(b, p, c);
                    let wz = weight(z);
                    add_row(&[(z, wz), (n + s, -wz)], wz * b.exposure_s.ln());
                }
            }
            add_row(&[(n / 2, 1.0)], 0.0);
            for z in 1..n - 1 {
                let wz = settings.lambda * (weight(z) + 1.0);
                add_row(&[(z - 1, wz), (z, -2.0 * wz), (z + 1, wz)], 0.0);
            }
            let g = cholesky_solve(&mut ata, &atb, m).unwrap();
            for z in 0..n {
                let (full, reduced) = (g[z], curve.values[c][z].ln());
                assert!(
                    (full - reduced).abs() < 1e-9 * (1.0 + full.abs()),
                    "channel {c} code {z}: full system {full}, reduced {reduced}"
                );
            }
        }
    }

    #[test]
    fn merge_weights_and_exclusions() {
        // linear response; a pixel at 0.5 in exposure 1 and clipped in exposure 4
        let b1 = Bracket {
            image: image(vec![[0.5, 0.99, 0.001]]),
            exposure_s: 1.0,
            gain: 1.0,
        };
        let b2 = Bracket {
            image: image(vec![[1.0, 1.0, 0.004]]),
            exposure_s: 4.0,
            gain: 1.0,
        };
        let out = merge_brackets(
            &[b1, b2],
            &ResponseModel::Linear,
            255.0,
            &Radiometry::default(),
            MergeLimits::default(),
        )
        .unwrap();
        // red: only exposure 1 counts (exposure 4 is clipped)
        assert!((out[0][0] - 0.5).abs() < 1e-6);
        // green: clipped everywhere → the shortest exposure's value, a lower bound
        assert!((out[0][1] - 0.99).abs() < 1e-6);
        // blue: dark everywhere → the longest exposure's value
        assert!((out[0][2] - 0.001).abs() < 1e-6);
    }

    #[test]
    fn bad_brackets_are_errors() {
        let ok = Bracket {
            image: image(vec![[0.5; 3]; 2]),
            exposure_s: 1.0,
            gain: 1.0,
        };
        let m = ResponseModel::Srgb;
        let r = Radiometry::default();
        let l = MergeLimits::default();
        assert_eq!(
            merge_brackets(&[], &m, 255.0, &r, l).unwrap_err(),
            BracketError::Empty
        );
        let small = Bracket {
            image: image(vec![[0.5; 3]]),
            ..ok.clone()
        };
        let e = merge_brackets(&[ok.clone(), small], &m, 255.0, &r, l).unwrap_err();
        assert!(e.to_string().contains("bracket 2 is 1x1"), "{e}");
        let zero = Bracket {
            exposure_s: 0.0,
            ..ok.clone()
        };
        let e = merge_brackets(&[ok.clone(), zero], &m, 255.0, &r, l).unwrap_err();
        assert!(e.to_string().contains("bracket 2: exposure 0"), "{e}");
        let bad_limits = MergeLimits {
            dark: 0.9,
            saturated: 0.1,
        };
        assert!(merge_brackets(std::slice::from_ref(&ok), &m, 255.0, &r, bad_limits).is_err());
        let e = recover_response(std::slice::from_ref(&ok), SolveSettings::default()).unwrap_err();
        assert!(e.to_string().contains("at least 2"), "{e}");
        // Identical exposures cannot determine a curve (one wrote a flat curve).
        let e = recover_response(&[ok.clone(), ok.clone()], SolveSettings::default()).unwrap_err();
        assert!(e.to_string().contains("different exposures"), "{e}");
        let longer = Bracket {
            exposure_s: 4.0,
            ..ok.clone()
        };
        for lambda in [0.0, 2e6, f64::NAN] {
            let settings = SolveSettings {
                lambda,
                ..SolveSettings::default()
            };
            let e = recover_response(&[ok.clone(), longer.clone()], settings).unwrap_err();
            assert!(e.to_string().contains("lambda"), "{lambda}: {e}");
        }
    }

    /// Every λ in the documented range (0, 10⁶] solves at any level count: with the scale
    /// fixed by a row of weight 1, λ = 10⁶ at 256 levels and λ = 10⁵ at 1024 reported a
    /// singular system (the row was lost in rounding beside smoothness rows of λ²·n²).
    #[test]
    fn the_largest_smoothness_weights_still_solve() {
        let brackets = graded_brackets((64, 48), &[0.05, 0.2, 0.8, 3.2]);
        for (levels, lambda) in [(16, 1e6), (256, 1e5), (256, MAX_LAMBDA), (1024, 1e5)] {
            let settings = SolveSettings {
                levels,
                lambda,
                samples: 300,
            };
            let curve = recover_response(&brackets, settings)
                .unwrap_or_else(|e| panic!("{levels} levels, λ = {lambda:e}: {e}"));
            for values in &curve.values {
                assert!((values[levels / 2] - 1.0).abs() < 1e-12, "scale not fixed");
                assert!(values.iter().all(|v| v.is_finite() && *v > 0.0));
                // So smooth a curve is a straight line in log space: increasing, as the data.
                assert!(
                    values[levels - 1] > values[0],
                    "{levels} levels, λ = {lambda:e}"
                );
            }
        }
    }

    /// CRC-32 (PNG's) of `bytes`.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }

    /// A PNG that declares more pixels than are read is refused from its header, before the
    /// image is allocated (an 11000×11000 black PNG of 353 KB took 2.8 GB).
    #[test]
    fn oversized_bracket_images_are_refused_from_the_header() {
        let mut ihdr = b"IHDR".to_vec();
        ihdr.extend_from_slice(&20_000u32.to_be_bytes());
        ihdr.extend_from_slice(&20_000u32.to_be_bytes());
        ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
        let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
        png.extend_from_slice(&13u32.to_be_bytes());
        png.extend_from_slice(&ihdr);
        png.extend_from_slice(&crc32(&ihdr).to_be_bytes());
        for chunk in [&b"IDAT"[..], b"IEND"] {
            png.extend_from_slice(&0u32.to_be_bytes());
            png.extend_from_slice(chunk);
            png.extend_from_slice(&crc32(chunk).to_be_bytes());
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("huge.png");
        std::fs::write(&path, png).unwrap();
        let e = read_bracket_image(&path).unwrap_err().to_string();
        assert!(e.contains("huge.png") && e.contains("too large"), "{e}");
    }
}
