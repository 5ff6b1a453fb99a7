//! Wavelet lighting (Michiels et al. 2013 after Ng, Ramamoorthi and Hanrahan 2004).
//!
//! Part B (this branch): per-vertex visibility by ray casting, BRDF slices, the sparse
//! triple-product binding tensor, relighting and hierarchical inverse rendering.

pub mod basis;
mod taps;
pub mod transform;
pub mod visibility;
