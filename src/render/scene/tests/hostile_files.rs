//! Bad, hostile and mutated scene files: each is an error naming the file and the problem,
//! never a panic.

use super::*;
use crate::render::scene::gltf_loader::load_gltf_within;
use crate::render::scene::obj_loader::read_mtl;

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

/// An image without the source glTF requires: in a buffer view but without a `mimeType`, or
/// with neither a `uri` nor a `bufferView` (the `gltf` crate unwraps both; found by
/// fuzz/'s scene target).
#[test]
fn images_without_a_source_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let text = textured_gltf_text(dir.path());
    let image = r#""images":[{"uri":"tex.png"}]"#;
    assert!(text.contains(image));
    for (name, edited, needle) in [
        (
            "view.gltf",
            r#""images":[{"bufferView":0}]"#,
            "image 0 lies in a bufferView but has no mimeType",
        ),
        (
            "none.gltf",
            r#""images":[{"name":"lost"}]"#,
            "image 0 has neither a uri nor a bufferView",
        ),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, text.replacen(image, edited, 1)).unwrap();
        assert_load_fails_naming(&path, needle);
    }
    let typed = dir.path().join("typed.gltf");
    let edited = r#""images":[{"bufferView":0,"mimeType":"image/png"}]"#;
    std::fs::write(&typed, text.replacen(image, edited, 1)).unwrap();
    // The view holds positions, not a PNG: an error about the image, no longer a panic.
    assert_load_fails_naming(&typed, "image 0 (buffer view 0)");
}

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
                 "extensions":{"KHR_texture_transform":{"offset":[0,0],"scale":[1,1],"rotation":0}}}},
             "KHR_materials_sheen":{"sheenColorFactor":[0.5,0.25,1],"sheenRoughnessFactor":0.5}}"#,
    );
    std::fs::write(&path, &extended).unwrap();
    let m = Scene::load(&path, false).expect("the unmutated extended scene loads");
    assert_eq!(m.materials[0].clearcoat, 0.5);
    assert_eq!(m.materials[0].sheen_color, [0.5, 0.25, 1.0]);
    assert!(m.materials[0].textures.clearcoat_normal.is_some());
    for (start, end) in number_spans(&extended) {
        for value in HOSTILE_NUMBERS {
            let mutated = format!("{}{value}{}", &extended[..start], &extended[end..]);
            std::fs::write(&path, mutated).unwrap();
            loads_without_panic(&path);
        }
    }

    // Cameras, perspective and orthographic, rolled and moved: a camera that loads projects
    // to finite clip coordinates.
    let perspective = r#"{"type":"perspective","perspective":{"yfov":0.5,"znear":0.1}}"#;
    let ortho =
        r#"{"type":"orthographic","orthographic":{"xmag":1,"ymag":1,"zfar":10,"znear":0.1}}"#;
    // Node 1, the first camera node, takes camera 0: each kind in turn.
    for (first, second, orthographic) in [(perspective, ortho, false), (ortho, perspective, true)] {
        let scene = text.replace(
            r#""scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],"#,
            &format!(
                r#""scenes":[{{"nodes":[0,1,2]}}],"nodes":[{{"mesh":0}},
                     {{"camera":0,"translation":[0,1,5],"rotation":[0,0,0.38268343,0.9238795]}},
                     {{"camera":1,"translation":[3,0,0],"scale":[1,1,1]}}],
                   "cameras":[{first},{second}],"#
            ),
        );
        assert_ne!(scene, text);
        std::fs::write(&path, &scene).unwrap();
        let s = Scene::load(&path, false).expect("the unmutated camera scene loads");
        assert_eq!(
            matches!(s.camera.projection, Projection::Orthographic { .. }),
            orthographic
        );
        for (start, end) in number_spans(&scene) {
            for value in HOSTILE_NUMBERS {
                let mutated = format!("{}{value}{}", &scene[..start], &scene[end..]);
                std::fs::write(&path, mutated).unwrap();
                if !loads_without_panic(&path) {
                    continue;
                }
                let s = Scene::load(&path, false).unwrap();
                let m = s.camera.view_proj(16.0 / 9.0, 1e-3, 1e4);
                assert!(
                    m.is_finite(),
                    "camera {:?} of a mutated scene projects to {m}",
                    s.camera
                );
            }
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
