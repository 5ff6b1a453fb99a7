//! Runs the default decomposition of one map many times (for `perf record` and timing).
//!
//! ```text
//! cargo run --release --example profile_decompose -- tests/data/rooitou_park_1k.hdr 2000
//! cargo run --release --example profile_decompose -- sky 3000 128
//! cargo run --release --example profile_decompose -- turn:tests/data/rooitou_park_1k.hdr 2000 - no-reuse
//! cargo run --release --example profile_decompose -- fisheye:tests/data/rooitou_park_1k.hdr 2000
//! cargo run --release --example profile_decompose -- tests/data/st_peters_square_night_1k.hdr 2000 - lloyd
//! ```
//!
//! Arguments: the map (an .hdr file; `turn:` before it turns the map about the zenith by a
//! pixel per frame, 8 frames forwards and back, so every light moves every frame; `fisheye:`
//! before that sees the map through a 1280×960 equidistant fisheye, a camera's frames; or `sky` for
//! one second of the built-in sky at 256×128, 60 frames played forwards and back, as the
//! streaming bench uses them),
//! the number of frames, optionally the working width (`-` or nothing: the decomposition's
//! default), then any of `no-reuse` (build the region pass's candidate lists afresh every frame)
//! `lloyd` (the concentrated Lloyd step, `--concentrated-lloyd`), `no-refine` (without the
//! refinement of the concentrated sources' regions, `--no-refine-concentrated`), `blend` and
//! `fade` (`--bright-history`: the filter's treatment of bright lights; default `fold`),
//! `split` (the split of bright lights, `--split`) and
//! `merge` (`--merge`, the default spacing), `lights=N` (default 256) and `threads=N` (the
//! resampling threads of a fisheye frame, `decompose.resample_threads`; default 2).
//! Prints the mean, median, minimum, 95th and 99th percentile and maximum time per frame, how
//! often the region pass built its candidate lists (in full, and in stages), and a hash of the
//! last frame's lights (every field's bits), so that two builds can be checked to give the
//! same lights.
use envlight::capture::image_file::read_hdr_image;
use envlight::capture::sky::{render_sky, SkyOptions};
use envlight::decompose::{BrightHistory, DecomposeSettings, Decomposer};
use envlight::envmap::{FisheyeCalibration, Projection};
use envlight::HdrFrame;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .unwrap_or_else(|| "tests/data/rooitou_park_1k.hdr".into());
    let iterations: usize = args.next().map_or(Ok(1000), |s| s.parse())?;
    let mut settings = DecomposeSettings::default();
    if let Some(width) = args.next().filter(|w| w != "-") {
        settings.working_width = width.parse()?;
    }
    let mut reuse = true;
    for option in args {
        match option.as_str() {
            "no-reuse" => reuse = false,
            "lloyd" => settings.concentrated_lloyd = true,
            "no-refine" => settings.refine_concentrated = false,
            "split" => {
                settings.split_factor = Some(envlight::decompose::split::DEFAULT_SPLIT_FACTOR)
            }
            "blend" => settings.bright_history = BrightHistory::Blend,
            other if other.starts_with("lights=") => settings.lights = other[7..].parse()?,
            other if other.starts_with("threads=") => {
                settings.resample_threads = other[8..].parse()?
            }
            "fade" => settings.bright_history = BrightHistory::Fade,
            "merge" => {
                settings.merge_spacing_fraction =
                    Some(envlight::decompose::merge::DEFAULT_SPACING_FRACTION)
            }
            other => {
                anyhow::bail!(
                    "unknown option {other:?} (expected no-reuse, lloyd, no-refine, split, \
                     blend, fade, lights=N, threads=N or merge)"
                )
            }
        }
    }
    let frames: Vec<HdrFrame> = if path == "sky" {
        let options = SkyOptions {
            width: 256,
            height: 128,
            // The sky the documented figures were measured on (seed 0, the default until 2026-11-23).
            seed: 0,
            ..SkyOptions::default()
        };
        let second: Vec<HdrFrame> = (0..60)
            .map(|i| render_sky(&options, f64::from(i) / 60.0))
            .collect();
        // Forwards and back (0, 1, …, 59, 58, …, 1): the sky moves on continuously, where
        // jumping back from the last frame to the first would move the sun 2° in one frame.
        (0..118)
            .map(|k| second[if k < 60 { k } else { 118 - k }].clone())
            .collect()
    } else {
        let (fisheye, path) = match path.strip_prefix("fisheye:") {
            Some(path) => (true, path.to_string()),
            None => (false, path),
        };
        let (turn, path) = match path.strip_prefix("turn:") {
            Some(path) => (true, path),
            None => (false, path.as_str()),
        };
        let image = read_hdr_image(std::path::Path::new(path))?;
        let mut frame = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
            .ok_or_else(|| anyhow::anyhow!("empty image"))?;
        if fisheye {
            let camera = Projection::Fisheye(FisheyeCalibration::default());
            frame = frame
                .reprojected(camera, 1280, 960)
                .ok_or_else(|| anyhow::anyhow!("empty image"))?;
        }
        if turn {
            // 0, 1, …, 7, 6, …, 1 pixels: one pixel per frame, every frame.
            (0..14usize)
                .map(|k| frame.turned_columns(if k <= 7 { k } else { 14 - k }))
                .collect()
        } else {
            vec![frame]
        }
    };
    let mut decomposer = Decomposer::new(settings)?;
    decomposer.set_candidate_reuse(reuse);
    // The point set is computed once per process: keep it out of the timing.
    decomposer.decompose(&frames[0]);
    // Per-frame times: on a shared machine the median and the minimum say more than the mean.
    let mut times = Vec::with_capacity(iterations);
    let mut lights = 0;
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    for i in 0..iterations {
        let start = std::time::Instant::now();
        let frame = decomposer.decompose(&frames[i % frames.len()]);
        times.push(start.elapsed().as_secs_f64() * 1e3);
        lights += frame.lights.len();
        if i + 1 == iterations {
            // FNV-1a over every field of the last frame's lights.
            for l in &frame.lights {
                let words = [l.id]
                    .into_iter()
                    .chain(l.dir.iter().chain(&l.rgb).map(|v| v.to_bits()))
                    .chain([l.solid_angle.to_bits()]);
                for w in words {
                    hash = (hash ^ u64::from(w)).wrapping_mul(0x100_0000_01b3);
                }
            }
        }
    }
    let n = iterations.max(1);
    let mean = times.iter().sum::<f64>() / n as f64;
    times.sort_by(f64::total_cmp);
    let at = |q: f64| {
        times
            .get((q * times.len() as f64) as usize)
            .copied()
            .unwrap_or(0.0)
    };
    println!(
        "{mean:.3} ms per frame (median {:.3}, min {:.3}, p95 {:.3}, p99 {:.3}, max {:.3}), {} lights per frame, lights hash {hash:016x}, candidate lists built {} times in full and {} in stages",
        at(0.5),
        at(0.0),
        at(0.95),
        at(0.99),
        times.last().copied().unwrap_or(0.0),
        lights / n,
        decomposer.candidate_builds(),
        decomposer.candidate_staged_builds()
    );
    Ok(())
}
