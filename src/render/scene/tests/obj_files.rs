//! Wavefront OBJ files and their MTL materials.

use super::*;
use crate::render::scene::obj_loader::{scan_obj, strip_trailing_comments, ObjScan};

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
    let s =
        load("newmtl t\nKd 1 1 1\nKe 2 1 0.5\nmap_Ke tex.png\nmap_Kd tex.png\nmap_d mask.png\n")
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
    let text = "o part#2\nv 0 0 0 # origin\nv 1 0 0\nv 0 1 0#up\n  f 1 2 3 # front\nusemtl a#b\n";
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
