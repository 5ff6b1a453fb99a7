//! Benchmarks of the light decomposition (single-threaded: one core).
//!
//! - `frame/default_256/{128x64,256x128,512x256,1024x512,2048x1024,1000x500,1920x960}`: one
//!   frame of rooitou_park (lat-long) decomposed with the default settings (256 lights, filter
//!   on, merge off). One `Decomposer` is reused across iterations, as in the daemon: its filter
//!   state and per-geometry tables persist, so this is the steady per-frame cost. 512×256,
//!   256×128 and 128×64 are the map box-downsampled by 2, 4 and 8, 2048×1024 the map upsampled
//!   by pixel replication, 1000×500 and 1920×960 resampled by nearest pixel: sizes that are no
//!   multiple of the working map's, resampled by exact overlap, as is 128×64, narrower than
//!   the working map.
//! - `frame/raw_256/1024x512`: the same without filter and merge.
//! - `frame/filter_merge_256/1024x512`: the same with filter and merge (`--merge`, the default
//!   merge spacing), the configuration the target names.
//! - `frame/read_only/1024x512`: a plain sum of the same frame's floats (nothing else): what
//!   reading the frame costs at that moment, the floor of the decomposition's resampling and,
//!   on a shared machine, a gauge of how fast its memory system is running (docs/performance.md,
//!   "what a slow phase is").
//! - `frame/filter_merge_256_uncached/1024x512` and `frame/read_only_uncached/1024x512`: the two
//!   cases above on 12 copies of the frame (75 MB, more than the L3 of the VMs measured on: 8
//!   and 32 MB) taken in turn, so every frame is read from memory, as a new frame of a live
//!   stream may be; the lights are those of the cached case (the copies are equal).
//! - `frame/turning_256/1024x512` and `frame/turning_256_no_reuse/1024x512`: default settings on
//!   rooitou_park turned about the zenith by one pixel per frame (0, 1, …, 7, 6, …, 1 pixels,
//!   cycled), so every light moves every frame: the cost of a moving map, with the region pass's
//!   candidate lists reused while the lights stay within their margin, and built every frame.
//! - `filter/{blend,fold,fade}_256`: the temporal filter alone (`FirFilter::apply`) on the raw
//!   256-light lists of the built-in sky's first 30 frames, forwards and back (the sun in view,
//!   its pixels changing hands between lights), with each `bright_history`: the filter's share
//!   of a frame and what grouping the bright lights' windows costs.
//! - `distribution/new_256x128`: `PiecewiseConstant2d::new` on 256×128 luminance × solid-angle
//!   weights (the default working-map size).
//! - `solid_angles/{equidistant,equisolid,stereographic,orthographic,angular,latlong}_1280x960`:
//!   the exact per-pixel solid angles of a 1280×960 camera image under each projection (default
//!   calibration). Computed once per geometry and cached, so this is a start-up (and
//!   calibration-change) cost, not a per-frame one. The fisheye and angular cases run on
//!   rayon's threads (all cores; `RAYON_NUM_THREADS=1` for one).
//! - `frame/fisheye_256/1280x960`: default settings but one thread on rooitou_park's upper
//!   hemisphere seen by a 1280×960 equidistant fisheye (a camera's frames; the resampling goes
//!   through the per-geometry table instead of the lat-long box filter), one `Decomposer`
//!   reused. `frame/fisheye_256_2threads/1280x960`: the same with the default
//!   `resample_threads` (2), the resampling's bands of input rows on two threads.
//! - `first_frame/fisheye_1280x960`: a new `Decomposer` (default settings) and its first frame,
//!   rooitou_park seen by a 1280×960 equidistant fisheye (default calibration): what a camera's
//!   first frame, or the first after a calibration change, costs with the per-geometry tables
//!   (solid angles and the resampling plan on rayon's threads) built and the resampling
//!   threads started.
//!
//! Run with `cargo bench --bench decompose`; quote the medians.

use criterion::{criterion_group, criterion_main, Criterion};
use envlight::capture::image_file::read_hdr_image;
use envlight::capture::sky::{render_sky, SkyOptions};
use envlight::decompose::{
    BrightHistory, DecomposeSettings, Decomposer, FirFilter, PiecewiseConstant2d,
};
use envlight::envmap::{FisheyeCalibration, FisheyeModel, Projection};
use envlight::frame::luminance;
use envlight::HdrFrame;
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

/// How many copies of the frame the uncached cases cycle through: 12 × 6.29 MB = 75 MB.
const UNCACHED_COPIES: usize = 12;

fn rooitou() -> HdrFrame {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rooitou_park_1k.hdr");
    let image = read_hdr_image(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut frame = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .expect("valid size");
    frame.sanitize();
    frame
}

/// Box-downsamples by 2 in each direction.
fn downsample2(frame: &HdrFrame) -> HdrFrame {
    let (w, h) = (frame.width / 2, frame.height / 2);
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let mut sum = [0.0f32; 3];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let p = frame.pixel(2 * x + dx, 2 * y + dy);
                for c in 0..3 {
                    sum[c] += 0.25 * p[c];
                }
            }
            pixels.push(sum);
        }
    }
    HdrFrame::new(w, h, pixels, Projection::LatLong).expect("valid size")
}

/// Upsamples by 2 in each direction by pixel replication.
fn upsample2(frame: &HdrFrame) -> HdrFrame {
    let (w, h) = (frame.width * 2, frame.height * 2);
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            pixels.push(frame.pixel(x / 2, y / 2));
        }
    }
    HdrFrame::new(w, h, pixels, Projection::LatLong).expect("valid size")
}

/// Resamples to `w`×`h` by nearest pixel (a frame of a size that is no multiple of the working
/// map's).
fn resize_nearest(frame: &HdrFrame, w: u32, h: u32) -> HdrFrame {
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let sx = (u64::from(x) * u64::from(frame.width) / u64::from(w)) as u32;
            let sy = (u64::from(y) * u64::from(frame.height) / u64::from(h)) as u32;
            pixels.push(frame.pixel(sx, sy));
        }
    }
    HdrFrame::new(w, h, pixels, Projection::LatLong).expect("valid size")
}

/// Luminance × solid angle of `frame` box-downsampled by `factor`.
fn energy_weights(frame: &HdrFrame, factor: u32) -> (Vec<f64>, usize, usize) {
    let (w, h) = (frame.width / factor, frame.height / factor);
    let omega = Projection::LatLong.solid_angles(frame.width, frame.height);
    let mut weights = vec![0.0f64; (w * h) as usize];
    for y in 0..h * factor {
        for x in 0..w * factor {
            let i = (y * frame.width + x) as usize;
            weights[((y / factor) * w + x / factor) as usize] +=
                f64::from(luminance(frame.pixels[i])) * omega[i];
        }
    }
    (weights, w as usize, h as usize)
}

/// Σ of every float of `frame`, with sixteen running sums so that the loop is bound by memory,
/// not by the chain of adds.
fn read_frame(frame: &HdrFrame) -> f32 {
    let floats = frame.pixels.as_flattened();
    let mut sums = [0.0f32; 16];
    let chunks = floats.chunks_exact(16);
    let tail: f32 = chunks.remainder().iter().sum();
    for chunk in chunks {
        for (s, &v) in sums.iter_mut().zip(chunk) {
            *s += v;
        }
    }
    sums.iter().sum::<f32>() + tail
}

fn bench_frames(c: &mut Criterion) {
    let full = rooitou();
    let half = downsample2(&full);
    let quarter = downsample2(&half);
    let frames = [
        ("128x64", downsample2(&quarter)),
        ("256x128", quarter),
        ("512x256", half),
        ("2048x1024", upsample2(&full)),
        ("1000x500", resize_nearest(&full, 1000, 500)),
        ("1920x960", resize_nearest(&full, 1920, 960)),
        ("1024x512", full),
    ];
    let mut group = c.benchmark_group("frame");
    for (size, frame) in &frames {
        let mut decomposer = Decomposer::new(DecomposeSettings::default()).expect("valid");
        group.bench_function(format!("default_256/{size}"), |b| {
            b.iter(|| decomposer.decompose(black_box(frame)))
        });
    }
    let raw = DecomposeSettings {
        lights: 256,
        filter_taps: None,
        merge_spacing_fraction: None,
        ..DecomposeSettings::default()
    };
    let mut decomposer = Decomposer::new(raw.clone()).expect("valid");
    // By name: frames added to the list above moved the index (from 2026-12-04 20:39 to
    // 2026-12-05 the cases below named 1024x512 decomposed the 512×256 frame).
    let full = &frames
        .iter()
        .find(|(size, _)| *size == "1024x512")
        .expect("the 1024x512 frame")
        .1;
    group.bench_function("raw_256/1024x512", |b| {
        b.iter(|| decomposer.decompose(black_box(full)))
    });
    let merged = DecomposeSettings {
        merge_spacing_fraction: Some(envlight::decompose::merge::DEFAULT_SPACING_FRACTION),
        ..DecomposeSettings::default()
    };
    let mut decomposer = Decomposer::new(merged.clone()).expect("valid");
    group.bench_function("filter_merge_256/1024x512", |b| {
        b.iter(|| decomposer.decompose(black_box(full)))
    });
    group.bench_function("read_only/1024x512", |b| {
        b.iter(|| read_frame(black_box(full)))
    });

    // Copies of the same frame, more bytes than the last-level cache, taken in turn: every frame
    // comes from memory, as a new frame of a live stream may (same lights as the cached case).
    let copies: Vec<HdrFrame> = (0..UNCACHED_COPIES).map(|_| full.clone()).collect();
    let mut decomposer = Decomposer::new(merged).expect("valid");
    let mut next = 0;
    group.bench_function("filter_merge_256_uncached/1024x512", |b| {
        b.iter(|| {
            next = (next + 1) % copies.len();
            decomposer.decompose(black_box(&copies[next]))
        })
    });
    let mut next = 0;
    group.bench_function("read_only_uncached/1024x512", |b| {
        b.iter(|| {
            next = (next + 1) % copies.len();
            read_frame(black_box(&copies[next]))
        })
    });

    // A pixel per frame, forwards and back: every light moves every frame.
    let turning: Vec<HdrFrame> = (0..14usize)
        .map(|k| full.turned_columns(if k <= 7 { k } else { 14 - k }))
        .collect();
    for (name, reuse) in [("turning_256", true), ("turning_256_no_reuse", false)] {
        let mut decomposer = Decomposer::new(DecomposeSettings::default()).expect("valid");
        decomposer.set_candidate_reuse(reuse);
        let mut next = 0;
        group.bench_function(format!("{name}/1024x512"), |b| {
            b.iter(|| {
                next = (next + 1) % turning.len();
                decomposer.decompose(black_box(&turning[next]))
            })
        });
    }
    group.finish();

    let mut unfiltered = Decomposer::new(raw.clone()).expect("valid");
    let sky = SkyOptions::default();
    let sky_lights: Vec<_> = (0..58usize)
        .map(|k| {
            let t = if k < 30 { k } else { 58 - k };
            unfiltered
                .decompose(&render_sky(&sky, t as f64 / 30.0))
                .lights
        })
        .collect();
    let mut group = c.benchmark_group("filter");
    for bright in BrightHistory::ALL {
        let mut filter = FirFilter::with_default_taps().with_bright_history(bright);
        let mut next = 0;
        let mut lights = Vec::new();
        group.bench_function(format!("{}_256", bright.name()), |b| {
            b.iter(|| {
                next = (next + 1) % sky_lights.len();
                lights.clone_from(&sky_lights[next]);
                filter.apply(black_box(&mut lights));
            })
        });
    }
    group.finish();

    let (weights, w, h) = energy_weights(full, 4);
    c.bench_function("distribution/new_256x128", |b| {
        b.iter(|| PiecewiseConstant2d::new(black_box(&weights), w, h))
    });

    let fisheye = full
        .reprojected(
            Projection::Fisheye(FisheyeCalibration::default()),
            1280,
            960,
        )
        .expect("a valid size");
    let mut group = c.benchmark_group("frame");
    let one_thread = DecomposeSettings {
        resample_threads: 1,
        ..DecomposeSettings::default()
    };
    let mut decomposer = Decomposer::new(one_thread).expect("valid");
    group.bench_function("fisheye_256/1280x960", |b| {
        b.iter(|| decomposer.decompose(black_box(&fisheye)))
    });
    let mut decomposer = Decomposer::new(DecomposeSettings::default()).expect("valid");
    group.bench_function("fisheye_256_2threads/1280x960", |b| {
        b.iter(|| decomposer.decompose(black_box(&fisheye)))
    });
    group.finish();

    let mut group = c.benchmark_group("first_frame");
    group.sample_size(10);
    group.bench_function("fisheye_1280x960", |b| {
        b.iter(|| {
            let mut decomposer = Decomposer::new(DecomposeSettings::default()).expect("valid");
            decomposer.decompose(black_box(&fisheye))
        })
    });
    group.finish();

    let mut group = c.benchmark_group("solid_angles");
    let projections = FisheyeModel::ALL
        .into_iter()
        .map(|model| {
            let calibration = FisheyeCalibration {
                model,
                ..Default::default()
            };
            (model.name(), Projection::Fisheye(calibration))
        })
        .chain([
            ("angular", Projection::AngularMap),
            ("latlong", Projection::LatLong),
        ]);
    for (name, projection) in projections {
        group.bench_function(format!("{name}_1280x960"), |b| {
            b.iter(|| black_box(&projection).solid_angles(1280, 960))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(5));
    targets = bench_frames
}
criterion_main!(benches);
