//! GPU-side data of the G-buffer and shading passes: each CPU struct beside its `#[repr(C)]`
//! `…Raw` twin (as in the wgpu examples), made by `to_raw()`. The layouts match
//! `shaders/shade.wgsl`.

use super::scene::{AlphaMode, Material};
use super::shadow;
use super::shadow_raster::ShadowRaster;
use super::textures::{MaterialLayers, TEXTURE_SLOTS};
use crate::light::Light;
use glam::{Mat4, Vec3, Vec4};

/// Per-frame constants of the G-buffer and shading passes.
#[derive(Clone, Copy, Debug)]
pub struct Globals {
    pub view_proj: Mat4,
    /// The camera's [`Camera::viewer`](super::scene::Camera::viewer): its eye (w = 1) or, for
    /// an orthographic camera, the direction towards it (w = 0).
    pub viewer: Vec4,
    pub light_count: u32,
    pub culling: bool,
    pub shadows: bool,
    /// Where the shading pass reads the maps.
    pub shadow_raster: ShadowRaster,
    /// Side of each shadow map in texels.
    pub shadow_resolution: u32,
    /// Normal offset of shadow lookups, world units.
    pub normal_offset: f32,
    /// Depth bias of shadow lookups, in shadow-map depth units.
    pub depth_bias: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GlobalsRaw {
    view_proj: [[f32; 4]; 4],
    viewer: [f32; 4],
    light_count: u32,
    culling: u32,
    /// Read by the ASG pass too (its lobes' shadow maps).
    pub(super) shadows: u32,
    pub(super) shadow_source: u32,
    pub(super) shadow_params: [f32; 4],
}

impl Globals {
    pub fn to_raw(&self) -> GlobalsRaw {
        GlobalsRaw {
            view_proj: self.view_proj.to_cols_array_2d(),
            viewer: self.viewer.to_array(),
            light_count: self.light_count,
            culling: u32::from(self.culling),
            shadows: u32::from(self.shadows),
            shadow_source: u32::from(self.shadow_raster == ShadowRaster::Compute),
            shadow_params: [
                self.normal_offset,
                self.depth_bias,
                self.shadow_resolution as f32,
                0.0,
            ],
        }
    }
}

/// One light as the shading pass sees it.
#[derive(Clone, Copy, Debug)]
pub struct GpuLight {
    /// Unit direction towards the light.
    pub dir: Vec3,
    pub rgb: [f32; 3],
    /// Solid angle of the light's region or merged source (sr).
    pub solid_angle: f32,
    /// Shadow-map layer, if the light has a map.
    pub layer: Option<u32>,
    /// The light camera's view-projection (identity without a map).
    pub view_proj: Mat4,
    /// PCF kernel radius in shadow-map uv.
    pub pcf_radius: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LightRaw {
    dir: [f32; 4],
    rgb: [f32; 4],
    view_proj: [[f32; 4]; 4],
    params: [f32; 4],
}

impl GpuLight {
    /// From a light of the list; `None` for a light with a non-finite or zero direction or
    /// non-finite power (negative channels are clamped to 0).
    pub fn from_light(light: &Light) -> Option<Self> {
        let dir = Vec3::from_array(light.dir);
        if !dir.is_finite()
            || dir.length_squared() < 1e-12
            || light.rgb.iter().any(|c| !c.is_finite())
        {
            return None;
        }
        let omega = if light.solid_angle.is_finite() {
            light.solid_angle.max(0.0)
        } else {
            0.0
        };
        Some(Self {
            dir: dir.normalize(),
            rgb: light.rgb.map(|c| c.max(0.0)),
            solid_angle: omega,
            layer: None,
            view_proj: Mat4::IDENTITY,
            pcf_radius: 0.0,
        })
    }

    pub fn to_raw(&self) -> LightRaw {
        LightRaw {
            dir: self
                .dir
                .extend(shadow::angular_radius(self.solid_angle))
                .to_array(),
            rgb: [
                self.rgb[0],
                self.rgb[1],
                self.rgb[2],
                self.layer.map_or(-1.0, |l| l as f32),
            ],
            view_proj: self.view_proj.to_cols_array_2d(),
            params: [self.pcf_radius, 0.0, 0.0, 0.0],
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MaterialRaw {
    base_color: [f32; 4],
    /// x: roughness, y: metallic, z: unused, w: flags.
    params: [f32; 4],
    /// The layers of the textures in slot order ([`super::textures::MaterialLayers`],
    /// `scene::MaterialTextures::slots`), four a row, then two unused; −1: no texture.
    layers: [[f32; 4]; 3],
    /// x, y: the wrap modes of slots 0–7 and 8–9, four bits each; z: the texture-coordinate
    /// channels, a bit per slot; w: unused.
    texture_modes: [u32; 4],
    /// x: the normal texture's scale; y: the occlusion texture's strength; z: the alpha cutoff
    /// (negative: opaque; positive for a blended material); w: 1 for a blended material (its
    /// shadow dithered by its alpha), else 0.
    extra: [f32; 4],
    /// rgb: emitted radiance (the emissive texture multiplies it); w: unused.
    emission: [f32; 4],
    /// The texture-coordinate transforms of the textures in slot order, two rows
    /// (m0, m1, m2, unused) each ([`super::scene::TextureRef::transform`]).
    uv_transforms: [[[f32; 4]; 2]; TEXTURE_SLOTS],
    /// rgb: the dielectric F0 before its clamp to 1 and its strength, 0.16 · specular² ·
    /// specular_color; w: the strength `specular_factor` (0 where the level is 0). The shaders
    /// take F0 = min(rgb · the specular-colour texture, 1) · w · the specular texture's A,
    /// and F90 = w · A ([`Material::dielectric_fresnel`] without textures).
    specular: [f32; 4],
    /// x: the clear coat's strength; y: its roughness; z: the scale of its normal texture;
    /// w: unused.
    coat: [f32; 4],
    /// rgb: the sheen's colour; w: its distribution's α ([`super::sheen::alpha`]), 0 where the
    /// colour is black (no sheen).
    sheen: [f32; 4],
    /// The sheen's directional albedo E(n·v) at n·v = 0, 1/15, …, 1, four a row
    /// ([`super::sheen::albedo_table`]); zero without a sheen.
    sheen_albedo: [[f32; 4]; 4],
}

/// Material flag: the surface is a shadow catcher (mixed-reality compositing).
pub const FLAG_CATCHER: u32 = 1;
/// Material flag: the surface is double-sided (set by [`Material::to_raw`] from the material).
pub const FLAG_DOUBLE_SIDED: u32 = 2;
/// Material flag: the surface is unlit (set by [`Material::to_raw`] from the material).
pub const FLAG_UNLIT: u32 = 4;

impl Material {
    /// The dielectric Fresnel terms (F0 per channel, F90) of glTF's `KHR_materials_specular`:
    /// F0 = min(0.16 · specular² · specular_color, 1) · specular_factor, F90 =
    /// specular_factor; both 0 where the level `specular` is 0 (a Lambertian material: no
    /// reflection at grazing incidence either).
    pub fn dielectric_fresnel(&self) -> ([f32; 3], f32) {
        let (tinted, strength) = self.dielectric_factors();
        (tinted.map(|c| c.min(1.0) * strength), strength)
    }

    /// The factors of [`Material::dielectric_fresnel`] before its clamp, which the shaders
    /// apply after the specular-colour texture: 0.16 · specular² · specular_color and the
    /// strength `specular_factor` (both 0 where the level is 0).
    fn dielectric_factors(&self) -> ([f32; 3], f32) {
        if self.specular <= 0.0 {
            return ([0.0; 3], 0.0);
        }
        let f0 = 0.16 * self.specular * self.specular;
        (self.specular_color.map(|c| f0 * c), self.specular_factor)
    }

    /// The shaders' form, with its texture layers from [`super::textures::material_layers`].
    pub fn to_raw(&self, flags: u32, textures: MaterialLayers) -> MaterialRaw {
        let [r, g, b] = self.emission;
        let mut layers = [[-1.0; 4]; 3];
        for (slot, &layer) in textures.layers.iter().enumerate() {
            layers[slot / 4][slot % 4] = layer;
        }
        MaterialRaw {
            base_color: [
                self.base_color[0],
                self.base_color[1],
                self.base_color[2],
                self.alpha,
            ],
            params: [
                self.roughness,
                self.metallic,
                0.0,
                (flags
                    | if self.double_sided {
                        FLAG_DOUBLE_SIDED
                    } else {
                        0
                    }
                    | if self.unlit { FLAG_UNLIT } else { 0 }) as f32,
            ],
            layers,
            texture_modes: [
                textures.wrap_modes[0],
                textures.wrap_modes[1],
                textures.channels,
                0,
            ],
            extra: [
                self.textures.normal_scale,
                self.textures.occlusion_strength,
                match self.alpha_mode {
                    AlphaMode::Opaque => -1.0,
                    AlphaMode::Mask(cutoff) => cutoff,
                    // Any positive value: tested in the shadow maps, by the dither.
                    AlphaMode::Blend => 1.0,
                },
                if self.alpha_mode == AlphaMode::Blend {
                    1.0
                } else {
                    0.0
                },
            ],
            emission: [r, g, b, 0.0],
            uv_transforms: self.textures.slots().map(|t| {
                let m = t.map_or(super::scene::NO_UV_TRANSFORM, |t| t.transform);
                m.map(|[a, b, c]| [a, b, c, 0.0])
            }),
            specular: {
                let ([r, g, b], strength) = self.dielectric_factors();
                [r, g, b, strength]
            },
            coat: [
                self.clearcoat,
                self.clearcoat_roughness,
                self.textures.clearcoat_normal_scale,
                0.0,
            ],
            sheen: match self.sheen_color {
                [0.0, 0.0, 0.0] => [0.0; 4],
                [r, g, b] => [r, g, b, super::sheen::alpha(self.sheen_roughness)],
            },
            sheen_albedo: if self.sheen_color == [0.0; 3] {
                [[0.0; 4]; 4]
            } else {
                let table = super::sheen::albedo_table(self.sheen_roughness);
                std::array::from_fn(|row| std::array::from_fn(|k| table[4 * row + k]))
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_lights_are_dropped_or_clamped() {
        let l = |dir: [f32; 3], rgb: [f32; 3]| Light {
            id: 0,
            dir,
            rgb,
            solid_angle: f32::NAN,
        };
        assert!(GpuLight::from_light(&l([0.0; 3], [1.0; 3])).is_none());
        assert!(GpuLight::from_light(&l([f32::NAN, 1.0, 0.0], [1.0; 3])).is_none());
        assert!(GpuLight::from_light(&l([0.0, 1.0, 0.0], [f32::INFINITY, 1.0, 1.0])).is_none());
        let g = GpuLight::from_light(&l([0.0, 2.0, 0.0], [-1.0, 2.0, 3.0])).unwrap();
        assert_eq!(g.rgb, [0.0, 2.0, 3.0]);
        assert_eq!(g.dir, Vec3::Y);
        assert_eq!(g.solid_angle, 0.0);
        assert_eq!(g.to_raw().rgb[3], -1.0);
    }
}
