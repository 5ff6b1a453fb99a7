//! Scene animation: glTF keyframe animations of node transforms (translation, rotation,
//! scale) and of morph-target weights played over time, the meshes they move placed anew in
//! world space every frame.
//!
//! The scene is flattened into one world-space vertex buffer (the module doc of `scene`), so a
//! moved mesh keeps its vertices in its own space too ([`LocalGeometry`], shared by the
//! instances of one primitive) and is placed again when the pose changes:
//! 1. each channel of the playing clip is sampled at the time (glTF 2.0, Appendix C: STEP holds
//!    a key's value, LINEAR interpolates — rotations by spherical linear interpolation on the
//!    shorter arc — and CUBICSPLINE is a cubic Hermite spline through the keys with the file's
//!    in- and out-tangents scaled by the key interval; rotations renormalised); before the
//!    first key a channel holds its first value, after the last its last;
//! 2. the sampled values replace those parts of their nodes' rest transforms, and the world
//!    matrices follow down the hierarchy, parents first;
//! 3. a mesh with morph targets (glTF 2.0, 3.7.2.2) takes its node's weights — those a
//!    `weights` channel samples (each weight on its own, as a scalar), else the node's or its
//!    mesh's default ones — and each vertex is its base plus the weighted sum of the targets'
//!    displacements of position, normal and tangent;
//! 4. every moved mesh instance's vertices are placed through its node's world matrix (and its
//!    `EXT_mesh_gpu_instancing` transform): positions by the matrix, normals by its cofactor
//!    matrix, tangents by its linear part with the handedness turned by a mirror.
//!
//!    A skinned mesh (glTF skins) is placed by linear blend skinning instead: each vertex
//!    through the sum of its joints' world matrices (four from each `JOINTS_n`/`WEIGHTS_n`
//!    set) times their inverse bind matrices, weighted; its node's own transform does not apply (morphed first, as glTF
//!    orders it).
//! 5. the scene's camera, where its node moves, is placed at the node's new world matrix.
//!
//! A clip loops over `[0, duration]`, its duration the latest key time of its channels. The
//! triangles' winding is fixed when the scene is loaded (turned where the rest pose mirrors a
//! mesh); a clip whose scale changes sign mid-play leaves those triangles facing the other
//! way. A vertex that a pose would take past f32 (a clip's values overflowing in their
//! products) keeps its last place. A morphed primitive without normals of its own keeps the
//! smooth normals of its base shape where its targets give no normal displacements.

use super::*;
use glam::{Quat, Vec4};
use std::sync::Arc;

/// Vertex data in a mesh's own space (before its node's transform), as the file gives it or
/// as the loader completes it (smooth normals, MikkTSpace tangents).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LocalGeometry {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// Empty where the material has no normal texture.
    pub tangents: Vec<[f32; 4]>,
    /// The primitive's morph targets (none for most meshes).
    pub targets: Vec<MorphTarget>,
}

/// One morph target of a primitive: per vertex, the displacement of each attribute it moves
/// (a list is empty where the target does not move that attribute).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MorphTarget {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// Of the tangent's direction (its handedness does not morph).
    pub tangents: Vec<Vec3>,
}

/// The morph targets that weigh in: `(target, weight)` for each non-zero weight of `weights`
/// (by target; weights past the targets are left out).
fn active_targets(weights: &[f32], targets: usize) -> Vec<(usize, f32)> {
    (weights.iter().copied().enumerate())
        .take(targets)
        .filter(|&(_, w)| w != 0.0)
        .collect()
}

/// Vertices placed in world space ([`LocalGeometry::place`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlacedGeometry {
    pub positions: Vec<Vec3>,
    /// Not normalised (the builder and [`LocalGeometry::place_into`] normalise them).
    pub normals: Vec<Vec3>,
    pub tangents: Vec<[f32; 4]>,
}

impl LocalGeometry {
    /// Vertex `i` in its mesh's space, morphed by `active` ([`active_targets`]): its position,
    /// its normal (not normalised) and its tangent, each where the geometry has one.
    fn morphed(&self, i: usize, active: &[(usize, f32)]) -> (Vec3, Option<Vec3>, Option<[f32; 4]>) {
        let mut position = self.positions[i];
        let mut normal = self.normals.get(i).copied();
        let mut tangent = self.tangents.get(i).copied();
        for &(k, w) in active {
            let Some(target) = self.targets.get(k) else {
                continue;
            };
            if let Some(&d) = target.positions.get(i) {
                position += w * d;
            }
            if let (Some(n), Some(&d)) = (normal.as_mut(), target.normals.get(i)) {
                *n += w * d;
            }
            if let (Some([x, y, z, _]), Some(&d)) = (tangent.as_mut(), target.tangents.get(i)) {
                (*x, *y, *z) = (*x + w * d.x, *y + w * d.y, *z + w * d.z);
            }
        }
        (position, normal, tangent)
    }

    /// The vertices morphed by `weights` (by target; none: the base shape) and placed through
    /// `world`: positions by the matrix, normals by its cofactor matrix (defined where the
    /// matrix is singular too), tangents by its linear part, their handedness turned where
    /// `world` mirrors.
    pub fn place(&self, world: Mat4, weights: &[f32]) -> PlacedGeometry {
        let normal_matrix = normal_matrix(world);
        let handedness = world.determinant().signum();
        let active = active_targets(weights, self.targets.len());
        let mut placed = PlacedGeometry::default();
        for i in 0..self.positions.len() {
            let (position, normal, tangent) = self.morphed(i, &active);
            placed.positions.push(world.transform_point3(position));
            if let Some(n) = normal {
                placed.normals.push(normal_matrix * n);
            }
            if let Some(t) = tangent {
                placed.tangents.push(place_tangent(world, handedness, t));
            }
        }
        placed
    }

    /// [`Self::place`] written into `vertices` (one per local vertex, the rest left as they
    /// are), normals normalised as the builder does; in parallel over blocks of vertices.
    pub fn place_into(&self, world: Mat4, weights: &[f32], vertices: &mut [Vertex]) {
        use rayon::prelude::*;
        let active = active_targets(weights, self.targets.len());
        let count = self.positions.len().min(vertices.len());
        vertices[..count]
            .par_chunks_mut(BLOCK)
            .enumerate()
            .for_each(|(k, block)| self.place_block(world, &active, k * BLOCK, block));
    }

    /// Places vertices `first..` into `vertices`, morphed by `active`.
    fn place_block(
        &self,
        world: Mat4,
        active: &[(usize, f32)],
        first: usize,
        vertices: &mut [Vertex],
    ) {
        if active.is_empty() {
            // The base shape (most meshes), read straight from the lists (the morphing loop
            // cost 263k vertices 0.8 ms more with no target weighing in).
            let base = |i: usize| {
                let normal = self.normals.get(i).copied();
                (self.positions[i], normal, self.tangents.get(i).copied())
            };
            place_each(world, first, vertices, base);
        } else {
            place_each(world, first, vertices, |i| self.morphed(i, active));
        }
    }
}

/// Places vertices `first..` of a mesh, each as `local` gives it in its mesh's space
/// (position, normal, tangent), through `world` into `vertices`.
#[inline(always)]
fn place_each(
    world: Mat4,
    first: usize,
    vertices: &mut [Vertex],
    local: impl Fn(usize) -> (Vec3, Option<Vec3>, Option<[f32; 4]>),
) {
    let normal_matrix = normal_matrix(world);
    let handedness = world.determinant().signum();
    for (i, v) in (first..).zip(vertices.iter_mut()) {
        let (position, normal, tangent) = local(i);
        let position = world.transform_point3(position);
        if !position.is_finite() {
            // A pose past f32 (a clip's values overflowing): the vertex keeps its place.
            continue;
        }
        v.position = position.to_array();
        if let Some(n) = normal {
            v.normal = (normal_matrix * n).normalize_or(Vec3::Y).to_array();
        }
        if let Some(t) = tangent {
            v.tangent = place_tangent(world, handedness, t);
        }
    }
}

/// Vertices a task places or skins (about 0.2 ms of work).
const BLOCK: usize = 16384;

/// A tangent (xyz, handedness w) through `world`, whose determinant has the sign
/// `handedness`.
fn place_tangent(world: Mat4, handedness: f32, [x, y, z, w]: [f32; 4]) -> [f32; 4] {
    let t = world
        .transform_vector3(Vec3::new(x, y, z))
        .normalize_or_zero();
    let w = if w < 0.0 { -handedness } else { handedness };
    [t.x, t.y, t.z, w]
}

/// How a channel's values run between its keys (glTF's sampler `interpolation`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    Step,
    Linear,
    /// Each key holds an in-tangent, a value and an out-tangent.
    CubicSpline,
}

/// Which part of a node's transform a channel drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Property {
    Translation,
    /// A unit quaternion (x, y, z, w).
    Rotation,
    Scale,
}

/// One animated property of one node.
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    pub node: usize,
    pub property: Property,
    pub interpolation: Interpolation,
    /// Key times in seconds, non-decreasing.
    pub times: Vec<f32>,
    /// One value per key (three with [`Interpolation::CubicSpline`]: in-tangent, value,
    /// out-tangent): xyz for translation and scale (w unused), a quaternion for rotation.
    pub values: Vec<Vec4>,
}

/// Where a time falls among a channel's keys.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Segment {
    /// At or outside the keys, or where two keys share a time: key `k`'s value holds.
    Hold(usize),
    /// Between key `k` and `k + 1`, `u` of the way over an `interval` of seconds.
    Between { k: usize, u: f32, interval: f32 },
}

impl Segment {
    /// Where `t` falls among the key `times` (non-decreasing): before the first key its value
    /// holds, after the last the last's.
    fn of(times: &[f32], t: f32) -> Self {
        let last = times.len().saturating_sub(1);
        // The first key after t: t lies in [times[next − 1], times[next]).
        let next = times.partition_point(|&key| key <= t);
        if next == 0 {
            return Self::Hold(0);
        }
        if next > last {
            return Self::Hold(last);
        }
        let k = next - 1;
        let interval = times[next] - times[k];
        if interval.is_nan() || interval <= 0.0 {
            return Self::Hold(next);
        }
        let u = ((t - times[k]) / interval).clamp(0.0, 1.0);
        Self::Between { k, u, interval }
    }
}

/// The cubic Hermite basis at `u` with the tangents scaled by `interval` (glTF 2.0,
/// Appendix C): the weights of the first value, its out-tangent, the second value and its
/// in-tangent.
fn hermite(u: f32, interval: f32) -> [f32; 4] {
    let (u2, u3) = (u * u, u * u * u);
    [
        2.0 * u3 - 3.0 * u2 + 1.0,
        (u3 - 2.0 * u2 + u) * interval,
        -2.0 * u3 + 3.0 * u2,
        (u3 - u2) * interval,
    ]
}

impl Channel {
    /// The value at `t` seconds (see the module doc).
    pub fn sample(&self, t: f32) -> Vec4 {
        let cubic = self.interpolation == Interpolation::CubicSpline;
        let get = |i: usize| self.values.get(i).copied().unwrap_or(Vec4::ZERO);
        // The value of key k (past the tangents where there are any).
        let value = |k: usize| get(if cubic { 3 * k + 1 } else { k });
        let (k, u, interval) = match Segment::of(&self.times, t) {
            Segment::Hold(k) => return value(k),
            Segment::Between { k, u, interval } => (k, u, interval),
        };
        let rotation = self.property == Property::Rotation;
        match self.interpolation {
            Interpolation::Step => value(k),
            Interpolation::Linear if rotation => {
                let [a, b] = [value(k), value(k + 1)].map(Quat::from_vec4);
                Vec4::from(a.normalize().slerp(b.normalize(), u))
            }
            Interpolation::Linear => value(k).lerp(value(k + 1), u),
            Interpolation::CubicSpline => {
                let [a, out_tangent, b, in_tangent] = hermite(u, interval);
                let v = a * value(k)
                    + out_tangent * get(3 * k + 2)
                    + b * value(k + 1)
                    + in_tangent * get(3 * (k + 1));
                if rotation && v.length_squared() > 0.0 {
                    v.normalize()
                } else {
                    v
                }
            }
        }
    }
}

/// The morph-target weights of one node, animated: each key holds one weight per target
/// (three sets with [`Interpolation::CubicSpline`]: in-tangents, values, out-tangents), each
/// weight interpolated on its own.
#[derive(Clone, Debug, PartialEq)]
pub struct WeightsChannel {
    pub node: usize,
    pub interpolation: Interpolation,
    /// Key times in seconds, non-decreasing.
    pub times: Vec<f32>,
    /// How many weights a key holds: the node's mesh's morph targets.
    pub targets: usize,
    /// Key after key, `targets` weights a set.
    pub values: Vec<f32>,
}

impl WeightsChannel {
    /// The weights at `t` seconds, written into `weights` (one per target; those past them
    /// left as they are).
    pub fn sample_into(&self, t: f32, weights: &mut [f32]) {
        let n = self.targets;
        let cubic = self.interpolation == Interpolation::CubicSpline;
        let get = |set: usize, j: usize| self.values.get(set * n + j).copied().unwrap_or(0.0);
        // Weight j of key k (past the in-tangents where there are any).
        let value = |k: usize, j: usize| get(if cubic { 3 * k + 1 } else { k }, j);
        let segment = Segment::of(&self.times, t);
        for (j, w) in weights.iter_mut().enumerate().take(n) {
            *w = match (segment, self.interpolation) {
                (Segment::Hold(k), _) | (Segment::Between { k, .. }, Interpolation::Step) => {
                    value(k, j)
                }
                (Segment::Between { k, u, .. }, Interpolation::Linear) => {
                    value(k, j) + (value(k + 1, j) - value(k, j)) * u
                }
                (Segment::Between { k, u, interval }, Interpolation::CubicSpline) => {
                    let [a, out_tangent, b, in_tangent] = hermite(u, interval);
                    a * value(k, j)
                        + out_tangent * get(3 * k + 2, j)
                        + b * value(k + 1, j)
                        + in_tangent * get(3 * (k + 1), j)
                }
            };
        }
    }
}

/// One animation of the file: its channels and how long it runs.
#[derive(Clone, Debug, PartialEq)]
pub struct Clip {
    /// The file's name for it, or "" where it has none.
    pub name: String,
    pub channels: Vec<Channel>,
    /// Its morph-target weight channels.
    pub weights: Vec<WeightsChannel>,
    /// The latest key time, in seconds: the clip loops over `[0, duration]`.
    pub duration: f32,
}

/// A node's transform in its parent's space where no channel drives it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RestTransform {
    /// The file's matrix (or its translation, rotation and scale composed), used while no
    /// channel of the playing clip drives the node.
    pub matrix: Mat4,
    pub translation: Vec3,
    pub rotation: Quat,
    pub scale: Vec3,
}

impl RestTransform {
    /// The transform composed from its parts (those a channel drives replaced).
    fn composed(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }
}

/// A mesh instance that a clip may move or morph: its node, its instance transform within
/// the node, where its vertices lie in the scene's vertex list, and its local geometry; a
/// skinned one also its skin (by index into [`SceneAnimation::skins`]) and vertex weights.
#[derive(Clone, Debug, PartialEq)]
pub struct Piece {
    pub node: usize,
    pub instance: Mat4,
    pub first_vertex: usize,
    pub geometry: Arc<LocalGeometry>,
    pub skin: Option<(usize, Arc<SkinWeights>)>,
    /// Its morph-target weights where no clip drives them (its node's, else its mesh's; none
    /// without targets).
    pub morph_weights: Vec<f32>,
}

/// A glTF skin: its joints (node indices) and each joint's inverse bind matrix (the
/// identity where the file gives none).
#[derive(Clone, Debug, PartialEq)]
pub struct Skin {
    pub joints: Vec<usize>,
    pub inverse_bind: Vec<Mat4>,
}

/// Per vertex of a skinned primitive: its joints (indices into its skin's joints) and their
/// weights, which sum to 1 — four from each of the file's `JOINTS_n`/`WEIGHTS_n` sets, the
/// vertex's `influences` of them back to back.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SkinWeights {
    /// Joints and weights a vertex: 4 per set.
    pub influences: usize,
    pub joints: Vec<u16>,
    pub weights: Vec<f32>,
}

impl LocalGeometry {
    /// Skins vertices `first..` of this geometry into `vertices` (linear blend skinning: each
    /// vertex through the weighted sum of its joints' matrices — four or more — normals and
    /// tangents through the sum's linear part, renormalised).
    fn skin_block(
        &self,
        joint_matrices: &[Mat4],
        influences: &SkinWeights,
        active: &[(usize, f32)],
        first: usize,
        vertices: &mut [Vertex],
    ) {
        for (i, v) in (first..).zip(vertices.iter_mut()) {
            let n = influences.influences;
            let span = i * n..(i + 1) * n;
            let (Some(joints), Some(weights)) = (
                influences.joints.get(span.clone()),
                influences.weights.get(span),
            ) else {
                continue;
            };
            let mut m = Mat4::ZERO;
            for (&j, &w) in joints.iter().zip(weights) {
                if w != 0.0 {
                    m += *joint_matrices
                        .get(usize::from(j))
                        .unwrap_or(&Mat4::IDENTITY)
                        * w;
                }
            }
            let (position, normal, tangent) = self.morphed(i, active);
            let position = m.transform_point3(position);
            if !position.is_finite() {
                // A pose past f32: the vertex keeps its place.
                continue;
            }
            v.position = position.to_array();
            if let Some(n) = normal {
                v.normal = m.transform_vector3(n).normalize_or(Vec3::Y).to_array();
            }
            if let Some(t) = tangent {
                v.tangent = place_tangent(m, m.determinant().signum(), t);
            }
        }
    }
}

/// The scene's animations and what they move.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneAnimation {
    /// Every node of the file by index: its parent and rest transform (those not in the drawn
    /// scene too; nothing reads them).
    pub parents: Vec<Option<usize>>,
    pub rest: Vec<RestTransform>,
    /// The node indices, parents before their children.
    pub order: Vec<usize>,
    pub clips: Vec<Clip>,
    /// The mesh instances under an animated node (in some clip).
    pub pieces: Vec<Piece>,
    /// The clip that plays ([`Scene::select_animation`]); `None` holds the rest pose.
    pub playing: Option<usize>,
    /// Per node: whether some clip drives it or one of its ancestors.
    pub moved: Vec<bool>,
    /// Per node: whether some clip drives its morph-target weights.
    pub morphed: Vec<bool>,
    /// The file's skins by index (`None`: not used by a drawn mesh).
    pub skins: Vec<Option<Skin>>,
    /// The clip and time of the pose the scene's vertices hold, once [`Scene::animate`] has
    /// posed them (a repeat of it changes nothing).
    pub last_pose: Option<(Option<usize>, f32)>,
    /// The scene's camera node and projection where a clip moves it (the view follows), unless
    /// the camera was set by hand ([`Scene::hold_camera`]).
    pub camera: Option<(usize, super::Projection)>,
}

impl SceneAnimation {
    /// The world matrix of every node with `clip` (or none: the rest pose) at `t` seconds
    /// (not wrapped: see [`Self::clip_time`]).
    pub fn node_worlds(&self, clip: Option<usize>, t: f32) -> Vec<Mat4> {
        let mut local: Vec<Mat4> = self.rest.iter().map(|r| r.matrix).collect();
        if let Some(clip) = clip.and_then(|c| self.clips.get(c)) {
            let mut driven: Vec<Option<RestTransform>> = vec![None; local.len()];
            for channel in &clip.channels {
                let Some(node) = driven.get_mut(channel.node) else {
                    continue;
                };
                let node = node.get_or_insert(self.rest[channel.node]);
                let v = channel.sample(t);
                match channel.property {
                    Property::Translation => node.translation = v.truncate(),
                    Property::Rotation => {
                        // A cubic spline may pass through (0, 0, 0, 0): the rest rotation holds.
                        let q = Quat::from_vec4(v);
                        if q.is_finite() && q.length_squared() > 0.0 {
                            node.rotation = q.normalize();
                        }
                    }
                    Property::Scale => node.scale = v.truncate(),
                }
            }
            for (m, parts) in local.iter_mut().zip(driven) {
                if let Some(parts) = parts {
                    *m = parts.composed();
                }
            }
        }
        let mut world = vec![Mat4::IDENTITY; local.len()];
        for &n in &self.order {
            let parent = self.parents.get(n).copied().flatten();
            let parent = parent.map_or(Mat4::IDENTITY, |p| world[p]);
            world[n] = parent * local[n];
        }
        world
    }

    /// `seconds` within the playing clip's loop: wrapped into `[0, duration)` (0 for a clip
    /// of one instant, or for no clip).
    pub fn clip_time(&self, seconds: f64) -> f32 {
        let duration = self
            .playing
            .and_then(|c| self.clips.get(c))
            .map_or(0.0, |c| f64::from(c.duration));
        if duration > 0.0 && seconds.is_finite() {
            seconds.rem_euclid(duration) as f32
        } else {
            0.0
        }
    }

    /// The morph-target weights that `clip` gives at `t` seconds: `(node, weights)` for each
    /// node it drives.
    pub fn node_weights(&self, clip: Option<usize>, t: f32) -> Vec<(usize, Vec<f32>)> {
        let Some(clip) = clip.and_then(|c| self.clips.get(c)) else {
            return Vec::new();
        };
        (clip.weights.iter())
            .map(|channel| {
                let mut weights = vec![0.0; channel.targets];
                channel.sample_into(t, &mut weights);
                (channel.node, weights)
            })
            .collect()
    }

    /// Places every piece in `vertices` for `clip` at `t` seconds, morphed by its weights: a
    /// skinned one by its joints (its node's own transform does not apply, as glTF defines),
    /// the others by their node's world matrix and instance transform. Returns every node's
    /// world matrix.
    pub fn pose(&self, clip: Option<usize>, t: f32, vertices: &mut [Vertex]) -> Vec<Mat4> {
        let worlds = self.node_worlds(clip, t);
        let driven_weights = self.node_weights(clip, t);
        let world = |n: usize| worlds.get(n).copied().unwrap_or(Mat4::IDENTITY);
        // Each used skin's joint matrices: the joint's world matrix times its inverse bind.
        let joint_matrices: Vec<Vec<Mat4>> = (self.skins.iter())
            .map(|skin| {
                skin.as_ref().map_or(Vec::new(), |skin| {
                    (skin.joints.iter().zip(&skin.inverse_bind))
                        .map(|(&j, &inverse)| world(j) * inverse)
                        .collect()
                })
            })
            .collect();
        for piece in &self.pieces {
            let Some(vertices) = vertices.get_mut(piece.first_vertex..) else {
                continue;
            };
            let weights = (driven_weights.iter())
                .find(|(node, _)| *node == piece.node)
                .map_or(&piece.morph_weights[..], |(_, w)| &w[..]);
            match &piece.skin {
                Some((skin, influences)) => {
                    use rayon::prelude::*;
                    let matrices = joint_matrices.get(*skin).map_or(&[][..], |m| &m[..]);
                    let active = active_targets(weights, piece.geometry.targets.len());
                    let count = piece.geometry.positions.len().min(vertices.len());
                    vertices[..count]
                        .par_chunks_mut(BLOCK)
                        .enumerate()
                        .for_each(|(k, block)| {
                            let first = k * BLOCK;
                            (piece.geometry).skin_block(matrices, influences, &active, first, block)
                        });
                }
                None => {
                    piece
                        .geometry
                        .place_into(world(piece.node) * piece.instance, weights, vertices)
                }
            }
        }
        worlds
    }

    /// Where the pieces' vertices lie in the scene's vertex list.
    pub fn moved_vertices(&self) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        (self.pieces.iter()).map(|p| p.first_vertex..p.first_vertex + p.geometry.positions.len())
    }

    /// [`Self::moved_vertices`] in order, joined where they touch (one run of the vertex list
    /// for each run of adjacent pieces).
    pub fn moved_runs(&self) -> Vec<std::ops::Range<usize>> {
        merged_ranges(self.moved_vertices())
    }

    /// Times at which to pose each clip to find the space it sweeps: 64 evenly spaced over its
    /// loop and its end.
    pub fn sweep_times(clip: &Clip) -> impl Iterator<Item = f32> + '_ {
        const STEPS: u32 = 64;
        (0..=STEPS).map(move |i| clip.duration * i as f32 / STEPS as f32)
    }
}

/// `ranges` sorted and joined where they touch or overlap (the moved pieces of an animated
/// scene lie back to back where one node's primitives follow each other: one upload each run).
fn merged_ranges(
    ranges: impl Iterator<Item = std::ops::Range<usize>>,
) -> Vec<std::ops::Range<usize>> {
    let mut sorted: Vec<std::ops::Range<usize>> = ranges.filter(|r| !r.is_empty()).collect();
    sorted.sort_by_key(|r| r.start);
    let mut merged: Vec<std::ops::Range<usize>> = Vec::with_capacity(sorted.len());
    for range in sorted {
        match merged.last_mut() {
            Some(last) if range.start <= last.end => last.end = last.end.max(range.end),
            _ => merged.push(range),
        }
    }
    merged
}

/// Which clip plays: the file's first (the default), one by index or name, or none (the rest
/// pose).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum AnimationChoice {
    #[default]
    First,
    None,
    Index(usize),
    Name(String),
}

impl AnimationChoice {
    /// `none`, a clip's index (0, 1, …) or its name.
    pub fn parse(text: &str) -> Self {
        match text {
            "none" => Self::None,
            _ => text
                .parse()
                .map_or_else(|_| Self::Name(text.to_string()), Self::Index),
        }
    }
}

impl Scene {
    /// The names of the scene's clips (by index; "" where unnamed), none without animation.
    pub fn animation_names(&self) -> Vec<&str> {
        self.animation.as_ref().map_or(Vec::new(), |a| {
            a.clips.iter().map(|c| c.name.as_str()).collect()
        })
    }

    /// Chooses the clip that [`Self::animate`] plays; `None` holds the rest pose. A clip the
    /// scene does not have is an error naming those it has; a scene without animations takes
    /// `First` and `None` as they are (nothing plays).
    pub fn select_animation(&mut self, choice: &AnimationChoice) -> Result<(), String> {
        let names = self.animation_names();
        let listed = || {
            if names.is_empty() {
                "it has none".to_string()
            } else {
                let list: Vec<String> = (names.iter().enumerate())
                    .map(|(i, n)| format!("{i} {n:?}"))
                    .collect();
                format!("it has {}", list.join(", "))
            }
        };
        let playing = match choice {
            AnimationChoice::None => None,
            AnimationChoice::First => (!names.is_empty()).then_some(0),
            AnimationChoice::Index(i) if *i < names.len() => Some(*i),
            AnimationChoice::Index(i) => {
                return Err(format!("the scene has no animation {i}: {}", listed()))
            }
            AnimationChoice::Name(name) => match names.iter().position(|n| n == name) {
                Some(i) => Some(i),
                None => {
                    return Err(format!(
                        "the scene has no animation named {name:?}: {}",
                        listed()
                    ))
                }
            },
        };
        if let Some(animation) = &mut self.animation {
            animation.playing = playing;
        }
        Ok(())
    }

    /// The clip that plays, with its name and duration: `(index, name, seconds)`.
    pub fn playing_animation(&self) -> Option<(usize, &str, f32)> {
        let a = self.animation.as_ref()?;
        let i = a.playing?;
        let clip = a.clips.get(i)?;
        Some((i, clip.name.as_str(), clip.duration))
    }

    /// Poses the scene at `seconds` of its playing clip (looped), or at its rest pose where
    /// none plays; returns whether the vertices may have moved (false for a scene without
    /// animations, or where the pose is the one they hold). The casters' bounding sphere, which holds every pose of the loaded clips
    /// sampled over their loops ([`SceneAnimation::sweep_times`]), grows where a pose between
    /// the samples leaves it.
    pub fn animate(&mut self, seconds: f64) -> bool {
        let Some(animation) = &mut self.animation else {
            return false;
        };
        let t = animation.clip_time(seconds);
        let pose = Some((animation.playing, t));
        if animation.last_pose == pose {
            return false;
        }
        animation.last_pose = pose;
        let worlds = animation.pose(animation.playing, t, &mut self.vertices);
        if let Some((node, projection)) = animation.camera {
            // A pose that makes no camera (its up along its view) keeps the last view.
            let camera = worlds
                .get(node)
                .map(|&w| super::camera::gltf_camera(w, projection));
            if let Some(Ok(camera)) = camera {
                self.camera = camera;
            }
        }
        // Only the moved vertices can have left it.
        let center = self.bounds.center;
        let outside = {
            use rayon::prelude::*;
            let vertices = &self.vertices;
            (animation.moved_vertices())
                .filter_map(|range| vertices.get(range))
                .map(|moved| {
                    (moved.par_iter())
                        .map(|v| Vec3::from_array(v.position).distance_squared(center))
                        .reduce(|| 0.0f32, f32::max)
                })
                .fold(0.0f32, f32::max)
                .sqrt()
        };
        if outside > self.bounds.radius && outside.is_finite() {
            tracing::debug!(
                "animation at {t} s leaves the casters' bounding sphere ({} → {outside})",
                self.bounds.radius
            );
            self.bounds.radius = outside;
        }
        true
    }

    /// Keeps the camera where it is when the scene is posed (a camera placed by hand: it no
    /// longer follows an animated camera node).
    pub fn hold_camera(&mut self) {
        if let Some(animation) = &mut self.animation {
            animation.camera = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(
        property: Property,
        interpolation: Interpolation,
        times: &[f32],
        values: &[Vec4],
    ) -> Channel {
        Channel {
            node: 0,
            property,
            interpolation,
            times: times.to_vec(),
            values: values.to_vec(),
        }
    }

    fn x(v: f32) -> Vec4 {
        Vec4::new(v, 0.0, 0.0, 0.0)
    }

    #[test]
    fn step_and_linear_channels_hold_and_blend_their_keys() {
        let keys = [x(1.0), x(3.0), x(-1.0)];
        let times = [1.0, 2.0, 4.0];
        let step = channel(Property::Translation, Interpolation::Step, &times, &keys);
        let linear = channel(Property::Translation, Interpolation::Linear, &times, &keys);
        for (t, held, blended) in [
            // Before the first key: its value; after the last: the last value.
            (0.0, 1.0, 1.0),
            (1.0, 1.0, 1.0),
            (1.5, 1.0, 2.0),
            (2.0, 3.0, 3.0),
            (3.0, 3.0, 1.0),
            (3.999, 3.0, -0.998),
            (4.0, -1.0, -1.0),
            (9.0, -1.0, -1.0),
        ] {
            assert_eq!(step.sample(t).x, held, "step at {t}");
            assert!((linear.sample(t).x - blended).abs() < 1e-5, "linear at {t}");
        }
        // Two keys at one time: the later value from that time on (no division by zero).
        let jump = channel(
            Property::Scale,
            Interpolation::Linear,
            &[0.0, 1.0, 1.0],
            &keys,
        );
        assert_eq!(jump.sample(1.0).x, -1.0);
        assert!((jump.sample(0.5).x - 2.0).abs() < 1e-6);
    }

    #[test]
    fn linear_rotations_turn_along_the_shorter_arc_at_a_steady_rate() {
        let quarter = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
        // The second key written as −q (the same rotation): slerp still turns by 90°, not 270°.
        let keys = [Vec4::from(Quat::IDENTITY), -Vec4::from(quarter)];
        let turn = channel(
            Property::Rotation,
            Interpolation::Linear,
            &[0.0, 2.0],
            &keys,
        );
        for (t, degrees) in [(0.5, 22.5f32), (1.0, 45.0), (1.5, 67.5)] {
            let q = Quat::from_vec4(turn.sample(t));
            let expected = Quat::from_rotation_y(degrees.to_radians());
            assert!(q.angle_between(expected) < 1e-4, "{t}: {q}");
            assert!((q.length() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn cubic_splines_follow_their_tangents() {
        // Value 0 → 1 over [0, 2] with both tangents the slope (0.5 a second): the spline is
        // that line. Zero tangents make it the smoothstep 3u² − 2u³.
        let line = [x(0.0), x(0.0), x(0.5), x(0.5), x(1.0), x(0.0)];
        let flat = [x(9.0), x(0.0), x(0.0), x(0.0), x(1.0), x(9.0)];
        let line = channel(
            Property::Translation,
            Interpolation::CubicSpline,
            &[0.0, 2.0],
            &line,
        );
        let flat = channel(
            Property::Translation,
            Interpolation::CubicSpline,
            &[0.0, 2.0],
            &flat,
        );
        for t in [0.0f32, 0.3, 1.0, 1.7, 2.0] {
            let u = t / 2.0;
            assert!((line.sample(t).x - u).abs() < 1e-6, "line at {t}");
            let smooth = 3.0 * u * u - 2.0 * u * u * u;
            assert!((flat.sample(t).x - smooth).abs() < 1e-6, "flat at {t}");
        }
        // The first in-tangent and the last out-tangent (9) are never used; past the ends the
        // key values hold.
        assert_eq!(flat.sample(-1.0).x, 0.0);
        assert_eq!(flat.sample(5.0).x, 1.0);
        // Rotations come out unit length.
        let q = [
            Vec4::ZERO,
            Vec4::W,
            Vec4::ZERO,
            Vec4::ZERO,
            Vec4::from(Quat::from_rotation_x(1.0)),
            Vec4::ZERO,
        ];
        let spun = channel(
            Property::Rotation,
            Interpolation::CubicSpline,
            &[0.0, 1.0],
            &q,
        );
        assert!((spun.sample(0.4).length() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn weight_channels_interpolate_each_target_on_its_own() {
        // Two targets over keys at 0 and 2 s: [0, 1] → [1, −1].
        let weights = |interpolation, values: &[f32]| WeightsChannel {
            node: 0,
            interpolation,
            times: vec![0.0, 2.0],
            targets: 2,
            values: values.to_vec(),
        };
        let step = weights(Interpolation::Step, &[0.0, 1.0, 1.0, -1.0]);
        let linear = weights(Interpolation::Linear, &[0.0, 1.0, 1.0, -1.0]);
        // Cubic: per key in-tangents, values, out-tangents; zero tangents make each weight
        // follow the smoothstep 3u² − 2u³ between its values.
        let cubic = weights(
            Interpolation::CubicSpline,
            &[9.0, 9.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, -1.0, 9.0, 9.0],
        );
        for t in [-1.0f32, 0.0, 0.5, 1.0, 1.5, 2.0, 3.0] {
            let u = (t / 2.0).clamp(0.0, 1.0);
            let smooth = 3.0 * u * u - 2.0 * u * u * u;
            let mut w = [7.0; 3];
            step.sample_into(t, &mut w);
            let held = if t < 2.0 { [0.0, 1.0] } else { [1.0, -1.0] };
            assert_eq!(w, [held[0], held[1], 7.0], "step at {t}");
            linear.sample_into(t, &mut w);
            assert!((w[0] - u).abs() < 1e-6 && (w[1] - (1.0 - 2.0 * u)).abs() < 1e-6);
            cubic.sample_into(t, &mut w);
            assert!((w[0] - smooth).abs() < 1e-6, "cubic at {t}: {w:?}");
            assert!(
                (w[1] - (1.0 - 2.0 * smooth)).abs() < 1e-6,
                "cubic at {t}: {w:?}"
            );
        }
    }

    #[test]
    fn morphs_add_the_weighted_displacements_before_the_transform() {
        let geometry = LocalGeometry {
            positions: vec![Vec3::ZERO, Vec3::X],
            normals: vec![Vec3::Y, Vec3::Y],
            tangents: vec![[1.0, 0.0, 0.0, -1.0]; 2],
            targets: vec![
                MorphTarget {
                    positions: vec![Vec3::Y, Vec3::ZERO],
                    normals: Vec::new(),
                    tangents: Vec::new(),
                },
                MorphTarget {
                    positions: vec![Vec3::Z, Vec3::Z],
                    normals: vec![Vec3::X, Vec3::X],
                    tangents: vec![Vec3::new(-1.0, 1.0, 0.0); 2],
                },
            ],
        };
        let world = Mat4::from_translation(Vec3::new(10.0, 0.0, 0.0));
        let placed = geometry.place(world, &[0.5, 2.0, 99.0]);
        assert_eq!(
            placed.positions,
            [Vec3::new(10.0, 0.5, 2.0), Vec3::new(11.0, 0.0, 2.0)]
        );
        assert_eq!(placed.normals, [Vec3::new(2.0, 1.0, 0.0); 2]);
        let t = Vec3::new(-1.0, 2.0, 0.0).normalize();
        assert!(placed
            .tangents
            .iter()
            .all(|&[x, y, z, w]| { Vec3::new(x, y, z).distance(t) < 1e-6 && w == -1.0 }));
        // No weights (or zeros): the base shape.
        assert_eq!(
            geometry.place(world, &[]),
            geometry.place(world, &[0.0, 0.0])
        );
        assert_eq!(
            geometry.place(world, &[]).positions[1],
            Vec3::new(11.0, 0.0, 0.0)
        );
    }

    #[test]
    fn moved_ranges_merge_where_they_touch_or_overlap() {
        let ranges = [10..20, 0..4, 4..6, 30..30, 15..25, 40..41];
        assert_eq!(merged_ranges(ranges.into_iter()), [0..6, 10..25, 40..41]);
        assert!(merged_ranges(std::iter::empty()).is_empty());
    }

    #[test]
    fn clips_choose_by_index_name_or_none() {
        assert_eq!(AnimationChoice::parse("none"), AnimationChoice::None);
        assert_eq!(AnimationChoice::parse("2"), AnimationChoice::Index(2));
        assert_eq!(
            AnimationChoice::parse("walk"),
            AnimationChoice::Name("walk".into())
        );
    }
}
