//! How close warm-started refits get to a long fit of the same frame, and what they cost (issue
//! 6's target: a refit at ≥ 30 frames/s on one core within 2 % of a 6,000-iteration fit).
//!
//! Built-in sky at 30 frames/s (sun at 2°/s, clouds drifting), K = 16. Frame 0 is fitted with
//! the default first-frame schedule; frames 1…F are refitted warm with `n` iterations each (one
//! thread), for several `n`, with and without L_T. On frame F the loss L_R + L_D (no temporal
//! term) is compared with a 6,000-iteration fit of frame F started from the same previous
//! lobes. Times are CPU time of the fitting thread (`/proc/thread-self/schedstat`), median over
//! the F refits, so a loaded machine inflates them less than wall time.
//!
//! Run: `cargo run --release --example asg_refit [HEIGHT] [FRAMES] [WARM_RATE]`
//! (defaults 256, 8 and `FitSettings::default().warm_learning_rate`).

use envlight::asg::fit::{
    initial_lobes, loss, optimise, optimise_pyramid, AsgFitter, FitSettings, FitTarget,
};
use envlight::asg::Asg;
use envlight::capture::sky::{render_sky, SkyOptions};

/// CPU time of this thread in seconds (Linux), or wall time where that is unavailable.
fn cpu_seconds() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or_else(
            || {
                std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0.0, |d| d.as_secs_f64())
            },
            |ns| ns * 1e-9,
        )
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

fn main() {
    let mut args = std::env::args().skip(1);
    let height: u32 = args.next().and_then(|a| a.parse().ok()).unwrap_or(256);
    let frames: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(8);
    let defaults = FitSettings::default();
    let warm_learning_rate: f64 = args
        .next()
        .and_then(|a| a.parse().ok())
        .unwrap_or(defaults.warm_learning_rate);
    let settings = FitSettings {
        height,
        threads: 1,
        warm_learning_rate,
        ..defaults
    };
    let plain = FitSettings {
        temporal_weight: 0.0,
        ..settings.clone()
    };
    let sky = SkyOptions::default();
    let targets: Vec<FitTarget> = (0..=frames)
        .map(|i| {
            FitTarget::from_frame(
                &render_sky(&sky, i as f64 / 30.0),
                height,
                settings.diffuse_normals,
            )
            .expect("sky frame")
        })
        .collect();
    let mut fitter = AsgFitter::new(settings.clone()).expect("valid settings");
    let c0 = cpu_seconds();
    let first = fitter.fit_target(&targets[0]);
    let first_cpu = cpu_seconds() - c0;
    let last = &targets[frames];
    let score = |lobes: &[Asg]| loss(last, lobes, None, &plain).total;
    // Refit sequences: (name, lobes before frame F, lobes of F, median CPU time per refit).
    let mut rows: Vec<(String, Vec<Asg>, Vec<Asg>, f64)> = Vec::new();
    for &(its, wt) in &[
        (settings.warm_iterations, settings.temporal_weight),
        (3usize, settings.temporal_weight),
        (12, settings.temporal_weight),
        (30, settings.temporal_weight),
        (settings.warm_iterations, 0.0),
        (30, 0.0),
    ] {
        let mut f = fitter.clone();
        f.set_settings(FitSettings {
            warm_iterations: its,
            temporal_weight: wt,
            ..settings.clone()
        })
        .expect("valid settings");
        let mut before = first.lobes.clone();
        let mut times = Vec::new();
        for t in &targets[1..] {
            before = f.previous().map(<[Asg]>::to_vec).unwrap_or_default();
            let c = cpu_seconds();
            let _ = f.fit_target(t);
            times.push(cpu_seconds() - c);
        }
        let name = format!("warm refit, {its} iterations, L_T weight {wt}");
        if !rows.iter().any(|r| r.0 == name) {
            let now = f.previous().map(<[Asg]>::to_vec).unwrap_or_default();
            rows.push((name, before, now, median(times)));
        }
    }
    let c = cpu_seconds();
    let long = optimise(last, &rows[0].1, None, 6000, settings.learning_rate, &plain);
    let long_cpu = cpu_seconds() - c;
    let reference = score(&long.lobes);
    println!(
        "fit map {}x{height}, K = {}, frame {frames} of the sky; first frame {} iterations in {first_cpu:.2} s CPU; 6,000-iteration reference {long_cpu:.1} s CPU",
        2 * height,
        settings.lobes,
        settings.iterations,
    );
    println!(
        "| fit of frame {frames} | loss L_R + L_D | gap to 6,000 iterations | CPU time per refit |"
    );
    println!("|---|---:|---:|---:|");
    let row = |name: &str, l: f64, t: Option<f64>| {
        println!(
            "| {name} | {l:.5} | {:+.2} % | {} |",
            100.0 * (l / reference - 1.0),
            t.map_or("–".to_string(), |t| format!("{:.1} ms", 1e3 * t))
        )
    };
    row(
        &format!("frame {}'s lobes, no refit", frames - 1),
        score(&rows[0].1),
        None,
    );
    for (name, _, lobes, t) in &rows {
        row(name, score(lobes), Some(*t));
    }
    let cold = optimise_pyramid(
        last,
        &initial_lobes(last, settings.lobes),
        settings.iterations,
        settings.learning_rate,
        &plain,
    );
    row(
        &format!(
            "from scratch, first-frame schedule ({} iterations)",
            settings.iterations
        ),
        score(&cold.lobes),
        None,
    );
    row("6,000 iterations from the previous lobes", reference, None);
}
