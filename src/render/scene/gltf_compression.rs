//! Compressed glTF geometry, decoded into plain buffers before the loader reads the file, so
//! that everything after it (the accessor checks, the `gltf` crate's reader,
//! `KHR_mesh_quantization`) sees an ordinary glTF file.
//!
//! - **`EXT_meshopt_compression`** and its ratified successor **`KHR_meshopt_compression`**
//!   (meshoptimizer's codecs, as gltfpack and glTF-Transform write them): each compressed
//!   buffer view is decoded into its place in its buffer — most often a *placeholder* buffer
//!   that has a length and no data ([`is_placeholder`]) — with the `meshopt` crate's
//!   meshoptimizer: mode `ATTRIBUTES`, `TRIANGLES` or `INDICES`, then the view's filter
//!   (`OCTAHEDRAL`, `QUATERNION`, `EXPONENTIAL`, and the KHR version's `COLOR`). The library
//!   checks the compressed bytes but takes its parameters on trust (C `assert`s), so every
//!   rule of the extensions' validity lists is checked here first, by name.
//! - **`KHR_draco_mesh_compression`** (Google's Draco, as Blender, glTF-Transform and
//!   gltf-pipeline write it): each primitive's Draco bitstream is decoded with `draco-core`
//!   (a pure-Rust port of Draco 1.5.7), under ceilings of [`MAX_SCENE_ELEMENTS`] points and
//!   faces. Its faces become `u32` indices and each attribute the extension names (by Draco
//!   unique id) becomes `FLOAT` values — integer values divided by their type's largest value
//!   where the primitive's accessor is normalised — in a new buffer. The primitive's own
//!   accessors, which hold no data (the `gltf` crate's validation refuses them, so this runs
//!   before it), are rewritten to read them; an accessor that holds data (an uncompressed
//!   fallback, perhaps read by another primitive too) or that an earlier Draco primitive
//!   already took is left as it is, and a new accessor reads the decoded values instead.
//!
//! Errors name the buffer view or primitive and the property at fault; a decoder's panic on a
//! hostile file is caught and reported as an error.

use super::MAX_SCENE_ELEMENTS;
use gltf::json;
use serde::Deserialize as _;
use serde_json::Value;

/// The extension compressing buffer views.
pub(super) const MESHOPT: &str = "EXT_meshopt_compression";
/// Its Khronos version (the same, with the `COLOR` filter and the vertex codec's version 1).
pub(super) const MESHOPT_KHR: &str = "KHR_meshopt_compression";

/// The extension compressing primitives.
pub(super) const DRACO: &str = "KHR_draco_mesh_compression";

/// A bufferView's or buffer's meshopt extension object (either version), and its name.
fn meshopt_extension(others: &serde_json::Map<String, Value>) -> Option<(&'static str, &Value)> {
    [MESHOPT, MESHOPT_KHR]
        .into_iter()
        .find_map(|name| Some((name, others.get(name)?)))
}

/// Whether buffer `index` of a file (`has_blob`: a GLB with a binary chunk) is a placeholder
/// for meshopt's decoded views, to be allocated (zeroed) rather than read: one marked
/// `"fallback": true` by either version of the extension, or one without a URI that is not
/// the GLB's binary chunk (index 0) in a file using either.
pub(super) fn is_placeholder(root: &json::Root, index: usize, has_blob: bool) -> bool {
    let buffer = &root.buffers[index];
    let uses_meshopt = root
        .extensions_used
        .iter()
        .any(|e| e == MESHOPT || e == MESHOPT_KHR);
    let fallback = buffer
        .extensions
        .as_ref()
        .and_then(|e| meshopt_extension(&e.others))
        .and_then(|(_, e)| e.get("fallback"))
        .and_then(Value::as_bool)
        == Some(true);
    fallback || (uses_meshopt && buffer.uri.is_none() && (index > 0 || !has_blob))
}

/// Whether the document has a meshopt-compressed buffer view or a Draco-compressed primitive
/// (whatever `extensionsUsed` says).
fn has_compressed_data(root: &json::Root) -> bool {
    let views = root.buffer_views.iter().any(|v| {
        v.extensions
            .as_ref()
            .is_some_and(|e| meshopt_extension(&e.others).is_some())
    });
    let primitives = root.meshes.iter().flat_map(|m| &m.primitives).any(|p| {
        p.extensions
            .as_ref()
            .is_some_and(|e| e.others.contains_key(DRACO))
    });
    views || primitives
}

/// Decodes the file's compressed buffer views into their buffers, then its Draco primitives
/// into a new buffer read by their accessors (see the module documentation). A file without
/// either comes back as it was.
pub(super) fn decompress(
    mut root: json::Root,
    mut buffers: Vec<gltf::buffer::Data>,
) -> Result<(json::Root, Vec<gltf::buffer::Data>), String> {
    if !has_compressed_data(&root) {
        return Ok((root, buffers));
    }
    for (index, view) in root.buffer_views.iter().enumerate() {
        let Some((name, extension)) = view
            .extensions
            .as_ref()
            .and_then(|e| meshopt_extension(&e.others))
        else {
            continue;
        };
        decode_meshopt_view(view, extension, &mut buffers)
            .map_err(|m| format!("buffer view {index}: {name}: {m}"))?;
    }
    let mut decoded = DecodedBuffer::new(root.buffers.len());
    for m in 0..root.meshes.len() {
        for p in 0..root.meshes[m].primitives.len() {
            decode_draco_primitive(&mut root, m, p, &buffers, &mut decoded)
                .map_err(|e| format!("mesh {m} primitive {p}: {DRACO}: {e}"))?;
        }
    }
    if !decoded.bytes.is_empty() {
        root.buffers.push(json::Buffer {
            byte_length: decoded.bytes.len().into(),
            name: Some("decoded Draco geometry".into()),
            uri: None,
            extensions: None,
            extras: Default::default(),
        });
        buffers.push(gltf::buffer::Data(decoded.bytes));
    }
    Ok((root, buffers))
}

// ---------------------------------------------------------------------------------------------
// EXT_meshopt_compression

/// A bufferView's `EXT_meshopt_compression` or `KHR_meshopt_compression` object.
#[derive(Debug, serde::Deserialize)]
#[serde(rename_all = "camelCase")]
struct MeshoptView {
    buffer: usize,
    #[serde(default)]
    byte_offset: usize,
    byte_length: usize,
    byte_stride: usize,
    count: usize,
    mode: MeshoptMode,
    #[serde(default)]
    filter: MeshoptFilter,
}

#[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize)]
#[serde(rename_all = "UPPERCASE")]
enum MeshoptMode {
    Attributes,
    Triangles,
    Indices,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Deserialize)]
#[serde(rename_all = "UPPERCASE")]
enum MeshoptFilter {
    #[default]
    None,
    Octahedral,
    Quaternion,
    Exponential,
    Color,
}

impl std::fmt::Display for MeshoptMode {
    /// The JSON's name.
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(match self {
            Self::Attributes => "ATTRIBUTES",
            Self::Triangles => "TRIANGLES",
            Self::Indices => "INDICES",
        })
    }
}

impl std::fmt::Display for MeshoptFilter {
    /// The JSON's name.
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str(match self {
            Self::None => "NONE",
            Self::Octahedral => "OCTAHEDRAL",
            Self::Quaternion => "QUATERNION",
            Self::Exponential => "EXPONENTIAL",
            Self::Color => "COLOR",
        })
    }
}

impl MeshoptView {
    /// The extension's validity rules that the decoders assume, as errors.
    fn check(&self, view: &json::buffer::View) -> Result<(), String> {
        let (stride, count) = (self.byte_stride, self.count);
        if let Some(view_stride) = view.byte_stride {
            if view_stride.0 != stride {
                return Err(format!(
                    "byteStride {stride} differs from the buffer view's {}",
                    view_stride.0
                ));
            }
        }
        let decoded = stride.checked_mul(count);
        if decoded != Some(view.byte_length.0 as usize) {
            return Err(format!(
                "count {count} × byteStride {stride} is not the buffer view's byteLength {}",
                view.byte_length.0
            ));
        }
        if count > MAX_SCENE_ELEMENTS {
            return Err(format!(
                "count {count} is more than the {MAX_SCENE_ELEMENTS} elements a scene may have"
            ));
        }
        match self.mode {
            MeshoptMode::Attributes => {
                if stride == 0 || stride % 4 != 0 || stride > 256 {
                    return Err(format!(
                        "byteStride {stride} of mode ATTRIBUTES is not a multiple of 4 from 4 to \
                         256"
                    ));
                }
            }
            MeshoptMode::Triangles | MeshoptMode::Indices => {
                if stride != 2 && stride != 4 {
                    return Err(format!(
                        "byteStride {stride} of mode {} is neither 2 nor 4",
                        self.mode
                    ));
                }
                if self.mode == MeshoptMode::Triangles && count % 3 != 0 {
                    return Err(format!(
                        "count {count} of mode TRIANGLES is not a multiple of 3"
                    ));
                }
                if self.filter != MeshoptFilter::None {
                    return Err(format!(
                        "filter {} on mode {} (filters apply to ATTRIBUTES only)",
                        self.filter, self.mode
                    ));
                }
            }
        }
        let filter_fits = match self.filter {
            MeshoptFilter::None | MeshoptFilter::Exponential => true,
            MeshoptFilter::Octahedral | MeshoptFilter::Color => stride == 4 || stride == 8,
            MeshoptFilter::Quaternion => stride == 8,
        };
        if !filter_fits {
            return Err(format!(
                "filter {} does not take byteStride {stride} (OCTAHEDRAL and COLOR take 4 or \
                 8, QUATERNION 8)",
                self.filter
            ));
        }
        Ok(())
    }
}

/// Decodes one compressed buffer view (its meshopt extension object `extension`) into
/// its place in its buffer.
fn decode_meshopt_view(
    view: &json::buffer::View,
    extension: &Value,
    buffers: &mut [gltf::buffer::Data],
) -> Result<(), String> {
    let spec = MeshoptView::deserialize(extension).map_err(|e| e.to_string())?;
    spec.check(view)?;
    let source = buffers
        .get(spec.buffer)
        .ok_or_else(|| format!("buffer {} does not exist", spec.buffer))?;
    let compressed = spec
        .byte_offset
        .checked_add(spec.byte_length)
        .and_then(|end| source.0.get(spec.byte_offset..end))
        .ok_or_else(|| {
            format!(
                "the compressed bytes {}..+{} lie outside buffer {} ({} bytes)",
                spec.byte_offset,
                spec.byte_length,
                spec.buffer,
                source.0.len()
            )
        })?;
    let size = spec.byte_stride * spec.count;
    // Decoded into words: the filters read 16- and 32-bit values in place.
    let mut words = vec![0u32; size.div_ceil(4)];
    let out = words.as_mut_ptr().cast::<std::ffi::c_void>();
    let (count, stride) = (spec.count, spec.byte_stride);
    // SAFETY: `words` holds `count × stride` bytes; `compressed` is a live slice of its
    // length; the parameters satisfy the functions' preconditions (`MeshoptView::check`:
    // ATTRIBUTES strides are multiples of 4 up to 256, index strides 2 or 4, triangle counts
    // multiples of 3, each filter's stride its own), and the decoders read no further than
    // the given size.
    let status = unsafe {
        use meshopt::ffi;
        match spec.mode {
            MeshoptMode::Attributes => ffi::meshopt_decodeVertexBuffer(
                out,
                count,
                stride,
                compressed.as_ptr(),
                compressed.len(),
            ),
            MeshoptMode::Triangles => ffi::meshopt_decodeIndexBuffer(
                out,
                count,
                stride,
                compressed.as_ptr(),
                compressed.len(),
            ),
            MeshoptMode::Indices => ffi::meshopt_decodeIndexSequence(
                out,
                count,
                stride,
                compressed.as_ptr(),
                compressed.len(),
            ),
        }
    };
    if status != 0 {
        return Err(format!(
            "the {} data ({} bytes in buffer {}) do not decode to {count} elements of {stride} \
             bytes (meshoptimizer's code {status}: {})",
            spec.mode,
            spec.byte_length,
            spec.buffer,
            match status {
                -1 => "a bitstream version it does not know",
                -2 => "truncated or malformed data",
                _ => "malformed data",
            }
        ));
    }
    // SAFETY: as above; each filter runs on `count` elements of its checked stride in the
    // 4-byte-aligned words.
    unsafe {
        use meshopt::ffi;
        match spec.filter {
            MeshoptFilter::None => {}
            MeshoptFilter::Octahedral => ffi::meshopt_decodeFilterOct(out, count, stride),
            MeshoptFilter::Quaternion => ffi::meshopt_decodeFilterQuat(out, count, stride),
            MeshoptFilter::Exponential => ffi::meshopt_decodeFilterExp(out, count, stride),
            MeshoptFilter::Color => ffi::meshopt_decodeFilterColor(out, count, stride),
        }
    }
    let target = view.buffer.value();
    let offset = view.byte_offset.map_or(0, |o| o.0 as usize);
    let length = buffers.get(target).map_or(0, |b| b.0.len());
    let place = offset
        .checked_add(size)
        .and_then(|end| buffers.get_mut(target)?.0.get_mut(offset..end))
        .ok_or_else(|| {
            format!(
                "the decoded {size} bytes at offset {offset} lie outside buffer {target} \
                 ({length} bytes)"
            )
        })?;
    place.copy_from_slice(&bytemuck::cast_slice::<u32, u8>(&words)[..size]);
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// KHR_draco_mesh_compression

/// The buffer the decoded Draco geometry goes to: its bytes, and its index among the file's
/// buffers (after the file's own).
struct DecodedBuffer {
    index: usize,
    bytes: Vec<u8>,
}

impl DecodedBuffer {
    fn new(index: usize) -> Self {
        Self {
            index,
            bytes: Vec::new(),
        }
    }

    /// Appends `data` (4-byte aligned) as a new buffer view of `root`; returns its index.
    fn push_view(&mut self, root: &mut json::Root, data: &[u8]) -> u32 {
        let offset = self.bytes.len();
        self.bytes.extend_from_slice(data);
        self.bytes.resize(self.bytes.len().next_multiple_of(4), 0);
        root.buffer_views.push(json::buffer::View {
            buffer: json::Index::new(self.index as u32),
            byte_length: data.len().into(),
            byte_offset: Some(offset.into()),
            byte_stride: None,
            name: None,
            target: None,
            extensions: None,
            extras: Default::default(),
        });
        (root.buffer_views.len() - 1) as u32
    }
}

/// A primitive's `KHR_draco_mesh_compression` object.
#[derive(Debug, serde::Deserialize)]
#[serde(rename_all = "camelCase")]
struct DracoPrimitive {
    buffer_view: usize,
    attributes: std::collections::BTreeMap<String, u32>,
}

/// Decodes primitive `p` of mesh `m` if it is Draco-compressed: its geometry goes into
/// `decoded`, read by the primitive's accessors where they have no data of their own (one
/// rewritten for an earlier primitive has: its view into `decoded`), by new accessors
/// otherwise (so an accessor that another primitive also reads keeps its meaning).
fn decode_draco_primitive(
    root: &mut json::Root,
    m: usize,
    p: usize,
    buffers: &[gltf::buffer::Data],
    decoded: &mut DecodedBuffer,
) -> Result<(), String> {
    use json::mesh::Mode;
    use json::validation::Checked;
    let primitive = &root.meshes[m].primitives[p];
    let Some(extension) = primitive
        .extensions
        .as_ref()
        .and_then(|e| e.others.get(DRACO))
    else {
        return Ok(());
    };
    let spec = DracoPrimitive::deserialize(extension).map_err(|e| e.to_string())?;
    if let Some(indices) = primitive.indices.map(|i| i.value()) {
        if indices >= root.accessors.len() {
            return Err(format!(
                "indices name accessor {indices}, but the file has {} accessors",
                root.accessors.len()
            ));
        }
    }
    let view = root
        .buffer_views
        .get(spec.buffer_view)
        .ok_or_else(|| format!("buffer view {} does not exist", spec.buffer_view))?;
    let bytes =
        view_bytes(view, buffers).map_err(|e| format!("buffer view {}: {e}", spec.buffer_view))?;
    let mesh = decode_draco(bytes)?;
    let points = mesh.num_points();
    let triangles = matches!(
        root.meshes[m].primitives[p].mode,
        Checked::Valid(Mode::Triangles | Mode::TriangleStrip)
    );
    if triangles && mesh.num_faces() == 0 {
        return Err(format!(
            "the Draco data ({} bytes) hold no triangles (a point cloud?), for a primitive of \
             triangles",
            bytes.len()
        ));
    }
    let mut indices = Vec::with_capacity(mesh.num_faces() * 3);
    for face in mesh.faces() {
        for point in face {
            if point.0 as usize >= points {
                return Err(format!(
                    "a face names point {}, but the mesh has {points}",
                    point.0
                ));
            }
            indices.push(point.0);
        }
    }
    // Each attribute the extension names and the primitive lists: (its semantic, accessor,
    // values and type).
    let mut attributes: Vec<(&str, usize, Vec<f32>, json::accessor::Type)> = Vec::new();
    for (semantic, &unique_id) in &spec.attributes {
        let Some(accessor_index) = primitive
            .attributes
            .iter()
            .find(|(s, _)| s.to_string() == *semantic)
            .map(|(_, a)| a.value())
        else {
            // An attribute the primitive does not list is not read.
            continue;
        };
        let accessor = root.accessors.get(accessor_index).ok_or_else(|| {
            format!("attribute {semantic} names accessor {accessor_index}, which does not exist")
        })?;
        let attribute = mesh.attribute_by_unique_id(unique_id).ok_or_else(|| {
            format!(
                "attribute {semantic}: the Draco data have no attribute of unique id {unique_id}"
            )
        })?;
        let Checked::Valid(type_) = accessor.type_ else {
            return Err(format!(
                "attribute {semantic}: accessor {accessor_index} has no valid type"
            ));
        };
        let components = usize::from(attribute.num_components());
        if components != type_.multiplicity() {
            return Err(format!(
                "attribute {semantic}: the Draco data have {components} components, accessor \
                 {accessor_index} ({type_:?}) takes {}",
                type_.multiplicity()
            ));
        }
        let mut values = attribute.read_f32s(points, components);
        if let (true, Some((largest, signed))) =
            (accessor.normalized, integer_range(attribute.data_type()))
        {
            for v in &mut values {
                *v = if signed {
                    (*v / largest).max(-1.0)
                } else {
                    *v / largest
                };
            }
        }
        if values.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "attribute {semantic} decodes to a value that is not a finite number"
            ));
        }
        attributes.push((semantic, accessor_index, values, type_));
    }
    // Every check passed: the data, then the accessors that read them.
    let place = |root: &mut json::Root, accessor: Option<usize>, new: json::Accessor| {
        let in_place = accessor.filter(|&a| {
            root.accessors[a].buffer_view.is_none() && root.accessors[a].sparse.is_none()
        });
        match in_place {
            Some(a) => {
                root.accessors[a] = json::Accessor {
                    name: root.accessors[a].name.take(),
                    ..new
                };
                a
            }
            None => {
                root.accessors.push(new);
                root.accessors.len() - 1
            }
        }
    };
    let mut replacements = Vec::new();
    for (semantic, accessor, values, type_) in attributes {
        let view = decoded.push_view(root, bytemuck::cast_slice(&values));
        let components = type_.multiplicity();
        let (mut lo, mut hi) = (vec![f32::MAX; components], vec![f32::MIN; components]);
        for element in values.chunks_exact(components) {
            for (c, &v) in element.iter().enumerate() {
                lo[c] = lo[c].min(v);
                hi[c] = hi[c].max(v);
            }
        }
        let bounds = (points > 0).then(|| (Value::from(lo), Value::from(hi)));
        let new = tight_accessor(
            view,
            points,
            json::accessor::ComponentType::F32,
            type_,
            bounds,
        );
        replacements.push((semantic.to_string(), place(root, Some(accessor), new)));
    }
    let index_accessor = (!indices.is_empty()).then(|| {
        let view = decoded.push_view(root, bytemuck::cast_slice(&indices));
        let new = tight_accessor(
            view,
            indices.len(),
            json::accessor::ComponentType::U32,
            json::accessor::Type::Scalar,
            None,
        );
        let old = root.meshes[m].primitives[p].indices.map(|i| i.value());
        place(root, old, new)
    });
    let primitive = &mut root.meshes[m].primitives[p];
    for (semantic, new) in replacements {
        for (s, a) in primitive.attributes.iter_mut() {
            if s.to_string() == semantic {
                *a = json::Index::new(new as u32);
            }
        }
    }
    if let Some(index_accessor) = index_accessor {
        primitive.indices = Some(json::Index::new(index_accessor as u32));
        if primitive.mode == Checked::Valid(Mode::TriangleStrip) {
            // Draco's faces are a triangle list.
            primitive.mode = Checked::Valid(Mode::Triangles);
        }
    }
    if let Some(extensions) = primitive.extensions.as_mut() {
        extensions.others.remove(DRACO);
    }
    Ok(())
}

/// The bytes of a buffer view, checked to lie within its buffer.
fn view_bytes<'a>(
    view: &json::buffer::View,
    buffers: &'a [gltf::buffer::Data],
) -> Result<&'a [u8], String> {
    let buffer = view.buffer.value();
    let data = buffers
        .get(buffer)
        .ok_or_else(|| format!("buffer {buffer} does not exist"))?;
    let offset = view.byte_offset.map_or(0, |o| o.0 as usize);
    let length = view.byte_length.0 as usize;
    offset
        .checked_add(length)
        .and_then(|end| data.0.get(offset..end))
        .ok_or_else(|| {
            format!(
                "its bytes {offset}..+{length} lie outside buffer {buffer} ({} bytes)",
                data.0.len()
            )
        })
}

/// Decodes a Draco bitstream into a mesh, within the scene's element limit.
fn decode_draco(bytes: &[u8]) -> Result<draco_core::Mesh, String> {
    let limits = draco_core::DecodeLimits::default()
        .with_max_points(MAX_SCENE_ELEMENTS as u64)
        .with_max_faces((MAX_SCENE_ELEMENTS / 3) as u64);
    let decoded = std::panic::catch_unwind(|| {
        let mut buffer = draco_core::DecoderBuffer::new(bytes).with_limits(limits);
        let mut mesh = draco_core::Mesh::new();
        draco_core::MeshDecoder::new()
            .decode(&mut buffer, &mut mesh)
            .map(|()| mesh)
    });
    match decoded {
        Ok(Ok(mesh)) => Ok(mesh),
        Ok(Err(e)) => Err(format!(
            "the Draco data ({} bytes) do not decode: {e}",
            bytes.len()
        )),
        Err(_) => Err(format!(
            "the Draco decoder failed on the data ({} bytes; corrupt file?)",
            bytes.len()
        )),
    }
}

/// The largest value of an integer Draco type and whether it is signed; `None` for floats.
fn integer_range(data_type: draco_core::DataType) -> Option<(f32, bool)> {
    use draco_core::DataType as D;
    match data_type {
        D::Int8 => Some((127.0, true)),
        D::Uint8 => Some((255.0, false)),
        D::Int16 => Some((32767.0, true)),
        D::Uint16 => Some((65535.0, false)),
        D::Int32 => Some((2147483647.0, true)),
        D::Uint32 => Some((4294967295.0, false)),
        _ => None,
    }
}

/// A tightly packed accessor of `count` elements of `type_` in `view`.
fn tight_accessor(
    view: u32,
    count: usize,
    component: json::accessor::ComponentType,
    type_: json::accessor::Type,
    bounds: Option<(Value, Value)>,
) -> json::Accessor {
    let (min, max) = bounds.unzip();
    json::Accessor {
        buffer_view: Some(json::Index::new(view)),
        byte_offset: Some(0u64.into()),
        count: count.into(),
        component_type: json::validation::Checked::Valid(json::accessor::GenericComponentType(
            component,
        )),
        extensions: None,
        extras: Default::default(),
        type_: json::validation::Checked::Valid(type_),
        min,
        max,
        name: None,
        normalized: false,
        sparse: None,
    }
}
