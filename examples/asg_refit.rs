//! How close a warm-started refit gets to a long fit of the same frame (issue 6's target: within
//! 2 % of a 6,000-iteration fit). Built-in sky, frames 0 and 1 (1/30 s apart), K = 16.
//!
//! Run: `cargo run --release --example asg_refit [HEIGHT]` (default fit-map height 128).

use envlight::asg::fit::{initial_lobes, loss, optimise, FitSettings, FitTarget};
use envlight::capture::sky::{render_sky, SkyOptions};

fn main() {
    let height: u32 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(128);
    let settings = FitSettings {
        height,
        ..FitSettings::default()
    };
    let sky = SkyOptions::default();
    let t0 =
        FitTarget::from_frame(&render_sky(&sky, 0.0), height, settings.diffuse_normals).unwrap();
    let t1 = FitTarget::from_frame(
        &render_sky(&sky, 1.0 / 30.0),
        height,
        settings.diffuse_normals,
    )
    .unwrap();
    let first = optimise(
        &t0,
        &initial_lobes(&t0, settings.lobes),
        None,
        settings.iterations,
        settings.learning_rate,
        &settings,
    );
    // Compare reconstruction + diffuse loss (no temporal term) on frame 1.
    let plain = FitSettings {
        temporal_weight: 0.0,
        ..settings.clone()
    };
    let score = |lobes: &[envlight::asg::Asg]| loss(&t1, lobes, None, &plain).total;
    let long = optimise(
        &t1,
        &first.lobes,
        None,
        6000,
        settings.learning_rate,
        &plain,
    );
    let reference = score(&long.lobes);
    println!(
        "fit map {}x{}, K = {}; loss of frame 1 (L_R + L_D):",
        2 * height,
        height,
        settings.lobes
    );
    println!("| fit of frame 1 | loss | gap to 6,000 iterations |");
    println!("|---|---:|---:|");
    let row = |name: &str, l: f64| {
        println!(
            "| {name} | {l:.5} | {:+.2} % |",
            100.0 * (l / reference - 1.0)
        )
    };
    row("frame 0's lobes, no refit", score(&first.lobes));
    for its in [30, 100, 300] {
        let warm = optimise(
            &t1,
            &first.lobes,
            Some(&first.lobes),
            its,
            settings.warm_learning_rate,
            &settings,
        );
        row(
            &format!("warm start + L_T, {its} iterations"),
            score(&warm.lobes),
        );
    }
    for (its, lr) in [
        (30, settings.warm_learning_rate),
        (30, settings.learning_rate),
        (300, settings.learning_rate),
    ] {
        let warm = optimise(&t1, &first.lobes, None, its, lr, &plain);
        row(
            &format!("warm start, no L_T, {its} iterations, rate {lr}"),
            score(&warm.lobes),
        );
    }
    let cold = optimise(
        &t1,
        &initial_lobes(&t1, settings.lobes),
        None,
        settings.iterations,
        settings.learning_rate,
        &plain,
    );
    row("from scratch, 300 iterations", score(&cold.lobes));
    row("6,000 iterations from frame 0's lobes", reference);
}
