//! Supersampling anti-aliasing ([`super::RenderSettings::supersample`]): every pass renders at
//! s times the output's width and height (s² samples a pixel on a regular grid), and a compute
//! pass (`shaders/resolve.wgsl`) averages each pixel's s × s samples into the output image — a
//! box filter, in linear HDR with premultiplied alpha. Edges, shadow-catcher boundaries and
//! texture detail are resolved exactly to 1/s² of a pixel's coverage, at s² times the shading
//! and G-buffer memory; the shadow maps do not change.
//!
//! Supersampling rather than MSAA: the shading is deferred (a compute pass over a G-buffer), and
//! MSAA would need the G-buffer per sample and the shading per distinct sample along edges;
//! supersampling shades every sample and so also anti-aliases what MSAA does not (specular
//! highlights smaller than a pixel, texture and shadow edges).

/// The largest supersampling factor (16 samples a pixel).
pub const MAX_SUPERSAMPLE: u32 = 4;

/// WGSL source of the resolve pass.
pub const RESOLVE_WGSL: &str = include_str!("../../shaders/resolve.wgsl");

/// The output image and the pass that resolves the samples into it (`width` × `height`, from
/// the frame at s times that size).
pub(super) fn resolve(
    device: &wgpu::Device,
    samples: &wgpu::TextureView,
    width: u32,
    height: u32,
) -> super::post::PostPass {
    super::post::PostPass::new(
        device,
        ("resolve", RESOLVE_WGSL, "cs_resolve"),
        samples,
        width,
        height,
    )
}
