//! glTF animations and skins read into [`SceneAnimation`]: every channel's sampler checked
//! (key times finite and non-decreasing, as many values as the interpolation needs, the
//! component types glTF allows) before its accessors are read, so that a bad file is an
//! error naming the animation and channel, never a panic. A morph-target weights channel
//! holds one weight per morph target of its node's mesh each key. A skin's joints and inverse bind
//! matrices are read when a drawn mesh first uses it; the loader reads each skinned
//! primitive's joints and weights.

use super::animation::{
    Channel, Clip, Interpolation, Property, RestTransform, SceneAnimation, Skin, WeightsChannel,
};
use super::gltf_loader::{check_accessor, normalised_component, read_attribute};
use super::*;
use glam::{Quat, Vec4};

/// The file's animations, in its order: each clip's channels that drive a node's translation,
/// rotation, scale or morph-target weights. Errors name the animation and channel.
pub(super) fn read_clips(
    document: &gltf::Document,
    buffers: &[gltf::buffer::Data],
) -> Result<Vec<Clip>, String> {
    check_channel_targets(document)?;
    document
        .animations()
        .map(|animation| {
            let name = animation.name().unwrap_or("").to_string();
            let mut channels = Vec::new();
            let mut weights = Vec::new();
            for channel in animation.channels() {
                let read = read_channel(&channel, buffers).map_err(|m| {
                    format!(
                        "animation {} ({name:?}) channel {}: {m}",
                        animation.index(),
                        channel.index()
                    )
                })?;
                match read {
                    ReadChannel::Transform(c) => channels.push(c),
                    ReadChannel::Weights(w) => weights.push(w),
                }
            }
            let last_keys = (channels.iter().map(|c: &Channel| &c.times))
                .chain(weights.iter().map(|w: &WeightsChannel| &w.times))
                .filter_map(|times| times.last().copied());
            let duration = last_keys.fold(0.0f32, f32::max);
            Ok(Clip {
                name,
                channels,
                weights,
                duration,
            })
        })
        .collect()
}

/// Checks what the `gltf` crate's validation leaves out for animations (its accessors unwrap
/// them): each channel's target node exists, and its path and its sampler's interpolation are
/// ones glTF defines.
fn check_channel_targets(document: &gltf::Document) -> Result<(), String> {
    use gltf::json::validation::Checked;
    let root = document.as_json();
    for (a, animation) in root.animations.iter().enumerate() {
        let name = animation.name.as_deref().unwrap_or("");
        for (c, channel) in animation.channels.iter().enumerate() {
            let at = || format!("animation {a} ({name:?}) channel {c}");
            let node = channel.target.node.value();
            if node >= root.nodes.len() {
                return Err(format!(
                    "{}: its target node {node} does not exist ({} nodes)",
                    at(),
                    root.nodes.len()
                ));
            }
            if matches!(channel.target.path, Checked::Invalid) {
                return Err(format!(
                    "{}: its target path is not translation, rotation, scale or weights",
                    at()
                ));
            }
            let sampler = animation.samplers.get(channel.sampler.value());
            match sampler.map(|s| &s.interpolation) {
                Some(Checked::Valid(_)) => {}
                Some(Checked::Invalid) => {
                    return Err(format!(
                        "{}: its sampler's interpolation is not LINEAR, STEP or CUBICSPLINE",
                        at()
                    ))
                }
                None => {
                    return Err(format!(
                        "{}: its sampler {} does not exist",
                        at(),
                        channel.sampler.value()
                    ))
                }
            }
        }
    }
    Ok(())
}

/// A channel as read: of a node's transform or of its morph-target weights.
enum ReadChannel {
    Transform(Channel),
    Weights(WeightsChannel),
}

/// One channel's keys and values.
fn read_channel(
    channel: &gltf::animation::Channel,
    buffers: &[gltf::buffer::Data],
) -> Result<ReadChannel, String> {
    use gltf::accessor::{
        DataType::{F32, I16, I8, U16, U8},
        Dimensions,
    };
    let property = match channel.target().property() {
        gltf::animation::Property::Translation => Property::Translation,
        gltf::animation::Property::Rotation => Property::Rotation,
        gltf::animation::Property::Scale => Property::Scale,
        gltf::animation::Property::MorphTargetWeights => {
            return read_weights_channel(channel, buffers).map(ReadChannel::Weights)
        }
    };
    let sampler = channel.sampler();
    let interpolation = read_interpolation(&sampler);
    let times = read_key_times(&sampler, buffers)?;
    let output = sampler.output();
    // Rotations may be normalised integers (glTF 2.0, 3.11), the rest floats.
    let (dimensions, types) = match property {
        Property::Rotation => (Dimensions::Vec4, &[F32, I8, U8, I16, U16][..]),
        _ => (Dimensions::Vec3, &[F32][..]),
    };
    check_accessor(&output, buffers, dimensions, types).map_err(|m| format!("its values: {m}"))?;
    let values: Vec<Vec4> = match property {
        Property::Rotation => read_attribute::<4>(&output, buffers)
            .map(|v| v.into_iter().map(Vec4::from_array).collect()),
        _ => read_attribute::<3>(&output, buffers).map(|v| {
            v.into_iter()
                .map(|v| Vec3::from_array(v).extend(0.0))
                .collect()
        }),
    }
    .ok_or("its values cannot be read")?;
    let per_key = values_per_key(interpolation);
    if values.len() != per_key * times.len() {
        return Err(format!(
            "{} values for {} key times ({per_key} a key with {interpolation:?} interpolation)",
            values.len(),
            times.len()
        ));
    }
    if let Some(v) = values.iter().find(|v| !v.is_finite()) {
        let shown = match property {
            Property::Rotation => format!("{v}"),
            _ => format!("{}", v.truncate()),
        };
        return Err(format!("value {shown} is not finite"));
    }
    if property == Property::Rotation {
        // Every key's value (not the tangents) must be a rotation.
        let key_values = values.iter().skip(per_key / 2).step_by(per_key);
        if let Some(q) = key_values.clone().find(|q| q.length() < 1e-6) {
            return Err(format!(
                "rotation {q} is not a rotation (a unit quaternion x, y, z, w)"
            ));
        }
    }
    Ok(ReadChannel::Transform(Channel {
        node: channel.target().node().index(),
        property,
        interpolation,
        times,
        values,
    }))
}

/// A sampler's interpolation as ours.
fn read_interpolation(sampler: &gltf::animation::Sampler) -> Interpolation {
    match sampler.interpolation() {
        gltf::animation::Interpolation::Step => Interpolation::Step,
        gltf::animation::Interpolation::Linear => Interpolation::Linear,
        gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
    }
}

/// How many values a key holds: three (in-tangent, value, out-tangent) with a cubic spline.
fn values_per_key(interpolation: Interpolation) -> usize {
    if interpolation == Interpolation::CubicSpline {
        3
    } else {
        1
    }
}

/// A sampler's key times: finite floats, non-decreasing.
fn read_key_times(
    sampler: &gltf::animation::Sampler,
    buffers: &[gltf::buffer::Data],
) -> Result<Vec<f32>, String> {
    use gltf::accessor::{DataType::F32, Dimensions};
    let input = sampler.input();
    check_accessor(&input, buffers, Dimensions::Scalar, &[F32])
        .map_err(|m| format!("its key times: {m}"))?;
    let get = |b: gltf::Buffer| buffers.get(b.index()).map(|d| &d.0[..]);
    let times: Vec<f32> = gltf::accessor::Iter::<f32>::new(input, get)
        .ok_or("its key times cannot be read")?
        .collect();
    if let Some(t) = times.iter().find(|t| !t.is_finite()) {
        return Err(format!("key time {t} is not a finite number"));
    }
    if let Some(k) = times.windows(2).position(|w| w[1] < w[0]) {
        return Err(format!(
            "key times decrease ({} then {}); glTF requires increasing times",
            times[k],
            times[k + 1]
        ));
    }
    Ok(times)
}

/// A morph-target weights channel: its node's mesh must have morph targets, and each key
/// holds one weight per target (floats, or normalised integers as glTF 2.0, 3.11 allows).
fn read_weights_channel(
    channel: &gltf::animation::Channel,
    buffers: &[gltf::buffer::Data],
) -> Result<WeightsChannel, String> {
    use gltf::accessor::{
        DataType::{F32, I16, I8, U16, U8},
        Dimensions,
    };
    let node = channel.target().node();
    let targets = node.mesh().map_or(0, |mesh| {
        (mesh.primitives())
            .map(|p| p.morph_targets().len())
            .max()
            .unwrap_or(0)
    });
    if targets == 0 {
        return Err(format!(
            "it animates the morph-target weights of node {} ({:?}), whose {} no morph targets",
            node.index(),
            node.name().unwrap_or(""),
            if node.mesh().is_some() {
                "mesh has"
            } else {
                "has no mesh and"
            }
        ));
    }
    let sampler = channel.sampler();
    let interpolation = read_interpolation(&sampler);
    let times = read_key_times(&sampler, buffers)?;
    let output = sampler.output();
    check_accessor(
        &output,
        buffers,
        Dimensions::Scalar,
        &[F32, I8, U8, I16, U16],
    )
    .map_err(|m| format!("its weights: {m}"))?;
    let values = read_scalars(&output, buffers).ok_or("its weights cannot be read")?;
    let per_key = values_per_key(interpolation);
    if values.len() != per_key * targets * times.len() {
        return Err(format!(
            "{} weights for {} key times of {targets} morph targets ({per_key} sets a key \
             with {interpolation:?} interpolation)",
            values.len(),
            times.len()
        ));
    }
    if let Some(w) = values.iter().find(|w| !w.is_finite()) {
        return Err(format!("weight {w} is not a finite number"));
    }
    Ok(WeightsChannel {
        node: node.index(),
        interpolation,
        times,
        targets,
        values,
    })
}

/// A scalar accessor's values as floats (normalised integers to [0, 1] or [−1, 1]); `None`
/// where it cannot be read. Its type was checked ([`check_accessor`]).
pub(super) fn read_scalars(
    accessor: &gltf::Accessor,
    buffers: &[gltf::buffer::Data],
) -> Option<Vec<f32>> {
    use gltf::accessor::{DataType, Iter};
    let get = |b: gltf::Buffer| buffers.get(b.index()).map(|d| &d.0[..]);
    let normalized = accessor.normalized();
    let unit = move |c: f32, max: f32| normalised_component(c, max, normalized);
    let read = accessor.clone();
    Some(match accessor.data_type() {
        DataType::F32 => Iter::<f32>::new(read, get)?.collect(),
        DataType::I8 => (Iter::<i8>::new(read, get)?)
            .map(|c| unit(f32::from(c), 127.0))
            .collect(),
        DataType::U8 => (Iter::<u8>::new(read, get)?)
            .map(|c| unit(f32::from(c), 255.0))
            .collect(),
        DataType::I16 => (Iter::<i16>::new(read, get)?)
            .map(|c| unit(f32::from(c), 32767.0))
            .collect(),
        DataType::U16 => (Iter::<u16>::new(read, get)?)
            .map(|c| unit(f32::from(c), 65535.0))
            .collect(),
        DataType::U32 => return None,
    })
}

impl SceneAnimation {
    /// The clips of `document` over its nodes' rest transforms; the hierarchy (parents, order)
    /// and the moved pieces are filled in as the loader walks the scene ([`Self::visit`]).
    pub(super) fn new(document: &gltf::Document, clips: Vec<Clip>) -> Self {
        let clips_empty = clips.is_empty();
        let nodes = document.nodes().len();
        let mut animated = vec![false; nodes];
        for channel in clips.iter().flat_map(|c| &c.channels) {
            if let Some(a) = animated.get_mut(channel.node) {
                *a = true;
            }
        }
        let mut morphed = vec![false; nodes];
        for channel in clips.iter().flat_map(|c| &c.weights) {
            if let Some(m) = morphed.get_mut(channel.node) {
                *m = true;
            }
        }
        let rest = document
            .nodes()
            .map(|node| {
                let matrix = Mat4::from_cols_array_2d(&node.transform().matrix());
                let (translation, rotation, scale) = match node.transform() {
                    gltf::scene::Transform::Decomposed {
                        translation,
                        rotation,
                        scale,
                    } => (
                        Vec3::from_array(translation),
                        Quat::from_array(rotation),
                        Vec3::from_array(scale),
                    ),
                    // glTF animates only nodes given by parts; a matrix node is taken apart.
                    gltf::scene::Transform::Matrix { .. } => {
                        let (s, r, t) = matrix.to_scale_rotation_translation();
                        (t, r, s)
                    }
                };
                let finite = |v: Vec3, or: Vec3| if v.is_finite() { v } else { or };
                let unit = rotation.length() > 1e-6 && rotation.is_finite();
                RestTransform {
                    matrix,
                    translation: finite(translation, Vec3::ZERO),
                    rotation: if unit {
                        rotation.normalize()
                    } else {
                        Quat::IDENTITY
                    },
                    scale: finite(scale, Vec3::ONE),
                }
            })
            .collect();
        SceneAnimation {
            parents: vec![None; nodes],
            rest,
            order: Vec::new(),
            clips,
            pieces: Vec::new(),
            playing: (!clips_empty).then_some(0),
            moved: animated,
            morphed,
            skins: vec![None; document.skins().len()],
            last_pose: None,
            camera: None,
        }
    }

    /// The index of `skin` in [`Self::skins`], read from the file the first time a drawn mesh
    /// uses it ([`read_skin`]).
    pub(super) fn skin(
        &mut self,
        skin: &gltf::Skin,
        buffers: &[gltf::buffer::Data],
    ) -> Result<usize, String> {
        let index = skin.index();
        let slot = self
            .skins
            .get_mut(index)
            .ok_or_else(|| format!("skin {index} does not exist"))?;
        if slot.is_none() {
            *slot = Some(read_skin(skin, buffers)?);
        }
        Ok(index)
    }

    /// Records that the loader reached `node` under `parent` (parents are reached first):
    /// it is moved if a clip drives it or moves its parent.
    pub(super) fn visit(&mut self, node: usize, parent: Option<usize>) {
        if node >= self.parents.len() {
            return;
        }
        self.parents[node] = parent;
        self.order.push(node);
        if let Some(p) = parent.and_then(|p| self.moved.get(p).copied()) {
            self.moved[node] |= p;
        }
    }

    /// Whether a clip moves `node` (after [`Self::visit`]).
    pub(super) fn moves(&self, node: usize) -> bool {
        self.moved.get(node).copied().unwrap_or(false)
    }

    /// Whether a clip drives the morph-target weights of `node`.
    pub(super) fn morphs(&self, node: usize) -> bool {
        self.morphed.get(node).copied().unwrap_or(false)
    }
}

/// A skin's joints and inverse bind matrices (MAT4 floats, at least one per joint; the
/// identity for each where the file gives none). Errors name the skin.
fn read_skin(skin: &gltf::Skin, buffers: &[gltf::buffer::Data]) -> Result<Skin, String> {
    let name = format!("skin {} ({:?})", skin.index(), skin.name().unwrap_or(""));
    let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
    if joints.is_empty() {
        return Err(format!("{name} has no joints"));
    }
    if joints.len() > usize::from(u16::MAX) + 1 {
        return Err(format!(
            "{name} has {} joints, more than the 65536 a JOINTS_0 index can name",
            joints.len()
        ));
    }
    let inverse_bind = match skin.inverse_bind_matrices() {
        None => vec![Mat4::IDENTITY; joints.len()],
        Some(accessor) => {
            use gltf::accessor::{DataType::F32, Dimensions::Mat4 as Mat4x4};
            check_accessor(&accessor, buffers, Mat4x4, &[F32])
                .map_err(|m| format!("{name}: its inverseBindMatrices {m}"))?;
            let get = |b: gltf::Buffer| buffers.get(b.index()).map(|d| &d.0[..]);
            let matrices: Vec<Mat4> = gltf::accessor::Iter::<[[f32; 4]; 4]>::new(accessor, get)
                .ok_or_else(|| format!("{name}: its inverseBindMatrices cannot be read"))?
                .map(|m| Mat4::from_cols_array_2d(&m))
                .collect();
            if matrices.len() < joints.len() {
                return Err(format!(
                    "{name}: {} inverse bind matrices for {} joints",
                    matrices.len(),
                    joints.len()
                ));
            }
            if let Some(m) = matrices.iter().find(|m| !m.is_finite()) {
                return Err(format!(
                    "{name}: inverse bind matrix {m} has a value that is not a finite number"
                ));
            }
            matrices
        }
    };
    Ok(Skin {
        joints,
        inverse_bind,
    })
}

/// The glTF extension whose animation channels target a property by JSON pointer.
pub(super) const ANIMATION_POINTER: &str = "KHR_animation_pointer";

/// A file's bytes as rewritten by [`resolve_animation_pointers`], and its notes of what was
/// left out.
pub(super) type ResolvedPointers = (Vec<u8>, Vec<String>);

/// A glTF or GLB file's bytes with its `KHR_animation_pointer` channels made core channels
/// where they drive a node's translation, rotation, scale or morph-target weights
/// (`/nodes/N/translation` becomes node N, path `translation`), and taken out where they
/// drive anything else (a camera's field of view, a material's factors: not played), with one
/// note for each kind taken out. `None` where the file uses no animation pointer (the bytes
/// are read as they are). The `gltf` crate cannot read such a channel (it has no `node`):
/// without this the whole file failed to load. Errors name the animation and channel.
pub(super) fn resolve_animation_pointers(bytes: &[u8]) -> Result<Option<ResolvedPointers>, String> {
    let needle = ANIMATION_POINTER.as_bytes();
    if !bytes.windows(needle.len()).any(|w| w == needle) {
        return Ok(None);
    }
    let glb = bytes.starts_with(b"glTF");
    // A GLB: its JSON chunk (the header was checked: 12 bytes, then chunk 0 is the JSON).
    let (json_bytes, rest) = if glb {
        let length = bytes
            .get(12..16)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
            .ok_or("its GLB has no JSON chunk")?;
        let json = bytes
            .get(20..20 + length)
            .ok_or("its GLB's JSON chunk runs past the file")?;
        (json, &bytes[20 + length..])
    } else {
        (bytes, &[][..])
    };
    let mut root: serde_json::Value =
        serde_json::from_slice(json_bytes).map_err(|e| e.to_string())?;
    let mut notes = std::collections::BTreeSet::new();
    let mut changed = false;
    let animations = root.get_mut("animations").and_then(|a| a.as_array_mut());
    for (a, animation) in animations.into_iter().flatten().enumerate() {
        let Some(channels) = animation.get_mut("channels").and_then(|c| c.as_array_mut()) else {
            continue;
        };
        let mut kept = Vec::new();
        for (c, mut channel) in std::mem::take(channels).into_iter().enumerate() {
            let target = channel.get("target");
            if target.and_then(|t| t.get("path")).and_then(|p| p.as_str()) != Some("pointer") {
                kept.push(channel);
                continue;
            }
            changed = true;
            let pointer = target
                .and_then(|t| t.get("extensions"))
                .and_then(|e| e.get(ANIMATION_POINTER))
                .and_then(|e| e.get("pointer"))
                .and_then(|p| p.as_str())
                .ok_or_else(|| {
                    format!(
                        "animation {a} channel {c}: its target path is \"pointer\" but it has \
                         no {ANIMATION_POINTER} pointer string"
                    )
                })?;
            match node_pointer(pointer) {
                Some((node, path)) => {
                    channel["target"] = serde_json::json!({"node": node, "path": path});
                    kept.push(channel);
                }
                None => {
                    // "/materials/0/pbrMetallicRoughness/baseColorFactor" → "materials".
                    let kind = pointer.trim_start_matches('/').split('/').next();
                    notes.insert(format!(
                        "{ANIMATION_POINTER} channels of {} (not played)",
                        kind.filter(|k| !k.is_empty())
                            .unwrap_or("the document root")
                    ));
                }
            }
        }
        *channels = kept;
    }
    if !changed {
        return Ok(None);
    }
    let mut json = serde_json::to_vec(&root).map_err(|e| e.to_string())?;
    if !glb {
        return Ok(Some((json, notes.into_iter().collect())));
    }
    // The GLB again: the JSON chunk padded with spaces to 4 bytes, the rest as it was.
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + rest.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&bytes[..8]);
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(rest);
    Ok(Some((out, notes.into_iter().collect())))
}

/// The node and core path of a pointer to a node's transform or weights
/// (`/nodes/3/rotation` → (3, "rotation")); `None` for any other pointer.
fn node_pointer(pointer: &str) -> Option<(u64, &str)> {
    let rest = pointer.strip_prefix("/nodes/")?;
    let (node, path) = rest.split_once('/')?;
    let node: u64 = node.parse().ok()?;
    matches!(path, "translation" | "rotation" | "scale" | "weights").then_some((node, path))
}
