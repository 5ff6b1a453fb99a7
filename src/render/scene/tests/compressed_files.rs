//! Compressed glTF geometry (`KHR_draco_mesh_compression`, `EXT_meshopt_compression`): the
//! fixtures of tests/data/compressed, made by the extensions' reference encoders, load as
//! their uncompressed source; inconsistent or corrupt compressed data are errors naming the
//! buffer view or primitive, never a panic.

use super::*;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/compressed")
        .join(name)
}

/// How far a scene loaded from a compressed file is from the source's: the largest
/// differences of each vertex from the source vertex nearest to it in position and texture
/// coordinates (as the base-colour texture reads them: gltfpack stores them quantised, with a
/// `KHR_texture_transform` that scales them back).
#[derive(Debug)]
struct Differences {
    position: f32,
    normal_degrees: f32,
    uv: f32,
    colour: f32,
}

/// Compares `scene` with `source` (see [`Differences`]) and asserts that the triangles are the
/// source's: the same multiset of source-vertex triples, each in its winding order.
fn compare(source: &Scene, scene: &Scene, what: &str) -> Differences {
    assert_eq!(
        scene.indices.len(),
        source.indices.len(),
        "{what}: index count"
    );
    let uv = |scene: &Scene, v: &Vertex| {
        let t = scene.materials[v.material as usize]
            .textures
            .base_color
            .unwrap()
            .transform;
        let [u, w] = v.uv;
        [
            t[0][0] * u + t[0][1] * w + t[0][2],
            t[1][0] * u + t[1][1] * w + t[1][2],
        ]
    };
    let key = |scene: &Scene, v: &Vertex| {
        let [x, y, z] = v.position;
        let [u, w] = uv(scene, v);
        [x, y, z, u, w]
    };
    let nearest: Vec<usize> = scene
        .vertices
        .iter()
        .map(|v| {
            let k = key(scene, v);
            let distance = |s: &Vertex| -> f32 {
                key(source, s)
                    .iter()
                    .zip(&k)
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum()
            };
            (0..source.vertices.len())
                .min_by(|&a, &b| {
                    distance(&source.vertices[a]).total_cmp(&distance(&source.vertices[b]))
                })
                .unwrap()
        })
        .collect();
    let mut d = Differences {
        position: 0.0,
        normal_degrees: 0.0,
        uv: 0.0,
        colour: 0.0,
    };
    for (v, &n) in scene.vertices.iter().zip(&nearest) {
        let s = &source.vertices[n];
        let gap = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max)
        };
        d.position = d.position.max(gap(&v.position, &s.position));
        d.uv = d.uv.max(gap(&uv(scene, v), &uv(source, s)));
        let colour = |c: [u16; 4]| c.map(|c| f32::from(c) / 65535.0);
        d.colour = d.colour.max(gap(&colour(v.color), &colour(s.color)));
        let cos = Vec3::from(v.normal)
            .normalize()
            .dot(Vec3::from(s.normal).normalize())
            .clamp(-1.0, 1.0);
        d.normal_degrees = d.normal_degrees.max(cos.acos().to_degrees());
    }
    // Triangles as vertex triples, rotated to start at their smallest index (winding kept).
    let canonical = |t: [usize; 3]| {
        let r = (0..3).min_by_key(|&i| t[i]).unwrap();
        [t[r], t[(r + 1) % 3], t[(r + 2) % 3]]
    };
    let triangles = |indices: &[u32], map: &dyn Fn(u32) -> usize| {
        let mut t: Vec<[usize; 3]> = indices
            .chunks_exact(3)
            .map(|c| canonical([map(c[0]), map(c[1]), map(c[2])]))
            .collect();
        t.sort_unstable();
        t
    };
    assert_eq!(
        triangles(&scene.indices, &|i| nearest[i as usize]),
        triangles(&source.indices, &|i| i as usize),
        "{what}: the triangles differ from the source's"
    );
    d
}

/// Every fixture loads as the source sphere: the same triangles, and vertices within one step
/// of the encoders' quantisation of the source (their defaults: 14 bits for positions, one
/// step 1.8e-4 of the sphere's 3-unit span; 12 for texture coordinates, 2.4e-4; 8 for
/// colours, 1/255; normals 10 bits (Draco) or 8-bit octahedral (meshopt), within 1°).
/// Measured: positions within 0.9–1.1e-4, normals 0.16° (Draco) to 0.76°, texture
/// coordinates 1.2–1.3e-4, colours 0.0020. A decoding fault (a wrong filter, normalisation or
/// attribute) moves values by far more.
#[test]
fn compressed_fixtures_load_as_their_source() {
    let source = Scene::load(&fixture("sphere.glb"), false).unwrap();
    assert_eq!(source.indices.len(), 1584);
    for name in [
        "sphere_draco.glb",
        "sphere_draco_sequential.glb",
        "sphere_meshopt.glb",
        "sphere_gltfpack.glb",
        "sphere_gltfpack.gltf",
    ] {
        let scene = Scene::load(&fixture(name), false).unwrap_or_else(|e| panic!("{name}: {e}"));
        let d = compare(&source, &scene, name);
        eprintln!("{name}: {d:?}");
        assert!(d.position < 3.0 / 16383.0, "{name}: {d:?}");
        assert!(d.normal_degrees < 1.0, "{name}: {d:?}");
        assert!(d.uv < 1.0 / 4095.0, "{name}: {d:?}");
        assert!(d.colour < 1.0 / 255.0, "{name}: {d:?}");
        assert_eq!(scene.textures.len(), 1, "{name}: the base-colour texture");
    }
    // The external buffer of the .gltf is one of its files; its placeholder has no file.
    let files = scene_files(&fixture("sphere_gltfpack.gltf"));
    assert_eq!(
        files,
        [
            fixture("sphere_gltfpack.gltf"),
            fixture("sphere_gltfpack.bin")
        ]
    );
}

/// `EXT_mesh_gpu_instancing` (gltfpack's `-mi`, its attributes meshopt-compressed with the
/// EXPONENTIAL and QUATERNION filters) draws the mesh once per instance, as the six nodes of
/// the source do: the same triangles, with vertices within the quantisation. gltfpack's
/// defaults: the mesh's positions in 14 bits (1.4e-4 here, the instances scaling it up to
/// 1.5×), the instances' translations and scales with 16-bit mantissas, and their rotations
/// in 12-bit components (`-ar 12`): about 1e-3 rad, on points up to 3.6 units from the
/// instances' origin. Measured: positions within 1.95e-3, normals 0.97° (8-bit octahedral
/// normals, as in `compressed_fixtures_load_as_their_source`, plus the rotations').
#[test]
fn instanced_meshes_load_as_their_nodes() {
    let source = Scene::load(&fixture("spheres.glb"), false).unwrap();
    assert_eq!(source.indices.len(), 6 * 1584);
    let scene = Scene::load(&fixture("spheres_instanced.glb"), false).unwrap();
    let d = compare(&source, &scene, "spheres_instanced.glb");
    eprintln!("spheres_instanced.glb: {d:?}");
    assert!(d.position < 4e-3, "{d:?}");
    assert!(d.normal_degrees < 1.5, "{d:?}");
    assert!(d.uv < 1.0 / 4095.0, "{d:?}");
}

/// An instancing node whose attributes disagree in count, name no accessor or an accessor of
/// the wrong type, hold a rotation that is no rotation, or are missing, is an error naming the
/// node and the attribute.
#[test]
fn inconsistent_instancing_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let name = "spheres_instanced.glb";
    let attributes = "/nodes/0/extensions/EXT_mesh_gpu_instancing/attributes";
    let cases: Vec<(Box<GlbEdit<'_>>, &str)> = vec![
        (
            Box::new(|j, _| {
                let scale = j.pointer(&format!("{attributes}/SCALE")).unwrap().as_u64();
                j["accessors"][scale.unwrap() as usize]["count"] = 5.into();
            }),
            "node 0 (\"\"): EXT_mesh_gpu_instancing: SCALE holds 5 instances, TRANSLATION 6",
        ),
        (
            Box::new(|j, _| *j.pointer_mut(&format!("{attributes}/ROTATION")).unwrap() = 99.into()),
            "EXT_mesh_gpu_instancing: ROTATION names accessor 99, which does not exist",
        ),
        (
            Box::new(|j, _| {
                let rotation = j
                    .pointer(&format!("{attributes}/ROTATION"))
                    .unwrap()
                    .clone();
                *j.pointer_mut(&format!("{attributes}/TRANSLATION")).unwrap() = rotation;
            }),
            "EXT_mesh_gpu_instancing: TRANSLATION accessor",
        ),
        (
            Box::new(|j, _| {
                j["nodes"][0]["extensions"]["EXT_mesh_gpu_instancing"]["attributes"] =
                    serde_json::json!({});
            }),
            "EXT_mesh_gpu_instancing: none of TRANSLATION, ROTATION and SCALE",
        ),
        (
            Box::new(|j, _| {
                j["nodes"][0]["extensions"]["EXT_mesh_gpu_instancing"] = serde_json::json!({});
            }),
            "EXT_mesh_gpu_instancing: no attributes object",
        ),
    ];
    for (edit, want) in cases {
        let e = load_edited(d, name, |j, b| edit(j, b)).unwrap_err();
        assert!(e.contains(name) && e.contains(want), "{want}\n{e}");
    }
    // A zero quaternion: the rotations stored as floats, one of them zero.
    let e = load_edited(d, name, |j, b| {
        let rotation = j
            .pointer(&format!("{attributes}/ROTATION"))
            .unwrap()
            .as_u64()
            .unwrap();
        let view = j["bufferViews"].as_array().unwrap().len();
        let offset = b.len();
        let mut quaternions = [[0.0f32, 0.0, 0.0, 1.0]; 6];
        quaternions[3] = [0.0; 4];
        b.extend(quaternions.iter().flatten().flat_map(|c| c.to_le_bytes()));
        j["bufferViews"]
            .as_array_mut()
            .unwrap()
            .push(serde_json::json!({"buffer": 0, "byteOffset": offset, "byteLength": 96}));
        j["buffers"][0]["byteLength"] = b.len().into();
        let a = &mut j["accessors"][rotation as usize];
        a["bufferView"] = view.into();
        a["componentType"] = 5126.into();
        a["normalized"] = false.into();
    })
    .unwrap_err();
    assert!(
        e.contains("instance 3: rotation [0.0, 0.0, 0.0, 0.0] is not a rotation"),
        "{e}"
    );
}

/// A GLB's JSON and binary chunk.
fn glb_parts(bytes: &[u8]) -> (serde_json::Value, Vec<u8>) {
    let json_length = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let json = serde_json::from_slice(&bytes[20..20 + json_length]).unwrap();
    let bin_start = 20 + json_length;
    let bin_length = u32::from_le_bytes(bytes[bin_start..bin_start + 4].try_into().unwrap());
    let bin = bytes[bin_start + 8..bin_start + 8 + bin_length as usize].to_vec();
    (json, bin)
}

/// A GLB of `json` and `bin`.
fn glb(json: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let mut text = serde_json::to_vec(json).unwrap();
    text.resize(text.len().next_multiple_of(4), b' ');
    let mut bin = bin.to_vec();
    bin.resize(bin.len().next_multiple_of(4), 0);
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// A change to a GLB's JSON and binary chunk.
type GlbEdit<'a> = dyn Fn(&mut serde_json::Value, &mut Vec<u8>) + 'a;

/// Loads fixture `name` changed by `edit` (of its JSON and binary chunk), written to `dir`.
fn load_edited(
    dir: &Path,
    name: &str,
    edit: impl FnOnce(&mut serde_json::Value, &mut Vec<u8>),
) -> Result<Scene, String> {
    let (mut json, mut bin) = glb_parts(&std::fs::read(fixture(name)).unwrap());
    edit(&mut json, &mut bin);
    let path = dir.join(name);
    std::fs::write(&path, glb(&json, &bin)).unwrap();
    Scene::load(&path, false).map_err(|e| e.to_string())
}

/// View `view`'s `EXT_meshopt_compression` object in a GLB's JSON.
fn meshopt(json: &mut serde_json::Value, view: usize) -> &mut serde_json::Value {
    &mut json["bufferViews"][view]["extensions"]["EXT_meshopt_compression"]
}

/// The extension's validity rules that meshoptimizer takes on trust (C `assert`s in a debug
/// build, undefined behaviour otherwise), and bytes that do not decode, are errors naming the
/// buffer view and the property.
#[test]
fn inconsistent_or_corrupt_meshopt_views_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // sphere_gltfpack.glb: view 1 positions (EXPONENTIAL, stride 12), view 2 normals
    // (OCTAHEDRAL, stride 4), view 3 texture coordinates (stride 4), view 5 indices
    // (TRIANGLES, stride 2, 1584); buffer 1 the placeholder.
    let name = "sphere_gltfpack.glb";
    let refusal = |edit: &GlbEdit<'_>| load_edited(d, name, |j, b| edit(j, b)).unwrap_err();
    let cases: Vec<(Box<GlbEdit<'_>>, &str)> = vec![
        (
            Box::new(|j, _| {
                meshopt(j, 5)["count"] = 1582.into();
                j["bufferViews"][5]["byteLength"] = 3164.into();
            }),
            "buffer view 5: EXT_meshopt_compression: count 1582 of mode TRIANGLES is not a multiple of 3",
        ),
        (
            Box::new(|j, _| {
                meshopt(j, 3)["byteStride"] = 6.into();
                j["bufferViews"][3]["byteStride"] = 6.into();
                j["bufferViews"][3]["byteLength"] = 1938.into();
            }),
            "buffer view 3: EXT_meshopt_compression: byteStride 6 of mode ATTRIBUTES is not a multiple of 4",
        ),
        (
            Box::new(|j, _| {
                meshopt(j, 1)["filter"] = "OCTAHEDRAL".into();
            }),
            "buffer view 1: EXT_meshopt_compression: filter OCTAHEDRAL does not take byteStride 12",
        ),
        (
            Box::new(|j, _| {
                meshopt(j, 5)["filter"] = "EXPONENTIAL".into();
            }),
            "filter EXPONENTIAL on mode TRIANGLES (filters apply to ATTRIBUTES only)",
        ),
        (
            Box::new(|j, _| {
                meshopt(j, 5)["mode"] = "STRIPS".into();
            }),
            "buffer view 5: EXT_meshopt_compression: unknown variant `STRIPS`",
        ),
        (
            Box::new(|j, _| {
                meshopt(j, 2)["count"] = 322.into();
            }),
            "count 322 × byteStride 4 is not the buffer view's byteLength 1292",
        ),
        (
            Box::new(|j, _| {
                j["bufferViews"][2]["byteStride"] = 8.into();
            }),
            "byteStride 4 differs from the buffer view's 8",
        ),
        (
            Box::new(|j, _| {
                meshopt(j, 2)["byteOffset"] = 1_000_000.into();
            }),
            "the compressed bytes 1000000..+688 lie outside buffer 0",
        ),
        (
            Box::new(|j, _| {
                j["buffers"][1]["byteLength"] = 100.into();
            }),
            "lie outside buffer 1 (100 bytes)",
        ),
        (
            // The vertex codec's header byte (0xa0 | version) made unknown.
            Box::new(|j, b| {
                let offset = meshopt(j, 2)["byteOffset"].as_u64().unwrap() as usize;
                b[offset] = 0x00;
            }),
            "buffer view 2: EXT_meshopt_compression: the ATTRIBUTES data (688 bytes in buffer 0) \
             do not decode to 323 elements of 4 bytes",
        ),
        (
            Box::new(|j, _| {
                meshopt(j, 5)["byteLength"] = 100.into();
            }),
            "the TRIANGLES data (100 bytes in buffer 0) do not decode to 1584 elements of 2 bytes",
        ),
    ];
    for (edit, want) in cases {
        let e = refusal(&*edit);
        assert!(e.contains(name) && e.contains(want), "{want}\n{e}");
    }
}

/// A Draco primitive whose extension names a missing view or attribute, or whose bitstream is
/// cut short or garbage, is an error naming the primitive.
#[test]
fn inconsistent_or_corrupt_draco_primitives_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let name = "sphere_draco.glb";
    let draco = "/meshes/0/primitives/0/extensions/KHR_draco_mesh_compression";
    let cases: Vec<(Box<GlbEdit<'_>>, &str)> = vec![
        (
            Box::new(|j, _| *j.pointer_mut(&format!("{draco}/bufferView")).unwrap() = 9.into()),
            "mesh 0 primitive 0: KHR_draco_mesh_compression: buffer view 9 does not exist",
        ),
        (
            Box::new(|j, _| {
                *j.pointer_mut(&format!("{draco}/attributes/NORMAL"))
                    .unwrap() = 7.into()
            }),
            "attribute NORMAL: the Draco data have no attribute of unique id 7",
        ),
        (
            Box::new(|j, _| j["accessors"][4]["type"] = "VEC3".into()),
            "attribute COLOR_0: the Draco data have 4 components, accessor 4 (Vec3) takes 3",
        ),
        (
            Box::new(|j, _| j["bufferViews"][1]["byteLength"] = 1000.into()),
            "KHR_draco_mesh_compression: the Draco data (1000 bytes) do not decode",
        ),
        (
            Box::new(|j, b| {
                let offset = j["bufferViews"][1]["byteOffset"].as_u64().unwrap() as usize;
                b[offset..offset + 5].copy_from_slice(b"DRAKO");
            }),
            "KHR_draco_mesh_compression: the Draco data (2366 bytes) do not decode",
        ),
        (
            Box::new(|j, _| j["bufferViews"][1]["byteOffset"] = 100_000.into()),
            "buffer view 1: its bytes 100000..+2366 lie outside buffer 0",
        ),
    ];
    for (edit, want) in cases {
        let e = load_edited(d, name, |j, b| edit(j, b)).unwrap_err();
        assert!(e.contains(name) && e.contains(want), "{want}\n{e}");
    }
}

/// Damage anywhere in the compressed bytes loads or fails with an error, never a panic (the
/// decoders' own checks, the ceilings on what they may produce, and the loader's checks of
/// the decoded values): every 5th byte of the Draco stream, and of meshopt's streams, flipped
/// in turn.
#[test]
fn damaged_compressed_bytes_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for name in [
        "sphere_draco.glb",
        "sphere_draco_sequential.glb",
        "sphere_gltfpack.glb",
    ] {
        let (json, bin) = glb_parts(&std::fs::read(fixture(name)).unwrap());
        // The image is view 0 in every fixture; the rest is geometry.
        let start = json["bufferViews"][0]["byteLength"].as_u64().unwrap() as usize;
        let (mut loaded, mut refused) = (0, 0);
        for at in (start..bin.len()).step_by(5) {
            let result = load_edited(d, name, |_, b| b[at] ^= 0x5a);
            match result {
                Ok(_) => loaded += 1,
                Err(e) => {
                    assert!(e.contains(name), "{e}");
                    refused += 1;
                }
            }
        }
        eprintln!("{name}: {loaded} damaged files loaded, {refused} refused");
        assert!(refused > 0, "{name}: no damage was noticed");
    }
}

/// Every number of the compressed fixtures' JSON (the extensions' offsets, lengths, strides,
/// counts and unique ids, the accessors, views and buffers) replaced by hostile values
/// (0, -1, 2³² − 1, 2⁶⁴ − 1, 1e308, …): each load returns, an error or a scene, and no
/// reader panics ([`loads_without_panic`]).
#[test]
fn mutated_compressed_files_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mutated.glb");
    for name in [
        "sphere_draco.glb",
        "sphere_gltfpack.glb",
        "sphere_gltfpack_khr.glb",
        "spheres_instanced.glb",
    ] {
        let (json, bin) = glb_parts(&std::fs::read(fixture(name)).unwrap());
        let text = serde_json::to_string(&json).unwrap();
        let numbers = number_spans(&text);
        assert!(numbers.len() > 40, "{name}: {}", numbers.len());
        let mut loaded = 0;
        for &(start, end) in &numbers {
            for value in HOSTILE_NUMBERS {
                let mutated = format!("{}{value}{}", &text[..start], &text[end..]);
                let Ok(json) = serde_json::from_str::<serde_json::Value>(&mutated) else {
                    continue;
                };
                std::fs::write(&path, glb(&json, &bin)).unwrap();
                loaded += usize::from(loads_without_panic(&path));
            }
        }
        eprintln!(
            "{name}: {} mutated files, {loaded} loaded",
            numbers.len() * HOSTILE_NUMBERS.len()
        );
    }
}
