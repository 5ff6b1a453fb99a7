//! Wavelet lighting (issue 7, after Michiels et al. 2013 and Ng, Ramamoorthi and Hanrahan 2004):
//! the environment as a sparse set of orthonormal wavelet coefficients on the sphere.
//!
//! Steps, each in its own module:
//! 1. [`sphere`]: resample any [`HdrFrame`](crate::HdrFrame) onto the equal-area octahedral
//!    map, a `side × side` square (`side = 2^n`) whose texels all have solid angle 4π/side².
//! 2. [`transform`]: the 2-D orthonormal wavelet transform of that square (nonstandard pyramid,
//!    periodic boundary, PyWavelets' `periodization` mode exactly), for the bases of [`basis`]:
//!    Haar, Daubechies db2..db10, Coiflets coif1..coif5.
//! 3. [`approx`]: non-linear approximation keeping the K largest coefficients, as a serialisable
//!    [`WaveletSet`](approx::WaveletSet) that can be streamed and reconstructed.
//!
//! Because the texels have equal area, the discrete transform of the texel radiances is (up to
//! the constant factor √(4π)/side) the expansion of L(ω) in an orthonormal basis of L²(S²) made
//! of piecewise-constant-on-texels functions; Parseval holds on the sphere as on the square.

pub mod approx;
pub mod basis;
pub mod sphere;
mod taps;
pub mod transform;

pub use approx::{approximate, WaveletSet};
pub use basis::Basis;
pub use sphere::{OctahedralMap, Resampler};
pub use transform::{forward_2d, inverse_2d, TransformError};
