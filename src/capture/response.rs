//! Camera response: normalised code values → linear radiance.
//!
//! A code value v ∈ [0, 1] (from [`super::pixel_format`]) is first mapped to a *relative
//! exposure* X(v) by the response model, then exposure time, gain, white balance and an
//! absolute scale are folded in:
//!
//! L_c = X_c(v_c) · wb_c · scale / (t · gain)
//!
//! with t the exposure time in seconds and gain the linear sensor gain (both from the camera's
//! controls or the config), wb the per-channel white balance and scale the absolute calibration
//! (W/(m²·sr) per unit of X/s; measure it once against a radiometer or a known source).
//!
//! Models ([`ResponseModel`]):
//! - `Linear`: X = v (raw sensor data);
//! - `Srgb`: the IEC 61966-2-1 decoding, X = v/12.92 for v ≤ 0.04045, else ((v + 0.055)/1.055)^2.4;
//! - `Gamma(γ)`: X = v^γ;
//! - `Logarithmic { a, b }`: the logarithmic HDR sensors (HDRC): the code in digital numbers
//!   D = v·code_max relates to radiance as D = a·ln X + b, so X = exp((D − b)/a);
//! - `Curve`: a measured curve (for instance from `envlight calibrate-response`, Debevec &
//!   Malik 1997), tabulated per channel and interpolated linearly in v (clamped at the ends).
//!
//! Curve file format (text): lines starting with `#` and blank lines are ignored; every other
//! line is `code red green blue` with the normalised code in [0, 1] (strictly increasing) and
//! the relative exposure X per channel (finite, ≥ 0). At least two lines.
//!
//! Per frame the model is applied through a [`Linearizer`]: a table of 4096 intervals per
//! channel (with the exposure, white balance and scale already multiplied in) interpolated
//! linearly, so a frame costs one table look-up per sample. The table's interpolation error is
//! below 1e-4 relative for the smooth models (tested against [`ResponseModel::relative_exposure`]).
//! The linear model needs no table: its samples are clamped and multiplied by the channel's
//! factor (vectorised; a raw 1280×960 frame in about a third of the look-ups' time). A frame
//! kept as bytes ([`ByteImage`]: MJPEG, RGB24, BGR24, 8-bit grey) takes one look-up per sample
//! in 256-entry tables made from those look-ups, with the same radiances to the bit.

use super::pixel_format::{self, ByteImage, CodeImage, PixelError, RawFrame, YuvMatrix};
use super::CaptureError;
use std::path::Path;
use std::sync::Arc;

/// A tabulated response curve: relative exposure per channel at increasing normalised codes.
#[derive(Clone, Debug, PartialEq)]
pub struct ResponseCurve {
    /// Normalised code values, strictly increasing, in [0, 1].
    pub codes: Vec<f64>,
    /// Relative exposure X per channel at each code.
    pub values: [Vec<f64>; 3],
}

fn format_err(path: &Path, message: String) -> CaptureError {
    CaptureError::Format {
        path: path.to_path_buf(),
        message,
    }
}

impl ResponseCurve {
    /// Checks the table: ≥ 2 entries, codes strictly increasing in [0, 1], finite values ≥ 0.
    pub fn new(codes: Vec<f64>, values: [Vec<f64>; 3]) -> Result<Self, String> {
        if codes.len() < 2 {
            return Err(format!("needs at least 2 entries, has {}", codes.len()));
        }
        if values.iter().any(|v| v.len() != codes.len()) {
            return Err("every channel needs one value per code".into());
        }
        for (i, w) in codes.windows(2).enumerate() {
            if !(w[1] > w[0] && w[1].is_finite()) {
                return Err(format!(
                    "codes must increase strictly: entry {} ({}) follows {}",
                    i + 2,
                    w[1],
                    w[0]
                ));
            }
        }
        if !(codes[0] >= 0.0 && codes[codes.len() - 1] <= 1.0) {
            return Err(format!(
                "codes must lie in [0, 1], found {} to {}",
                codes[0],
                codes[codes.len() - 1]
            ));
        }
        for (c, v) in values.iter().enumerate() {
            if let Some((i, x)) = v
                .iter()
                .enumerate()
                .find(|(_, x)| !(x.is_finite() && **x >= 0.0))
            {
                return Err(format!(
                    "{} value {x} at entry {} must be finite and ≥ 0",
                    ["red", "green", "blue"][c],
                    i + 1
                ));
            }
        }
        Ok(Self { codes, values })
    }

    /// Parses the text format; `path` is used in error messages (which name the line).
    pub fn parse(text: &str, path: &Path) -> Result<Self, CaptureError> {
        let mut codes = Vec::new();
        let mut values: [Vec<f64>; 3] = Default::default();
        for (n, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let nums: Result<Vec<f64>, _> = line.split_whitespace().map(str::parse).collect();
            match nums {
                Ok(v) if v.len() == 4 => {
                    codes.push(v[0]);
                    for c in 0..3 {
                        values[c].push(v[c + 1]);
                    }
                }
                _ => {
                    return Err(format_err(
                        path,
                        format!(
                            "line {}: expected 4 numbers `code red green blue`, got {line:?}",
                            n + 1
                        ),
                    ))
                }
            }
        }
        Self::new(codes, values).map_err(|m| format_err(path, format!("response curve {m}")))
    }

    /// Reads a curve file: a regular text file of at most [`MAX_CURVE_FILE_BYTES`].
    pub fn read(path: &Path) -> Result<Self, CaptureError> {
        let text =
            crate::read_file::read_regular_text(path, MAX_CURVE_FILE_BYTES, "a response curve")
                .map_err(|source| CaptureError::Io {
                    path: path.to_path_buf(),
                    source,
                })?;
        Self::parse(&text, path)
    }

    /// The text format, with a header comment. Every number is written in the shortest form
    /// that reads back to the same `f64`, so `parse(to_text(c)) == c` for any valid curve
    /// (codes closer than 10⁻⁶ included).
    pub fn to_text(&self, comment: &str) -> String {
        let mut s = String::from("# envlight response curve: code red green blue\n");
        s.push_str("# code = normalised code value in [0, 1]; columns = relative exposure X\n");
        for line in comment.lines() {
            s.push_str(&format!("# {line}\n"));
        }
        for (i, code) in self.codes.iter().enumerate() {
            s.push_str(&format!(
                "{code} {:e} {:e} {:e}\n",
                self.values[0][i], self.values[1][i], self.values[2][i]
            ));
        }
        s
    }

    /// Writes the text format.
    pub fn write(&self, path: &Path, comment: &str) -> Result<(), CaptureError> {
        std::fs::write(path, self.to_text(comment)).map_err(|source| CaptureError::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    /// X of `channel` at normalised code `v`, linear interpolation, clamped at the ends.
    pub fn eval(&self, channel: usize, v: f64) -> f64 {
        let (codes, vals) = (&self.codes, &self.values[channel.min(2)]);
        let n = codes.len().min(vals.len());
        if n == 0 {
            return 0.0;
        }
        if v.is_nan() || v <= codes[0] {
            return vals[0];
        }
        if v >= codes[n - 1] {
            return vals[n - 1];
        }
        let i = codes.partition_point(|&c| c <= v).clamp(1, n - 1);
        let t = (v - codes[i - 1]) / (codes[i] - codes[i - 1]);
        vals[i - 1] + t * (vals[i] - vals[i - 1])
    }
}

/// SMPTE ST 2084's EOTF: the luminance of PQ code `v` (in [0, 1]) as a fraction of
/// 10,000 cd/m².
pub fn pq_luminance(v: f64) -> f64 {
    const M1: f64 = 2610.0 / 16384.0;
    const M2: f64 = 2523.0 / 4096.0 * 128.0;
    const C1: f64 = 3424.0 / 4096.0;
    const C2: f64 = 2413.0 / 4096.0 * 32.0;
    const C3: f64 = 2392.0 / 4096.0 * 32.0;
    let p = v.clamp(0.0, 1.0).powf(1.0 / M2);
    ((p - C1).max(0.0) / (C2 - C3 * p)).powf(1.0 / M1)
}

/// ITU-R BT.2100's HLG inverse OETF: the scene light (in [0, 1]) of HLG code `v` (in [0, 1]).
pub fn hlg_scene_light(v: f64) -> f64 {
    const A: f64 = 0.178_832_77;
    const B: f64 = 1.0 - 4.0 * A;
    // c = 0.5 − a·ln(4a), as BT.2100 gives it to 8 digits.
    const C: f64 = 0.559_910_73;
    let v = v.clamp(0.0, 1.0);
    if v <= 0.5 {
        v * v / 3.0
    } else {
        (((v - C) / A).exp() + B) / 12.0
    }
}

/// How code values relate to light.
#[derive(Clone, Debug, PartialEq)]
pub enum ResponseModel {
    Linear,
    Srgb,
    Gamma(f64),
    /// SMPTE ST 2084's perceptual quantiser (HDR10 video; ITU-R BT.2100 PQ): X is the display
    /// luminance the code stands for, as a fraction of 10,000 cd/m² (X = 0.01 is 100 cd/m²).
    Pq,
    /// ITU-R BT.2100 hybrid log-gamma (ARIB STD-B67; HDR broadcast video): X is the scene
    /// light, in [0, 1], of the inverse OETF (no display OOTF: the camera's scene is wanted).
    Hlg,
    /// HDRC logarithmic sensor: digital number D = a·ln X + b.
    Logarithmic {
        a: f64,
        b: f64,
    },
    Curve(Arc<ResponseCurve>),
}

impl ResponseModel {
    /// Relative exposure X of `channel` at normalised code `v`; `code_max` converts v to digital
    /// numbers for the logarithmic model.
    pub fn relative_exposure(&self, channel: usize, v: f64, code_max: f64) -> f64 {
        match self {
            ResponseModel::Linear => v,
            ResponseModel::Srgb => {
                if v <= 0.04045 {
                    v / 12.92
                } else {
                    ((v + 0.055) / 1.055).powf(2.4)
                }
            }
            ResponseModel::Gamma(g) => v.max(0.0).powf(*g),
            ResponseModel::Pq => pq_luminance(v),
            ResponseModel::Hlg => hlg_scene_light(v),
            ResponseModel::Logarithmic { a, b } => ((v * code_max - b) / a).exp(),
            ResponseModel::Curve(c) => c.eval(channel, v),
        }
    }

    /// Checks the parameters; the message names the parameter.
    pub fn check(&self) -> Result<(), String> {
        match self {
            ResponseModel::Gamma(g) if !(g.is_finite() && *g > 0.0) => {
                Err(format!("gamma = {g} must be a positive number"))
            }
            ResponseModel::Logarithmic { a, .. } if !(a.is_finite() && *a != 0.0) => {
                Err(format!("log_a = {a} must be a finite non-zero number"))
            }
            ResponseModel::Logarithmic { b, .. } if !b.is_finite() => {
                Err(format!("log_b = {b} must be finite"))
            }
            _ => Ok(()),
        }
    }

    /// Short name for logs.
    pub fn name(&self) -> &'static str {
        match self {
            ResponseModel::Linear => "linear",
            ResponseModel::Srgb => "srgb",
            ResponseModel::Gamma(_) => "gamma",
            ResponseModel::Pq => "pq",
            ResponseModel::Hlg => "hlg",
            ResponseModel::Logarithmic { .. } => "logarithmic",
            ResponseModel::Curve(_) => "curve",
        }
    }
}

/// Radiometric calibration applied after the response: L = X · wb · scale / (t · gain).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Radiometry {
    /// Exposure time in seconds.
    pub exposure_s: f64,
    /// Linear sensor gain (1 = unity).
    pub gain: f64,
    pub white_balance: [f64; 3],
    pub scale: f64,
}

impl Default for Radiometry {
    fn default() -> Self {
        Self {
            exposure_s: 1.0,
            gain: 1.0,
            white_balance: [1.0; 3],
            scale: 1.0,
        }
    }
}

impl Radiometry {
    /// Per-channel factor wb · scale / (t · gain).
    pub fn factors(&self) -> [f64; 3] {
        let k = self.scale / (self.exposure_s * self.gain);
        self.white_balance.map(|w| w * k)
    }
}

/// The largest response-curve file that is read (one written by `calibrate-response` is about
/// 20 kB).
pub const MAX_CURVE_FILE_BYTES: u64 = 16 << 20;

/// Intervals of the per-channel look-up table.
pub const LUT_INTERVALS: usize = 4096;

/// A channel's look-up table: per interval, (value at the interval's start, slope over the
/// interval). A fixed size, so that a look-up needs no bounds check.
type Lut = [[f32; 2]; LUT_INTERVALS];

/// Piecewise-linear table look-up of a normalised code (clamped to [0, 1]).
#[inline(always)]
fn lookup(lut: &Lut, v: f32) -> f32 {
    const N: f32 = LUT_INTERVALS as f32;
    let p = (v * N).clamp(0.0, N);
    // The interval: p is in [0, N] (a NaN code takes interval 0 and stays NaN below), so a
    // conversion to i32 is exact; it compiles to far fewer instructions than the saturating
    // conversion to a 64-bit unsigned integer of `as usize`. p = N lands at the end of the
    // last interval.
    let i = if p >= 0.0 { p as i32 } else { 0 }.min(LUT_INTERVALS as i32 - 1) as usize;
    let [a, slope] = lut[i];
    a + (p - i as f32) * slope
}

/// The three look-ups of a colour pixel, `[lookup(r, p[0]), lookup(g, p[1]), lookup(b, p[2])]`
/// bit for bit, with the position, clamping, interval and interpolation of the three channels
/// done in one 4-lane vector (x86-64, whose SSE2 every such CPU has); elsewhere the scalar ones.
#[inline(always)]
fn lookup_rgb(luts: [&Lut; 3], p: [f32; 3]) -> [f32; 3] {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: SSE2 is part of the x86-64 baseline, so the function's target feature is
        // always present.
        unsafe { lookup_rgb_sse2(luts, p) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        [
            lookup(luts[0], p[0]),
            lookup(luts[1], p[1]),
            lookup(luts[2], p[2]),
        ]
    }
}

/// [`lookup_rgb`] on SSE2. The clamp keeps a NaN (`max`/`min` return their second operand when
/// one is NaN) as [`lookup`]'s does, while the interval's position sends it to 0; the
/// interval is the truncation of the position clamped to the last interval's start, which
/// equals [`lookup`]'s for every position in [0, N].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse2")]
#[inline]
fn lookup_rgb_sse2(luts: [&Lut; 3], p: [f32; 3]) -> [f32; 3] {
    use std::arch::x86_64::*;
    const N: f32 = LUT_INTERVALS as f32;
    const LAST: f32 = (LUT_INTERVALS - 1) as f32;
    let x = _mm_mul_ps(_mm_setr_ps(p[0], p[1], p[2], 0.0), _mm_set1_ps(N));
    let zero = _mm_setzero_ps();
    // (v · N).clamp(0, N), NaN kept.
    let clamped = _mm_min_ps(_mm_set1_ps(N), _mm_max_ps(zero, x));
    // The interval, NaN → 0.
    let interval = _mm_cvttps_epi32(_mm_min_ps(_mm_max_ps(x, zero), _mm_set1_ps(LAST)));
    let frac = _mm_sub_ps(clamped, _mm_cvtepi32_ps(interval));
    // In 0..LUT_INTERVALS by the clamp; the mask (LUT_INTERVALS is a power of two) only
    // spares the bounds checks.
    const _: () = assert!(LUT_INTERVALS.is_power_of_two());
    let at = |lane: i32| (lane as usize) & (LUT_INTERVALS - 1);
    let i0 = at(_mm_cvtsi128_si32(interval));
    let i1 = at(_mm_cvtsi128_si32(_mm_srli_si128::<4>(interval)));
    let i2 = at(_mm_cvtsi128_si32(_mm_srli_si128::<8>(interval)));
    let ([a0, s0], [a1, s1], [a2, s2]) = (luts[0][i0], luts[1][i1], luts[2][i2]);
    let value = _mm_add_ps(
        _mm_setr_ps(a0, a1, a2, 0.0),
        _mm_mul_ps(frac, _mm_setr_ps(s0, s1, s2, 0.0)),
    );
    let mut out = [0.0f32; 4];
    // SAFETY: `out` holds four f32, the store's size; unaligned stores are allowed.
    unsafe { _mm_storeu_ps(out.as_mut_ptr(), value) };
    [out[0], out[1], out[2]]
}

/// The linear model's radiance of code `v` with the channel's factor: v clamped to [0, 1] (a
/// NaN stays NaN, as through a table; adding 0 turns −0 into +0, as the table gives) times
/// the factor.
#[inline(always)]
fn linear_radiance(v: f32, factor: f32) -> f32 {
    (v.clamp(0.0, 1.0) + 0.0) * factor
}

/// Code values → radiance through per-channel tables (response × radiometry folded in).
#[derive(Clone, Debug)]
pub struct Linearizer {
    /// Per channel and interval: (value at the interval's start, slope over the interval).
    luts: [Box<Lut>; 3],
    /// For models that treat every channel alike (all but `Curve`): the table of X alone and
    /// the per-channel factors, so a grey pixel (R = G = B codes, as from GREY/Y10/Y12/Y16)
    /// costs one look-up.
    shared: Option<(Box<Lut>, [f32; 3])>,
    /// For the linear model (raw sensor data), the per-channel factors: X = v needs no table,
    /// a frame is converted with one clamp and one multiplication per sample (vectorised).
    /// `None` if a factor is not a finite f32 (the tables saturate at f32::MAX instead).
    linear: Option<[f32; 3]>,
}

impl Linearizer {
    /// Tables for `model` on a format whose largest code is `code_max`.
    pub fn new(model: &ResponseModel, code_max: f32, radiometry: &Radiometry) -> Self {
        let factors = radiometry.factors();
        let table = |c: usize, factor: f64| -> Box<Lut> {
            let knots: Vec<f32> = (0..=LUT_INTERVALS)
                .map(|i| {
                    let v = i as f64 / LUT_INTERVALS as f64;
                    let x = model.relative_exposure(c, v, f64::from(code_max)) * factor;
                    // Clamped before the conversion: an f64 past f32's range would become ∞,
                    // and the slopes beside it ∞ − ∞ = NaN.
                    if x.is_finite() {
                        x.clamp(0.0, f64::from(f32::MAX)) as f32
                    } else {
                        f32::MAX
                    }
                })
                .collect();
            let mut lut = Box::new([[0.0f32; 2]; LUT_INTERVALS]);
            for (entry, k) in lut.iter_mut().zip(knots.windows(2)) {
                *entry = [k[0], k[1] - k[0]];
            }
            lut
        };
        let luts = std::array::from_fn(|c| table(c, factors[c]));
        let shared = match model {
            ResponseModel::Curve(_) => None,
            _ => Some((table(0, 1.0), factors.map(|f| f as f32))),
        };
        let linear = match model {
            ResponseModel::Linear => {
                let f = factors.map(|f| f as f32);
                f.iter().all(|f| f.is_finite() && *f >= 0.0).then_some(f)
            }
            _ => None,
        };
        Self {
            luts,
            shared,
            linear,
        }
    }

    /// Radiance of one code value in `channel` (v clamped to [0, 1]).
    #[inline]
    pub fn apply(&self, channel: usize, v: f32) -> f32 {
        match self.linear {
            Some(f) => linear_radiance(v, f[channel]),
            None => lookup(&self.luts[channel], v),
        }
    }

    /// Radiance of every pixel of a code image.
    pub fn linearize(&self, image: &CodeImage) -> Vec<[f32; 3]> {
        let mut out = Vec::new();
        self.linearize_into(image, &mut out);
        out
    }

    /// [`Self::linearize`] into an existing buffer.
    pub fn linearize_into(&self, image: &CodeImage, out: &mut Vec<[f32; 3]>) {
        self.linearize_into_on(image, out, None);
    }

    /// [`Self::linearize`] with blocks of pixels on the calling thread and `pool`'s helper
    /// threads together (`None`: the calling thread alone; src/parallel.rs); each pixel by
    /// itself, so the result is the same to the bit either way.
    pub fn linearize_on(
        &self,
        image: &CodeImage,
        pool: Option<&rayon::ThreadPool>,
    ) -> Vec<[f32; 3]> {
        let mut out = Vec::new();
        self.linearize_into_on(image, &mut out, pool);
        out
    }

    /// [`Self::linearize_into`] with blocks of pixels in parallel on `pool` (`None`: the
    /// calling thread).
    ///
    /// The closures hold the tables as plain references to fixed-size arrays, so the look-ups
    /// need no bounds checks.
    pub fn linearize_into_on(
        &self,
        image: &CodeImage,
        out: &mut Vec<[f32; 3]>,
        pool: Option<&rayon::ThreadPool>,
    ) {
        /// Pixels per parallel task (32 rows of a 1280-wide frame).
        const PIXELS_PER_TASK: usize = 32 * 1280;
        let n = image.pixels.len();
        if out.len() != n {
            // Every element is written below; a new buffer comes zeroed from the allocator
            // (fresh pages), a reused one of the right size is not cleared at all.
            if out.capacity() >= n {
                out.resize(n, [0.0; 3]);
            } else {
                *out = vec![[0.0; 3]; n];
            }
        }
        // The calling thread alone, or with the pool's helpers taking chunks in turn
        // (src/parallel.rs).
        crate::parallel::for_each_chunk_mut(pool, out, PIXELS_PER_TASK, |i, out| {
            let codes = image.pixels.get(i * PIXELS_PER_TASK..).unwrap_or(&[]);
            self.linearize_slice(codes, out)
        });
    }

    /// Decodes a raw camera buffer and linearises it in one pass over bands of rows
    /// ([`pixel_format::decode_each_band_on`]): each band's codes are linearised while they are
    /// in the cache, so no whole-frame code image is written and read again (15 MB each way
    /// for 1280×960). The radiances are [`pixel_format::decode_into_on`] then
    /// [`Self::linearize_into_on`], to the bit; `out`'s allocation is reused and every
    /// element written.
    pub fn decode_linearize_into_on(
        &self,
        raw: &RawFrame<'_>,
        matrix: YuvMatrix,
        out: &mut Vec<[f32; 3]>,
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), PixelError> {
        pixel_format::decode_each_band_on(raw, matrix, out, pool, |codes, out| {
            self.linearize_slice(codes, out)
        })
    }

    /// The radiance of each code pixel of `codes` into the same element of `out` (as many as
    /// the shorter has). The tables are taken as plain references to fixed-size arrays, so the
    /// look-ups need no bounds checks.
    fn linearize_slice(&self, codes: &[[f32; 3]], out: &mut [[f32; 3]]) {
        let [r, g, b] = &self.luts;
        let (r, g, b): (&Lut, &Lut, &Lut) = (r, g, b);
        match (&self.linear, &self.shared) {
            (Some([fr, fg, fb]), _) => {
                let (fr, fg, fb) = (*fr, *fg, *fb);
                for (o, p) in out.iter_mut().zip(codes) {
                    *o = [
                        linear_radiance(p[0], fr),
                        linear_radiance(p[1], fg),
                        linear_radiance(p[2], fb),
                    ];
                }
            }
            (None, Some((x, [fr, fg, fb]))) => {
                let (x, fr, fg, fb): (&Lut, f32, f32, f32) = (x, *fr, *fg, *fb);
                for (o, p) in out.iter_mut().zip(codes) {
                    *o = if p[0] == p[1] && p[1] == p[2] {
                        let v = lookup(x, p[0]);
                        [v * fr, v * fg, v * fb]
                    } else {
                        lookup_rgb([r, g, b], *p)
                    };
                }
            }
            (None, None) => {
                for (o, p) in out.iter_mut().zip(codes) {
                    *o = lookup_rgb([r, g, b], *p);
                }
            }
        }
    }

    /// What [`Self::linearize_into_on`] gives a grey pixel (R = G = B = `v`): the shared table
    /// or the linear factors where the model has them, else the three channels' tables.
    fn grey_radiance(&self, v: f32) -> [f32; 3] {
        match (&self.linear, &self.shared) {
            (Some(f), _) => f.map(|f| linear_radiance(v, f)),
            (None, Some((x, f))) => {
                let v = lookup(x, v);
                f.map(|f| v * f)
            }
            (None, None) => std::array::from_fn(|c| lookup(&self.luts[c], v)),
        }
    }

    /// [`Self::linearize_into_on`] of `image`'s codes ([`ByteImage::to_codes_into_on`]), to
    /// the bit, straight from its bytes: the radiance of each of the 256 codes is computed once
    /// per call, in each channel for colour pixels and for grey ones (R = G = B, which take the
    /// shared table as above), and every sample is one look-up in those tables. No code
    /// image is written or read: for a decoded MJPEG frame this saves more than half of the
    /// conversion after the decoding (docs/performance.md, "Camera conversions").
    pub fn linearize_bytes_into_on(
        &self,
        image: &ByteImage,
        out: &mut Vec<[f32; 3]>,
        pool: Option<&rayon::ThreadPool>,
    ) {
        /// Pixels per parallel task (32 rows of a 1280-wide frame).
        const PIXELS_PER_TASK: usize = 32 * 1280;
        let code = image.code_of_byte();
        let colour: [[f32; 256]; 3] =
            std::array::from_fn(|c| std::array::from_fn(|b| self.apply(c, code[b])));
        let grey: [[f32; 3]; 256] = std::array::from_fn(|b| self.grey_radiance(code[b]));
        let n = image.width as usize * image.height as usize;
        if out.len() != n {
            // Every element is written below (as in linearize_into_on).
            if out.capacity() >= n {
                out.resize(n, [0.0; 3]);
            } else {
                *out = vec![[0.0; 3]; n];
            }
        }
        let channels = image.channels.max(1);
        let [r, g, b] = &colour;
        crate::parallel::for_each_chunk_mut(pool, out, PIXELS_PER_TASK, |i, out| {
            let start = i * PIXELS_PER_TASK * channels;
            let bytes = image.bytes.get(start..).unwrap_or(&[]);
            let written = if channels == 1 {
                for (o, &v) in out.iter_mut().zip(bytes) {
                    *o = grey[usize::from(v)];
                }
                bytes.len()
            } else {
                for (o, p) in out.iter_mut().zip(bytes.chunks_exact(3)) {
                    let (pr, pg, pb) = (usize::from(p[0]), usize::from(p[1]), usize::from(p[2]));
                    // Both looked up and one kept, without a branch: grey pixels come in runs
                    // (clipped highlights) or scattered (noise), which a branch mispredicts.
                    let is_grey = pr == pg && pg == pb;
                    let (c, gr) = ([r[pr], g[pg], b[pb]], grey[pr]);
                    *o = std::array::from_fn(|k| if is_grey { gr[k] } else { c[k] });
                }
                bytes.len() / 3
            };
            // Pixels the image has no bytes for (it is shorter than its size says) are 0.
            if let Some(missing) = out.get_mut(written..) {
                missing.fill([0.0; 3]);
            }
        });
    }
}

/// Reads a curve file for a `ResponseModel::Curve` (convenience for config and CLI).
pub fn load_curve(path: &Path) -> Result<ResponseModel, CaptureError> {
    Ok(ResponseModel::Curve(Arc::new(ResponseCurve::read(path)?)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::pixel_format::byte_stream;

    /// The look-up as first written (a saturating `as usize`): [`lookup`] must give the same
    /// bits for every code, out-of-range and non-finite ones included.
    fn lookup_reference(lut: &Lut, v: f32) -> f32 {
        const N: f32 = LUT_INTERVALS as f32;
        let p = (v * N).clamp(0.0, N);
        let i = (p as usize).min(LUT_INTERVALS - 1);
        let [a, slope] = lut[i];
        a + (p - i as f32) * slope
    }

    #[test]
    fn lookup_equals_the_saturating_reference_bit_for_bit() {
        let lin = Linearizer::new(&ResponseModel::Srgb, 255.0, &Radiometry::default());
        let lut = &lin.luts[1];
        let mut codes = vec![
            0.0,
            -0.0,
            1.0,
            1.0 - f32::EPSILON,
            1.0 + f32::EPSILON,
            -1.0,
            2.0,
            1e30,
            -1e30,
            f32::MIN_POSITIVE,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            f32::MAX,
        ];
        // Every interval's start and middle, and a sweep of bit patterns.
        codes.extend((0..=LUT_INTERVALS).map(|i| i as f32 / LUT_INTERVALS as f32));
        codes.extend((0..LUT_INTERVALS).map(|i| (i as f32 + 0.5) / LUT_INTERVALS as f32));
        codes.extend((0..200_000u32).map(|k| f32::from_bits(k.wrapping_mul(2_654_435_761))));
        for v in codes {
            let (got, want) = (lookup(lut, v), lookup_reference(lut, v));
            assert!(
                got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                "code {v:e}: {got:e} against {want:e}"
            );
        }
    }

    /// The vector look-up of a colour pixel equals the three scalar ones bit for bit, with
    /// distinct tables per channel (a white balance) and codes as in the test above.
    #[test]
    fn colour_lookup_equals_three_scalar_lookups_bit_for_bit() {
        let radiometry = Radiometry {
            white_balance: [1.9, 1.0, 1.4],
            ..Radiometry::default()
        };
        let lin = Linearizer::new(&ResponseModel::Gamma(2.2), 1023.0, &radiometry);
        let [r, g, b] = &lin.luts;
        let luts: [&Lut; 3] = [r, g, b];
        let specials = [
            0.0,
            -0.0,
            1.0,
            2.0,
            -1.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        let mut state = 0x9e37_79b9u32;
        let mut next = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            match state % 4 {
                0 => specials[(state >> 8) as usize % specials.len()],
                1 => f32::from_bits(state.rotate_left(7)),
                _ => (state >> 8) as f32 / (1u32 << 24) as f32,
            }
        };
        for _ in 0..100_000 {
            let p = [next(), next(), next()];
            let got = lookup_rgb(luts, p);
            for c in 0..3 {
                let want = lookup(luts[c], p[c]);
                assert!(
                    got[c].to_bits() == want.to_bits() || (got[c].is_nan() && want.is_nan()),
                    "codes {p:?}, channel {c}: {} against {want}",
                    got[c]
                );
            }
        }
    }

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs().max(1e-300)
    }

    #[test]
    fn srgb_known_values() {
        let m = ResponseModel::Srgb;
        // IEC 61966-2-1: code 0.5 → 0.214041, 0.04045 → 0.0031308 (the break point), 1 → 1
        assert!(rel(m.relative_exposure(0, 0.5, 255.0), 0.214_041_14) < 1e-6);
        assert!(rel(m.relative_exposure(0, 0.04045, 255.0), 0.003_130_8) < 1e-4);
        assert!(rel(m.relative_exposure(1, 1.0, 255.0), 1.0) < 1e-12);
        assert_eq!(m.relative_exposure(2, 0.0, 255.0), 0.0);
        // continuous at the break point
        let below = m.relative_exposure(0, 0.04045 - 1e-9, 255.0);
        let above = m.relative_exposure(0, 0.04045 + 1e-9, 255.0);
        assert!((below - above).abs() < 1e-8);
    }

    #[test]
    fn gamma_and_linear_known_values() {
        let g = ResponseModel::Gamma(2.2);
        assert!(rel(g.relative_exposure(0, 0.5, 255.0), 0.217_637_64) < 1e-6);
        assert_eq!(ResponseModel::Linear.relative_exposure(1, 0.3, 255.0), 0.3);
        assert!(ResponseModel::Gamma(-1.0)
            .check()
            .unwrap_err()
            .contains("gamma"));
    }

    /// PQ against its inverse (ST 2084's OETF⁻¹ written out here) and the codes of 100,
    /// 1,000 and 10,000 cd/m²; HLG at its knee (1/12 at code 1/2, where both pieces meet), its
    /// top (1) and below the knee (E'²/3); codes outside [0, 1] clamped.
    #[test]
    fn pq_and_hlg_known_values() {
        let pq_code = |l: f64| {
            let (m1, m2) = (2610.0 / 16384.0, 2523.0 / 4096.0 * 128.0);
            let (c1, c2, c3) = (
                3424.0 / 4096.0,
                2413.0 / 4096.0 * 32.0,
                2392.0 / 4096.0 * 32.0,
            );
            let lm: f64 = f64::powf(l, m1);
            ((c1 + c2 * lm) / (1.0 + c3 * lm)).powf(m2)
        };
        for l in [1e-6, 1e-4, 0.003, 0.01, 0.1, 0.5, 1.0] {
            let x = ResponseModel::Pq.relative_exposure(0, pq_code(l), 1023.0);
            assert!(rel(x, l) < 1e-9, "PQ {l}: {x}");
        }
        // Published codes (to 4 digits): 100 cd/m² 0.5081, 1,000 cd/m² 0.7518.
        for (code, nits) in [(0.5081, 100.0), (0.7518, 1000.0), (1.0, 10_000.0)] {
            let l = pq_luminance(code) * 1e4;
            assert!(rel(l, nits) < 2e-3, "PQ {code}: {l} cd/m²");
        }
        assert_eq!(pq_luminance(0.0), 0.0);
        assert_eq!(pq_luminance(-0.5), 0.0);
        assert_eq!(pq_luminance(1.5), pq_luminance(1.0));
        let hlg = |v| ResponseModel::Hlg.relative_exposure(2, v, 1023.0);
        assert!(rel(hlg(0.5), 1.0 / 12.0) < 1e-8);
        assert!(
            rel(hlg(0.5 + 1e-12), 1.0 / 12.0) < 1e-8,
            "continuous at the knee"
        );
        assert!(rel(hlg(1.0), 1.0) < 1e-7);
        assert!(rel(hlg(0.3), 0.03) < 1e-12);
        assert_eq!(hlg(-1.0), 0.0);
        assert_eq!(hlg(2.0), hlg(1.0));
        // Monotonic: more code, more light.
        let codes: Vec<f64> = (0..=1000).map(|i| f64::from(i) / 1000.0).collect();
        for w in codes.windows(2) {
            assert!(pq_luminance(w[1]) >= pq_luminance(w[0]));
            assert!(hlg_scene_light(w[1]) > hlg_scene_light(w[0]));
        }
    }

    #[test]
    fn logarithmic_sensor_known_values() {
        // D = a ln X + b with a = 60 DN per neper and b = 300 DN, 10-bit codes
        let m = ResponseModel::Logarithmic { a: 60.0, b: 300.0 };
        let at = |dn: f64| m.relative_exposure(0, dn / 1023.0, 1023.0);
        assert!(rel(at(300.0), 1.0) < 1e-12);
        assert!(rel(at(360.0), std::f64::consts::E) < 1e-12);
        assert!(rel(at(300.0 + 60.0 * 10f64.ln()), 10.0) < 1e-12);
        // 6 decades over 829 DN: the dynamic range an HDRC sensor is bought for
        assert!(rel(at(1023.0) / at(194.0), (829.0f64 / 60.0).exp()) < 1e-9);
        assert!(ResponseModel::Logarithmic { a: 0.0, b: 1.0 }
            .check()
            .unwrap_err()
            .contains("log_a"));
    }

    #[test]
    fn curve_file_round_trip_and_interpolation() {
        let curve = ResponseCurve::new(
            vec![0.0, 0.5, 1.0],
            [
                vec![0.0, 1.0, 4.0],
                vec![0.0, 2.0, 4.0],
                vec![1.0, 1.0, 1.0],
            ],
        )
        .unwrap();
        let text = curve.to_text("test");
        let back = ResponseCurve::parse(&text, Path::new("c.txt")).unwrap();
        assert_eq!(back, curve);
        let m = ResponseModel::Curve(Arc::new(back));
        assert_eq!(m.relative_exposure(0, 0.25, 255.0), 0.5);
        assert_eq!(m.relative_exposure(0, 0.75, 255.0), 2.5);
        assert_eq!(m.relative_exposure(1, 0.75, 255.0), 3.0);
        assert_eq!(m.relative_exposure(0, -1.0, 255.0), 0.0);
        assert_eq!(m.relative_exposure(0, 2.0, 255.0), 4.0);
    }

    /// Codes 10⁻⁷ apart and values with 17 significant digits: the six decimals the text
    /// format used to write merged such codes into a file that could not be read back.
    #[test]
    fn curve_text_reads_back_exactly() {
        let codes = vec![0.0, 1e-7, 2e-7, 0.333_333_333_333_333_3, 1.0];
        let values = [
            vec![0.0, 1e-300, 0.1 + 0.2, 1.234_567_890_123_456_7, f64::MAX],
            vec![0.0; 5],
            vec![5e-324, 1.0, 2.0, 3.0, 4.0],
        ];
        let curve = ResponseCurve::new(codes, values).unwrap();
        let back = ResponseCurve::parse(&curve.to_text("a\nb"), Path::new("c.txt")).unwrap();
        assert_eq!(back, curve);
    }

    #[test]
    fn bad_curve_files_name_the_line() {
        let p = Path::new("curve.txt");
        let e = ResponseCurve::parse("# c\n0 1 1 1\n0.5 1 x 1\n", p).unwrap_err();
        assert!(e.to_string().contains("line 3") && e.to_string().contains("curve.txt"));
        let e = ResponseCurve::parse("0 1 1 1\n", p).unwrap_err();
        assert!(e.to_string().contains("at least 2"), "{e}");
        let e = ResponseCurve::parse("0.5 1 1 1\n0.2 1 1 1\n", p).unwrap_err();
        assert!(e.to_string().contains("increase"), "{e}");
        let e = ResponseCurve::parse("0 1 1 1\n1 1 -1 1\n", p).unwrap_err();
        assert!(e.to_string().contains("green value -1"), "{e}");
        let e = ResponseCurve::parse("0 1 1 1\n1.5 1 1 1\n", p).unwrap_err();
        assert!(e.to_string().contains("[0, 1]"), "{e}");
        let e = ResponseCurve::read(Path::new("/nonexistent/curve.txt")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/curve.txt"), "{e}");
        // A device (read whole, /dev/zero ran out of memory, even in check-config).
        let e = ResponseCurve::read(Path::new("/dev/zero")).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
    }

    /// Blocks of pixels can be linearised in parallel: the radiances must be the same to the bit
    /// on the calling thread and on a pool, grey and colour pixels, with and without the shared
    /// table.
    #[test]
    fn linearizing_does_not_depend_on_the_number_of_threads() {
        let radiometry = Radiometry {
            exposure_s: 0.01,
            gain: 1.0,
            white_balance: [1.1, 1.0, 0.9],
            scale: 2.0,
        };
        let mut state = 7u64;
        let mut code = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        // 300 × 400 pixels: several blocks of the parallel split; every fifth pixel grey.
        let pixels: Vec<[f32; 3]> = (0..300 * 400)
            .map(|i| {
                let v = code();
                if i % 5 == 0 {
                    [v; 3]
                } else {
                    [v, code(), code()]
                }
            })
            .collect();
        let img = CodeImage {
            width: 300,
            height: 400,
            pixels,
        };
        for model in [ResponseModel::Srgb, ResponseModel::Linear] {
            let lin = Linearizer::new(&model, 4095.0, &radiometry);
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(3)
                .build()
                .expect("a thread pool");
            let (one, three) = (lin.linearize(&img), lin.linearize_on(&img, Some(&pool)));
            // A buffer handed back by the pipeline (FrameSource::recycle) holds an old frame:
            // every pixel is written over.
            let mut reused = vec![[f32::NAN; 3]; img.pixels.len()];
            lin.linearize_into_on(&img, &mut reused, Some(&pool));
            assert_eq!(one.len(), img.pixels.len());
            for other in [&three, &reused] {
                assert!(
                    one.iter()
                        .flatten()
                        .zip(other.iter().flatten())
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "{model:?}"
                );
            }
            for (p, o) in img.pixels.iter().zip(&one).step_by(997) {
                for c in 0..3 {
                    let want = lin.apply(c, p[c]);
                    assert!(
                        (o[c] - want).abs() <= 1e-6 * want.abs().max(1e-6),
                        "{p:?} {o:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn grey_pixels_take_the_shared_table_with_the_same_result() {
        let radiometry = Radiometry {
            exposure_s: 0.02,
            gain: 1.5,
            white_balance: [1.2, 1.0, 0.7],
            scale: 4.0,
        };
        let lin = Linearizer::new(&ResponseModel::Gamma(2.2), 4095.0, &radiometry);
        let pixels: Vec<[f32; 3]> = (0..=100).map(|i| [i as f32 / 100.0; 3]).collect();
        let img = CodeImage {
            width: 101,
            height: 1,
            pixels: pixels.clone(),
        };
        let out = lin.linearize(&img);
        for (p, o) in pixels.iter().zip(&out) {
            for c in 0..3 {
                let want = lin.apply(c, p[c]);
                assert!(
                    (o[c] - want).abs() <= 1e-6 * want.abs().max(1e-6),
                    "{p:?} {o:?}"
                );
            }
        }
    }

    #[test]
    fn linearizer_folds_exposure_gain_white_balance_and_scale() {
        let radiometry = Radiometry {
            exposure_s: 0.01,
            gain: 2.0,
            white_balance: [2.0, 1.0, 0.5],
            scale: 3.0,
        };
        let models = [
            ResponseModel::Srgb,
            ResponseModel::Gamma(2.2),
            ResponseModel::Linear,
            ResponseModel::Pq,
            ResponseModel::Hlg,
            ResponseModel::Logarithmic { a: 60.0, b: 700.0 },
        ];
        for m in models {
            let lin = Linearizer::new(&m, 1023.0, &radiometry);
            let f = radiometry.factors();
            assert!(rel(f[0], 2.0 * 3.0 / 0.02) < 1e-12);
            for i in 0..=200 {
                let v = i as f64 / 200.0 * 0.999 + 0.0005;
                for c in 0..3 {
                    let want = m.relative_exposure(c, v, 1023.0) * f[c];
                    let got = f64::from(lin.apply(c, v as f32));
                    assert!(
                        rel(got, want) < 1e-4 || (got - want).abs() < 1e-7 * f[c],
                        "{m:?} v={v} c={c}: {got} vs {want}"
                    );
                }
            }
        }
    }

    /// The linear model multiplies instead of looking up: every sample is its clamped code
    /// times the channel's factor, rounded once (the table's interpolation is off by an ulp for
    /// some codes, so this fails if the tables are used); a NaN code stays NaN, −0 and negative
    /// codes give +0, codes past 1 (and +∞) the factor. A factor too large for f32 falls back
    /// to the tables, which saturate at f32::MAX.
    #[test]
    fn linear_response_is_one_multiplication_per_sample() {
        let radiometry = Radiometry {
            exposure_s: 0.004,
            gain: 1.5,
            white_balance: [1.9, 1.0, 1.3],
            scale: 7.0,
        };
        let lin = Linearizer::new(&ResponseModel::Linear, 4095.0, &radiometry);
        let f = radiometry.factors().map(|f| f as f32);
        let mut pixels = vec![
            [f32::NAN, -0.0, 1.5],
            [-3.0, f32::INFINITY, f32::NEG_INFINITY],
            [0.0, 1.0, 0.5],
        ];
        pixels.extend((0..4096).map(|i| {
            let v = i as f32 / 4095.0;
            [v, 1.0 - v, (v * 0.37).fract()]
        }));
        let image = CodeImage {
            width: pixels.len() as u32,
            height: 1,
            pixels,
        };
        let out = lin.linearize(&image);
        for (p, o) in image.pixels.iter().zip(&out) {
            for c in 0..3 {
                let (v, got, one) = (p[c], o[c], lin.apply(c, p[c]));
                if v.is_nan() {
                    assert!(got.is_nan() && one.is_nan(), "NaN code, channel {c}");
                    continue;
                }
                let want = if v > 0.0 { v.min(1.0) * f[c] } else { 0.0 };
                assert_eq!(got.to_bits(), want.to_bits(), "code {v} channel {c}");
                assert_eq!(one.to_bits(), want.to_bits(), "code {v} channel {c}");
            }
        }
        assert_eq!(out[0][1].to_bits(), 0.0f32.to_bits(), "−0 gives +0");
        // A factor past f32's range: the tables, saturated, never ∞ or NaN.
        let huge = Radiometry {
            exposure_s: 1e-300,
            ..radiometry
        };
        let lin = Linearizer::new(&ResponseModel::Linear, 4095.0, &huge);
        let out = lin.linearize(&image);
        assert_eq!(out[2], [0.0, f32::MAX, f32::MAX]);
    }

    /// A measured-style curve that differs per channel (so no shared grey table).
    fn per_channel_curve() -> ResponseModel {
        let curve = ResponseCurve::new(
            vec![0.0, 0.3, 1.0],
            [
                vec![0.0, 0.2, 5.0],
                vec![0.0, 0.5, 4.0],
                vec![0.1, 0.4, 3.0],
            ],
        )
        .unwrap();
        ResponseModel::Curve(Arc::new(curve))
    }

    /// A frame kept as bytes is linearised to the same radiances, to the bit, as its code
    /// image: every response model (the shared grey table, the linear factors, per-channel
    /// curves), every byte value grey and in colour, three- and one-channel images, on one
    /// thread and on a pool, into a used buffer; an image shorter than its size gives 0 for the
    /// pixels it lacks.
    #[test]
    fn byte_frames_linearise_as_their_codes_bit_for_bit() {
        let radiometry = Radiometry {
            exposure_s: 0.004,
            gain: 2.0,
            white_balance: [1.3, 1.0, 0.7],
            scale: 3.0,
        };
        let models = [
            ResponseModel::Srgb,
            ResponseModel::Linear,
            ResponseModel::Gamma(2.2),
            ResponseModel::Logarithmic { a: 20.0, b: 30.0 },
            per_channel_curve(),
        ];
        // every byte value as a grey pixel, then pseudo-random colours, some of them grey
        let (w, h) = (256u32, 200u32);
        let mut byte = byte_stream(11u64);
        let mut colour = Vec::new();
        for i in 0..w * h {
            if i < 256 {
                colour.extend_from_slice(&[i as u8; 3]);
            } else if i % 11 == 0 {
                colour.extend_from_slice(&[byte(); 3]);
            } else {
                colour.extend_from_slice(&[byte(), byte(), byte()]);
            }
        }
        let grey: Vec<u8> = (0..w * h).map(|i| (i * 7 % 256) as u8).collect();
        let images = [
            ByteImage {
                width: w,
                height: h,
                channels: 3,
                bytes: colour,
            },
            ByteImage {
                width: w,
                height: h,
                channels: 1,
                bytes: grey,
            },
        ];
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .expect("a thread pool");
        let same = |a: &[[f32; 3]], b: &[[f32; 3]]| {
            a.len() == b.len()
                && a.iter()
                    .flatten()
                    .zip(b.iter().flatten())
                    .all(|(x, y)| x.to_bits() == y.to_bits())
        };
        for model in &models {
            let lin = Linearizer::new(model, 255.0, &radiometry);
            for image in &images {
                let mut codes = CodeImage {
                    width: 0,
                    height: 0,
                    pixels: Vec::new(),
                };
                image.to_codes_into_on(&mut codes, None);
                let want = lin.linearize(&codes);
                let mut one = Vec::new();
                lin.linearize_bytes_into_on(image, &mut one, None);
                let mut used = vec![[f32::NAN; 3]; want.len()];
                lin.linearize_bytes_into_on(image, &mut used, Some(&pool));
                assert!(same(&one, &want), "{model:?}, {} channels", image.channels);
                assert!(
                    same(&used, &want),
                    "{model:?}, {} channels, pool",
                    image.channels
                );
            }
        }
        // the last row missing: its pixels are 0, not what the buffer held
        let lin = Linearizer::new(&ResponseModel::Srgb, 255.0, &radiometry);
        let mut short = images[0].clone();
        short.bytes.truncate(3 * (w * (h - 1)) as usize);
        let mut out = vec![[f32::NAN; 3]; (w * h) as usize];
        lin.linearize_bytes_into_on(&short, &mut out, Some(&pool));
        let (head, tail) = out.split_at((w * (h - 1)) as usize);
        assert!(tail.iter().flatten().all(|&v| v == 0.0));
        assert!(head.iter().flatten().all(|v| v.is_finite()));
    }

    /// Decoding and linearising band by band gives the radiances of the two steps (a whole
    /// code image, then its linearisation) to the bit: every pixel format, padded rows, several
    /// bands with a short last one, the shared grey table, linear factors and per-channel
    /// curves, on one thread and on a pool, into a used buffer; a bad buffer is the same error.
    #[test]
    fn decoding_and_linearising_in_one_pass_equals_the_two_steps() {
        use crate::capture::pixel_format::{decode, PixelFormat};
        let (w, h) = (72u32, 100u32);
        let mut byte = byte_stream(0x1234_5678_9abc_def1u64);
        let rgb: Vec<u8> = (0..3 * w * h).map(|_| byte() / 2 + 64).collect();
        let mut jpeg = Vec::new();
        jpeg_encoder::Encoder::new(&mut jpeg, 90)
            .encode(&rgb, w as u16, h as u16, jpeg_encoder::ColorType::Rgb)
            .unwrap();
        let models = [
            ResponseModel::Srgb,
            ResponseModel::Linear,
            per_channel_curve(),
        ];
        let radiometry = Radiometry {
            exposure_s: 0.02,
            gain: 1.0,
            white_balance: [1.2, 1.0, 0.8],
            scale: 1.0,
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .expect("a thread pool");
        for format in PixelFormat::all() {
            // packed rows padded by 6 bytes; every fifth byte repeated, so grey runs occur
            let stride = (format.row_bytes(w) + 6) * usize::from(format != PixelFormat::Mjpeg);
            let data: Vec<u8> = if format == PixelFormat::Mjpeg {
                jpeg.clone()
            } else {
                let mut last = 0;
                (0..format.buffer_len(w, h, stride).expect("a valid test frame"))
                    .map(|i| {
                        if i % 5 != 0 {
                            last = byte();
                        }
                        last
                    })
                    .collect()
            };
            let frame = RawFrame {
                data: &data,
                format,
                width: w,
                height: h,
                stride,
            };
            let codes = decode(&frame, YuvMatrix::Bt601).unwrap();
            for model in &models {
                let lin = Linearizer::new(model, format.code_max(), &radiometry);
                let want = lin.linearize(&codes);
                for (threads, used) in [
                    (None, Vec::new()),
                    (Some(&pool), vec![[f32::NAN; 3]; want.len()]),
                    (Some(&pool), vec![[1.0; 3]; 5]),
                ] {
                    let mut out = used;
                    lin.decode_linearize_into_on(&frame, YuvMatrix::Bt601, &mut out, threads)
                        .unwrap();
                    assert_eq!(out.len(), want.len(), "{format}");
                    assert!(
                        out.iter()
                            .flatten()
                            .zip(want.iter().flatten())
                            .all(|(a, b)| a.to_bits() == b.to_bits()),
                        "{format}, {model:?}, pool {}",
                        threads.is_some()
                    );
                }
            }
            // a buffer one byte short of the last row (a JPEG cut inside its header): the
            // decoder's own error
            let cut = if format == PixelFormat::Mjpeg {
                20
            } else {
                data.len() - 7
            };
            let short = RawFrame {
                data: &data[..cut],
                ..frame
            };
            let lin = Linearizer::new(&ResponseModel::Srgb, format.code_max(), &radiometry);
            let mut out = Vec::new();
            let e = lin
                .decode_linearize_into_on(&short, YuvMatrix::Bt601, &mut out, None)
                .unwrap_err();
            assert_eq!(Err(e), decode(&short, YuvMatrix::Bt601), "{format}");
        }
    }
}
