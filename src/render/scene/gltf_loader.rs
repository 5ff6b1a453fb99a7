//! glTF 2.0 loading (`.gltf` with external or embedded buffers, `.glb`): the file and its
//! buffers checked before the `gltf` crate trusts them, the node hierarchy flattened into
//! world space, the materials with the extensions envlight draws, textures, and the camera.

use super::*;

/// The glTF extension that transforms texture coordinates, read from each texture's extensions.
const TEXTURE_TRANSFORM: &str = "KHR_texture_transform";

/// A `KHR_texture_transform` object (offset, rotation in radians counter-clockwise, scale, and
/// an optional texture-coordinate set that overrides the texture's) as its matrix
/// T(offset) · R(rotation) · S(scale) (the extension's definition, column-major there:
/// R = [[cos, −sin], [sin, cos]]) and that set. Errors name the property.
pub(super) fn uv_transform(
    value: &serde_json::Value,
) -> Result<([[f32; 3]; 2], Option<u32>), String> {
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

/// Checks what the `gltf` crate's reader takes on trust (it panics or aborts otherwise): the
/// type and component type (`dimensions` and one of `types`: POSITION and NORMAL are VEC3
/// floats, indices SCALAR unsigned integers), a count between 1 and [`MAX_SCENE_ELEMENTS`],
/// the elements, sparse values and sparse indices within their buffer views and the views
/// within their buffers ([`check_span`]), and a sparse accessor's indices within its count.
/// Returns the problem, worded to follow the accessor's name.
pub(super) fn check_accessor(
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

/// Every image has the source glTF 2.0 requires (section 5.18): a `uri`, or a `bufferView`
/// with its `mimeType`. The `gltf` crate's validation lets either miss and then unwraps them
/// when the image is read (found by fuzz/: a panic that `Scene::load` caught).
fn check_image_sources(root: &gltf::json::Root) -> Result<(), String> {
    for (index, image) in root.images.iter().enumerate() {
        match (&image.buffer_view, &image.uri, &image.mime_type) {
            (Some(_), _, None) => {
                return Err(format!(
                    "image {index} lies in a bufferView but has no mimeType (glTF requires \
                     one there: \"image/png\", \"image/jpeg\", ...)"
                ))
            }
            (None, None, _) => {
                return Err(format!("image {index} has neither a uri nor a bufferView"))
            }
            _ => {}
        }
    }
    Ok(())
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

/// A glTF file's JSON, checked and mended where the `gltf` crate would trust it, and its GLB
/// binary chunk; not yet validated (compressed geometry is decoded first: a Draco primitive's
/// accessors have no data until then, which the crate's validation refuses).
fn parse_gltf(bytes: &[u8], path: &Path) -> Result<(gltf::json::Root, Option<Vec<u8>>), String> {
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
    // A texture's WebP image, where it has one, is the one drawn (the core `source` is then a
    // fallback for viewers without the extension, or absent).
    let images = root.images.len();
    for (t, texture) in root.textures.iter_mut().enumerate() {
        let webp = texture
            .extensions
            .as_ref()
            .and_then(|e| e.others.get(TEXTURE_WEBP))
            .map(|e| e.get("source"));
        match webp {
            None => {}
            Some(Some(source)) => match source.as_u64() {
                Some(i) if (i as usize) < images => {
                    texture.source = gltf::json::Index::new(i as u32);
                }
                _ => {
                    return Err(format!(
                        "texture {t}: {TEXTURE_WEBP}.source {source} is not one of the file's \
                         {images} images"
                    ))
                }
            },
            Some(None) => {
                return Err(format!(
                    "texture {t}: {TEXTURE_WEBP} has no source (the index of its WebP image)"
                ))
            }
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
    Ok((root, blob))
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
fn load_gltf_buffers(
    root: &gltf::json::Root,
    mut blob: Option<Vec<u8>>,
    base: &Path,
) -> Result<Vec<gltf::buffer::Data>, String> {
    let has_blob = blob.is_some();
    let mut buffers = Vec::new();
    for (index, buffer) in root.buffers.iter().enumerate() {
        let length = buffer.byte_length.0 as usize;
        if super::gltf_compression::is_placeholder(root, index, has_blob) {
            // Filled by the decoded views (zeroed pages cost nothing until written).
            if length as u64 > MAX_SCENE_FILE_BYTES {
                return Err(format!(
                    "buffer {index} (a placeholder for meshopt-compressed data) declares \
                     {length} bytes, more than the {MAX_SCENE_FILE_BYTES} a scene's buffer may \
                     hold"
                ));
            }
            buffers.push(gltf::buffer::Data(vec![0; length.next_multiple_of(4)]));
            continue;
        }
        let (source, crate_source) = match buffer.uri.as_deref() {
            Some(uri) => (
                buffer_source(base, uri).map_err(|m| format!("buffer {index}: {m}"))?,
                gltf::buffer::Source::Uri(uri),
            ),
            None => (BufferSource::Embedded, gltf::buffer::Source::Bin),
        };
        let mut data = match source {
            BufferSource::File(file) => {
                crate::read_file::read_regular_file(&file, MAX_SCENE_FILE_BYTES, "a glTF buffer")
                    .map_err(|e| format!("buffer {index} ({}): {e}", file.display()))?
            }
            BufferSource::Embedded => {
                gltf::buffer::Data::from_source_and_blob(crate_source, None, &mut blob)
                    .map_err(|e| format!("buffer {index}: {e}"))?
                    .0
            }
        };
        if data.len() < length {
            return Err(format!(
                "buffer {index} holds {} bytes, less than its byteLength {length}",
                data.len(),
            ));
        }
        // As the gltf crate does: buffers are padded to four bytes.
        data.resize(data.len().next_multiple_of(4), 0);
        buffers.push(gltf::buffer::Data(data));
    }
    Ok(buffers)
}

pub(super) fn load_gltf(path: &Path) -> Result<Builder, SceneError> {
    load_gltf_within(path, MAX_SCENE_ELEMENTS)
}

/// [`load_gltf`] with at most `max_elements` vertices and indices in the flattened scene.
pub(super) fn load_gltf_within(path: &Path, max_elements: usize) -> Result<Builder, SceneError> {
    let err = |message: String| SceneError::Gltf {
        path: path.to_path_buf(),
        message,
    };
    let bytes = read_scene_file(path)?;
    check_glb_header(&bytes).map_err(err)?;
    // Animation pointers to nodes made core channels; those to other things left out, named.
    let (bytes, pointer_notes) =
        match super::gltf_animation::resolve_animation_pointers(&bytes).map_err(err)? {
            Some((resolved, notes)) => (resolved, notes),
            None => (bytes, Vec::new()),
        };
    let (root, blob) = parse_gltf(&bytes, path).map_err(err)?;
    let base = path.parent().unwrap_or(Path::new("."));
    // The GLB's binary chunk moves into its buffer (nothing reads it after).
    let buffers = load_gltf_buffers(&root, blob, base).map_err(err)?;
    let (root, buffers) = super::gltf_compression::decompress(root, buffers).map_err(err)?;
    check_image_sources(&root).map_err(err)?;
    let document = gltf::Document::from_json(root).map_err(|e| err(e.to_string()))?;

    let mut b = Builder::default();
    let mut material_ids = std::collections::HashMap::new();
    let mut images = std::collections::HashMap::new();
    let mut ignored: std::collections::BTreeSet<String> = pointer_notes.into_iter().collect();
    for extension in document.extensions_used() {
        if !DRAWN_EXTENSIONS.contains(&extension) {
            ignored.insert(format!("extension {extension}"));
        }
    }
    for material in document.materials() {
        let sheen = material.extension_value(SHEEN);
        if SHEEN_TEXTURES
            .iter()
            .any(|t| sheen.and_then(|s| s.get(*t)).is_some())
        {
            ignored.insert(format!("{SHEEN} textures (its factors are drawn)"));
        }
    }
    let scene = document
        .default_scene()
        .or_else(|| document.scenes().next());
    let Some(scene) = scene else {
        return Err(err("no scene".into()));
    };
    // The animations, where the file has any (the meshes they move are recorded below).
    let clips = super::gltf_animation::read_clips(&document, &buffers).map_err(err)?;
    // Skinned meshes are placed by their joints, so they need the hierarchy too.
    let mut rig = (!clips.is_empty() || document.skins().len() > 0)
        .then(|| SceneAnimation::new(&document, clips));
    let mut stack: Vec<(gltf::Node, Mat4, Option<usize>)> =
        scene.nodes().map(|n| (n, Mat4::IDENTITY, None)).collect();
    // glTF's node hierarchy is a forest: a node reached twice sits in a cycle or has several
    // parents (flattening such a graph could multiply the meshes without bound).
    let mut reached = vec![false; document.nodes().len()];
    let mut camera_nodes: Vec<(usize, Mat4)> = Vec::new();
    while let Some((node, parent, parent_index)) = stack.pop() {
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
        if let Some(rig) = rig.as_mut() {
            rig.visit(node.index(), parent_index);
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        for child in node.children() {
            stack.push((child, world, Some(node.index())));
        }
        if node.camera().is_some() {
            camera_nodes.push((node.index(), world));
        }
        let Some(mesh) = node.mesh() else { continue };
        // Only where a mesh is drawn: a helper node without one may overflow harmlessly.
        let node_name = format!("node {} ({:?})", node.index(), node.name().unwrap_or(""));
        let instances = node_instances(&node, &document, &buffers)
            .map_err(|m| err(format!("{node_name}: {INSTANCING}: {m}")))?;
        let moved = rig.as_ref().is_some_and(|r| r.moves(node.index()));
        // A skinned mesh: its skin (read once), and every primitive's joints and weights.
        let skin = match (node.skin(), rig.as_mut()) {
            (Some(skin), Some(rig)) => Some(
                rig.skin(&skin, &buffers)
                    .map_err(|m| err(format!("{node_name}: {m}")))?,
            ),
            _ => None,
        };
        let joint_count = skin
            .and_then(|s| rig.as_ref().and_then(|r| r.skins[s].as_ref()))
            .map_or(0, |s| s.joints.len());
        let mesh_name = |prim: &gltf::Primitive| {
            format!(
                "mesh {} ({:?}) primitive {}",
                mesh.index(),
                mesh.name().unwrap_or(""),
                prim.index()
            )
        };
        // Its morph-target weights where no clip drives them: the node's, else the mesh's.
        let morph_weights =
            morph_weights(&node, &mesh).map_err(|m| err(format!("{node_name}: {m}")))?;
        let morphed = rig.as_ref().is_some_and(|r| r.morphs(node.index()));
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
            // The whole scene, flattened, within the per-accessor limit too: nodes that
            // instance one mesh add its vertices again each time (4,000 nodes of one
            // 100,000-vertex mesh, a 1.4 MB file, needed 13 GB).
            let vertex_count = prim
                .get(&gltf::Semantic::Positions)
                .map_or(0, |a| a.count());
            let index_count = prim.indices().map_or(vertex_count, |a| a.count());
            let room = |b: &Builder| {
                if b.vertices.len() + vertex_count > max_elements
                    || b.indices.len() + index_count > max_elements
                {
                    return Err(err(format!(
                        "{}: the scene flattened to world space holds more than {max_elements} \
                         vertices or indices ({} and {} before this primitive of \
                         {vertex_count} and {index_count}; every node that uses a mesh adds it \
                         again)",
                        mesh_name(&prim),
                        b.vertices.len(),
                        b.indices.len()
                    )));
                }
                Ok(())
            };
            check_primitive(
                &prim,
                &buffers,
                &channels,
                (normal_textured, skin.is_some()),
                &mesh_name(&prim),
                &mut ignored,
            )
            .map_err(err)?;
            room(&b)?;
            let local = read_primitive(
                &prim,
                &buffers,
                &channels,
                (normal_textured, joint_count),
                path,
                &mesh_name(&prim),
            )
            .map_err(err)?;
            let Some(local) = local else { continue };
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
                        &document,
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
            for (instance, transform) in instances.iter().enumerate() {
                let world = world * *transform;
                let node_name = if instances.len() > 1 {
                    format!("{node_name}, instance {instance}")
                } else {
                    node_name.clone()
                };
                if !world.is_finite() {
                    return Err(err(format!(
                        "{node_name}: its transform combined with its parents' overflows f32 \
                         (scales or translations whose product exceeds 3.4e38)"
                    )));
                }
                room(&b)?;
                let placed = local.geometry.place(world, &morph_weights);
                if placed
                    .positions
                    .iter()
                    .chain(&placed.normals)
                    .any(|p| !p.is_finite())
                {
                    return Err(err(format!(
                        "{node_name}, {}: a vertex position or normal is not finite in world \
                         space (a vertex times the node's transform overflows f32?)",
                        mesh_name(&prim)
                    )));
                }
                // A mirroring node reverses the triangles' winding (glTF): turned back, so
                // that front faces wind counter-clockwise in world space (single-sided
                // materials, the normals made from the winding).
                let mut indices = local.indices.clone();
                if world.determinant() < 0.0 {
                    for triangle in indices.chunks_exact_mut(3) {
                        triangle.swap(1, 2);
                    }
                }
                let first = b.vertices.len();
                b.mesh(
                    &placed.positions,
                    &placed.normals,
                    &local.uvs[0],
                    &indices,
                    id,
                );
                b.set_second_uvs(first, &local.uvs[1]);
                b.set_colors(first, &local.colors);
                b.set_tangents(first, &placed.tangents);
                let skinned = skin.zip(local.skin.clone());
                let posed = moved || skinned.is_some() || morphed;
                if let (true, Some(rig)) = (posed, rig.as_mut()) {
                    rig.pieces.push(super::animation::Piece {
                        node: node.index(),
                        instance: *transform,
                        first_vertex: first,
                        geometry: local.geometry.clone(),
                        skin: skinned,
                        morph_weights: morph_weights.clone(),
                    });
                }
            }
        }
    }
    // The first camera node (by index) of the scene: the view the file was made for.
    if let Some(&(index, world)) = camera_nodes.iter().min_by_key(|(index, _)| *index) {
        let node = document.nodes().nth(index);
        let camera = node.as_ref().and_then(|n| n.camera());
        let name = format!(
            "camera node {index} ({:?})",
            node.as_ref().and_then(|n| n.name()).unwrap_or("")
        );
        // `node.camera()` is there: the node was listed for its camera.
        if let Some(camera) = camera {
            let projection = match camera.projection() {
                gltf::camera::Projection::Perspective(p) => {
                    Projection::Perspective { fov_y: p.yfov() }
                }
                gltf::camera::Projection::Orthographic(o) => Projection::Orthographic {
                    half_height: o.ymag(),
                },
            };
            b.camera =
                Some(gltf_camera(world, projection).map_err(|m| err(format!("{name}: {m}")))?);
            tracing::info!("{}: the view of its {name}", path.display());
            // A camera a clip moves follows it.
            if let Some(rig) = rig.as_mut().filter(|r| r.moves(index)) {
                rig.camera = Some((index, projection));
            }
        }
    }
    // Skinned meshes stand as their joints' rest pose places them (their node's transform,
    // with which they were placed above, does not apply).
    if let Some(rig) = rig
        .as_ref()
        .filter(|r| r.pieces.iter().any(|p| p.skin.is_some()))
    {
        rig.pose(None, 0.0, &mut b.vertices);
        for piece in rig.pieces.iter().filter(|p| p.skin.is_some()) {
            let end = piece.first_vertex + piece.geometry.positions.len();
            let placed = b.vertices.get(piece.first_vertex..end).unwrap_or(&[]);
            if placed
                .iter()
                .any(|v| !v.position.iter().all(|c| c.is_finite()))
            {
                return Err(err(format!(
                    "node {}: its skin's joints place a vertex at a position that is not \
                     finite (joint or inverse bind matrices that overflow f32?)",
                    piece.node
                )));
            }
        }
    }
    b.animation = match rig {
        Some(rig) if rig.pieces.is_empty() && rig.camera.is_none() => {
            tracing::info!(
                "{}: its {} animation(s) move no drawn mesh and not its camera; drawn still",
                path.display(),
                rig.clips.len()
            );
            None
        }
        rig => rig,
    };
    if !ignored.is_empty() {
        tracing::warn!(
            "{}: not drawn (envlight renders the alpha modes, the index of refraction, and base \
             colour, metallic, roughness, emission, specular and clear coat, with their \
             textures, the sheen's factors, unlit materials, and normal and occlusion \
             textures): {}",
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
    let (sheen_color, sheen_roughness) = gltf_sheen(material)?;
    Ok(Material {
        base_color: [c[0], c[1], c[2]],
        roughness,
        metallic,
        specular,
        specular_color,
        specular_factor,
        clearcoat,
        clearcoat_roughness,
        sheen_color,
        sheen_roughness,
        emission: gltf_emission(material)?,
        alpha: c[3],
        alpha_mode,
        double_sided: material.double_sided(),
        unlit: material.extension_value(UNLIT).is_some(),
        textures,
    })
}

/// The glTF extension that lets vertex attributes be bytes and shorts (`read_attribute`).
const MESH_QUANTIZATION: &str = "KHR_mesh_quantization";

/// The glTF extension that draws a node's mesh once per instance ([`node_instances`]).
const INSTANCING: &str = "EXT_mesh_gpu_instancing";

/// The local transforms of a node's mesh instances: `EXT_mesh_gpu_instancing`'s
/// TRANSLATION, ROTATION and SCALE of each instance, as T · R · S within the node's space (each
/// attribute absent is the identity's; floats, or the bytes and shorts `KHR_mesh_quantization`
/// allows); the identity alone for a node without the extension. The attributes' accessors
/// are checked as the vertex attributes are ([`check_accessor`]) and must have one count.
/// Errors name the attribute or instance.
fn node_instances(
    node: &gltf::Node,
    document: &gltf::Document,
    buffers: &[gltf::buffer::Data],
) -> Result<Vec<Mat4>, String> {
    use gltf::accessor::{
        DataType::{F32, I16, I8, U16, U8},
        Dimensions,
    };
    let Some(extension) = node.extension_value(INSTANCING) else {
        return Ok(vec![Mat4::IDENTITY]);
    };
    let attributes = extension
        .get("attributes")
        .and_then(serde_json::Value::as_object)
        .ok_or("no attributes object")?;
    let accessor = |name: &str| -> Result<Option<gltf::Accessor>, String> {
        let Some(value) = attributes.get(name) else {
            return Ok(None);
        };
        let index = value
            .as_u64()
            .ok_or_else(|| format!("{name} {value} is not an accessor index"))?;
        document
            .accessors()
            .nth(index as usize)
            .map(Some)
            .ok_or_else(|| format!("{name} names accessor {index}, which does not exist"))
    };
    let (translation, rotation, scale) = (
        accessor("TRANSLATION")?,
        accessor("ROTATION")?,
        accessor("SCALE")?,
    );
    let mut counts = Vec::new();
    for (name, a, dimensions, types) in [
        (
            "TRANSLATION",
            &translation,
            Dimensions::Vec3,
            &[F32, I8, U8, I16, U16][..],
        ),
        ("ROTATION", &rotation, Dimensions::Vec4, &[F32, I8, I16][..]),
        (
            "SCALE",
            &scale,
            Dimensions::Vec3,
            &[F32, I8, U8, I16, U16][..],
        ),
    ] {
        if let Some(a) = a {
            check_accessor(a, buffers, dimensions, types).map_err(|m| format!("{name} {m}"))?;
            counts.push((name, a.count()));
        }
    }
    let Some(&(_, count)) = counts.first() else {
        return Err("none of TRANSLATION, ROTATION and SCALE".into());
    };
    if let Some((name, other)) = counts.iter().find(|(_, c)| *c != count) {
        return Err(format!(
            "{name} holds {other} instances, {} {count}",
            counts[0].0
        ));
    }
    let read3 = |a: &Option<gltf::Accessor>, name: &str| -> Result<Vec<[f32; 3]>, String> {
        match a {
            Some(a) => read_attribute::<3>(a, buffers)
                .filter(|v| v.len() == count)
                .ok_or_else(|| format!("{name} could not be read")),
            None => Ok(Vec::new()),
        }
    };
    let translations = read3(&translation, "TRANSLATION")?;
    let scales = read3(&scale, "SCALE")?;
    let rotations = match &rotation {
        Some(a) => read_attribute::<4>(a, buffers)
            .filter(|v| v.len() == count)
            .ok_or("ROTATION could not be read")?,
        None => Vec::new(),
    };
    (0..count)
        .map(|i| {
            let t = translations.get(i).map_or(Vec3::ZERO, |&t| Vec3::from(t));
            let s = scales.get(i).map_or(Vec3::ONE, |&s| Vec3::from(s));
            let q = rotations.get(i).map_or([0.0, 0.0, 0.0, 1.0], |&q| q);
            let quaternion = glam::DVec4::from_array(q.map(f64::from));
            if !(t.is_finite() && s.is_finite() && quaternion.is_finite()) {
                return Err(format!(
                    "instance {i}: translation {t}, rotation {q:?} or scale {s} is not finite"
                ));
            }
            if quaternion.length() < 1e-6 {
                return Err(format!(
                    "instance {i}: rotation {q:?} is not a rotation (a unit quaternion x, y, z, w)"
                ));
            }
            let q = quaternion.normalize().as_vec4();
            let rotation = glam::Quat::from_xyzw(q.x, q.y, q.z, q.w);
            Ok(Mat4::from_scale_rotation_translation(s, rotation, t))
        })
        .collect()
}

/// The glTF extension that shows a material's base colour unlit ([`Material::unlit`]).
const UNLIT: &str = "KHR_materials_unlit";

/// The glTF extension that gives a texture a WebP image (in place of, or besides, its PNG or
/// JPEG `source`).
const TEXTURE_WEBP: &str = "EXT_texture_webp";

/// The glTF extension that scales a material's emission past 1.
const EMISSIVE_STRENGTH: &str = "KHR_materials_emissive_strength";

/// The glTF extensions the renderer draws (a file may require them).
const DRAWN_EXTENSIONS: [&str; 14] = [
    MESH_QUANTIZATION,
    INSTANCING,
    UNLIT,
    super::gltf_compression::MESHOPT,
    super::gltf_compression::MESHOPT_KHR,
    super::gltf_compression::DRACO,
    TEXTURE_TRANSFORM,
    TEXTURE_WEBP,
    EMISSIVE_STRENGTH,
    IOR,
    SPECULAR,
    CLEARCOAT,
    SHEEN,
    super::gltf_animation::ANIMATION_POINTER,
];

/// The glTF extension that lays a velvet-like sheen over a material.
const SHEEN: &str = "KHR_materials_sheen";

/// The sheen's textures, which the renderer does not draw (its factors alone are).
const SHEEN_TEXTURES: [&str; 2] = ["sheenColorTexture", "sheenRoughnessTexture"];

/// A glTF material's sheen: `KHR_materials_sheen`'s `sheenColorFactor` (three numbers in
/// [0, 1]; black without) and `sheenRoughnessFactor` (in [0, 1]; 0 without). Errors name the
/// property.
fn gltf_sheen(material: &gltf::Material) -> Result<([f32; 3], f32), String> {
    let roughness = extension_number(
        material,
        (SHEEN, "sheenRoughnessFactor"),
        0.0,
        in_unit_interval,
        IN_UNIT_INTERVAL,
    )?;
    let color = extension_rgb(
        material,
        (SHEEN, "sheenColorFactor"),
        [0.0; 3],
        in_unit_interval,
        "is not three numbers in [0, 1]",
    )?;
    Ok((color, roughness))
}

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
    let color = extension_rgb(
        material,
        (SPECULAR, "specularColorFactor"),
        [1.0; 3],
        |x| x.is_finite() && x >= 0.0,
        "is not three finite numbers ≥ 0",
    )?;
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

/// A colour (three numbers, each `valid`) named `name` in a glTF material's `extension`:
/// `default` where absent; else an error naming the property, the value and the
/// `requirement`.
fn extension_rgb(
    material: &gltf::Material,
    (extension, name): (&str, &str),
    default: [f32; 3],
    valid: impl Fn(f32) -> bool,
    requirement: &str,
) -> Result<[f32; 3], String> {
    match material
        .extension_value(extension)
        .and_then(|e| e.get(name))
    {
        None => Ok(default),
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
            .filter(|c| c.iter().all(|&x| valid(x)))
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
pub(super) fn read_attribute<const N: usize>(
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
    let unit = move |c: f32, max: f32| normalised_component(c, max, normalized);
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

/// An integer component `c` of a type whose largest value is `max` as a float: normalised to
/// [0, 1] or [−1, 1] where its accessor is `normalized` (glTF 2.0, 3.11), else as it is.
pub(super) fn normalised_component(c: f32, max: f32, normalized: bool) -> f32 {
    if normalized {
        (c / max).max(-1.0)
    } else {
        c
    }
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

/// The external buffers and images a glTF file (`bytes`, in directory `base`) refers to, for
/// [`scene_files`]; best effort. Read from the JSON without validation, so that a file which
/// requires an extension the `gltf` crate does not know (a compression, say) still names its
/// files.
pub(super) fn referenced_files(bytes: &[u8], base: &Path) -> Vec<PathBuf> {
    let Ok(gltf) = gltf::Gltf::from_slice_without_validation(bytes) else {
        return Vec::new();
    };
    let root = gltf.document.as_json();
    let buffer_uris = root.buffers.iter().filter_map(|b| b.uri.as_deref());
    let image_uris = root.images.iter().filter_map(|i| i.uri.as_deref());
    buffer_uris
        .chain(image_uris)
        .filter_map(|uri| match buffer_source(base, uri) {
            Ok(BufferSource::File(file)) => Some(file),
            _ => None,
        })
        .collect()
}

/// A triangle primitive's vertices in its mesh's own space, read once however many nodes and
/// instances draw it.
struct LocalPrimitive {
    /// Positions, normals (the file's, else smooth ones from the triangles; zero normals
    /// repaired) and tangents where a normal texture needs them (the file's, else MikkTSpace's).
    geometry: std::sync::Arc<LocalGeometry>,
    /// The texture coordinates of each channel ([`TextureChannels`]; none where the material
    /// has no set for it).
    uvs: [Vec<[f32; 2]>; 2],
    /// `COLOR_0`, or none.
    colors: Vec<[u16; 4]>,
    /// As the file winds them (the loader turns them where a node mirrors).
    indices: Vec<u32>,
    /// A skinned primitive's joints and weights.
    skin: Option<std::sync::Arc<SkinWeights>>,
}

/// Reads primitive `prim` (named `name` in errors) of a material with these texture
/// `channels`: `None` for one without positions (skipped with a warning, as the spec
/// advises). Its accessors were checked ([`check_accessor`]).
fn read_primitive(
    prim: &gltf::Primitive,
    buffers: &[gltf::buffer::Data],
    channels: &TextureChannels,
    (normal_textured, joints): (bool, usize),
    path: &Path,
    name: &str,
) -> Result<Option<LocalPrimitive>, String> {
    let mat = prim.material();
    let reader = prim.reader(|buf| buffers.get(buf.index()).map(|d| &d.0[..]));
    let attribute = |semantic: gltf::Semantic| prim.get(&semantic);
    let Some(positions) =
        attribute(gltf::Semantic::Positions).and_then(|a| read_attribute::<3>(&a, buffers))
    else {
        if prim.get(&gltf::Semantic::Positions).is_none() {
            // The spec's advice for a primitive without positions: skip it.
            tracing::warn!(
                "{}: skipping {name}: it has no POSITION attribute",
                path.display()
            );
            return Ok(None);
        }
        return Err(format!(
            "{name}: its POSITION accessor cannot be read (out of range of its buffer?)"
        ));
    };
    let positions: Vec<Vec3> = positions.into_iter().map(Vec3::from_array).collect();
    let indices: Vec<u32> = match (reader.read_indices(), prim.indices()) {
        (Some(i), _) => i.into_u32().collect(),
        (None, None) => (0..positions.len() as u32).collect(),
        (None, Some(_)) => {
            return Err(format!(
                "{name}: its indices accessor cannot be read (out of range of its buffer?)"
            ))
        }
    };
    if !indices.len().is_multiple_of(3) {
        return Err(format!(
            "{name}: {} indices, not a multiple of 3 (triangles)",
            indices.len()
        ));
    }
    if let Some(i) = indices.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(format!(
            "{name}: index {i} out of range of its {} vertices",
            positions.len()
        ));
    }
    let read_normals =
        attribute(gltf::Semantic::Normals).and_then(|a| read_attribute::<3>(&a, buffers));
    let mut normals: Vec<Vec3> = match read_normals {
        Some(n) => n.into_iter().map(Vec3::from_array).collect(),
        None if prim.get(&gltf::Semantic::Normals).is_some() => {
            return Err(format!(
                "{name}: its NORMAL accessor cannot be read (out of range of its buffer?)"
            ))
        }
        None => smooth_normals(&positions, &indices),
    };
    if normals.len() != positions.len() {
        return Err(format!(
            "{name}: {} normals for {} positions",
            normals.len(),
            positions.len()
        ));
    }
    // Placed later; a value the file gives as not a number is said as such then (in world
    // space, with the node's name). Repairs need finite data.
    if positions.iter().chain(&normals).all(|p| p.is_finite()) {
        repair_zero_normals(path, &positions, &mut normals, &indices);
    }
    let mut uvs: [Vec<[f32; 2]>; 2] = Default::default();
    for (channel, &set) in channels.sets.iter().enumerate() {
        let read = attribute(gltf::Semantic::TexCoords(set))
            .and_then(|a| read_attribute::<2>(&a, buffers));
        let Some(read) = read else {
            return Err(format!(
                "{name}: its material is textured, but it has no readable TEXCOORD_{set}"
            ));
        };
        check_per_vertex(&read, positions.len(), &format!("TEXCOORD_{set}"))
            .map_err(|m| format!("{name}: {m}"))?;
        uvs[channel] = read;
    }
    // MikkTSpace's tangents follow the normal texture's coordinates (the clear coat's where
    // the base has none).
    let normal_slot = if mat.normal_texture().is_some() {
        NORMAL_SLOT
    } else {
        COAT_NORMAL_SLOT
    };
    let normal_uvs = &uvs[channels.channel[normal_slot] as usize];
    // Tangents where a normal texture needs them: the file's, or MikkTSpace's, as glTF asks.
    let read_tangents =
        attribute(gltf::Semantic::Tangents).and_then(|a| read_attribute::<4>(&a, buffers));
    let tangents: Vec<[f32; 4]> = match (normal_textured, read_tangents) {
        (false, _) => Vec::new(),
        (true, _) if normal_uvs.is_empty() => Vec::new(),
        (true, Some(t)) => t,
        (true, None) if prim.get(&gltf::Semantic::Tangents).is_some() => {
            return Err(format!(
                "{name}: its TANGENT accessor cannot be read (out of range of its buffer?)"
            ))
        }
        (true, None) => generate_tangents(&positions, &normals, normal_uvs, &indices)
            .unwrap_or_else(|| {
                tracing::warn!(
                    "{}: {name}: no tangents could be made for its normal texture (degenerate \
                     texture coordinates?); drawn without it",
                    path.display()
                );
                Vec::new()
            }),
    };
    if !tangents.is_empty() {
        check_per_vertex(&tangents, positions.len(), "TANGENT")
            .map_err(|m| format!("{name}: {m}"))?;
    }
    let colors: Vec<[u16; 4]> = match reader.read_colors(0) {
        // Through f32: the crate widens bytes by a shift (255 became 65280, not 1).
        Some(c) => c
            .into_rgba_f32()
            .map(|c| c.map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16))
            .collect(),
        None if prim.get(&gltf::Semantic::Colors(0)).is_some() => {
            return Err(format!(
                "{name}: its COLOR_0 accessor cannot be read (out of range of its buffer?)"
            ))
        }
        None => Vec::new(),
    };
    if !colors.is_empty() && colors.len() != positions.len() {
        return Err(format!(
            "{name}: {} COLOR_0 values for {} positions",
            colors.len(),
            positions.len()
        ));
    }
    let targets = read_morph_targets(prim, buffers, positions.len(), !tangents.is_empty())
        .map_err(|m| format!("{name}: {m}"))?;
    let skin = if joints > 0 {
        Some(std::sync::Arc::new(read_influences(
            prim,
            buffers,
            joints,
            positions.len(),
            name,
        )?))
    } else {
        None
    };
    Ok(Some(LocalPrimitive {
        geometry: std::sync::Arc::new(LocalGeometry {
            positions,
            normals,
            tangents,
            targets,
        }),
        uvs,
        colors,
        indices,
        skin,
    }))
}

/// The morph-target weights of a mesh drawn by `node` where no clip drives them: the node's
/// `weights`, else its mesh's, else zeros; one per morph target of its primitives (which must
/// have as many each), finite. Empty for a mesh without morph targets.
fn morph_weights(node: &gltf::Node, mesh: &gltf::Mesh) -> Result<Vec<f32>, String> {
    let counts: Vec<usize> = mesh.primitives().map(|p| p.morph_targets().len()).collect();
    let targets = counts.first().copied().unwrap_or(0);
    if let Some(p) = counts.iter().position(|&c| c != targets) {
        return Err(format!(
            "mesh {} ({:?}): its primitive {p} has {} morph targets, its primitive 0 {targets} \
             (glTF requires as many in every primitive)",
            mesh.index(),
            mesh.name().unwrap_or(""),
            counts[p]
        ));
    }
    let (weights, whose) = match (node.weights(), mesh.weights()) {
        (Some(w), _) => (w, "its weights"),
        (None, Some(w)) => (w, "its mesh's weights"),
        (None, None) => return Ok(vec![0.0; targets]),
    };
    if weights.len() != targets {
        return Err(format!(
            "{whose} hold {} values for {targets} morph targets",
            weights.len()
        ));
    }
    if let Some(w) = weights.iter().find(|w| !w.is_finite()) {
        return Err(format!("{whose} hold {w}, not a finite number"));
    }
    Ok(weights.to_vec())
}

/// A primitive's morph targets (their accessors checked by [`check_primitive`]): per
/// target, the displacements of its `vertices` positions and normals, and of their tangents
/// where the primitive has them (`tangents`); each finite, one per vertex.
fn read_morph_targets(
    prim: &gltf::Primitive,
    buffers: &[gltf::buffer::Data],
    vertices: usize,
    tangents: bool,
) -> Result<Vec<MorphTarget>, String> {
    let displacements = |accessor: Option<gltf::Accessor>, what: &str, k: usize| {
        let Some(accessor) = accessor else {
            return Ok(Vec::new());
        };
        let read = read_attribute::<3>(&accessor, buffers)
            .ok_or_else(|| format!("morph target {k}: its {what} cannot be read"))?;
        if read.len() != vertices {
            return Err(format!(
                "morph target {k}: {} {what} displacements for {vertices} positions",
                read.len()
            ));
        }
        if let Some(d) = read.iter().find(|d| !d.iter().all(|c| c.is_finite())) {
            return Err(format!(
                "morph target {k}: {what} displacement {d:?} is not finite"
            ));
        }
        Ok(read.into_iter().map(Vec3::from_array).collect())
    };
    prim.morph_targets()
        .enumerate()
        .map(|(k, target)| {
            Ok(MorphTarget {
                positions: displacements(target.positions(), "POSITION", k)?,
                normals: displacements(target.normals(), "NORMAL", k)?,
                tangents: if tangents {
                    displacements(target.tangents(), "TANGENT", k)?
                } else {
                    Vec::new()
                },
            })
        })
        .collect()
}

/// How many sets of joint influences a primitive has: `JOINTS_n` or `WEIGHTS_n` for n = 0, 1,
/// … without a gap (one past a gap is not read: [`check_primitive`] names it).
fn influence_sets(prim: &gltf::Primitive) -> u32 {
    (0..)
        .take_while(|&n| {
            prim.get(&gltf::Semantic::Joints(n)).is_some()
                || prim.get(&gltf::Semantic::Weights(n)).is_some()
        })
        .count() as u32
}

/// A skinned primitive's `JOINTS_n` and `WEIGHTS_n` sets (checked by [`check_primitive`]):
/// one of each per vertex in every set, joints within the skin's `joints`, weights finite and
/// not negative, made to sum to 1 over all sets (a vertex of zero weights follows its first
/// joint).
fn read_influences(
    prim: &gltf::Primitive,
    buffers: &[gltf::buffer::Data],
    joints: usize,
    vertices: usize,
    name: &str,
) -> Result<SkinWeights, String> {
    let sets = influence_sets(prim);
    if sets == 0 {
        return Err(format!(
            "{name}: its node has a skin, but it has no JOINTS_0 and WEIGHTS_0"
        ));
    }
    let stride = 4 * sets as usize;
    let mut joint_indices = vec![0u16; vertices * stride];
    let mut weights = vec![0.0f32; vertices * stride];
    let get = |b: gltf::Buffer| buffers.get(b.index()).map(|d| &d.0[..]);
    for set in 0..sets {
        let (Some(joint_accessor), Some(weight_accessor)) = (
            prim.get(&gltf::Semantic::Joints(set)),
            prim.get(&gltf::Semantic::Weights(set)),
        ) else {
            return Err(format!(
                "{name}: it has only one of JOINTS_{set} and WEIGHTS_{set} (glTF pairs them)"
            ));
        };
        let read: Option<Vec<[u16; 4]>> = match joint_accessor.data_type() {
            gltf::accessor::DataType::U8 => {
                gltf::accessor::Iter::<[u8; 4]>::new(joint_accessor, get)
                    .map(|i| i.map(|j| j.map(u16::from)).collect())
            }
            _ => gltf::accessor::Iter::<[u16; 4]>::new(joint_accessor, get).map(|i| i.collect()),
        };
        let set_joints = read.ok_or_else(|| format!("{name}: its JOINTS_{set} cannot be read"))?;
        let set_weights = read_attribute::<4>(&weight_accessor, buffers)
            .ok_or_else(|| format!("{name}: its WEIGHTS_{set} cannot be read"))?;
        if set_joints.len() != vertices || set_weights.len() != vertices {
            return Err(format!(
                "{name}: {} JOINTS_{set} and {} WEIGHTS_{set} values for {vertices} positions",
                set_joints.len(),
                set_weights.len()
            ));
        }
        let slots = |v: usize| v * stride + 4 * set as usize..v * stride + 4 * set as usize + 4;
        for (v, (j, w)) in set_joints.iter().zip(&set_weights).enumerate() {
            joint_indices[slots(v)].copy_from_slice(j);
            weights[slots(v)].copy_from_slice(w);
        }
    }
    let vertex_influences =
        (joint_indices.chunks_exact(stride)).zip(weights.chunks_exact_mut(stride));
    for (v, (j, w)) in vertex_influences.enumerate() {
        if let Some(k) = (0..stride).find(|&k| w[k] != 0.0 && usize::from(j[k]) >= joints) {
            return Err(format!(
                "{name}: vertex {v}'s JOINTS_{} names joint {}, past its skin's {joints}",
                k / 4,
                j[k]
            ));
        }
        if let Some(k) = (0..stride).find(|&k| !(w[k].is_finite() && w[k] >= 0.0)) {
            let set = k / 4;
            return Err(format!(
                "{name}: vertex {v}'s WEIGHTS_{set} {:?} are not finite, non-negative numbers",
                &w[4 * set..4 * set + 4]
            ));
        }
        let sum: f32 = w.iter().sum();
        if sum > 0.0 {
            w.iter_mut().for_each(|x| *x /= sum);
        } else {
            w.fill(0.0);
            w[0] = 1.0;
        }
    }
    Ok(SkinWeights {
        influences: stride,
        joints: joint_indices,
        weights,
    })
}

/// Checks the accessors of primitive `prim` (named `name` in errors) that [`read_primitive`]
/// reads ([`check_accessor`]): positions, normals, the texture coordinates of its material's
/// `channels`, tangents where a normal texture needs them, `COLOR_0`, the `JOINTS_n` and
/// `WEIGHTS_n` of a skinned mesh, its morph targets' displacements, and the indices. Further colour sets and influences past a gap are
/// named in `ignored`.
fn check_primitive(
    prim: &gltf::Primitive,
    buffers: &[gltf::buffer::Data],
    channels: &TextureChannels,
    (normal_textured, skinned): (bool, bool),
    name: &str,
    ignored: &mut std::collections::BTreeSet<String>,
) -> Result<(), String> {
    let influence_sets = influence_sets(prim);
    for (semantic, accessor) in prim.attributes() {
        use gltf::accessor::{
            DataType::{F32, I16, I8, U16, U8},
            Dimensions::{Vec2, Vec3, Vec4},
        };
        // Floats, and the integers KHR_mesh_quantization allows (`read_attribute`).
        let (attribute, dimensions, types) = match semantic {
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
            gltf::Semantic::Joints(n) if skinned && n < influence_sets => {
                (format!("JOINTS_{n}"), Vec4, &[U8, U16][..])
            }
            gltf::Semantic::Weights(n) if skinned && n < influence_sets => {
                (format!("WEIGHTS_{n}"), Vec4, &[F32, U8, U16][..])
            }
            gltf::Semantic::Joints(_) | gltf::Semantic::Weights(_) if skinned => {
                ignored.insert("joint influences past a gap in JOINTS_n, WEIGHTS_n".into());
                continue;
            }
            _ => continue,
        };
        check_accessor(&accessor, buffers, dimensions, types)
            .map_err(|m| format!("{name}: {attribute} {m}"))?;
    }
    for (k, target) in prim.morph_targets().enumerate() {
        use gltf::accessor::{
            DataType::{F32, I16, I8},
            Dimensions::Vec3,
        };
        // Floats, or the integers KHR_mesh_quantization allows for displacements.
        let attributes = [
            ("POSITION", target.positions()),
            ("NORMAL", target.normals()),
            ("TANGENT", target.tangents().filter(|_| normal_textured)),
        ];
        for (attribute, accessor) in attributes {
            if let Some(accessor) = accessor {
                check_accessor(&accessor, buffers, Vec3, &[F32, I8, I16])
                    .map_err(|m| format!("{name}: morph target {k}'s {attribute} {m}"))?;
            }
        }
    }
    if let Some(accessor) = prim.indices() {
        use gltf::accessor::{
            DataType::{U16, U32, U8},
            Dimensions::Scalar,
        };
        check_accessor(&accessor, buffers, Scalar, &[U8, U16, U32])
            .map_err(|m| format!("{name}: indices {m}"))?;
    }
    Ok(())
}
