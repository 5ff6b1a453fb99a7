//! SH lighting: shades the scene under an environment given as spherical-harmonic coefficients
//! ([`crate::sh`]) in closed form (`shaders/sh.wgsl`), the representation engines use for
//! ambient light (light probes).
//!
//! One pass draws the scene into the renderer's HDR target; per pixel:
//! 1. **Diffuse**: albedo/π · max(E(n), 0), E(n) = Σ_l Â_l Σ_m L_lm Y_lm(n)
//!    ([`ShCoefficients::irradiance`]; Ramamoorthi & Hanrahan 2001).
//! 2. **Specular** (split sum): f0 · [`ggx_albedo`]`(n·v, α)` · max(R(r), 0), A the GGX
//!    directional albedo (F = 1, tabulated once, [`albedo_table`]), R the radiance
//!    prefiltered around the mirror direction r by a normalised spherical Gaussian of sharpness
//!    [`ggx_sharpness`]`(α)` ([`ShCoefficients::prefiltered_radiance`]); a clear coat the
//!    same on its normal; a sheen its directional albedo times E(n)/π.
//! 3. **No shadows**: SH light is the unshadowed environment, so only a material's occlusion
//!    texture occludes it, and a shadow catcher is transparent.
//!
//! The basis is evaluated on the GPU as [`crate::sh::Basis::evaluate`] does, with the
//! normalisation constants and Â_l uploaded once ([`basis_table`]), as is the albedo table. `tests/render.rs` compares
//! the shaded pixels of spheres with [`shade_reference`], the CPU twin.
//!
//! The pass is built on first use ([`Renderer::render_sh`]); the light pass is untouched.

use super::closed_form::SurfacePipelines;
use super::setup::{compute_storage_entry, uniform_entry};
use super::{FrameStats, Image, RenderError, Renderer};
use crate::sh::{coefficient_count, cosine_lobe_factor, Basis, ShCoefficients, MAX_DEGREE};
use glam::DVec3;
use std::time::Instant;

/// WGSL source of the SH pass (`surface.wgsl` prepended).
pub const SH_WGSL: &str = concat!(
    include_str!("../../shaders/surface.wgsl"),
    include_str!("../../shaders/sh.wgsl"),
    include_str!("../../shaders/closed_form.wgsl")
);

/// Per-frame constants of the SH pass (matches `Globals` in sh.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ShGlobalsRaw {
    view_proj: [[f32; 4]; 4],
    /// The camera's [`Camera::viewer`](super::scene::Camera::viewer).
    viewer: [f32; 4],
    degree: u32,
    _pad: [u32; 3],
}

/// The band table sh.wgsl reads: Â_0 ..= Â_15, then K_l^m (×√2 for m > 0) at
/// 16 + l(l + 1)/2 + m, as [`crate::sh::Basis`] computes them.
pub fn basis_table() -> Vec<f32> {
    let basis = Basis::new(MAX_DEGREE);
    let bands = (0..=MAX_DEGREE).map(|l| cosine_lobe_factor(l) as f32);
    bands
        .chain(basis.norms().iter().map(|&k| k as f32))
        .collect()
}

/// λ = 1/(2α²): the sharpness of the spherical Gaussian that stands for a GGX lobe of α around
/// the mirror direction (its Gaussian in the half-vector angle, exp(−θ_h²/α²), doubled in
/// angle by the reflection); α is floored at 0.002 as the shading does.
pub fn ggx_sharpness(alpha: f64) -> f64 {
    let alpha = alpha.max(0.002);
    1.0 / (2.0 * alpha * alpha)
}

/// Nodes of the directional-albedo table over n·v ∈ [0, 1].
pub const ALBEDO_TABLE_COSINES: usize = 32;
/// Nodes over √α ∈ [0, 1] (perceptual roughness: finer where the albedo changes fastest).
pub const ALBEDO_TABLE_ROUGHNESS: usize = 32;

/// The GGX directional albedo for F = 1 at the table's nodes, row by row in √α (the layout
/// sh.wgsl reads): ∫ D G2 / (4 n·v n·l) · n·l dω_l with Smith's height-correlated G2, the
/// BRDF of the light and ASG passes with F = 1 — the split sum's second factor. Integrated
/// by importance sampling of D on a fixed 256 × 64 grid of half vectors (φ over half the
/// circle, by symmetry); computed once per process.
pub fn albedo_table() -> &'static [f32] {
    static TABLE: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut out = Vec::with_capacity(ALBEDO_TABLE_COSINES * ALBEDO_TABLE_ROUGHNESS);
        for j in 0..ALBEDO_TABLE_ROUGHNESS {
            let roughness = j as f64 / (ALBEDO_TABLE_ROUGHNESS - 1) as f64;
            let alpha = (roughness * roughness).max(0.002);
            for i in 0..ALBEDO_TABLE_COSINES {
                let n_v = i as f64 / (ALBEDO_TABLE_COSINES - 1) as f64;
                out.push(ggx_albedo_integral(n_v, alpha) as f32);
            }
        }
        out
    })
}

/// The integral of [`albedo_table`] at one cosine and α.
fn ggx_albedo_integral(n_v: f64, alpha: f64) -> f64 {
    const THETA_STEPS: usize = 256;
    const PHI_STEPS: usize = 64;
    if n_v <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let lambda = |c: f64| crate::wavelet::relight::smith_lambda(c, a2);
    let v = DVec3::new((1.0 - n_v * n_v).max(0.0).sqrt(), 0.0, n_v);
    let mut sum = 0.0;
    for a in 0..THETA_STEPS {
        // θ_h drawn from D(h) n·h: cos²θ_h = (1 − u)/(1 + (α² − 1) u).
        let u = (a as f64 + 0.5) / THETA_STEPS as f64;
        let cos_h = ((1.0 - u) / (1.0 + (a2 - 1.0) * u)).sqrt();
        let sin_h = (1.0 - cos_h * cos_h).max(0.0).sqrt();
        for b in 0..PHI_STEPS {
            let phi = std::f64::consts::PI * (b as f64 + 0.5) / PHI_STEPS as f64;
            let h = DVec3::new(sin_h * phi.cos(), sin_h * phi.sin(), cos_h);
            let v_h = v.dot(h);
            let l = 2.0 * v_h * h - v;
            if v_h <= 0.0 || l.z <= 0.0 {
                continue;
            }
            // f · cos / pdf(l), pdf(l) = D n·h / (4 v·h): G2 v·h / (n·v n·h).
            let g2 = 1.0 / (1.0 + lambda(n_v) + lambda(l.z));
            sum += g2 * v_h / (n_v * cos_h);
        }
    }
    sum / (THETA_STEPS * PHI_STEPS) as f64
}

/// The GGX directional albedo for F = 1 at cosine `n_v` and α: [`albedo_table`] interpolated
/// bilinearly in n·v and √α (clamped to the table), as sh.wgsl's `ggx_albedo` does.
pub fn ggx_albedo(n_v: f64, alpha: f64) -> f64 {
    let table = albedo_table();
    let (nc, nr) = (ALBEDO_TABLE_COSINES, ALBEDO_TABLE_ROUGHNESS);
    let x = n_v.clamp(0.0, 1.0) * (nc - 1) as f64;
    let y = alpha.clamp(0.0, 1.0).sqrt() * (nr - 1) as f64;
    let (i, j) = ((x as usize).min(nc - 2), (y as usize).min(nr - 2));
    let (fx, fy) = (x - i as f64, y - j as f64);
    let at = |i: usize, j: usize| f64::from(table[j * nc + i]);
    let a0 = at(i, j) + (at(i + 1, j) - at(i, j)) * fx;
    let a1 = at(i, j + 1) + (at(i + 1, j + 1) - at(i, j + 1)) * fx;
    a0 + (a1 - a0) * fy
}

/// The radiance sh.wgsl gives an opaque point of unit normal `n` seen along unit `v` (towards
/// the viewer), of diffuse albedo `albedo`, specular reflectance `f0` and GGX α `alpha` (no
/// coat, sheen, occlusion or emission): the CPU reference of the pass.
pub fn shade_reference(
    sh: &ShCoefficients,
    n: DVec3,
    v: DVec3,
    albedo: [f64; 3],
    f0: [f64; 3],
    alpha: f64,
) -> [f64; 3] {
    let alpha = alpha.max(0.002);
    let e = sh.irradiance(n).map(|c| c.max(0.0));
    let n_v = n.dot(v);
    let specular = if n_v > 1e-6 {
        let r = (2.0 * n_v * n - v).normalize();
        let albedo = ggx_albedo(n_v, alpha);
        sh.prefiltered_radiance(r, ggx_sharpness(alpha))
            .map(|c| c.max(0.0) * albedo)
    } else {
        [0.0; 3]
    };
    std::array::from_fn(|c| albedo[c] / std::f64::consts::PI * e[c] + f0[c] * specular[c])
}

/// GPU objects of the SH pass.
pub(super) struct ShPass {
    pipelines: SurfacePipelines,
    globals: wgpu::Buffer,
    /// Room for the coefficients of [`MAX_DEGREE`], so it is never replaced.
    coefficients: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

/// `buffer` whole at `binding`.
fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}

/// A read-only storage buffer of the fragment stage.
fn storage_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        visibility: wgpu::ShaderStages::FRAGMENT,
        ..compute_storage_entry(binding, true)
    }
}

impl ShPass {
    fn new(renderer: &Renderer) -> Self {
        use wgpu::util::DeviceExt;
        let device = &renderer.gpu.device;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("sh"),
            entries: &[
                uniform_entry(0, wgpu::ShaderStages::VERTEX_FRAGMENT),
                storage_entry(1),
                storage_entry(2),
                storage_entry(3),
                storage_entry(4),
            ],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("sh.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SH_WGSL.into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("sh"),
            bind_group_layouts: &[Some(&layout), None, Some(&renderer.surface_textures.layout)],
            immediate_size: 0,
        });
        let pipelines = SurfacePipelines::new(renderer, "sh", &pipeline_layout, &module);
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("sh globals"),
            size: std::mem::size_of::<ShGlobalsRaw>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let coefficients = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("sh coefficients"),
            size: (coefficient_count(MAX_DEGREE) * 16) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let table = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("sh basis table"),
            contents: bytemuck::cast_slice(&basis_table()),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let albedo = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("ggx albedo table"),
            contents: bytemuck::cast_slice(albedo_table()),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("sh"),
            layout: &layout,
            entries: &[
                entry(0, &globals),
                entry(1, &coefficients),
                entry(2, &renderer.material_buffer),
                entry(3, &table),
                entry(4, &albedo),
            ],
        });
        Self {
            pipelines,
            globals,
            coefficients,
            bind_group,
        }
    }
}

impl Renderer {
    /// Uploads the coefficients (building the pass on first use); returns how many there
    /// are per channel. A coefficient beyond f32's range is an error naming it (the shading
    /// would give infinities or NaN).
    fn prepare_sh(&mut self, sh: &ShCoefficients) -> Result<usize, RenderError> {
        let mut raw = Vec::with_capacity(sh.rgb().len());
        for (i, c) in sh.rgb().iter().enumerate() {
            let v = c.map(|x| x as f32);
            if !v.iter().all(|x| x.is_finite()) {
                return Err(RenderError::Settings(format!(
                    "SH coefficient {i} ({c:?}) is not a finite f32"
                )));
            }
            raw.push([v[0], v[1], v[2], 0.0]);
        }
        let pass = match self.sh_pass.take() {
            Some(pass) => pass,
            None => ShPass::new(self),
        };
        self.gpu
            .queue
            .write_buffer(&pass.coefficients, 0, bytemuck::cast_slice(&raw));
        let globals = ShGlobalsRaw {
            view_proj: self.view_proj().to_cols_array_2d(),
            viewer: self.scene.camera.viewer().to_array(),
            degree: sh.degree() as u32,
            _pad: [0; 3],
        };
        self.gpu
            .queue
            .write_buffer(&pass.globals, 0, bytemuck::bytes_of(&globals));
        self.sh_pass = Some(pass);
        Ok(raw.len())
    }

    fn encode_sh(&self, readback: bool) -> wgpu::CommandEncoder {
        let pass = self.sh_pass.as_ref().map(|p| (&p.pipelines, &p.bind_group));
        self.encode_closed_form("sh shade", pass, 0, readback)
    }

    /// Renders one frame under SH lighting and waits for it, without reading the image back.
    /// `FrameStats::lights` counts the coefficients per channel, `shadow_maps` is 0; GPU times
    /// where the adapter has timestamps, as for the lights.
    pub fn render_sh_timed(&mut self, sh: &ShCoefficients) -> Result<FrameStats, RenderError> {
        let start = Instant::now();
        let n = self.prepare_sh(sh)?;
        let enc = self.encode_sh(false);
        self.submit_frame(enc, start, n, 0)
    }

    /// Renders one frame under SH lighting (module doc) and reads the image back.
    pub fn render_sh(&mut self, sh: &ShCoefficients) -> Result<(Image, FrameStats), RenderError> {
        let start = Instant::now();
        let n = self.prepare_sh(sh)?;
        let enc = self.encode_sh(true);
        let stats = self.submit_frame(enc, start, n, 0)?;
        Ok((self.read_image()?, stats))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_sizes_match_the_shader() {
        assert_eq!(std::mem::size_of::<ShGlobalsRaw>(), 96);
    }

    /// sh.wgsl's `sh_sum`, line for line, in f64 on the uploaded table.
    fn shader_sum(
        table: &[f32],
        sh: &ShCoefficients,
        d: DVec3,
        weight: impl Fn(usize) -> f64,
    ) -> [f64; 3] {
        let coefficients = sh.rgb();
        let degree = sh.degree();
        let mut sum = [0.0; 3];
        let (mut re, mut im, mut q_diagonal) = (1.0f64, 0.0f64, 1.0f64);
        for m in 0..=degree {
            if m > 0 {
                (re, im) = (re * d.x - im * d.y, re * d.y + im * d.x);
                q_diagonal *= (2 * m - 1) as f64;
            }
            let (mut q_before, mut q) = (0.0, q_diagonal);
            for l in m..=degree {
                if l > m {
                    let next = ((2 * l - 1) as f64 * d.z * q - (l + m - 1) as f64 * q_before)
                        / (l - m) as f64;
                    (q_before, q) = (q, next);
                }
                let nq = weight(l) * f64::from(table[MAX_DEGREE + 1 + l * (l + 1) / 2 + m]) * q;
                let centre = l * l + l;
                for c in 0..3 {
                    sum[c] += nq
                        * if m == 0 {
                            coefficients[centre][c]
                        } else {
                            coefficients[centre + m][c] * re + coefficients[centre - m][c] * im
                        };
                }
            }
        }
        sum
    }

    #[test]
    fn the_shaders_sum_on_the_table_equals_the_cpu_basis() {
        let table = basis_table();
        assert_eq!(
            table.len(),
            MAX_DEGREE + 1 + (MAX_DEGREE + 1) * (MAX_DEGREE + 2) / 2
        );
        for l in 0..=MAX_DEGREE {
            assert_eq!(table[l], cosine_lobe_factor(l) as f32);
        }
        // Some coefficients of every degree up to the highest, with every sign.
        let rgb: Vec<[f64; 3]> = (0..coefficient_count(MAX_DEGREE))
            .map(|i| {
                let x = ((i * 37 + 11) % 23) as f64 / 23.0 - 0.4;
                [x, 0.5 * x + 0.1, -x]
            })
            .collect();
        let sh = ShCoefficients::from_rgb(rgb).unwrap();
        for d in [
            DVec3::new(0.3, -0.5, 0.7),
            DVec3::Y,
            DVec3::new(-0.9, 0.1, -0.2),
            DVec3::Z,
        ] {
            let d = d.normalize();
            let got = shader_sum(&table, &sh, d, |l| f64::from(table[l]));
            let want = sh.irradiance(d);
            let glossy = shader_sum(&table, &sh, d, |l| crate::sh::gaussian_lobe_factor(l, 7.0));
            let want_glossy = sh.prefiltered_radiance(d, 7.0);
            for c in 0..3 {
                // The table's constants are f32: 1e-6 relative, on sums of order 10.
                assert!((got[c] - want[c]).abs() < 1e-4, "{d}: {got:?} vs {want:?}");
                assert!((glossy[c] - want_glossy[c]).abs() < 1e-4, "{d}: {glossy:?}");
            }
        }
    }

    #[test]
    fn the_albedo_table_is_the_brdfs_integral() {
        // Against a brute-force quadrature of the wavelet relighting's GGX (the same BRDF, F = 1),
        // over a fine grid of light directions, where the lobe is wide enough for it.
        use crate::wavelet::relight::Brdf;
        for (n_v, alpha) in [
            (1.0, 0.25),
            (0.5, 0.25),
            (0.2, 0.5),
            (0.8, 1.0),
            (0.05, 1.0),
        ] {
            let brdf = Brdf::Ggx { alpha };
            let theta_v = f64::acos(n_v);
            let normal = glam::Vec3::Z;
            let view = glam::Vec3::new(theta_v.sin() as f32, 0.0, n_v as f32);
            let (nt, np) = (1024, 1024);
            let mut sum = 0.0;
            for a in 0..nt {
                let theta = std::f64::consts::FRAC_PI_2 * (a as f64 + 0.5) / nt as f64;
                let d_omega = theta.sin() * std::f64::consts::FRAC_PI_2 / nt as f64
                    * std::f64::consts::TAU
                    / np as f64;
                for b in 0..np {
                    let phi = std::f64::consts::TAU * (b as f64 + 0.5) / np as f64;
                    let dir = glam::Vec3::new(
                        (theta.sin() * phi.cos()) as f32,
                        (theta.sin() * phi.sin()) as f32,
                        theta.cos() as f32,
                    );
                    sum += brdf.eval(normal, view, dir) * d_omega;
                }
            }
            let alpha = f64::from(alpha);
            let node = ggx_albedo_integral(n_v, alpha);
            assert!(
                (node - sum).abs() < 0.005,
                "A({n_v}, {alpha}): {node} vs {sum}"
            );
            let interpolated = ggx_albedo(n_v, alpha);
            assert!(
                (interpolated - sum).abs() < 0.01,
                "A({n_v}, {alpha}) interpolated: {interpolated} vs {sum}"
            );
        }
        // A mirror seen head-on reflects everything; roughness loses energy to masking.
        assert!((ggx_albedo(1.0, 0.002) - 1.0).abs() < 0.01);
        assert!(ggx_albedo(1.0, 1.0) < ggx_albedo(1.0, 0.1));
        assert_eq!(ggx_albedo(0.0, 0.5), 0.0);
        assert_eq!(ggx_sharpness(0.5), 2.0);
        assert_eq!(ggx_sharpness(0.0), ggx_sharpness(0.002));
    }

    #[test]
    fn the_reference_of_a_uniform_environment_is_the_albedos() {
        // Radiance 1 everywhere: E = π, so the diffuse term is the albedo; the prefiltered
        // radiance is 1, so the specular term is f0 · A(n·v, α).
        let sh = ShCoefficients::from_rgb(vec![[(4.0 * std::f64::consts::PI).sqrt(); 3]]).unwrap();
        let n = DVec3::Y;
        let v = DVec3::new(0.6, 0.8, 0.0);
        let got = shade_reference(&sh, n, v, [0.5, 0.25, 0.0], [0.04; 3], 0.3);
        let a = ggx_albedo(0.8, 0.3);
        for (c, albedo) in [0.5, 0.25, 0.0].into_iter().enumerate() {
            assert!((got[c] - (albedo + 0.04 * a)).abs() < 1e-12, "{got:?}");
        }
        // Seen from behind: no specular.
        let behind = shade_reference(&sh, n, -v, [0.5; 3], [1.0; 3], 0.3);
        assert!((behind[0] - 0.5).abs() < 1e-12);
    }
}
