//! Orthonormal discrete wavelet transforms with periodic boundaries, in 1-D and 2-D.
//!
//! # Filters and boundary
//!
//! One analysis step of a signal `x` of even length `m` with the decomposition filters
//! `h = Basis::lowpass()` and `g = Basis::highpass()` (PyWavelets' `dec_lo` / `dec_hi`, `F` taps):
//!
//! ```text
//! a[i] = Σ_j h[j] · x[(2i + F/2 − j) mod m]      d[i] = Σ_j g[j] · x[(2i + F/2 − j) mod m]
//! ```
//!
//! for `i in 0..m/2`. This is PyWavelets' `mode="periodization"` exactly (the same index shift,
//! checked against its output in `tests/wavelet.rs`): the signal is treated as periodic, so the
//! step is an orthogonal matrix and the synthesis step is its transpose,
//! `x[(2i + F/2 − j) mod m] += h[j]·a[i] + g[j]·d[i]`. The index wraps as often as needed, so a
//! filter longer than the signal is still exact (the periodised filter bank stays orthonormal).
//!
//! # Multilevel layout (Mallat / `pywt.coeffs_to_array`)
//!
//! [`forward_1d`] with `levels` steps leaves `[a_L | d_L | d_{L−1} | … | d_1]` in place: the
//! coarsest approximation first, then the details from coarse to fine (`d_1`, the finest, is the
//! second half).
//!
//! [`forward_2d`] is the nonstandard (pyramid) decomposition of `pywt.wavedec2` on a square
//! `side × side` row-major array (`side = 2^n`): each level transforms every row and then every
//! column of the current top-left `m × m` approximation block and halves `m`. After `levels`
//! levels the top-left `(side>>levels)²` block holds the coarsest approximation (LL); level `l`'s
//! details (`m = side >> (l−1)`, `h = m/2`) lie in
//! - rows `0..h`, columns `h..m`: low-pass along y, high-pass along x (pywt `'ad'`, cV),
//! - rows `h..m`, columns `0..h`: high-pass along y, low-pass along x (pywt `'da'`, cH),
//! - rows `h..m`, columns `h..m`: high-pass along both (pywt `'dd'`, cD).
//!
//! This is exactly the array `pywt.coeffs_to_array(pywt.wavedec2(x, w, mode="periodization",
//! level=levels))` returns. The transforms work in place with scratch space kept in a
//! [`Workspace`] (one line, and one `side²` block for the column pass, which combines whole rows
//! so that memory is read sequentially); nothing is allocated per level, nor per call when a
//! `Workspace` is reused.

use super::basis::Basis;

/// Errors of the transforms: sizes the transform cannot take.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TransformError {
    #[error("wavelet transform needs a power-of-two side of at least 2, got {0}")]
    NotPowerOfTwo(usize),
    #[error("wavelet transform of side {side} allows at most {max} levels, asked for {levels}")]
    TooManyLevels { side: usize, levels: u32, max: u32 },
    #[error("wavelet transform of side {side} needs {expected} samples, got {len}")]
    Length {
        side: usize,
        expected: usize,
        len: usize,
    },
}

/// The deepest decomposition a power-of-two `side` allows: log2(side) (down to one sample).
pub fn max_levels(side: usize) -> u32 {
    if side.is_power_of_two() {
        side.trailing_zeros()
    } else {
        0
    }
}

/// Checks `side` (a power of two ≥ 2), `levels` (≤ log2 side) and `len` (`expected`).
fn check(side: usize, levels: u32, len: usize, expected: usize) -> Result<(), TransformError> {
    if side < 2 || !side.is_power_of_two() {
        return Err(TransformError::NotPowerOfTwo(side));
    }
    let max = max_levels(side);
    if levels > max {
        return Err(TransformError::TooManyLevels { side, levels, max });
    }
    if len != expected {
        return Err(TransformError::Length {
            side,
            expected,
            len,
        });
    }
    Ok(())
}

/// Scratch space for the transforms: reuse one across calls to avoid allocating per frame.
#[derive(Debug, Default, Clone)]
pub struct Workspace {
    out: Vec<f64>,
    /// Rows of the column pass of the 2-D transforms (`side²`).
    block: Vec<f64>,
}

impl Workspace {
    pub fn new() -> Self {
        Self::default()
    }

    fn ensure(&mut self, n: usize) {
        if self.out.len() < n {
            self.out.resize(n, 0.0);
        }
    }

    fn ensure_block(&mut self, n: usize) {
        if self.block.len() < n {
            self.block.resize(n, 0.0);
        }
    }
}

/// One analysis step: `x` (length m, even) → `out[..m/2]` approximation, `out[m/2..m]` detail.
#[inline]
fn analyze(x: &[f64], out: &mut [f64], lo: &[f64], hi: &[f64]) {
    let m = x.len();
    let half = m / 2;
    let f = lo.len();
    let shift = f / 2;
    for i in 0..half {
        let base = 2 * i + shift;
        let (mut a, mut d) = (0.0, 0.0);
        if base >= f - 1 && base < m {
            // No wrap: indices base − j for j in 0..f all lie in 0..m.
            for j in 0..f {
                let v = x[base - j];
                a += lo[j] * v;
                d += hi[j] * v;
            }
        } else {
            for j in 0..f {
                let k = (base as isize - j as isize).rem_euclid(m as isize) as usize;
                let v = x[k];
                a += lo[j] * v;
                d += hi[j] * v;
            }
        }
        out[i] = a;
        out[half + i] = d;
    }
}

/// One synthesis step, the transpose of [`analyze`]: `c[..m/2]` approximation and `c[m/2..m]`
/// detail → `out` (length m).
#[inline]
fn synthesize(c: &[f64], out: &mut [f64], lo: &[f64], hi: &[f64]) {
    let m = c.len();
    let half = m / 2;
    let f = lo.len();
    let shift = f / 2;
    out.fill(0.0);
    for i in 0..half {
        let base = 2 * i + shift;
        let (a, d) = (c[i], c[half + i]);
        if base >= f - 1 && base < m {
            for j in 0..f {
                out[base - j] += lo[j] * a + hi[j] * d;
            }
        } else {
            for j in 0..f {
                let k = (base as isize - j as isize).rem_euclid(m as isize) as usize;
                out[k] += lo[j] * a + hi[j] * d;
            }
        }
    }
}

/// [`analyze`] applied down every column of the top-left `m × m` block of a row-major array of
/// row length `side`, as whole-row multiply-adds (sequential memory access, vectorisable) into
/// `block` (`m × m`), then copied back.
fn analyze_columns(
    data: &mut [f64],
    side: usize,
    m: usize,
    lo: &[f64],
    hi: &[f64],
    block: &mut [f64],
) {
    let half = m / 2;
    let f = lo.len();
    let shift = f / 2;
    let block = &mut block[..m * m];
    block.fill(0.0);
    for i in 0..half {
        let (top, bottom) = block.split_at_mut(half * m);
        let a_row = &mut top[i * m..(i + 1) * m];
        let d_row = &mut bottom[i * m..(i + 1) * m];
        for j in 0..f {
            let k = (2 * i + shift) as isize - j as isize;
            let k = k.rem_euclid(m as isize) as usize;
            let src = &data[k * side..k * side + m];
            let (l, h) = (lo[j], hi[j]);
            for ((a, d), &v) in a_row.iter_mut().zip(d_row.iter_mut()).zip(src) {
                *a += l * v;
                *d += h * v;
            }
        }
    }
    for y in 0..m {
        data[y * side..y * side + m].copy_from_slice(&block[y * m..(y + 1) * m]);
    }
}

/// [`synthesize`] applied down every column of the top-left `m × m` block (the transpose of
/// [`analyze_columns`]).
fn synthesize_columns(
    data: &mut [f64],
    side: usize,
    m: usize,
    lo: &[f64],
    hi: &[f64],
    block: &mut [f64],
) {
    let half = m / 2;
    let f = lo.len();
    let shift = f / 2;
    let block = &mut block[..m * m];
    block.fill(0.0);
    for i in 0..half {
        let a_row = &data[i * side..i * side + m];
        let d_row = &data[(half + i) * side..(half + i) * side + m];
        for j in 0..f {
            let k = (2 * i + shift) as isize - j as isize;
            let k = k.rem_euclid(m as isize) as usize;
            let dst = &mut block[k * m..(k + 1) * m];
            let (l, h) = (lo[j], hi[j]);
            for ((o, &a), &d) in dst.iter_mut().zip(a_row).zip(d_row) {
                *o += l * a + h * d;
            }
        }
    }
    for y in 0..m {
        data[y * side..y * side + m].copy_from_slice(&block[y * m..(y + 1) * m]);
    }
}

/// Multilevel forward transform of a 1-D signal of power-of-two length, in place; layout
/// `[a_L | d_L | … | d_1]`.
pub fn forward_1d(data: &mut [f64], basis: Basis, levels: u32) -> Result<(), TransformError> {
    let mut ws = Workspace::new();
    forward_1d_with(data, basis, levels, &mut ws)
}

/// [`forward_1d`] with caller-provided scratch space.
pub fn forward_1d_with(
    data: &mut [f64],
    basis: Basis,
    levels: u32,
    ws: &mut Workspace,
) -> Result<(), TransformError> {
    let n = data.len();
    check(n, levels, n, n)?;
    ws.ensure(n);
    let (lo, hi) = (basis.lowpass(), basis.highpass());
    let mut m = n;
    for _ in 0..levels {
        let out = &mut ws.out[..m];
        analyze(&data[..m], out, lo, hi);
        data[..m].copy_from_slice(out);
        m /= 2;
    }
    Ok(())
}

/// Inverse of [`forward_1d`] with the same `basis` and `levels`, in place.
pub fn inverse_1d(data: &mut [f64], basis: Basis, levels: u32) -> Result<(), TransformError> {
    let mut ws = Workspace::new();
    inverse_1d_with(data, basis, levels, &mut ws)
}

/// [`inverse_1d`] with caller-provided scratch space.
pub fn inverse_1d_with(
    data: &mut [f64],
    basis: Basis,
    levels: u32,
    ws: &mut Workspace,
) -> Result<(), TransformError> {
    let n = data.len();
    check(n, levels, n, n)?;
    ws.ensure(n);
    let (lo, hi) = (basis.lowpass(), basis.highpass());
    let mut m = n >> levels;
    for _ in 0..levels {
        m *= 2;
        let out = &mut ws.out[..m];
        synthesize(&data[..m], out, lo, hi);
        data[..m].copy_from_slice(out);
    }
    Ok(())
}

/// Nonstandard (pyramid) 2-D forward transform of a `side × side` row-major array, in place,
/// `levels` levels (0 ≤ levels ≤ log2 side). Layout: see the module documentation.
pub fn forward_2d(
    data: &mut [f64],
    side: usize,
    basis: Basis,
    levels: u32,
) -> Result<(), TransformError> {
    let mut ws = Workspace::new();
    forward_2d_with(data, side, basis, levels, &mut ws)
}

/// [`forward_2d`] with caller-provided scratch space.
pub fn forward_2d_with(
    data: &mut [f64],
    side: usize,
    basis: Basis,
    levels: u32,
    ws: &mut Workspace,
) -> Result<(), TransformError> {
    check(side, levels, data.len(), side.saturating_mul(side))?;
    ws.ensure(side);
    ws.ensure_block(side * side);
    let (lo, hi) = (basis.lowpass(), basis.highpass());
    let mut m = side;
    for _ in 0..levels {
        // Rows.
        for y in 0..m {
            let row = &mut data[y * side..y * side + m];
            let out = &mut ws.out[..m];
            analyze(row, out, lo, hi);
            row.copy_from_slice(out);
        }
        // Columns.
        analyze_columns(data, side, m, lo, hi, &mut ws.block);
        m /= 2;
    }
    Ok(())
}

/// Inverse of [`forward_2d`] with the same `side`, `basis` and `levels`, in place.
pub fn inverse_2d(
    data: &mut [f64],
    side: usize,
    basis: Basis,
    levels: u32,
) -> Result<(), TransformError> {
    let mut ws = Workspace::new();
    inverse_2d_with(data, side, basis, levels, &mut ws)
}

/// [`inverse_2d`] with caller-provided scratch space.
pub fn inverse_2d_with(
    data: &mut [f64],
    side: usize,
    basis: Basis,
    levels: u32,
    ws: &mut Workspace,
) -> Result<(), TransformError> {
    check(side, levels, data.len(), side.saturating_mul(side))?;
    ws.ensure(side);
    ws.ensure_block(side * side);
    let (lo, hi) = (basis.lowpass(), basis.highpass());
    let mut m = side >> levels;
    for _ in 0..levels {
        m *= 2;
        // Columns first (the transpose of forward's rows-then-columns order).
        synthesize_columns(data, side, m, lo, hi, &mut ws.block);
        for y in 0..m {
            let row = &mut data[y * side..y * side + m];
            let out = &mut ws.out[..m];
            synthesize(row, out, lo, hi);
            row.copy_from_slice(out);
        }
    }
    Ok(())
}

/// [`forward_2d`] of each channel of an RGB array (`side²` pixels): returns the three
/// coefficient planes.
pub fn forward_2d_rgb(
    pixels: &[[f64; 3]],
    side: usize,
    basis: Basis,
    levels: u32,
) -> Result<[Vec<f64>; 3], TransformError> {
    check(side, levels, pixels.len(), side.saturating_mul(side))?;
    let mut ws = Workspace::new();
    let mut planes: [Vec<f64>; 3] = std::array::from_fn(|c| pixels.iter().map(|p| p[c]).collect());
    for plane in &mut planes {
        forward_2d_with(plane, side, basis, levels, &mut ws)?;
    }
    Ok(planes)
}

/// Inverse of [`forward_2d_rgb`]: three coefficient planes back to RGB pixels.
pub fn inverse_2d_rgb(
    planes: [Vec<f64>; 3],
    side: usize,
    basis: Basis,
    levels: u32,
) -> Result<Vec<[f64; 3]>, TransformError> {
    let mut ws = Workspace::new();
    let mut planes = planes;
    for plane in &mut planes {
        inverse_2d_with(plane, side, basis, levels, &mut ws)?;
    }
    Ok((0..side * side)
        .map(|i| [planes[0][i], planes[1][i], planes[2][i]])
        .collect())
}
