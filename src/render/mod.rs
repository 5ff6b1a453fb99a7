//! The wgpu renderer: shades a scene under a frame's directional lights, with a shadow map per
//! light, per-pixel light culling and a fixed frame budget.
//!
//! Passes, per frame:
//! 1. **Shadow maps**: for every light that reaches a visible surface
//!    ([`shadow::reaches_visible`]), a depth map of the shadow casters with an orthographic
//!    projection fitted to the casters' bounding sphere ([`shadow::light_view_proj`]); lights
//!    that reach nothing visible get no map. [`RenderSettings::shadow_raster`] says how:
//!    one depth-only render pass per map into its layer of a `Depth32Float` texture array
//!    (`shaders/shadow.wgsl`), or one compute pass that rasterises every map into a storage
//!    buffer ([`shadow_raster`]) — on an H200 0.37 ms for 256 maps of 512² against 11.4 ms as
//!    render passes, whose depth fill runs on the small graphics part of that chip. (An atlas,
//!    one render pass per 8192² layer of 256 tiles set by viewport and scissor, was tried on
//!    2026-12-04 and was slower still, 15.5 ms; docs/performance.md.) Casters cut out by
//!    their alpha (glTF's MASK) write no depth where it is below the cutoff, in both ways.
//! 2. **G-buffer pass** (`fs_gbuffer` of `shaders/shade.wgsl`): one draw of the whole scene
//!    into four `Rgba32Float` targets: world position with material, shading normal (turned by
//!    a normal texture) with roughness, base colour with metallic, and emission with occlusion,
//!    and an `Rgba32Uint` one of 16-bit fields: the dielectric Fresnel terms and the clear
//!    coat's strength, roughness and normal
//!    — the material's factors times its textures ([`textures`]), sampled here where the
//!    screen derivatives that choose their mip level exist.
//! 3. **Shading pass** (`cs_shade`, a compute shader): per pixel it reads the G-buffer and sums
//!    Lambertian diffuse + GGX specular (metallic-roughness) over the lights, each times its
//!    PCF-filtered shadow visibility; a light's solid angle widens both its PCF kernel (softer
//!    shadows for merged lights) and its specular lobe. The sum is scaled by the occlusion
//!    texture's value and the emission added. It writes an `Rgba32Float` frame (linear
//!    HDR, premultiplied alpha over a transparent background). Deferred, each pixel is shaded
//!    once whatever the overdraw, and the light loop is compute work, which every
//!    multiprocessor of a GPU runs: on an H200, whose graphics pipeline has a small part of the
//!    chip, the frame without shadows went from 20.8 ms as a fragment shader to 1.66 ms
//!    (1280×720, 256 lights; docs/performance.md).
//! 4. **Blended surfaces** (glTF's BLEND; only where the scene has any): a render pass
//!    (`fs_blended`) draws them over the shaded frame, back to front (sorted by
//!    `order_triangles`), depth-tested against the G-buffer pass's depth, each fragment shaded
//!    as `cs_shade` shades a pixel and blended by its alpha (premultiplied over).
//! 5. **Resolve** (only with [`RenderSettings::supersample`] above 1): every pass above runs at
//!    s times the output's size, and a compute pass averages each pixel's s × s samples
//!    ([`supersample`]); or **FXAA** (only with [`RenderSettings::fxaa`]): a compute pass
//!    smooths the frame's edges ([`post`], `shaders/fxaa.wgsl`).
//! 6. Read-back (for files and tests) and timing: GPU timestamps around the shadow passes and
//!    the rest of the frame where the adapter has them, CPU wall time from submit to
//!    completion otherwise.
//!
//! **Per-pixel light culling** (Havran et al. 2005 cull lights below a pixel's horizon; this
//! renderer also culls by the specular lobe): a light with n·l ≤ 0 is skipped before any
//! shading or shadow lookup (exact: its contribution is zero). On glossy pixels (any
//! specular), only lights inside a cone around the mirror direction — where the half vector is
//! within θ_h of the normal, tan θ_h = 3α′, so the GGX lobe is above ~1% of its peak (α′ the
//! roughness widened by the light's angular radius) — take the full path (a 12-tap PCF); the
//! others take a cheap path with four bilinear 2×2 comparison taps. Culling changes only the
//! shadow filtering of off-lobe lights, so culled and unculled images differ only in
//! penumbrae: the tolerance
//! ([`CULLING_TOLERANCE`]) is stated in docs/rendering.md and enforced by tests/render.rs.
//!
//! **ASG lighting** ([`Renderer::render_asg`], module [`asg`], `shaders/asg.wgsl`): the same
//! scene shaded in closed form under anisotropic spherical Gaussians instead of lights — one
//! pass, no shadow maps, no occlusion but the materials' occlusion textures.
//!
//! Mixed reality: with [`RenderSettings::shadow_catcher`], the ground outputs (0, 0, 0, α) with
//! α = 1 − E_shadowed/E_unshadowed, so the RGBA image composites over the camera picture (or
//! over the environment map, [`output::composite_background`]).

pub mod asg;
pub mod budget;
pub mod device;
pub mod output;
pub mod post;
pub mod scene;
pub mod shading;
pub mod shadow;
pub mod shadow_raster;
pub mod sheen;
pub mod supersample;
pub mod textures;
#[cfg(feature = "window")]
pub mod window;

use crate::light::Light;
use device::{DeviceError, Gpu};
use glam::{Mat4, Vec3};
use scene::Scene;
use shading::{Globals, GpuLight};
use shadow_raster::ComputeShadows;
pub use shadow_raster::ShadowRaster;
use std::time::Instant;
use thiserror::Error;

/// WGSL source of the G-buffer and shading passes (`surface.wgsl` prepended).
pub const SHADE_WGSL: &str = concat!(
    include_str!("../../shaders/surface.wgsl"),
    include_str!("../../shaders/shadow_lookup.wgsl"),
    include_str!("../../shaders/shade.wgsl")
);
/// WGSL source of the shadow pass (`surface.wgsl` prepended, for the cut-out casters).
pub const SHADOW_WGSL: &str = concat!(
    include_str!("../../shaders/surface.wgsl"),
    include_str!("../../shaders/shadow.wgsl")
);
/// WGSL source of the windowed mode's present pass.
pub const PRESENT_WGSL: &str = include_str!("../../shaders/present.wgsl");
/// Every shader module the renderer builds, by the file that defines its entry points, as
/// composed (the naga test validates each).
pub const SHADERS: &[(&str, &str)] = &[
    ("asg.wgsl", asg::ASG_WGSL),
    ("present.wgsl", PRESENT_WGSL),
    ("shade.wgsl", SHADE_WGSL),
    ("shadow.wgsl", SHADOW_WGSL),
    ("shadow_raster.wgsl", shadow_raster::SHADOW_RASTER_WGSL),
    ("resolve.wgsl", supersample::RESOLVE_WGSL),
    ("fxaa.wgsl", post::FXAA_WGSL),
];
/// The shared prelude prepended to `shade.wgsl`, `asg.wgsl`, `shadow.wgsl` and
/// `shadow_raster.wgsl`: vertex layout, materials and their textures, the shaded point's set-up.
pub const SURFACE_WGSL: &str = include_str!("../../shaders/surface.wgsl");
/// The second prelude of `shade.wgsl` and `asg.wgsl`, after [`SURFACE_WGSL`]: the light
/// records and the PCF shadow lookup, over bindings each of those files declares.
pub const SHADOW_LOOKUP_WGSL: &str = include_str!("../../shaders/shadow_lookup.wgsl");

/// Culled vs unculled images: bounds on the difference, relative to the unculled image's mean
/// opaque value (see docs/rendering.md): (mean absolute difference, 99.9th percentile).
pub const CULLING_TOLERANCE: (f32, f32) = (0.0005, 0.01);

const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// GPU timestamps per frame: start of the shadow passes, start of the G-buffer pass, end of the
/// frame's last pass (shading, blended surfaces, resolve or FXAA).
const TIMESTAMPS: u32 = 3;
/// `cs_shade`'s workgroup is 8×8 pixels.
const SHADE_WORKGROUP: u32 = 8;

/// Renderer errors.
#[derive(Debug, Error)]
pub enum RenderError {
    #[error(transparent)]
    Device(#[from] DeviceError),
    #[error("invalid render settings: {0}")]
    Settings(String),
    #[error("GPU failure: {0}")]
    Gpu(String),
    /// An output file (the daemon's `render.latest_png`) could not be written.
    #[error("cannot write the rendered image: {0}")]
    Output(String),
}

/// What to render and how.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    /// Side of each shadow map in texels.
    pub shadow_resolution: u32,
    pub shadows: bool,
    /// Per-pixel light culling (see the module doc).
    pub culling: bool,
    /// The ground plane is a shadow catcher (mixed-reality output).
    pub shadow_catcher: bool,
    /// How the shadow maps are drawn: render passes or compute shaders ([`shadow_raster`]);
    /// a renderer's [`Renderer::settings`] hold the way it resolved `Auto` to.
    pub shadow_raster: ShadowRaster,
    /// The most samples of anisotropic texture filtering, 1 (off) to
    /// [`textures::MAX_ANISOTROPY`] (the default; where the adapter has it).
    pub texture_anisotropy: u16,
    /// Supersampling anti-aliasing ([`supersample`]): the frame is rendered at this many times
    /// `width` and `height`, and each pixel is the mean of its samples; 1 (the default) is
    /// off, at most [`supersample::MAX_SUPERSAMPLE`].
    pub supersample: u32,
    /// Fast approximate anti-aliasing ([`post`], `shaders/fxaa.wgsl`) of the output image:
    /// edges smoothed along their length from the image alone, for a small part of
    /// supersampling's cost. Off by default; not with `supersample` above 1 (it would blur
    /// the resolved edges).
    pub fxaa: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            width: 640,
            height: 360,
            shadow_resolution: 512,
            shadows: true,
            culling: true,
            shadow_catcher: false,
            shadow_raster: ShadowRaster::default(),
            texture_anisotropy: textures::MAX_ANISOTROPY,
            supersample: 1,
            fxaa: false,
        }
    }
}

/// A rendered frame: linear HDR RGBA, premultiplied alpha, row 0 at the top.
#[derive(Clone, Debug)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<f32>,
}

impl Image {
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 4] {
        let i = 4 * (y as usize * self.width as usize + x as usize);
        [
            self.rgba[i],
            self.rgba[i + 1],
            self.rgba[i + 2],
            self.rgba[i + 3],
        ]
    }
}

/// What one frame cost.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameStats {
    /// Lights drawn.
    pub lights: usize,
    /// Shadow maps rendered.
    pub shadow_maps: usize,
    /// GPU time of the passes (timestamp queries), if the adapter has them.
    pub gpu_ms: Option<f64>,
    /// GPU time of the shadow passes alone (part of `gpu_ms`), where measured and some map
    /// was rendered.
    pub shadow_gpu_ms: Option<f64>,
    /// CPU wall time from the start of encoding to completion on the GPU.
    pub cpu_ms: f64,
}

impl FrameStats {
    /// The time the budget controller uses: GPU time where measured, else CPU time.
    pub fn frame_ms(&self) -> f64 {
        self.gpu_ms.unwrap_or(self.cpu_ms)
    }
}

struct ShadowArray {
    _texture: wgpu::Texture,
    layer_views: Vec<wgpu::TextureView>,
    array_view: wgpu::TextureView,
    layers: u32,
}

struct Timestamps {
    set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    read: wgpu::Buffer,
    period_ns: f32,
}

/// The renderer: device, pipelines and buffers for one scene and image size.
pub struct Renderer {
    gpu: Gpu,
    scene: Scene,
    settings: RenderSettings,
    facing: Vec<Vec3>,
    vertex_buffer: wgpu::Buffer,
    index_buffer: wgpu::Buffer,
    material_buffer: wgpu::Buffer,
    globals_buffer: wgpu::Buffer,
    light_buffer: wgpu::Buffer,
    light_capacity: usize,
    light_cam_buffer: wgpu::Buffer,
    light_cam_stride: u64,
    light_cam_capacity: usize,
    shadow: ShadowArray,
    shadow_sampler: wgpu::Sampler,
    shade_layout: wgpu::BindGroupLayout,
    shadow_cam_layout: wgpu::BindGroupLayout,
    shade_bind_group: wgpu::BindGroup,
    shadow_cam_bind_group: wgpu::BindGroup,
    /// The G-buffer's textures (position + material, normal + roughness, base colour +
    /// metallic, emission + occlusion) and the frame, for `cs_shade`.
    gbuffer_bind_group: wgpu::BindGroup,
    gbuffer_pipeline: wgpu::RenderPipeline,
    shade_pipeline: wgpu::ComputePipeline,
    shadow_pipeline: wgpu::RenderPipeline,
    /// The shadow pass of the cut-out casters (alpha mode MASK).
    masked_shadow_pipeline: wgpu::RenderPipeline,
    /// Where the cut-out and the blended casters start in the index buffer
    /// ([`order_triangles`]).
    groups: TriangleGroups,
    /// The blended surfaces' pass over the shaded frame (`fs_blended`), where the scene has
    /// any.
    blended_pipeline: Option<wgpu::RenderPipeline>,
    /// The frame the passes draw (at `supersample` times the output's size).
    color_view: wgpu::TextureView,
    color_texture: wgpu::Texture,
    /// The pass after the shading that makes the output image, where there is one: the
    /// supersampling's resolve of `color_view`'s samples, or FXAA (the two are not combined,
    /// [`RenderSettings::fxaa`]).
    post_pass: Option<post::PostPass>,
    depth_view: wgpu::TextureView,
    gbuffer_views: [wgpu::TextureView; GBUFFER_TARGETS],
    /// Whether the G-buffer pass writes its fifth target (else a 1 × 1 placeholder is bound):
    /// some material's Fresnel terms or clear coat vary over it
    /// ([`scene::Material::needs_layered_gbuffer`]).
    layered_gbuffer: bool,
    /// The materials' texture arrays (group 2 of the G-buffer and ASG passes).
    surface_textures: textures::SurfaceTextures,
    readback: wgpu::Buffer,
    padded_row: u32,
    timestamps: Option<Timestamps>,
    warned_layers: bool,
    /// The ASG lighting pass, built on first use.
    asg_pass: Option<asg::AsgPass>,
    /// The compute rasteriser, with [`ShadowRaster::Compute`].
    compute_shadows: Option<ComputeShadows>,
    /// Bound in its place otherwise.
    no_shadow_depths: wgpu::Buffer,
    /// Counts the times [`Self::prepare`] replaced a buffer or texture the shadow lookup binds
    /// (the light buffer, the map array, the compute maps), so that the ASG pass, which binds
    /// them too, rebinds only then.
    shadow_bindings_generation: u64,
}

/// The G-buffer's targets: position + material, normal + roughness, base colour + metallic,
/// emission + occlusion (`Rgba32Float`), and the layers over the base (`Rgba32Uint`, 16-bit
/// fields: the dielectric Fresnel terms, the clear coat's strength, roughness and normal;
/// `shaders/shade.wgsl`, `pack_layers`).
const GBUFFER_TARGETS: usize = 5;

/// The formats of the G-buffer's targets, in order.
const GBUFFER_FORMATS: [wgpu::TextureFormat; GBUFFER_TARGETS] = [
    COLOR_FORMAT,
    COLOR_FORMAT,
    COLOR_FORMAT,
    COLOR_FORMAT,
    wgpu::TextureFormat::Rgba32Uint,
];

/// The vertex attributes the surface passes (G-buffer, ASG) read: position, normal, material,
/// the two texture coordinates, tangent, colour (`shaders/surface.wgsl`, `VertexIn`), in
/// [`scene::Vertex`]'s order.
const SURFACE_ATTRIBUTES: [wgpu::VertexAttribute; 7] = wgpu::vertex_attr_array![
    0 => Float32x3, 1 => Float32x3, 2 => Uint32, 3 => Float32x2, 5 => Float32x2, 4 => Float32x4,
    6 => Unorm16x4
];

/// The vertex attributes the cut-out casters' shadow pass reads (`shaders/shadow.wgsl`,
/// `MaskedIn`): position, material, the two texture coordinates and the colour (its alpha), at
/// their offsets in [`scene::Vertex`].
const MASKED_SHADOW_ATTRIBUTES: [wgpu::VertexAttribute; 5] = {
    use std::mem::offset_of;
    use wgpu::VertexFormat::{Float32x2, Float32x3, Uint32, Unorm16x4};
    const fn at(
        format: wgpu::VertexFormat,
        offset: usize,
        shader_location: u32,
    ) -> wgpu::VertexAttribute {
        wgpu::VertexAttribute {
            format,
            offset: offset as u64,
            shader_location,
        }
    }
    [
        at(Float32x3, offset_of!(scene::Vertex, position), 0),
        at(Uint32, offset_of!(scene::Vertex, material), 2),
        at(Float32x2, offset_of!(scene::Vertex, uv), 3),
        at(Float32x2, offset_of!(scene::Vertex, uv1), 5),
        at(Unorm16x4, offset_of!(scene::Vertex, color), 6),
    ]
};

fn vertex_layout(attributes: &[wgpu::VertexAttribute]) -> wgpu::VertexBufferLayout<'_> {
    wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<scene::Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes,
    }
}

/// A uniform-buffer binding (no dynamic offset) seen by the `visibility` stages.
fn uniform_entry(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A storage-buffer binding read (or, without `read_only`, written) by compute shaders.
/// A single-level, single-sample 2D texture of `width` × `height` (the frame, the G-buffer, the
/// post passes' outputs).
fn texture_2d(
    device: &wgpu::Device,
    label: &str,
    (width, height): (u32, u32),
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

/// A layout entry for a 2D float texture read with `textureLoad` (not filtered: the
/// `Rgba32Float` frame and G-buffer), visible to `visibility`.
fn unfiltered_texture_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

fn compute_storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Where a pass binds what `shaders/shadow_lookup.wgsl` reads: the light records, the
/// shadow-map array, its comparison sampler and the compute rasteriser's depths (the light
/// pass and the ASG pass, each at its own binding numbers).
#[derive(Clone, Copy, Debug)]
struct ShadowLookupBindings {
    lights: u32,
    maps: u32,
    sampler: u32,
    depths: u32,
}

impl ShadowLookupBindings {
    /// The layout entries, visible to `visibility`.
    fn layout_entries(self, visibility: wgpu::ShaderStages) -> [wgpu::BindGroupLayoutEntry; 4] {
        [
            wgpu::BindGroupLayoutEntry {
                visibility,
                ..compute_storage_entry(self.lights, true)
            },
            wgpu::BindGroupLayoutEntry {
                binding: self.maps,
                visibility,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Depth,
                    view_dimension: wgpu::TextureViewDimension::D2Array,
                    multisampled: false,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: self.sampler,
                visibility,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                visibility,
                ..compute_storage_entry(self.depths, true)
            },
        ]
    }

    /// The bind-group entries of those resources.
    fn bind_entries<'a>(
        self,
        lights: &'a wgpu::Buffer,
        maps: &'a wgpu::TextureView,
        sampler: &'a wgpu::Sampler,
        depths: &'a wgpu::Buffer,
    ) -> [wgpu::BindGroupEntry<'a>; 4] {
        [
            wgpu::BindGroupEntry {
                binding: self.lights,
                resource: lights.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: self.maps,
                resource: wgpu::BindingResource::TextureView(maps),
            },
            wgpu::BindGroupEntry {
                binding: self.sampler,
                resource: wgpu::BindingResource::Sampler(sampler),
            },
            wgpu::BindGroupEntry {
                binding: self.depths,
                resource: depths.as_entire_binding(),
            },
        ]
    }
}

/// The light pass's [`ShadowLookupBindings`] (group 0 of `shaders/shade.wgsl`).
const SHADE_SHADOW_BINDINGS: ShadowLookupBindings = ShadowLookupBindings {
    lights: 1,
    maps: 3,
    sampler: 4,
    depths: 5,
};

/// A triangle pipeline over the scene's vertices (the vertex entry point reading the given
/// attributes), depth-tested with `Less`, no culling; with `fragment = Some((entry, formats))`,
/// that fragment entry point writes targets of those formats (none: it only discards), without it
/// the pass is depth-only (shadow maps). Unblended, it writes depth; with `blend` (the blended
/// surfaces' passes) its targets are blended so and depth is only tested.
#[allow(clippy::too_many_arguments)]
fn depth_tested_pipeline(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
    (vertex_entry, attributes): (&str, &[wgpu::VertexAttribute]),
    bias: wgpu::DepthBiasState,
    fragment: Option<(&str, &[wgpu::TextureFormat])>,
    blend: Option<wgpu::BlendState>,
) -> wgpu::RenderPipeline {
    let targets: Vec<_> = fragment
        .map_or(&[][..], |(_, formats)| formats)
        .iter()
        .map(|&format| {
            Some(wgpu::ColorTargetState {
                format,
                blend,
                write_mask: wgpu::ColorWrites::ALL,
            })
        })
        .collect();
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(label),
        layout: Some(layout),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some(vertex_entry),
            compilation_options: Default::default(),
            buffers: &[Some(vertex_layout(attributes))],
        },
        primitive: wgpu::PrimitiveState {
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: DEPTH_FORMAT,
            depth_write_enabled: Some(blend.is_none()),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias,
        }),
        multisample: Default::default(),
        fragment: fragment.map(|(entry, _)| wgpu::FragmentState {
            module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            targets: &targets,
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// Where the groups of shadow casters start in the scene's index list, as
/// [`order_triangles`] leaves it: opaque casters `0..cutout_start`, then those cut out by their
/// alpha in the shadow maps (masked or blended) up to `caster_indices`, of which the blended
/// ones are `blended_start..caster_indices`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct TriangleGroups {
    cutout_start: u32,
    blended_start: u32,
}

/// Orders the shadow casters' triangles of `scene` (the ground, after them, is left as it is):
/// opaque first, then masked (a cutoff above 0), each in its order, then blended (glTF's BLEND)
/// back to front from the camera, by the distance of their centroids. The shadow pass draws
/// the opaque group with the depth-only pipeline and the other two with the alpha-testing one;
/// the G-buffer pass draws all but the blended group, which the blended pass draws over the
/// frame in this order. (Sorting triangles rather than objects orders intersecting and nested
/// blended surfaces too, except where two triangles overlap in depth.)
fn order_triangles(scene: &mut Scene) -> TriangleGroups {
    use scene::AlphaMode;
    let casters = (scene.caster_indices as usize).min(scene.indices.len());
    let mode = |triangle: &[u32]| {
        triangle
            .first()
            .and_then(|&i| scene.vertices.get(i as usize))
            .and_then(|v| scene.materials.get(v.material as usize))
            .map_or(AlphaMode::Opaque, |m| m.alpha_mode)
    };
    let (mut opaque, mut masked, mut blended) = (Vec::new(), Vec::new(), Vec::new());
    for triangle in scene.indices[..casters].chunks(3) {
        match mode(triangle) {
            AlphaMode::Mask(cutoff) if cutoff > 0.0 => masked.push(triangle),
            AlphaMode::Blend => blended.push(triangle),
            _ => opaque.push(triangle),
        }
    }
    let depth = |triangle: &[u32]| {
        let sum: Vec3 = triangle
            .iter()
            .filter_map(|&i| scene.vertices.get(i as usize))
            .map(|v| Vec3::from(v.position))
            .sum();
        scene.camera.sort_depth(sum / 3.0)
    };
    // Farthest first; each depth computed once.
    let mut by_depth: Vec<(f32, &[u32])> = blended.into_iter().map(|t| (depth(t), t)).collect();
    by_depth.sort_by(|a, b| b.0.total_cmp(&a.0));
    let blended: Vec<&[u32]> = by_depth.into_iter().map(|(_, t)| t).collect();
    let groups = TriangleGroups {
        cutout_start: (opaque.len() * 3) as u32,
        blended_start: ((opaque.len() + masked.len()) * 3) as u32,
    };
    let ordered: Vec<u32> = [opaque, masked, blended]
        .into_iter()
        .flatten()
        .flatten()
        .copied()
        .collect();
    scene.indices[..ordered.len()].copy_from_slice(&ordered);
    groups
}

/// Makes the blended materials of `scene` opaque (an adapter that cannot blend `Rgba32Float`
/// targets), with a warning that says how many.
fn draw_blended_opaque(scene: &mut Scene) {
    let blended = scene
        .materials
        .iter_mut()
        .filter(|m| m.alpha_mode == scene::AlphaMode::Blend)
        .map(|m| m.alpha_mode = scene::AlphaMode::Opaque)
        .count();
    if blended > 0 {
        tracing::warn!(
            "{blended} blended material(s) drawn opaque: the adapter cannot blend Rgba32Float \
             targets (wgpu's FLOAT32_BLENDABLE)"
        );
    }
}

impl Renderer {
    /// Opens the preferred adapter ([`Gpu::new`]) and builds a renderer.
    pub fn new(scene: Scene, settings: RenderSettings) -> Result<Self, RenderError> {
        let gpu = Gpu::new()?;
        Self::with_gpu(gpu, scene, settings)
    }

    /// Builds a renderer on an open device.
    pub fn with_gpu(
        gpu: Gpu,
        mut scene: Scene,
        mut settings: RenderSettings,
    ) -> Result<Self, RenderError> {
        use wgpu::util::DeviceExt;
        let max_dim = gpu.device.limits().max_texture_dimension_2d;
        if settings.width == 0
            || settings.height == 0
            || settings.width > max_dim
            || settings.height > max_dim
        {
            return Err(RenderError::Settings(format!(
                "image size {}x{} outside 1..={max_dim}",
                settings.width, settings.height
            )));
        }
        let s = settings.supersample;
        if !(1..=supersample::MAX_SUPERSAMPLE).contains(&s) {
            return Err(RenderError::Settings(format!(
                "supersampling {s} outside 1..={}",
                supersample::MAX_SUPERSAMPLE
            )));
        }
        if settings.fxaa && s > 1 {
            return Err(RenderError::Settings(format!(
                "FXAA with supersampling {s}: FXAA blurs the resolved edges (further from their \
                 covered fraction than the supersampling alone, docs/rendering.md); choose one"
            )));
        }
        if u64::from(settings.width.max(settings.height)) * u64::from(s) > u64::from(max_dim) {
            return Err(RenderError::Settings(format!(
                "image size {}x{} supersampled {s}× is {}x{}, past the adapter's largest \
                 texture side {max_dim}; a smaller size or supersampling",
                settings.width,
                settings.height,
                u64::from(settings.width) * u64::from(s),
                u64::from(settings.height) * u64::from(s),
            )));
        }
        if !(16..=max_dim).contains(&settings.shadow_resolution) {
            return Err(RenderError::Settings(format!(
                "shadow map resolution {} outside 16..={max_dim}",
                settings.shadow_resolution
            )));
        }
        if scene.indices.is_empty() {
            return Err(RenderError::Settings("the scene has no triangles".into()));
        }
        if !(1..=textures::MAX_ANISOTROPY).contains(&settings.texture_anisotropy) {
            return Err(RenderError::Settings(format!(
                "texture anisotropy {} outside 1..={}",
                settings.texture_anisotropy,
                textures::MAX_ANISOTROPY
            )));
        }
        settings.shadow_raster = settings
            .shadow_raster
            .resolve_for(
                gpu.info.device_type,
                ComputeShadows::max_maps(&gpu.device, settings.shadow_resolution),
                settings.shadow_resolution,
            )
            .map_err(RenderError::Settings)?;
        // A buffer past the device's limit is a validation error, and wgpu's buffer
        // initialisation then panicked on the invalid buffer's mapping.
        let max_buffer = gpu.device.limits().max_buffer_size;
        for (what, count, bytes) in [
            (
                "vertices",
                scene.vertices.len(),
                std::mem::size_of_val(scene.vertices.as_slice()),
            ),
            (
                "triangle indices",
                scene.indices.len(),
                std::mem::size_of_val(scene.indices.as_slice()),
            ),
        ] {
            if bytes as u64 > max_buffer {
                return Err(RenderError::Settings(format!(
                    "the scene's {count} {what} take {bytes} bytes, more than the largest \
                     buffer the adapter allows ({max_buffer} bytes); simplify the model"
                )));
            }
        }
        if !gpu.float32_blendable {
            draw_blended_opaque(&mut scene);
        }
        let groups = order_triangles(&mut scene);
        let layered_gbuffer = scene
            .materials
            .iter()
            .any(scene::Material::needs_layered_gbuffer);
        let device = &gpu.device;
        let vertex_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: bytemuck::cast_slice(&scene.vertices),
            // Storage: the compute rasteriser reads the positions.
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::STORAGE,
        });
        let index_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("indices"),
            contents: bytemuck::cast_slice(&scene.indices),
            usage: wgpu::BufferUsages::INDEX | wgpu::BufferUsages::STORAGE,
        });
        let texture_plan = textures::plan_layers(&scene, max_dim);
        let surface_textures = textures::SurfaceTextures::new(
            &gpu.device,
            &gpu.queue,
            &scene,
            &texture_plan,
            settings.texture_anisotropy,
        )
        .map_err(|e| RenderError::Settings(e.to_string()))?;
        let materials: Vec<shading::MaterialRaw> = scene
            .materials
            .iter()
            .zip(textures::material_layers(&scene, &texture_plan))
            .enumerate()
            .map(|(i, (m, layers))| {
                let catcher = settings.shadow_catcher && scene.ground_material == Some(i as u32);
                m.to_raw(if catcher { shading::FLAG_CATCHER } else { 0 }, layers)
            })
            .collect();
        let material_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("materials"),
            contents: bytemuck::cast_slice(&materials),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let globals_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("globals"),
            size: std::mem::size_of::<shading::GlobalsRaw>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let light_capacity = 64;
        let light_buffer = Self::make_light_buffer(device, light_capacity);
        let align = u64::from(device.limits().min_uniform_buffer_offset_alignment);
        let light_cam_stride = 64u64.div_ceil(align) * align;
        let light_cam_capacity = 64;
        let light_cam_buffer =
            Self::make_light_cam_buffer(device, light_cam_stride, light_cam_capacity);
        let shadow = Self::make_shadow_array(device, settings.shadow_resolution, 1);
        let shadow_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow comparison"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });

        // The fragment stages: the G-buffer pass reads the materials' factors and texture
        // layers, the blended pass shades as the compute pass does.
        let shading_stages = wgpu::ShaderStages::COMPUTE | wgpu::ShaderStages::FRAGMENT;
        let [lights_entry, maps_entry, sampler_entry, depths_entry] =
            SHADE_SHADOW_BINDINGS.layout_entries(shading_stages);
        let shade_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shade"),
            entries: &[
                uniform_entry(0, wgpu::ShaderStages::VERTEX | shading_stages),
                lights_entry,
                wgpu::BindGroupLayoutEntry {
                    visibility: shading_stages,
                    ..compute_storage_entry(2, true)
                },
                maps_entry,
                sampler_entry,
                depths_entry,
            ],
        });
        let shadow_cam_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("light camera"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: true,
                        min_binding_size: wgpu::BufferSize::new(64),
                    },
                    count: None,
                },
                // The materials, for the cut-out casters' alpha.
                wgpu::BindGroupLayoutEntry {
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ..compute_storage_entry(1, true)
                },
            ],
        });

        let gbuffer_texture =
            |binding| unfiltered_texture_entry(binding, wgpu::ShaderStages::COMPUTE);
        let gbuffer_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("g-buffer and frame"),
            entries: &[
                gbuffer_texture(0),
                gbuffer_texture(1),
                gbuffer_texture(3),
                gbuffer_texture(4),
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: COLOR_FORMAT,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                    count: None,
                },
            ],
        });

        let shade_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shade.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADE_WGSL.into()),
        });
        let shadow_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shadow.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADOW_WGSL.into()),
        });
        let gbuffer_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("g-buffer"),
            bind_group_layouts: &[Some(&shade_layout), None, Some(&surface_textures.layout)],
            immediate_size: 0,
        });
        let shade_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shade"),
            bind_group_layouts: &[Some(&shade_layout), Some(&gbuffer_layout)],
            immediate_size: 0,
        });
        let shadow_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shadow"),
            bind_group_layouts: &[Some(&shadow_cam_layout)],
            immediate_size: 0,
        });
        let shadow_attrs = wgpu::vertex_attr_array![0 => Float32x3];
        let gbuffer_pipeline = depth_tested_pipeline(
            device,
            "g-buffer",
            &gbuffer_pl,
            &shade_module,
            ("vs_main", &SURFACE_ATTRIBUTES),
            wgpu::DepthBiasState::default(),
            Some(if layered_gbuffer {
                ("fs_gbuffer_layered", &GBUFFER_FORMATS[..])
            } else {
                ("fs_gbuffer", &GBUFFER_FORMATS[..GBUFFER_TARGETS - 1])
            }),
            None,
        );
        let blended_pipeline = (groups.blended_start < scene.caster_indices).then(|| {
            depth_tested_pipeline(
                device,
                "blended",
                &gbuffer_pl,
                &shade_module,
                ("vs_main", &SURFACE_ATTRIBUTES),
                wgpu::DepthBiasState::default(),
                Some(("fs_blended", &[COLOR_FORMAT])),
                Some(wgpu::BlendState::PREMULTIPLIED_ALPHA_BLENDING),
            )
        });
        let shade_pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("shade"),
            layout: Some(&shade_pl),
            module: &shade_module,
            entry_point: Some("cs_shade"),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants: &[("LAYERED_GBUFFER", f64::from(u8::from(layered_gbuffer)))],
                ..Default::default()
            },
            cache: None,
        });
        let shadow_bias = wgpu::DepthBiasState {
            constant: 2,
            slope_scale: 1.5,
            clamp: 0.0,
        };
        let shadow_pipeline = depth_tested_pipeline(
            device,
            "shadow",
            &shadow_pl,
            &shadow_module,
            ("vs_main", &shadow_attrs),
            shadow_bias,
            None,
            None,
        );
        // The cut-out casters: the same maps, with the materials and their textures, and a
        // fragment stage that discards where the alpha is below the cutoff (no colour target).
        let masked_shadow_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("masked shadow"),
            bind_group_layouts: &[
                Some(&shadow_cam_layout),
                None,
                Some(&surface_textures.layout),
            ],
            immediate_size: 0,
        });
        let masked_shadow_pipeline = depth_tested_pipeline(
            device,
            "masked shadow",
            &masked_shadow_pl,
            &shadow_module,
            ("vs_masked", &MASKED_SHADOW_ATTRIBUTES),
            shadow_bias,
            Some(("fs_masked", &[])),
            None,
        );

        let (width, height) = (settings.width * s, settings.height * s);
        let (color_texture, color_view, depth_view) = Self::make_targets(device, width, height);
        let gbuffer_views = Self::make_gbuffer(device, width, height, layered_gbuffer);
        let (out_width, out_height) = (settings.width, settings.height);
        let post_pass = if s > 1 {
            Some(supersample::resolve(
                device,
                &color_view,
                out_width,
                out_height,
            ))
        } else if settings.fxaa {
            Some(post::fxaa(device, &color_view, out_width, out_height))
        } else {
            None
        };
        let gbuffer_bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("g-buffer and frame"),
            layout: &gbuffer_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[0]),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[1]),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&color_view),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[2]),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[3]),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[4]),
                },
            ],
        });
        let padded_row = (settings.width * 16).div_ceil(256) * 256;
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded_row) * u64::from(settings.height),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let timestamps = gpu.timestamps.then(|| Timestamps {
            set: device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("frame timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: TIMESTAMPS,
            }),
            resolve: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: 8 * u64::from(TIMESTAMPS),
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            read: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp read"),
                size: 8 * u64::from(TIMESTAMPS),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            period_ns: gpu.queue.get_timestamp_period(),
        });
        // The compute rasteriser and its depth buffer, or a placeholder for binding 5.
        let compute_shadows = (settings.shadow_raster == ShadowRaster::Compute).then(|| {
            ComputeShadows::new(
                device,
                &scene,
                (&vertex_buffer, &index_buffer, &material_buffer),
                &surface_textures,
                settings.shadow_resolution,
            )
        });
        let no_shadow_depths = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("no compute shadow maps"),
            size: 4,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let shade_bind_group = Self::make_shade_bind_group(
            device,
            &shade_layout,
            &globals_buffer,
            &light_buffer,
            &material_buffer,
            &shadow.array_view,
            &shadow_sampler,
            compute_shadows
                .as_ref()
                .map_or(&no_shadow_depths, ComputeShadows::depths),
        );
        let shadow_cam_bind_group = Self::make_cam_bind_group(
            device,
            &shadow_cam_layout,
            &light_cam_buffer,
            &material_buffer,
        );
        let facing = shadow::facing_normals(&scene);
        if let Some(error) = gpu.take_error() {
            return Err(RenderError::Gpu(format!(
                "{error} (a smaller --size or --shadow-res needs less GPU memory)"
            )));
        }
        Ok(Self {
            gpu,
            scene,
            settings,
            facing,
            vertex_buffer,
            index_buffer,
            material_buffer,
            globals_buffer,
            light_buffer,
            light_capacity,
            light_cam_buffer,
            light_cam_stride,
            light_cam_capacity,
            shadow,
            shadow_sampler,
            shade_layout,
            shadow_cam_layout,
            shade_bind_group,
            shadow_cam_bind_group,
            gbuffer_bind_group,
            gbuffer_pipeline,
            shade_pipeline,
            shadow_pipeline,
            masked_shadow_pipeline,
            groups,
            blended_pipeline,
            color_view,
            color_texture,
            post_pass,
            depth_view,
            gbuffer_views,
            layered_gbuffer,
            surface_textures,
            readback,
            padded_row,
            timestamps,
            warned_layers: false,
            asg_pass: None,
            compute_shadows,
            no_shadow_depths,
            shadow_bindings_generation: 0,
        })
    }

    fn make_light_buffer(device: &wgpu::Device, capacity: usize) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lights"),
            size: (capacity.max(1) * std::mem::size_of::<shading::LightRaw>()) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    fn make_light_cam_buffer(device: &wgpu::Device, stride: u64, capacity: usize) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("light cameras"),
            size: stride * capacity.max(1) as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    fn make_shadow_array(device: &wgpu::Device, resolution: u32, layers: u32) -> ShadowArray {
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow maps"),
            size: wgpu::Extent3d {
                width: resolution,
                height: resolution,
                depth_or_array_layers: layers,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let layer_views = (0..layers)
            .map(|i| {
                texture.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("shadow layer"),
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: i,
                    array_layer_count: Some(1),
                    ..Default::default()
                })
            })
            .collect();
        let array_view = texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some("shadow array"),
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        ShadowArray {
            _texture: texture,
            layer_views,
            array_view,
            layers,
        }
    }

    /// The G-buffer's targets ([`GBUFFER_FORMATS`]): world position + material, normal +
    /// roughness, base colour + metallic, emission + occlusion, the layers over the base (1 × 1
    /// unless `layered`).
    fn make_gbuffer(
        device: &wgpu::Device,
        width: u32,
        height: u32,
        layered: bool,
    ) -> [wgpu::TextureView; GBUFFER_TARGETS] {
        let labels = [
            "g-buffer position",
            "g-buffer normal",
            "g-buffer surface",
            "g-buffer emission",
            "g-buffer layers",
        ];
        std::array::from_fn(|i| {
            let (label, format) = (labels[i], GBUFFER_FORMATS[i]);
            let (width, height) = if i + 1 < GBUFFER_TARGETS || layered {
                (width, height)
            } else {
                (1, 1)
            };
            let usage =
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
            texture_2d(device, label, (width, height), format, usage)
                .create_view(&Default::default())
        })
    }

    fn make_targets(
        device: &wgpu::Device,
        width: u32,
        height: u32,
    ) -> (wgpu::Texture, wgpu::TextureView, wgpu::TextureView) {
        let color = texture_2d(
            device,
            "color",
            (width, height),
            COLOR_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::STORAGE_BINDING,
        );
        let depth = texture_2d(
            device,
            "depth",
            (width, height),
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let cv = color.create_view(&Default::default());
        let dv = depth.create_view(&Default::default());
        (color, cv, dv)
    }

    #[allow(clippy::too_many_arguments)]
    fn make_shade_bind_group(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        globals: &wgpu::Buffer,
        lights: &wgpu::Buffer,
        materials: &wgpu::Buffer,
        shadow_view: &wgpu::TextureView,
        sampler: &wgpu::Sampler,
        shadow_depths: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let [lights, maps, sampler, depths] =
            SHADE_SHADOW_BINDINGS.bind_entries(lights, shadow_view, sampler, shadow_depths);
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("shade"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: globals.as_entire_binding(),
                },
                lights,
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: materials.as_entire_binding(),
                },
                maps,
                sampler,
                depths,
            ],
        })
    }

    fn make_cam_bind_group(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        buffer: &wgpu::Buffer,
        materials: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("light camera"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer,
                        offset: 0,
                        size: wgpu::BufferSize::new(64),
                    }),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: materials.as_entire_binding(),
                },
            ],
        })
    }

    /// The adapter, for reports.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    pub fn settings(&self) -> &RenderSettings {
        &self.settings
    }

    /// The HDR output image (`Rgba32Float`, `settings().width` × `height`; resolved from the
    /// samples with supersampling, anti-aliased with FXAA), for passes that read the frame.
    pub fn color_view(&self) -> &wgpu::TextureView {
        self.post_pass
            .as_ref()
            .map_or(&self.color_view, |p| &p.view)
    }

    /// The texture behind [`Self::color_view`].
    fn output_texture(&self) -> &wgpu::Texture {
        self.post_pass
            .as_ref()
            .map_or(&self.color_texture, |p| &p.texture)
    }

    /// Encodes the pass after the shading (resolve or FXAA), where there is one, writing
    /// `frame_end`.
    fn encode_post_pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        frame_end: Option<(&Timestamps, u32)>,
    ) {
        if let Some(pass) = &self.post_pass {
            pass.encode(
                enc,
                frame_end.map(|(t, end)| wgpu::ComputePassTimestampWrites {
                    query_set: &t.set,
                    beginning_of_pass_write_index: None,
                    end_of_pass_write_index: Some(end),
                }),
            );
        }
    }

    /// Turns culling on or off for the next frames.
    pub fn set_culling(&mut self, on: bool) {
        self.settings.culling = on;
    }

    /// The camera's view-projection for this image's aspect ratio.
    pub fn view_proj(&self) -> Mat4 {
        let (near, far) = self.clip_planes();
        self.scene.camera.view_proj(
            self.settings.width as f32 / self.settings.height as f32,
            near,
            far,
        )
    }

    fn clip_planes(&self) -> (f32, f32) {
        let b = self.scene.bounds;
        let d = self.scene.camera.eye.distance(b.center);
        let far = (d + b.radius) * 8.0 + 10.0;
        let near = (far * 1e-4).max(1e-3);
        (near, far)
    }

    /// Writes the frame's lights and shadow cameras; returns the GPU lights and the number of
    /// shadow maps.
    fn prepare(&mut self, lights: &[Light]) -> Result<(Vec<GpuLight>, usize), RenderError> {
        let device = &self.gpu.device;
        let mut gpu_lights: Vec<GpuLight> =
            lights.iter().filter_map(GpuLight::from_light).collect();
        let res = self.settings.shadow_resolution;
        let bounds = self.scene.bounds;
        // Shadow maps: one layer each, at most as many as the adapter's texture arrays allow
        // (render passes) or its largest storage buffer holds (compute).
        let (max_maps, limit) = match &self.compute_shadows {
            Some(compute) => (
                compute.map_limit(),
                "what the adapter's largest storage buffer holds",
            ),
            None => (
                self.gpu.max_array_layers,
                "the adapter's texture-array layer limit",
            ),
        };
        let mut mapped: Vec<usize> = Vec::new();
        let mut skipped = 0usize;
        if self.settings.shadows {
            for (i, l) in gpu_lights.iter().enumerate() {
                if !shadow::reaches_visible(&self.facing, l.dir) {
                    continue;
                }
                if mapped.len() as u32 >= max_maps {
                    skipped += 1;
                    continue;
                }
                mapped.push(i);
            }
        }
        let maps = mapped.len() as u32;
        if skipped > 0 && !self.warned_layers {
            tracing::warn!(
                "{skipped} lights drawn without shadows: at most {max_maps} shadow maps \
                 ({limit})"
            );
            self.warned_layers = true;
        }
        let mut rebind = false;
        if gpu_lights.len() > self.light_capacity {
            // The adapter binds a storage buffer of at most so many bytes: a frame of more
            // lights is an error that says so (it was a validation error about "buffer binding
            // 1", after the frame had been drawn; found by an audit).
            let light_bytes = std::mem::size_of::<shading::LightRaw>() as u64;
            let most = device.limits().max_storage_buffer_binding_size / light_bytes;
            if gpu_lights.len() as u64 > most {
                return Err(RenderError::Settings(format!(
                    "a frame of {} lights is more than this adapter can shade in one pass \
                     (its storage buffers hold at most {most} lights); give fewer lights",
                    gpu_lights.len()
                )));
            }
            self.light_capacity = gpu_lights.len().next_power_of_two().min(most as usize);
            self.light_buffer = Self::make_light_buffer(device, self.light_capacity);
            rebind = true;
        }
        for (k, &i) in mapped.iter().enumerate() {
            let l = &mut gpu_lights[i];
            l.layer = Some(k as u32);
            l.view_proj = shadow::light_view_proj(l.dir, bounds);
            l.pcf_radius = shadow::pcf_radius_uv(l.solid_angle, res);
        }
        let cameras = mapped.iter().map(|&i| gpu_lights[i].view_proj);
        rebind |= match self.compute_shadows.as_mut() {
            Some(compute) => compute.prepare(&self.gpu, cameras),
            None => self.prepare_shadow_passes(cameras),
        };
        let device = &self.gpu.device;
        if rebind {
            self.shade_bind_group = Self::make_shade_bind_group(
                device,
                &self.shade_layout,
                &self.globals_buffer,
                &self.light_buffer,
                &self.material_buffer,
                &self.shadow.array_view,
                &self.shadow_sampler,
                self.shadow_depths(),
            );
            self.shadow_bindings_generation += 1;
        }
        let raw: Vec<shading::LightRaw> = gpu_lights.iter().map(GpuLight::to_raw).collect();
        if !raw.is_empty() {
            self.gpu
                .queue
                .write_buffer(&self.light_buffer, 0, bytemuck::cast_slice(&raw));
        }
        let globals = self.frame_globals(gpu_lights.len() as u32);
        self.gpu.queue.write_buffer(
            &self.globals_buffer,
            0,
            bytemuck::bytes_of(&globals.to_raw()),
        );
        self.check_gpu()?;
        Ok((gpu_lights, maps as usize))
    }

    /// The compute rasteriser's depth buffer, or the placeholder bound in its place.
    fn shadow_depths(&self) -> &wgpu::Buffer {
        self.compute_shadows
            .as_ref()
            .map_or(&self.no_shadow_depths, ComputeShadows::depths)
    }

    /// The light pass's constants for a frame of `light_count` lights (the shadow lookup's
    /// offsets follow the map side and the casters' bounds).
    fn frame_globals(&self, light_count: u32) -> Globals {
        let res = self.settings.shadow_resolution;
        let texel_world = 2.0 * self.scene.bounds.radius / res as f32;
        Globals {
            view_proj: self.view_proj(),
            viewer: self.scene.camera.viewer(),
            light_count,
            culling: self.settings.culling,
            shadows: self.settings.shadows,
            shadow_raster: self.settings.shadow_raster,
            shadow_resolution: res,
            normal_offset: 2.0 * texel_world,
            depth_bias: 1.0 / res as f32,
        }
    }

    /// The render passes' part of [`Self::prepare`]: grows the depth array and the light-camera
    /// buffer to hold the frame's maps and writes their cameras (map k's at the k-th dynamic
    /// offset); returns whether the array was replaced (the shading pass must bind the new one).
    fn prepare_shadow_passes(&mut self, cameras: impl ExactSizeIterator<Item = Mat4>) -> bool {
        let device = &self.gpu.device;
        let maps = cameras.len();
        let mut grown = false;
        if maps as u32 > self.shadow.layers {
            let layers = (maps as u32)
                .next_power_of_two()
                .min(self.gpu.max_array_layers);
            self.shadow = Self::make_shadow_array(device, self.settings.shadow_resolution, layers);
            grown = true;
        }
        if maps > self.light_cam_capacity {
            self.light_cam_capacity = maps.next_power_of_two();
            self.light_cam_buffer =
                Self::make_light_cam_buffer(device, self.light_cam_stride, self.light_cam_capacity);
            self.shadow_cam_bind_group = Self::make_cam_bind_group(
                device,
                &self.shadow_cam_layout,
                &self.light_cam_buffer,
                &self.material_buffer,
            );
        }
        if maps > 0 {
            let stride = self.light_cam_stride as usize;
            let mut cams = vec![0u8; stride * maps];
            for (k, m) in cameras.enumerate() {
                let at = stride * k;
                cams[at..at + 64].copy_from_slice(bytemuck::cast_slice(&m.to_cols_array()));
            }
            self.gpu
                .queue
                .write_buffer(&self.light_cam_buffer, 0, &cams);
        }
        grown
    }

    /// Fails with the first error the device reported (an allocation it could not make, such
    /// as shadow maps of a huge --shadow-res or targets of a huge --size) instead of rendering
    /// with the resource missing.
    fn check_gpu(&self) -> Result<(), RenderError> {
        match self.gpu.take_error() {
            Some(error) => Err(RenderError::Gpu(format!(
                "{error} (a smaller --size or --shadow-res needs less GPU memory)"
            ))),
            None => Ok(()),
        }
    }

    fn encode(&self, maps: usize, readback: bool) -> wgpu::CommandEncoder {
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        let ts = self.timestamps.as_ref();
        self.encode_shadow_maps(&mut enc, maps);
        self.encode_gbuffer_pass(&mut enc);
        // The frame's end, written by its last pass: the resolve or FXAA where there is one,
        // else the blended surfaces' where there are any, else the shading.
        let frame_end = ts.map(|t| (t, 2));
        let (shade_end, blended_end, post_end) = match (&self.blended_pipeline, &self.post_pass) {
            (_, Some(_)) => (None, None, frame_end),
            (Some(_), None) => (None, frame_end, None),
            (None, None) => (frame_end, None, None),
        };
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("shade"),
                timestamp_writes: shade_end.map(|(t, end)| wgpu::ComputePassTimestampWrites {
                    query_set: &t.set,
                    beginning_of_pass_write_index: None,
                    end_of_pass_write_index: Some(end),
                }),
            });
            pass.set_pipeline(&self.shade_pipeline);
            pass.set_bind_group(0, &self.shade_bind_group, &[]);
            pass.set_bind_group(1, &self.gbuffer_bind_group, &[]);
            let s = self.settings.supersample;
            pass.dispatch_workgroups(
                (self.settings.width * s).div_ceil(SHADE_WORKGROUP),
                (self.settings.height * s).div_ceil(SHADE_WORKGROUP),
                1,
            );
        }
        if let Some(pipeline) = &self.blended_pipeline {
            self.encode_blended_pass(&mut enc, pipeline, blended_end);
        }
        self.encode_post_pass(&mut enc, post_end);
        if let Some(t) = ts {
            enc.resolve_query_set(&t.set, 0..TIMESTAMPS, &t.resolve, 0);
            enc.copy_buffer_to_buffer(&t.resolve, 0, &t.read, 0, 8 * u64::from(TIMESTAMPS));
        }
        if readback {
            self.encode_readback(&mut enc);
        }
        enc
    }

    /// One depth-only render pass per map into its layer of the depth array (the GPU timestamp
    /// of the frame's start at the first).
    /// The frame's `maps` shadow maps, by the compute rasteriser or by render passes (the
    /// frame's start timestamp at the first).
    fn encode_shadow_maps(&self, enc: &mut wgpu::CommandEncoder, maps: usize) {
        match &self.compute_shadows {
            Some(compute) if maps > 0 => compute.encode(
                enc,
                maps as u32,
                self.timestamps
                    .as_ref()
                    .map(|t| wgpu::ComputePassTimestampWrites {
                        query_set: &t.set,
                        beginning_of_pass_write_index: Some(0),
                        end_of_pass_write_index: None,
                    }),
            ),
            Some(_) => {}
            None => self.encode_shadow_passes(enc, maps),
        }
    }

    fn encode_shadow_passes(&self, enc: &mut wgpu::CommandEncoder, maps: usize) {
        let ts = self.timestamps.as_ref();
        for layer in 0..maps {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.shadow.layer_views[layer],
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: ts.filter(|_| layer == 0).map(|t| {
                    wgpu::RenderPassTimestampWrites {
                        query_set: &t.set,
                        beginning_of_pass_write_index: Some(0),
                        end_of_pass_write_index: None,
                    }
                }),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.shadow_pipeline);
            pass.set_bind_group(
                0,
                &self.shadow_cam_bind_group,
                &[(layer as u64 * self.light_cam_stride) as u32],
            );
            pass.set_vertex_buffer(0, self.vertex_buffer.slice(..));
            pass.set_index_buffer(self.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..self.groups.cutout_start, 0, 0..1);
            if self.groups.cutout_start < self.scene.caster_indices {
                pass.set_pipeline(&self.masked_shadow_pipeline);
                pass.set_bind_group(2, &self.surface_textures.bind_group, &[]);
                pass.draw_indexed(self.groups.cutout_start..self.scene.caster_indices, 0, 0..1);
            }
        }
    }

    /// Draws the blended surfaces over the shaded frame (`fs_blended`, back to front as
    /// [`order_triangles`] sorted them), depth-tested against the G-buffer pass's depth;
    /// `frame_end`: the timestamp to write at its end.
    fn encode_blended_pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::RenderPipeline,
        frame_end: Option<(&Timestamps, u32)>,
    ) {
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("blended"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &self.color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: frame_end.map(|(t, end)| wgpu::RenderPassTimestampWrites {
                query_set: &t.set,
                beginning_of_pass_write_index: None,
                end_of_pass_write_index: Some(end),
            }),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &self.shade_bind_group, &[]);
        pass.set_bind_group(2, &self.surface_textures.bind_group, &[]);
        pass.set_vertex_buffer(0, self.vertex_buffer.slice(..));
        pass.set_index_buffer(self.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
        pass.draw_indexed(
            self.groups.blended_start..self.scene.caster_indices,
            0,
            0..1,
        );
    }

    /// Rasterises the scene into the G-buffer (cleared to zero: no surface), all but the
    /// blended surfaces; their pass reads its depth afterwards.
    fn encode_gbuffer_pass(&self, enc: &mut wgpu::CommandEncoder) {
        let timestamps = self
            .timestamps
            .as_ref()
            .map(|t| wgpu::RenderPassTimestampWrites {
                query_set: &t.set,
                beginning_of_pass_write_index: Some(1),
                end_of_pass_write_index: None,
            });
        self.encode_scene_pass(
            enc,
            "g-buffer",
            &self.gbuffer_views.each_ref()[..if self.layered_gbuffer {
                GBUFFER_TARGETS
            } else {
                GBUFFER_TARGETS - 1
            }],
            &self.gbuffer_pipeline,
            &self.shade_bind_group,
            timestamps,
            None,
        );
    }

    /// Draws the scene but its blended surfaces with `pipeline` and `bind_group` into
    /// `targets` (cleared to transparent) over a fresh depth buffer, then the blended ones with
    /// `blended` where given: the G-buffer pass (whose depth is kept for the blended pass where
    /// the scene has blended surfaces), and the ASG pass into the colour target.
    #[allow(clippy::too_many_arguments)]
    fn encode_scene_pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        label: &str,
        targets: &[&wgpu::TextureView],
        pipeline: &wgpu::RenderPipeline,
        bind_group: &wgpu::BindGroup,
        timestamp_writes: Option<wgpu::RenderPassTimestampWrites<'_>>,
        blended: Option<&wgpu::RenderPipeline>,
    ) {
        let color_attachments: Vec<_> = targets
            .iter()
            .map(|view| {
                Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })
            })
            .collect();
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some(label),
            color_attachments: &color_attachments,
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: if self.blended_pipeline.is_some() {
                        wgpu::StoreOp::Store
                    } else {
                        wgpu::StoreOp::Discard
                    },
                }),
                stencil_ops: None,
            }),
            timestamp_writes,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        pass.set_bind_group(2, &self.surface_textures.bind_group, &[]);
        pass.set_vertex_buffer(0, self.vertex_buffer.slice(..));
        pass.set_index_buffer(self.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
        let blended_range = self.groups.blended_start..self.scene.caster_indices;
        pass.draw_indexed(0..blended_range.start, 0, 0..1);
        pass.draw_indexed(blended_range.end..self.scene.indices.len() as u32, 0, 0..1);
        if let Some(pipeline) = blended.filter(|_| !blended_range.is_empty()) {
            pass.set_pipeline(pipeline);
            pass.draw_indexed(blended_range, 0, 0..1);
        }
    }

    /// Copies the output image into the read-back buffer.
    fn encode_readback(&self, enc: &mut wgpu::CommandEncoder) {
        {
            enc.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: self.output_texture(),
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &self.readback,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(self.padded_row),
                        rows_per_image: Some(self.settings.height),
                    },
                },
                wgpu::Extent3d {
                    width: self.settings.width,
                    height: self.settings.height,
                    depth_or_array_layers: 1,
                },
            );
        }
    }

    fn wait(&self) -> Result<(), RenderError> {
        self.gpu
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| RenderError::Gpu(e.to_string()))
    }

    /// Maps `buffer`, waits, and hands its bytes to `f`.
    fn read_buffer<T>(
        &self,
        buffer: &wgpu::Buffer,
        f: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, RenderError> {
        let slice = buffer.slice(..);
        let (tx, rx) = crossbeam_channel::bounded(1);
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|e| RenderError::Gpu(format!("buffer map callback lost: {e}")))?
            .map_err(|e| RenderError::Gpu(format!("cannot map a buffer: {e}")))?;
        let out = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| RenderError::Gpu(format!("cannot read a mapped buffer: {e:?}")))?;
            f(&view)
        };
        buffer.unmap();
        Ok(out)
    }

    /// GPU time of the last frame and of its shadow passes (`None` without timestamps, or
    /// for the shadows without `shadow_passes`), in ms.
    fn gpu_time(&self, shadow_passes: bool) -> Result<(Option<f64>, Option<f64>), RenderError> {
        let Some(t) = &self.timestamps else {
            return Ok((None, None));
        };
        let [shadows, shading, end] = self.read_buffer(&t.read, |b| {
            let v: &[u64] = bytemuck::cast_slice(b);
            [v[0], v[1], v[2]]
        })?;
        let ms = |from: u64, to: u64| {
            (to >= from).then(|| (to - from) as f64 * f64::from(t.period_ns) * 1e-6)
        };
        Ok(if shadow_passes {
            (ms(shadows, end), ms(shadows, shading))
        } else {
            (ms(shading, end), None)
        })
    }

    /// Renders one frame and waits for it, without reading the image back (benchmarks,
    /// display-less budget runs).
    pub fn render_timed(&mut self, lights: &[Light]) -> Result<FrameStats, RenderError> {
        let start = Instant::now();
        let (gl, maps) = self.prepare(lights)?;
        let cmd = self.encode(maps, false).finish();
        self.gpu.queue.submit([cmd]);
        self.wait()?;
        let cpu_ms = start.elapsed().as_secs_f64() * 1e3;
        let (gpu_ms, shadow_gpu_ms) = self.gpu_time(maps > 0)?;
        Ok(FrameStats {
            lights: gl.len(),
            shadow_maps: maps,
            gpu_ms,
            shadow_gpu_ms,
            cpu_ms,
        })
    }

    /// Renders one frame, lets `then` encode more work that reads the frame (the HDR colour
    /// view, `Rgba32Float`) into the same submission, and waits for it (the windowed mode's
    /// present pass).
    pub fn render_then(
        &mut self,
        lights: &[Light],
        then: impl FnOnce(&wgpu::Device, &mut wgpu::CommandEncoder, &wgpu::TextureView),
    ) -> Result<FrameStats, RenderError> {
        let start = Instant::now();
        let (gl, maps) = self.prepare(lights)?;
        let mut enc = self.encode(maps, false);
        then(&self.gpu.device, &mut enc, self.color_view());
        self.gpu.queue.submit([enc.finish()]);
        self.wait()?;
        let cpu_ms = start.elapsed().as_secs_f64() * 1e3;
        let (gpu_ms, shadow_gpu_ms) = self.gpu_time(maps > 0)?;
        Ok(FrameStats {
            lights: gl.len(),
            shadow_maps: maps,
            gpu_ms,
            shadow_gpu_ms,
            cpu_ms,
        })
    }

    /// Renders one frame and reads the image back.
    pub fn render(&mut self, lights: &[Light]) -> Result<(Image, FrameStats), RenderError> {
        let start = Instant::now();
        let (gl, maps) = self.prepare(lights)?;
        let cmd = self.encode(maps, true).finish();
        self.gpu.queue.submit([cmd]);
        self.wait()?;
        let cpu_ms = start.elapsed().as_secs_f64() * 1e3;
        let image = self.read_image()?;
        let (gpu_ms, shadow_gpu_ms) = self.gpu_time(maps > 0)?;
        let stats = FrameStats {
            lights: gl.len(),
            shadow_maps: maps,
            gpu_ms,
            shadow_gpu_ms,
            cpu_ms,
        };
        Ok((image, stats))
    }

    /// Reads the rendered image from the read-back buffer (after a frame encoded with it).
    fn read_image(&self) -> Result<Image, RenderError> {
        let (w, h) = (self.settings.width as usize, self.settings.height as usize);
        let row = self.padded_row as usize;
        let rgba = self.read_buffer(&self.readback, |bytes| {
            let mut out = Vec::with_capacity(w * h * 4);
            for y in 0..h {
                let line = &bytes[y * row..y * row + w * 16];
                out.extend(
                    line.chunks_exact(4)
                        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                );
            }
            out
        })?;
        Ok(Image {
            width: self.settings.width,
            height: self.settings.height,
            rgba,
        })
    }

    /// World-space direction of the camera ray through the centre of pixel (x, y): from the
    /// eye for a perspective camera, the view direction for an orthographic one.
    pub fn pixel_ray(&self, x: f32, y: f32) -> Vec3 {
        let inv = self.view_proj().inverse();
        let ndc_x = (x + 0.5) / self.settings.width as f32 * 2.0 - 1.0;
        let ndc_y = 1.0 - (y + 0.5) / self.settings.height as f32 * 2.0;
        let p = inv.project_point3(Vec3::new(ndc_x, ndc_y, 0.5));
        -self.scene.camera.toward_viewer(p)
    }
}

/// The first `count` lights of the progressive set (sorted by id), carrying the whole frame's
/// power: each light past the prefix is merged into the prefix light nearest to it in
/// direction — its rgb and solid angle added, the merged light's direction the
/// luminance-weighted mean of its group's (its own if the group is black). Each light carries
/// only its own region's power, so a truncated list darkened the image in proportion to what
/// it dropped (a frame-time budget that kept 16 of 64 lights under a uniform sky rendered it at
/// 0.22 of its brightness), and a sun among the dropped lights went missing.
///
/// The nearest prefix light is found in a uniform grid over the unit cube (`DirectionGrid`).
/// Measured (one core, Fibonacci-sphere directions, ids a random permutation, as spread as a
/// progressive prefix): 1024 lights to 512 in 0.16 ms, 4096 to 2048 in 1.0 ms, 16384 to 8192 in
/// 5.2 ms, against 0.60, 9.5 and 149 ms by brute force; ids in the order of the directions (a
/// prefix that is one polar cap, which no decomposition gives) 0.87, 12 and 239 ms.
pub fn light_prefix(lights: &[Light], count: usize) -> Vec<Light> {
    let mut v = lights.to_vec();
    v.sort_by_key(|l| l.id);
    if count >= v.len() || count == 0 {
        v.truncate(count);
        return v;
    }
    let dropped = v.split_off(count);
    let dir = |l: &Light| Vec3::from_array(l.dir);
    // Per kept light: the luminance-weighted sum of its group's directions, in f64.
    let mut weighted: Vec<glam::DVec3> = v
        .iter()
        .map(|l| dir(l).as_dvec3() * f64::from(l.luminance().max(0.0)))
        .collect();
    let mut rgb: Vec<[f64; 3]> = v.iter().map(|l| l.rgb.map(f64::from)).collect();
    let mut solid_angle: Vec<f64> = v.iter().map(|l| f64::from(l.solid_angle)).collect();
    let grid = DirectionGrid::new(v.iter().map(dir).collect());
    for d in &dropped {
        let to = dir(d);
        let nearest = grid.nearest(to);
        weighted[nearest] += to.as_dvec3() * f64::from(d.luminance().max(0.0));
        for (sum, c) in rgb[nearest].iter_mut().zip(d.rgb) {
            *sum += f64::from(c);
        }
        solid_angle[nearest] += f64::from(d.solid_angle);
    }
    for (i, light) in v.iter_mut().enumerate() {
        if let Some(mean) = weighted[i].try_normalize() {
            light.dir = mean.as_vec3().to_array();
        }
        light.rgb = rgb[i].map(|c| c.min(f64::from(f32::MAX)) as f32);
        light.solid_angle = solid_angle[i] as f32;
    }
    v
}

/// Nearest-point queries among unit vectors (a light prefix's directions): the points are
/// binned in a uniform grid over [-1, 1]³ whose cell side is about their spacing on the sphere
/// (√(4π/n)); a query searches shells of cells around its own, nearest first, and stops once
/// the next shell can hold nothing nearer than the best point found (every point of shell
/// s + 1 is at least s cell sides away). Exact: on unit vectors the nearest point in space is
/// the one of largest dot product.
struct DirectionGrid {
    points: Vec<Vec3>,
    side: f32,
    cells: usize,
    /// Points by cell: those of cell c are `order[start[c]..start[c + 1]]`.
    start: Vec<usize>,
    order: Vec<usize>,
}

impl DirectionGrid {
    fn new(points: Vec<Vec3>) -> Self {
        let n = points.len().max(1);
        let cells =
            ((2.0 / (4.0 * std::f32::consts::PI / n as f32).sqrt()).ceil() as usize).clamp(1, 128);
        let side = 2.0 / cells as f32;
        let mut grid = DirectionGrid {
            points,
            side,
            cells,
            start: vec![0; cells * cells * cells + 1],
            order: Vec::new(),
        };
        let index: Vec<usize> = grid.points.iter().map(|&p| grid.cell_index(p)).collect();
        let mut most = 0;
        for &c in &index {
            grid.start[c + 1] += 1;
            most = most.max(grid.start[c + 1]);
        }
        for c in 0..grid.cells.pow(3) {
            grid.start[c + 1] += grid.start[c];
        }
        let mut next = grid.start.clone();
        grid.order = vec![0; grid.points.len()];
        for (i, &c) in index.iter().enumerate() {
            grid.order[next[c]] = i;
            next[c] += 1;
        }
        if most > DirectionGrid::CROWDED {
            grid.drop_repeated_points();
        }
        grid
    }

    /// Points in a cell past which [`DirectionGrid::drop_repeated_points`] runs.
    const CROWDED: usize = 32;

    /// A point at the very place of a lower-indexed one is never the answer (ties go to the
    /// lower index): in a crowded cell (more than [`DirectionGrid::CROWDED`] points; the
    /// caller knows from binning whether there is one) such points are left out. A light file
    /// of 900,000 lights in one direction put them all in one cell, which every query then
    /// scanned (33 s a frame; found by an audit). Cells of a spread prefix hold a few points
    /// and are left as they are.
    fn drop_repeated_points(&mut self) {
        let mut start = Vec::with_capacity(self.start.len());
        let mut order = Vec::with_capacity(self.order.len());
        start.push(0);
        for c in 0..self.start.len() - 1 {
            let cell = &self.order[self.start[c]..self.start[c + 1]];
            if cell.len() > Self::CROWDED {
                let bits = |i: usize| self.points[i].to_array().map(f32::to_bits);
                let mut kept: Vec<usize> = cell.to_vec();
                kept.sort_unstable_by_key(|&i| (bits(i), i));
                kept.dedup_by_key(|&mut i| bits(i));
                kept.sort_unstable();
                order.extend(kept);
            } else {
                order.extend_from_slice(cell);
            }
            start.push(order.len());
        }
        (self.start, self.order) = (start, order);
    }

    fn cell(&self, p: Vec3) -> [usize; 3] {
        let at = |x: f32| (((x + 1.0) / self.side) as usize).min(self.cells - 1);
        [at(p.x), at(p.y), at(p.z)]
    }

    fn cell_index(&self, p: Vec3) -> usize {
        let [x, y, z] = self.cell(p);
        (x * self.cells + y) * self.cells + z
    }

    /// The index of the point nearest to `to` (0 if there are none). Points far from the
    /// query (a prefix that is not spread over the sphere, from a light file) would take many
    /// shells of empty cells: past as many cells as there are points, all points are tried.
    fn nearest(&self, to: Vec3) -> usize {
        let home = self.cell(to).map(|c| c as i64);
        let last = self.cells as i64 - 1;
        let (mut best, mut best_d2) = (0, f32::INFINITY);
        let mut visited = 0usize;
        for shell in 0..=last {
            visited += (2 * shell as usize + 1).pow(3);
            if visited > self.points.len() + 27 {
                return (0..self.points.len())
                    .min_by(|&a, &b| {
                        (self.points[a].distance_squared(to))
                            .total_cmp(&self.points[b].distance_squared(to))
                    })
                    .unwrap_or(0);
            }
            for dx in -shell..=shell {
                for dy in -shell..=shell {
                    for dz in -shell..=shell {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != shell {
                            continue;
                        }
                        let [x, y, z] = [home[0] + dx, home[1] + dy, home[2] + dz];
                        if [x, y, z].iter().any(|&c| c < 0 || c > last) {
                            continue;
                        }
                        let c = ((x * (last + 1) + y) * (last + 1) + z) as usize;
                        for &i in &self.order[self.start[c]..self.start[c + 1]] {
                            let d2 = self.points[i].distance_squared(to);
                            if d2 < best_d2 || (d2 == best_d2 && i < best) {
                                (best, best_d2) = (i, d2);
                            }
                        }
                    }
                }
            }
            let reach = shell as f32 * self.side;
            if best_d2 < reach * reach {
                break;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The casters are ordered opaque, masked, then blended back to front from the camera;
    /// the ground stays after them; no triangle is lost or changed.
    #[test]
    fn triangles_are_ordered_opaque_masked_then_blended_back_to_front() {
        use scene::AlphaMode;
        let mut scene = Scene::default_scene();
        scene.materials[0].alpha_mode = AlphaMode::Blend;
        scene.materials[1].alpha_mode = AlphaMode::Mask(0.5);
        let before = scene.clone();
        let groups = order_triangles(&mut scene);
        let triangle_mode =
            |t: &[u32]| scene.materials[scene.vertices[t[0] as usize].material as usize].alpha_mode;
        let casters = scene.caster_indices as usize;
        let (cutout, blended) = (groups.cutout_start as usize, groups.blended_start as usize);
        assert!(
            0 < cutout && cutout < blended && blended < casters,
            "{groups:?}"
        );
        let modes = |range: std::ops::Range<usize>| -> Vec<AlphaMode> {
            scene.indices[range].chunks(3).map(triangle_mode).collect()
        };
        assert!(modes(0..cutout).iter().all(|m| *m == AlphaMode::Opaque));
        assert!(modes(cutout..blended)
            .iter()
            .all(|m| *m == AlphaMode::Mask(0.5)));
        assert!(modes(blended..casters)
            .iter()
            .all(|m| *m == AlphaMode::Blend));
        let distance = |t: &[u32]| {
            let centroid: Vec3 = t
                .iter()
                .map(|&i| Vec3::from(scene.vertices[i as usize].position))
                .sum();
            scene.camera.eye.distance(centroid / 3.0)
        };
        let distances: Vec<f32> = scene.indices[blended..casters]
            .chunks(3)
            .map(distance)
            .collect();
        assert!(
            distances.windows(2).all(|w| w[0] >= w[1]),
            "not back to front"
        );
        assert!(distances[0] > distances[distances.len() - 1]);
        assert_eq!(scene.indices[casters..], before.indices[casters..]);
        let sorted = |indices: &[u32]| {
            let mut t: Vec<&[u32]> = indices.chunks(3).collect();
            t.sort();
            t.concat()
        };
        assert_eq!(sorted(&scene.indices), sorted(&before.indices));
        // Without blended or masked materials nothing moves.
        let mut plain = Scene::default_scene();
        let groups = order_triangles(&mut plain);
        assert_eq!(plain.indices, Scene::default_scene().indices);
        assert_eq!(
            (groups.cutout_start, groups.blended_start),
            (plain.caster_indices, plain.caster_indices)
        );
        // An adapter that cannot blend draws them opaque.
        let mut fallback = before;
        draw_blended_opaque(&mut fallback);
        assert_eq!(fallback.materials[0].alpha_mode, AlphaMode::Opaque);
        assert_eq!(fallback.materials[1].alpha_mode, AlphaMode::Mask(0.5));
    }

    #[test]
    fn every_wgsl_file_parses_and_validates() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "wgsl"))
            .collect();
        files.sort();
        assert!(!files.is_empty());
        for path in &files {
            let name = path.file_name().unwrap().to_str().unwrap();
            let file = std::fs::read_to_string(path).unwrap();
            // Every file on disk is one the renderer loads: a module's entry file is its source
            // or its source after the preludes; the first prelude must stand alone too, the
            // second is validated within the files it precedes.
            let text = if name == "surface.wgsl" {
                assert_eq!(file, SURFACE_WGSL);
                file
            } else if name == "shadow_lookup.wgsl" {
                assert_eq!(file, SHADOW_LOOKUP_WGSL);
                let users = SHADERS
                    .iter()
                    .filter(|(_, text)| text.contains(SHADOW_LOOKUP_WGSL))
                    .count();
                assert_eq!(users, 2, "shade.wgsl and asg.wgsl include it");
                continue;
            } else {
                let (_, text) = SHADERS
                    .iter()
                    .find(|(n, _)| *n == name)
                    .unwrap_or_else(|| panic!("{name} is not in render::SHADERS"));
                assert!(
                    *text == file
                        || *text == format!("{SURFACE_WGSL}{file}")
                        || *text == format!("{SURFACE_WGSL}{SHADOW_LOOKUP_WGSL}{file}"),
                    "{name}: render::SHADERS holds another text"
                );
                text.to_string()
            };
            let module = naga::front::wgsl::parse_str(&text)
                .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&text)));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::empty(),
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&text)));
        }
        // The two preludes are not in SHADERS.
        assert_eq!(files.len(), SHADERS.len() + 2);
    }

    /// The Rust twins of the shaders' structs have the WGSL layouts' sizes (naga's), and the
    /// compute rasteriser steps through the vertex buffer by `Vertex`'s size.
    #[test]
    fn shader_layouts_match_their_rust_twins() {
        use std::mem::size_of;
        let parse = |name: &str| {
            let (_, text) = SHADERS.iter().find(|(n, _)| *n == name).unwrap();
            naga::front::wgsl::parse_str(text).unwrap()
        };
        let struct_size = |module: &naga::Module, name: &str| {
            let mut layouter = naga::proc::Layouter::default();
            layouter.update(module.to_ctx()).unwrap();
            let (handle, _) = module
                .types
                .iter()
                .find(|(_, t)| t.name.as_deref() == Some(name))
                .unwrap_or_else(|| panic!("no struct {name}"));
            layouter[handle].size as usize
        };
        let shade = parse("shade.wgsl");
        assert_eq!(
            struct_size(&shade, "Material"),
            size_of::<shading::MaterialRaw>()
        );
        assert_eq!(struct_size(&shade, "Light"), size_of::<shading::LightRaw>());
        assert_eq!(
            struct_size(&shade, "Globals"),
            size_of::<shading::GlobalsRaw>()
        );
        let asg = parse("asg.wgsl");
        assert_eq!(struct_size(&asg, "Lobe"), size_of::<asg::LobeRaw>());
        assert_eq!(
            struct_size(&asg, "Globals"),
            size_of::<asg::AsgGlobalsRaw>()
        );
        let raster = parse("shadow_raster.wgsl");
        let (_, words) = raster
            .constants
            .iter()
            .find(|(_, c)| c.name.as_deref() == Some("VERTEX_WORDS"))
            .unwrap();
        assert_eq!(
            raster.global_expressions[words.init],
            naga::Expression::Literal(naga::Literal::U32((size_of::<scene::Vertex>() / 4) as u32))
        );
    }

    #[test]
    fn prefix_is_by_id() {
        let l = |id| Light {
            id,
            dir: [0.0, 1.0, 0.0],
            rgb: [1.0; 3],
            solid_angle: 0.1,
        };
        let p = light_prefix(&[l(5), l(1), l(3), l(0)], 3);
        assert_eq!(p.iter().map(|l| l.id).collect::<Vec<_>>(), vec![0, 1, 3]);
    }

    /// The grid finds the nearest direction as a brute-force search does, for prefixes of a
    /// Fibonacci sphere and for random directions.
    #[test]
    fn the_direction_grid_finds_the_nearest_point() {
        let fibonacci = |n: usize| -> Vec<Vec3> {
            (0..n)
                .map(|i| {
                    let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                    let r = (1.0 - y * y).sqrt();
                    let phi = 2.399_963 * i as f32;
                    Vec3::new(r * phi.cos(), y, r * phi.sin())
                })
                .collect()
        };
        let mut seed = 7u64;
        let mut unit = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        for n in [1, 2, 5, 64, 1000] {
            let points = fibonacci(n);
            let grid = DirectionGrid::new(points.clone());
            for _ in 0..500 {
                let Some(q) = Vec3::new(unit(), unit(), unit()).try_normalize() else {
                    continue;
                };
                let brute = (0..n)
                    .min_by(|&a, &b| {
                        points[a]
                            .distance_squared(q)
                            .total_cmp(&points[b].distance_squared(q))
                    })
                    .unwrap();
                let found = grid.nearest(q);
                assert!(
                    points[found].distance_squared(q) <= points[brute].distance_squared(q),
                    "n {n}, query {q}: {found} vs {brute}"
                );
            }
        }
        // Repeated points are binned once (all in one cell, they made every query scan them
        // all); the answer is still the lowest index of the nearest place.
        let places = fibonacci(50);
        let points: Vec<Vec3> = (0..5000).map(|i| places[(i * 7) % 50]).collect();
        let grid = DirectionGrid::new(points.clone());
        assert_eq!(grid.order.len(), 50);
        for _ in 0..500 {
            let Some(q) = Vec3::new(unit(), unit(), unit()).try_normalize() else {
                continue;
            };
            let brute = (0..points.len())
                .min_by(|&a, &b| {
                    points[a]
                        .distance_squared(q)
                        .total_cmp(&points[b].distance_squared(q))
                })
                .unwrap();
            assert_eq!(grid.nearest(q), brute, "query {q}");
        }
    }

    /// A prefix carries the frame's whole power, colour by colour, and its solid angle: each
    /// dropped light joins the nearest kept one, which turns towards it by luminance (the
    /// prefix was a plain truncation: 16 of 64 lights rendered a uniform sky at 0.22 of its
    /// brightness).
    #[test]
    fn a_prefix_keeps_the_power_of_the_lights_it_drops() {
        let light = |id, dir: [f32; 3], rgb| Light {
            id,
            dir: Vec3::from_array(dir).normalize().to_array(),
            rgb,
            solid_angle: 0.5,
        };
        let lights = [
            light(0, [0.0, 1.0, 0.0], [1.0, 1.0, 1.0]),
            light(1, [0.0, -1.0, 0.0], [2.0, 2.0, 2.0]),
            // Near light 0: a bright red sun, dropped.
            light(2, [0.3, 1.0, 0.0], [30.0, 0.0, 0.0]),
            // Near light 1, black.
            light(3, [0.0, -1.0, 0.2], [0.0, 0.0, 0.0]),
        ];
        let p = light_prefix(&lights, 2);
        assert_eq!(p.len(), 2);
        assert_eq!(p[0].rgb, [31.0, 1.0, 1.0]);
        assert_eq!(p[1].rgb, [2.0, 2.0, 2.0]);
        assert_eq!(p[0].solid_angle, 1.0);
        assert_eq!(p[1].solid_angle, 1.0);
        // Light 0 turns most of the way to the sun (luminance 0.2126 × 30 against 1).
        let sun = Vec3::from_array(lights[2].dir);
        let turned = Vec3::from_array(p[0].dir);
        assert!(
            turned.dot(sun) > 0.99 && (turned.length() - 1.0).abs() < 1e-6,
            "{turned}"
        );
        // A black group keeps its light's direction.
        assert_eq!(p[1].dir, lights[1].dir);
        // Every light, or none, as before.
        assert_eq!(light_prefix(&lights, 4).len(), 4);
        assert!(light_prefix(&lights, 0).is_empty());
    }
}
