//! Animated glTF files: clips played on the scene's nodes, their meshes and children moved,
//! bounds that hold every pose, and bad keyframes refused naming the animation and channel.

use super::*;

/// One channel of a test clip: node, `path` (translation, rotation, scale), interpolation,
/// key times and values (3 or 4 numbers each, three per key for CUBICSPLINE).
struct Keys<'a> {
    node: usize,
    path: &'a str,
    interpolation: &'a str,
    times: Vec<f32>,
    values: Vec<f32>,
}

/// A glTF of [`write_gltf`]'s one triangle, drawn by `nodes` (the scene's roots `roots`), with
/// the clips `clips` (name, channels), their keys in a second buffer.
fn animated_gltf(
    dir: &Path,
    name: &str,
    nodes: &str,
    roots: &str,
    clips: &[(&str, Vec<Keys>)],
) -> PathBuf {
    let triangle = write_gltf(dir, name, nodes, [3, 3, 3], "[0.5,0.5,0.5,1]");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&triangle).unwrap()).unwrap();
    json["scenes"][0]["nodes"] = serde_json::from_str(roots).unwrap();
    let mut data: Vec<u8> = Vec::new();
    let mut accessors = json["accessors"].as_array().unwrap().clone();
    let mut views = json["bufferViews"].as_array().unwrap().clone();
    // Adds `floats` as an accessor of `kind` over a view of its own; returns its index.
    let mut add = |floats: &[f32], kind: &str, width: usize| {
        let offset = data.len();
        data.extend(floats.iter().flat_map(|f| f.to_le_bytes()));
        views.push(serde_json::json!({"buffer": 1, "byteOffset": offset,
            "byteLength": 4 * floats.len()}));
        accessors.push(serde_json::json!({"bufferView": views.len() - 1,
            "componentType": 5126, "count": floats.len() / width, "type": kind}));
        accessors.len() - 1
    };
    let mut animations = Vec::new();
    for (clip, channels) in clips {
        let (mut samplers, mut targets) = (Vec::new(), Vec::new());
        for keys in channels {
            let input = add(&keys.times, "SCALAR", 1);
            let (kind, width) = if keys.path == "rotation" {
                ("VEC4", 4)
            } else {
                ("VEC3", 3)
            };
            let output = add(&keys.values, kind, width);
            samplers.push(serde_json::json!({"input": input, "output": output,
                "interpolation": keys.interpolation}));
            targets.push(serde_json::json!({"sampler": samplers.len() - 1,
                "target": {"node": keys.node, "path": keys.path}}));
        }
        animations.push(serde_json::json!({"name": clip, "channels": targets,
            "samplers": samplers}));
    }
    json["accessors"] = accessors.into();
    json["bufferViews"] = views.into();
    json["animations"] = animations.into();
    json["buffers"]
        .as_array_mut()
        .unwrap()
        .push(serde_json::json!({
            "byteLength": data.len(),
            "uri": format!("data:application/octet-stream;base64,{}", base64_encode(&data)),
        }));
    std::fs::write(&triangle, serde_json::to_string(&json).unwrap()).unwrap();
    triangle
}

/// The quaternion (x, y, z, w) of `degrees` about +z.
fn about_z(degrees: f32) -> [f32; 4] {
    glam::Quat::from_rotation_z(degrees.to_radians()).to_array()
}

/// A parent sliding 4 units along +x over 2 s, with a child that snaps a quarter turn
/// about z at 1 s, and a still node beside them: clip "slide".
fn sliding_parent(dir: &Path) -> PathBuf {
    let keys = vec![
        Keys {
            node: 0,
            path: "translation",
            interpolation: "LINEAR",
            times: vec![0.0, 2.0],
            values: vec![0.0, 0.0, 0.0, 4.0, 0.0, 0.0],
        },
        Keys {
            node: 1,
            path: "rotation",
            interpolation: "STEP",
            times: vec![0.0, 1.0],
            values: [about_z(0.0), about_z(90.0)].concat(),
        },
    ];
    animated_gltf(
        dir,
        "slide.gltf",
        r#"[{"name":"parent","children":[1]},{"name":"child","mesh":0,"translation":[0,1,0]},
            {"name":"still","mesh":0,"translation":[5,0,0]}]"#,
        "[0,2]",
        &[("slide", keys)],
    )
}

/// Where vertex `k` of the animated piece lies after [`Scene::animate`] at `t`.
fn posed(scene: &mut Scene, t: f64, k: usize) -> Vec3 {
    scene.animate(t);
    let first = scene.animation.as_ref().unwrap().pieces[0].first_vertex;
    Vec3::from_array(scene.vertices[first + k].position)
}

#[test]
fn animated_nodes_move_their_meshes_and_their_children() {
    let dir = tempfile::tempdir().unwrap();
    let mut scene = Scene::load(&sliding_parent(dir.path()), false).unwrap();
    let animation = scene.animation.as_ref().unwrap();
    // The child is moved (through its parent); the still node is not.
    assert_eq!(animation.pieces.len(), 1);
    assert_eq!(animation.pieces[0].node, 1);
    assert_eq!(scene.playing_animation(), Some((0, "slide", 2.0)));
    let still: Vec<Vertex> = (scene.vertices.iter())
        .filter(|v| v.position[0] >= 5.0)
        .copied()
        .collect();
    assert_eq!(still.len(), 3);
    // Vertex 1 is (1, 0, 0) in the mesh; the child stands 1 up in its parent.
    let close = |a: Vec3, b: Vec3| a.distance(b) < 1e-5;
    let at = posed(&mut scene, 0.5, 1);
    assert!(close(at, Vec3::new(2.0, 1.0, 0.0)), "{at}");
    // At 1.5 s the parent is 3 along and the child turned: (1, 0, 0) → (0, 1, 0).
    let at = posed(&mut scene, 1.5, 1);
    assert!(close(at, Vec3::new(3.0, 2.0, 0.0)), "{at}");
    let first = scene.animation.as_ref().unwrap().pieces[0].first_vertex;
    // The triangle's normal (+z) is along the axis of the turn.
    let normal = Vec3::from_array(scene.vertices[first].normal);
    assert!(close(normal, Vec3::Z), "{normal}");
    // The clip loops; negative times too.
    assert!(close(posed(&mut scene, 3.5, 1), at));
    assert!(close(posed(&mut scene, -0.5, 1), at));
    // The still node never moved.
    let now: Vec<Vertex> = (scene.vertices.iter())
        .filter(|v| v.position[0] >= 5.0)
        .copied()
        .collect();
    assert_eq!(now, still);
    // No clip: the rest pose, whatever the time.
    scene.select_animation(&AnimationChoice::None).unwrap();
    assert_eq!(scene.playing_animation(), None);
    let rest = posed(&mut scene, 1.5, 1);
    assert!(close(rest, Vec3::new(1.0, 1.0, 0.0)), "{rest}");
    // By name or index; an absent one is refused, naming those there are.
    scene
        .select_animation(&AnimationChoice::Name("slide".into()))
        .unwrap();
    assert!(close(posed(&mut scene, 1.5, 1), at));
    for (choice, needle) in [
        (
            AnimationChoice::Index(1),
            "no animation 1: it has 0 \"slide\"",
        ),
        (
            AnimationChoice::Name("run".into()),
            "no animation named \"run\": it has 0 \"slide\"",
        ),
    ] {
        let e = scene.select_animation(&choice).unwrap_err();
        assert!(e.contains(needle), "{e}");
    }
    // A still scene takes the default and `none`; a clip by index is refused.
    let p = write_gltf(
        dir.path(),
        "still.gltf",
        r#"[{"mesh":0}]"#,
        [3, 3, 3],
        "[1,1,1,1]",
    );
    let mut still = Scene::load(&p, false).unwrap();
    assert!(still.animation.is_none());
    assert!(!still.animate(1.0));
    still.select_animation(&AnimationChoice::First).unwrap();
    still.select_animation(&AnimationChoice::None).unwrap();
    let e = still
        .select_animation(&AnimationChoice::Index(0))
        .unwrap_err();
    assert!(e.contains("it has none"), "{e}");
}

/// The shadow maps are fitted to the casters' bounds once: every pose of the clip lies within
/// them, and the ground lies under the lowest pose.
#[test]
fn bounds_hold_every_pose_and_the_ground_lies_under_the_lowest() {
    let dir = tempfile::tempdir().unwrap();
    let bounce = vec![Keys {
        node: 0,
        path: "translation",
        interpolation: "LINEAR",
        times: vec![0.0, 1.0, 2.0],
        values: vec![0.0, 0.0, 0.0, 0.0, -3.0, 0.0, 0.0, 0.0, 0.0],
    }];
    let spin = vec![Keys {
        node: 0,
        path: "rotation",
        interpolation: "LINEAR",
        times: vec![0.0, 1.0, 2.0, 3.0, 4.0],
        values: [0.0, 90.0, 180.0, 270.0, 360.0].map(about_z).concat(),
    }];
    let p = animated_gltf(
        dir.path(),
        "bounce.gltf",
        r#"[{"mesh":0}]"#,
        "[0]",
        &[("bounce", bounce), ("spin", spin)],
    );
    let mut scene = Scene::load(&p, true).unwrap();
    let ground = scene.vertices.len() - 4;
    for v in &scene.vertices[ground..] {
        assert!((v.position[1] - -3.0).abs() < 1e-6, "{:?}", v.position);
    }
    let bounds = scene.bounds;
    for clip in ["bounce", "spin"] {
        scene
            .select_animation(&AnimationChoice::Name(clip.into()))
            .unwrap();
        for step in 0..=400 {
            scene.animate(f64::from(step) * 0.01);
            for v in &scene.vertices[..ground] {
                let d = Vec3::from_array(v.position).distance(bounds.center);
                assert!(d <= bounds.radius * (1.0 + 1e-5), "{clip} at {step}: {d}");
            }
            assert_eq!(scene.bounds, bounds, "{clip} at {step}");
        }
    }
}

#[test]
fn animations_with_bad_keys_are_refused_naming_the_channel() {
    let dir = tempfile::tempdir().unwrap();
    let translation = |interpolation, times: Vec<f32>, values: Vec<f32>| Keys {
        node: 0,
        path: "translation",
        interpolation,
        times,
        values,
    };
    let cases = [
        (
            translation("LINEAR", vec![1.0, 0.0], vec![0.0; 6]),
            "key times decrease (1 then 0)",
        ),
        (
            translation("LINEAR", vec![0.0, f32::NAN], vec![0.0; 6]),
            "key time NaN is not a finite number",
        ),
        (
            translation("LINEAR", vec![0.0, 1.0], vec![0.0; 9]),
            "3 values for 2 key times",
        ),
        (
            translation("CUBICSPLINE", vec![0.0, 1.0], vec![0.0; 6]),
            "2 values for 2 key times (3 a key with CubicSpline interpolation)",
        ),
        (
            translation(
                "STEP",
                vec![0.0, 1.0],
                vec![0.0, 0.0, 0.0, f32::INFINITY, 0.0, 0.0],
            ),
            "value [inf, 0, 0] is not finite",
        ),
        (
            Keys {
                node: 0,
                path: "rotation",
                interpolation: "LINEAR",
                times: vec![0.0, 1.0],
                values: vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            },
            "rotation [0, 0, 0, 0] is not a rotation",
        ),
    ];
    for (i, (keys, needle)) in cases.into_iter().enumerate() {
        let p = animated_gltf(
            dir.path(),
            &format!("bad{i}.gltf"),
            r#"[{"mesh":0}]"#,
            "[0]",
            &[("walk", vec![keys])],
        );
        assert_load_fails_naming(&p, &format!("animation 0 (\"walk\") channel 0: {needle}"));
    }
    // Accessors are checked before they are read: values past their view, times of ints.
    let p = sliding_parent(dir.path());
    let text = std::fs::read_to_string(&p).unwrap();
    fails_when_edited(
        &p,
        &text,
        |json| json["accessors"][4]["count"] = 3.into(),
        "channel 0: its values: accessor 4: 3 elements of 12 bytes",
    );
    fails_when_edited(
        &p,
        &text,
        |json| json["accessors"][3]["componentType"] = 5125.into(),
        "channel 0: its key times: accessor 3 has component type U32",
    );
}

/// `text` (a glTF's JSON) edited by `edit` and written to `path` fails to load, naming the
/// file and `needle`.
fn fails_when_edited(
    path: &Path,
    text: &str,
    edit: impl FnOnce(&mut serde_json::Value),
    needle: &str,
) {
    let mut json: serde_json::Value = serde_json::from_str(text).unwrap();
    edit(&mut json);
    std::fs::write(path, json.to_string()).unwrap();
    assert_load_fails_naming(path, needle);
}

/// Every number of an animated file's JSON (a node animation, and the skinned arm) replaced by
/// hostile values: each load returns, and a scene that loads plays its clip at any time
/// without a panic.
#[test]
fn mutated_animated_files_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mutated.gltf");
    let sources = [
        sliding_parent(dir.path()),
        fixture("bending_arm.gltf"),
        fixture("morphing_tent.gltf"),
    ];
    for source in sources {
        let text = std::fs::read_to_string(&source).unwrap();
        let numbers = number_spans(&text);
        assert!(numbers.len() > 40, "{}", numbers.len());
        let mut played = 0;
        for &(start, end) in &numbers {
            for value in HOSTILE_NUMBERS {
                let mutated = format!("{}{value}{}", &text[..start], &text[end..]);
                std::fs::write(&path, mutated).unwrap();
                if !loads_without_panic(&path) {
                    continue;
                }
                let Ok(mut scene) = Scene::load(&path, true) else {
                    continue;
                };
                for t in [-1.0, 0.0, 0.5, 1.0, 1e9, f64::NAN, f64::INFINITY] {
                    scene.animate(t);
                }
                played += 1;
            }
        }
        assert!(played > 100, "{}: {played}", source.display());
    }
}

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/animated")
        .join(name)
}

/// The fixtures of tests/data/animated: the animated boxes at 1 s of clip "turn" are the
/// still file of that pose, vertex for vertex — and so, within its quantisation, is the file
/// gltfpack made of them (positions of 14 bits, rotations as normalised 16-bit integers, keys
/// resampled at 30 a second, all meshopt-compressed). Clip "hop" (a cubic spline with flat
/// tangents) lifts the top box half way at a quarter of its second.
#[test]
fn fixtures_play_as_their_still_pose_and_tools_files_too() {
    let still = Scene::load(&fixture("turned_boxes.gltf"), false).unwrap();
    let mut turning = Scene::load(&fixture("turning_boxes.gltf"), false).unwrap();
    assert_eq!(turning.animation_names(), ["turn", "hop"]);
    turning.animate(1.0);
    assert_eq!(turning.vertices.len(), still.vertices.len());
    for (a, b) in turning.vertices.iter().zip(&still.vertices) {
        let (pa, pb) = (Vec3::from_array(a.position), Vec3::from_array(b.position));
        let (na, nb) = (Vec3::from_array(a.normal), Vec3::from_array(b.normal));
        assert!(
            pa.distance(pb) < 1e-5 && na.distance(nb) < 1e-5,
            "{pa} {pb}"
        );
    }
    let mut packed = Scene::load(&fixture("turning_boxes_gltfpack.glb"), false).unwrap();
    assert_eq!(packed.animation_names(), ["turn", "hop"]);
    packed.animate(1.0);
    // Every vertex near one of the still file's with the same normal, and back.
    let near = |from: &Scene, to: &Scene| {
        from.vertices.iter().all(|a| {
            to.vertices.iter().any(|b| {
                let d = Vec3::from_array(a.position).distance(Vec3::from_array(b.position));
                let n = Vec3::from_array(a.normal).distance(Vec3::from_array(b.normal));
                d < 2e-3 && n < 1e-2
            })
        })
    };
    assert!(near(&packed, &still) && near(&still, &packed));
    for scene in [&mut turning, &mut packed] {
        scene
            .select_animation(&AnimationChoice::Name("hop".into()))
            .unwrap();
        for (t, height) in [(0.0, 1.25), (0.25, 1.75), (0.5, 2.25), (1.25, 1.75)] {
            scene.animate(t);
            let top: Vec<f32> = (scene.vertices.iter())
                .map(|v| v.position[1])
                .filter(|&y| y > 0.52)
                .collect();
            assert_eq!(top.len(), 24, "at {t}");
            let mean = top.iter().sum::<f32>() / 24.0;
            assert!((mean - height).abs() < 5e-3, "at {t}: {mean}");
        }
    }
}

/// tests/data/animated/bending_arm.gltf (make_skinned.py): a column skinned to a shoulder and
/// an elbow, its node's own translation (5, 0, 0) ignored as glTF defines. At rest it stands
/// as modelled; at the end of clip "bend" (the elbow turned 90° about +z) its top ring has
/// swung to x = −1 and its middle ring, half on each joint, lies half way. gltfpack's file of
/// it (positions quantised with the dequantisation folded into the inverse bind matrices,
/// weights as normalised bytes, meshopt) bends the same within its quantisation.
#[test]
fn skinned_meshes_bend_with_their_joints() {
    let tolerance = [1e-5, 2e-3];
    for (file, tolerance) in ["bending_arm.gltf", "bending_arm_gltfpack.glb"]
        .into_iter()
        .zip(tolerance)
    {
        let mut scene = Scene::load(&fixture(file), false).unwrap();
        let modelled: Vec<Vec3> = (scene.vertices.iter())
            .map(|v| Vec3::from_array(v.position))
            .collect();
        assert_eq!(modelled.len(), 24, "{file}");
        // At rest: as modelled, at the origin (not at the node's x = 5).
        for p in &modelled {
            assert!(
                p.x.abs() <= 0.25 + tolerance && p.y >= -tolerance,
                "{file}: {p}"
            );
        }
        scene.animate(1.0 - 1e-6);
        for (v, rest) in scene.vertices.iter().zip(&modelled) {
            let p = Vec3::from_array(v.position);
            let (x, ring, z) = (rest.x, rest.y.round(), rest.z);
            let expected = match ring as i32 {
                0 => *rest,
                1 => Vec3::new(x / 2.0, 1.0 + x / 2.0, z),
                _ => Vec3::new(-1.0, 1.0 + x, z),
            };
            assert!(
                p.distance(expected) < tolerance,
                "{file}: {rest} went to {p}, not {expected}"
            );
            // The top ring's normals turned with it: +x became +y.
            let n = Vec3::from_array(v.normal);
            if ring == 2.0 && x > 0.2 && z.abs() < 0.2 {
                assert!(n.distance(Vec3::Y) < 1e-2, "{file}: {n}");
            }
        }
    }
    // A JOINTS_0 past the skin's joints, and weights of a type glTF does not allow, are named.
    let text = std::fs::read_to_string(fixture("bending_arm.gltf")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("arm.gltf");
    let one_joint = |json: &mut serde_json::Value| {
        json["skins"][0]["joints"] = serde_json::json!([1]);
        let skin = json["skins"][0].as_object_mut().unwrap();
        skin.remove("inverseBindMatrices");
    };
    fails_when_edited(
        &path,
        &text,
        one_joint,
        "vertex 2's JOINTS_0 names joint 1, past its skin's 1",
    );
    fails_when_edited(
        &path,
        &text,
        |json| json["accessors"][3]["componentType"] = 5125.into(),
        "WEIGHTS_0 accessor 3 has component type U32",
    );
}

/// The bending arm with its influences split over two sets (`JOINTS_1`/`WEIGHTS_1`: the top
/// ring's elbow and half the middle ring's in the second set, the rest in the first) bends as
/// the file with one set does; a `JOINTS_1` without its `WEIGHTS_1` is named.
#[test]
fn a_second_set_of_influences_weighs_in() {
    let text = std::fs::read_to_string(fixture("bending_arm.gltf")).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
    // The fixture's vertices: per side, rings 0, 1 and 2 of two vertices each.
    let (mut data, mut sets): (Vec<u8>, [Vec<u8>; 2]) = (Vec::new(), Default::default());
    let mut set_weights: [Vec<f32>; 2] = Default::default();
    for v in 0..24 {
        let (first, second) = match (v % 6) / 2 {
            0 => (1.0, 0.0),
            1 => (0.5, 0.5),
            _ => (0.0, 1.0),
        };
        sets[0].extend([0, 0, 0, 0]);
        sets[1].extend([1, 0, 0, 0]);
        set_weights[0].extend([first, 0.0, 0.0, 0.0]);
        set_weights[1].extend([second, 0.0, 0.0, 0.0]);
    }
    let mut accessors = json["accessors"].as_array().unwrap().clone();
    let mut views = json["bufferViews"].as_array().unwrap().clone();
    let mut add = |bytes: &[u8], component: u32| {
        let offset = data.len();
        data.extend_from_slice(bytes);
        views.push(serde_json::json!({"buffer": 1, "byteOffset": offset,
            "byteLength": bytes.len()}));
        accessors.push(serde_json::json!({"bufferView": views.len() - 1,
            "componentType": component, "count": 24, "type": "VEC4"}));
        accessors.len() - 1
    };
    let floats = |w: &[f32]| w.iter().flat_map(|f| f.to_le_bytes()).collect::<Vec<u8>>();
    let joints_0 = add(&sets[0], 5121);
    let weights_0 = add(&floats(&set_weights[0]), 5126);
    let joints_1 = add(&sets[1], 5121);
    let weights_1 = add(&floats(&set_weights[1]), 5126);
    json["accessors"] = accessors.into();
    json["bufferViews"] = views.into();
    json["buffers"]
        .as_array_mut()
        .unwrap()
        .push(serde_json::json!({"byteLength": data.len(),
            "uri": format!("data:application/octet-stream;base64,{}", base64_encode(&data))}));
    let attributes = &mut json["meshes"][0]["primitives"][0]["attributes"];
    attributes["JOINTS_0"] = joints_0.into();
    attributes["WEIGHTS_0"] = weights_0.into();
    attributes["JOINTS_1"] = joints_1.into();
    attributes["WEIGHTS_1"] = weights_1.into();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two_sets.gltf");
    std::fs::write(&path, json.to_string()).unwrap();
    let mut one = Scene::load(&fixture("bending_arm.gltf"), false).unwrap();
    let mut two = Scene::load(&path, false).unwrap();
    for t in [0.0, 0.5, 1.0 - 1e-6] {
        one.animate(t);
        two.animate(t);
        for (a, b) in one.vertices.iter().zip(&two.vertices) {
            let (pa, pb) = (Vec3::from_array(a.position), Vec3::from_array(b.position));
            assert!(pa.distance(pb) < 1e-5, "at {t}: {pa} and {pb}");
        }
    }
    // The bend is there (the top ring far from where it stood).
    let top = |scene: &Scene| {
        (scene.vertices.iter())
            .map(|v| v.position[0])
            .fold(0.0, f32::min)
    };
    assert!(top(&two) < -0.9, "{}", top(&two));
    let text = json.to_string();
    fails_when_edited(
        &path,
        &text,
        |json| {
            let attributes = &mut json["meshes"][0]["primitives"][0]["attributes"];
            attributes.as_object_mut().unwrap().remove("WEIGHTS_1");
        },
        "only one of JOINTS_1 and WEIGHTS_1",
    );
}

/// `KHR_animation_pointer` channels (Blender and three.js write them): those pointing at a
/// node's translation, rotation, scale or weights play as core channels — the boxes and the
/// tent with every channel so written pose as the files with core channels, a `.glb` (its JSON
/// chunk rewritten) too — and one pointing at anything else (a camera's field of view) is left
/// out while the rest plays. Without this such a file failed to load ("missing field `node`").
#[test]
fn animation_pointers_to_nodes_play_as_core_channels() {
    // `channel` rewritten as a pointer channel to the same node and path.
    fn as_pointer(channel: &mut serde_json::Value) {
        let node = channel["target"]["node"].as_u64().unwrap();
        let path = channel["target"]["path"].as_str().unwrap().to_string();
        channel["target"] = serde_json::json!({"path": "pointer", "extensions":
            {"KHR_animation_pointer": {"pointer": format!("/nodes/{node}/{path}")}}});
    }
    let pointered = |json: &mut serde_json::Value| {
        for animation in json["animations"].as_array_mut().unwrap() {
            animation["channels"]
                .as_array_mut()
                .unwrap()
                .iter_mut()
                .for_each(as_pointer);
        }
        json["extensionsUsed"] = serde_json::json!(["KHR_animation_pointer"]);
    };
    let dir = tempfile::tempdir().unwrap();
    for (file, t) in [("turning_boxes.gltf", 1.0), ("morphing_tent.gltf", 1.5)] {
        let text = std::fs::read_to_string(fixture(file)).unwrap();
        let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
        pointered(&mut json);
        // And a pointer at something else, left out.
        let yfov = serde_json::json!({"sampler": 0, "target": {"path": "pointer", "extensions":
            {"KHR_animation_pointer": {"pointer": "/cameras/0/perspective/yfov"}}}});
        json["animations"][0]["channels"]
            .as_array_mut()
            .unwrap()
            .push(yfov);
        let path = dir.path().join(file);
        std::fs::write(&path, json.to_string()).unwrap();
        let mut core = Scene::load(&fixture(file), false).unwrap();
        let mut pointer = Scene::load(&path, false).unwrap();
        assert_eq!(pointer.animation_names(), core.animation_names());
        core.animate(t);
        pointer.animate(t);
        assert_eq!(pointer.vertices, core.vertices, "{file}");
        assert!(pointer.animate(t + 0.1), "{file}: the clip plays");
    }
    // The packed boxes (a .glb) with pointer channels: its JSON chunk is rewritten.
    let bytes = std::fs::read(fixture("turning_boxes_gltfpack.glb")).unwrap();
    let json_length = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let mut json: serde_json::Value = serde_json::from_slice(&bytes[20..20 + json_length]).unwrap();
    pointered(&mut json);
    let mut chunk = json.to_string().into_bytes();
    while !chunk.len().is_multiple_of(4) {
        chunk.push(b' ');
    }
    let rest = &bytes[20 + json_length..];
    let mut glb = bytes[..8].to_vec();
    glb.extend(((20 + chunk.len() + rest.len()) as u32).to_le_bytes());
    glb.extend((chunk.len() as u32).to_le_bytes());
    glb.extend(b"JSON");
    glb.extend(&chunk);
    glb.extend(rest);
    let path = dir.path().join("packed.glb");
    std::fs::write(&path, glb).unwrap();
    let mut core = Scene::load(&fixture("turning_boxes_gltfpack.glb"), false).unwrap();
    let mut pointer = Scene::load(&path, false).unwrap();
    core.animate(1.0);
    pointer.animate(1.0);
    assert_eq!(pointer.vertices, core.vertices);
    // A pointer channel without its pointer is named.
    let text = std::fs::read_to_string(fixture("turning_boxes.gltf")).unwrap();
    fails_when_edited(
        &dir.path().join("bad.gltf"),
        &text,
        |json| {
            pointered(json);
            json["animations"][0]["channels"][1]["target"]["extensions"] = serde_json::json!({});
        },
        "animation 0 channel 1: its target path is \"pointer\" but it has no \
         KHR_animation_pointer pointer string",
    );
}

/// tests/data/animated/morphing_tent.gltf (make_morphed.py): one mesh with two morph targets
/// (a sparse one lifting the centre vertex, a ramp with normal displacements) drawn by a node
/// whose weights clip "rise" drives and by one whose own weights [0.5, 1] hold. Loaded, the
/// posed node stands as its weights shape it and the animated one flat (its mesh's weights);
/// at 1.5 s of "rise" both are the vertices and normals that the script baked into
/// morphed_tent.gltf; the STEP clip "blink" jumps at 0.5 s. gltfpack's file of it (positions
/// and displacements as 16-bit integers, normals as normalised bytes, the weights as
/// normalised bytes resampled at 30 keys a second) plays the same within its quantisation.
#[test]
fn morph_targets_shape_meshes_by_their_weights() {
    let still = Scene::load(&fixture("morphed_tent.gltf"), false).unwrap();
    assert_eq!(still.vertices.len(), 50);
    // Every vertex of `a` at the one of `b` with the same index (`near`) or near one of
    // them, and back (the packed file orders its vertices as it likes).
    let same = |a: &Scene, b: &Scene, what: &str, tolerance: [f32; 2]| {
        let close = |u: &Vertex, v: &Vertex| {
            let d = Vec3::from_array(u.position).distance(Vec3::from_array(v.position));
            let n = Vec3::from_array(u.normal).distance(Vec3::from_array(v.normal));
            d < tolerance[0] && n < tolerance[1]
        };
        let near = |from: &Scene, to: &Scene| {
            (from.vertices.iter()).all(|u| to.vertices.iter().any(|v| close(u, v)))
        };
        assert_eq!(a.vertices.len(), b.vertices.len(), "{what}");
        assert!(near(a, b) && near(b, a), "{what}");
    };
    // The vertices of the sheet left (x < 2: the animated node's) or right of x = 2 that lie
    // at y = 0 (within `tolerance`).
    let flat = |scene: &Scene, left: bool, tolerance: f32| {
        (scene.vertices.iter())
            .filter(|v| (v.position[0] < 2.0) == left && v.position[1].abs() < tolerance)
            .count()
    };
    for (file, tolerance) in [
        ("morphing_tent.gltf", [1e-5, 1e-5]),
        ("morphing_tent_gltfpack.glb", [5e-3, 2e-2]),
    ] {
        let mut scene = Scene::load(&fixture(file), false).unwrap();
        assert_eq!(scene.animation_names(), ["rise", "blink"], "{file}");
        // At rest the animated sheet is flat; the posed one only along its x = 0 (the ramp's
        // foot), but for the centre that the peak lifts.
        let flats = [true, false].map(|left| flat(&scene, left, tolerance[0]));
        assert_eq!(flats, [25, 4], "{file}");
        scene.animate(1.5);
        same(&scene, &still, file, tolerance);
        // Vertex for vertex where no tool reordered them.
        if file.ends_with(".gltf") {
            for (u, v) in scene.vertices.iter().zip(&still.vertices) {
                assert!(
                    Vec3::from_array(u.position).distance(Vec3::from_array(v.position)) < 1e-5,
                    "{file}"
                );
            }
        }
        // "blink" (STEP): flat until 0.5 s, then the centre vertex lifted by 1.
        scene
            .select_animation(&AnimationChoice::Name("blink".into()))
            .unwrap();
        let peak = |scene: &Scene| {
            (scene.vertices.iter())
                .filter(|v| v.position[0].abs() < 0.1 && v.position[2].abs() < 0.1)
                .map(|v| v.position[1])
                .fold(f32::NEG_INFINITY, f32::max)
        };
        scene.animate(0.45);
        assert!(
            peak(&scene).abs() < tolerance[0],
            "{file}: {}",
            peak(&scene)
        );
        scene.animate(0.55);
        assert!(
            (peak(&scene) - 1.0).abs() < tolerance[0],
            "{file}: {}",
            peak(&scene)
        );
        // The bounds hold the lifted peak.
        assert!(scene.bounds.center.y + scene.bounds.radius >= 1.0, "{file}");
    }
    // Weights that do not match the targets, and displacements of the wrong type, are named.
    let text = std::fs::read_to_string(fixture("morphing_tent.gltf")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tent.gltf");
    fails_when_edited(
        &path,
        &text,
        |json| json["nodes"][1]["weights"] = serde_json::json!([0.5]),
        "node 1 (\"posed\"): its weights hold 1 values for 2 morph targets",
    );
    fails_when_edited(
        &path,
        &text,
        |json| json["accessors"][7]["count"] = 5.into(),
        "channel 0: 5 weights for 3 key times of 2 morph targets",
    );
    fails_when_edited(
        &path,
        &text,
        |json| json["meshes"][0]["primitives"][0]["targets"][1]["POSITION"] = 0.into(),
        "morph target 1's POSITION accessor 0 has type Scalar",
    );
    fails_when_edited(
        &path,
        &text,
        |json| json["accessors"][7]["componentType"] = 5125.into(),
        "channel 0: its weights: accessor 7 has component type U32",
    );
    // A weights channel on a node whose mesh has no morph targets.
    let no_targets = |json: &mut serde_json::Value| {
        let primitive = json["meshes"][0]["primitives"][0].as_object_mut().unwrap();
        primitive.remove("targets");
        let mesh = json["meshes"][0].as_object_mut().unwrap();
        mesh.remove("weights");
        json["nodes"][1].as_object_mut().unwrap().remove("weights");
    };
    fails_when_edited(
        &path,
        &text,
        no_targets,
        "node 0 (\"animated\"), whose mesh has no morph targets",
    );
}

/// A camera node that a clip moves carries the view with it; a camera placed by hand
/// ([`Scene::hold_camera`]) stays.
#[test]
fn animated_cameras_carry_the_view() {
    let dir = tempfile::tempdir().unwrap();
    let keys = vec![Keys {
        node: 0,
        path: "translation",
        interpolation: "LINEAR",
        times: vec![0.0, 2.0],
        values: vec![0.0, 0.0, 0.0, 4.0, 0.0, 0.0],
    }];
    let p = animated_gltf(
        dir.path(),
        "dolly.gltf",
        r#"[{"name":"rig","children":[1]},{"name":"camera","camera":0,"translation":[0,0,10]},
            {"name":"model","mesh":0}]"#,
        "[0,2]",
        &[("dolly", keys)],
    );
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    json["cameras"] =
        serde_json::json!([{"type":"perspective","perspective":{"yfov":0.8,"znear":0.1}}]);
    std::fs::write(&p, json.to_string()).unwrap();
    let mut scene = Scene::load(&p, false).unwrap();
    // Nothing drawn moves, but the camera does: the animation is kept for it.
    assert!(scene.animation.as_ref().unwrap().pieces.is_empty());
    assert!(scene.camera.eye.distance(Vec3::new(0.0, 0.0, 10.0)) < 1e-5);
    scene.animate(0.5);
    let eye = scene.camera.eye;
    assert!(eye.distance(Vec3::new(1.0, 0.0, 10.0)) < 1e-5, "{eye}");
    let ahead = scene.camera.target - eye;
    assert!(ahead.normalize().distance(Vec3::NEG_Z) < 1e-5, "{ahead}");
    scene.hold_camera();
    scene.animate(1.5);
    assert_eq!(scene.camera.eye, eye);
}

/// Keys that are finite but whose spline overflows f32 (tangents of 3·10³⁸): a file whose
/// clip sweeps the model past what can be drawn is refused naming its animations; a pose
/// that overflows anyway (the clip changed after loading) leaves the vertices where they
/// were, finite, rather than handing the GPU infinities.
#[test]
fn poses_past_f32_keep_the_vertices_finite() {
    let dir = tempfile::tempdir().unwrap();
    let big = 3e38f32;
    let huge = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, big, big, big];
    let keys = vec![Keys {
        node: 0,
        path: "scale",
        interpolation: "CUBICSPLINE",
        times: vec![0.0, 1.0],
        values: [huge, [big, big, big, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]].concat(),
    }];
    let p = animated_gltf(
        dir.path(),
        "huge.gltf",
        r#"[{"mesh":0}]"#,
        "[0]",
        &[("grow", keys)],
    );
    let e = Scene::load(&p, true).unwrap_err().to_string();
    assert!(
        e.contains("huge.gltf: its animations take its vertices over a sphere of radius inf"),
        "{e}"
    );
    let mut scene = Scene::load(&sliding_parent(dir.path()), true).unwrap();
    // The parent and the child each scaled by about 5·10³⁷ half way: their product overflows.
    let clip = &mut scene.animation.as_mut().unwrap().clips[0];
    for channel in &mut clip.channels {
        channel.property = Property::Scale;
        channel.interpolation = Interpolation::CubicSpline;
        channel.times = vec![0.0, 2.0];
        channel.values = [0.0, 1.0, big, 0.0, 1.0, 0.0]
            .map(glam::Vec4::splat)
            .to_vec();
    }
    let piece = scene.animation.as_ref().unwrap().pieces[0].first_vertex;
    let before = scene.vertices[piece..piece + 3].to_vec();
    scene.animate(1.0);
    assert_eq!(
        scene.vertices[piece..piece + 3],
        before[..],
        "the overflowing pose moved them"
    );
    for t in [0.25, 0.5, 0.75] {
        scene.animate(t);
        for v in &scene.vertices {
            assert!(
                v.position.iter().chain(&v.normal).all(|c| c.is_finite()),
                "{t}: {v:?}"
            );
        }
    }
}
