//! Per-frame cost of the daemon's wavelet stage (`[wavelet]`, src/wavelet_stage.rs): the
//! resampling onto the octahedral map, the transform and the selection, each timed alone, and
//! the stage's `WaveletTransformer::transform` as a whole, on one thread.
//!
//! ```text
//! cargo run --release --example wavelet_stage_cost -- sky 300
//! cargo run --release --example wavelet_stage_cost -- tests/data/rooitou_park_1k.hdr 300 db4 128 1024
//! ```
//!
//! Arguments: the input (`sky`: 60 frames of the built-in sky at its default 512×256, cycled;
//! or an .hdr file, lat-long), frames to time (default 300), basis, side and coefficients
//! (default: the stage's, haar 64 256). Prints the median and 90th percentile of the wall time
//! per frame, and the thread's CPU time per frame (from /proc/thread-self/schedstat, so a
//! loaded machine shows up as wall ≫ CPU). The resampling plan is built once, before timing
//! (the stage builds it once per frame shape), and its cost is printed separately.
use envlight::capture::image_file::read_hdr_image;
use envlight::capture::sky::{render_sky, SkyOptions};
use envlight::envmap::Projection;
use envlight::wavelet::approx::Coefficients;
use envlight::wavelet::sphere::Resampler;
use envlight::wavelet::transform::Workspace;
use envlight::wavelet::Basis;
use envlight::wavelet_stage::{WaveletSettings, WaveletTransformer};
use envlight::HdrFrame;
use std::time::{Duration, Instant};

/// CPU time of the calling thread.
fn thread_cpu() -> Duration {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").unwrap_or_default();
    let nanos = text
        .split_whitespace()
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    Duration::from_nanos(nanos)
}

struct Timing {
    wall: Vec<Duration>,
    cpu: Duration,
}

fn time(frames: usize, mut f: impl FnMut(usize)) -> Timing {
    f(0); // warm-up
    let mut wall = Vec::with_capacity(frames);
    let cpu = thread_cpu();
    for i in 0..frames {
        let start = Instant::now();
        f(i);
        wall.push(start.elapsed());
    }
    let cpu = thread_cpu().saturating_sub(cpu);
    wall.sort_unstable();
    Timing { wall, cpu }
}

fn report(what: &str, t: &Timing) {
    let n = t.wall.len().max(1);
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!(
        "{what:<28} median {:7.3} ms  p90 {:7.3} ms  CPU {:7.3} ms per frame",
        ms(t.wall[n / 2]),
        ms(t.wall[(n * 9 / 10).min(n - 1)]),
        ms(t.cpu) / n as f64
    );
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let input = args.next().unwrap_or_else(|| "sky".into());
    let count: usize = args.next().map_or(Ok(300), |s| s.parse())?;
    let d = WaveletSettings::default();
    let basis = match args.next() {
        Some(name) => Basis::parse(&name)?,
        None => d.basis,
    };
    let side: usize = args.next().map_or(Ok(d.side), |s| s.parse())?;
    let k: usize = args.next().map_or(Ok(d.coefficients), |s| s.parse())?;
    let settings = WaveletSettings {
        basis,
        side,
        coefficients: k,
        // Filtered in time with the lights' taps, as the daemon's stage is by default.
        ..d
    };
    let frames: Vec<HdrFrame> = if input == "sky" {
        let options = SkyOptions {
            // The sky the documented figures were measured on (seed 0, the default until 2026-11-23).
            seed: 0,
            ..SkyOptions::default()
        };
        (0..60)
            .map(|i| render_sky(&options, f64::from(i) / 30.0))
            .collect()
    } else {
        let image = read_hdr_image(std::path::Path::new(&input))?;
        vec![
            HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
                .ok_or_else(|| anyhow::anyhow!("empty image"))?,
        ]
    };
    let f0 = &frames[0];
    println!(
        "{input}: {}x{} frames; {basis}, side {side}, {} levels, {k} coefficients; {count} frames timed",
        f0.width,
        f0.height,
        settings.levels()
    );
    let plan_start = Instant::now();
    let resampler = Resampler::new(f0.projection, f0.width, f0.height, side)?;
    println!(
        "resampling plan (once per frame shape): {:.1} ms",
        plan_start.elapsed().as_secs_f64() * 1e3
    );
    let frame = |i: usize| &frames[i % frames.len()];

    let maps: Vec<_> = frames
        .iter()
        .map(|f| resampler.resample(f))
        .collect::<Result<_, _>>()?;
    let mut ws = Workspace::new();
    let coefficients: Vec<_> = maps
        .iter()
        .map(|m| Coefficients::analyze_with(m.texels(), side, basis, settings.levels(), &mut ws))
        .collect::<Result<_, _>>()?;

    let resample = time(count, |i| {
        std::hint::black_box(resampler.resample(frame(i)).ok());
    });
    let transform = time(count, |i| {
        let m = &maps[i % maps.len()];
        std::hint::black_box(
            Coefficients::analyze_with(m.texels(), side, basis, settings.levels(), &mut ws).ok(),
        );
    });
    let select = time(count, |i| {
        std::hint::black_box(coefficients[i % coefficients.len()].truncate(k));
    });
    let mut transformer = WaveletTransformer::new(settings)?;
    let whole = time(count, |i| {
        std::hint::black_box(transformer.transform(frame(i)).ok());
    });
    report("1. resample", &resample);
    report("2. transform (3 channels)", &transform);
    report("3. keep the largest", &select);
    report("the stage (1 + 2 + 3)", &whole);
    Ok(())
}
