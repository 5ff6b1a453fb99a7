//! Spherical-harmonics speed (`[sh]` stage, src/sh): the projection plan of a lat-long map
//! (pixel directions and exact solid angles, built once per frame shape) and the per-frame
//! projection of rooitou_park at 512×256, 1024×512 and 2048×1024 onto degree 2 (9
//! coefficients per channel) and degree 4 (25), on one thread and on rayon's threads; the
//! same for a camera's 1280×960 fisheye frame (the per-pixel weights at degrees 2 and 4, the
//! basis evaluated at every pixel at degree 8); the evaluation of
//! irradiance from a set; the temporal filter with the lights' default taps
//! (`envlight::set_filter`) on a degree-8 set (243 numbers) and, for the wavelet stage, on a
//! 64² octahedral map (12,288 f32). Run: `cargo bench --bench sh` (`-- --quick` for a short
//! run).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use envlight::capture::image_file::read_hdr_image;
use envlight::envmap::Projection;
use envlight::set_filter::SetFilter;
use envlight::sh::{project, Projector};
use envlight::HdrFrame;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/rooitou_park_1k.hdr"
    );
    let image = read_hdr_image(std::path::Path::new(path)).expect("test map");
    let park =
        HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong).expect("frame");
    let sizes = [(512u32, 256u32), (1024, 512), (2048, 1024)];
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");

    let mut group = c.benchmark_group("sh");
    group.sample_size(20);
    for (width, height) in sizes {
        let frame = park
            .reprojected(Projection::LatLong, width, height)
            .expect("resized frame");
        let size = format!("{width}x{height}");
        group.bench_function(BenchmarkId::new("plan", &size), |b| {
            b.iter(|| Projector::new(2, width, height, Projection::LatLong))
        });
        for degree in [2usize, 4] {
            let plan = Projector::new(degree, width, height, Projection::LatLong);
            group.bench_function(
                BenchmarkId::new(format!("project_degree{degree}_1thread"), &size),
                |b| b.iter(|| one_thread.install(|| plan.project(black_box(&frame)))),
            );
            group.bench_function(
                BenchmarkId::new(format!("project_degree{degree}_all_threads"), &size),
                |b| b.iter(|| plan.project(black_box(&frame))),
            );
        }
    }
    // A camera's frame: rooitou_park's upper hemisphere through the default fisheye lens at
    // 1280×960 (the per-pixel path).
    let fisheye = Projection::Fisheye(envlight::envmap::FisheyeCalibration::default());
    let camera = park.reprojected(fisheye, 1280, 960).expect("fisheye frame");
    group.bench_function("plan/fisheye_1280x960", |b| {
        b.iter(|| Projector::new(2, 1280, 960, fisheye))
    });
    for degree in [2usize, 4] {
        let plan = Projector::new(degree, 1280, 960, fisheye);
        group.bench_function(
            BenchmarkId::new(
                format!("project_degree{degree}_1thread"),
                "fisheye_1280x960",
            ),
            |b| b.iter(|| one_thread.install(|| plan.project(black_box(&camera)))),
        );
        group.bench_function(
            BenchmarkId::new(
                format!("project_degree{degree}_all_threads"),
                "fisheye_1280x960",
            ),
            |b| b.iter(|| plan.project(black_box(&camera))),
        );
    }
    // Degree 8: weights past the plan's budget, so the basis is evaluated at every pixel.
    let plan = Projector::new(8, 1280, 960, fisheye);
    group.bench_function(
        BenchmarkId::new("project_degree8_1thread", "fisheye_1280x960"),
        |b| b.iter(|| one_thread.install(|| plan.project(black_box(&camera)))),
    );
    group.bench_function(
        BenchmarkId::new("project_degree8_all_threads", "fisheye_1280x960"),
        |b| b.iter(|| plan.project(black_box(&camera))),
    );
    let set = project(&park, 2);
    let normals: Vec<glam::DVec3> = envlight::yardstick::evaluation_directions();
    group.bench_function("irradiance_degree2_1024_normals", |b| {
        b.iter(|| {
            normals
                .iter()
                .map(|&n| set.irradiance(black_box(n)))
                .fold(0.0, |s, e| s + e[1])
        })
    });
    // The temporal filter, per frame, on a full window (7 taps).
    let taps = envlight::decompose::filter::DEFAULT_TAPS;
    let degree8 = project(&park, 8);
    let mut sh_filter = SetFilter::<f64>::new(&taps).expect("taps");
    let mut number = 0u64;
    group.bench_function("filter_degree8_set", |b| {
        b.iter(|| {
            let mut set = degree8.clone();
            number += 1;
            sh_filter.apply(number, set.values_mut());
            set
        })
    });
    let map = envlight::wavelet::sphere::OctahedralMap::from_frame(&park, 64).expect("map");
    let mut map_filter = SetFilter::<f32>::new(&taps).expect("taps");
    let mut number = 0u64;
    let mut texels = map.texels().to_vec();
    group.bench_function("filter_octahedral_map_64", |b| {
        b.iter(|| {
            number += 1;
            map_filter.apply(number, bytemuck::cast_slice_mut(black_box(&mut texels)));
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
