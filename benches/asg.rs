//! ASG fitting speed (issue 6), K = 16 on the paper's 256×512 map, built-in sky:
//! - `prepare_target_256x512`: resampling a frame and its diffuse ground truth;
//! - `loss_gradient_fast_256x512`: one evaluation of the loss and its gradient by the f32 tiled
//!   kernel the optimiser uses (initial lobes and fitted lobes);
//! - `first_frame_default_1_thread` / `_all_threads`: the default first frame through
//!   `AsgFitter` (greedy init + `FitSettings::iterations`, on 1/`first_subset` of the tiles
//!   per iteration);
//! - `prepare_refill_256x512`: the same target refilled in place for a new frame, tiles
//!   included (what `AsgFitter` does from the second frame on);
//!   `prepare_refill_256x512_from_2000x1000` from a frame of a size that is no multiple of the
//!   map (the resampling by area overlap); `prepare_refill_256x512_from_fisheye_2048` from a
//!   2048 × 2048 fisheye frame (bilinear splatting, `src/asg/splat.rs`);
//! - `warm_refit_default_1_thread`: one warm-started refit of the next frame's prepared target
//!   with the default `warm_iterations` on 1/`warm_subset` of the tiles, continuing Adam's
//!   state as `AsgFitter` does, after a default first frame;
//! - `warm_frame_whole_1_thread`: the issue's ≤ 33.3 ms target as one number: a whole warm
//!   frame through `AsgFitter::fit_frame` — the target of the new frame prepared (refilling
//!   the previous frame's, tiles included) and refitted from the fitter's state after the
//!   default first frame, on one thread. The refits run with `FitSettings::warm_loss` off (the
//!   default, as the daemon runs them): no whole-map loss of the result;
//! - `lobe_filter_16_lobes`: the lights' FIR filter (default taps) on one frame's 16 fitted
//!   lobes (`envlight::asg::temporal::LobeFilter`, as the daemon's stage applies it after each
//!   fit): alignment, states, the window's sum and the lobes rebuilt.
//!
//! Run: `cargo bench --bench asg` (or `-- --warm-up-time 1 --measurement-time 5`; the first-frame
//! cases take seconds per sample: `-- warm` runs the refit alone).

use criterion::{criterion_group, criterion_main, Criterion};
use envlight::asg::fit::{fast_loss_gradient, initial_lobes, AsgFitter, FitSettings, FitTarget};
use envlight::capture::sky::{render_sky, SkyOptions};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let options = SkyOptions {
        // The sky the documented figures were measured on (seed 0, the default until 2026-11-23).
        seed: 0,
        ..SkyOptions::default()
    };
    let settings = FitSettings {
        threads: 1,
        ..FitSettings::default()
    };
    let target = |t: f64| {
        FitTarget::from_frame(
            &render_sky(&options, t),
            settings.height,
            settings.diffuse_normals,
        )
        .expect("sky frame")
    };
    let (t0, t1) = (target(0.0), target(1.0 / 30.0));
    // The first frame on all cores (setup only), the refits on one.
    let mut fitter = AsgFitter::new(FitSettings {
        threads: 0,
        ..settings.clone()
    })
    .expect("valid settings");
    // Through `fit_frame`, so the fitter holds frame 0's target for the whole-frame case.
    let first = fitter
        .fit_frame(&render_sky(&options, 0.0))
        .expect("sky frame");
    fitter
        .set_settings(settings.clone())
        .expect("valid settings");
    let _ = t1.tiled();

    let mut group = c.benchmark_group("asg");
    group.sample_size(10);
    group.bench_function("prepare_target_256x512", |b| {
        let frame = render_sky(&options, 0.5);
        b.iter(|| FitTarget::from_frame(black_box(&frame), 256, 256))
    });
    group.bench_function("prepare_refill_256x512", |b| {
        let frame = render_sky(&options, 0.5);
        let mut t = target(0.0);
        let _ = t.tiled();
        b.iter(|| t.refill(black_box(&frame)))
    });
    // A frame of a size that is no multiple of the map: the resampling by area overlap.
    group.bench_function("prepare_refill_256x512_from_2000x1000", |b| {
        let large = SkyOptions {
            width: 2000,
            height: 1000,
            ..options.clone()
        };
        let frame = render_sky(&large, 0.5);
        let mut t = target(0.0);
        let _ = t.tiled();
        t.refill(&frame).expect("sky frame");
        b.iter(|| t.refill(black_box(&frame)))
    });
    // A 2048 × 2048 fisheye frame of the sky (the rig's camera): bilinear splatting through
    // the table built by the first refill (src/asg/splat.rs).
    group.bench_function("prepare_refill_256x512_from_fisheye_2048", |b| {
        use envlight::envmap::{fisheye_detect::render_fisheye, FisheyeCalibration, Projection};
        let sky = render_sky(&options, 0.5);
        let calibration = FisheyeCalibration::default();
        let pixels = render_fisheye(
            &sky.pixels,
            sky.width,
            sky.height,
            &calibration,
            2048,
            2048,
            1,
        );
        let frame = envlight::HdrFrame::new(2048, 2048, pixels, Projection::Fisheye(calibration))
            .expect("fisheye frame");
        let mut t = target(0.0);
        let _ = t.tiled();
        t.refill(&frame).expect("fisheye frame");
        b.iter(|| t.refill(black_box(&frame)))
    });
    let init = initial_lobes(&t0, 16);
    group.bench_function("loss_gradient_fast_256x512_initial_lobes", |b| {
        b.iter(|| fast_loss_gradient(black_box(&t0), &init, &settings))
    });
    group.bench_function("loss_gradient_fast_256x512_fitted_lobes", |b| {
        b.iter(|| fast_loss_gradient(black_box(&t0), &first.lobes, &settings))
    });
    for (name, threads) in [
        ("first_frame_default_1_thread", 1),
        ("first_frame_default_all_threads", 0),
    ] {
        let s = FitSettings {
            threads,
            ..settings.clone()
        };
        group.bench_function(name, |b| {
            b.iter(|| {
                AsgFitter::new(s.clone())
                    .expect("valid settings")
                    .fit_target(black_box(&t0))
            })
        });
    }
    group.bench_function("warm_refit_default_1_thread", |b| {
        b.iter_batched(
            || fitter.clone(),
            |mut f| f.fit_target(black_box(&t1)),
            criterion::BatchSize::SmallInput,
        )
    });
    let frame1 = render_sky(&options, 1.0 / 30.0);
    group.bench_function("warm_frame_whole_1_thread", |b| {
        // Each iteration starts from a copy of the fitter after frame 0 (made untimed); the
        // copy is returned so that criterion drops it outside the timed region.
        b.iter_batched(
            || fitter.clone(),
            |mut f| {
                let r = f.fit_frame(black_box(&frame1));
                (f, r)
            },
            criterion::BatchSize::PerIteration,
        )
    });
    group.bench_function("lobe_filter_16_lobes", |b| {
        let mut filter = envlight::asg::temporal::LobeFilter::new(Some(
            &envlight::decompose::filter::DEFAULT_TAPS,
        ))
        .expect("default taps");
        let mut lobes = first.lobes.clone();
        b.iter(|| {
            lobes.copy_from_slice(&first.lobes);
            filter.apply(black_box(&mut lobes));
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
