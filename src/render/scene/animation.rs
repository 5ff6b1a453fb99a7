//! Scene animation: glTF keyframe animations of node transforms (translation, rotation,
//! scale) played over time, the meshes they move placed anew in world space every frame.
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
//! 3. every moved mesh instance's vertices are placed through its node's world matrix (and its
//!    `EXT_mesh_gpu_instancing` transform): positions by the matrix, normals by its cofactor
//!    matrix, tangents by its linear part with the handedness turned by a mirror.
//!
//!    A skinned mesh (glTF skins) is placed by linear blend skinning instead: each vertex
//!    through the sum of its (up to four) joints' world matrices times their inverse bind
//!    matrices, weighted; its node's own transform does not apply.
//! 4. the scene's camera, where its node moves, is placed at the node's new world matrix.
//!
//! A clip loops over `[0, duration]`, its duration the latest key time of its channels. The
//! triangles' winding is fixed when the scene is loaded (turned where the rest pose mirrors a
//! mesh); a clip whose scale changes sign mid-play leaves those triangles facing the other
//! way. A vertex that a pose would take past f32 (a clip's values overflowing in their
//! products) keeps its last place. Morph-target weights are not played (the loader names
//! morph targets).

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
    /// The vertices through `world`: positions by the matrix, normals by its cofactor matrix
    /// (defined where the matrix is singular too), tangents by its linear part, their
    /// handedness turned where `world` mirrors.
    pub fn place(&self, world: Mat4) -> PlacedGeometry {
        let normal_matrix = normal_matrix(world);
        let handedness = world.determinant().signum();
        PlacedGeometry {
            positions: (self.positions.iter())
                .map(|&p| world.transform_point3(p))
                .collect(),
            normals: self.normals.iter().map(|&n| normal_matrix * n).collect(),
            tangents: (self.tangents.iter())
                .map(|&t| place_tangent(world, handedness, t))
                .collect(),
        }
    }

    /// [`Self::place`] written into `vertices` (one per local vertex, the rest left as they
    /// are), normals normalised as the builder does; in parallel over blocks of vertices.
    pub fn place_into(&self, world: Mat4, vertices: &mut [Vertex]) {
        use rayon::prelude::*;
        let count = self.positions.len().min(vertices.len());
        vertices[..count]
            .par_chunks_mut(BLOCK)
            .enumerate()
            .for_each(|(k, block)| self.place_block(world, k * BLOCK, block));
    }

    /// Places vertices `first..` into `vertices`.
    fn place_block(&self, world: Mat4, first: usize, vertices: &mut [Vertex]) {
        let normal_matrix = normal_matrix(world);
        let handedness = world.determinant().signum();
        for (i, v) in (first..).zip(vertices.iter_mut()) {
            let position = world.transform_point3(self.positions[i]);
            if !position.is_finite() {
                // A pose past f32 (a clip's values overflowing): the vertex keeps its place.
                continue;
            }
            v.position = position.to_array();
            if let Some(&n) = self.normals.get(i) {
                v.normal = (normal_matrix * n).normalize_or(Vec3::Y).to_array();
            }
            if let Some(&t) = self.tangents.get(i) {
                v.tangent = place_tangent(world, handedness, t);
            }
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

impl Channel {
    /// The value at `t` seconds (see the module doc).
    pub fn sample(&self, t: f32) -> Vec4 {
        let cubic = self.interpolation == Interpolation::CubicSpline;
        // The value of key k (past the tangents where there are any).
        let value = |k: usize| {
            let i = if cubic { 3 * k + 1 } else { k };
            self.values.get(i).copied().unwrap_or(Vec4::ZERO)
        };
        let last = self.times.len().saturating_sub(1);
        // The first key after t: t lies in [times[next − 1], times[next]).
        let next = self.times.partition_point(|&key| key <= t);
        if next == 0 {
            return value(0);
        }
        if next > last {
            return value(last);
        }
        let k = next - 1;
        let interval = self.times[next] - self.times[k];
        if interval.is_nan() || interval <= 0.0 {
            return value(next);
        }
        let u = ((t - self.times[k]) / interval).clamp(0.0, 1.0);
        let rotation = self.property == Property::Rotation;
        match self.interpolation {
            Interpolation::Step => value(k),
            Interpolation::Linear if rotation => {
                let [a, b] = [value(k), value(next)].map(Quat::from_vec4);
                Vec4::from(a.normalize().slerp(b.normalize(), u))
            }
            Interpolation::Linear => value(k).lerp(value(next), u),
            Interpolation::CubicSpline => {
                let out_tangent = self.values.get(3 * k + 2).copied().unwrap_or(Vec4::ZERO);
                let in_tangent = (self.values.get(3 * next)).copied().unwrap_or(Vec4::ZERO);
                let (u2, u3) = (u * u, u * u * u);
                let v = (2.0 * u3 - 3.0 * u2 + 1.0) * value(k)
                    + (u3 - 2.0 * u2 + u) * interval * out_tangent
                    + (-2.0 * u3 + 3.0 * u2) * value(next)
                    + (u3 - u2) * interval * in_tangent;
                if rotation && v.length_squared() > 0.0 {
                    v.normalize()
                } else {
                    v
                }
            }
        }
    }
}

/// One animation of the file: its channels and how long it runs.
#[derive(Clone, Debug, PartialEq)]
pub struct Clip {
    /// The file's name for it, or "" where it has none.
    pub name: String,
    pub channels: Vec<Channel>,
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

/// A mesh instance that a clip may move: its node, its instance transform within the node,
/// where its vertices lie in the scene's vertex list, and its local geometry; a skinned one
/// also its skin (by index into [`SceneAnimation::skins`]) and vertex weights.
#[derive(Clone, Debug, PartialEq)]
pub struct Piece {
    pub node: usize,
    pub instance: Mat4,
    pub first_vertex: usize,
    pub geometry: Arc<LocalGeometry>,
    pub skin: Option<(usize, Arc<SkinWeights>)>,
}

/// A glTF skin: its joints (node indices) and each joint's inverse bind matrix (the
/// identity where the file gives none).
#[derive(Clone, Debug, PartialEq)]
pub struct Skin {
    pub joints: Vec<usize>,
    pub inverse_bind: Vec<Mat4>,
}

/// Per vertex of a skinned primitive: four joints (indices into its skin's joints) and their
/// weights, which sum to 1.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SkinWeights {
    pub joints: Vec<[u16; 4]>,
    pub weights: Vec<[f32; 4]>,
}

impl LocalGeometry {
    /// Skins vertices `first..` of this geometry into `vertices` (linear blend skinning: each
    /// vertex through the weighted sum of its joints' matrices; normals and tangents through
    /// the sum's linear part, renormalised).
    fn skin_block(
        &self,
        joint_matrices: &[Mat4],
        influences: &SkinWeights,
        first: usize,
        vertices: &mut [Vertex],
    ) {
        for (i, v) in (first..).zip(vertices.iter_mut()) {
            let (Some(joints), Some(weights)) =
                (influences.joints.get(i), influences.weights.get(i))
            else {
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
            let position = m.transform_point3(self.positions[i]);
            if !position.is_finite() {
                // A pose past f32: the vertex keeps its place.
                continue;
            }
            v.position = position.to_array();
            if let Some(&n) = self.normals.get(i) {
                v.normal = m.transform_vector3(n).normalize_or(Vec3::Y).to_array();
            }
            if let Some(&t) = self.tangents.get(i) {
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

    /// Places every piece in `vertices` for `clip` at `t` seconds: a skinned one by its
    /// joints (its node's own transform does not apply, as glTF defines), the others by their
    /// node's world matrix and instance transform. Returns every node's world matrix.
    pub fn pose(&self, clip: Option<usize>, t: f32, vertices: &mut [Vertex]) -> Vec<Mat4> {
        let worlds = self.node_worlds(clip, t);
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
            match &piece.skin {
                Some((skin, influences)) => {
                    use rayon::prelude::*;
                    let matrices = joint_matrices.get(*skin).map_or(&[][..], |m| &m[..]);
                    let count = piece.geometry.positions.len().min(vertices.len());
                    vertices[..count]
                        .par_chunks_mut(BLOCK)
                        .enumerate()
                        .for_each(|(k, block)| {
                            (piece.geometry).skin_block(matrices, influences, k * BLOCK, block)
                        });
                }
                None => piece
                    .geometry
                    .place_into(world(piece.node) * piece.instance, vertices),
            }
        }
        worlds
    }

    /// Where the pieces' vertices lie in the scene's vertex list.
    pub fn moved_vertices(&self) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        (self.pieces.iter()).map(|p| p.first_vertex..p.first_vertex + p.geometry.positions.len())
    }

    /// Times at which to pose each clip to find the space it sweeps: 64 evenly spaced over its
    /// loop and its end.
    pub fn sweep_times(clip: &Clip) -> impl Iterator<Item = f32> + '_ {
        const STEPS: u32 = 64;
        (0..=STEPS).map(move |i| clip.duration * i as f32 / STEPS as f32)
    }
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
    fn clips_choose_by_index_name_or_none() {
        assert_eq!(AnimationChoice::parse("none"), AnimationChoice::None);
        assert_eq!(AnimationChoice::parse("2"), AnimationChoice::Index(2));
        assert_eq!(
            AnimationChoice::parse("walk"),
            AnimationChoice::Name("walk".into())
        );
    }
}
