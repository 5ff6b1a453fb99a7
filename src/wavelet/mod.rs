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
//!    [`WaveletSet`] that can be streamed and reconstructed.
//!
//! Because the texels have equal area, the discrete transform of the texel radiances is (up to
//! the constant factor √(4π)/side) the expansion of L(ω) in an orthonormal basis of L²(S²) made
//! of piecewise-constant-on-texels functions; Parseval holds on the sphere as on the square.
//!
//! Light transport on top of that basis:
//! 4. [`visibility`]: per-vertex visibility of every texel direction by CPU ray casting (BVH).
//! 5. [`relight`]: BRDF slices and per-vertex transport in the same basis, and per-frame
//!    relighting of a static mesh as a sparse dot product per vertex.
//! 6. [`triple`]: the sparse triple-product binding tensor `C_ijk = ∫ Ψ_i Ψ_j Ψ_k dω` from the
//!    separable structure of the basis, and `B = Σ V_i L_j ρ_k C_ijk`.
//! 7. [`inverse`]: hierarchical refinement for inverse rendering: lighting coefficients from
//!    observed radiance, growing the wavelet tree only where the system stays full rank.

pub mod approx;
pub mod basis;
pub mod inverse;
pub mod relight;
pub mod sphere;
mod taps;
pub mod transform;
pub mod triple;
pub mod visibility;

pub use approx::{approximate, WaveletSet};
pub use basis::Basis;
pub use sphere::{OctahedralMap, Resampler};
pub use transform::{forward_2d, inverse_2d, TransformError};
