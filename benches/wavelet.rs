//! Wavelet lighting speed (issue 7): the resampling plan of a 1k lat-long map onto the
//! octahedral square (built once per projection and size) and its use per frame; the forward
//! transform + top-K approximation of the RGB square (128² and 256², K = 1024) for each of the
//! issue's bases; the reconstruction from the sparse set.
//! One thread. Run: `cargo bench --bench wavelet` (add `-- --quick` for a short run).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use envlight::capture::image_file::read_hdr_image;
use envlight::envmap::Projection;
use envlight::wavelet::approx::Coefficients;
use envlight::wavelet::sphere::{OctahedralMap, Resampler};
use envlight::wavelet::transform::{max_levels, Workspace};
use envlight::wavelet::Basis;
use envlight::HdrFrame;
use std::hint::black_box;

const K: usize = 1024;

fn bench(c: &mut Criterion) {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/rooitou_park_1k.hdr"
    );
    let image = read_hdr_image(std::path::Path::new(path)).expect("test map");
    let mut frame =
        HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong).expect("frame");
    frame.sanitize();

    let mut group = c.benchmark_group("wavelet");
    group.sample_size(20);
    for side in [128usize, 256] {
        group.bench_function(BenchmarkId::new("resample_plan_1k_latlong", side), |b| {
            b.iter(|| {
                Resampler::new(frame.projection, frame.width, frame.height, side).expect("plan")
            })
        });
        let plan = Resampler::new(frame.projection, frame.width, frame.height, side).expect("plan");
        group.bench_function(BenchmarkId::new("resample_1k_latlong", side), |b| {
            b.iter(|| plan.resample(black_box(&frame)).expect("map"))
        });
    }
    for side in [128usize, 256] {
        let map = OctahedralMap::from_frame(&frame, side).expect("map");
        let levels = max_levels(side);
        for basis in Basis::issue_set() {
            let mut ws = Workspace::new();
            group.bench_function(
                BenchmarkId::new(format!("forward_rgb_{side}"), basis.name()),
                |b| {
                    b.iter(|| {
                        Coefficients::analyze_with(
                            black_box(map.texels()),
                            side,
                            basis,
                            levels,
                            &mut ws,
                        )
                        .expect("transform")
                    })
                },
            );
            let coeffs = Coefficients::analyze(map.texels(), side, basis, levels).expect("coeffs");
            group.bench_function(
                BenchmarkId::new(format!("forward_and_top{K}_{side}"), basis.name()),
                |b| {
                    b.iter(|| {
                        Coefficients::analyze_with(
                            black_box(map.texels()),
                            side,
                            basis,
                            levels,
                            &mut ws,
                        )
                        .expect("transform")
                        .truncate(K)
                    })
                },
            );
            let set = coeffs.truncate(K);
            group.bench_function(
                BenchmarkId::new(format!("reconstruct_top{K}_{side}"), basis.name()),
                |b| b.iter(|| black_box(&set).reconstruct().expect("reconstruct")),
            );
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
