//! ASG fitting speed (issue 6): the first frame of the built-in sky fitted from scratch, and a
//! warm-started refit of the next frame, K = 16 on the paper's 256×512 map, on one thread.
//! Run: `cargo bench --bench asg`.

use criterion::{criterion_group, criterion_main, Criterion};
use envlight::asg::fit::{initial_lobes, optimise, FitSettings, FitTarget};
use envlight::capture::sky::{render_sky, SkyOptions};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let options = SkyOptions::default();
    let settings = FitSettings {
        threads: 1,
        ..FitSettings::default()
    };
    let t0 = FitTarget::from_frame(
        &render_sky(&options, 0.0),
        settings.height,
        settings.diffuse_normals,
    )
    .expect("sky frame");
    let t1 = FitTarget::from_frame(
        &render_sky(&options, 1.0 / 30.0),
        settings.height,
        settings.diffuse_normals,
    )
    .expect("sky frame");
    let init = initial_lobes(&t0, settings.lobes);
    let first = optimise(
        &t0,
        &init,
        None,
        settings.iterations,
        settings.learning_rate,
        &settings,
    );

    let mut group = c.benchmark_group("asg");
    group.sample_size(10);
    group.bench_function("prepare_target_256x512", |b| {
        let frame = render_sky(&options, 0.5);
        b.iter(|| FitTarget::from_frame(black_box(&frame), 256, 256))
    });
    group.bench_function("first_frame_k16_300_iterations", |b| {
        b.iter(|| {
            let init = initial_lobes(black_box(&t0), 16);
            optimise(
                &t0,
                &init,
                None,
                settings.iterations,
                settings.learning_rate,
                &settings,
            )
        })
    });
    group.bench_function("warm_refit_k16_30_iterations", |b| {
        b.iter(|| {
            optimise(
                black_box(&t1),
                &first.lobes,
                Some(&first.lobes),
                settings.warm_iterations,
                settings.warm_learning_rate,
                &settings,
            )
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
