//! glTF 2.0 files: geometry, node transforms, materials and their extensions, textures,
//! cameras.

use super::*;
use crate::render::scene::gltf_loader::uv_transform;

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

/// glTF textures load from a data URI or a file beside the scene, once per image, with
/// their sampler's wrap modes and the primitive's TEXCOORD_0; the scene's files include
/// the image file; an image that is missing, corrupt or neither PNG, JPEG nor WebP is an error
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
        ("pic.gif", "not a PNG, JPEG or WebP"),
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
/// 0.04 and F90 1; `KHR_materials_clearcoat` gives the coat's factors and
/// `KHR_materials_sheen` the sheen's; bad values are errors naming the property.
#[test]
fn ior_specular_clearcoat_and_sheen_load_with_their_factors() {
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
    // A sheen's factors (black, none, without the extension).
    assert_eq!((m.sheen_color, m.sheen_roughness), ([0.0; 3], 0.0));
    let m = load(
        r#""KHR_materials_sheen":{"sheenColorFactor":[0.9,0.5,0.25],"sheenRoughnessFactor":0.4}"#,
    )
    .unwrap();
    assert_eq!((m.sheen_color, m.sheen_roughness), ([0.9, 0.5, 0.25], 0.4));
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
        (
            r#""KHR_materials_sheen":{"sheenColorFactor":[1,2,0]}"#,
            "KHR_materials_sheen.sheenColorFactor [1,2,0] is not three numbers in [0, 1]",
        ),
        (
            r#""KHR_materials_sheen":{"sheenRoughnessFactor":1.5}"#,
            "KHR_materials_sheen.sheenRoughnessFactor 1.5 must lie in [0, 1]",
        ),
    ] {
        let e = load(extensions).unwrap_err().to_string();
        assert!(e.contains("shiny.gltf") && e.contains(needle), "{e}");
    }
}

/// A glTF scene's first camera node (by index) is its camera: the eye at the node's world
/// position, looking along its −Z with its +Y up (a rolled camera is drawn rolled), with its
/// vertical field of view or, orthographic, its half-height; a bad field of view or height, or
/// a transform that turns up along the view, is an error naming the node. A camera override
/// replaces the parts given (a field of view makes the camera a perspective one), keeps the
/// camera's up direction, and refuses bad parts.
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
    assert_eq!(s.camera.projection, Projection::Perspective { fov_y: 0.5 });
    assert!((s.camera.up - Vec3::Y).length() < 1e-6);
    let s = load(
        r#"{"camera":1,"translation":[0,1,5]},
           {"camera":0,"translation":[3,0,0],"rotation":[0,0.70710677,0,0.70710677]}"#,
        &format!("{perspective},{ortho}"),
    )
    .unwrap();
    assert_eq!(s.camera.eye, Vec3::new(0.0, 1.0, 5.0));
    assert_eq!(
        s.camera.projection,
        Projection::Orthographic { half_height: 1.0 }
    );
    let ortho_camera = s.camera;
    let s = load(
        r#"{"camera":0,"translation":[3,0,0],"rotation":[0,0.70710677,0,0.70710677]},
           {"camera":0,"translation":[0,0,9],"rotation":[0,0,0.38268343,0.9238795]}"#,
        perspective,
    )
    .unwrap();
    assert!((s.camera.target - s.camera.eye - Vec3::NEG_X).length() < 1e-6);
    // Rolled 45° about its view direction (node 1): its +Y, turned 45° towards −X, is up in
    // the image, and the world's +Y leans to the right.
    let s = load(
        r#"{"camera":0,"translation":[0,0,9],"rotation":[0,0,0.38268343,0.9238795]},
           {"translation":[0,0,0]}"#,
        perspective,
    )
    .unwrap();
    assert!((s.camera.target - s.camera.eye - Vec3::NEG_Z).length() < 1e-6);
    let half = std::f32::consts::FRAC_1_SQRT_2;
    assert!((s.camera.up - Vec3::new(-half, half, 0.0)).length() < 1e-6);
    let m = s.camera.view_proj(1.0, 0.1, 100.0);
    let along_up = m.project_point3(s.camera.target + 0.1 * s.camera.up);
    assert!(along_up.x.abs() < 1e-5 && along_up.y > 0.01, "{along_up}");
    let world_up = m.project_point3(s.camera.target + 0.1 * Vec3::Y);
    assert!(world_up.x > 0.01 && world_up.y > 0.01, "{world_up}");
    let rolled_camera = s.camera;
    for (camera, needle) in [
        (
            r#"{"type":"perspective","perspective":{"yfov":4,"znear":0.1}}"#,
            "yfov 4",
        ),
        (
            r#"{"type":"orthographic","orthographic":{"xmag":1,"ymag":0,"zfar":10,"znear":0.1}}"#,
            "ymag 0 is not a positive height",
        ),
    ] {
        let e = load(
            r#"{"camera":0,"translation":[0,1,5]},{"translation":[0,0,0]}"#,
            camera,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("camera.gltf") && e.contains("camera node 1") && e.contains(needle),
            "{e}"
        );
    }
    // +Y mapped onto −Z: up along the view.
    let e = load(
        r#"{"camera":0,"matrix":[1,0,0,0, 0,0,-1,0, 0,0,1,0, 0,0,0,1]},{"translation":[0,0,0]}"#,
        perspective,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("camera node 1") && e.contains("turns its up direction (+Y) along its view"),
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
    assert_eq!(
        moved.projection,
        Projection::Perspective {
            fov_y: 30f32.to_radians()
        }
    );
    let widened = CameraOverride {
        fov_deg: Some(50.0),
        ..Default::default()
    }
    .apply(ortho_camera)
    .unwrap();
    assert_eq!(
        widened.projection,
        Projection::Perspective {
            fov_y: 50f32.to_radians()
        }
    );
    let turned = CameraOverride {
        look_at: Some(Vec3::new(1.0, 0.0, 0.0)),
        ..Default::default()
    }
    .apply(rolled_camera)
    .unwrap();
    assert_eq!(turned.up, rolled_camera.up);
    let plan = CameraOverride {
        ortho_height: Some(3.0),
        ..Default::default()
    }
    .apply(camera)
    .unwrap();
    assert_eq!(
        plan.projection,
        Projection::Orthographic { half_height: 1.5 }
    );
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
                ortho_height: Some(-1.0),
                ..Default::default()
            },
            "orthographic height -1 is not a positive number",
        ),
        (
            CameraOverride {
                fov_deg: Some(30.0),
                ortho_height: Some(1.0),
                ..Default::default()
            },
            "exclude each other",
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
        close(&tangents[0], &[1.0, 0.0, 0.0, 1.0]) && close(&tangents[2], &[1.0, 0.0, 0.0, -1.0]),
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

/// A texture's `EXT_texture_webp` image is the one drawn, whether its core `source` is a PNG
/// fallback or absent (the extension then required); a WebP source that names no image, or
/// the extension without a source, is an error naming the texture.
#[test]
fn webp_textures_are_drawn_in_place_of_their_fallback() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let text = textured_gltf_text(d);
    // The PNG's texels swapped: blue, then red.
    let mut webp = Vec::new();
    image::codecs::webp::WebPEncoder::new_lossless(&mut webp)
        .encode(
            &[0, 0, 255, 255, 255, 0, 0, 255],
            2,
            1,
            image::ExtendedColorType::Rgba8,
        )
        .unwrap();
    std::fs::write(d.join("tex.webp"), &webp).unwrap();
    let text = text.replace(
        r#""images":[{"uri":"tex.png"}]"#,
        r#""images":[{"uri":"tex.png"},{"uri":"tex.webp"}]"#,
    );
    let p = d.join("webp.gltf");
    let load = |texture: &str, required: bool| {
        let mut file = text.replace(r#""textures":[{"source":0,"sampler":0}]"#, texture);
        if required {
            file = file.replacen(
                "{",
                r#"{"extensionsUsed":["EXT_texture_webp"],"extensionsRequired":["EXT_texture_webp"],"#,
                1,
            );
        }
        std::fs::write(&p, file).unwrap();
        Scene::load(&p, false).map_err(|e| e.to_string())
    };
    for (texture, required) in [
        (
            r#""textures":[{"source":0,"sampler":0,"extensions":{"EXT_texture_webp":{"source":1}}}]"#,
            false,
        ),
        (
            r#""textures":[{"sampler":0,"extensions":{"EXT_texture_webp":{"source":1}}}]"#,
            true,
        ),
    ] {
        let s = load(texture, required).unwrap();
        assert_eq!(s.textures.len(), 1, "{texture}");
        assert_eq!(
            s.textures[0].rgba,
            [0, 0, 255, 255, 255, 0, 0, 255],
            "{texture}"
        );
    }
    for (texture, want) in [
        (
            r#""textures":[{"source":0,"sampler":0,"extensions":{"EXT_texture_webp":{"source":5}}}]"#,
            "texture 0: EXT_texture_webp.source 5 is not one of the file's 2 images",
        ),
        (
            r#""textures":[{"source":0,"sampler":0,"extensions":{"EXT_texture_webp":{}}}]"#,
            "texture 0: EXT_texture_webp has no source",
        ),
    ] {
        let e = load(texture, false).unwrap_err();
        assert!(e.contains("webp.gltf") && e.contains(want), "{want}\n{e}");
    }
}

/// A file may require the extensions the renderer draws (the `gltf` crate refused them,
/// none of its features being enabled), and `KHR_materials_unlit` makes its material unlit;
/// another required extension is an error naming it.
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
            r#"["KHR_texture_transform","KHR_materials_emissive_strength","KHR_materials_ior","KHR_materials_specular","KHR_materials_clearcoat","KHR_draco_mesh_compression","EXT_meshopt_compression","KHR_meshopt_compression","EXT_texture_webp","KHR_materials_unlit"]"#,
        ),
    )
    .unwrap();
    assert!(!Scene::load(&p, false).unwrap().materials[0].unlit);
    // KHR_materials_unlit on the material makes it unlit.
    std::fs::write(
        &p,
        requiring(r#"["KHR_materials_unlit"]"#).replace(
            r#""normalTexture":{"index":0}"#,
            r#""normalTexture":{"index":0},"extensions":{"KHR_materials_unlit":{}}"#,
        ),
    )
    .unwrap();
    assert!(Scene::load(&p, false).unwrap().materials[0].unlit);
    std::fs::write(&p, requiring(r#"["KHR_texture_basisu"]"#)).unwrap();
    let e = Scene::load(&p, false).unwrap_err().to_string();
    assert!(
        e.contains("required.gltf") && e.contains("requires extension KHR_texture_basisu"),
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
    let only_second = r#""pbrMetallicRoughness":{"baseColorTexture":{"index":0,"texCoord":1}}}],"#;
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
