//! Triple-product speed (issue 7): the sparse binding tensor `C_ijk` and the per-vertex triple
//! product `B = Σ V_i L_j ρ_k C_ijk` (`envlight::wavelet::triple`), for Haar and a high-order
//! basis (Coiflet-6, coif1), at side 32 (1,024 coefficients).
//!
//! Setup (not timed): the unit sphere resting on a ground plane, per-vertex visibility of the
//! map's directions by ray casting; one ground vertex beside the contact point (partly shadowed
//! by the sphere); its visibility and the rooitou_park lighting (tests/data, luminance only)
//! projected and each truncated to its K largest coefficients; the Lambert slice of the vertex
//! kept whole.
//!
//! Timed:
//! - `build`: `TripleTensor::new` (the factored tensor: 1-D triples, support masks, pruning);
//! - `triple/K`: one vertex's `B` for K visibility × K lighting coefficients (one channel);
//! - `product/K`: the projected product `P = V ⊗ L` (`TripleTensor::product`), which then serves
//!   any BRDF slice as `Σ_k P_k ρ_k` (a moving view);
//! - `pixel/K`: the same B without the tensor, for comparison: scatter the K + K coefficients
//!   into dense arrays, inverse-transform V, L and ρ to the texels (`Grid::reconstruct`) and sum
//!   `V_t L_t ρ_t dω` — equal to the triple product to rounding, because the tensor is exact in
//!   the discrete setting (`triple.rs`), at O(side² log side) whatever K.
//!
//! Run: `cargo bench --bench wavelet_triple` (add `-- --quick` for a short run).

use criterion::{criterion_group, criterion_main, Criterion};
use envlight::capture::image_file::read_hdr_image;
use envlight::envmap::Projection;
use envlight::wavelet::relight::{visibility_texels, Brdf, Grid};
use envlight::wavelet::triple::{sparse_largest, TripleTensor, DEFAULT_PRUNE};
use envlight::wavelet::visibility::{vertex_visibility, Bvh, Mesh};
use envlight::wavelet::{Basis, OctahedralMap};
use envlight::HdrFrame;
use glam::Vec3;
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

const SIDE: usize = 32;

fn bench(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rooitou_park_1k.hdr");
    let image = read_hdr_image(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut frame = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .expect("valid size");
    frame.sanitize();
    let map = OctahedralMap::from_frame(&frame, SIDE).expect("resample");
    let luminance: Vec<f64> = map
        .texels()
        .iter()
        .map(|t| 0.2126 * f64::from(t[0]) + 0.7152 * f64::from(t[1]) + 0.0722 * f64::from(t[2]))
        .collect();
    let mesh = Mesh::sphere_on_plane(32, 16);
    let bvh = Bvh::build(&mesh).expect("mesh");
    // The ground vertex nearest to (0.6, 0, 0): beside the contact point, in the sphere's shadow
    // for part of the sky.
    let vertex = (0..mesh.positions.len())
        .min_by(|&a, &b| {
            let d = |v: usize| (mesh.positions[v] - Vec3::new(0.6, 0.0, 0.0)).length();
            d(a).total_cmp(&d(b))
        })
        .expect("mesh has vertices");

    let mut group = c.benchmark_group("wavelet_triple");
    group.sample_size(20);
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(3));
    for basis in [Basis::Haar, Basis::Coiflet(1)] {
        let grid = Grid::new(SIDE, basis, None).expect("grid");
        group.bench_function(format!("{basis}/side_{SIDE}/build"), |b| {
            b.iter(|| TripleTensor::new(black_box(&grid), DEFAULT_PRUNE).expect("tensor"))
        });
        let tensor = TripleTensor::new(&grid, DEFAULT_PRUNE).expect("tensor");
        let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);
        let v_coeffs = grid
            .project(&visibility_texels(&vis, vertex))
            .expect("project visibility");
        let l_coeffs = grid.project(&luminance).expect("project lighting");
        let slice = Brdf::Lambert.slice(mesh.normals[vertex], Vec3::Y, &grid.dirs);
        let rho = grid.project(&slice).expect("project slice");
        for k in [64usize, 256] {
            let v = sparse_largest(&v_coeffs, k);
            let l = sparse_largest(&l_coeffs, k);
            group.bench_function(format!("{basis}/side_{SIDE}/triple/{k}"), |b| {
                b.iter(|| {
                    tensor
                        .triple(black_box(&v), black_box(&l), &rho)
                        .expect("triple")
                })
            });
            group.bench_function(format!("{basis}/side_{SIDE}/product/{k}"), |b| {
                b.iter(|| {
                    tensor
                        .product(black_box(&v), black_box(&l))
                        .expect("product")
                })
            });
            let by_tensor = tensor.triple(&v, &l, &rho).expect("triple");
            let by_pixels = pixel_domain(&grid, &v, &l, &rho);
            assert!(
                (by_tensor - by_pixels).abs() <= 1e-9 * by_tensor.abs().max(1e-30),
                "{basis} K={k}: tensor {by_tensor} vs pixels {by_pixels}"
            );
            group.bench_function(format!("{basis}/side_{SIDE}/pixel/{k}"), |b| {
                b.iter(|| pixel_domain(&grid, black_box(&v), black_box(&l), &rho))
            });
        }
    }
    group.finish();
}

/// `Σ_t V_t L_t ρ_t dω` from sparse V and L and dense ρ by inverse transforms.
fn pixel_domain(grid: &Grid, v: &[(u32, f64)], l: &[(u32, f64)], rho: &[f64]) -> f64 {
    let dense = |sparse: &[(u32, f64)]| {
        let mut d = vec![0.0; grid.len()];
        for &(i, c) in sparse {
            d[i as usize] = c;
        }
        grid.reconstruct(&d).expect("reconstruct")
    };
    let (vt, lt) = (dense(v), dense(l));
    let rt = grid.reconstruct(rho).expect("reconstruct");
    let sum: f64 = vt
        .iter()
        .zip(&lt)
        .zip(&rt)
        .map(|((a, b), c)| a * b * c)
        .sum();
    sum * grid.d_omega()
}

criterion_group!(benches, bench);
criterion_main!(benches);
