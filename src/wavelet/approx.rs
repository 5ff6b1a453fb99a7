//! Non-linear wavelet approximation: keep the K largest coefficients of an RGB map.
//!
//! Steps: transform each channel of the `side × side` RGB map ([`transform::forward_2d`]), rank
//! every coefficient index by the **Euclidean norm of its RGB triple** (√(r² + g² + b²)) and keep
//! the K largest (ties broken by the lower index, so the set is deterministic). One index carries
//! all three channels. Because the transform is orthonormal, Parseval makes this choice optimal
//! for the RGB L2 error of the reconstructed map: the squared error is exactly the sum of the
//! squared norms of the dropped coefficients.
//!
//! The result, [`WaveletSet`], is what is streamed as the wavelet representation (serde; f32
//! coefficients). Its coefficients are those of the discrete transform of the texel radiances
//! (W/(m²·sr) per channel); multiply by √(4π)/side for coefficients of L(ω) in the orthonormal
//! basis of L²(S²) ([`WaveletSet::sphere_scale`]).

use super::basis::Basis;
use super::transform::{self, TransformError, Workspace};

/// A sparse set of wavelet coefficients of an RGB `side × side` map, reconstructible with
/// [`WaveletSet::reconstruct`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WaveletSet {
    /// The basis of the transform.
    pub basis: Basis,
    /// Side of the square map (a power of two).
    pub side: u32,
    /// Decomposition levels of the transform.
    pub levels: u32,
    /// (index into the `side × side` coefficient array in the layout of
    /// [`transform`], rgb coefficient), sorted by index; indices unique.
    pub coefficients: Vec<(u32, [f32; 3])>,
}

/// Errors of the approximation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ApproxError {
    #[error(transparent)]
    Transform(#[from] TransformError),
    #[error("wavelet set of side {side} has coefficient index {index} outside 0..{}", side * side)]
    IndexOutOfRange { side: u32, index: u32 },
    #[error("wavelet set has coefficient index {0} twice")]
    DuplicateIndex(u32),
    #[error("wavelet set uses unsupported basis {0:?}")]
    UnsupportedBasis(Basis),
    #[error("wavelet set has a non-finite coefficient at index {0}")]
    NonFinite(u32),
}

/// The coefficient planes of an RGB map: all `side²` coefficients per channel, layout of
/// [`transform`].
#[derive(Clone, Debug, PartialEq)]
pub struct Coefficients {
    pub basis: Basis,
    pub side: usize,
    pub levels: u32,
    /// One plane per channel, `side²` coefficients each.
    pub planes: [Vec<f64>; 3],
}

impl Coefficients {
    /// Transforms an RGB `side × side` map (row-major).
    pub fn analyze(
        pixels: &[[f32; 3]],
        side: usize,
        basis: Basis,
        levels: u32,
    ) -> Result<Self, ApproxError> {
        let mut ws = Workspace::new();
        Self::analyze_with(pixels, side, basis, levels, &mut ws)
    }

    /// [`Coefficients::analyze`] with caller-provided scratch space.
    pub fn analyze_with(
        pixels: &[[f32; 3]],
        side: usize,
        basis: Basis,
        levels: u32,
        ws: &mut Workspace,
    ) -> Result<Self, ApproxError> {
        if !basis.is_supported() {
            return Err(ApproxError::UnsupportedBasis(basis));
        }
        let expected = side.saturating_mul(side);
        if pixels.len() != expected {
            return Err(TransformError::Length {
                side,
                expected,
                len: pixels.len(),
            }
            .into());
        }
        let mut planes: [Vec<f64>; 3] =
            std::array::from_fn(|c| pixels.iter().map(|p| f64::from(p[c])).collect());
        for plane in &mut planes {
            transform::forward_2d_with(plane, side, basis, levels, ws)?;
        }
        Ok(Self {
            basis,
            side,
            levels,
            planes,
        })
    }

    /// Squared RGB norm of coefficient `i`.
    #[inline]
    pub fn norm2(&self, i: usize) -> f64 {
        let [r, g, b] = [self.planes[0][i], self.planes[1][i], self.planes[2][i]];
        r * r + g * g + b * b
    }

    /// Indices of the `k` largest coefficients by RGB norm (ties: lower index first), sorted by
    /// index. `k` larger than `side²` keeps all.
    pub fn largest(&self, k: usize) -> Vec<u32> {
        let n = self.side * self.side;
        let k = k.min(n);
        let mut order: Vec<(f64, u32)> = (0..n).map(|i| (self.norm2(i), i as u32)).collect();
        // Descending norm, then ascending index; NaN cannot occur for finite inputs but sorts last.
        let cmp = |a: &(f64, u32), b: &(f64, u32)| {
            b.0.partial_cmp(&a.0)
                .unwrap_or_else(|| a.0.is_nan().cmp(&b.0.is_nan()))
                .then(a.1.cmp(&b.1))
        };
        if k < n && k > 0 {
            order.select_nth_unstable_by(k - 1, cmp);
        }
        let mut kept: Vec<u32> = order[..k].iter().map(|&(_, i)| i).collect();
        kept.sort_unstable();
        kept
    }

    /// The sparse set of the `k` largest coefficients.
    pub fn truncate(&self, k: usize) -> WaveletSet {
        let coefficients = self
            .largest(k)
            .into_iter()
            .map(|i| {
                let u = i as usize;
                (
                    i,
                    [0, 1, 2].map(|c| crate::light::saturating_f32(self.planes[c][u])),
                )
            })
            .collect();
        WaveletSet {
            basis: self.basis,
            side: self.side as u32,
            levels: self.levels,
            coefficients,
        }
    }

    /// Σ over all coefficients of the squared RGB norm (= Σ over pixels of |rgb|², Parseval).
    pub fn energy(&self) -> f64 {
        self.planes.iter().flatten().map(|v| v * v).sum()
    }

    /// The relative L2 error ‖f − f_K‖ / ‖f‖ of keeping only the coefficients `kept` (indices;
    /// others are ignored), exact by Parseval: the energy of the coefficients left out over
    /// the total, the left-out ones summed as such. (The total less the kept cancels when one
    /// coefficient dwarfs the others: `wavelet approx` reported 0 for a map with a sun of 10⁸
    /// whose error was 2·10⁻⁷.) 0 for a black map.
    pub fn relative_l2_error(&self, kept: impl IntoIterator<Item = u32>) -> f64 {
        let n = self.planes[0].len();
        let mut is_kept = vec![false; n];
        for i in kept {
            if let Some(k) = is_kept.get_mut(i as usize) {
                *k = true;
            }
        }
        let (mut total, mut dropped) = (0.0, 0.0);
        for (i, &k) in is_kept.iter().enumerate() {
            let e = self.norm2(i);
            total += e;
            if !k {
                dropped += e;
            }
        }
        if total > 0.0 {
            (dropped / total).sqrt()
        } else {
            0.0
        }
    }
}

/// Transforms `pixels` (`side × side` RGB, row-major) with `basis` and `levels` and keeps the
/// `k` largest coefficients by RGB norm.
pub fn approximate(
    pixels: &[[f32; 3]],
    side: usize,
    basis: Basis,
    levels: u32,
    k: usize,
) -> Result<WaveletSet, ApproxError> {
    Ok(Coefficients::analyze(pixels, side, basis, levels)?.truncate(k))
}

impl WaveletSet {
    /// Number of kept coefficients.
    pub fn len(&self) -> usize {
        self.coefficients.len()
    }

    /// Whether no coefficient is kept.
    pub fn is_empty(&self) -> bool {
        self.coefficients.is_empty()
    }

    /// Factor from these coefficients to coefficients of L(ω) in the orthonormal basis of
    /// L²(S²) on the equal-area octahedral map: √(4π)/side.
    pub fn sphere_scale(&self) -> f64 {
        (4.0 * std::f64::consts::PI).sqrt() / f64::from(self.side.max(1))
    }

    /// Checks basis, side, levels and indices (in range, unique) and that coefficients are finite.
    pub fn validate(&self) -> Result<(), ApproxError> {
        if !self.basis.is_supported() {
            return Err(ApproxError::UnsupportedBasis(self.basis));
        }
        let side = self.side as usize;
        if side < 2 || !side.is_power_of_two() {
            return Err(TransformError::NotPowerOfTwo(side).into());
        }
        let max = transform::max_levels(side);
        if self.levels > max {
            return Err(TransformError::TooManyLevels {
                side,
                levels: self.levels,
                max,
            }
            .into());
        }
        let n = side * side;
        let mut seen = vec![false; n];
        for &(i, rgb) in &self.coefficients {
            let u = i as usize;
            if u >= n {
                return Err(ApproxError::IndexOutOfRange {
                    side: self.side,
                    index: i,
                });
            }
            if std::mem::replace(&mut seen[u], true) {
                return Err(ApproxError::DuplicateIndex(i));
            }
            if rgb.iter().any(|c| !c.is_finite()) {
                return Err(ApproxError::NonFinite(i));
            }
        }
        Ok(())
    }

    /// The dense coefficient planes of this set (dropped coefficients are 0).
    pub fn dense(&self) -> Result<Coefficients, ApproxError> {
        self.validate()?;
        let side = self.side as usize;
        let mut planes: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; side * side]);
        for &(i, rgb) in &self.coefficients {
            for c in 0..3 {
                planes[c][i as usize] = f64::from(rgb[c]);
            }
        }
        Ok(Coefficients {
            basis: self.basis,
            side,
            levels: self.levels,
            planes,
        })
    }

    /// The reconstructed `side × side` RGB map (row-major, f64).
    pub fn reconstruct(&self) -> Result<Vec<[f64; 3]>, ApproxError> {
        let dense = self.dense()?;
        Ok(transform::inverse_2d_rgb(
            dense.planes,
            dense.side,
            self.basis,
            self.levels,
        )?)
    }
}

#[cfg(test)]
mod relative_error_tests {
    use super::*;

    /// One coefficient of 10⁸ among fifteen of 1, all kept but one small one: the error is
    /// 1/√(10¹⁶ + 15) to rounding (the total less the kept gave √2 times that: 10¹⁶ + 15 and
    /// 10¹⁶ + 14 round to 10¹⁶ + 16 and 10¹⁶ + 14).
    #[test]
    fn the_error_of_a_sun_is_not_lost_in_cancellation() {
        let mut plane = vec![1.0; 16];
        plane[3] = 1e8;
        let coeffs = Coefficients {
            basis: Basis::Haar,
            side: 4,
            levels: 2,
            planes: [plane, vec![0.0; 16], vec![0.0; 16]],
        };
        let kept = (0..16u32).filter(|&i| i != 7);
        let e = coeffs.relative_l2_error(kept);
        let expected = 1.0 / (1e16f64 + 15.0).sqrt();
        assert!(
            (e - expected).abs() <= 1e-12 * expected,
            "{e} vs {expected}"
        );
        assert_eq!(coeffs.relative_l2_error(0..16), 0.0);
        assert_eq!(coeffs.relative_l2_error([]), 1.0);
        let black = Coefficients {
            planes: [vec![0.0; 16], vec![0.0; 16], vec![0.0; 16]],
            ..coeffs
        };
        assert_eq!(black.relative_l2_error([]), 0.0);
    }
}
