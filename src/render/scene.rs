//! Scenes: triangle meshes with PBR materials, a camera and a ground plane.
//!
//! All meshes are flattened into one world-space vertex and index buffer (node transforms
//! applied on the CPU), with a material index per vertex, so the G-buffer pass is one draw call and
//! the shadow pass one draw of the shadow casters. The ground plane comes last in the index
//! buffer: it receives shadows (or catches them, for mixed reality) but casts none, so the
//! shadow maps are fitted to the casters' bounding sphere alone.
//!
//! Sources: [`Scene::default_scene`] (spheres of different roughness and a box on a ground
//! plane), glTF 2.0 (`.gltf` with external or embedded buffers, `.glb`) and Wavefront OBJ (with
//! its MTL materials where present). Loading never panics on bad input: every error names the
//! file and the problem.

use glam::{Mat3, Mat4, Vec3};
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Why a scene file could not be loaded.
#[derive(Debug, Error)]
pub enum SceneError {
    #[error("cannot read scene {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("invalid glTF file {path}: {message}")]
    Gltf { path: PathBuf, message: String },
    #[error("invalid OBJ file {path}: {message}")]
    Obj { path: PathBuf, message: String },
    #[error("scene {path} has no triangles")]
    Empty { path: PathBuf },
    #[error("scene {path}: unknown format (expected .gltf, .glb or .obj)")]
    UnknownFormat { path: PathBuf },
    #[error("scene {path}: its vertices span a sphere of radius {radius:.3e}, more than the {MAX_SCENE_RADIUS:e} that can be drawn (f32 depth and shadow maps); scale the model down")]
    TooLarge { path: PathBuf, radius: f64 },
    #[error("scene {path}: its vertices lie {distance:.3e} from the origin, {ratio:.1e} times their bounding radius {radius:.3e} (at most {MAX_SCENE_OFFSET:e}): f32 positions that far out lose the model's detail; move the model near the origin")]
    TooFar {
        path: PathBuf,
        distance: f64,
        radius: f32,
        ratio: f64,
    },
}

/// The largest bounding-sphere radius of a loaded scene (in its own units): beyond it the
/// camera distance and the shadow cameras' depth ranges lose all precision in f32.
pub const MAX_SCENE_RADIUS: f32 = 1e15;

/// The most elements a glTF accessor or an OBJ file may hold (vertices or indices): 2^26, a
/// 1.8 GiB vertex buffer. A file of a few bytes can declare billions (a sparse accessor needs
/// no buffer), and reading them aborted the process on a failed allocation.
pub const MAX_SCENE_ELEMENTS: usize = 1 << 26;

/// How far from the origin a scene may lie, in units of its bounding radius: vertices are
/// f32, whose rounding at a distance d is about 6e-8·d, so at 10^5 radii a vertex moves by
/// 0.6 % of the model's size (and beyond, the camera fitted to it lost the model altogether:
/// a 10-unit model at x = 1e10 drew nothing).
pub const MAX_SCENE_OFFSET: f32 = 1e5;

/// One vertex as the GPU reads it (world space).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub material: u32,
    /// Texture coordinates (glTF's `TEXCOORD_n` of the material's first set, OBJ's `vt` with v
    /// flipped): (0, 0) is the image's top-left corner. (0, 0) where the mesh has none.
    pub uv: [f32; 2],
    /// A second set of texture coordinates (glTF's `TEXCOORD_n` of the material's second set,
    /// often a light map's for the occlusion texture), read by textures whose
    /// [`TextureRef::channel`] is 1. (0, 0) where the material has no second set.
    pub uv1: [f32; 2],
    /// Tangent (xyz, world space, along increasing u) and handedness w (±1): the bitangent is
    /// cross(normal, tangent) · w, towards the top of the image (glTF's `TANGENT`). Zero where
    /// the material has no normal texture.
    pub tangent: [f32; 4],
    /// Linear RGBA (0..=65535 for 0..1) multiplying the base colour and its alpha (glTF's
    /// `COLOR_0`). White where the mesh has none.
    pub color: [u16; 4],
}

/// [`Vertex::color`] of a vertex without colour.
pub const WHITE: [u16; 4] = [u16::MAX; 4];

/// How a texture coordinate outside [0, 1] is read (glTF's sampler wrap modes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Wrap {
    #[default]
    Repeat,
    ClampToEdge,
    MirroredRepeat,
}

/// A material's use of a texture image: which image of [`Scene::textures`], how its
/// coordinates wrap (u, v), the affine map from the vertex's texture coordinates to the
/// image's (glTF's `KHR_texture_transform`), and which of the vertex's coordinates it reads.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    pub image: u32,
    pub wrap: [Wrap; 2],
    /// Rows of the 2 × 3 matrix M: the image is read at M · (u, v, 1).
    pub transform: [[f32; 3]; 2],
    /// 0: [`Vertex::uv`]; 1: [`Vertex::uv1`].
    pub channel: u32,
}

impl TextureRef {
    /// Image `image` repeating both ways, untransformed (an OBJ map's, glTF's defaults).
    pub fn repeating(image: u32) -> Self {
        Self {
            image,
            wrap: [Wrap::Repeat; 2],
            transform: NO_UV_TRANSFORM,
            channel: 0,
        }
    }

    /// Where the image is read for texture coordinates `uv`: [`TextureRef::transform`] applied.
    pub fn image_coordinates(&self, uv: [f32; 2]) -> [f32; 2] {
        self.transform.map(|[a, b, c]| a * uv[0] + b * uv[1] + c)
    }
}

/// The glTF extension that transforms texture coordinates, read from each texture's extensions.
const TEXTURE_TRANSFORM: &str = "KHR_texture_transform";

/// The identity [`TextureRef::transform`].
pub const NO_UV_TRANSFORM: [[f32; 3]; 2] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

/// A `KHR_texture_transform` object (offset, rotation in radians counter-clockwise, scale, and
/// an optional texture-coordinate set that overrides the texture's) as its matrix
/// T(offset) · R(rotation) · S(scale) (the extension's definition, column-major there:
/// R = [[cos, −sin], [sin, cos]]) and that set. Errors name the property.
fn uv_transform(value: &serde_json::Value) -> Result<([[f32; 3]; 2], Option<u32>), String> {
    let pair = |name: &str, default: [f32; 2]| -> Result<[f32; 2], String> {
        match value.get(name) {
            None => Ok(default),
            Some(v) => {
                let items = v.as_array().filter(|a| a.len() == 2);
                let numbers: Option<Vec<f32>> = items.map(|a| {
                    a.iter()
                        .filter_map(|x| x.as_f64().map(|x| x as f32))
                        .filter(|x| x.is_finite())
                        .collect()
                });
                match numbers.as_deref() {
                    Some(&[a, b]) => Ok([a, b]),
                    _ => Err(format!(
                        "KHR_texture_transform.{name} {v} is not two finite numbers"
                    )),
                }
            }
        }
    };
    let offset = pair("offset", [0.0, 0.0])?;
    let scale = pair("scale", [1.0, 1.0])?;
    let rotation = match value.get("rotation") {
        None => 0.0,
        Some(v) => v
            .as_f64()
            .map(|r| r as f32)
            .filter(|r| r.is_finite())
            .ok_or_else(|| format!("KHR_texture_transform.rotation {v} is not a finite number"))?,
    };
    let set = match value.get("texCoord") {
        None => None,
        Some(v) => Some(
            v.as_u64()
                .and_then(|s| u32::try_from(s).ok())
                .ok_or_else(|| format!("KHR_texture_transform.texCoord {v} is not a set index"))?,
        ),
    };
    let (s, c) = rotation.sin_cos();
    Ok((
        [
            [c * scale[0], -s * scale[1], offset[0]],
            [s * scale[0], c * scale[1], offset[1]],
        ],
        set,
    ))
}

/// The textures of a material, each multiplying its factor (glTF's metallic-roughness model),
/// its tangent-space normal texture, its ambient-occlusion texture and its emission texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaterialTextures {
    /// sRGB-encoded base colour (RGB), and in A a linear alpha (read where
    /// [`Material::alpha_mode`] is not opaque).
    pub base_color: Option<TextureRef>,
    /// Linear; roughness in G, metallic in B.
    pub metallic_roughness: Option<TextureRef>,
    /// Linear; a tangent-space normal (x right, y up the image, z out of the surface) as
    /// RGB = (n + 1)/2.
    pub normal: Option<TextureRef>,
    /// Scales the normal's x and y (glTF's `normalTexture.scale`).
    pub normal_scale: f32,
    /// Linear; in R, the fraction of the environment's light that reaches the surface (glTF's
    /// `occlusionTexture`: 0 fully occluded, 1 open).
    pub occlusion: Option<TextureRef>,
    /// How much of the occlusion applies (glTF's `occlusionTexture.strength`, in [0, 1]): the
    /// light is scaled by 1 + strength · (R − 1).
    pub occlusion_strength: f32,
    /// sRGB-encoded emission (RGB), multiplying [`Material::emission`].
    pub emissive: Option<TextureRef>,
    /// Linear; in A, the strength of the dielectric specular, multiplying
    /// [`Material::specular_factor`] (glTF's `KHR_materials_specular.specularTexture`).
    pub specular: Option<TextureRef>,
    /// sRGB-encoded tint of the dielectric F0 (RGB), multiplying [`Material::specular_color`]
    /// (`KHR_materials_specular.specularColorTexture`).
    pub specular_color: Option<TextureRef>,
    /// Linear; in R, the clear coat's strength, multiplying [`Material::clearcoat`]
    /// (`KHR_materials_clearcoat.clearcoatTexture`).
    pub clearcoat: Option<TextureRef>,
    /// Linear; in G, the clear coat's roughness, multiplying [`Material::clearcoat_roughness`]
    /// (`clearcoatRoughnessTexture`).
    pub clearcoat_roughness: Option<TextureRef>,
    /// Linear; the clear coat's own tangent-space normal, as [`MaterialTextures::normal`]
    /// (`clearcoatNormalTexture`). Without it the coat follows the interpolated vertex normal,
    /// not the base's normal texture (as the extension asks).
    pub clearcoat_normal: Option<TextureRef>,
    /// Scales the clear-coat normal's x and y (`clearcoatNormalTexture.scale`).
    pub clearcoat_normal_scale: f32,
}

impl MaterialTextures {
    /// The textures in slot order: base colour, metallic-roughness, normal, occlusion,
    /// emissive, specular, specular colour, clear coat, clear-coat roughness, clear-coat
    /// normal ([`SLOT_NAMES`]; the shaders' `TEX_*` slots, `textures::TEXTURE_SLOTS`).
    pub fn slots(&self) -> [Option<TextureRef>; 10] {
        [
            self.base_color,
            self.metallic_roughness,
            self.normal,
            self.occlusion,
            self.emissive,
            self.specular,
            self.specular_color,
            self.clearcoat,
            self.clearcoat_roughness,
            self.clearcoat_normal,
        ]
    }

    /// [`MaterialTextures::slots`], to change.
    pub fn slots_mut(&mut self) -> [&mut Option<TextureRef>; 10] {
        [
            &mut self.base_color,
            &mut self.metallic_roughness,
            &mut self.normal,
            &mut self.occlusion,
            &mut self.emissive,
            &mut self.specular,
            &mut self.specular_color,
            &mut self.clearcoat,
            &mut self.clearcoat_roughness,
            &mut self.clearcoat_normal,
        ]
    }
}

impl Default for MaterialTextures {
    fn default() -> Self {
        Self {
            base_color: None,
            metallic_roughness: None,
            normal: None,
            normal_scale: 1.0,
            occlusion: None,
            occlusion_strength: 1.0,
            emissive: None,
            specular: None,
            specular_color: None,
            clearcoat: None,
            clearcoat_roughness: None,
            clearcoat_normal: None,
            clearcoat_normal_scale: 1.0,
        }
    }
}

impl Material {
    /// Whether the G-buffer must carry this material's dielectric Fresnel terms and clear coat
    /// per pixel (its fifth target): their textures vary them over the surface, or a clear
    /// coat lies over a normal texture (the coat keeps the interpolated normal, which the
    /// G-buffer does not otherwise hold). Otherwise the shading takes them from the factors.
    pub fn needs_layered_gbuffer(&self) -> bool {
        let t = &self.textures;
        t.specular.is_some()
            || t.specular_color.is_some()
            || (self.clearcoat > 0.0
                && (t.normal.is_some()
                    || t.clearcoat.is_some()
                    || t.clearcoat_roughness.is_some()
                    || t.clearcoat_normal.is_some()))
    }
}

/// A texture image of a scene, decoded to 8-bit RGBA (still in its own encoding: sRGB for base
/// colours, linear for metallic-roughness).
#[derive(Clone, Debug, PartialEq)]
pub struct TextureImage {
    /// Where it came from, for messages ("image 2 (bricks.png)").
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Row-major RGBA, `width × height × 4` bytes.
    pub rgba: Vec<u8>,
}

impl TextureImage {
    /// The linear RGB of an sRGB-encoded image at texture coordinates `uv` (texel centres at
    /// (i + 0.5)/width), filtered bilinearly with the wrap modes applied texel by texel. Black
    /// for an image whose bytes do not match its size.
    pub fn sample_srgb(&self, uv: [f32; 2], wrap: [Wrap; 2]) -> [f32; 3] {
        let (w, h) = (self.width as usize, self.height as usize);
        if w == 0 || h == 0 || self.rgba.len() != w * h * 4 {
            return [0.0; 3];
        }
        let texel_index = |i: i64, n: usize, mode: Wrap| -> usize {
            let n = n as i64;
            (match mode {
                Wrap::Repeat => i.rem_euclid(n),
                Wrap::ClampToEdge => i.clamp(0, n - 1),
                Wrap::MirroredRepeat => {
                    let m = i.rem_euclid(2 * n);
                    if m < n {
                        m
                    } else {
                        2 * n - 1 - m
                    }
                }
            }) as usize
        };
        let decode = |byte: u8| super::output::srgb_eotf(f32::from(byte) / 255.0);
        // Texel-space position, centres at integers; far-out coordinates are reduced first
        // (f32 texel positions past 2^24 have no fraction left).
        let axis = |t: f32, n: usize| {
            let x = f64::from(t) * n as f64 - 0.5;
            let base = x.floor();
            (base as i64, (x - base) as f32)
        };
        let (x0, fx) = axis(uv[0], w);
        let (y0, fy) = axis(uv[1], h);
        let mut out = [0.0f32; 3];
        for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
            for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
                let x = texel_index(x0.saturating_add(dx), w, wrap[0]);
                let y = texel_index(y0.saturating_add(dy), h, wrap[1]);
                let p = &self.rgba[(y * w + x) * 4..][..3];
                for c in 0..3 {
                    out[c] += wx * wy * decode(p[c]);
                }
            }
        }
        out
    }
}

/// A metallic-roughness material (glTF's model).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Linear base colour (albedo for dielectrics, F0 for metals).
    pub base_color: [f32; 3],
    /// Perceptual roughness in [0, 1]; GGX α = roughness².
    pub roughness: f32,
    /// 0: dielectric, 1: metal.
    pub metallic: f32,
    /// Dielectric specular level (Filament's): F0 = 0.16 · specular²; 0.5 gives F0 = 0.04
    /// (glTF's default index of refraction, 1.5; `KHR_materials_ior` sets it). 0 makes a
    /// dielectric purely Lambertian.
    pub specular: f32,
    /// Tint of the dielectric F0 (`KHR_materials_specular`'s `specularColorFactor`; white by
    /// default): F0 = min(0.16 · specular² · tint, 1) · `specular_factor`.
    pub specular_color: [f32; 3],
    /// Strength of the dielectric specular (`KHR_materials_specular`'s `specularFactor`, in
    /// [0, 1]; 1 by default): scales F0 and the grazing reflectance F90.
    pub specular_factor: f32,
    /// Strength of a clear coat over the material (`KHR_materials_clearcoat`'s
    /// `clearcoatFactor`, in [0, 1]; 0: none): a dielectric GGX layer of F0 0.04 whose
    /// Fresnel reflectance Fc takes the fraction `clearcoat` · Fc of the light from the
    /// material beneath.
    pub clearcoat: f32,
    /// The clear coat's perceptual roughness (`clearcoatRoughnessFactor`, in [0, 1]).
    pub clearcoat_roughness: f32,
    /// Emitted radiance (linear RGB, W·sr⁻¹·m⁻² in the lights' units), added to the light the
    /// surface reflects: glTF's `emissiveFactor` times `KHR_materials_emissive_strength`.
    /// Zero for a surface that does not glow.
    pub emission: [f32; 3],
    /// The base colour's alpha (glTF's `baseColorFactor[3]`), times the base-colour texture's
    /// A where there is one.
    pub alpha: f32,
    /// What the alpha does (glTF's `alphaMode`): nothing, cut the surface out, or blend it
    /// over what lies behind.
    pub alpha_mode: AlphaMode,
    /// glTF's `doubleSided`: seen from behind (its triangles winding clockwise on screen), the
    /// surface is shaded with its normal reversed; single-sided, its back is not drawn (it
    /// still casts shadows). OBJ and built-in materials are double-sided.
    pub double_sided: bool,
    /// Textures multiplying `base_color`, `roughness`, `metallic` and `emission`, the normal
    /// texture and the occlusion texture.
    pub textures: MaterialTextures,
}

impl Default for Material {
    fn default() -> Self {
        Self {
            base_color: [0.8, 0.8, 0.8],
            roughness: 0.5,
            metallic: 0.0,
            specular: 0.5,
            specular_color: [1.0; 3],
            specular_factor: 1.0,
            clearcoat: 0.0,
            clearcoat_roughness: 0.0,
            emission: [0.0; 3],
            alpha: 1.0,
            alpha_mode: AlphaMode::Opaque,
            double_sided: true,
            textures: MaterialTextures::default(),
        }
    }
}

impl Material {
    /// A purely Lambertian material of the given albedo.
    pub fn lambertian(albedo: [f32; 3]) -> Self {
        Self {
            base_color: albedo,
            roughness: 1.0,
            metallic: 0.0,
            specular: 0.0,
            ..Self::default()
        }
    }
}

/// What a material's alpha does (glTF's `alphaMode`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum AlphaMode {
    /// The alpha is not read: the surface is opaque.
    #[default]
    Opaque,
    /// glTF's MASK with its `alphaCutoff`: where the alpha is below the cutoff the surface is
    /// not there — not drawn, and casting no shadow.
    Mask(f32),
    /// glTF's BLEND: the surface is drawn over what lies behind it by the over operator
    /// (colour · α + behind · (1 − α)), after the opaque surfaces, back to front. Its shadow
    /// blocks the fraction α of the light (glTF's alpha is coverage): in the shadow maps it
    /// covers the fraction α of the texels in an ordered-dither pattern, which the shadow
    /// filter averages (a shadow map holds one depth, not a transmittance).
    Blend,
}

/// A perspective camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    /// Vertical field of view in radians.
    pub fov_y: f32,
}

impl Camera {
    pub fn view(&self) -> Mat4 {
        let fwd = (self.target - self.eye).normalize_or(Vec3::NEG_Z);
        let up = if fwd.y.abs() > 0.999 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        look_at_rh(self.eye, self.target, up)
    }

    /// The camera in words, for the log: eye, look-at point, vertical field of view.
    pub fn describe(&self) -> String {
        let p = |v: Vec3| format!("({:.3}, {:.3}, {:.3})", v.x, v.y, v.z);
        format!(
            "eye {}, looking at {}, vertical field of view {:.1}°",
            p(self.eye),
            p(self.target),
            self.fov_y.to_degrees()
        )
    }

    /// View-projection with wgpu's [0, 1] depth range.
    pub fn view_proj(&self, aspect: f32, near: f32, far: f32) -> Mat4 {
        perspective_rh(self.fov_y, aspect, near, far) * self.view()
    }
}

/// Right-handed view matrix (camera looks along −Z).
pub fn look_at_rh(eye: Vec3, center: Vec3, up: Vec3) -> Mat4 {
    let f = (center - eye).normalize();
    let s = f.cross(up).normalize();
    let u = s.cross(f);
    Mat4::from_cols(
        glam::Vec4::new(s.x, u.x, -f.x, 0.0),
        glam::Vec4::new(s.y, u.y, -f.y, 0.0),
        glam::Vec4::new(s.z, u.z, -f.z, 0.0),
        glam::Vec4::new(-s.dot(eye), -u.dot(eye), f.dot(eye), 1.0),
    )
}

/// Right-handed perspective projection with depth in [0, 1] (wgpu).
pub fn perspective_rh(fov_y: f32, aspect: f32, near: f32, far: f32) -> Mat4 {
    let h = 1.0 / (0.5 * fov_y).tan();
    let w = h / aspect;
    let r = far / (near - far);
    Mat4::from_cols(
        glam::Vec4::new(w, 0.0, 0.0, 0.0),
        glam::Vec4::new(0.0, h, 0.0, 0.0),
        glam::Vec4::new(0.0, 0.0, r, -1.0),
        glam::Vec4::new(0.0, 0.0, r * near, 0.0),
    )
}

/// Right-handed orthographic projection with depth in [0, 1] (wgpu).
pub fn orthographic_rh(left: f32, right: f32, bottom: f32, top: f32, near: f32, far: f32) -> Mat4 {
    let rw = 1.0 / (right - left);
    let rh = 1.0 / (top - bottom);
    let r = 1.0 / (near - far);
    Mat4::from_cols(
        glam::Vec4::new(2.0 * rw, 0.0, 0.0, 0.0),
        glam::Vec4::new(0.0, 2.0 * rh, 0.0, 0.0),
        glam::Vec4::new(0.0, 0.0, r, 0.0),
        glam::Vec4::new(-(left + right) * rw, -(top + bottom) * rh, r * near, 1.0),
    )
}

/// A bounding sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    pub center: Vec3,
    pub radius: f32,
}

/// Ground plane options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ground {
    /// Height of the plane (y).
    pub height: f32,
    /// Half the side of the square plane.
    pub half_size: f32,
    pub material: Material,
}

/// A renderable scene.
#[derive(Clone, Debug)]
pub struct Scene {
    pub vertices: Vec<Vertex>,
    pub indices: Vec<u32>,
    /// Indices `0..caster_indices` are shadow casters; the rest (the ground) only receive.
    pub caster_indices: u32,
    pub materials: Vec<Material>,
    /// The texture images the materials use ([`TextureRef::image`] indexes them).
    pub textures: Vec<TextureImage>,
    /// Index of the ground's material, if the scene has a ground plane.
    pub ground_material: Option<u32>,
    pub camera: Camera,
    /// Bounding sphere of the shadow casters.
    pub bounds: Sphere,
}

/// Accumulates meshes (casters first), then the ground.
#[derive(Default)]
struct Builder {
    vertices: Vec<Vertex>,
    indices: Vec<u32>,
    materials: Vec<Material>,
    textures: Vec<TextureImage>,
    /// The file's own camera (glTF's first perspective camera node), if any.
    camera: Option<Camera>,
}

impl Builder {
    fn material(&mut self, m: Material) -> u32 {
        self.materials.push(m);
        (self.materials.len() - 1) as u32
    }

    /// Adds a mesh; `uvs` holds one texture coordinate per position, or none.
    fn mesh(
        &mut self,
        positions: &[Vec3],
        normals: &[Vec3],
        uvs: &[[f32; 2]],
        indices: &[u32],
        material: u32,
    ) {
        let base = self.vertices.len() as u32;
        for (i, (p, n)) in positions.iter().zip(normals).enumerate() {
            self.vertices.push(Vertex {
                position: p.to_array(),
                normal: n.normalize_or(Vec3::Y).to_array(),
                material,
                uv: uvs.get(i).copied().unwrap_or([0.0; 2]),
                uv1: [0.0; 2],
                tangent: [0.0; 4],
                color: WHITE,
            });
        }
        self.indices.extend(indices.iter().map(|i| base + i));
    }

    /// Sets the tangents of the vertices from `first` on (one per vertex of the mesh added
    /// there).
    fn set_tangents(&mut self, first: usize, tangents: &[[f32; 4]]) {
        for (v, t) in self.vertices[first..].iter_mut().zip(tangents) {
            v.tangent = *t;
        }
    }

    /// Sets the colours ([`Vertex::color`]) of the vertices from `first` on.
    fn set_colors(&mut self, first: usize, colors: &[[u16; 4]]) {
        for (v, c) in self.vertices[first..].iter_mut().zip(colors) {
            v.color = *c;
        }
    }

    /// Sets the second texture coordinates ([`Vertex::uv1`]) of the vertices from `first` on.
    fn set_second_uvs(&mut self, first: usize, uvs: &[[f32; 2]]) {
        for (v, uv) in self.vertices[first..].iter_mut().zip(uvs) {
            v.uv1 = *uv;
        }
    }

    fn uv_sphere(&mut self, center: Vec3, radius: f32, segments: u32, material: u32) {
        let rings = segments / 2;
        let mut pos = Vec::new();
        let mut nor = Vec::new();
        for r in 0..=rings {
            let theta = std::f32::consts::PI * r as f32 / rings as f32;
            for s in 0..=segments {
                let phi = std::f32::consts::TAU * s as f32 / segments as f32;
                let n = Vec3::new(
                    theta.sin() * phi.sin(),
                    theta.cos(),
                    theta.sin() * phi.cos(),
                );
                pos.push(center + radius * n);
                nor.push(n);
            }
        }
        let mut idx = Vec::new();
        let row = segments + 1;
        for r in 0..rings {
            for s in 0..segments {
                let a = r * row + s;
                let b = a + row;
                idx.extend_from_slice(&[a, b, a + 1, a + 1, b, b + 1]);
            }
        }
        self.mesh(&pos, &nor, &[], &idx, material);
    }

    fn cuboid(&mut self, center: Vec3, half: Vec3, material: u32) {
        let mut pos = Vec::new();
        let mut nor = Vec::new();
        let mut idx = Vec::new();
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let mut n = Vec3::ZERO;
                n[axis] = sign;
                let u = Vec3::from_array(std::array::from_fn(|i| {
                    if i == (axis + 1) % 3 {
                        1.0
                    } else {
                        0.0
                    }
                }));
                let v = n.cross(u);
                let base = pos.len() as u32;
                for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                    pos.push(center + (n + a * u + b * v) * half);
                    nor.push(n);
                }
                // (u, v, n) is right-handed: counter-clockwise seen from outside.
                idx.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
            }
        }
        self.mesh(&pos, &nor, &[], &idx, material);
    }

    /// Finishes the casters, adds the ground (if any) and fits the camera when none is given.
    fn finish(mut self, ground: Option<Ground>, camera: Option<Camera>) -> Scene {
        let bounds = bounding_sphere(&self.vertices);
        let caster_indices = self.indices.len() as u32;
        let ground_material = ground.map(|g| {
            let m = self.material(g.material);
            let h = g.half_size;
            let y = g.height;
            let pos = [
                Vec3::new(-h, y, -h),
                Vec3::new(-h, y, h),
                Vec3::new(h, y, h),
                Vec3::new(h, y, -h),
            ];
            self.mesh(&pos, &[Vec3::Y; 4], &[], &[0, 1, 2, 0, 2, 3], m);
            m
        });
        let camera = camera.unwrap_or_else(|| fit_camera(bounds));
        Scene {
            vertices: self.vertices,
            indices: self.indices,
            caster_indices,
            materials: self.materials,
            textures: self.textures,
            ground_material,
            camera,
            bounds,
        }
    }
}

/// A glTF perspective camera placed by its node's world transform `world` (it looks along the
/// node's −Z with +Y up) with vertical field of view `yfov` (radians): the camera's eye and
/// target (one unit ahead). The renderer keeps the horizon level (+Y up), so a camera rolled
/// about its view direction is drawn unrolled, with a warning; glTF's aspect ratio and clip
/// planes are the renderer's own (the image's, and the scene's bounds).
fn gltf_camera(world: Mat4, yfov: f32) -> Result<Camera, String> {
    if !(yfov.is_finite() && yfov > 0.0 && yfov < std::f32::consts::PI) {
        return Err(format!("yfov {yfov} is not an angle in (0, π) radians"));
    }
    let eye = world.transform_point3(Vec3::ZERO);
    let forward = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
    if !eye.is_finite() || forward == Vec3::ZERO || !forward.is_finite() {
        return Err("its transform does not place it (not finite, or degenerate)".into());
    }
    let up = world.transform_vector3(Vec3::Y).normalize_or_zero();
    if forward.y.abs() < 0.999 {
        let level = forward.cross(Vec3::Y).normalize().cross(forward);
        let roll = up.dot(level).clamp(-1.0, 1.0).acos().to_degrees();
        if roll > 1.0 {
            tracing::warn!(
                "a glTF camera rolled {roll:.0}° about its view direction is drawn level (+Y up)"
            );
        }
    }
    Ok(Camera {
        eye,
        target: eye + forward,
        fov_y: yfov,
    })
}

/// A camera set by the user over a scene's own (`envlight render --eye`, `--look-at`, `--fov`;
/// the daemon's `[render] eye`, `look_at`, `fov_deg`): each given part replaces the camera's.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CameraOverride {
    pub eye: Option<Vec3>,
    pub look_at: Option<Vec3>,
    /// Vertical field of view, degrees.
    pub fov_deg: Option<f32>,
}

impl CameraOverride {
    /// The range of [`CameraOverride::fov_deg`].
    pub const FOV_DEG: std::ops::RangeInclusive<f32> = 1.0..=179.0;

    /// `camera` with the given parts replaced; an error where a part is not finite, the field
    /// of view is outside [`CameraOverride::FOV_DEG`] or the eye is at the point it looks at.
    pub fn apply(&self, camera: Camera) -> Result<Camera, String> {
        let mut c = camera;
        if let Some(eye) = self.eye {
            if !eye.is_finite() {
                return Err(format!("camera eye {eye} is not finite"));
            }
            c.eye = eye;
        }
        if let Some(target) = self.look_at {
            if !target.is_finite() {
                return Err(format!("camera look-at point {target} is not finite"));
            }
            c.target = target;
        }
        if let Some(fov) = self.fov_deg {
            if !Self::FOV_DEG.contains(&fov) {
                return Err(format!(
                    "field of view {fov}° is outside {}..={}°",
                    Self::FOV_DEG.start(),
                    Self::FOV_DEG.end()
                ));
            }
            c.fov_y = fov.to_radians();
        }
        if c.eye.distance(c.target) < 1e-6 * (1.0 + c.eye.length()) {
            return Err(format!(
                "the camera's eye {} is where it looks ({}); give another --look-at or --eye",
                c.eye, c.target
            ));
        }
        Ok(c)
    }
}

/// A camera looking at the sphere from the front and a little above, framing it.
pub fn fit_camera(bounds: Sphere) -> Camera {
    let fov_y = 40f32.to_radians();
    let dist = bounds.radius / (fov_y * 0.5).sin() * 1.15;
    let dir = Vec3::new(0.0, 0.35, 1.0).normalize();
    Camera {
        eye: bounds.center + dir * dist,
        target: bounds.center,
        fov_y,
    }
}

/// Ritter-style bounding sphere: the box centre and the farthest vertex.
fn bounding_sphere(vertices: &[Vertex]) -> Sphere {
    if vertices.is_empty() {
        return Sphere {
            center: Vec3::ZERO,
            radius: 1.0,
        };
    }
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for v in vertices {
        let p = Vec3::from_array(v.position);
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let center = 0.5 * (lo + hi);
    let radius = vertices
        .iter()
        .map(|v| Vec3::from_array(v.position).distance(center))
        .fold(0.0f32, f32::max)
        .max(1e-3);
    Sphere { center, radius }
}

/// Smooth vertex normals (area-weighted face normals, unit length), for meshes that have
/// none. The sums are in f64, so large but finite coordinates do not overflow.
fn smooth_normals(positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
    let mut n = vec![glam::DVec3::ZERO; positions.len()];
    for t in indices.chunks_exact(3) {
        let [a, b, c] = [t[0] as usize, t[1] as usize, t[2] as usize];
        let [pa, pb, pc] = [positions[a], positions[b], positions[c]].map(|p| p.as_dvec3());
        let f = (pb - pa).cross(pc - pa);
        n[a] += f;
        n[b] += f;
        n[c] += f;
    }
    n.into_iter()
        .map(|v| v.normalize_or_zero().as_vec3())
        .collect()
}

/// Replaces the zero normals a file gives (`vn 0 0 0`, a zero NORMAL) by the vertex's smooth
/// normal from its triangles, and says how many there were (they were drawn facing +Y: lit as
/// if facing up, whatever their triangle's orientation). Returns the count.
fn repair_zero_normals(
    path: &Path,
    positions: &[Vec3],
    normals: &mut [Vec3],
    indices: &[u32],
) -> usize {
    let zero = |n: &Vec3| n.is_finite() && n.length_squared() == 0.0;
    let count = normals.iter().filter(|n| zero(n)).count();
    if count > 0 {
        let smooth = smooth_normals(positions, indices);
        for (n, s) in normals.iter_mut().zip(smooth) {
            if zero(n) {
                *n = s;
            }
        }
        tracing::warn!(
            "{}: {count} vertices have a zero normal; using their triangles' normal instead",
            path.display()
        );
    }
    count
}

/// The matrix that carries normals through `world`: the cofactor matrix of its linear part,
/// which is det · (M⁻¹)ᵀ, with the sign of the determinant taken out. Unlike the inverse
/// transpose it exists for a singular transform (a node scaled by 0 flattens its mesh; the
/// normals of the flat mesh are still defined).
///
/// Computed in f64 and scaled so that its largest entry is 1 (the normals are normalised
/// later), so that large scales do not overflow f32.
fn normal_matrix(world: Mat4) -> Mat3 {
    let m = Mat3::from_mat4(world).as_dmat3();
    let (a, b, c) = (m.x_axis, m.y_axis, m.z_axis);
    let cofactor = glam::DMat3::from_cols(b.cross(c), c.cross(a), a.cross(b));
    let largest = cofactor
        .to_cols_array()
        .iter()
        .fold(0.0f64, |l, v| l.max(v.abs()));
    let scale = if largest > 0.0 && largest.is_finite() {
        largest.recip()
    } else {
        1.0
    };
    let sign = if m.determinant() < 0.0 { -1.0 } else { 1.0 };
    (cofactor * (sign * scale)).as_mat3()
}

impl Scene {
    /// Three spheres (glossy, medium, rough) and a box on a grey ground plane.
    pub fn default_scene() -> Self {
        let mut b = Builder::default();
        let glossy = b.material(Material {
            base_color: [0.9, 0.2, 0.15],
            roughness: 0.15,
            metallic: 0.0,
            specular: 0.5,
            ..Material::default()
        });
        let metal = b.material(Material {
            base_color: [0.95, 0.8, 0.5],
            roughness: 0.35,
            metallic: 1.0,
            specular: 0.5,
            ..Material::default()
        });
        let rough = b.material(Material {
            base_color: [0.2, 0.5, 0.85],
            roughness: 0.8,
            metallic: 0.0,
            specular: 0.5,
            ..Material::default()
        });
        let matte = b.material(Material::lambertian([0.75, 0.75, 0.7]));
        b.uv_sphere(Vec3::new(-1.15, 0.5, 0.0), 0.5, 48, glossy);
        b.uv_sphere(Vec3::new(0.0, 0.5, -0.3), 0.5, 48, metal);
        b.uv_sphere(Vec3::new(1.15, 0.5, 0.0), 0.5, 48, rough);
        b.cuboid(Vec3::new(0.3, 0.2, 0.9), Vec3::new(0.2, 0.2, 0.2), matte);
        let camera = Camera {
            eye: Vec3::new(0.0, 1.9, 4.6),
            target: Vec3::new(0.0, 0.35, 0.0),
            fov_y: 40f32.to_radians(),
        };
        b.finish(
            Some(Ground {
                height: 0.0,
                half_size: 6.0,
                material: Material {
                    base_color: [0.5, 0.5, 0.5],
                    roughness: 0.9,
                    metallic: 0.0,
                    specular: 0.5,
                    ..Material::default()
                },
            }),
            Some(camera),
        )
    }

    /// One sphere of the given material, with an optional ground plane, for tests and
    /// comparisons with analytic references.
    pub fn sphere(
        center: Vec3,
        radius: f32,
        segments: u32,
        material: Material,
        ground: Option<Ground>,
        camera: Camera,
    ) -> Self {
        let mut b = Builder::default();
        let m = b.material(material);
        b.uv_sphere(center, radius, segments.max(4), m);
        b.finish(ground, Some(camera))
    }

    /// Loads a glTF 2.0 (.gltf, .glb) or OBJ (.obj) file, adds a ground plane under it (if
    /// `ground`) and fits the camera to it.
    pub fn load(path: &Path, ground: bool) -> Result<Self, SceneError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        let load = match ext.as_deref() {
            Some("gltf" | "glb") => load_gltf,
            Some("obj") => load_obj,
            _ => {
                // What is not a file (missing, a directory) is said as such before its name.
                if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
                    read_scene_file(path)?;
                }
                return Err(SceneError::UnknownFormat {
                    path: path.to_path_buf(),
                });
            }
        };
        // The checks before the gltf and tobj crates cover what they were found to panic on;
        // a panic still left in them becomes an error naming the file (the default panic hook
        // prints its message to stderr too).
        let b = std::panic::catch_unwind(|| load(path)).unwrap_or_else(|panic| {
            let what = (panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_string());
            let (path, message) = (path.to_path_buf(), format!("the reader panicked: {what}"));
            Err(if ext.as_deref() == Some("obj") {
                SceneError::Obj { path, message }
            } else {
                SceneError::Gltf { path, message }
            })
        })?;
        if b.indices.is_empty() {
            return Err(SceneError::Empty {
                path: path.to_path_buf(),
            });
        }
        let bounds = bounding_sphere(&b.vertices);
        if !(bounds.radius.is_finite() && bounds.radius <= MAX_SCENE_RADIUS) {
            // f32 sums overflow for coordinates near 1e38: the size is then measured in f64
            // (half the bounding box's diagonal).
            let radius = if bounds.radius.is_finite() {
                f64::from(bounds.radius)
            } else {
                let (low, high) = b.vertices.iter().fold(
                    (glam::DVec3::splat(f64::MAX), glam::DVec3::splat(f64::MIN)),
                    |(low, high), v| {
                        let p = Vec3::from_array(v.position).as_dvec3();
                        (low.min(p), high.max(p))
                    },
                );
                0.5 * (high - low).length()
            };
            return Err(SceneError::TooLarge {
                path: path.to_path_buf(),
                radius,
            });
        }
        let distance = bounds.center.as_dvec3().length();
        if distance > f64::from(MAX_SCENE_OFFSET * bounds.radius) {
            return Err(SceneError::TooFar {
                path: path.to_path_buf(),
                distance,
                radius: bounds.radius,
                ratio: distance / f64::from(bounds.radius),
            });
        }
        let low = b
            .vertices
            .iter()
            .map(|v| v.position[1])
            .fold(f32::INFINITY, f32::min);
        let g = ground.then_some(Ground {
            height: low,
            half_size: bounds.radius * 6.0 + bounds.center.x.abs().max(bounds.center.z.abs()),
            material: Material {
                base_color: [0.5, 0.5, 0.5],
                roughness: 0.9,
                metallic: 0.0,
                specular: 0.5,
                ..Material::default()
            },
        });
        let camera = b.camera;
        Ok(b.finish(g, camera))
    }

    /// The base colour (linear) at vertex `index`: its material's factor times its texture
    /// sampled bilinearly at the vertex's texture coordinates times its colour — for per-vertex
    /// shading (the wavelet relighting's albedo). White past the vertex list.
    pub fn vertex_base_color(&self, index: usize) -> [f32; 3] {
        let Some(v) = self.vertices.get(index) else {
            return [1.0; 3];
        };
        let c = self
            .vertex_color(index, |m| (m.base_color, m.textures.base_color))
            .unwrap_or([1.0; 3]);
        [0, 1, 2].map(|k| c[k] * f32::from(v.color[k]) / f32::from(u16::MAX))
    }

    /// The emitted radiance (linear) at vertex `index`: its material's emission times its
    /// emissive texture, as [`Scene::vertex_base_color`] reads the base colour. Zero past the
    /// vertex list.
    pub fn vertex_emission(&self, index: usize) -> [f32; 3] {
        self.vertex_color(index, |m| (m.emission, m.textures.emissive))
            .unwrap_or([0.0; 3])
    }

    /// A factor of vertex `index`'s material times its sRGB texture (`pick` chooses both) at
    /// the vertex's texture coordinates; `None` past the vertex or material list.
    fn vertex_color(
        &self,
        index: usize,
        pick: impl Fn(&Material) -> ([f32; 3], Option<TextureRef>),
    ) -> Option<[f32; 3]> {
        let v = self.vertices.get(index)?;
        let (factor, texture) = pick(self.materials.get(v.material as usize)?);
        let texel = texture
            .and_then(|t| Some((self.textures.get(t.image as usize)?, t)))
            .map_or([1.0; 3], |(image, t)| {
                let uv = if t.channel == 1 { v.uv1 } else { v.uv };
                image.sample_srgb(t.image_coordinates(uv), t.wrap)
            });
        Some([0, 1, 2].map(|c| factor[c] * texel[c]))
    }

    /// Number of triangles that cast shadows.
    pub fn caster_triangles(&self) -> u32 {
        self.caster_indices / 3
    }

    /// What the scene holds, in words, for the log: triangles (and how many cast shadows),
    /// materials (and how many are blended, cut out, clear-coated, emissive or textured) and
    /// texture images, so that a user sees what of a file was taken up.
    pub fn summary(&self) -> String {
        let count = |f: &dyn Fn(&Material) -> bool| self.materials.iter().filter(|m| f(m)).count();
        let kinds = [
            ("blended", count(&|m| m.alpha_mode == AlphaMode::Blend)),
            (
                "cut out",
                count(&|m| matches!(m.alpha_mode, AlphaMode::Mask(_))),
            ),
            ("clear-coated", count(&|m| m.clearcoat > 0.0)),
            ("emissive", count(&|m| m.emission.iter().any(|&e| e > 0.0))),
            (
                "textured",
                count(&|m| m.textures.slots().iter().any(Option::is_some)),
            ),
        ];
        let kinds: Vec<String> = kinds
            .iter()
            .filter(|(_, n)| *n > 0)
            .map(|(what, n)| format!("{n} {what}"))
            .collect();
        let counted = |n: usize, what: &str| match n {
            1 => format!("1 {what}"),
            _ => format!("{n} {what}s"),
        };
        let mut materials = counted(self.materials.len(), "material");
        if !kinds.is_empty() {
            materials += &format!(" ({})", kinds.join(", "));
        }
        format!(
            "{} ({} casting shadows), {materials}, {}",
            counted(self.indices.len() / 3, "triangle"),
            self.caster_triangles(),
            counted(self.textures.len(), "texture image")
        )
    }
}

/// Checks what the `gltf` crate's reader takes on trust (it panics or aborts otherwise): the
/// type and component type (`dimensions` and one of `types`: POSITION and NORMAL are VEC3
/// floats, indices SCALAR unsigned integers), a count between 1 and [`MAX_SCENE_ELEMENTS`],
/// the elements, sparse values and sparse indices within their buffer views and the views
/// within their buffers ([`check_span`]), and a sparse accessor's indices within its count.
/// Returns the problem, worded to follow the accessor's name.
fn check_accessor(
    accessor: &gltf::Accessor,
    buffers: &[gltf::buffer::Data],
    dimensions: gltf::accessor::Dimensions,
    types: &[gltf::accessor::DataType],
) -> Result<(), String> {
    let index = accessor.index();
    if accessor.dimensions() != dimensions {
        return Err(format!(
            "accessor {index} has type {:?}; expected {dimensions:?}",
            accessor.dimensions()
        ));
    }
    if !types.contains(&accessor.data_type()) {
        return Err(format!(
            "accessor {index} has component type {:?}; expected {}",
            accessor.data_type(),
            types
                .iter()
                .map(|t| format!("{t:?}"))
                .collect::<Vec<_>>()
                .join(" or ")
        ));
    }
    if accessor.count() > MAX_SCENE_ELEMENTS {
        return Err(format!(
            "accessor {index} holds {} elements, more than the {MAX_SCENE_ELEMENTS} a scene \
             may have",
            accessor.count()
        ));
    }
    if accessor.count() == 0 {
        return Err(format!(
            "accessor {index} has a count of 0 (glTF requires at least 1)"
        ));
    }
    if let Some(view) = accessor.view() {
        let stride = view.stride().unwrap_or(accessor.size());
        check_span(
            &view,
            accessor.offset(),
            stride,
            accessor.count(),
            accessor.size(),
            buffers,
        )
        .map_err(|m| format!("accessor {index}: {m}"))?;
    }
    if let Some(sparse) = accessor.sparse() {
        if sparse.count() == 0 {
            return Err(format!(
                "accessor {index}: its sparse count is 0 (glTF requires at least 1)"
            ));
        }
        let values = sparse.values();
        let value_stride = values.view().stride().unwrap_or(accessor.size());
        check_span(
            &values.view(),
            values.offset(),
            value_stride,
            sparse.count(),
            accessor.size(),
            buffers,
        )
        .map_err(|m| format!("accessor {index}: its sparse values: {m}"))?;
        let indices = sparse.indices();
        let view = indices.view();
        let width = match indices.index_type() {
            gltf::accessor::sparse::IndexType::U8 => 1,
            gltf::accessor::sparse::IndexType::U16 => 2,
            gltf::accessor::sparse::IndexType::U32 => 4,
        };
        let stride = view.stride().unwrap_or(width);
        check_span(
            &view,
            indices.offset(),
            stride,
            sparse.count(),
            width,
            buffers,
        )
        .map_err(|m| format!("accessor {index}: its sparse indices: {m}"))?;
        // Within the view, which lies within its buffer: the sums below cannot overflow.
        let data = &buffers[view.buffer().index()].0[view.offset() + indices.offset()..];
        for k in 0..sparse.count() {
            let mut le = [0u8; 4];
            le[..width].copy_from_slice(&data[k * stride..k * stride + width]);
            let i = u32::from_le_bytes(le) as usize;
            if i >= accessor.count() {
                return Err(format!(
                    "accessor {index}: sparse index {i} out of range of its count {}",
                    accessor.count()
                ));
            }
        }
    }
    Ok(())
}

/// Checks that `count` elements of `size` bytes, `stride` bytes apart from byte `offset` of
/// `view`, lie within the view, and the view within its buffer, in checked arithmetic: the
/// `gltf` crate's reader adds and multiplies these unchecked (offsets near 2⁶⁴ overflow, a
/// panic with overflow checks on) and reads a view past its buffer as no data.
fn check_span(
    view: &gltf::buffer::View,
    offset: usize,
    stride: usize,
    count: usize,
    size: usize,
    buffers: &[gltf::buffer::Data],
) -> Result<(), String> {
    if stride < size {
        return Err(format!(
            "buffer view {} has a byteStride of {stride} bytes, less than one element ({size} \
             bytes)",
            view.index()
        ));
    }
    let buffer_bytes = buffers.get(view.buffer().index()).map_or(0, |d| d.0.len());
    if view
        .offset()
        .checked_add(view.length())
        .is_none_or(|end| end > buffer_bytes)
    {
        return Err(format!(
            "buffer view {} ({} bytes from byte {}) lies outside buffer {} of {buffer_bytes} bytes",
            view.index(),
            view.length(),
            view.offset(),
            view.buffer().index()
        ));
    }
    let end = count
        .checked_sub(1)
        .and_then(|last| last.checked_mul(stride))
        .and_then(|bytes| bytes.checked_add(offset))
        .and_then(|bytes| bytes.checked_add(size));
    if end.is_none_or(|end| end > view.length()) {
        return Err(format!(
            "{count} elements of {size} bytes, {stride} apart from byte {offset}, reach past \
             the end of buffer view {} ({} bytes)",
            view.index(),
            view.length()
        ));
    }
    Ok(())
}

/// The largest scene file (OBJ, glTF, GLB) or external glTF buffer that is read: 4 GiB, more
/// than [`MAX_SCENE_ELEMENTS`] vertices and indices need.
pub const MAX_SCENE_FILE_BYTES: u64 = 1 << 32;

/// The largest OBJ material library that is read.
pub const MAX_MTL_BYTES: u64 = 64 << 20;

/// Reads a scene file: a regular file of at most [`MAX_SCENE_FILE_BYTES`].
fn read_scene_file(path: &Path) -> Result<Vec<u8>, SceneError> {
    crate::read_file::read_regular_file(path, MAX_SCENE_FILE_BYTES, "a scene file").map_err(
        |source| SceneError::Io {
            path: path.to_path_buf(),
            source,
        },
    )
}

/// A binary glTF's header declares the file's length, which the `gltf` crate takes on trust
/// (a length under the header's own 12 bytes underflows its subtraction, a panic with overflow
/// checks on).
fn check_glb_header(bytes: &[u8]) -> Result<(), String> {
    if let Some(length) = bytes
        .strip_prefix(b"glTF")
        .and_then(|rest| rest.get(4..8))
        .map(|l| u32::from_le_bytes([l[0], l[1], l[2], l[3]]))
    {
        if length < 12 {
            return Err(format!(
                "its GLB header declares a length of {length} bytes, less than the header's own 12"
            ));
        }
    }
    Ok(())
}

/// Parses and validates a glTF or GLB file as `gltf::Gltf::from_slice` does, but checks first
/// that every primitive attribute names an accessor the file has: gltf-json's validation
/// indexes the accessors with the POSITION attribute's index unchecked (a panic, found by
/// `mutated_gltf_and_glb_files_never_panic`).
/// How far from 1 a node's rotation quaternion may be in length before the warning that it was
/// normalised (glTF requires unit quaternions; files written with few digits miss by ~10⁻⁴).
const UNIT_QUATERNION_TOLERANCE: f64 = 1e-3;

/// A node's transform as glTF 2.0 allows it (section 5.25): a matrix or translation, rotation
/// and scale, not both; a matrix that is affine (its last row 0 0 0 1: decomposable into TRS);
/// finite numbers; a rotation of non-zero length (normalised by the caller).
fn check_node_transform(node: &gltf::json::Node) -> Result<(), String> {
    let trs = node.translation.is_some() || node.rotation.is_some() || node.scale.is_some();
    if let Some(m) = node.matrix {
        if trs {
            return Err(
                "has both a matrix and translation/rotation/scale (glTF allows one \
                        or the other)"
                    .into(),
            );
        }
        if !m.iter().all(|v| v.is_finite()) {
            return Err(format!(
                "matrix {m:?} has a value that is not a finite number"
            ));
        }
        // Column-major: the last row is elements 3, 7, 11 and 15.
        if [m[3], m[7], m[11], m[15]] != [0.0, 0.0, 0.0, 1.0] {
            return Err(format!(
                "matrix's last row is [{}, {}, {}, {}], not [0, 0, 0, 1]: a projective \
                 matrix is not a node transform (glTF requires one that decomposes into \
                 translation, rotation and scale)",
                m[3], m[7], m[11], m[15]
            ));
        }
    }
    let vectors = [
        ("translation", node.translation.map(|v| v.to_vec())),
        ("rotation", node.rotation.map(|r| r.0.to_vec())),
        ("scale", node.scale.map(|v| v.to_vec())),
    ];
    for (name, value) in vectors {
        if let Some(v) = value.filter(|v| !v.iter().all(|x| x.is_finite())) {
            return Err(format!(
                "{name} {v:?} has a value that is not a finite number"
            ));
        }
    }
    if let Some(r) = node.rotation {
        if glam::DVec4::from_array(r.0.map(f64::from)).length() < 1e-6 {
            return Err(format!(
                "rotation {:?} is not a rotation (a unit quaternion x, y, z, w)",
                r.0
            ));
        }
    }
    Ok(())
}

fn parse_gltf(bytes: &[u8], path: &Path) -> Result<gltf::Gltf, String> {
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| e.to_string())?;
    let mut root = document.into_json();
    // The crate refuses a required extension that none of its features enables, those drawn
    // here included: each is checked here, by name, and the list cleared.
    for extension in std::mem::take(&mut root.extensions_required) {
        if !DRAWN_EXTENSIONS.contains(&extension.as_str()) {
            return Err(format!(
                "the file requires extension {extension}, which envlight does not implement \
                 (it draws {})",
                DRAWN_EXTENSIONS.join(", ")
            ));
        }
    }
    for (n, node) in root.nodes.iter_mut().enumerate() {
        check_node_transform(node).map_err(|m| format!("node {n}: {m}"))?;
        if let Some(rotation) = &mut node.rotation {
            // In f64: the length of a quaternion of huge components overflows f32.
            let q = glam::DVec4::from_array(rotation.0.map(f64::from));
            if (q.length() - 1.0).abs() > UNIT_QUATERNION_TOLERANCE {
                tracing::warn!(
                    "{}: node {n}: rotation {:?} is not a unit quaternion (length {}); \
                     normalised",
                    path.display(),
                    rotation.0,
                    q.length()
                );
            }
            rotation.0 = q.normalize().to_array().map(|c| c as f32);
        }
    }
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            for index in primitive.attributes.values() {
                if index.value() >= root.accessors.len() {
                    return Err(format!(
                        "mesh {m} primitive {p}: an attribute names accessor {}, but the file \
                         has {} accessors",
                        index.value(),
                        root.accessors.len()
                    ));
                }
            }
        }
    }
    let document = gltf::Document::from_json(root).map_err(|e| e.to_string())?;
    Ok(gltf::Gltf { document, blob })
}

/// Where a glTF buffer's data is: embedded (`data:` URIs, the GLB blob) or in a file, as the
/// `gltf` crate resolves URIs: `file:` and `file://` as written, a relative URI
/// percent-decoded under `base`.
enum BufferSource {
    Embedded,
    File(PathBuf),
}

/// Resolves a buffer URI (see [`BufferSource`]). A relative URI whose percent-decoding is not
/// UTF-8 is an error (the `gltf` crate panics on it); a scheme it does not know is left to it.
fn buffer_source(base: &Path, uri: &str) -> Result<BufferSource, String> {
    if uri.contains(':') {
        return Ok(
            match uri.strip_prefix("file://").or(uri.strip_prefix("file:")) {
                Some(file) => BufferSource::File(PathBuf::from(file)),
                None => BufferSource::Embedded,
            },
        );
    }
    let decoded = urlencoding::decode(uri)
        .map_err(|e| format!("the URI {uri:?} does not percent-decode to UTF-8 text ({e})"))?;
    Ok(BufferSource::File(base.join(&*decoded)))
}

/// Loads a glTF document's buffers: the files with [`crate::read_file::read_regular_file`]
/// (regular files of at most [`MAX_SCENE_FILE_BYTES`]; the `gltf` crate would read a device
/// without end, or allocate a sparse file's whole size at once), the embedded ones with the
/// `gltf` crate. Each must hold at least its declared `byteLength`. Errors name the buffer.
fn load_gltf_buffers(gltf: &gltf::Gltf, base: &Path) -> Result<Vec<gltf::buffer::Data>, String> {
    let mut blob = gltf.blob.clone();
    let mut buffers = Vec::new();
    for buffer in gltf.document.buffers() {
        let index = buffer.index();
        let source = match buffer.source() {
            gltf::buffer::Source::Uri(uri) => {
                buffer_source(base, uri).map_err(|m| format!("buffer {index}: {m}"))?
            }
            gltf::buffer::Source::Bin => BufferSource::Embedded,
        };
        let mut data = match source {
            BufferSource::File(file) => {
                crate::read_file::read_regular_file(&file, MAX_SCENE_FILE_BYTES, "a glTF buffer")
                    .map_err(|e| format!("buffer {index} ({}): {e}", file.display()))?
            }
            BufferSource::Embedded => {
                gltf::buffer::Data::from_source_and_blob(buffer.source(), None, &mut blob)
                    .map_err(|e| format!("buffer {index}: {e}"))?
                    .0
            }
        };
        if data.len() < buffer.length() {
            return Err(format!(
                "buffer {index} holds {} bytes, less than its byteLength {}",
                data.len(),
                buffer.length()
            ));
        }
        // As the gltf crate does: buffers are padded to four bytes.
        data.resize(data.len().next_multiple_of(4), 0);
        buffers.push(gltf::buffer::Data(data));
    }
    Ok(buffers)
}

fn load_gltf(path: &Path) -> Result<Builder, SceneError> {
    load_gltf_within(path, MAX_SCENE_ELEMENTS)
}

/// [`load_gltf`] with at most `max_elements` vertices and indices in the flattened scene.
fn load_gltf_within(path: &Path, max_elements: usize) -> Result<Builder, SceneError> {
    let err = |message: String| SceneError::Gltf {
        path: path.to_path_buf(),
        message,
    };
    let bytes = read_scene_file(path)?;
    check_glb_header(&bytes).map_err(err)?;
    let gltf = parse_gltf(&bytes, path).map_err(err)?;
    let base = path.parent().unwrap_or(Path::new("."));
    let buffers = load_gltf_buffers(&gltf, base).map_err(err)?;
    let mut b = Builder::default();
    let mut material_ids = std::collections::HashMap::new();
    let mut images = std::collections::HashMap::new();
    let mut ignored = std::collections::BTreeSet::<String>::new();
    for extension in gltf.document.extensions_used() {
        if !DRAWN_EXTENSIONS.contains(&extension) {
            ignored.insert(format!("extension {extension}"));
        }
    }
    let scene = gltf
        .document
        .default_scene()
        .or_else(|| gltf.document.scenes().next());
    let Some(scene) = scene else {
        return Err(err("no scene".into()));
    };
    let mut stack: Vec<(gltf::Node, Mat4)> = scene.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
    // glTF's node hierarchy is a forest: a node reached twice sits in a cycle or has several
    // parents (flattening such a graph could multiply the meshes without bound).
    let mut reached = vec![false; gltf.document.nodes().len()];
    let mut camera_nodes: Vec<(usize, Mat4)> = Vec::new();
    while let Some((node, parent)) = stack.pop() {
        match reached.get_mut(node.index()) {
            Some(seen) if !*seen => *seen = true,
            _ => {
                return Err(err(format!(
                    "node {} is reached twice: the node hierarchy has a cycle or a node with \
                     several parents (glTF requires disjoint trees)",
                    node.index()
                )))
            }
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        for child in node.children() {
            stack.push((child, world));
        }
        if node.camera().is_some() {
            camera_nodes.push((node.index(), world));
        }
        let Some(mesh) = node.mesh() else { continue };
        // Only where a mesh is drawn: a helper node without one may overflow harmlessly.
        let node_name = format!("node {} ({:?})", node.index(), node.name().unwrap_or(""));
        if !world.is_finite() {
            return Err(err(format!(
                "{node_name}: its transform combined with its parents' overflows f32 (scales \
                 or translations whose product exceeds 3.4e38)"
            )));
        }
        let normal_matrix = normal_matrix(world);
        let mesh_name = |prim: &gltf::Primitive| {
            format!(
                "mesh {} ({:?}) primitive {}",
                mesh.index(),
                mesh.name().unwrap_or(""),
                prim.index()
            )
        };
        for prim in mesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                tracing::warn!(
                    "{}: skipping a primitive of mode {:?} (only triangles are drawn)",
                    path.display(),
                    prim.mode()
                );
                continue;
            }
            let mat = prim.material();
            let channels = texture_channels(&mat);
            // A normal texture, the base's or the clear coat's, needs the tangent frame.
            let coat_normal =
                extension_texture(&mat, COAT_NORMAL_TEXTURE).is_ok_and(|t| t.is_some());
            let normal_textured = mat.normal_texture().is_some() || coat_normal;
            for (semantic, accessor) in prim.attributes() {
                use gltf::accessor::{
                    DataType::{F32, I16, I8, U16, U8},
                    Dimensions::{Vec2, Vec3, Vec4},
                };
                // Floats, and the integers KHR_mesh_quantization allows (`read_attribute`).
                let (name, dimensions, types) = match semantic {
                    gltf::Semantic::Positions => {
                        ("POSITION".to_string(), Vec3, &[F32, I8, U8, I16, U16][..])
                    }
                    gltf::Semantic::Normals => ("NORMAL".to_string(), Vec3, &[F32, I8, I16][..]),
                    gltf::Semantic::TexCoords(set) if channels.sets.contains(&set) => (
                        format!("TEXCOORD_{set}"),
                        Vec2,
                        &[F32, I8, U8, I16, U16][..],
                    ),
                    gltf::Semantic::Tangents if normal_textured => {
                        ("TANGENT".to_string(), Vec4, &[F32, I8, I16][..])
                    }
                    gltf::Semantic::Colors(0) => {
                        // VEC3 or VEC4.
                        let dimensions = match accessor.dimensions() {
                            Vec3 => Vec3,
                            _ => Vec4,
                        };
                        ("COLOR_0".to_string(), dimensions, &[F32, U8, U16][..])
                    }
                    gltf::Semantic::Colors(_) => {
                        ignored.insert("vertex colours past COLOR_0".into());
                        continue;
                    }
                    _ => continue,
                };
                check_accessor(&accessor, &buffers, dimensions, types)
                    .map_err(|m| err(format!("{}: {name} {m}", mesh_name(&prim))))?;
            }
            if let Some(accessor) = prim.indices() {
                use gltf::accessor::{
                    DataType::{U16, U32, U8},
                    Dimensions::Scalar,
                };
                check_accessor(&accessor, &buffers, Scalar, &[U8, U16, U32])
                    .map_err(|m| err(format!("{}: indices {m}", mesh_name(&prim))))?;
            }
            // The whole scene, flattened, within the per-accessor limit too: nodes that
            // instance one mesh add its vertices again each time (4,000 nodes of one
            // 100,000-vertex mesh, a 1.4 MB file, needed 13 GB).
            let vertex_count = prim
                .get(&gltf::Semantic::Positions)
                .map_or(0, |a| a.count());
            let index_count = prim.indices().map_or(vertex_count, |a| a.count());
            if b.vertices.len() + vertex_count > max_elements
                || b.indices.len() + index_count > max_elements
            {
                return Err(err(format!(
                    "{}: the scene flattened to world space holds more than {max_elements} \
                     vertices or indices ({} and {} before this primitive of {vertex_count} \
                     and {index_count}; every node that uses a mesh adds it again)",
                    mesh_name(&prim),
                    b.vertices.len(),
                    b.indices.len()
                )));
            }
            let reader = prim.reader(|buf| buffers.get(buf.index()).map(|d| &d.0[..]));
            let attribute = |semantic: gltf::Semantic| prim.get(&semantic);
            let Some(positions) = attribute(gltf::Semantic::Positions)
                .and_then(|a| read_attribute::<3>(&a, &buffers))
            else {
                if prim.get(&gltf::Semantic::Positions).is_none() {
                    // The spec's advice for a primitive without positions: skip it.
                    tracing::warn!(
                        "{}: skipping {}: it has no POSITION attribute",
                        path.display(),
                        mesh_name(&prim)
                    );
                    continue;
                }
                return Err(err(format!(
                    "{}: its POSITION accessor cannot be read (out of range of its buffer?)",
                    mesh_name(&prim)
                )));
            };
            let positions: Vec<Vec3> = positions
                .into_iter()
                .map(|p| world.transform_point3(Vec3::from_array(p)))
                .collect();
            let mut indices: Vec<u32> = match (reader.read_indices(), prim.indices()) {
                (Some(i), _) => i.into_u32().collect(),
                (None, None) => (0..positions.len() as u32).collect(),
                (None, Some(_)) => {
                    return Err(err(format!(
                        "{}: its indices accessor cannot be read (out of range of its buffer?)",
                        mesh_name(&prim)
                    )))
                }
            };
            if !indices.len().is_multiple_of(3) {
                return Err(err(format!(
                    "{}: {} indices, not a multiple of 3 (triangles)",
                    mesh_name(&prim),
                    indices.len()
                )));
            }
            if let Some(i) = indices.iter().find(|&&i| i as usize >= positions.len()) {
                return Err(err(format!(
                    "{}: index {i} out of range of its {} vertices",
                    mesh_name(&prim),
                    positions.len()
                )));
            }
            // A mirroring node reverses the triangles' winding (glTF): turned back, so that
            // front faces wind counter-clockwise in world space (single-sided materials, the
            // normals made from the winding).
            if world.determinant() < 0.0 {
                for triangle in indices.chunks_exact_mut(3) {
                    triangle.swap(1, 2);
                }
            }
            let read_normals =
                attribute(gltf::Semantic::Normals).and_then(|a| read_attribute::<3>(&a, &buffers));
            let mut normals: Vec<Vec3> = match read_normals {
                Some(n) => n
                    .into_iter()
                    .map(|n| normal_matrix * Vec3::from_array(n))
                    .collect::<Vec<_>>(),
                None if prim.get(&gltf::Semantic::Normals).is_some() => {
                    return Err(err(format!(
                        "{}: its NORMAL accessor cannot be read (out of range of its buffer?)",
                        mesh_name(&prim)
                    )))
                }
                None => smooth_normals(&positions, &indices),
            };
            if normals.len() != positions.len() {
                return Err(err("normal count differs from position count".into()));
            }
            if positions.iter().chain(&normals).any(|p| !p.is_finite()) {
                return Err(err(format!(
                    "{node_name}, {}: a vertex position or normal is not finite in world space \
                     (a vertex times the node's transform overflows f32?)",
                    mesh_name(&prim)
                )));
            }
            repair_zero_normals(path, &positions, &mut normals, &indices);
            // The texture coordinates of each channel (none where the material has no set for
            // it).
            let mut uvs: [Vec<[f32; 2]>; 2] = Default::default();
            for (channel, &set) in channels.sets.iter().enumerate() {
                let read = attribute(gltf::Semantic::TexCoords(set))
                    .and_then(|a| read_attribute::<2>(&a, &buffers));
                let Some(read) = read else {
                    return Err(err(format!(
                        "{}: its material is textured, but it has no readable TEXCOORD_{set}",
                        mesh_name(&prim)
                    )));
                };
                check_per_vertex(&read, positions.len(), &format!("TEXCOORD_{set}"))
                    .map_err(|m| err(format!("{}: {m}", mesh_name(&prim))))?;
                uvs[channel] = read;
            }
            // MikkTSpace's tangents follow the normal texture's coordinates (the clear
            // coat's where the base has none).
            let normal_slot = if mat.normal_texture().is_some() {
                NORMAL_SLOT
            } else {
                COAT_NORMAL_SLOT
            };
            let normal_uvs = &uvs[channels.channel[normal_slot] as usize];
            // Tangents where a normal texture needs them: the file's, turned with the node
            // (mirrored by a negative determinant), or MikkTSpace's, as glTF asks.
            let read_tangents =
                attribute(gltf::Semantic::Tangents).and_then(|a| read_attribute::<4>(&a, &buffers));
            let tangents: Vec<[f32; 4]> = match (normal_textured, read_tangents) {
                (false, _) => Vec::new(),
                (true, _) if normal_uvs.is_empty() => Vec::new(),
                (true, Some(t)) => {
                    let handedness = world.determinant().signum();
                    t.into_iter()
                        .map(|[x, y, z, w]| {
                            let t = world
                                .transform_vector3(Vec3::new(x, y, z))
                                .normalize_or_zero();
                            [
                                t.x,
                                t.y,
                                t.z,
                                if w < 0.0 { -handedness } else { handedness },
                            ]
                        })
                        .collect()
                }
                (true, None) if prim.get(&gltf::Semantic::Tangents).is_some() => {
                    return Err(err(format!(
                        "{}: its TANGENT accessor cannot be read (out of range of its buffer?)",
                        mesh_name(&prim)
                    )))
                }
                (true, None) => generate_tangents(&positions, &normals, normal_uvs, &indices)
                    .unwrap_or_else(|| {
                        tracing::warn!(
                            "{}: {}: no tangents could be made for its normal texture (degenerate \
                             texture coordinates?); drawn without it",
                            path.display(),
                            mesh_name(&prim)
                        );
                        Vec::new()
                    }),
            };
            if !tangents.is_empty() {
                check_per_vertex(&tangents, positions.len(), "TANGENT")
                    .map_err(|m| err(format!("{}: {m}", mesh_name(&prim))))?;
            }
            let key = mat.index();
            let id = match material_ids.get(&key) {
                Some(&id) => id,
                None => {
                    if mat.normal_texture().is_some()
                        && coat_normal
                        && channels.channel[NORMAL_SLOT] != channels.channel[COAT_NORMAL_SLOT]
                    {
                        tracing::warn!(
                            "{}: material {:?}: its clear-coat normal texture reads other \
                             texture coordinates than its normal texture; read with the normal \
                             texture's tangents",
                            path.display(),
                            mat.name().unwrap_or("")
                        );
                    }
                    for &(slot, set) in &channels.unplaced {
                        tracing::warn!(
                            "{}: material {:?}: its {slot} texture reads TEXCOORD_{set}, a third \
                             set (envlight reads two: TEXCOORD_{} and TEXCOORD_{}); read with \
                             TEXCOORD_{}",
                            path.display(),
                            mat.name().unwrap_or(""),
                            channels.sets[0],
                            channels.sets[1],
                            channels.sets[0]
                        );
                    }
                    let material = gltf_material(
                        &gltf.document,
                        &mat,
                        &channels,
                        &buffers,
                        base,
                        &mut b,
                        &mut images,
                    )
                    .map_err(|m| {
                        err(format!(
                            "material {} ({:?}): {m}",
                            mat.index().map_or("default".to_string(), |i| i.to_string()),
                            mat.name().unwrap_or("")
                        ))
                    })?;
                    let id = b.material(material);
                    material_ids.insert(key, id);
                    id
                }
            };
            let colors: Vec<[u16; 4]> = match reader.read_colors(0) {
                // Through f32: the crate widens bytes by a shift (255 became 65280, not 1).
                Some(c) => c
                    .into_rgba_f32()
                    .map(|c| c.map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16))
                    .collect(),
                None if prim.get(&gltf::Semantic::Colors(0)).is_some() => {
                    return Err(err(format!(
                        "{}: its COLOR_0 accessor cannot be read (out of range of its buffer?)",
                        mesh_name(&prim)
                    )))
                }
                None => Vec::new(),
            };
            if !colors.is_empty() && colors.len() != positions.len() {
                return Err(err(format!(
                    "{}: {} COLOR_0 values for {} positions",
                    mesh_name(&prim),
                    colors.len(),
                    positions.len()
                )));
            }
            let first = b.vertices.len();
            b.mesh(&positions, &normals, &uvs[0], &indices, id);
            b.set_second_uvs(first, &uvs[1]);
            b.set_colors(first, &colors);
            b.set_tangents(first, &tangents);
        }
    }
    // The first camera node (by index) of the scene: the view the file was made for.
    if let Some(&(index, world)) = camera_nodes.iter().min_by_key(|(index, _)| *index) {
        let node = gltf.document.nodes().nth(index);
        let camera = node.as_ref().and_then(|n| n.camera());
        let name = format!(
            "camera node {index} ({:?})",
            node.as_ref().and_then(|n| n.name()).unwrap_or("")
        );
        let yfov = camera.as_ref().and_then(|c| match c.projection() {
            gltf::camera::Projection::Perspective(p) => Some(p.yfov()),
            gltf::camera::Projection::Orthographic(_) => None,
        });
        match yfov {
            Some(yfov) => {
                b.camera = Some(gltf_camera(world, yfov).map_err(|m| err(format!("{name}: {m}")))?);
                tracing::info!("{}: the view of its {name}", path.display());
            }
            _ => tracing::warn!(
                "{}: its {name} is orthographic, which envlight does not draw: the camera is \
                 fitted to the scene instead",
                path.display()
            ),
        }
    }
    if !ignored.is_empty() {
        tracing::warn!(
            "{}: not drawn (envlight renders the alpha modes, the index of refraction, and base \
             colour, metallic, roughness, emission, specular and clear coat, with their \
             textures, and normal and occlusion textures): {}",
            path.display(),
            ignored.into_iter().collect::<Vec<_>>().join(", ")
        );
    }
    Ok(b)
}

/// A glTF material as the renderer's: its factors, checked to lie in [0, 1], its alpha mode,
/// emission and sidedness, and its textures (loaded into `b` once per image, see
/// [`gltf_texture`]), each reading the vertex channel `channels` gives it
/// ([`texture_channels`]). Errors name the property; the caller names the material.
fn gltf_material(
    document: &gltf::Document,
    material: &gltf::Material,
    channels: &TextureChannels,
    buffers: &[gltf::buffer::Data],
    base: &Path,
    b: &mut Builder,
    images: &mut std::collections::HashMap<usize, u32>,
) -> Result<Material, String> {
    let pbr = material.pbr_metallic_roughness();
    let c = pbr.base_color_factor();
    if !c.iter().all(|v| (0.0..=1.0).contains(v)) {
        return Err(format!("baseColorFactor {c:?} must lie in [0, 1]"));
    }
    let (roughness, metallic) = (pbr.roughness_factor(), pbr.metallic_factor());
    for (name, value) in [("roughnessFactor", roughness), ("metallicFactor", metallic)] {
        if !(0.0..=1.0).contains(&value) {
            return Err(format!("{name} {value} must lie in [0, 1]"));
        }
    }
    let mut load = |texture: gltf::Texture, transform: Option<&serde_json::Value>| {
        gltf_texture(&texture, transform, buffers, base, b, images)
    };
    let base_color = pbr
        .base_color_texture()
        .map(|t| load(t.texture(), t.extension_value(TEXTURE_TRANSFORM)))
        .transpose()?;
    let metallic_roughness = pbr
        .metallic_roughness_texture()
        .map(|t| load(t.texture(), t.extension_value(TEXTURE_TRANSFORM)))
        .transpose()?;
    let normal = material.normal_texture();
    let normal_scale = normal.as_ref().map_or(1.0, |n| n.scale());
    if !normal_scale.is_finite() {
        return Err(format!("normalTexture.scale {normal_scale} is not finite"));
    }
    let normal = normal
        .map(|n| {
            load(n.texture(), n.extension_value(TEXTURE_TRANSFORM))
                .map_err(|m| format!("normal {m}"))
        })
        .transpose()?;
    let occlusion = material.occlusion_texture();
    let occlusion_strength = occlusion.as_ref().map_or(1.0, |o| o.strength());
    if !(0.0..=1.0).contains(&occlusion_strength) {
        return Err(format!(
            "occlusionTexture.strength {occlusion_strength} must lie in [0, 1]"
        ));
    }
    let occlusion = occlusion
        .map(|o| {
            load(o.texture(), o.extension_value(TEXTURE_TRANSFORM))
                .map_err(|m| format!("occlusion {m}"))
        })
        .transpose()?;
    let emissive = material
        .emissive_texture()
        .map(|t| {
            load(t.texture(), t.extension_value(TEXTURE_TRANSFORM))
                .map_err(|m| format!("emissive {m}"))
        })
        .transpose()?;
    let mut extension = |property| {
        extension_texture(material, property)?
            .map(|t| {
                let texture = document.textures().nth(t.index).ok_or_else(|| {
                    format!(
                        "{}.{}.index {}: the file has {} textures",
                        property.0,
                        property.1,
                        t.index,
                        document.textures().len()
                    )
                })?;
                let loaded = gltf_texture(&texture, t.transform, buffers, base, b, images)
                    .map_err(|m| format!("{}.{} {m}", property.0, property.1))?;
                Ok::<_, String>((loaded, t.scale))
            })
            .transpose()
    };
    let mut loaded = [None; EXTENSION_TEXTURES.len()];
    for (texture, property) in loaded.iter_mut().zip(EXTENSION_TEXTURES) {
        *texture = extension(property)?;
    }
    let [specular, specular_color, clearcoat, clearcoat_roughness, clearcoat_normal] =
        loaded.map(|t| t.map(|t| t.0));
    let clearcoat_normal_scale = loaded[4].map_or(1.0, |t| t.1);
    let mut textures = MaterialTextures {
        base_color,
        metallic_roughness,
        normal,
        normal_scale,
        occlusion,
        occlusion_strength,
        emissive,
        specular,
        specular_color,
        clearcoat,
        clearcoat_roughness,
        clearcoat_normal,
        clearcoat_normal_scale,
    };
    for (slot, texture) in textures.slots_mut().into_iter().enumerate() {
        if let Some(t) = texture {
            t.channel = channels.channel[slot];
        }
    }
    let alpha_mode = match material.alpha_mode() {
        gltf::material::AlphaMode::Mask => {
            let cutoff = material.alpha_cutoff().unwrap_or(0.5);
            if !(cutoff.is_finite() && cutoff >= 0.0) {
                return Err(format!("alphaCutoff {cutoff} is not a finite number ≥ 0"));
            }
            AlphaMode::Mask(cutoff)
        }
        gltf::material::AlphaMode::Blend => AlphaMode::Blend,
        gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
    };
    let (specular, specular_color, specular_factor) = gltf_specular(material)?;
    let (clearcoat, clearcoat_roughness) = gltf_clearcoat(material)?;
    Ok(Material {
        base_color: [c[0], c[1], c[2]],
        roughness,
        metallic,
        specular,
        specular_color,
        specular_factor,
        clearcoat,
        clearcoat_roughness,
        emission: gltf_emission(material)?,
        alpha: c[3],
        alpha_mode,
        double_sided: material.double_sided(),
        textures,
    })
}

/// The glTF extension that lets vertex attributes be bytes and shorts (`read_attribute`).
const MESH_QUANTIZATION: &str = "KHR_mesh_quantization";

/// The glTF extension that scales a material's emission past 1.
const EMISSIVE_STRENGTH: &str = "KHR_materials_emissive_strength";

/// The glTF extensions the renderer draws (a file may require them).
const DRAWN_EXTENSIONS: [&str; 6] = [
    MESH_QUANTIZATION,
    TEXTURE_TRANSFORM,
    EMISSIVE_STRENGTH,
    IOR,
    SPECULAR,
    CLEARCOAT,
];

/// The glTF extension that lays a clear coat over a material.
const CLEARCOAT: &str = "KHR_materials_clearcoat";

/// A glTF material's clear coat: `KHR_materials_clearcoat`'s `clearcoatFactor` and
/// `clearcoatRoughnessFactor` (each in [0, 1]; 0 without). Errors name the property.
fn gltf_clearcoat(material: &gltf::Material) -> Result<(f32, f32), String> {
    let factor = |name| {
        extension_number(
            material,
            (CLEARCOAT, name),
            0.0,
            in_unit_interval,
            IN_UNIT_INTERVAL,
        )
    };
    Ok((
        factor("clearcoatFactor")?,
        factor("clearcoatRoughnessFactor")?,
    ))
}

/// The glTF extension that sets a material's index of refraction (its dielectric F0).
const IOR: &str = "KHR_materials_ior";
/// The glTF extension that scales and tints a material's dielectric specular.
const SPECULAR: &str = "KHR_materials_specular";

/// A glTF material's dielectric specular as [`Material`]'s `specular` (level),
/// `specular_color` and `specular_factor`: the level from `KHR_materials_ior.ior` (≥ 1; 1.5
/// without the extension: F0 = ((ior − 1)/(ior + 1))² = 0.16 · level²), the tint and the
/// strength from `KHR_materials_specular`'s `specularColorFactor` (finite, ≥ 0; white without)
/// and `specularFactor` (in [0, 1]; 1 without). Errors name the property.
fn gltf_specular(material: &gltf::Material) -> Result<(f32, [f32; 3], f32), String> {
    let ior = extension_number(
        material,
        (IOR, "ior"),
        1.5,
        |x| x.is_finite() && x >= 1.0,
        "is not a finite number ≥ 1",
    )?;
    let factor = extension_number(
        material,
        (SPECULAR, "specularFactor"),
        1.0,
        in_unit_interval,
        IN_UNIT_INTERVAL,
    )?;
    let color = match material
        .extension_value(SPECULAR)
        .and_then(|e| e.get("specularColorFactor"))
    {
        None => [1.0; 3],
        Some(v) => v
            .as_array()
            .filter(|a| a.len() == 3)
            .and_then(|a| {
                let c: Vec<f32> = a
                    .iter()
                    .filter_map(|x| x.as_f64())
                    .map(|x| x as f32)
                    .collect();
                <[f32; 3]>::try_from(c).ok()
            })
            .filter(|c| c.iter().all(|x| x.is_finite() && *x >= 0.0))
            .ok_or_else(|| {
                format!("{SPECULAR}.specularColorFactor {v} is not three finite numbers ≥ 0")
            })?,
    };
    Ok(((ior - 1.0) / (ior + 1.0) / 0.4, color, factor))
}

/// A texture named in a glTF material's extension (a `textureInfo` object in the extension's
/// JSON, which the `gltf` crate does not parse): its texture `index`, its texture-coordinate
/// set (`texCoord`, 0 without), the `scale` of a normal texture (1 without) and its own
/// `KHR_texture_transform` object.
#[derive(Clone, Copy, Debug)]
struct ExtensionTexture<'a> {
    index: usize,
    tex_coord: u32,
    scale: f32,
    transform: Option<&'a serde_json::Value>,
}

/// Texture `name` of a glTF material's extension `extension` (`None` where either is absent).
/// Errors name the property and its value.
fn extension_texture<'a>(
    material: &'a gltf::Material,
    (extension, name): (&str, &str),
) -> Result<Option<ExtensionTexture<'a>>, String> {
    let Some(info) = material
        .extension_value(extension)
        .and_then(|e| e.get(name))
    else {
        return Ok(None);
    };
    let whole = |key: &str, default: u64| -> Result<u64, String> {
        match info.get(key) {
            None => Ok(default),
            Some(v) => v
                .as_u64()
                .ok_or_else(|| format!("{extension}.{name}.{key} {v} is not a whole number ≥ 0")),
        }
    };
    if info.get("index").is_none() {
        return Err(format!("{extension}.{name} has no index"));
    }
    let index = usize::try_from(whole("index", 0)?).unwrap_or(usize::MAX);
    let tex_coord = u32::try_from(whole("texCoord", 0)?)
        .map_err(|_| format!("{extension}.{name}.texCoord is out of range"))?;
    let scale = match info.get("scale") {
        None => 1.0,
        Some(v) => v
            .as_f64()
            .map(|x| x as f32)
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{extension}.{name}.scale {v} is not a finite number"))?,
    };
    let transform = info
        .get("extensions")
        .and_then(|e| e.get(TEXTURE_TRANSFORM));
    Ok(Some(ExtensionTexture {
        index,
        tex_coord,
        scale,
        transform,
    }))
}

/// The extension textures, in slot order after the core five ([`SLOT_NAMES`]): specular,
/// specular colour, clear coat, clear-coat roughness, clear-coat normal.
const EXTENSION_TEXTURES: [(&str, &str); 5] = [
    (SPECULAR, "specularTexture"),
    (SPECULAR, "specularColorTexture"),
    (CLEARCOAT, "clearcoatTexture"),
    (CLEARCOAT, "clearcoatRoughnessTexture"),
    COAT_NORMAL_TEXTURE,
];

/// The clear coat's normal texture (the last of [`EXTENSION_TEXTURES`]).
const COAT_NORMAL_TEXTURE: (&str, &str) = (CLEARCOAT, "clearcoatNormalTexture");

/// The slots ([`SLOT_NAMES`]) of the two normal textures, the base's and the clear coat's.
const NORMAL_SLOT: usize = 2;
const COAT_NORMAL_SLOT: usize = 9;

/// A glTF material's emitted radiance: `emissiveFactor` (each in [0, 1]) times its
/// `KHR_materials_emissive_strength.emissiveStrength` (finite, ≥ 0; 1 without the extension).
/// Errors name the property.
fn gltf_emission(material: &gltf::Material) -> Result<[f32; 3], String> {
    let factor = material.emissive_factor();
    if !factor.iter().all(|v| (0.0..=1.0).contains(v)) {
        return Err(format!("emissiveFactor {factor:?} must lie in [0, 1]"));
    }
    let strength = extension_number(
        material,
        (EMISSIVE_STRENGTH, "emissiveStrength"),
        1.0,
        |x| x.is_finite() && x >= 0.0,
        "is not a finite number ≥ 0",
    )?;
    Ok(factor.map(|f| f * strength))
}

/// Number `name` of a glTF material's extension `extension`: `default` where either is absent;
/// a number `valid` accepts, else an error naming the property and its value and saying
/// `requirement`.
fn extension_number(
    material: &gltf::Material,
    (extension, name): (&str, &str),
    default: f32,
    valid: impl Fn(f32) -> bool,
    requirement: &str,
) -> Result<f32, String> {
    match material
        .extension_value(extension)
        .and_then(|e| e.get(name))
    {
        None => Ok(default),
        Some(v) => v
            .as_f64()
            .map(|x| x as f32)
            .filter(|&x| valid(x))
            .ok_or_else(|| format!("{extension}.{name} {v} {requirement}")),
    }
}

/// [`extension_number`]'s requirement for factors in [0, 1].
const IN_UNIT_INTERVAL: &str = "must lie in [0, 1]";

fn in_unit_interval(x: f32) -> bool {
    (0.0..=1.0).contains(&x)
}

/// A primitive's per-vertex attribute `name`: one value per position, every component finite.
fn check_per_vertex<const N: usize>(
    values: &[[f32; N]],
    positions: usize,
    name: &str,
) -> Result<(), String> {
    if values.len() != positions {
        return Err(format!(
            "{} {name} values for {positions} positions",
            values.len()
        ));
    }
    if values.iter().flatten().any(|c| !c.is_finite()) {
        return Err(format!("a {name} value is not finite"));
    }
    Ok(())
}

/// The names of a material's texture slots ([`MaterialTextures::slots`]' order), for messages.
pub const SLOT_NAMES: [&str; 10] = [
    "base colour",
    "metallic-roughness",
    "normal",
    "occlusion",
    "emissive",
    "specular",
    "specular colour",
    "clear-coat",
    "clear-coat roughness",
    "clear-coat normal",
];

/// Which of a glTF material's texture-coordinate sets fill the vertex's two channels
/// ([`Vertex::uv`], [`Vertex::uv1`]), and the channel each texture slot reads.
#[derive(Clone, Debug, Default, PartialEq)]
struct TextureChannels {
    /// The `TEXCOORD_n` set of channel 0, then of channel 1 (at most two).
    sets: Vec<u32>,
    /// Per slot ([`SLOT_NAMES`]' order): its channel.
    channel: [u32; 10],
    /// Textures on a third set, read with channel 0: (slot name, set).
    unplaced: Vec<(&'static str, u32)>,
}

/// The channels of a glTF material's textures: channel 0 is the set of its first textured
/// slot (in [`SLOT_NAMES`]' order), channel 1 the first other set; a texture on a third set
/// is read with channel 0 (the caller warns). Each texture's set is its `texCoord`, or its
/// `KHR_texture_transform`'s where that gives one.
fn texture_channels(material: &gltf::Material) -> TextureChannels {
    let pbr = material.pbr_metallic_roughness();
    let info_set =
        |t: gltf::texture::Info| texture_set(t.tex_coord(), t.extension_value(TEXTURE_TRANSFORM));
    let slot_sets = [
        pbr.base_color_texture().map(info_set),
        pbr.metallic_roughness_texture().map(info_set),
        material
            .normal_texture()
            .map(|t| texture_set(t.tex_coord(), t.extension_value(TEXTURE_TRANSFORM))),
        material
            .occlusion_texture()
            .map(|t| texture_set(t.tex_coord(), t.extension_value(TEXTURE_TRANSFORM))),
        material.emissive_texture().map(info_set),
    ];
    // A malformed extension texture is reported by `gltf_material`.
    let extension_sets = EXTENSION_TEXTURES.map(|property| {
        extension_texture(material, property)
            .ok()
            .flatten()
            .map(|t| texture_set(t.tex_coord, t.transform))
    });
    let mut channels = TextureChannels::default();
    for (slot, set) in slot_sets.into_iter().chain(extension_sets).enumerate() {
        let Some(set) = set else { continue };
        match channels.sets.iter().position(|&s| s == set) {
            Some(c) => channels.channel[slot] = c as u32,
            None if channels.sets.len() < 2 => {
                channels.sets.push(set);
                channels.channel[slot] = (channels.sets.len() - 1) as u32;
            }
            None => channels.unplaced.push((SLOT_NAMES[slot], set)),
        }
    }
    channels
}

/// A vertex attribute's values as floats, whatever its component type: glTF's floats, and the
/// integers of `KHR_mesh_quantization` (bytes and shorts, signed or not) — normalised ones
/// mapped as glTF defines (c / 255 or c / 65535; max(c / 127, −1) or max(c / 32767, −1)),
/// others taken as their values (the node's transform then scales them, as a quantising
/// writer such as gltfpack arranges). Sparse accessors are read through the `gltf` crate.
/// `None` where the accessor cannot be read; the caller has checked its type and span
/// (`check_accessor`).
fn read_attribute<const N: usize>(
    accessor: &gltf::Accessor,
    buffers: &[gltf::buffer::Data],
) -> Option<Vec<[f32; N]>>
where
    [f32; N]: gltf::accessor::Item,
    [i8; N]: gltf::accessor::Item,
    [u8; N]: gltf::accessor::Item,
    [i16; N]: gltf::accessor::Item,
    [u16; N]: gltf::accessor::Item,
{
    use gltf::accessor::{DataType, Iter};
    let get = |b: gltf::Buffer| buffers.get(b.index()).map(|d| &d.0[..]);
    let normalized = accessor.normalized();
    fn widened<T: Copy, const N: usize>(
        values: Iter<'_, [T; N]>,
        to_f32: impl Fn(T) -> f32,
    ) -> Vec<[f32; N]>
    where
        [T; N]: gltf::accessor::Item,
    {
        values.map(|v| v.map(&to_f32)).collect()
    }
    // A component of `max` as its largest value: normalised, to [0, 1] or [−1, 1].
    let unit = move |c: f32, max: f32| {
        if normalized {
            (c / max).max(-1.0)
        } else {
            c
        }
    };
    let read = accessor.clone();
    Some(match accessor.data_type() {
        DataType::F32 => Iter::<[f32; N]>::new(read, get)?.collect(),
        DataType::I8 => widened(Iter::<[i8; N]>::new(read, get)?, |c| {
            unit(f32::from(c), 127.0)
        }),
        DataType::U8 => widened(Iter::<[u8; N]>::new(read, get)?, |c| {
            unit(f32::from(c), 255.0)
        }),
        DataType::I16 => widened(Iter::<[i16; N]>::new(read, get)?, |c| {
            unit(f32::from(c), 32767.0)
        }),
        DataType::U16 => widened(Iter::<[u16; N]>::new(read, get)?, |c| {
            unit(f32::from(c), 65535.0)
        }),
        DataType::U32 => return None,
    })
}

/// MikkTSpace tangents (the `mikktspace` crate) of an indexed triangle mesh, one per vertex, in
/// glTF's convention: xyz along increasing u, w the handedness that makes cross(n, t)·w point
/// up the image (towards decreasing v: MikkTSpace's bitangent follows increasing v, so it is
/// given 1 − v). `None` where the crate fails or panics (degenerate input), or a tangent is not
/// finite.
fn generate_tangents(
    positions: &[Vec3],
    normals: &[Vec3],
    uvs: &[[f32; 2]],
    indices: &[u32],
) -> Option<Vec<[f32; 4]>> {
    struct Mesh<'a> {
        positions: &'a [Vec3],
        normals: &'a [Vec3],
        uvs: &'a [[f32; 2]],
        indices: &'a [u32],
        tangents: Vec<[f32; 4]>,
    }
    impl Mesh<'_> {
        fn vertex(&self, face: usize, vert: usize) -> usize {
            self.indices[face * 3 + vert] as usize
        }
    }
    impl mikktspace::Geometry for Mesh<'_> {
        fn num_faces(&self) -> usize {
            self.indices.len() / 3
        }
        fn num_vertices_of_face(&self, _face: usize) -> usize {
            3
        }
        fn position(&self, face: usize, vert: usize) -> [f32; 3] {
            self.positions[self.vertex(face, vert)].to_array()
        }
        fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
            self.normals[self.vertex(face, vert)]
                .normalize_or(Vec3::Y)
                .to_array()
        }
        fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
            let [u, v] = self.uvs[self.vertex(face, vert)];
            [u, 1.0 - v]
        }
        fn set_tangent_encoded(&mut self, tangent: [f32; 4], face: usize, vert: usize) {
            let i = self.vertex(face, vert);
            self.tangents[i] = tangent;
        }
    }
    let mut mesh = Mesh {
        positions,
        normals,
        uvs,
        indices,
        tangents: vec![[0.0; 4]; positions.len()],
    };
    let made = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        mikktspace::generate_tangents(&mut mesh)
    }));
    (matches!(made, Ok(true)) && mesh.tangents.iter().flatten().all(|c| c.is_finite()))
        .then_some(mesh.tangents)
}

/// The largest side of a scene's texture image, in pixels.
pub const MAX_TEXTURE_SIDE: u32 = 8192;

/// A glTF texture: its image (loaded once per scene, see [`gltf_image`]), its sampler's wrap
/// modes and its `KHR_texture_transform` (`transform`, the extension's object).
fn gltf_texture(
    texture: &gltf::Texture,
    transform: Option<&serde_json::Value>,
    buffers: &[gltf::buffer::Data],
    base: &Path,
    b: &mut Builder,
    images: &mut std::collections::HashMap<usize, u32>,
) -> Result<TextureRef, String> {
    use gltf::texture::WrappingMode;
    let wrap = |mode| match mode {
        WrappingMode::Repeat => Wrap::Repeat,
        WrappingMode::ClampToEdge => Wrap::ClampToEdge,
        WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
    };
    let sampler = texture.sampler();
    let image = texture.source();
    let index = match images.get(&image.index()) {
        Some(&index) => index,
        None => {
            let decoded = gltf_image(&image, buffers, base)
                .map_err(|m| format!("texture {}: {m}", texture.index()))?;
            b.textures.push(decoded);
            let index = (b.textures.len() - 1) as u32;
            images.insert(image.index(), index);
            index
        }
    };
    let transform = match transform {
        Some(value) => uv_transform(value)?.0,
        None => NO_UV_TRANSFORM,
    };
    Ok(TextureRef {
        image: index,
        wrap: [wrap(sampler.wrap_s()), wrap(sampler.wrap_t())],
        transform,
        // Set by the caller, which knows the material's sets.
        channel: 0,
    })
}

/// The texture-coordinate set a texture reads: its `texCoord`, or its `KHR_texture_transform`'s
/// where that gives one.
fn texture_set(tex_coord: u32, transform: Option<&serde_json::Value>) -> u32 {
    transform
        .and_then(|t| uv_transform(t).ok())
        .and_then(|(_, set)| set)
        .unwrap_or(tex_coord)
}

/// Reads and decodes a glTF image: a buffer view (a `.glb`'s embedded images), a `data:` URI
/// or a file next to the scene (read as the buffers are, a regular file of bounded size).
fn gltf_image(
    image: &gltf::Image,
    buffers: &[gltf::buffer::Data],
    base: &Path,
) -> Result<TextureImage, String> {
    let index = image.index();
    let (bytes, name) = match image.source() {
        gltf::image::Source::View { view, .. } => {
            let data = buffers
                .get(view.buffer().index())
                .map_or(&[][..], |d| &d.0[..]);
            let bytes = view
                .offset()
                .checked_add(view.length())
                .and_then(|end| data.get(view.offset()..end))
                .ok_or_else(|| {
                    format!(
                        "image {index}: buffer view {} ({} bytes from byte {}) lies outside \
                         buffer {} of {} bytes",
                        view.index(),
                        view.length(),
                        view.offset(),
                        view.buffer().index(),
                        data.len()
                    )
                })?;
            (
                bytes.to_vec(),
                format!("image {index} (buffer view {})", view.index()),
            )
        }
        gltf::image::Source::Uri { uri, .. } => {
            match buffer_source(base, uri).map_err(|m| format!("image {index}: {m}"))? {
                BufferSource::File(file) => {
                    let name = format!("image {index} ({})", file.display());
                    let bytes = crate::read_file::read_regular_file(
                        &file,
                        MAX_SCENE_FILE_BYTES,
                        "a glTF image",
                    )
                    .map_err(|e| format!("{name}: {e}"))?;
                    (bytes, name)
                }
                BufferSource::Embedded => {
                    let name = format!("image {index} (a data URI)");
                    let bytes = gltf::buffer::Data::from_source_and_blob(
                        gltf::buffer::Source::Uri(uri),
                        None,
                        &mut None,
                    )
                    .map_err(|e| format!("{name}: {e}"))?
                    .0;
                    (bytes, name)
                }
            }
        }
    };
    decode_texture(&bytes, name)
}

/// Decodes a PNG or JPEG texture image to RGBA8, at most [`MAX_TEXTURE_SIDE`] a side. Errors
/// begin with `name`.
fn decode_texture(bytes: &[u8], name: String) -> Result<TextureImage, String> {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("{name}: {e}"))?;
    if !matches!(
        reader.format(),
        Some(image::ImageFormat::Png | image::ImageFormat::Jpeg)
    ) {
        return Err(format!(
            "{name}: not a PNG or JPEG image (the formats a glTF core texture may have)"
        ));
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIDE);
    limits.max_image_height = Some(MAX_TEXTURE_SIDE);
    // A 16-bit RGBA image of the largest size, decoded and converted.
    limits.max_alloc = Some(u64::from(MAX_TEXTURE_SIDE).pow(2) * 12);
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| format!("{name}: {e}"))?;
    let rgba = decoded.to_rgba8();
    Ok(TextureImage {
        name,
        width: rgba.width(),
        height: rgba.height(),
        rgba: rgba.into_raw(),
    })
}

/// The files loading the scene at `path` reads: the file itself and, for glTF, its external
/// buffers, for OBJ, its material libraries — the files no output of a command that reads the
/// scene may overwrite. Best effort: references that cannot be worked out are left out.
pub fn scene_files(path: &Path) -> Vec<PathBuf> {
    let mut files = vec![path.to_path_buf()];
    let base = path.parent().unwrap_or(Path::new("."));
    let Ok(bytes) = read_scene_file(path) else {
        return files;
    };
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("gltf" | "glb") => {
            if let Ok(gltf) = gltf::Gltf::from_slice(&bytes) {
                for buffer in gltf.document.buffers() {
                    if let gltf::buffer::Source::Uri(uri) = buffer.source() {
                        if let Ok(BufferSource::File(file)) = buffer_source(base, uri) {
                            files.push(file);
                        }
                    }
                }
                for image in gltf.document.images() {
                    if let gltf::image::Source::Uri { uri, .. } = image.source() {
                        if let Ok(BufferSource::File(file)) = buffer_source(base, uri) {
                            files.push(file);
                        }
                    }
                }
            }
        }
        Some("obj") => {
            for line in String::from_utf8_lossy(&bytes).lines() {
                if let Some(names) = line.trim_start().strip_prefix("mtllib") {
                    for library in names.split_whitespace().map(|name| base.join(name)) {
                        // Its maps that are drawn.
                        let maps = crate::read_file::read_regular_file(
                            &library,
                            MAX_MTL_BYTES,
                            "a material library",
                        )
                        .map(|text| {
                            String::from_utf8_lossy(&text)
                                .lines()
                                .filter_map(|l| {
                                    let l = l.trim_start();
                                    ["map_Kd", "map_Ke", "map_d"]
                                        .iter()
                                        .find_map(|kind| l.strip_prefix(kind))
                                        .filter(|rest| rest.starts_with([' ', '\t']))
                                })
                                .map(|m| base.join(map_file_name(m)))
                                .collect::<Vec<_>>()
                        });
                        files.push(library);
                        files.extend(maps.unwrap_or_default());
                    }
                }
            }
        }
        _ => {}
    }
    files
}

/// Reads an MTL file, checking what `tobj` would panic on: a colour (`Ka`, `Kd`, `Ks`, `Ke`)
/// with fewer than three numbers. The error carries tobj's kind and the problem in words.
fn read_mtl(path: &Path) -> Result<Vec<u8>, (tobj::LoadError, String)> {
    let bytes = crate::read_file::read_regular_file(path, MAX_MTL_BYTES, "a material library")
        .map_err(|e| (tobj::LoadError::OpenFileFailed, e.to_string()))?;
    for (number, line) in String::from_utf8_lossy(&bytes).lines().enumerate() {
        let mut words = line.split_whitespace();
        if let Some(key @ ("Ka" | "Kd" | "Ks" | "Ke")) = words.next() {
            if words.take(3).count() < 3 {
                return Err((
                    tobj::LoadError::MaterialParseError,
                    format!("line {}: {key} needs three numbers (r g b)", number + 1),
                ));
            }
        }
    }
    Ok(bytes)
}

/// What [`scan_obj`] found that is not drawn, for the warnings.
#[derive(Debug, Default, PartialEq)]
struct ObjScan {
    /// `l` and `p` elements (tobj would turn them into zero-area triangles).
    lines_and_points: usize,
    /// Faces of fewer than three corners (tobj drops them).
    short_faces: usize,
}

/// Checks an OBJ file's text before `tobj` parses it, with the line number of each problem
/// (tobj's own errors name neither line nor problem: "position parse error", "read error"):
/// every line UTF-8; `v x y z [w | r g b]` with numbers (w not 0, vertex colours on every
/// vertex or on none), `vt u v`, `vn x y z`; face corners `v`, `v/vt`, `v//vn` or `v/vt/vn`
/// with integer indices (in `l` lines too, which tobj parses as it does faces), each no larger
/// in magnitude than the number of positions, texture coordinates or normals in the file (a
/// negative one: than those defined above its line, which it counts back from), and not 0
/// (`tobj` multiplies the texture-coordinate and normal indices unchecked: an index near 2⁶³
/// overflows, a panic with overflow checks on, and wraps past its bounds check without); no
/// byte-order mark. Counts what will not be drawn ([`ObjScan`]).
fn scan_obj(text: &[u8]) -> Result<ObjScan, String> {
    // Finite in f32: "1e39" and "nan" parse, as infinity and NaN.
    let number = |word: &str| word.parse::<f32>().is_ok_and(f32::is_finite);
    let mut scan = ObjScan::default();
    let mut counts = [0usize; 3];
    // The first vertex line with a colour and the first without.
    let (mut coloured, mut plain) = (None, None);
    let lines = || text.split(|&c| c == b'\n').zip(1usize..);
    if text.starts_with("\u{feff}".as_bytes()) {
        return Err(
            "the file begins with a UTF-8 byte-order mark, which OBJ readers do not \
                    expect (its first line would be lost); remove it"
                .into(),
        );
    }
    for (line, n) in lines() {
        let line = std::str::from_utf8(line)
            .map_err(|_| format!("line {n} is not UTF-8 text (an OBJ file is text)"))?;
        let mut words = line.split_whitespace();
        let (kind, rest): (usize, Vec<&str>) = match words.next() {
            Some("v") => (0, words.collect()),
            Some("vt") => (1, words.collect()),
            Some("vn") => (2, words.collect()),
            Some("l" | "p") => {
                scan.lines_and_points += 1;
                continue;
            }
            _ => continue,
        };
        let needed = [3, 2, 3][kind];
        if rest.len() < needed || !rest[..needed].iter().all(|w| number(w)) {
            let form = ["v x y z", "vt u v", "vn x y z"][kind];
            return Err(format!(
                "line {n}: expected {needed} finite numbers ({form}), got {:?}",
                line.trim()
            ));
        }
        if kind == 0 {
            match rest[3..] {
                [] => plain = plain.or(Some(n)),
                [w] if number(w) && w.parse::<f32>().is_ok_and(|w| w != 0.0) => {
                    plain = plain.or(Some(n))
                }
                [w] => {
                    return Err(format!(
                        "line {n}: the homogeneous w {w:?} must be a number other than 0"
                    ))
                }
                [r, g, b] if [r, g, b].iter().all(|w| number(w)) => coloured = coloured.or(Some(n)),
                _ => {
                    return Err(format!(
                        "line {n}: a vertex is v x y z, v x y z w or v x y z r g b, got {:?}",
                        line.trim()
                    ))
                }
            }
            if let (Some(c), Some(p)) = (coloured, plain) {
                return Err(format!(
                    "line {c} gives a vertex colour and line {p} does not: vertex colours must \
                     be on every vertex or on none"
                ));
            }
        }
        counts[kind] += 1;
    }
    const KINDS: [&str; 3] = ["positions", "texture coordinates", "normals"];
    // Defined so far: a negative index counts back from the elements above its line.
    let mut defined = [0usize; 3];
    for (line, n) in lines() {
        // UTF-8: checked above.
        let line = std::str::from_utf8(line).unwrap_or_default();
        let mut words = line.split_whitespace();
        let keyword = words.next();
        match keyword {
            Some("v") => defined[0] += 1,
            Some("vt") => defined[1] += 1,
            Some("vn") => defined[2] += 1,
            _ => {}
        }
        // tobj parses `l` lines as it does faces (and then leaves them out).
        if !matches!(keyword, Some("f" | "l")) {
            continue;
        }
        let corners: Vec<&str> = words.collect();
        if corners.is_empty() {
            return Err(format!(
                "line {n}: {} without vertices",
                if keyword == Some("f") {
                    "a face"
                } else {
                    "a line"
                }
            ));
        }
        if keyword == Some("f") && corners.len() < 3 {
            scan.short_faces += 1;
        }
        for corner in corners {
            let parts: Vec<&str> = corner.split('/').collect();
            if parts.len() > 3 || parts[0].is_empty() {
                return Err(format!(
                    "line {n}: face corner {corner:?} is not v, v/vt, v//vn or v/vt/vn"
                ));
            }
            for (kind, index) in parts.iter().enumerate().filter(|(_, i)| !i.is_empty()) {
                let Ok(index) = index.parse::<i128>() else {
                    return Err(format!(
                        "line {n}: face corner {corner:?}: {index:?} is not an integer index"
                    ));
                };
                if index == 0 {
                    return Err(format!("line {n}: face index 0 (OBJ indices start at 1)"));
                }
                if index.unsigned_abs() > counts[kind] as u128 {
                    return Err(format!(
                        "line {n}: face index {index} out of range of the file's {} {}",
                        counts[kind], KINDS[kind]
                    ));
                }
                if index < 0 && index.unsigned_abs() > defined[kind] as u128 {
                    return Err(format!(
                        "line {n}: face index {index} counts back past the {} {} defined \
                         above it",
                        defined[kind], KINDS[kind]
                    ));
                }
            }
        }
    }
    Ok(scan)
}

/// The OBJ text with comments that follow the data on a geometry line (`f 1 2 3 # back`,
/// `v 0 0 0 # origin`) cut off. Exporters write them and most readers accept them; tobj reads
/// the `#` as one more number or corner and fails. Only geometry lines are cut (`v`, `vt`,
/// `vn`, `vp`, `f`, `l`, `p`, `s`): a name after `o`, `g`, `usemtl` or `mtllib` may hold a `#`.
/// Every line keeps its place, so line numbers in errors stay those of the file.
fn strip_trailing_comments(text: &[u8]) -> std::borrow::Cow<'_, [u8]> {
    const GEOMETRY: [&[u8]; 8] = [b"v", b"vt", b"vn", b"vp", b"f", b"l", b"p", b"s"];
    let cut = |line: &[u8]| -> Option<usize> {
        let keyword = line
            .trim_ascii_start()
            .split(u8::is_ascii_whitespace)
            .next()?;
        if !GEOMETRY.contains(&keyword) {
            return None;
        }
        line.iter().position(|&c| c == b'#')
    };
    if !text.split(|&c| c == b'\n').any(|line| cut(line).is_some()) {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = Vec::with_capacity(text.len());
    for (i, line) in text.split(|&c| c == b'\n').enumerate() {
        if i > 0 {
            out.push(b'\n');
        }
        out.extend_from_slice(&line[..cut(line).unwrap_or(line.len())]);
    }
    std::borrow::Cow::Owned(out)
}

fn load_obj(path: &Path) -> Result<Builder, SceneError> {
    let err = |message: String| SceneError::Obj {
        path: path.to_path_buf(),
        message,
    };
    // Read once: the text is scanned for lines and points here and parsed by tobj from memory.
    let text = read_scene_file(path)?;
    let text = strip_trailing_comments(&text);
    // Lines and points are not drawn: tobj would turn them into zero-area triangles, so they
    // are left out, and said so.
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_lines: true,
        ignore_points: true,
    };
    let scan = scan_obj(&text).map_err(err)?;
    if scan.lines_and_points > 0 {
        tracing::warn!(
            "{}: skipping {} line and point elements (only faces are drawn)",
            path.display(),
            scan.lines_and_points
        );
    }
    if scan.short_faces > 0 {
        tracing::warn!(
            "{}: skipping {} faces of fewer than 3 corners",
            path.display(),
            scan.short_faces
        );
    }
    // Material libraries are found next to the OBJ file, as `tobj::load_obj` does.
    let base = path.parent().unwrap_or(Path::new("."));
    // tobj's own errors say only "open file failed": the library's path and the problem are
    // kept here for the warning.
    let mtl_problem = std::cell::RefCell::new(None);
    let (models, materials) = tobj::load_obj_buf(&mut &text[..], &options, |mtl| {
        let mtl_path = base.join(mtl);
        let loaded = read_mtl(&mtl_path)
            .and_then(|bytes| tobj::load_mtl_buf(&mut &bytes[..]).map_err(|e| (e, e.to_string())));
        loaded.map_err(|(e, problem)| {
            *mtl_problem.borrow_mut() = Some(format!("{}: {problem}", mtl_path.display()));
            e
        })
    })
    .map_err(|e| err(e.to_string()))?;
    let mut warned = false;
    let materials = materials.unwrap_or_else(|e| {
        let problem = mtl_problem.take().unwrap_or_else(|| e.to_string());
        tracing::warn!(
            "{}: materials not loaded ({problem}); using grey",
            path.display()
        );
        warned = true;
        Vec::new()
    });
    // `usemtl` of a name no library defines: drawn grey, and said so.
    let unknown: std::collections::BTreeSet<String> = text
        .split(|&c| c == b'\n')
        .filter_map(|l| l.trim_ascii_start().strip_prefix(b"usemtl"))
        .map(|name| String::from_utf8_lossy(name).trim().to_string())
        .filter(|name| !name.is_empty() && !materials.iter().any(|m| &m.name == name))
        .collect();
    if !unknown.is_empty() && !warned {
        tracing::warn!(
            "{}: usemtl of materials its libraries do not define ({}); drawn grey",
            path.display(),
            unknown.into_iter().collect::<Vec<_>>().join(", ")
        );
    }
    let mut b = Builder::default();
    let mut ignored = std::collections::BTreeSet::new();
    let mut ids: Vec<Option<u32>> = vec![None; materials.len()];
    let mut default_id = None;
    for model in &models {
        let m = &model.mesh;
        let positions: Vec<Vec3> = m
            .positions
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect();
        let indices = m.indices.clone();
        if indices.iter().any(|&i| i as usize >= positions.len()) {
            return Err(err(format!("object {:?}: index out of range", model.name)));
        }
        let mut normals: Vec<Vec3> = if m.normals.len() == m.positions.len() {
            m.normals
                .chunks_exact(3)
                .map(|n| Vec3::new(n[0], n[1], n[2]))
                .collect()
        } else {
            smooth_normals(&positions, &indices)
        };
        if positions.iter().chain(&normals).any(|p| !p.is_finite()) {
            return Err(err("non-finite vertex position or normal".into()));
        }
        repair_zero_normals(path, &positions, &mut normals, &indices);
        // OBJ's v runs up the image, glTF's (and the renderer's) down.
        let uvs: Vec<[f32; 2]> = if m.texcoords.len() == 2 * positions.len() {
            m.texcoords
                .chunks_exact(2)
                .map(|t| [t[0], 1.0 - t[1]])
                .collect()
        } else {
            Vec::new()
        };
        if uvs.iter().flatten().any(|c| !c.is_finite()) {
            return Err(err(format!(
                "object {:?}: a texture coordinate is not finite",
                model.name
            )));
        }
        let id = match m.material_id.filter(|&i| i < materials.len()) {
            Some(i) => match ids[i] {
                Some(id) => id,
                None => {
                    let mat = &materials[i];
                    let d = mat.diffuse.unwrap_or([0.8, 0.8, 0.8]);
                    if !d.iter().all(|v| (0.0..=1.0).contains(v)) {
                        return Err(err(format!(
                            "material {:?}: Kd {d:?} must lie in [0, 1]",
                            mat.name
                        )));
                    }
                    // The PBR statements (Pr, Pm, Pc, Pcr), where given; else the Blinn-Phong
                    // exponent → roughness (α² ≈ 2 / (Ns + 2)).
                    let pbr = |key: &str| {
                        obj_pbr_factor(mat, key)
                            .map_err(|m| err(format!("material {:?}: {m}", mat.name)))
                    };
                    let roughness = match pbr("Pr")? {
                        Some(r) => r,
                        None => mat
                            .shininess
                            .map_or(0.5, |ns| (2.0 / (ns.max(0.0) + 2.0)).sqrt().sqrt()),
                    };
                    let metallic = pbr("Pm")?.unwrap_or(0.0);
                    let clearcoat = pbr("Pc")?.unwrap_or(0.0);
                    let clearcoat_roughness = pbr("Pcr")?.unwrap_or(0.0);
                    for (kind, texture) in [
                        ("map_Ka", &mat.ambient_texture),
                        ("map_Ks", &mat.specular_texture),
                        ("bump/norm", &mat.normal_texture),
                        ("map_Ns", &mat.shininess_texture),
                    ] {
                        if texture.is_some() {
                            ignored.insert(kind.to_string());
                        }
                    }
                    // Other maps (map_Pr, map_Pm, …), named rather than dropped silently.
                    for key in mat.unknown_param.keys() {
                        if key.starts_with("map_") && key != "map_Ke" {
                            ignored.insert(key.clone());
                        }
                    }
                    // d (or Tr = 1 − d) below 1: the surface is blended with that alpha.
                    let dissolve = obj_dissolve(mat)
                        .map_err(|m| err(format!("material {:?}: {m}", mat.name)))?;
                    let named =
                        |kind: &str, m: String| err(format!("material {:?}: {kind} {m}", mat.name));
                    let diffuse_map = mat
                        .diffuse_texture
                        .as_deref()
                        .map(|map| obj_texture("map_Kd", map, base, &mut b))
                        .transpose()
                        .map_err(|m| named("map_Kd", m))?;
                    // map_d: a cut-out mask, joined to the base colour's alpha.
                    let base_color = match mat.dissolve_texture.as_deref() {
                        Some(map) => {
                            let mask = obj_texture("map_d", map, base, &mut b)
                                .map_err(|m| named("map_d", m))?;
                            Some(with_mask(&mut b, diffuse_map, mask))
                        }
                        None => diffuse_map,
                    };
                    let emissive_map = mat.unknown_param.get("map_Ke");
                    let emissive = emissive_map
                        .map(|map| obj_texture("map_Ke", map, base, &mut b))
                        .transpose()
                        .map_err(|m| named("map_Ke", m))?;
                    // Ke scales map_Ke; a map_Ke without Ke glows at its texels' colour.
                    let emission = match mat.emissive {
                        Some(ke) if ke.iter().all(|v| v.is_finite() && *v >= 0.0) => ke,
                        Some(ke) => {
                            return Err(err(format!(
                                "material {:?}: Ke {ke:?} must be finite and ≥ 0",
                                mat.name
                            )))
                        }
                        None if emissive.is_some() => [1.0; 3],
                        None => [0.0; 3],
                    };
                    let id = b.material(Material {
                        base_color: d,
                        roughness: roughness.clamp(0.0, 1.0),
                        metallic,
                        specular: 0.5,
                        clearcoat,
                        clearcoat_roughness,
                        emission,
                        alpha: dissolve,
                        alpha_mode: if mat.dissolve_texture.is_some() {
                            AlphaMode::Mask(OBJ_ALPHA_CUTOFF)
                        } else if dissolve < 1.0 {
                            AlphaMode::Blend
                        } else {
                            AlphaMode::Opaque
                        },
                        textures: MaterialTextures {
                            base_color: base_color.map(TextureRef::repeating),
                            emissive: emissive.map(TextureRef::repeating),
                            ..Default::default()
                        },
                        ..Material::default()
                    });
                    ids[i] = Some(id);
                    id
                }
            },
            None => *default_id.get_or_insert_with(|| b.material(Material::default())),
        };
        if uvs.is_empty() && b.materials[id as usize].textures.base_color.is_some() {
            tracing::warn!(
                "{}: object {:?} has a textured material but no texture coordinates (vt); \
                 drawn with the texture's top-left texel",
                path.display(),
                model.name
            );
        }
        b.mesh(&positions, &normals, &uvs, &indices, id);
    }
    if !ignored.is_empty() {
        tracing::warn!(
            "{}: material maps not drawn (envlight renders map_Kd, map_Ke and map_d, as a \
             cut-out): {}",
            path.display(),
            ignored.into_iter().collect::<Vec<_>>().join(", ")
        );
    }
    Ok(b)
}

/// The file an MTL map statement (`map_Kd …`, the words after the keyword) names: all of it,
/// or, when options come first (`-s 1 1 1 file.png`), its last word.
fn map_file_name(map: &str) -> &str {
    let map = map.trim();
    if map.starts_with('-') {
        map.split_whitespace().last().unwrap_or(map)
    } else {
        map
    }
}

/// An MTL material's PBR factor `key` (the PBR extension of MTL: `Pr` roughness, `Pm`
/// metallic, `Pc` clear coat, `Pcr` its roughness), where given: a number in [0, 1], else an
/// error naming the statement.
fn obj_pbr_factor(mat: &tobj::Material, key: &str) -> Result<Option<f32>, String> {
    let Some(text) = mat.unknown_param.get(key) else {
        return Ok(None);
    };
    match text.trim().parse::<f32>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(Some(v)),
        _ => Err(format!("{key} {text:?} is not a number in [0, 1]")),
    }
}

/// An MTL material's opacity: its `d` (dissolve), or 1 − its `Tr` (transparency) where it has
/// no `d`, or 1. A value outside [0, 1] or not a number is an error naming the statement.
fn obj_dissolve(mat: &tobj::Material) -> Result<f32, String> {
    let (statement, opacity) = match (mat.dissolve, mat.unknown_param.get("Tr")) {
        (Some(d), _) => ("d", d),
        (None, Some(tr)) => match tr.trim().parse::<f32>() {
            Ok(t) => ("Tr", 1.0 - t),
            Err(_) => return Err(format!("Tr {tr:?} is not a number")),
        },
        (None, None) => return Ok(1.0),
    };
    if !(0.0..=1.0).contains(&opacity) {
        return Err(format!(
            "{statement} gives an opacity of {opacity}, outside [0, 1]"
        ));
    }
    if statement == "Tr" && opacity == 0.0 {
        // Some writers put the opacity in Tr (three.js's MTL loader has a switch for them).
        tracing::warn!(
            "material {:?}: Tr 1 makes it invisible (Tr is 1 − opacity); if its writer meant \
             opaque, write d 1",
            mat.name
        );
    }
    Ok(opacity)
}

/// The alpha below which an OBJ material with a `map_d` is cut out (as glTF's MASK default).
pub const OBJ_ALPHA_CUTOFF: f32 = 0.5;

/// A base-colour image for an OBJ material with a `map_d` mask (image `mask` of the scene's
/// textures): the `map_Kd` image `diffuse` (white without one) with its alpha replaced by the
/// mask's — its A channel where any texel is not opaque, else its R (a grey mask), read at the
/// same texture coordinates (nearest texel where the sizes differ). The joined image is added
/// to the scene; its index is returned.
fn with_mask(b: &mut Builder, diffuse: Option<u32>, mask: u32) -> u32 {
    let mask = &b.textures[mask as usize];
    let colour = diffuse.map(|i| &b.textures[i as usize]);
    let (width, height) = colour.map_or((mask.width, mask.height), |c| (c.width, c.height));
    let masked_alpha = mask.rgba.chunks_exact(4).any(|p| p[3] < 255);
    let mut rgba = Vec::with_capacity(width as usize * height as usize * 4);
    for y in 0..height {
        for x in 0..width {
            let rgb = colour.map_or([255; 3], |c| {
                let i = (y as usize * c.width as usize + x as usize) * 4;
                c.rgba
                    .get(i..i + 3)
                    .map_or([255; 3], |p| [p[0], p[1], p[2]])
            });
            // The mask's texel whose area holds this texel's centre.
            let mx = (u64::from(x) * u64::from(mask.width) / u64::from(width)) as usize;
            let my = (u64::from(y) * u64::from(mask.height) / u64::from(height)) as usize;
            let m = (my * mask.width as usize + mx) * 4;
            let alpha = mask
                .rgba
                .get(m..m + 4)
                .map_or(255, |p| if masked_alpha { p[3] } else { p[0] });
            rgba.extend_from_slice(&[rgb[0], rgb[1], rgb[2], alpha]);
        }
    }
    let name = match colour {
        Some(c) => format!("{} masked by {}", c.name, mask.name),
        None => format!("mask {}", mask.name),
    };
    b.textures.push(TextureImage {
        name,
        width,
        height,
        rgba,
    });
    (b.textures.len() - 1) as u32
}

/// Loads an MTL texture (`map_Kd`) named relative to the OBJ file's directory. Options before
/// the file name (`-s 1 1 1 file.png`) are not applied, with a warning.
fn obj_texture(kind: &str, map: &str, base: &Path, b: &mut Builder) -> Result<u32, String> {
    let file_name = map_file_name(map);
    if file_name != map.trim() {
        tracing::warn!("{kind} {map:?}: its options are not applied; reading {file_name:?}");
    }
    let file = base.join(file_name);
    if let Some(i) = b
        .textures
        .iter()
        .position(|t| t.name == file.display().to_string())
    {
        return Ok(i as u32);
    }
    let bytes = crate::read_file::read_regular_file(&file, MAX_SCENE_FILE_BYTES, "a texture")
        .map_err(|e| format!("{}: {e}", file.display()))?;
    b.textures
        .push(decode_texture(&bytes, file.display().to_string())?);
    Ok((b.textures.len() - 1) as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_matrices_map_the_view_frustum_to_wgpu_clip_space() {
        let cam = Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            fov_y: 1.0,
        };
        let m = cam.view_proj(2.0, 1.0, 10.0);
        // The target is at the centre; near and far map to depth 0 and 1.
        let c = m.project_point3(Vec3::ZERO);
        assert!(c.x.abs() < 1e-6 && c.y.abs() < 1e-6 && c.z > 0.0 && c.z < 1.0);
        assert!(m.project_point3(Vec3::new(0.0, 0.0, 4.0)).z.abs() < 1e-5);
        assert!((m.project_point3(Vec3::new(0.0, 0.0, -5.0)).z - 1.0).abs() < 1e-5);
        // +Y up on screen, +X right.
        assert!(m.project_point3(Vec3::new(0.0, 1.0, 0.0)).y > 0.0);
        assert!(m.project_point3(Vec3::new(1.0, 0.0, 0.0)).x > 0.0);
        // The top of the field of view maps to y = 1.
        let top = Vec3::new(0.0, 5.0 * (0.5f32).tan(), 0.0);
        assert!((m.project_point3(top).y - 1.0).abs() < 1e-5);
    }

    #[test]
    fn default_scene_has_casters_and_ground() {
        let s = Scene::default_scene();
        assert!(s.caster_indices > 0 && s.caster_indices < s.indices.len() as u32);
        assert!(s.ground_material.is_some());
        assert!(s.indices.iter().all(|&i| (i as usize) < s.vertices.len()));
        // The casters sit on the ground; the bounds hold all three spheres.
        assert!(s.bounds.radius > 1.5 && s.bounds.radius < 3.0);
    }

    #[test]
    fn cuboid_faces_point_outwards() {
        let mut b = Builder::default();
        let m = b.material(Material::default());
        b.cuboid(Vec3::ZERO, Vec3::ONE, m);
        for t in b.indices.chunks_exact(3) {
            let p = |i: u32| Vec3::from_array(b.vertices[i as usize].position);
            let face = (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]));
            let n = Vec3::from_array(b.vertices[t[0] as usize].normal);
            assert!(face.dot(n) > 0.0, "triangle {t:?} winds inwards");
        }
    }

    #[test]
    fn sphere_triangles_wind_outwards() {
        let mut b = Builder::default();
        let m = b.material(Material::default());
        b.uv_sphere(Vec3::ZERO, 1.0, 16, m);
        let mut checked = 0;
        for t in b.indices.chunks_exact(3) {
            let p = |i: u32| Vec3::from_array(b.vertices[i as usize].position);
            let face = (p(t[1]) - p(t[0])).cross(p(t[2]) - p(t[0]));
            if face.length() > 1e-6 {
                assert!(face.dot(p(t[0])) > 0.0);
                checked += 1;
            }
        }
        assert!(checked > 100);
    }

    #[test]
    fn bad_files_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("broken.gltf");
        std::fs::write(&p, b"{ not json").unwrap();
        let e = Scene::load(&p, true).unwrap_err().to_string();
        assert!(e.contains("broken.gltf"), "{e}");
        let p = dir.path().join("missing.obj");
        let e = Scene::load(&p, true).unwrap_err().to_string();
        assert!(e.contains("missing.obj"), "{e}");
        let p = dir.path().join("model.stl");
        std::fs::write(&p, b"solid").unwrap();
        let e = Scene::load(&p, true).unwrap_err().to_string();
        assert!(
            e.contains("model.stl") && e.contains("unknown format"),
            "{e}"
        );
        let p = dir.path().join("empty.obj");
        std::fs::write(&p, b"# nothing\n").unwrap();
        let e = Scene::load(&p, true).unwrap_err().to_string();
        assert!(e.contains("empty.obj"), "{e}");
    }

    #[test]
    fn obj_with_material_loads() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("m.mtl"),
            "newmtl red\nKd 0.9 0.1 0.1\nNs 98\n",
        )
        .unwrap();
        let p = dir.path().join("tri.obj");
        std::fs::write(
            &p,
            "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl red\nf 1 2 3\nf 2 4 3\n",
        )
        .unwrap();
        let s = Scene::load(&p, true).unwrap();
        assert_eq!(s.caster_indices, 6);
        assert_eq!(s.materials[0].base_color, [0.9, 0.1, 0.1]);
        assert!(s.materials[0].roughness < 0.5);
        // Computed normals face +Z (counter-clockwise faces).
        assert!(s.vertices[0].normal[2] > 0.99);
    }

    /// A zero normal in the file (`vn 0 0 0`) becomes its triangles' normal, not +Y (which lit
    /// a wall as if it faced up); the given ones are kept.
    #[test]
    fn zero_normals_take_their_triangles_normal() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("wall.obj");
        std::fs::write(
            &p,
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 0\nvn 1 0 0\nf 1//1 2//1 3//2\n",
        )
        .unwrap();
        let s = Scene::load(&p, false).unwrap();
        assert_eq!(s.vertices.len(), 3);
        assert_eq!(s.vertices[0].normal, [0.0, 0.0, 1.0]);
        assert_eq!(s.vertices[2].normal, [1.0, 0.0, 0.0]);
    }

    #[test]
    fn gltf_with_embedded_buffer_loads_with_transform_and_material() {
        // One triangle, translated by +2 in y, metallic-roughness material.
        let positions: [f32; 9] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let bytes: Vec<u8> = positions.iter().flat_map(|f| f.to_le_bytes()).collect();
        let b64 = base64_encode(&bytes);
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
            "nodes":[{{"mesh":0,"translation":[0,2,0]}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"material":0}}]}}],
            "materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":[0.1,0.2,0.3,1],"metallicFactor":1.0,"roughnessFactor":0.25}}}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
            "bufferViews":[{{"buffer":0,"byteLength":36}}],
            "buffers":[{{"byteLength":36,"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#
        );
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tri.gltf");
        std::fs::write(&p, json).unwrap();
        let s = Scene::load(&p, false).unwrap();
        assert_eq!(s.caster_indices, 3);
        assert_eq!(s.vertices[2].position, [0.0, 3.0, 0.0]);
        assert_eq!(s.materials[0].base_color, [0.1, 0.2, 0.3]);
        assert_eq!(s.materials[0].roughness, 0.25);
        assert_eq!(s.materials[0].metallic, 1.0);
        assert!(s.ground_material.is_none());
    }

    /// A 2 × 1 PNG: a red and a blue texel.
    fn two_texel_png() -> Vec<u8> {
        let mut png = Vec::new();
        image::RgbaImage::from_raw(2, 1, two_texel_png_rgba())
            .unwrap()
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        png
    }

    /// A one-triangle glTF with TEXCOORD_0 and a base-colour and a metallic-roughness texture
    /// of the image at `image_uri`, its sampler clamping u and mirroring v.
    fn textured_gltf(dir: &Path, name: &str, image_uri: &str) -> PathBuf {
        let positions: [f32; 9] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let uvs: [f32; 6] = [0.0, 0.0, 1.0, 0.0, 0.0, 2.0];
        let bytes: Vec<u8> = positions
            .iter()
            .chain(&uvs)
            .flat_map(|f| f.to_le_bytes())
            .collect();
        let b64 = base64_encode(&bytes);
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":1}},"material":0}}]}}],
            "materials":[{{"pbrMetallicRoughness":{{"baseColorTexture":{{"index":0}},"metallicRoughnessTexture":{{"index":0}}}},
                          "normalTexture":{{"index":0}}}}],
            "textures":[{{"source":0,"sampler":0}}],
            "samplers":[{{"wrapS":33071,"wrapT":33648}}],
            "images":[{{"uri":"{image_uri}"}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                         {{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}}],
            "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":24}}],
            "buffers":[{{"byteLength":60,"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#
        );
        let path = dir.join(name);
        std::fs::write(&path, json).unwrap();
        path
    }

    /// The text of a [`textured_gltf`] whose image is the [`two_texel_png`] `tex.png`, both
    /// written to `dir`, for tests that edit the file.
    fn textured_gltf_text(dir: &Path) -> String {
        std::fs::write(dir.join("tex.png"), two_texel_png()).unwrap();
        std::fs::read_to_string(textured_gltf(dir, "t.gltf", "tex.png")).unwrap()
    }

    /// glTF textures load from a data URI or a file beside the scene, once per image, with
    /// their sampler's wrap modes and the primitive's TEXCOORD_0; the scene's files include
    /// the image file; an image that is missing, corrupt or neither PNG nor JPEG is an error
    /// naming the image and the problem.
    #[test]
    fn gltf_textures_load_with_their_coordinates_and_wrap_modes() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let png = two_texel_png();
        let data_uri = format!("data:image/png;base64,{}", base64_encode(&png));
        std::fs::write(d.join("tex.png"), &png).unwrap();
        for uri in [data_uri.as_str(), "tex.png"] {
            let p = textured_gltf(d, "t.gltf", uri);
            let s = Scene::load(&p, false).unwrap();
            assert_eq!(s.textures.len(), 1, "{uri}: one image, used twice");
            assert_eq!((s.textures[0].width, s.textures[0].height), (2, 1));
            assert_eq!(s.textures[0].rgba, [255, 0, 0, 255, 0, 0, 255, 255]);
            let t = s.materials[0].textures;
            let want = TextureRef {
                image: 0,
                wrap: [Wrap::ClampToEdge, Wrap::MirroredRepeat],
                transform: NO_UV_TRANSFORM,
                channel: 0,
            };
            assert_eq!(
                (t.base_color, t.metallic_roughness),
                (Some(want), Some(want))
            );
            let uvs: Vec<_> = s.vertices.iter().map(|v| v.uv).collect();
            assert_eq!(uvs, [[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]]);
            if uri == "tex.png" {
                assert!(scene_files(&p).contains(&d.join("tex.png")));
            }
        }
        std::fs::write(d.join("bad.png"), &png[..png.len() / 2]).unwrap();
        std::fs::write(d.join("pic.gif"), b"GIF89a\x01\x00\x01\x00").unwrap();
        for (uri, needle) in [
            ("missing.png", "missing.png"),
            ("bad.png", "bad.png"),
            ("pic.gif", "not a PNG or JPEG"),
        ] {
            let p = textured_gltf(d, "t.gltf", uri);
            let e = Scene::load(&p, false).unwrap_err().to_string();
            assert!(
                e.contains("t.gltf") && e.contains("image 0") && e.contains(needle),
                "{uri}: {e}"
            );
        }
    }

    /// The CPU sampler (per-vertex albedo) filters bilinearly between texel centres and wraps
    /// as the GPU's sampler does; a vertex's base colour is its factor times the texture there,
    /// read through the texture's transform.
    #[test]
    fn textures_sample_bilinearly_with_their_wrap_modes() {
        // Texels: sRGB 0 and 255 (linear 0 and 1).
        let image = TextureImage {
            name: "t".into(),
            width: 2,
            height: 1,
            rgba: vec![0, 0, 0, 255, 255, 255, 255, 255],
        };
        let at = |u: f32, wrap: Wrap| image.sample_srgb([u, 0.5], [wrap; 2])[0];
        let close = |a: f32, b: f32| (a - b).abs() < 1e-6;
        // Texel centres at u = 0.25 and 0.75; halfway between them, half of each.
        assert!(close(at(0.25, Wrap::Repeat), 0.0));
        assert!(close(at(0.75, Wrap::Repeat), 1.0));
        assert!(close(at(0.5, Wrap::Repeat), 0.5));
        // Past the right edge: repeat reaches the first texel again, clamp stays on the last,
        // mirror reads the last twice.
        assert!(close(at(1.0, Wrap::Repeat), 0.5));
        assert!(close(at(1.0, Wrap::ClampToEdge), 1.0));
        assert!(close(at(1.0, Wrap::MirroredRepeat), 1.0));
        assert!(close(at(1.25, Wrap::MirroredRepeat), 1.0));
        assert!(close(at(1.75, Wrap::MirroredRepeat), 0.0));
        assert!(close(at(-0.25, Wrap::ClampToEdge), 0.0));
        // Far-out coordinates (no fraction left in f32) still read a texel.
        let far = at(1e30, Wrap::Repeat);
        assert!((0.0..=1.0).contains(&far), "{far}");
        let mut scene = Scene::default_scene();
        scene.textures = vec![image];
        scene.materials[0].base_color = [0.5, 0.5, 0.5];
        scene.materials[0].textures.base_color = Some(TextureRef::repeating(0));
        let v = scene.vertices.iter().position(|v| v.material == 0).unwrap();
        scene.vertices[v].uv = [0.75, 0.5];
        assert_eq!(scene.vertex_base_color(v), [0.5; 3]);
        scene.vertices[v].uv = [0.25, 0.5];
        assert_eq!(scene.vertex_base_color(v), [0.0; 3]);
        // The texture's transform applies: an offset of half the image reads the other texel.
        scene.materials[0].textures.base_color = Some(TextureRef {
            transform: [[1.0, 0.0, 0.5], [0.0, 1.0, 0.0]],
            ..TextureRef::repeating(0)
        });
        assert_eq!(scene.vertex_base_color(v), [0.5; 3]);
        let untextured = scene.vertices.iter().position(|v| v.material == 1).unwrap();
        assert_eq!(
            scene.vertex_base_color(untextured),
            scene.materials[1].base_color
        );
    }

    /// A normal texture's tangents: MikkTSpace's where the file has none, in glTF's convention
    /// (xyz along increasing u, cross(n, t)·w up the image, towards decreasing v); the file's
    /// turned with the node, whose mirroring flips w.
    #[test]
    fn normal_textures_get_tangents_in_gltf_convention() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("tex.png"), two_texel_png()).unwrap();
        // textured_gltf: u grows along +x, v along +y (v = 2 at y = 1), the normal is +z; up
        // the image is −y = cross(+z, +x)·(−1).
        let s = Scene::load(&textured_gltf(d, "t.gltf", "tex.png"), false).unwrap();
        assert!(s.materials[0].textures.normal.is_some());
        for v in &s.vertices {
            let t = v.tangent;
            assert!(
                (t[0] - 1.0).abs() < 1e-5 && t[1].abs() < 1e-5 && t[2].abs() < 1e-5,
                "{t:?}"
            );
            assert_eq!(t[3], -1.0);
        }
        // The file's tangents (+x, w = +1) under a node mirrored in x: −x, w = −1.
        let positions: [f32; 9] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let uvs: [f32; 6] = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0];
        let tangents: [f32; 12] = [1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0];
        let bytes: Vec<u8> = positions
            .iter()
            .chain(&uvs)
            .chain(&tangents)
            .flat_map(|f| f.to_le_bytes())
            .collect();
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0,"scale":[-1,1,1]}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":1,"TANGENT":2}},"material":0}}]}}],
            "materials":[{{"normalTexture":{{"index":0,"scale":0.5}}}}],
            "textures":[{{"source":0}}],"images":[{{"uri":"tex.png"}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                         {{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}},
                         {{"bufferView":2,"componentType":5126,"count":3,"type":"VEC4"}}],
            "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":24}},
                           {{"buffer":0,"byteOffset":60,"byteLength":48}}],
            "buffers":[{{"byteLength":108,"uri":"data:application/octet-stream;base64,{}"}}]}}"#,
            base64_encode(&bytes)
        );
        let p = d.join("mirrored.gltf");
        std::fs::write(&p, json).unwrap();
        let s = Scene::load(&p, false).unwrap();
        assert_eq!(s.materials[0].textures.normal_scale, 0.5);
        for v in &s.vertices {
            assert_eq!(v.tangent, [-1.0, 0.0, 0.0, -1.0]);
        }
        // An untextured scene has no tangents.
        assert!(Scene::default_scene()
            .vertices
            .iter()
            .all(|v| v.tangent == [0.0; 4]));
    }

    /// KHR_texture_transform: T(offset) · R(rotation) · S(scale) as the extension defines it,
    /// read for the base colour (a textureInfo) and the normal texture alike, its texCoord
    /// overriding the texture's; bad values are errors naming the property; the extension is
    /// not among those named as not drawn.
    #[test]
    fn texture_transforms_are_read_as_the_extension_defines_them() {
        let (m, set) = uv_transform(&serde_json::json!({})).unwrap();
        assert_eq!((m, set), (NO_UV_TRANSFORM, None));
        let (m, set) = uv_transform(&serde_json::json!({
            "offset": [0.5, -1], "rotation": std::f64::consts::FRAC_PI_2, "scale": [2, 3],
            "texCoord": 1
        }))
        .unwrap();
        // R(90°) maps u to v: (u, v) → (−3v + 0.5, 2u − 1).
        let close = |a: [[f32; 3]; 2], b: [[f32; 3]; 2]| {
            a.iter()
                .flatten()
                .zip(b.iter().flatten())
                .all(|(x, y)| (x - y).abs() < 1e-6)
        };
        assert!(close(m, [[0.0, -3.0, 0.5], [2.0, 0.0, -1.0]]), "{m:?}");
        assert_eq!(set, Some(1));
        for (bad, needle) in [
            (serde_json::json!({"offset": [1]}), "offset"),
            (serde_json::json!({"scale": "big"}), "scale"),
            (serde_json::json!({"rotation": [1]}), "rotation"),
            (serde_json::json!({"texCoord": -1}), "texCoord"),
        ] {
            let e = uv_transform(&bad).unwrap_err();
            assert!(e.contains(needle), "{e}");
        }
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = textured_gltf_text(d);
        let ext = r#""extensions":{"KHR_texture_transform":{"offset":[0.25,0],"scale":[2,2]}}"#;
        let text = text
            .replace(
                r#""baseColorTexture":{"index":0}"#,
                &format!(r#""baseColorTexture":{{"index":0,{ext}}}"#),
            )
            .replace(
                r#""normalTexture":{"index":0}"#,
                &format!(r#""normalTexture":{{"index":0,{ext}}}"#),
            )
            .replacen("{", r#"{"extensionsUsed":["KHR_texture_transform"],"#, 1);
        let p = d.join("transformed.gltf");
        std::fs::write(&p, &text).unwrap();
        let s = Scene::load(&p, false).unwrap();
        let t = s.materials[0].textures;
        let want = [[2.0, 0.0, 0.25], [0.0, 2.0, 0.0]];
        assert_eq!(t.base_color.unwrap().transform, want);
        assert_eq!(t.normal.unwrap().transform, want);
        assert_eq!(t.metallic_roughness.unwrap().transform, NO_UV_TRANSFORM);
        std::fs::write(&p, text.replace("[2,2]", "[2]")).unwrap();
        let e = Scene::load(&p, false).unwrap_err().to_string();
        assert!(e.contains("KHR_texture_transform.scale"), "{e}");
    }

    /// glTF's occlusion texture (with its strength) and emission (factor × the emissive
    /// strength extension, times the emissive texture) load, and the vertex emission samples
    /// them; out-of-range values are errors naming the property; the extension is not named as
    /// not drawn.
    #[test]
    fn occlusion_and_emission_load_with_their_strengths() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = textured_gltf_text(d);
        let with = |occlusion: &str, emissive: &str, strength: &str| {
            text.replace(
                r#""normalTexture":{"index":0}"#,
                &format!(
                    r#""normalTexture":{{"index":0}},
                    "occlusionTexture":{{"index":0,"strength":{occlusion}}},
                    "emissiveTexture":{{"index":0}},"emissiveFactor":{emissive},
                    "extensions":{{"KHR_materials_emissive_strength":{{"emissiveStrength":{strength}}}}}"#
                ),
            )
            .replacen(
                "{",
                r#"{"extensionsUsed":["KHR_materials_emissive_strength"],"#,
                1,
            )
        };
        let p = d.join("glowing.gltf");
        std::fs::write(&p, with("0.25", "[1,0.5,0]", "4")).unwrap();
        let s = Scene::load(&p, false).unwrap();
        let m = s.materials[0];
        let want = TextureRef {
            image: 0,
            wrap: [Wrap::ClampToEdge, Wrap::MirroredRepeat],
            transform: NO_UV_TRANSFORM,
            channel: 0,
        };
        assert_eq!(m.textures.occlusion, Some(want));
        assert_eq!(m.textures.occlusion_strength, 0.25);
        assert_eq!(m.textures.emissive, Some(want));
        assert_eq!(m.emission, [4.0, 2.0, 0.0]);
        // Vertex 0 sits at uv (0, 0): the red texel's centre is at u = 0.25, clamped left of
        // it; vertex 1 at u = 1, clamped to the blue texel.
        assert_eq!(s.vertex_emission(0), [4.0, 0.0, 0.0]);
        assert_eq!(s.vertex_emission(1), [0.0; 3]);
        assert_eq!(s.vertex_emission(99), [0.0; 3]);
        for (bad, needle) in [
            (with("1.5", "[1,0,0]", "1"), "occlusionTexture.strength 1.5"),
            (with("1", "[2,0,0]", "1"), "emissiveFactor"),
            (with("1", "[1,0,0]", "-1"), "emissiveStrength -1"),
            (with("1", "[1,0,0]", "\"big\""), "emissiveStrength"),
        ] {
            std::fs::write(&p, bad).unwrap();
            let e = Scene::load(&p, false).unwrap_err().to_string();
            assert!(e.contains("glowing.gltf") && e.contains(needle), "{e}");
        }
    }

    /// The summary names what the scene holds.
    #[test]
    fn summaries_count_triangles_materials_and_textures() {
        let mut s = Scene::default_scene();
        let plain = s.summary();
        assert!(
            plain.ends_with("5 materials, 0 texture images")
                && plain.contains(&format!("{} triangles", s.indices.len() / 3)),
            "{plain}"
        );
        s.materials[0].alpha_mode = AlphaMode::Blend;
        s.materials[1].clearcoat = 0.5;
        s.materials[2].emission = [1.0; 3];
        let text = s.summary();
        assert!(
            text.contains("5 materials (1 blended, 1 clear-coated, 1 emissive)"),
            "{text}"
        );
    }

    /// `KHR_materials_ior` sets the dielectric specular level (F0 = 0.16 · level² =
    /// ((ior − 1)/(ior + 1))²) and `KHR_materials_specular` its strength and tint, which
    /// [`Material::dielectric_fresnel`] combines as the extension does; without them F0 is
    /// 0.04 and F90 1; `KHR_materials_clearcoat` gives the coat's factors; bad values are
    /// errors naming the property.
    #[test]
    fn ior_specular_and_clearcoat_load_with_their_factors() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = textured_gltf_text(d);
        let p = d.join("shiny.gltf");
        let with = |extensions: &str| {
            text.replace(
                r#""normalTexture":{"index":0}"#,
                &format!(r#""normalTexture":{{"index":0}},"extensions":{{{extensions}}}"#),
            )
        };
        let load = |extensions: &str| {
            std::fs::write(&p, with(extensions)).unwrap();
            Scene::load(&p, false).map(|s| s.materials[0])
        };
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-6);
        let m = load("").unwrap();
        let (f0, f90) = m.dielectric_fresnel();
        assert!(close(f0, [0.04; 3]) && f90 == 1.0, "{f0:?} {f90}");
        // Diamond: ((2.42 − 1)/(3.42))² = 0.1724.
        let m = load(r#""KHR_materials_ior":{"ior":2.42}"#).unwrap();
        let f = (1.42f32 / 3.42).powi(2);
        assert!(close(m.dielectric_fresnel().0, [f; 3]), "{m:?}");
        let m = load(
            r#""KHR_materials_ior":{"ior":2},
               "KHR_materials_specular":{"specularFactor":0.5,"specularColorFactor":[1,0.5,8]}"#,
        )
        .unwrap();
        let (f0, f90) = m.dielectric_fresnel();
        let ninth = 1.0 / 9.0;
        // The tinted F0 is clamped to 1 before the factor: 8/9 stays, as 0.5 · 8/9.
        assert!(
            close(f0, [0.5 * ninth, 0.25 * ninth, 0.5 * 8.0 * ninth]),
            "{f0:?}"
        );
        assert_eq!(f90, 0.5);
        let m = load(r#""KHR_materials_ior":{"ior":1}"#).unwrap();
        assert_eq!(
            m.dielectric_fresnel(),
            ([0.0; 3], 0.0),
            "ior 1 reflects nothing"
        );
        // A clear coat's factors (none without the extension).
        assert_eq!((m.clearcoat, m.clearcoat_roughness), (0.0, 0.0));
        let m = load(
            r#""KHR_materials_clearcoat":{"clearcoatFactor":0.75,"clearcoatRoughnessFactor":0.25}"#,
        )
        .unwrap();
        assert_eq!((m.clearcoat, m.clearcoat_roughness), (0.75, 0.25));
        for (extensions, needle) in [
            (
                r#""KHR_materials_ior":{"ior":0.5}"#,
                "KHR_materials_ior.ior 0.5",
            ),
            (
                r#""KHR_materials_ior":{"ior":"glass"}"#,
                "KHR_materials_ior.ior \"glass\"",
            ),
            (
                r#""KHR_materials_specular":{"specularFactor":2}"#,
                "specularFactor 2 must lie in [0, 1]",
            ),
            (
                r#""KHR_materials_specular":{"specularColorFactor":[1,-1,0]}"#,
                "specularColorFactor [1,-1,0]",
            ),
            (
                r#""KHR_materials_specular":{"specularColorFactor":[1,1]}"#,
                "specularColorFactor [1,1]",
            ),
            (
                r#""KHR_materials_clearcoat":{"clearcoatFactor":1.5}"#,
                "KHR_materials_clearcoat.clearcoatFactor 1.5 must lie in [0, 1]",
            ),
            (
                r#""KHR_materials_clearcoat":{"clearcoatRoughnessFactor":-1}"#,
                "clearcoatRoughnessFactor -1",
            ),
        ] {
            let e = load(extensions).unwrap_err().to_string();
            assert!(e.contains("shiny.gltf") && e.contains(needle), "{e}");
        }
    }

    /// A glTF scene's first camera node (by index) is its camera: the eye at the node's world
    /// position, looking along its −Z, with its vertical field of view; a rolled one loads
    /// (drawn level); an orthographic one leaves the fitted camera; a bad field of view is an
    /// error naming the node. A camera override replaces the parts given and refuses bad ones.
    #[test]
    fn gltf_cameras_place_the_view_and_overrides_replace_it() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = textured_gltf_text(d);
        let p = d.join("camera.gltf");
        let load = |nodes: &str, cameras: &str| {
            let edited = text
                .replace(
                    r#""scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],"#,
                    &format!(r#""scenes":[{{"nodes":[0,1,2]}}],"nodes":[{{"mesh":0}},{nodes}],"cameras":[{cameras}],"#),
                );
            assert_ne!(edited, text);
            std::fs::write(&p, edited).unwrap();
            Scene::load(&p, false)
        };
        let perspective = r#"{"type":"perspective","perspective":{"yfov":0.5,"znear":0.1}}"#;
        let ortho =
            r#"{"type":"orthographic","orthographic":{"xmag":1,"ymag":1,"zfar":10,"znear":0.1}}"#;
        // Node 2 (a camera turned 90° about +Y, looking along −X) is not the first; node 1 is.
        let s = load(
            r#"{"camera":0,"translation":[0,1,5]},
               {"camera":1,"translation":[3,0,0],"rotation":[0,0.70710677,0,0.70710677]}"#,
            &format!("{perspective},{perspective}"),
        )
        .unwrap();
        assert_eq!(s.camera.eye, Vec3::new(0.0, 1.0, 5.0));
        assert!((s.camera.target - Vec3::new(0.0, 1.0, 4.0)).length() < 1e-6);
        assert_eq!(s.camera.fov_y, 0.5);
        let s = load(
            r#"{"camera":1,"translation":[0,1,5]},
               {"camera":0,"translation":[3,0,0],"rotation":[0,0.70710677,0,0.70710677]}"#,
            &format!("{perspective},{ortho}"),
        )
        .unwrap();
        assert_eq!(s.camera, fit_camera(s.bounds), "orthographic: fitted");
        let s = load(
            r#"{"camera":0,"translation":[3,0,0],"rotation":[0,0.70710677,0,0.70710677]},
               {"camera":0,"translation":[0,0,9],"rotation":[0,0,0.38268343,0.9238795]}"#,
            perspective,
        )
        .unwrap();
        assert!((s.camera.target - s.camera.eye - Vec3::NEG_X).length() < 1e-6);
        // Rolled 45° about its view direction (node 2): loads, drawn level.
        let s = load(
            r#"{"camera":0,"translation":[0,0,9],"rotation":[0,0,0.38268343,0.9238795]},
               {"translation":[0,0,0]}"#,
            perspective,
        )
        .unwrap();
        assert!((s.camera.target - s.camera.eye - Vec3::NEG_Z).length() < 1e-6);
        let e = load(
            r#"{"camera":0,"translation":[0,1,5]},{"translation":[0,0,0]}"#,
            r#"{"type":"perspective","perspective":{"yfov":4,"znear":0.1}}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("camera.gltf") && e.contains("camera node 1") && e.contains("yfov 4"),
            "{e}"
        );
        // Overrides.
        let camera = s.camera;
        let moved = CameraOverride {
            eye: Some(Vec3::new(1.0, 2.0, 3.0)),
            fov_deg: Some(30.0),
            ..Default::default()
        }
        .apply(camera)
        .unwrap();
        assert_eq!(moved.eye, Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(moved.target, camera.target);
        assert!((moved.fov_y - 30f32.to_radians()).abs() < 1e-7);
        for (bad, needle) in [
            (
                CameraOverride {
                    fov_deg: Some(0.5),
                    ..Default::default()
                },
                "field of view 0.5° is outside 1..=179°",
            ),
            (
                CameraOverride {
                    eye: Some(camera.target),
                    ..Default::default()
                },
                "is where it looks",
            ),
            (
                CameraOverride {
                    look_at: Some(Vec3::new(f32::NAN, 0.0, 0.0)),
                    ..Default::default()
                },
                "not finite",
            ),
        ] {
            let e = bad.apply(camera).unwrap_err();
            assert!(e.contains(needle), "{e}");
        }
    }

    /// KHR_mesh_quantization: positions, normals, tangents and texture coordinates as bytes
    /// and shorts load as the floats they stand for — normalised ones mapped as glTF defines
    /// (a signed minimum clamped to −1), plain ones as their values, scaled by the node as a
    /// quantising writer arranges — through strided views; a 32-bit integer position is still
    /// refused, and no number mutated to a hostile value makes the loader panic.
    #[test]
    fn quantized_attributes_load_as_the_floats_they_stand_for() {
        let mut bin: Vec<u8> = Vec::new();
        // POSITION: i16, not normalised, 8-byte stride (glTF's 4-byte alignment).
        for p in [[0i16, 0, 0], [1000, 0, 0], [0, 1000, 0]] {
            for c in p {
                bin.extend(c.to_le_bytes());
            }
            bin.extend([0u8; 2]);
        }
        // NORMAL: i8, normalised, 4-byte stride; −128 is clamped to −1.
        for n in [[0i8, 0, 127], [0, 0, 127], [0, -128, 0]] {
            bin.extend(n.map(|c| c as u8));
            bin.push(0);
        }
        // TEXCOORD_0: u16, normalised.
        for t in [[0u16, 0], [65535, 0], [0, 65535]] {
            for c in t {
                bin.extend(c.to_le_bytes());
            }
        }
        // TEXCOORD_1: u8, not normalised (texture coordinates past 1), 4-byte stride.
        for t in [[0u8, 0], [2, 0], [0, 2]] {
            bin.extend(t);
            bin.extend([0u8; 2]);
        }
        // TANGENT: i16, normalised.
        for t in [
            [32767i16, 0, 0, 32767],
            [32767, 0, 0, 32767],
            [32767, 0, 0, -32767],
        ] {
            for c in t {
                bin.extend(c.to_le_bytes());
            }
        }
        assert_eq!(bin.len(), 24 + 12 + 12 + 12 + 24);
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},
            "extensionsUsed":["KHR_mesh_quantization"],"extensionsRequired":["KHR_mesh_quantization"],
            "scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0,"scale":[0.001,0.001,0.001]}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1,"TEXCOORD_0":2,
                "TEXCOORD_1":3,"TANGENT":4}},"material":0}}]}}],
            "materials":[{{"pbrMetallicRoughness":{{"baseColorTexture":{{"index":0}}}},
                "normalTexture":{{"index":0}},"occlusionTexture":{{"index":0,"texCoord":1}}}}],
            "textures":[{{"source":0}}],"images":[{{"uri":"tex.png"}}],
            "accessors":[
                {{"bufferView":0,"componentType":5122,"count":3,"type":"VEC3","min":[0,0,0],"max":[1000,1000,0]}},
                {{"bufferView":1,"componentType":5120,"normalized":true,"count":3,"type":"VEC3"}},
                {{"bufferView":2,"componentType":5123,"normalized":true,"count":3,"type":"VEC2"}},
                {{"bufferView":3,"componentType":5121,"count":3,"type":"VEC2"}},
                {{"bufferView":4,"componentType":5122,"normalized":true,"count":3,"type":"VEC4"}}],
            "bufferViews":[{{"buffer":0,"byteLength":24,"byteStride":8}},
                {{"buffer":0,"byteOffset":24,"byteLength":12,"byteStride":4}},
                {{"buffer":0,"byteOffset":36,"byteLength":12}},
                {{"buffer":0,"byteOffset":48,"byteLength":12,"byteStride":4}},
                {{"buffer":0,"byteOffset":60,"byteLength":24}}],
            "buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{}"}}]}}"#,
            bin.len(),
            base64_encode(&bin)
        );
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("tex.png"), two_texel_png()).unwrap();
        let path = dir.path().join("quantized.gltf");
        std::fs::write(&path, json).unwrap();
        let s = Scene::load(&path, false).unwrap();
        let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5);
        let positions: Vec<[f32; 3]> = s.vertices.iter().map(|v| v.position).collect();
        assert!(
            positions
                .iter()
                .zip([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
                .all(|(a, b)| close(a, &b)),
            "{positions:?}"
        );
        let normals: Vec<[f32; 3]> = s.vertices.iter().map(|v| v.normal).collect();
        assert!(
            close(&normals[0], &[0.0, 0.0, 1.0]) && close(&normals[2], &[0.0, -1.0, 0.0]),
            "{normals:?}"
        );
        let uv: Vec<[f32; 2]> = s.vertices.iter().map(|v| v.uv).collect();
        assert_eq!(uv, [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
        let uv1: Vec<[f32; 2]> = s.vertices.iter().map(|v| v.uv1).collect();
        assert_eq!(uv1, [[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]]);
        let tangents: Vec<[f32; 4]> = s.vertices.iter().map(|v| v.tangent).collect();
        assert!(
            close(&tangents[0], &[1.0, 0.0, 0.0, 1.0])
                && close(&tangents[2], &[1.0, 0.0, 0.0, -1.0]),
            "{tangents:?}"
        );
        // A 32-bit integer position is still refused in words.
        let text = std::fs::read_to_string(&path).unwrap();
        let position = r#""componentType":5122,"count":3,"type":"VEC3""#;
        let wide = text.replacen(position, &position.replace("5122", "5125"), 1);
        std::fs::write(&path, wide).unwrap();
        let e = Scene::load(&path, false).unwrap_err().to_string();
        assert!(e.contains("POSITION") && e.contains("U32"), "{e}");
        for (start, end) in number_spans(&text) {
            for value in HOSTILE_NUMBERS {
                let mutated = format!("{}{value}{}", &text[..start], &text[end..]);
                std::fs::write(&path, mutated).unwrap();
                loads_without_panic(&path);
            }
        }
    }

    /// The textures of KHR_materials_specular and KHR_materials_clearcoat load into their
    /// slots with their own coordinate sets, transforms and (the coat's normal texture) scale;
    /// a clear-coat normal texture alone gets the mesh tangents; a missing, out-of-range or
    /// malformed texture reference is an error naming the property.
    #[test]
    fn specular_and_clearcoat_textures_load_into_their_slots() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = textured_gltf_text(d);
        let p = d.join("layered.gltf");
        let load = |extensions: &str| {
            let edited = text.replace(
                r#""normalTexture":{"index":0}"#,
                &format!(r#""extensions":{{{extensions}}}"#),
            );
            std::fs::write(&p, edited).unwrap();
            Scene::load(&p, false)
        };
        let s = load(
            r#""KHR_materials_specular":{"specularTexture":{"index":0},
                 "specularColorTexture":{"index":0,"extensions":{"KHR_texture_transform":{"offset":[0.5,0]}}}},
               "KHR_materials_clearcoat":{"clearcoatFactor":1,"clearcoatTexture":{"index":0},
                 "clearcoatRoughnessTexture":{"index":0,"texCoord":0},
                 "clearcoatNormalTexture":{"index":0,"scale":0.5}}"#,
        )
        .unwrap();
        let t = s.materials[0].textures;
        let plain = TextureRef {
            image: 0,
            wrap: [Wrap::ClampToEdge, Wrap::MirroredRepeat],
            transform: NO_UV_TRANSFORM,
            channel: 0,
        };
        assert_eq!(s.textures.len(), 1, "one image for all the slots");
        assert_eq!(t.normal, None);
        for (name, slot) in [
            ("specular", t.specular),
            ("clear coat", t.clearcoat),
            ("clear-coat roughness", t.clearcoat_roughness),
            ("clear-coat normal", t.clearcoat_normal),
        ] {
            assert_eq!(slot, Some(plain), "{name}");
        }
        let moved = t.specular_color.unwrap();
        assert_eq!(moved.transform, [[1.0, 0.0, 0.5], [0.0, 1.0, 0.0]]);
        assert_eq!(t.clearcoat_normal_scale, 0.5);
        assert!(
            s.vertices.iter().all(|v| v.tangent[..3] != [0.0; 3]),
            "the coat's normal texture needs tangents: {:?}",
            s.vertices
        );
        for (extensions, needle) in [
            (
                r#""KHR_materials_clearcoat":{"clearcoatTexture":{"index":3}}"#,
                "KHR_materials_clearcoat.clearcoatTexture.index 3: the file has 1 textures",
            ),
            (
                r#""KHR_materials_specular":{"specularTexture":{"texCoord":0}}"#,
                "KHR_materials_specular.specularTexture has no index",
            ),
            (
                r#""KHR_materials_specular":{"specularColorTexture":{"index":-1}}"#,
                "KHR_materials_specular.specularColorTexture.index -1 is not a whole number",
            ),
            (
                r#""KHR_materials_clearcoat":{"clearcoatNormalTexture":{"index":0,"scale":"x"}}"#,
                "KHR_materials_clearcoat.clearcoatNormalTexture.scale \"x\" is not a finite",
            ),
        ] {
            let e = load(extensions).unwrap_err().to_string();
            assert!(e.contains("layered.gltf") && e.contains(needle), "{e}");
        }
    }

    /// glTF's alpha mode MASK gives a cutoff (0.5 by default), BLEND blending, and each the
    /// base colour factor's alpha; a negative cutoff is an error naming it.
    #[test]
    fn alpha_modes_load_with_their_cutoff() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = textured_gltf_text(d);
        let p = d.join("masked.gltf");
        let with = |mode: &str| {
            text.replace(
                r#""baseColorTexture":{"index":0}"#,
                r#""baseColorFactor":[1,1,1,0.25],"baseColorTexture":{"index":0}"#,
            )
            .replace(
                r#""normalTexture":{"index":0}"#,
                &format!(r#""normalTexture":{{"index":0}}{mode}"#),
            )
        };
        for (mode, cutoff) in [
            (r#","alphaMode":"MASK""#, AlphaMode::Mask(0.5)),
            (
                r#","alphaMode":"MASK","alphaCutoff":0.75"#,
                AlphaMode::Mask(0.75),
            ),
            (r#","alphaMode":"BLEND""#, AlphaMode::Blend),
            (r#","alphaMode":"OPAQUE""#, AlphaMode::Opaque),
            ("", AlphaMode::Opaque),
        ] {
            std::fs::write(&p, with(mode)).unwrap();
            let m = Scene::load(&p, false).unwrap().materials[0];
            assert_eq!((m.alpha, m.alpha_mode), (0.25, cutoff), "{mode}");
        }
        std::fs::write(&p, with(r#","alphaMode":"MASK","alphaCutoff":-1"#)).unwrap();
        let e = Scene::load(&p, false).unwrap_err().to_string();
        assert!(
            e.contains("masked.gltf") && e.contains("alphaCutoff -1"),
            "{e}"
        );
    }

    /// A mirroring node reverses the winding back (glTF), so that the triangle still faces
    /// the way its normals do: made from the winding where the file has none (they pointed
    /// inwards before), or the file's own turned by the node; glTF's doubleSided is read
    /// (false by default; OBJ and built-in materials are double-sided).
    #[test]
    fn mirrored_nodes_keep_their_triangles_facing_their_normals() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = textured_gltf_text(d);
        let p = d.join("mirrored.gltf");
        for (node, double) in [
            (r#""nodes":[{"mesh":0}]"#, ""),
            (
                r#""nodes":[{"mesh":0,"scale":[-1,1,1]}]"#,
                r#","doubleSided":true"#,
            ),
        ] {
            let mirrored = text.replace(r#""nodes":[{"mesh":0}]"#, node).replace(
                r#""normalTexture":{"index":0}"#,
                &format!(r#""normalTexture":{{"index":0}}{double}"#),
            );
            std::fs::write(&p, mirrored).unwrap();
            let s = Scene::load(&p, false).unwrap();
            let at = |k: usize| Vec3::from_array(s.vertices[s.indices[k] as usize].position);
            let facing = (at(1) - at(0)).cross(at(2) - at(0));
            for v in &s.vertices {
                assert!(
                    facing.dot(Vec3::from_array(v.normal)) > 0.0 && v.normal[2] > 0.99,
                    "{node}: normal {:?}, triangle facing {facing}",
                    v.normal
                );
            }
            assert_eq!(s.materials[0].double_sided, !double.is_empty(), "{node}");
        }
        assert!(Material::default().double_sided);
    }

    /// glTF's COLOR_0 loads as float VEC3 (alpha 1) or normalised-byte VEC4, into
    /// `Vertex::color`, and multiplies the per-vertex base colour; other sets are named as not
    /// drawn; a COLOR_0 of another type is an error naming it.
    #[test]
    fn vertex_colours_load() {
        let dir = tempfile::tempdir().unwrap();
        let positions: [f32; 9] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let colors: [f32; 9] = [1.0, 0.5, 0.0, 0.0, 1.0, 0.25, 0.5, 0.5, 0.5];
        let mut bytes: Vec<u8> = positions
            .iter()
            .chain(&colors)
            .flat_map(|f| f.to_le_bytes())
            .collect();
        bytes.extend([255u8, 0, 51, 102, 0, 255, 0, 255, 0, 0, 255, 0]);
        let b64 = base64_encode(&bytes);
        let write = |color: &str| {
            let json = format!(
                r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
                "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,{color}}}}}]}}],
                "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                             {{"bufferView":1,"componentType":5126,"count":3,"type":"VEC3"}},
                             {{"bufferView":2,"componentType":5121,"normalized":true,"count":3,"type":"VEC4"}},
                             {{"bufferView":1,"componentType":5126,"count":3,"type":"SCALAR"}}],
                "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":36}},
                               {{"buffer":0,"byteOffset":72,"byteLength":12}}],
                "buffers":[{{"byteLength":84,"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#
            );
            let path = dir.path().join("coloured.gltf");
            std::fs::write(&path, json).unwrap();
            Scene::load(&path, false)
        };
        let s = write(r#""COLOR_0":1"#).unwrap();
        let unorm = |c: [f32; 4]| c.map(|v| (v * 65535.0).round() as u16);
        assert_eq!(s.vertices[0].color, unorm([1.0, 0.5, 0.0, 1.0]));
        assert_eq!(s.vertices[1].color, unorm([0.0, 1.0, 0.25, 1.0]));
        // The default material's base colour (glTF's: white) times the vertex colour.
        let c = s.vertex_base_color(0);
        assert!(
            (c[0] - 1.0).abs() < 1e-4 && (c[1] - 0.5).abs() < 1e-4 && c[2] == 0.0,
            "{c:?}"
        );
        let s = write(r#""COLOR_0":2,"COLOR_1":1"#).unwrap();
        assert_eq!(s.vertices[0].color, [65535, 0, 13107, 26214]);
        let e = write(r#""COLOR_0":3"#).unwrap_err().to_string();
        assert!(e.contains("COLOR_0") && e.contains("Scalar"), "{e}");
    }

    /// A file may require the extensions the renderer draws (the `gltf` crate refused them,
    /// none of its features being enabled); another required extension is an error naming it.
    #[test]
    fn required_extensions_load_when_drawn_and_are_named_otherwise() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = textured_gltf_text(d);
        let p = d.join("required.gltf");
        let requiring = |list: &str| {
            text.replacen(
                "{",
                &format!(r#"{{"extensionsUsed":{list},"extensionsRequired":{list},"#),
                1,
            )
        };
        std::fs::write(
            &p,
            requiring(
                r#"["KHR_texture_transform","KHR_materials_emissive_strength","KHR_materials_ior","KHR_materials_specular","KHR_materials_clearcoat"]"#,
            ),
        )
        .unwrap();
        Scene::load(&p, false).unwrap();
        std::fs::write(&p, requiring(r#"["KHR_draco_mesh_compression"]"#)).unwrap();
        let e = Scene::load(&p, false).unwrap_err().to_string();
        assert!(
            e.contains("required.gltf")
                && e.contains("requires extension KHR_draco_mesh_compression"),
            "{e}"
        );
    }

    /// A material's textures read up to two texture-coordinate sets: the first textured
    /// slot's set fills `Vertex::uv`, the first other set `Vertex::uv1`, and each texture
    /// reads its own; a third set is read with the first; a material whose only set is
    /// TEXCOORD_1 reads it as its first.
    #[test]
    fn textures_read_their_own_coordinate_sets() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = textured_gltf_text(d);
        // TEXCOORD_1 reads the same accessor as TEXCOORD_0.
        let text = text.replace(r#""TEXCOORD_0":1"#, r#""TEXCOORD_0":1,"TEXCOORD_1":1"#);
        let p = d.join("sets.gltf");
        std::fs::write(
            &p,
            text.replace(
                r#""normalTexture":{"index":0}"#,
                r#""normalTexture":{"index":0},"occlusionTexture":{"index":0,"texCoord":1},
                   "emissiveTexture":{"index":0,"texCoord":2},"emissiveFactor":[1,1,1]"#,
            ),
        )
        .unwrap();
        let s = Scene::load(&p, false).unwrap();
        let t = s.materials[0].textures;
        let channel = |t: Option<TextureRef>| t.unwrap().channel;
        assert_eq!(channel(t.base_color), 0);
        assert_eq!(channel(t.normal), 0);
        assert_eq!(channel(t.occlusion), 1);
        assert_eq!(channel(t.emissive), 0, "a third set reads the first");
        let uv1: Vec<_> = s.vertices.iter().map(|v| v.uv1).collect();
        assert_eq!(uv1, [[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]]);
        // Only TEXCOORD_1: it is the first channel, and no second is read.
        let only_second =
            r#""pbrMetallicRoughness":{"baseColorTexture":{"index":0,"texCoord":1}}}],"#;
        let start = text.find(r#""pbrMetallicRoughness""#).unwrap();
        let end = text.find(r#""textures""#).unwrap();
        let text = format!("{}{only_second}\n{}", &text[..start], &text[end..]);
        std::fs::write(&p, &text).unwrap();
        let s = Scene::load(&p, false).unwrap();
        assert_eq!(channel(s.materials[0].textures.base_color), 0);
        let uvs: Vec<_> = s.vertices.iter().map(|v| (v.uv, v.uv1)).collect();
        assert_eq!(
            uvs,
            [
                ([0.0, 0.0], [0.0; 2]),
                ([1.0, 0.0], [0.0; 2]),
                ([0.0, 2.0], [0.0; 2])
            ]
        );
        // A set the primitive lacks is an error naming it.
        std::fs::write(&p, text.replace(r#""texCoord":1"#, r#""texCoord":3"#)).unwrap();
        let e = Scene::load(&p, false).unwrap_err().to_string();
        assert!(e.contains("TEXCOORD_3"), "{e}");
    }

    /// An MTL's map_Kd loads (relative to the OBJ's folder), with the OBJ's vt flipped to
    /// glTF's v (down the image); a missing map_Kd file is an error naming it.
    #[test]
    fn obj_diffuse_maps_load_with_flipped_coordinates() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("tex.png"), two_texel_png()).unwrap();
        std::fs::write(d.join("m.mtl"), "newmtl t\nKd 1 1 1\nmap_Kd tex.png\n").unwrap();
        let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 0.25\nusemtl t\nf 1/1 2/2 3/3\n";
        let p = d.join("t.obj");
        std::fs::write(&p, obj).unwrap();
        let s = Scene::load(&p, false).unwrap();
        assert_eq!(s.textures.len(), 1);
        assert_eq!(s.materials[0].textures.base_color.map(|t| t.image), Some(0));
        let uvs: Vec<_> = s.vertices.iter().map(|v| v.uv).collect();
        assert_eq!(uvs, [[0.0, 1.0], [1.0, 1.0], [0.0, 0.75]]);
        assert!(scene_files(&p).contains(&d.join("tex.png")));
        std::fs::write(d.join("m.mtl"), "newmtl t\nmap_Kd gone.png\n").unwrap();
        let e = Scene::load(&p, false).unwrap_err().to_string();
        assert!(e.contains("map_Kd") && e.contains("gone.png"), "{e}");
    }

    /// An MTL's `Ke` and `map_Ke` make the emission, and its `map_d` a cut-out: the mask (its
    /// R where it has no alpha, its A where it has) joined to the `map_Kd` image's alpha, at
    /// the cutoff 0.5; the scene's files include both maps; a missing map, a negative `Ke` or an
    /// opacity outside [0, 1] is an error naming it; `d` (or `Tr` = 1 − d) below 1 without a
    /// map blends the surface with that opacity; the PBR statements `Pr`, `Pm`, `Pc`, `Pcr`
    /// set the roughness, metallic and clear coat (a value outside [0, 1] is an error).
    #[test]
    fn obj_emission_and_dissolve_maps_load() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("tex.png"), two_texel_png()).unwrap();
        let png = |image: image::DynamicImage| {
            let mut bytes = Vec::new();
            image
                .write_to(
                    &mut std::io::Cursor::new(&mut bytes),
                    image::ImageFormat::Png,
                )
                .unwrap();
            bytes
        };
        // A grey mask, 4 × 1: 0, 0, 255, 255 (nearest to the 2-texel colour image: 0, 255).
        let grey = image::GrayImage::from_raw(4, 1, vec![0, 0, 255, 255]).unwrap();
        std::fs::write(d.join("mask.png"), png(grey.into())).unwrap();
        // A mask with alpha: its A counts, not its R.
        let alpha = image::RgbaImage::from_raw(2, 1, vec![0, 0, 0, 200, 255, 255, 255, 10]);
        std::fs::write(d.join("alpha.png"), png(alpha.unwrap().into())).unwrap();
        let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl t\nf 1/1 2/2 3/3\n";
        let p = d.join("t.obj");
        std::fs::write(&p, obj).unwrap();
        let load = |mtl: &str| {
            std::fs::write(d.join("m.mtl"), mtl).unwrap();
            Scene::load(&p, false)
        };
        let s = load(
            "newmtl t\nKd 1 1 1\nKe 2 1 0.5\nmap_Ke tex.png\nmap_Kd tex.png\nmap_d mask.png\n",
        )
        .unwrap();
        let m = s.materials[0];
        assert_eq!(m.emission, [2.0, 1.0, 0.5]);
        assert_eq!(m.alpha_mode, AlphaMode::Mask(OBJ_ALPHA_CUTOFF));
        let emissive = m.textures.emissive.unwrap();
        assert_eq!(
            s.textures[emissive.image as usize].rgba,
            two_texel_png_rgba()
        );
        let joined = &s.textures[m.textures.base_color.unwrap().image as usize];
        assert_eq!((joined.width, joined.height), (2, 1));
        assert_eq!(joined.rgba, [255, 0, 0, 0, 0, 0, 255, 255]);
        let files = scene_files(&p);
        for name in ["tex.png", "mask.png", "m.mtl"] {
            assert!(files.contains(&d.join(name)), "{name}: {files:?}");
        }
        // No map_Kd: a white image of the mask's size; an alpha mask's A; no Ke: map_Ke's
        // texels at full strength.
        let s = load("newmtl t\nmap_d alpha.png\nmap_Ke tex.png\n").unwrap();
        let m = s.materials[0];
        assert_eq!(m.emission, [1.0; 3]);
        let joined = &s.textures[m.textures.base_color.unwrap().image as usize];
        assert_eq!(joined.rgba, [255, 255, 255, 200, 255, 255, 255, 10]);
        // No maps: no cut-out, no glow; a translucent d (or Tr) is blended with its opacity.
        let m = load("newmtl t\n").unwrap().materials[0];
        assert_eq!(
            (m.alpha, m.alpha_mode, m.emission),
            (1.0, AlphaMode::Opaque, [0.0; 3])
        );
        for (mtl, opacity) in [("d 0.25", 0.25), ("Tr 0.25", 0.75), ("d 0.5\nTr 0.9", 0.5)] {
            let m = load(&format!("newmtl t\n{mtl}\n")).unwrap().materials[0];
            assert_eq!(
                (m.alpha, m.alpha_mode),
                (opacity, AlphaMode::Blend),
                "{mtl}"
            );
        }
        let m = load("newmtl t\nd 1\n").unwrap().materials[0];
        assert_eq!((m.alpha, m.alpha_mode), (1.0, AlphaMode::Opaque));
        // The PBR statements override Ns's roughness and give the metallic and a clear coat.
        let m = load("newmtl t\nNs 900\nPr 0.25\nPm 1\nPc 0.5\nPcr 0.125\n")
            .unwrap()
            .materials[0];
        let pbr = (m.roughness, m.metallic, m.clearcoat, m.clearcoat_roughness);
        assert_eq!(pbr, (0.25, 1.0, 0.5, 0.125));
        for (mtl, needle) in [
            ("newmtl t\nmap_d gone.png\n", "map_d"),
            ("newmtl t\nmap_Ke gone.png\n", "map_Ke"),
            ("newmtl t\nKe -1 0 0\n", "Ke [-1.0, 0.0, 0.0]"),
            ("newmtl t\nd 1.5\n", "d gives an opacity of 1.5"),
            ("newmtl t\nTr glass\n", "Tr \"glass\" is not a number"),
            ("newmtl t\nPr 2\n", "Pr \"2\" is not a number in [0, 1]"),
            (
                "newmtl t\nPm shiny\n",
                "Pm \"shiny\" is not a number in [0, 1]",
            ),
        ] {
            let e = load(mtl).unwrap_err().to_string();
            assert!(
                e.contains(needle) && e.contains("material \"t\""),
                "{mtl}: {e}"
            );
        }
    }

    /// [`two_texel_png`]'s pixels: red, then blue.
    fn two_texel_png_rgba() -> Vec<u8> {
        vec![255, 0, 0, 255, 0, 0, 255, 255]
    }

    /// A one-triangle glTF (optionally with NORMALs and indices in the buffer), with the
    /// given nodes, accessor counts and material; written to `dir/name`.
    fn write_gltf(dir: &Path, name: &str, nodes: &str, counts: [u32; 3], color: &str) -> PathBuf {
        let positions: [f32; 9] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let normals: [f32; 9] = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0];
        let mut bytes: Vec<u8> = positions
            .iter()
            .chain(&normals)
            .flat_map(|f| f.to_le_bytes())
            .collect();
        bytes.extend([0u16, 1, 2].iter().flat_map(|i| i.to_le_bytes()));
        let b64 = base64_encode(&bytes);
        let [p, n, i] = counts;
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
            "nodes":{nodes},
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1}},"indices":2,"material":0}}]}}],
            "materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":{color}}}}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":{p},"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                         {{"bufferView":1,"componentType":5126,"count":{n},"type":"VEC3"}},
                         {{"bufferView":2,"componentType":5123,"count":{i},"type":"SCALAR"}}],
            "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":36}},
                           {{"buffer":0,"byteOffset":72,"byteLength":6}}],
            "buffers":[{{"byteLength":78,"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#
        );
        let path = dir.join(name);
        std::fs::write(&path, json).unwrap();
        path
    }

    /// Node transforms as glTF allows them: a rotation that is not of unit length is
    /// normalised (it scaled and sheared the mesh: (0, 1, 0) came out at (0, -1, 2)); a zero
    /// rotation, a projective matrix and a matrix given with translation/rotation/scale are
    /// errors naming the node (the zero rotation was read as the identity, the matrix's last
    /// row and the translation were dropped); so is a transform that overflows f32 with its
    /// parents' or applied to a vertex.
    #[test]
    fn node_transforms_are_read_as_gltf_defines_them() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let colour = "[0.5,0.5,0.5,1]";
        // 90° about x, written with length √2: (0, 1, 0) turns to (0, 0, 1).
        let p = write_gltf(
            d,
            "q.gltf",
            r#"[{"mesh":0,"rotation":[1,0,0,1]}]"#,
            [3, 3, 3],
            colour,
        );
        let s = Scene::load(&p, false).unwrap();
        let top = Vec3::from_array(s.vertices[2].position);
        assert!(top.distance(Vec3::Z) < 1e-6, "{top}");
        let refused = [
            (r#"[{"mesh":0,"rotation":[0,0,0,0]}]"#, "node 0: rotation"),
            (
                r#"[{"mesh":0,"matrix":[1,0,0,1, 0,1,0,0, 0,0,1,0, 0,0,0,1]}]"#,
                "node 0: matrix's last row is [1, 0, 0, 1]",
            ),
            (
                r#"[{"mesh":0,"matrix":[2,0,0,0, 0,2,0,0, 0,0,2,0, 0,0,0,1],"translation":[5,0,0]}]"#,
                "node 0: has both a matrix and translation",
            ),
            // Finite on their own, not together (it was "non-finite vertex position or
            // normal", after a warning about zero normals).
            (
                r#"[{"mesh":0,"name":"root","children":[1],"scale":[1e30,1e30,1e30]},
                    {"name":"leaf","mesh":0,"scale":[1e30,1e30,1e30]}]"#,
                "node 1 (\"leaf\"): its transform combined with its parents' overflows f32",
            ),
            (
                r#"[{"mesh":0,"scale":[3e38,3e38,3e38],"translation":[3e38,0,0]}]"#,
                "node 0 (\"\"), mesh 0 (\"\") primitive 0: a vertex position or normal is not finite",
            ),
        ];
        for (i, (nodes, needle)) in refused.into_iter().enumerate() {
            let p = write_gltf(d, &format!("n{i}.gltf"), nodes, [3, 3, 3], colour);
            assert_load_fails_naming(&p, needle);
        }
        // Helper nodes without a mesh may overflow: nothing of theirs is drawn (an audit
        // found such a scene refused).
        let p = write_gltf(
            d,
            "helpers.gltf",
            r#"[{"children":[1,3]},{"children":[2],"scale":[1e30,1e30,1e30]},
                {"scale":[1e30,1e30,1e30]},{"mesh":0}]"#,
            [3, 3, 3],
            colour,
        );
        if let Err(e) = Scene::load(&p, false) {
            panic!("{e}");
        }
    }

    /// The OBJ pre-scan names the line of a malformed vertex, normal, texture coordinate or
    /// face corner, of text that is not UTF-8 and of vertex colours on some vertices only
    /// (tobj said "position parse error", "read error" or "face vertex color index out of
    /// bounds"), and counts the elements that are not drawn: `l`/`p` also when indented or
    /// followed by a tab, faces of fewer than 3 corners (dropped without a word before).
    #[test]
    fn obj_scan_names_the_line_and_counts_what_is_not_drawn() {
        let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        let scan = scan_obj(format!("{tri}f 1 2 3\nf 1 2\nf 3\nl\t1 2\n  p 3\np 1\n").as_bytes());
        assert_eq!(
            scan,
            Ok(ObjScan {
                lines_and_points: 3,
                short_faces: 2
            })
        );
        let bad = [
            (
                "v a b c\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
                "line 1: expected 3 finite numbers (v x y z)",
            ),
            ("v 1\n", "line 1: expected 3 finite numbers"),
            // Parsed as infinity and NaN ("non-finite vertex position or normal", no line).
            ("v 0 1e39 0\n", "line 1: expected 3 finite numbers"),
            (
                "v 0 0 0\nvn nan 0 1\n",
                "line 2: expected 3 finite numbers (vn x y z)",
            ),
            ("v 0 0 0 1 0\n", "line 1: a vertex is v x y z"),
            ("v 0 0 0 0\n", "line 1: the homogeneous w \"0\""),
            (
                "v 0 0 0\nvn 0 1\n",
                "line 2: expected 3 finite numbers (vn x y z)",
            ),
            (
                "v 0 0 0\nvt x 0\n",
                "line 2: expected 2 finite numbers (vt u v)",
            ),
            (
                "v 0 0 0 1 0 0\nv 1 0 0\n",
                "line 1 gives a vertex colour and line 2 does not",
            ),
            (
                "v 0 0 0\nf 1 1/x 1\n",
                "line 2: face corner \"1/x\": \"x\" is not an integer",
            ),
            ("v 0 0 0\nf 1 /1 1\n", "line 2: face corner \"/1\" is not v"),
            (
                "v 0 0 0\nf 1 1 4\n",
                "line 2: face index 4 out of range of the file's 1 positions",
            ),
            // Negative indices count back from the line (tobj's bare "face vertex index out
            // of bounds" before); `l` lines are parsed too ("face parse error").
            (
                "v 0 0 0\nf -1 -2 -3\nv 1 0 0\nv 0 1 0\n",
                "line 2: face index -2 counts back past the 1 positions defined above it",
            ),
            ("v 0 0 0\nv 1 0 0\nl 1 abc\n", "line 3: face corner \"abc\""),
            ("\u{feff}v 0 0 0\n", "byte-order mark"),
            // tobj's "invalid polygon", without a line, before.
            ("v 0 0 0\nf\n", "line 2: a face without vertices"),
        ];
        for (text, needle) in bad {
            let e = scan_obj(text.as_bytes()).unwrap_err();
            assert!(e.contains(needle), "{text:?}: {e}");
        }
        let e = scan_obj(b"v 0 0 0\n\xff\xfe\n").unwrap_err();
        assert!(e.contains("line 2 is not UTF-8"), "{e}");
        // Vertex colours on every vertex are accepted.
        assert!(scan_obj(b"v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nf 1 2 3\n").is_ok());
    }

    /// A comment after the data of a geometry line is cut off (it was refused: "face corner
    /// \"#\" is not an integer index"); names, which may hold a `#`, are kept; the lines keep
    /// their numbers.
    #[test]
    fn trailing_comments_on_geometry_lines_are_cut() {
        let text =
            "o part#2\nv 0 0 0 # origin\nv 1 0 0\nv 0 1 0#up\n  f 1 2 3 # front\nusemtl a#b\n";
        let cut = strip_trailing_comments(text.as_bytes());
        assert_eq!(
            std::str::from_utf8(&cut).unwrap(),
            "o part#2\nv 0 0 0 \nv 1 0 0\nv 0 1 0\n  f 1 2 3 \nusemtl a#b\n"
        );
        assert_eq!(scan_obj(&cut), Ok(ObjScan::default()));
        // Nothing to cut: the text itself.
        let plain = b"v 0 0 0\n# a whole-line comment\nf 1 1 1\n";
        assert!(matches!(
            strip_trailing_comments(plain),
            std::borrow::Cow::Borrowed(_)
        ));
        // Errors still name the line of the file.
        let e = scan_obj(&strip_trailing_comments(b"# c\nv 0 0 0 # c\nf 1 1 9 # c\n")).unwrap_err();
        assert!(e.starts_with("line 3: face index 9"), "{e}");
        // And tobj reads what is left.
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("commented.obj");
        std::fs::write(&file, text).unwrap();
        if let Err(e) = Scene::load(&file, false) {
            panic!("{e}");
        }
    }

    /// A scene path without a scene extension that is not a file says so (a directory was
    /// reported as of "unknown format"); a file of another extension is of unknown format.
    #[test]
    fn a_scene_path_that_is_no_file_is_named_as_such() {
        let dir = tempfile::tempdir().unwrap();
        let e = Scene::load(dir.path(), false).err().unwrap().to_string();
        assert!(e.contains("not a regular file"), "{e}");
        let missing = dir.path().join("nothing");
        let e = Scene::load(&missing, false).err().unwrap().to_string();
        assert!(e.contains("No such file"), "{e}");
        let text = dir.path().join("notes.txt");
        std::fs::write(&text, "x").unwrap();
        let e = Scene::load(&text, false).err().unwrap().to_string();
        assert!(e.contains("unknown format"), "{e}");
    }

    /// A buffer file that is not there is named (the gltf crate's error named none).
    #[test]
    fn a_missing_buffer_file_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.gltf");
        std::fs::write(
            &p,
            r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":36,"uri":"nothere.bin"}]}"#,
        )
        .unwrap();
        let e = Scene::load(&p, false).err().unwrap().to_string();
        assert!(
            e.contains("t.gltf") && e.contains("buffer 0") && e.contains("nothere.bin"),
            "{e}"
        );
    }

    /// Nodes that instance one mesh add it again each time: the flattened scene is held to the
    /// element limit (here 8) as a whole, not only per accessor (4,000 instances of a
    /// 100,000-vertex mesh in a 1.4 MB file needed 13 GB and aborted).
    #[test]
    fn instancing_past_the_element_limit_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let ok = "[0.5,0.5,0.5,1]";
        let nodes = |k: usize| {
            let children: Vec<String> = (1..=k).map(|i| i.to_string()).collect();
            let mut nodes = vec![format!(r#"{{"children":[{}]}}"#, children.join(","))];
            nodes.extend((0..k).map(|_| r#"{"mesh":0}"#.to_owned()));
            format!("[{}]", nodes.join(","))
        };
        let two = write_gltf(dir.path(), "two.gltf", &nodes(2), [3, 3, 3], ok);
        let b = load_gltf_within(&two, 8).unwrap();
        assert_eq!((b.vertices.len(), b.indices.len()), (6, 6));
        let three = write_gltf(dir.path(), "three.gltf", &nodes(3), [3, 3, 3], ok);
        let e = load_gltf_within(&three, 8).err().unwrap().to_string();
        assert!(e.contains("three.gltf") && e.contains("more than 8"), "{e}");
    }

    /// Hostile scene files are errors naming the file and the problem — nothing of what the
    /// file holds is dropped, replaced or clamped silently — and a valid but unusual one (a
    /// node scaled by 0) loads.
    #[test]
    fn hostile_scene_files_are_errors_naming_the_problem() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let one = r#"[{"mesh":0}]"#;
        let ok = "[0.5,0.5,0.5,1]";
        assert!(Scene::load(&write_gltf(d, "ok.gltf", one, [3, 3, 3], ok), false).is_ok());
        for (path, needle) in [
            (
                write_gltf(
                    d,
                    "cycle.gltf",
                    r#"[{"mesh":0,"children":[0]}]"#,
                    [3, 3, 3],
                    ok,
                ),
                "reached twice",
            ),
            (
                write_gltf(
                    d,
                    "shared.gltf",
                    r#"[{"children":[1,2]},{"children":[3]},{"children":[3]},{"mesh":0}]"#,
                    [3, 3, 3],
                    ok,
                ),
                "reached twice",
            ),
            (
                write_gltf(d, "pos.gltf", one, [1000, 3, 3], ok),
                "POSITION accessor",
            ),
            (
                write_gltf(d, "nor.gltf", one, [3, 500, 3], ok),
                "NORMAL accessor",
            ),
            (
                write_gltf(d, "idx.gltf", one, [3, 3, 3_000_000], ok),
                "indices accessor",
            ),
            (
                write_gltf(d, "neg.gltf", one, [3, 3, 3], "[-1,0,0,1]"),
                "baseColorFactor",
            ),
            (
                write_gltf(d, "big.gltf", one, [3, 3, 3], "[1e38,0,0,1]"),
                "baseColorFactor",
            ),
            (
                write_gltf(
                    d,
                    "far.gltf",
                    r#"[{"mesh":0,"scale":[1e30,1e30,1]}]"#,
                    [3, 3, 3],
                    ok,
                ),
                "radius",
            ),
        ] {
            assert_load_fails_naming(&path, needle);
        }
        // A node scaled by 0 in y flattens the triangle; its normals stay defined.
        let flat = write_gltf(
            d,
            "flat.gltf",
            r#"[{"mesh":0,"scale":[1,0,1]}]"#,
            [3, 3, 3],
            ok,
        );
        let s = Scene::load(&flat, false).unwrap();
        assert!(s
            .vertices
            .iter()
            .all(|v| v.normal.iter().all(|c| c.is_finite())));

        // OBJ: a bad Kd names the material; lines and points are not drawn as triangles.
        std::fs::write(d.join("bad.mtl"), "newmtl red\nKd nan 5 -1\n").unwrap();
        let obj = d.join("kd.obj");
        std::fs::write(
            &obj,
            "mtllib bad.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n",
        )
        .unwrap();
        let e = Scene::load(&obj, false).unwrap_err().to_string();
        assert!(e.contains("kd.obj") && e.contains("Kd"), "{e}");
        let lines = d.join("lines.obj");
        std::fs::write(&lines, "v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\np 3\nf 1 2\n").unwrap();
        let e = Scene::load(&lines, false).unwrap_err().to_string();
        assert!(e.contains("no triangles"), "{e}");
        let mixed = d.join("mixed.obj");
        std::fs::write(&mixed, "v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\nf 1 2 3\n").unwrap();
        assert_eq!(Scene::load(&mixed, false).unwrap().caster_indices, 3);
        // Large but finite coordinates: the computed normals do not overflow.
        let large = d.join("large.obj");
        std::fs::write(&large, "v 0 0 0\nv 1e14 0 0\nv 0 1e14 0\nf 1 2 3\n").unwrap();
        let s = Scene::load(&large, false).unwrap();
        assert!(s.vertices[0].normal[2] > 0.99, "{:?}", s.vertices[0].normal);
    }

    /// What the `gltf` and `tobj` crates would panic on, abort on or read without end is an
    /// error naming the file and the problem: a relative buffer URI that percent-decodes to
    /// bytes that are not UTF-8 (a panic in release builds), buffers that are a device or a
    /// sparse terabyte, a GLB header declaring a length under its own size, an accessor of
    /// count 0 and offsets near 2⁶⁴ (overflows), OBJ face indices of 0 or near 2⁶³, and an OBJ
    /// or material library that is a device.
    #[test]
    fn files_the_scene_crates_trust_are_checked_first() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let uri = r#""uri":"data:application/octet-stream;base64,"#;
        std::fs::File::create(d.join("tera.bin"))
            .unwrap()
            .set_len(1 << 40)
            .unwrap();
        for (path, needle) in [
            (
                edited_gltf(d, "percent.gltf", uri, r#""uri":"%ff","name":""#),
                "does not percent-decode to UTF-8",
            ),
            (
                edited_gltf(d, "device.gltf", uri, r#""uri":"file:/dev/zero","name":""#),
                "not a regular file",
            ),
            (
                edited_gltf(d, "tera.gltf", uri, r#""uri":"tera.bin","name":""#),
                "1099511627776 bytes",
            ),
            (
                edited_gltf(
                    d,
                    "count0.gltf",
                    r#""count":3,"type":"VEC3","min""#,
                    r#""count":0,"type":"VEC3","min""#,
                ),
                "POSITION accessor 0 has a count of 0",
            ),
            (
                edited_gltf(
                    d,
                    "offset.gltf",
                    r#"{"bufferView":0,"componentType":5126"#,
                    r#"{"bufferView":0,"byteOffset":18446744073709551000,"componentType":5126"#,
                ),
                "reach past the end of buffer view 0",
            ),
            (
                edited_gltf(
                    d,
                    "view.gltf",
                    r#"{"buffer":0,"byteLength":36}"#,
                    r#"{"buffer":0,"byteOffset":18446744073709551000,"byteLength":36}"#,
                ),
                "lies outside buffer 0",
            ),
        ] {
            assert_load_fails_naming(&path, needle);
        }
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(0u32.to_le_bytes());
        std::fs::write(d.join("short.glb"), &glb).unwrap();
        assert_load_fails_naming(&d.join("short.glb"), "length of 0 bytes");

        let triangle = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\n";
        for (name, faces, needle) in [
            (
                "normal.obj",
                "f 1//6148914691236517207 2//1 3//1\n",
                "line 5: face index 6148914691236517207 out of range of the file's 1 normals",
            ),
            ("zero.obj", "f 1/0 2 3\n", "line 5: face index 0"),
            (
                "back.obj",
                "f -4 -2 -1\n",
                "face index -4 out of range of the file's 3 positions",
            ),
        ] {
            let obj = d.join(name);
            std::fs::write(&obj, format!("{triangle}{faces}")).unwrap();
            assert_load_fails_naming(&obj, needle);
        }
        let relative = d.join("relative.obj");
        std::fs::write(&relative, format!("{triangle}f -3//-1 -2//1 -1//1\n")).unwrap();
        assert_eq!(Scene::load(&relative, false).unwrap().caster_indices, 3);

        // A material library that is a device: the scene loads grey, with a warning.
        let mtl = d.join("device.obj");
        std::fs::write(&mtl, format!("mtllib /dev/zero\n{triangle}f 1 2 3\n")).unwrap();
        assert_eq!(Scene::load(&mtl, false).unwrap().caster_indices, 3);
        let e = read_mtl(Path::new("/dev/zero")).unwrap_err().1;
        assert!(e.contains("not a regular file"), "{e}");
        // A scene that is a device.
        let link = d.join("link.obj");
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        assert_load_fails_naming(&link, "not a regular file");
    }

    /// Whether `path` loads; a panic of the scene readers, which `Scene::load` turns into an
    /// error, fails the test (without this check the mutation tests could not fail).
    fn loads_without_panic(path: &Path) -> bool {
        match Scene::load(path, false) {
            Ok(_) => true,
            Err(e) => {
                let e = e.to_string();
                assert!(!e.contains("the reader panicked"), "{e}");
                false
            }
        }
    }

    /// The spans of the numbers in a JSON text (not those inside names such as `TEXCOORD_0`
    /// or in base64 data).
    fn number_spans(text: &str) -> Vec<(usize, usize)> {
        let bytes = text.as_bytes();
        let mut spans = Vec::new();
        let mut i = 0;
        while i < bytes.len() {
            let starts = bytes[i].is_ascii_digit()
                && !bytes[i - 1].is_ascii_alphanumeric()
                && bytes[i - 1] != b'+'
                && bytes[i - 1] != b'/';
            if starts {
                let end = (i..bytes.len())
                    .find(|&j| !(bytes[j].is_ascii_digit() || b".eE-".contains(&bytes[j])))
                    .unwrap_or(bytes.len());
                spans.push((i, end));
                i = end;
            } else {
                i += 1;
            }
        }
        spans
    }

    /// Values that overflow, wrap or misplace what a glTF number counts or indexes.
    const HOSTILE_NUMBERS: [&str; 12] = [
        "0",
        "-1",
        "1",
        "255",
        "65535",
        "4294967295",
        "4294967296",
        "18446744073709551615",
        "9007199254740993",
        "1e308",
        "-1e308",
        "0.5",
    ];

    /// Every number of a valid glTF replaced by hostile values (0, -1, 2³² − 1, 2⁶⁴ − 1, 1e308,
    /// …), and a GLB of the same scene with every byte inverted and cut at every length: each
    /// load returns, an error or a scene, and no reader panics, caught or not
    /// ([`loads_without_panic`]). (Overflow panics need overflow checks, which release tests
    /// lack; the checks before the crates make those cases errors in any build, as
    /// `files_the_scene_crates_trust_are_checked_first` shows.)
    #[test]
    fn mutated_gltf_and_glb_files_never_panic() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let text = std::fs::read_to_string(write_gltf(
            d,
            "base.gltf",
            r#"[{"mesh":0}]"#,
            [3, 3, 3],
            "[0.5,0.5,0.5,1]",
        ))
        .unwrap();
        let numbers = number_spans(&text);
        assert!(numbers.len() > 30, "{}", numbers.len());
        let path = d.join("mutated.gltf");
        let mut loaded = 0;
        for &(start, end) in &numbers {
            for value in HOSTILE_NUMBERS {
                let mutated = format!("{}{value}{}", &text[..start], &text[end..]);
                std::fs::write(&path, mutated).unwrap();
                loaded += usize::from(loads_without_panic(&path));
            }
        }
        assert!(loaded > 0);

        // A textured scene (sampler, texture and image indices, TEXCOORD_0), its image a file.
        std::fs::write(d.join("tex.png"), two_texel_png()).unwrap();
        let text = std::fs::read_to_string(textured_gltf(d, "textured.gltf", "tex.png")).unwrap();
        Scene::load(&d.join("textured.gltf"), false).expect("the unmutated textured scene loads");
        for (start, end) in number_spans(&text) {
            for value in HOSTILE_NUMBERS {
                let mutated = format!("{}{value}{}", &text[..start], &text[end..]);
                std::fs::write(&path, mutated).unwrap();
                loads_without_panic(&path);
            }
        }
        // Its material with every drawn extension's numbers, blended.
        let extended = text.replace(
            r#""normalTexture":{"index":0}"#,
            r#""normalTexture":{"index":0},"alphaMode":"BLEND","emissiveFactor":[1,1,1],
               "extensions":{"KHR_materials_ior":{"ior":1.5},
                 "KHR_materials_emissive_strength":{"emissiveStrength":2},
                 "KHR_materials_specular":{"specularFactor":0.5,"specularColorFactor":[1,0.5,0.25],
                   "specularTexture":{"index":0,"texCoord":0},"specularColorTexture":{"index":0}},
                 "KHR_materials_clearcoat":{"clearcoatFactor":0.5,"clearcoatRoughnessFactor":0.25,
                   "clearcoatTexture":{"index":0},"clearcoatRoughnessTexture":{"index":0},
                   "clearcoatNormalTexture":{"index":0,"scale":1,
                     "extensions":{"KHR_texture_transform":{"offset":[0,0],"scale":[1,1],"rotation":0}}}}}"#,
        );
        std::fs::write(&path, &extended).unwrap();
        let m = Scene::load(&path, false).expect("the unmutated extended scene loads");
        assert_eq!(m.materials[0].clearcoat, 0.5);
        assert!(m.materials[0].textures.clearcoat_normal.is_some());
        for (start, end) in number_spans(&extended) {
            for value in HOSTILE_NUMBERS {
                let mutated = format!("{}{value}{}", &extended[..start], &extended[end..]);
                std::fs::write(&path, mutated).unwrap();
                loads_without_panic(&path);
            }
        }

        // The same scene as a GLB: the buffer as its BIN chunk.
        let document: serde_json::Value = serde_json::from_str(&text).unwrap();
        let uri = document["buffers"][0]["uri"].as_str().unwrap();
        let b64 = uri.rsplit(',').next().unwrap();
        let bin = base64_decode(b64);
        let mut json = document.clone();
        json["buffers"][0].as_object_mut().unwrap().remove("uri");
        let glb = gltf::binary::Glb {
            header: gltf::binary::Header {
                magic: *b"glTF",
                version: 2,
                length: 0,
            },
            json: serde_json::to_vec(&json).unwrap().into(),
            bin: Some(bin.into()),
        }
        .to_vec()
        .unwrap();
        let path = d.join("mutated.glb");
        std::fs::write(&path, &glb).unwrap();
        Scene::load(&path, false).expect("the unmutated GLB loads");
        for i in 0..glb.len() {
            let mut bytes = glb.clone();
            bytes[i] ^= 0xff;
            std::fs::write(&path, &bytes).unwrap();
            loads_without_panic(&path);
            std::fs::write(&path, &glb[..i]).unwrap();
            assert!(Scene::load(&path, false).is_err(), "cut at {i}");
        }
    }

    /// Every number of a small OBJ (positions, texture coordinates, normals, face indices) and
    /// of its material library replaced by hostile values: each load returns and no reader
    /// panics ([`loads_without_panic`]).
    #[test]
    fn mutated_obj_files_never_panic() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nusemtl red\n\
                   f 1/1/1 2/1/1 3/1/1\nf -3 -2 -1\n";
        let mtl = "newmtl red\nKd 1 0.5 0\nNs 10\nd 1\nTr 0\nPr 0.5\nPm 0\nPc 0.25\nPcr 0.5\n";
        let hostile = [
            "0",
            "-1",
            "2",
            "-4",
            "9223372036854775807",
            "-9223372036854775808",
            "18446744073709551616",
            "6148914691236517207",
            "1e308",
            "nan",
            "inf",
            "x",
        ];
        let words = |text: &str| -> Vec<(usize, usize)> {
            let mut spans = Vec::new();
            let mut start = None;
            for (i, c) in text.char_indices().chain([(text.len(), ' ')]) {
                let part = c.is_ascii_digit() || c == '.' || c == '-';
                match (part, start) {
                    (true, None) => start = Some(i),
                    (false, Some(s)) => {
                        spans.push((s, i));
                        start = None;
                    }
                    _ => {}
                }
            }
            spans
        };
        let path = d.join("mutated.obj");
        let mut loaded = 0;
        for (file, other) in [(obj, mtl), (mtl, obj)] {
            for (start, end) in words(file) {
                for value in hostile {
                    let mutated = format!("{}{value}{}", &file[..start], &file[end..]);
                    let (o, m) = if file == obj {
                        (mutated.as_str(), other)
                    } else {
                        (other, mutated.as_str())
                    };
                    std::fs::write(&path, o).unwrap();
                    std::fs::write(d.join("m.mtl"), m).unwrap();
                    loaded += usize::from(loads_without_panic(&path));
                }
            }
        }
        assert!(loaded > 0);
    }

    fn base64_decode(text: &str) -> Vec<u8> {
        const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let digits: Vec<u32> = (text.bytes())
            .filter(|&c| c != b'=')
            .map(|c| A.iter().position(|&a| a == c).unwrap() as u32)
            .collect();
        let mut out = Vec::new();
        for chunk in digits.chunks(4) {
            let n = chunk
                .iter()
                .enumerate()
                .fold(0, |n, (k, d)| n | d << (18 - 6 * k));
            out.extend(&n.to_be_bytes()[1..chunk.len()]);
        }
        out
    }

    /// Loading `path` fails with an error naming the file and containing `needle`.
    fn assert_load_fails_naming(path: &Path, needle: &str) {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let e = Scene::load(path, false).err().map(|e| e.to_string());
        let e = e.unwrap_or_else(|| panic!("{name} loaded"));
        assert!(e.contains(&name) && e.contains(needle), "{e}");
    }

    /// The one-triangle glTF of [`write_gltf`] with `from` replaced by `to` in its text.
    fn edited_gltf(dir: &Path, name: &str, from: &str, to: &str) -> PathBuf {
        let path = write_gltf(dir, name, r#"[{"mesh":0}]"#, [3, 3, 3], "[0.5,0.5,0.5,1]");
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains(from), "{from}");
        std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
        path
    }

    /// The POSITION accessor of [`write_gltf`]'s file.
    const POSITIONS: &str = r#"{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}"#;

    /// A sparse POSITION accessor of `count` elements without a buffer view, its three sparse
    /// indices (0, 1, 2) and values taken from [`write_gltf`]'s buffer.
    fn sparse_positions(count: usize) -> String {
        format!(
            r#"{{"componentType":5126,"count":{count},"type":"VEC3","min":[0,0,0],"max":[1,1,0],
            "sparse":{{"count":3,"indices":{{"bufferView":2,"componentType":5123}},"values":{{"bufferView":0}}}}}}"#
        )
    }

    /// What the `gltf` crate's reader takes on trust is checked first: an index accessor of
    /// floats, a stride shorter than an element, a sparse accessor declaring 80 million
    /// vertices in a few bytes, a sparse index past the count (these panicked, aborted on a
    /// 36 GB allocation, or were ignored); material factors outside [0, 1] (clamped silently);
    /// a model 10^7 radii from the origin (f32 lost it: an empty image); an MTL colour of two
    /// numbers (tobj panicked) and a `usemtl` of an undefined material (grey) are warnings
    /// that say so.
    #[test]
    fn accessors_materials_and_placement_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for (path, needle) in [
            (
                edited_gltf(
                    d,
                    "float_idx.gltf",
                    r#""componentType":5123"#,
                    r#""componentType":5126"#,
                ),
                "indices accessor 2 has component type F32",
            ),
            (
                edited_gltf(
                    d,
                    "vec2_pos.gltf",
                    r#""count":3,"type":"VEC3","min""#,
                    r#""count":3,"type":"VEC2","min""#,
                ),
                "POSITION accessor 0 has type Vec2",
            ),
            (
                edited_gltf(
                    d,
                    "stride.gltf",
                    r#"{"buffer":0,"byteLength":36}"#,
                    r#"{"buffer":0,"byteLength":36,"byteStride":4}"#,
                ),
                "byteStride of 4 bytes, less than one element (12 bytes)",
            ),
            (
                edited_gltf(
                    d,
                    "sparse_huge.gltf",
                    POSITIONS,
                    &sparse_positions(80_000_001),
                ),
                "holds 80000001 elements",
            ),
            (
                edited_gltf(d, "sparse_oob.gltf", POSITIONS, &sparse_positions(2)),
                "sparse index 2 out of range of its count 2",
            ),
            (
                edited_gltf(
                    d,
                    "rough.gltf",
                    r#""baseColorFactor""#,
                    r#""roughnessFactor":5,"baseColorFactor""#,
                ),
                "roughnessFactor 5 must lie in [0, 1]",
            ),
            (
                edited_gltf(
                    d,
                    "metal.gltf",
                    r#""baseColorFactor""#,
                    r#""metallicFactor":-2,"baseColorFactor""#,
                ),
                "metallicFactor -2 must lie in [0, 1]",
            ),
            (
                edited_gltf(
                    d,
                    "far.gltf",
                    r#"{"mesh":0}"#,
                    r#"{"mesh":0,"translation":[1e7,0,0]}"#,
                ),
                "from the origin",
            ),
        ] {
            assert_load_fails_naming(&path, needle);
        }
        // Near the origin, or moved by a few radii, the same triangle loads.
        let near = edited_gltf(
            d,
            "near.gltf",
            r#"{"mesh":0}"#,
            r#"{"mesh":0,"translation":[1e3,0,0]}"#,
        );
        assert!(Scene::load(&near, false).is_ok());

        // OBJ: a two-number Kd and an undefined material load (grey), without a panic.
        std::fs::write(d.join("short.mtl"), "newmtl red\nKd 1 0\n").unwrap();
        std::fs::write(d.join("ok.mtl"), "newmtl red\nKd 1 0 0\n").unwrap();
        for (mtl, material) in [
            ("short.mtl", "red"),
            ("ok.mtl", "blue"),
            ("missing.mtl", "red"),
        ] {
            let obj = d.join(format!("{material}_{mtl}.obj"));
            std::fs::write(
                &obj,
                format!("mtllib {mtl}\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl {material}\nf 1 2 3\n"),
            )
            .unwrap();
            let s = Scene::load(&obj, false).unwrap();
            assert_eq!(
                s.materials[0].base_color,
                Material::default().base_color,
                "{mtl}"
            );
        }
        assert_eq!(
            read_mtl(&d.join("short.mtl")).unwrap_err().1,
            "line 2: Kd needs three numbers (r g b)"
        );
    }

    fn base64_encode(data: &[u8]) -> String {
        const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut out = String::new();
        for c in data.chunks(3) {
            let n = (u32::from(c[0]) << 16)
                | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
                | u32::from(*c.get(2).unwrap_or(&0));
            for i in 0..4 {
                if i <= c.len() {
                    out.push(A[(n >> (18 - 6 * i) & 63) as usize] as char);
                } else {
                    out.push('=');
                }
            }
        }
        out
    }
}
