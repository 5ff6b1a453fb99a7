//! Wavelet relighting speed (issue 7): one frame of a 100k-vertex mesh relit with 1,000 lighting
//! coefficients, for 64, 128 and 256 transport coefficients kept per vertex.
//!
//! Setup (not timed): a bumpy blob of 10,011 vertices with self-shadowing, visibility of the
//! 64×64 equal-area octahedral map's 4,096 directions by ray casting, Lambertian transport in
//! Coiflet-6 (coif1) wavelets truncated to `keep` coefficients per vertex. The 10,011 rows are
//! stored ten times over (100,110 vertices, each row its own copy in memory) to reach 100k
//! vertices without tracing 400 M rays in the setup: the per-frame cost depends only on the
//! number of rows and of entries per row and on the memory they occupy, which are those of a
//! real 100k-vertex mesh. The lighting is rooitou_park (tests/data) resampled to 64×64 and
//! truncated to its 1,000 largest coefficients.
//!
//! Timed per frame: scattering the 1,000 coefficients into the dense table
//! (`DenseLighting::set`) and the sparse dot product of every vertex (`Transport::relight`,
//! rayon over all cores).
//!
//! Run: `cargo bench --bench wavelet_relight` (add `-- --quick` for a short run).

use criterion::{criterion_group, criterion_main, Criterion};
use envlight::capture::image_file::read_hdr_image;
use envlight::envmap::Projection;
use envlight::wavelet::relight::{Brdf, DenseLighting, Grid, Transport, View};
use envlight::wavelet::visibility::{vertex_visibility, Bvh, Mesh};
use envlight::wavelet::{approximate, Basis, OctahedralMap};
use envlight::HdrFrame;
use glam::Vec3;
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

const COPIES: usize = 10;

fn bench(c: &mut Criterion) {
    let grid = Grid::new(64, Basis::Coiflet(1), None).expect("grid");
    let mesh = Mesh::bumpy_blob(140, 0.25);
    let bvh = Bvh::build(&mesh).expect("mesh");
    let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);

    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rooitou_park_1k.hdr");
    let image = read_hdr_image(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut frame = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .expect("valid size");
    frame.sanitize();
    let map = OctahedralMap::from_frame(&frame, grid.side).expect("resample");
    let set = approximate(map.texels(), grid.side, grid.basis, grid.levels, 1000).expect("approx");
    let mut light = DenseLighting::new(&grid);

    let mut group = c.benchmark_group("wavelet_relight");
    group.sample_size(20);
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(4));
    for keep in [64usize, 128, 256] {
        let base = Transport::precompute(
            &grid,
            &mesh.positions,
            &mesh.normals,
            &vis,
            Brdf::Lambert,
            View::Direction(Vec3::Y),
            keep,
        )
        .expect("transport");
        let rows = (0..COPIES).flat_map(|_| {
            (0..base.vertices())
                .map(|v| base.row(v).map(|(k, c)| (k as u16, c)).collect::<Vec<_>>())
        });
        let transport = Transport::from_rows(&grid, rows).expect("rows");
        let mut out = vec![[0.0f32; 3]; transport.vertices()];
        group.bench_function(
            format!(
                "{}_vertices/1000_light/{keep}_transport",
                transport.vertices()
            ),
            |b| {
                b.iter(|| {
                    light.set(&grid, black_box(&set)).expect("set");
                    transport.relight(&light, &mut out).expect("relight");
                    black_box(&out);
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
