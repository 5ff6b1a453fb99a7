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
//!
//! Files: this one holds the scene, its vertices and the builder the sources fill;
//! `material.rs` the materials and texture images, `camera.rs` the camera, `gltf_loader.rs`
//! and `obj_loader.rs` the two file formats, and `tests/` the tests by source.

use glam::{Mat3, Mat4, Vec3};
use std::path::{Path, PathBuf};
use thiserror::Error;

mod animation;
mod camera;
mod gltf_animation;
mod gltf_compression;
mod gltf_loader;
mod material;
mod obj_loader;

pub use animation::{
    AnimationChoice, Channel, Clip, Interpolation, LocalGeometry, MorphTarget, Piece,
    PlacedGeometry, Property, RestTransform, SceneAnimation, Skin, SkinWeights, WeightsChannel,
};
pub use camera::{
    fit_camera, look_at_rh, orthographic_rh, perspective_rh, Camera, CameraOverride, Projection,
};
pub use material::{
    AlphaMode, Material, MaterialTextures, TextureImage, TextureRef, Wrap, MAX_TEXTURE_SIDE,
    NO_UV_TRANSFORM, SLOT_NAMES, WHITE,
};
pub use obj_loader::{MAX_MTL_BYTES, OBJ_ALPHA_CUTOFF};

use camera::gltf_camera;
use gltf_loader::load_gltf;
use material::decode_texture;
use obj_loader::load_obj;

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
    #[error("scene {path}: its animations take its vertices over a sphere of radius {radius:.3e}, more than the {MAX_SCENE_RADIUS:e} that can be drawn (f32 depth and shadow maps); its clips' translations or scales are too large")]
    AnimationTooLarge { path: PathBuf, radius: f32 },
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
    /// Bounding sphere of the shadow casters (of every pose, in an animated scene).
    pub bounds: Sphere,
    /// The glTF file's animations and the meshes they move, where it has any that move a
    /// drawn mesh ([`Scene::animate`]).
    pub animation: Option<SceneAnimation>,
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
    /// The file's animations (glTF), where they move a mesh.
    animation: Option<SceneAnimation>,
    /// The casters' bounding sphere where worked out before [`Self::finish`] (of every pose,
    /// [`swept_bounds`]).
    bounds: Option<Sphere>,
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
        let bounds = (self.bounds).unwrap_or_else(|| bounding_sphere(&self.vertices));
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
            animation: self.animation,
        }
    }
}

/// The bounding sphere of `vertices` in every pose of `animation`'s clips sampled over their
/// loops ([`SceneAnimation::sweep_times`]) and in the rest pose, and the lowest height they
/// reach: the box of all poses gives the centre, the farthest vertex of any pose the radius.
fn swept_bounds(animation: &SceneAnimation, vertices: &[Vertex]) -> (Sphere, f32) {
    let mut posed = vertices.to_vec();
    let moved: Vec<std::ops::Range<usize>> = animation.moved_vertices().collect();
    // Every position of every pose: the vertices as given (the rest pose, the still ones
    // too), then the moved ones in each sampled pose of each clip.
    let mut each_position = |f: &mut dyn FnMut(Vec3)| {
        vertices
            .iter()
            .for_each(|v| f(Vec3::from_array(v.position)));
        for (c, clip) in animation.clips.iter().enumerate() {
            for t in SceneAnimation::sweep_times(clip) {
                animation.pose(Some(c), t, &mut posed);
                for range in &moved {
                    let placed = posed.get(range.clone()).unwrap_or(&[]);
                    placed.iter().for_each(|v| f(Vec3::from_array(v.position)));
                }
            }
        }
    };
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    each_position(&mut |p| {
        lo = lo.min(p);
        hi = hi.max(p);
    });
    let center = 0.5 * (lo + hi);
    let mut radius = 1e-3f32;
    each_position(&mut |p| radius = radius.max(p.distance(center)));
    (Sphere { center, radius }, lo.y)
}

/// The lowest height (y) of `vertices`.
fn lowest(vertices: &[Vertex]) -> f32 {
    vertices
        .iter()
        .map(|v| v.position[1])
        .fold(f32::INFINITY, f32::min)
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
        let camera = Camera::perspective(
            Vec3::new(0.0, 1.9, 4.6),
            Vec3::new(0.0, 0.35, 0.0),
            40f32.to_radians(),
        );
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
        let mut b = std::panic::catch_unwind(|| load(path)).unwrap_or_else(|panic| {
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
        let (bounds, low) = match &b.animation {
            Some(animation) => swept_bounds(animation, &b.vertices),
            None => (bounding_sphere(&b.vertices), lowest(&b.vertices)),
        };
        let rest_radius = match &b.animation {
            Some(_) => bounding_sphere(&b.vertices).radius,
            None => bounds.radius,
        };
        if rest_radius.is_finite()
            && rest_radius <= MAX_SCENE_RADIUS
            && !(bounds.radius.is_finite() && bounds.radius <= MAX_SCENE_RADIUS)
        {
            return Err(SceneError::AnimationTooLarge {
                path: path.to_path_buf(),
                radius: bounds.radius,
            });
        }
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
        b.bounds = Some(bounds);
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

/// The largest scene file (OBJ, glTF, GLB) or external glTF buffer that is read: 4 GiB, more
/// than [`MAX_SCENE_ELEMENTS`] vertices and indices need.
pub const MAX_SCENE_FILE_BYTES: u64 = 1 << 32;

/// Reads a scene file: a regular file of at most [`MAX_SCENE_FILE_BYTES`].
fn read_scene_file(path: &Path) -> Result<Vec<u8>, SceneError> {
    crate::read_file::read_regular_file(path, MAX_SCENE_FILE_BYTES, "a scene file").map_err(
        |source| SceneError::Io {
            path: path.to_path_buf(),
            source,
        },
    )
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
        Some("gltf" | "glb") => files.extend(gltf_loader::referenced_files(&bytes, base)),
        Some("obj") => files.extend(obj_loader::referenced_files(&bytes, base)),
        _ => {}
    }
    files
}

#[cfg(test)]
mod tests;
