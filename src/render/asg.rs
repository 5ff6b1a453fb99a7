//! ASG lighting: shades the scene under a set of anisotropic spherical Gaussians in closed form
//! (`shaders/asg.wgsl`), the GPU twin of [`Asg::irradiance`] and [`Asg::ggx_specular`].
//!
//! One pass draws the scene into the renderer's HDR target: per pixel, Lambertian diffuse
//! (albedo/π · Σ E_k(n), E from the normalised cosine convolution H tabulated by
//! [`crate::asg::cosine_convolution`] and uploaded once as a storage buffer) plus GGX specular
//! (Σ c_k · S_k(n, v, α) · f0, the spherical-Gaussian approximation of the GGX lobe), each
//! lobe's terms times its visibility: lobe k is a directional light along its axis, of its
//! solid angle, for the light pass's shadow maps and PCF (`Renderer::prepare`), so a sharp
//! lobe casts a hard shadow and a wide one a soft shadow; a shadow catcher outputs the
//! shadowed fraction of the lobes' irradiance as alpha. `tests/render.rs` compares the shaded
//! pixels of a sphere (shadows off) with the CPU closed form and measures the shadows.
//!
//! The pass is built on first use ([`Renderer::render_asg`]); the light pass is untouched.

use super::closed_form::SurfacePipelines;
use super::setup::{compute_storage_entry, uniform_entry};
use super::{FrameStats, Image, RenderError, Renderer};
use crate::asg::{cosine_convolution, integral, Asg};
use crate::light::Light;
use std::time::Instant;

/// WGSL source of the ASG pass (`surface.wgsl` prepended).
pub const ASG_WGSL: &str = concat!(
    include_str!("../../shaders/surface.wgsl"),
    include_str!("../../shaders/shadow_lookup.wgsl"),
    include_str!("../../shaders/asg.wgsl"),
    include_str!("../../shaders/closed_form.wgsl")
);

/// Nodes of the cosine-convolution table over t = n·z (as in `crate::asg`).
const TABLE_T: usize = 129;
/// Nodes over ln ν ∈ [ln 0.5, ln 4·10⁵].
const TABLE_NU: usize = 72;
const TABLE_NU_MIN: f64 = 0.5;
const TABLE_NU_MAX: f64 = 4.0e5;

/// Per-frame constants of the ASG pass (matches `Globals` in asg.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct AsgGlobalsRaw {
    view_proj: [[f32; 4]; 4],
    /// The camera's [`Camera::viewer`](super::scene::Camera::viewer).
    viewer: [f32; 4],
    lobe_count: u32,
    /// 1 where the lobes' shadow maps are read.
    shadows: u32,
    /// Where the maps are (as the light pass's `GlobalsRaw`).
    shadow_source: u32,
    _pad: u32,
    /// Normal offset, depth bias, map side (as the light pass's).
    shadow_params: [f32; 4],
}

/// One lobe as the shader reads it (matches `Lobe` in asg.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LobeRaw {
    /// Tangent, λ.
    pub x: [f32; 4],
    /// Bitangent, μ.
    pub y: [f32; 4],
    /// Axis, ν = 2√(λμ).
    pub z: [f32; 4],
    /// Amplitude, exact integral of the unit-amplitude lobe.
    pub rgb: [f32; 4],
}

impl LobeRaw {
    /// The shader's form of a lobe; `None` for a lobe with non-finite values or non-positive
    /// bandwidths (negative amplitudes are clamped to 0).
    pub fn from_asg(asg: &Asg) -> Option<Self> {
        let (x, y, z) = asg.frame();
        let ok = [x, y, z].iter().all(|v| v.is_finite())
            && asg.lambda.is_finite()
            && asg.mu.is_finite()
            && asg.lambda > 0.0
            && asg.mu > 0.0
            && asg.rgb.iter().all(|c| c.is_finite());
        if !ok {
            return None;
        }
        let v = |a: glam::DVec3, w: f64| [a.x as f32, a.y as f32, a.z as f32, w as f32];
        let c = asg.rgb.map(|c| c.max(0.0) as f32);
        Some(Self {
            x: v(x, asg.lambda),
            y: v(y, asg.mu),
            z: v(z, 2.0 * (asg.lambda * asg.mu).sqrt()),
            rgb: [c[0], c[1], c[2], integral(asg.lambda, asg.mu) as f32],
        })
    }
}

/// The table of H(t, ν) at its nodes, row by row in ν (the layout asg.wgsl reads), taken from
/// [`cosine_convolution`] at the nodes (where its bilinear interpolation returns the node).
pub fn cosine_table() -> Vec<f32> {
    let dl = (TABLE_NU_MAX / TABLE_NU_MIN).ln() / (TABLE_NU - 1) as f64;
    let mut out = Vec::with_capacity(TABLE_T * TABLE_NU);
    for j in 0..TABLE_NU {
        let nu = TABLE_NU_MIN * (dl * j as f64).exp();
        for i in 0..TABLE_T {
            let t = -1.0 + 2.0 * i as f64 / (TABLE_T - 1) as f64;
            out.push(cosine_convolution(t, nu).0 as f32);
        }
    }
    out
}

/// GPU objects of the ASG pass.
pub(super) struct AsgPass {
    pipelines: SurfacePipelines,
    layout: wgpu::BindGroupLayout,
    globals: wgpu::Buffer,
    lobes: wgpu::Buffer,
    capacity: usize,
    table: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    /// The renderer's `shadow_bindings_generation` when `bind_group` was made.
    bound_generation: u64,
}

/// Where the ASG pass binds the lobes' shadow maps (`shaders/asg.wgsl`, group 0).
const ASG_SHADOW_BINDINGS: super::ShadowLookupBindings = super::ShadowLookupBindings {
    lights: 4,
    maps: 5,
    sampler: 6,
    depths: 7,
};

/// A read-only storage buffer of the fragment stage.
fn storage_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        visibility: wgpu::ShaderStages::FRAGMENT,
        ..compute_storage_entry(binding, true)
    }
}

fn lobe_buffer(device: &wgpu::Device, capacity: usize) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("asg lobes"),
        size: (capacity * std::mem::size_of::<LobeRaw>()) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

impl AsgPass {
    fn new(renderer: &Renderer) -> Self {
        use wgpu::util::DeviceExt;
        let device = &renderer.gpu.device;
        let [lights_entry, maps_entry, sampler_entry, depths_entry] =
            ASG_SHADOW_BINDINGS.layout_entries(wgpu::ShaderStages::FRAGMENT);
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("asg"),
            entries: &[
                uniform_entry(0, wgpu::ShaderStages::VERTEX_FRAGMENT),
                storage_entry(1),
                storage_entry(2),
                storage_entry(3),
                lights_entry,
                maps_entry,
                sampler_entry,
                depths_entry,
            ],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("asg.wgsl"),
            source: wgpu::ShaderSource::Wgsl(ASG_WGSL.into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("asg"),
            bind_group_layouts: &[Some(&layout), None, Some(&renderer.surface_textures.layout)],
            immediate_size: 0,
        });
        let pipelines = SurfacePipelines::new(renderer, "asg", &pipeline_layout, &module);
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("asg globals"),
            size: std::mem::size_of::<AsgGlobalsRaw>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let capacity = 64;
        let lobes = lobe_buffer(device, capacity);
        let table = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("asg cosine table"),
            contents: bytemuck::cast_slice(&cosine_table()),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let bind_group = Self::bind(renderer, &layout, &globals, &lobes, &table);
        Self {
            bound_generation: renderer.shadow_bindings_generation,
            pipelines,
            layout,
            globals,
            lobes,
            capacity,
            table,
            bind_group,
        }
    }

    fn bind(
        renderer: &Renderer,
        layout: &wgpu::BindGroupLayout,
        globals: &wgpu::Buffer,
        lobes: &wgpu::Buffer,
        table: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        // The lobes' shadow maps, as the light pass binds them.
        let [lights, maps, sampler, depths] = ASG_SHADOW_BINDINGS.bind_entries(
            &renderer.light_buffer,
            &renderer.shadow.array_view,
            &renderer.shadow_sampler,
            renderer.shadow_depths(),
        );
        renderer
            .gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("asg"),
                layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: globals.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: lobes.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: renderer.material_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: table.as_entire_binding(),
                    },
                    lights,
                    maps,
                    sampler,
                    depths,
                ],
            })
    }
}

impl Renderer {
    /// Uploads the lobes (building the pass on first use) and prepares their shadow maps: each
    /// lobe is, for the light pass's shadow machinery ([`Renderer::prepare`]), a directional
    /// light along its axis of its solid angle (the exact integral of the unit-amplitude lobe,
    /// which sets its PCF kernel: a wide lobe casts a soft shadow), record k for lobe k.
    /// Returns how many lobes are drawn and how many shadow maps the frame has.
    fn prepare_asg(&mut self, lobes: &[Asg]) -> Result<(usize, usize), RenderError> {
        let raw: Vec<LobeRaw> = lobes.iter().filter_map(LobeRaw::from_asg).collect();
        let as_lights: Vec<Light> = raw
            .iter()
            .enumerate()
            .map(|(k, lobe)| Light {
                id: k as u32,
                dir: [lobe.z[0], lobe.z[1], lobe.z[2]],
                rgb: std::array::from_fn(|c| lobe.rgb[c] * lobe.rgb[3]),
                solid_angle: lobe.rgb[3],
            })
            .collect();
        let (records, maps) = self.prepare(&as_lights)?;
        if records.len() != raw.len() {
            // Every lobe that LobeRaw keeps is a valid light; a mismatch would put one lobe's
            // shadow under another.
            return Err(RenderError::Settings(format!(
                "{} lobes but {} shadow records",
                raw.len(),
                records.len()
            )));
        }
        let mut pass = match self.asg_pass.take() {
            Some(pass) => pass,
            None => AsgPass::new(self),
        };
        let mut rebind = pass.bound_generation != self.shadow_bindings_generation;
        if raw.len() > pass.capacity {
            pass.capacity = raw.len().next_power_of_two();
            pass.lobes = lobe_buffer(&self.gpu.device, pass.capacity);
            rebind = true;
        }
        if rebind {
            pass.bind_group =
                AsgPass::bind(self, &pass.layout, &pass.globals, &pass.lobes, &pass.table);
            pass.bound_generation = self.shadow_bindings_generation;
        }
        if !raw.is_empty() {
            self.gpu
                .queue
                .write_buffer(&pass.lobes, 0, bytemuck::cast_slice(&raw));
        }
        let shadow = self.frame_globals(raw.len() as u32).to_raw();
        let globals = AsgGlobalsRaw {
            view_proj: self.view_proj().to_cols_array_2d(),
            viewer: self.scene.camera.viewer().to_array(),
            lobe_count: raw.len() as u32,
            shadows: shadow.shadows,
            shadow_source: shadow.shadow_source,
            _pad: 0,
            shadow_params: shadow.shadow_params,
        };
        self.gpu
            .queue
            .write_buffer(&pass.globals, 0, bytemuck::bytes_of(&globals));
        self.asg_pass = Some(pass);
        Ok((raw.len(), maps))
    }

    fn encode_asg(&self, maps: usize, readback: bool) -> wgpu::CommandEncoder {
        let pass = self
            .asg_pass
            .as_ref()
            .map(|p| (&p.pipelines, &p.bind_group));
        self.encode_closed_form("asg shade", pass, maps, readback)
    }

    /// Renders one frame under ASG lighting and waits for it, without reading the image back.
    /// `FrameStats::lights` counts the lobes drawn, `shadow_maps` their maps; GPU times where
    /// the adapter has timestamps, as for the lights.
    pub fn render_asg_timed(&mut self, lobes: &[Asg]) -> Result<FrameStats, RenderError> {
        let start = Instant::now();
        let (n, maps) = self.prepare_asg(lobes)?;
        let enc = self.encode_asg(maps, false);
        self.submit_frame(enc, start, n, maps)
    }

    /// Renders one frame under ASG lighting (module doc) and reads the image back.
    pub fn render_asg(&mut self, lobes: &[Asg]) -> Result<(Image, FrameStats), RenderError> {
        let start = Instant::now();
        let (n, maps) = self.prepare_asg(lobes)?;
        let enc = self.encode_asg(maps, true);
        let stats = self.submit_frame(enc, start, n, maps)?;
        Ok((self.read_image()?, stats))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_sizes_match_the_shader() {
        assert_eq!(std::mem::size_of::<AsgGlobalsRaw>(), 112);
        assert_eq!(std::mem::size_of::<LobeRaw>(), 64);
    }

    #[test]
    fn table_reproduces_the_cpu_interpolant() {
        let table = cosine_table();
        assert_eq!(table.len(), TABLE_T * TABLE_NU);
        // Between nodes, bilinear interpolation of the uploaded table equals the CPU's.
        let dl = (TABLE_NU_MAX / TABLE_NU_MIN).ln() / (TABLE_NU - 1) as f64;
        for &(t, nu) in &[(0.3, 5.0), (-0.2, 0.9), (0.95, 3000.0), (0.0, 1.0e5)] {
            let ut = (t + 1.0) / (2.0 / (TABLE_T - 1) as f64);
            let un = (nu / TABLE_NU_MIN).ln() / dl;
            let (i, j) = (ut.floor() as usize, un.floor() as usize);
            let (ft, fv) = (ut - i as f64, un - j as f64);
            let at = |i: usize, j: usize| f64::from(table[j * TABLE_T + i]);
            let h0 = at(i, j) + (at(i + 1, j) - at(i, j)) * ft;
            let h1 = at(i, j + 1) + (at(i + 1, j + 1) - at(i, j + 1)) * ft;
            let h = h0 + (h1 - h0) * fv;
            let cpu = cosine_convolution(t, nu).0;
            assert!((h - cpu).abs() < 1e-6, "H({t}, {nu}): {h} vs {cpu}");
        }
    }

    #[test]
    fn degenerate_lobes_are_dropped() {
        let mut a = Asg::new(glam::DVec3::Y, glam::DVec3::X, 4.0, 2.0, [1.0, -1.0, 2.0]).unwrap();
        let raw = LobeRaw::from_asg(&a).unwrap();
        assert_eq!(raw.rgb[1], 0.0);
        assert!((raw.z[3] - 2.0 * 8f32.sqrt()).abs() < 1e-6);
        a.lambda = f64::NAN;
        assert!(LobeRaw::from_asg(&a).is_none());
        a.lambda = 0.0;
        assert!(LobeRaw::from_asg(&a).is_none());
    }
}
