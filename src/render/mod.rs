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
//!    Lambertian diffuse + GGX specular (metallic-roughness; a sheen, [`sheen`], and a clear
//!    coat over it where the material has them) over the lights, each times its
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
//! **SH lighting** ([`Renderer::render_sh`], module [`sh`], `shaders/sh.wgsl`): the same scene
//! shaded in closed form under spherical-harmonic coefficients (the environment's ambient
//! light): Lambert by the irradiance formula, GGX by a split sum over the prefiltered
//! coefficients; unshadowed.
//!
//! Mixed reality: with [`RenderSettings::shadow_catcher`], the ground outputs (0, 0, 0, α) with
//! α = 1 − E_shadowed/E_unshadowed, so the RGBA image composites over the camera picture (or
//! over the environment map, [`output::composite_background`]).
//!
//! Files: this one holds the renderer's settings, its state and its public frame API;
//! `setup.rs` builds the pipelines, bind groups and targets, `frame.rs` writes a frame's lights
//! and encodes its passes, `prefix.rs` takes a budget's prefix of the lights; the passes'
//! pieces have modules of their own (shadows, shading constants, ASG, SH and what their
//! closed-form passes share, post passes, textures).

pub mod asg;

pub mod budget;

pub mod device;

pub mod output;

pub mod post;

pub mod scene;

pub mod shading;

pub mod sh;

pub mod shadow;

pub mod shadow_raster;

pub mod sheen;

pub mod supersample;

pub mod textures;

#[cfg(feature = "window")]
pub mod window;

mod closed_form;
mod frame;
mod prefix;
mod setup;

pub use prefix::light_prefix;
use setup::{
    depth_tested_pipeline, frame_storage_entry, texture_2d, unfiltered_texture_entry, ShadowArray,
    ShadowLookupBindings, Timestamps, TriangleGroups, GBUFFER_TARGETS, SURFACE_ATTRIBUTES,
};

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
    ("sh.wgsl", sh::SH_WGSL),
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

/// The entry points appended to `asg.wgsl` and `sh.wgsl` (the closed-form lighting passes):
/// the vertex stage and the opaque and blended fragment stages, which call the file's `shaded`.
pub const CLOSED_FORM_WGSL: &str = include_str!("../../shaders/closed_form.wgsl");

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
    /// The CPU's share of `cpu_ms`: preparing the lights, encoding every pass and submitting,
    /// before the wait for the GPU.
    pub encode_ms: f64,
}

impl FrameStats {
    /// The time the budget controller uses: GPU time where measured, else CPU time.
    pub fn frame_ms(&self) -> f64 {
        self.gpu_ms.unwrap_or(self.cpu_ms)
    }
}

/// The renderer: device, pipelines and buffers for one scene and image size.
pub struct Renderer {
    gpu: Gpu,
    scene: Scene,
    settings: RenderSettings,
    facing: Vec<Vec3>,
    /// The facing normals of the vertices no clip moves ([`shadow::still_facing`]).
    still_facing: Option<shadow::FacingSet>,
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
    /// ([`setup::order_triangles`]).
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
    /// The SH lighting pass, built on first use.
    sh_pass: Option<sh::ShPass>,
    /// The compute rasteriser, with [`ShadowRaster::Compute`].
    compute_shadows: Option<ComputeShadows>,
    /// Bound in its place otherwise.
    no_shadow_depths: wgpu::Buffer,
    /// Counts the times [`Self::prepare`] replaced a buffer or texture the shadow lookup binds
    /// (the light buffer, the map array, the compute maps), so that the ASG pass, which binds
    /// them too, rebinds only then.
    shadow_bindings_generation: u64,
}

impl Renderer {
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

    /// Poses an animated scene ([`Scene::animate`]) at `seconds` of its playing clip (looped)
    /// for the next frames: its moved vertices uploaded again, the camera-facing normals that
    /// decide which lights get shadow maps recomputed (from the moved vertices, where the
    /// camera holds still), and its blended triangles sorted back to front again. Nothing
    /// happens for a scene without animations.
    pub fn set_scene_time(&mut self, seconds: f64) {
        if !self.scene.animate(seconds) {
            return;
        }
        let queue = &self.gpu.queue;
        if let Some(animation) = &self.scene.animation {
            for range in animation.moved_runs() {
                let Some(moved) = self.scene.vertices.get(range.clone()) else {
                    continue;
                };
                let offset = range.start * std::mem::size_of::<scene::Vertex>();
                queue.write_buffer(
                    &self.vertex_buffer,
                    offset as u64,
                    bytemuck::cast_slice(moved),
                );
            }
        }
        self.facing = shadow::posed_facing_normals(&self.scene, self.still_facing.as_ref());
        if self.groups.blended_start < self.scene.caster_indices {
            setup::sort_blended(&mut self.scene, self.groups);
            let blended = self.groups.blended_start as usize..self.scene.caster_indices as usize;
            queue.write_buffer(
                &self.index_buffer,
                4 * blended.start as u64,
                bytemuck::cast_slice(&self.scene.indices[blended]),
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

    /// Renders one frame and waits for it, without reading the image back (benchmarks,
    /// display-less budget runs).
    pub fn render_timed(&mut self, lights: &[Light]) -> Result<FrameStats, RenderError> {
        let start = Instant::now();
        let (gl, maps) = self.prepare(lights)?;
        let enc = self.encode(maps, false);
        self.submit_frame(enc, start, gl.len(), maps)
    }

    /// Submits `enc`, waits for it and returns the frame's stats: `counted` lights, lobes or
    /// coefficients in `lights`, `maps` shadow maps, CPU times since `start`, GPU times where
    /// the adapter has timestamps.
    pub(super) fn submit_frame(
        &mut self,
        enc: wgpu::CommandEncoder,
        start: Instant,
        counted: usize,
        maps: usize,
    ) -> Result<FrameStats, RenderError> {
        self.gpu.queue.submit([enc.finish()]);
        let encode_ms = start.elapsed().as_secs_f64() * 1e3;
        self.wait()?;
        let cpu_ms = start.elapsed().as_secs_f64() * 1e3;
        let (gpu_ms, shadow_gpu_ms) = self.gpu_time(maps > 0)?;
        Ok(FrameStats {
            lights: counted,
            shadow_maps: maps,
            gpu_ms,
            shadow_gpu_ms,
            cpu_ms,
            encode_ms,
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
        self.submit_frame(enc, start, gl.len(), maps)
    }

    /// Renders one frame and reads the image back.
    pub fn render(&mut self, lights: &[Light]) -> Result<(Image, FrameStats), RenderError> {
        let start = Instant::now();
        let (gl, maps) = self.prepare(lights)?;
        let enc = self.encode(maps, true);
        let stats = self.submit_frame(enc, start, gl.len(), maps)?;
        let image = self.read_image()?;
        Ok((image, stats))
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

#[cfg(test)]
mod tests {
    use super::*;
    use setup::{draw_blended_opaque, order_triangles};

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
            } else if name == "closed_form.wgsl" {
                assert_eq!(file, CLOSED_FORM_WGSL);
                let users = SHADERS
                    .iter()
                    .filter(|(_, text)| text.ends_with(CLOSED_FORM_WGSL))
                    .count();
                assert_eq!(users, 2, "asg.wgsl and sh.wgsl end with it");
                continue;
            } else {
                let (_, text) = SHADERS
                    .iter()
                    .find(|(n, _)| *n == name)
                    .unwrap_or_else(|| panic!("{name} is not in render::SHADERS"));
                assert!(
                    *text == file
                        || *text == format!("{SURFACE_WGSL}{file}")
                        || *text == format!("{SURFACE_WGSL}{file}{CLOSED_FORM_WGSL}")
                        || *text == format!("{SURFACE_WGSL}{SHADOW_LOOKUP_WGSL}{file}")
                        || *text
                            == format!(
                                "{SURFACE_WGSL}{SHADOW_LOOKUP_WGSL}{file}{CLOSED_FORM_WGSL}"
                            ),
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
        // The two preludes and the closed-form entry points are not in SHADERS.
        assert_eq!(files.len(), SHADERS.len() + 3);
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
        let sh = parse("sh.wgsl");
        assert_eq!(struct_size(&sh, "Globals"), size_of::<sh::ShGlobalsRaw>());
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
}
