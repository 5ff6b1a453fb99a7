//! Frame time against light count (16, 64, 256, 512) at 640×360, culling on and off, on the
//! adapter wgpu picks (a GPU, else lavapipe). Every light has a shadow map (512² texels by
//! default). Criterion measures wall time of a whole frame: encode, submit, wait; the GPU
//! timestamp figure, where the adapter has timestamps, is printed beside it.
//!
//! `cargo bench --bench render`; `ENVLIGHT_BENCH_LIGHTS=16,64` and `ENVLIGHT_BENCH_SIZE=1280x720`
//! and `ENVLIGHT_BENCH_SHADOW_RES=1024` change the grid (e.g. for the real-GPU target of 256
//! shadowed lights at 1280×720 under 8 ms); `ENVLIGHT_BENCH_RASTER=compute` (or `pipeline`, or
//! both, comma-separated: the default) picks how the shadow maps are drawn, one benchmark group
//! each.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, SamplingMode};
use envlight::light::Light;
use envlight::render::scene::Scene;
use envlight::render::{RenderSettings, Renderer, ShadowRaster};
use std::f32::consts::PI;
use std::time::Duration;

/// `n` lights on a Fibonacci sphere, brighter above the horizon and towards a sun.
fn lights(n: usize) -> Vec<Light> {
    let sun = glam::Vec3::new(0.5, 0.7, 0.4).normalize();
    let golden = PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - y * y).sqrt();
            let phi = golden * i as f32;
            let d = glam::Vec3::new(r * phi.cos(), y, r * phi.sin());
            let w = 4.0 * PI / n as f32;
            let s = (1.0 + 3.0 * d.y.max(0.0)) * (1.0 + 20.0 * d.dot(sun).max(0.0).powi(8)) * w;
            Light {
                id: i as u32,
                dir: d.to_array(),
                rgb: [20.0 * s, 22.0 * s, 25.0 * s],
                solid_angle: w,
            }
        })
        .collect()
}

fn env_list(name: &str, default: &[u32]) -> Vec<u32> {
    std::env::var(name)
        .ok()
        .map(|s| s.split(',').filter_map(|v| v.trim().parse().ok()).collect())
        .unwrap_or_else(|| default.to_vec())
}

fn bench(c: &mut Criterion) {
    let counts = env_list("ENVLIGHT_BENCH_LIGHTS", &[16, 64, 256, 512]);
    let size = std::env::var("ENVLIGHT_BENCH_SIZE").unwrap_or_else(|_| "640x360".into());
    let (w, h) = size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
        .expect("ENVLIGHT_BENCH_SIZE is WxH");
    let shadow_res = env_list("ENVLIGHT_BENCH_SHADOW_RES", &[512])[0];
    let rasters: Vec<ShadowRaster> = std::env::var("ENVLIGHT_BENCH_RASTER")
        .unwrap_or_else(|_| "pipeline,compute".into())
        .split(',')
        .map(|s| {
            ShadowRaster::parse(s.trim()).unwrap_or_else(|| {
                panic!("ENVLIGHT_BENCH_RASTER: {s:?} is not auto, pipeline or compute")
            })
        })
        .collect();
    for raster in rasters {
        bench_raster(c, &counts, (w, h), shadow_res, raster);
    }
}

fn bench_raster(
    c: &mut Criterion,
    counts: &[u32],
    (w, h): (u32, u32),
    shadow_res: u32,
    raster: ShadowRaster,
) {
    let settings = RenderSettings {
        width: w,
        height: h,
        shadow_resolution: shadow_res,
        shadow_raster: raster,
        ..Default::default()
    };
    let mut renderer = Renderer::new(Scene::default_scene(), settings)
        .unwrap_or_else(|e| panic!("the render benchmark needs a graphics adapter: {e}"));
    eprintln!("adapter: {}", renderer.gpu().describe());
    let mut group = c.benchmark_group(format!(
        "render_{w}x{h}_shadow{shadow_res}_{}",
        raster.name()
    ));
    // Frames take seconds on lavapipe: one frame per sample, 10 samples.
    group.sampling_mode(SamplingMode::Flat);
    group.sample_size(10);
    group.warm_up_time(Duration::from_millis(100));
    group.measurement_time(Duration::from_secs(1));
    for &n in counts {
        let set = lights(n as usize);
        for culling in [true, false] {
            renderer.set_culling(culling);
            // One untimed frame: allocates the shadow array for this count.
            let first = renderer.render_timed(&set).expect("render");
            let ms = |v: Option<f64>| v.map_or("n/a".to_string(), |ms| format!("{ms:.2} ms"));
            eprintln!(
                "{} maps, {n} lights, culling {}: {} shadow maps, GPU timestamps {} (shadow \
                 maps {})",
                raster.name(),
                if culling { "on" } else { "off" },
                first.shadow_maps,
                ms(first.gpu_ms),
                ms(first.shadow_gpu_ms),
            );
            let id = BenchmarkId::new(if culling { "culling_on" } else { "culling_off" }, n);
            group.bench_with_input(id, &set, |b, set| {
                b.iter(|| renderer.render_timed(set).expect("render"))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
