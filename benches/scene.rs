//! Scene loading: `Scene::load` (read, parse, decode compressed geometry, flatten to world
//! space, load textures) of glTF files, one benchmark per file. By default the small sphere
//! of tests/data/compressed in each of its forms; `ENVLIGHT_BENCH_SCENES=a.glb,b.glb` names
//! other files, such as the larger spheres that `tests/data/compressed/make_sphere.py OUT
//! SEGMENTS RINGS` writes and glTF-Transform or gltfpack compress (tests/data/compressed/
//! README.md; docs/performance.md, "Compressed glTF geometry", has the figures).
//!
//! `scene_animate`: posing an animated scene for a frame (`Scene::animate`: a clip sampled,
//! the node matrices composed, every moved vertex, normal and tangent placed again) and the
//! camera-facing normals the renderer then recomputes, for spheres of 33 k and 263 k vertices
//! turning on one node.
//!
//! `cargo bench --bench scene`

use criterion::{criterion_group, criterion_main, Criterion};
use envlight::render::scene::Scene;
use std::path::PathBuf;

fn scenes() -> Vec<PathBuf> {
    match std::env::var("ENVLIGHT_BENCH_SCENES") {
        Ok(list) => list.split(',').map(|s| PathBuf::from(s.trim())).collect(),
        Err(_) => [
            "sphere.glb",
            "sphere_draco.glb",
            "sphere_draco_sequential.glb",
            "sphere_meshopt.glb",
            "sphere_gltfpack.glb",
        ]
        .iter()
        .map(|f| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("tests/data/compressed")
                .join(f)
        })
        .collect(),
    }
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("scene_load");
    for path in scenes() {
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into(),
        );
        if let Err(e) = Scene::load(&path, false) {
            eprintln!("skipping {name}: {e}");
            continue;
        }
        group.bench_function(&name, |b| {
            b.iter(|| Scene::load(&path, false).map(|s| s.indices.len()))
        });
    }
    group.finish();
}

/// A sphere of `segments` × `segments / 2` quads turning about +y (LINEAR, one turn in 4 s)
/// on node 0: its first `moved` vertices move (all, where there are fewer), the rest stand
/// (a small animated model in a large still scene). With `morph`, it also breathes and
/// squashes by two morph targets (displacements of every position and normal) whose weights
/// a LINEAR channel drives.
fn turning_sphere(segments: u32, morph: bool, moved: usize) -> Scene {
    use envlight::render::scene::{
        Camera, Channel, Clip, Interpolation, LocalGeometry, Material, MorphTarget, Piece,
        Property, RestTransform, SceneAnimation, WeightsChannel,
    };
    use glam::{Mat4, Quat, Vec3, Vec4};
    let camera = Camera::perspective(Vec3::new(0.0, 0.5, 4.0), Vec3::ZERO, 0.7);
    let mut scene = Scene::sphere(Vec3::ZERO, 1.0, segments, Material::default(), None, camera);
    let moved = &scene.vertices[..moved.min(scene.vertices.len())];
    let positions: Vec<Vec3> = (moved.iter())
        .map(|v| Vec3::from_array(v.position))
        .collect();
    let normals: Vec<Vec3> = (moved.iter()).map(|v| Vec3::from_array(v.normal)).collect();
    let targets = if morph {
        let breathe = MorphTarget {
            positions: normals.iter().map(|&n| 0.2 * n).collect(),
            normals: Vec::new(),
            tangents: Vec::new(),
        };
        let squash = MorphTarget {
            positions: positions
                .iter()
                .map(|p| Vec3::new(0.0, -0.3 * p.y, 0.0))
                .collect(),
            normals: normals
                .iter()
                .map(|n| Vec3::new(0.0, 0.3 * n.y, 0.0))
                .collect(),
            tangents: Vec::new(),
        };
        vec![breathe, squash]
    } else {
        Vec::new()
    };
    let weights = if morph {
        vec![WeightsChannel {
            node: 0,
            interpolation: Interpolation::Linear,
            times: vec![0.0, 2.0, 4.0],
            targets: 2,
            values: vec![0.0, 1.0, 1.0, 0.5, 0.0, 1.0],
        }]
    } else {
        Vec::new()
    };
    let morph_weights = vec![0.0; targets.len()];
    let geometry = LocalGeometry {
        positions,
        normals,
        tangents: Vec::new(),
        targets,
    };
    let turn = |degrees: f32| Vec4::from(Quat::from_rotation_y(degrees.to_radians()));
    scene.animation = Some(SceneAnimation {
        parents: vec![None],
        rest: vec![RestTransform {
            matrix: Mat4::IDENTITY,
            translation: Vec3::ZERO,
            rotation: Quat::IDENTITY,
            scale: Vec3::ONE,
        }],
        order: vec![0],
        clips: vec![Clip {
            name: "turn".into(),
            channels: vec![Channel {
                node: 0,
                property: Property::Rotation,
                interpolation: Interpolation::Linear,
                times: vec![0.0, 1.0, 2.0, 3.0, 4.0],
                values: [0.0, 90.0, 180.0, 270.0, 360.0].map(turn).to_vec(),
            }],
            weights,
            duration: 4.0,
        }],
        pieces: vec![Piece {
            node: 0,
            instance: Mat4::IDENTITY,
            first_vertex: 0,
            geometry: std::sync::Arc::new(geometry),
            skin: None,
            morph_weights,
        }],
        playing: Some(0),
        moved: vec![true],
        morphed: vec![morph],
        skins: Vec::new(),
        last_pose: None,
        camera: None,
    });
    scene
}

fn bench_animate(c: &mut Criterion) {
    let mut group = c.benchmark_group("scene_animate");
    use envlight::render::shadow::{posed_facing_normals, still_facing};
    let all = usize::MAX;
    for (segments, morph, moved) in [
        (256u32, false, all),
        (724, false, all),
        (256, true, all),
        (724, true, all),
        (724, false, 33153),
    ] {
        let mut scene = turning_sphere(segments, morph, moved);
        let targets = if morph { "_2_morph_targets" } else { "" };
        let moved: usize = (scene.animation.as_ref().unwrap().moved_vertices())
            .map(|r| r.len())
            .sum();
        let name = if moved < scene.vertices.len() {
            format!("{moved}_of_{}_vertices{targets}", scene.vertices.len())
        } else {
            format!("{}_vertices{targets}", scene.vertices.len())
        };
        let still = still_facing(&scene);
        let mut t = 0.0;
        group.bench_function(&name, |b| {
            b.iter(|| {
                t += 0.016;
                scene.animate(t);
                posed_facing_normals(&scene, still.as_ref()).len()
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench, bench_animate);
criterion_main!(benches);
