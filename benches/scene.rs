//! Scene loading: `Scene::load` (read, parse, decode compressed geometry, flatten to world
//! space, load textures) of glTF files, one benchmark per file. By default the small sphere
//! of tests/data/compressed in each of its forms; `ENVLIGHT_BENCH_SCENES=a.glb,b.glb` names
//! other files, such as the larger spheres that `tests/data/compressed/make_sphere.py OUT
//! SEGMENTS RINGS` writes and glTF-Transform or gltfpack compress (tests/data/compressed/
//! README.md; docs/performance.md, "Compressed glTF geometry", has the figures).
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

criterion_group!(benches, bench);
criterion_main!(benches);
