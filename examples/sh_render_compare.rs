//! How close SH lighting comes to the lights: renders the built-in scene (spheres of diffuse,
//! metal and plastic on a ground) without shadows under each given lat-long map, once with 1024
//! of envlight's lights (one frame, no temporal filter: the reference; 64 lights already hold
//! these maps' irradiance to 0.13–0.44 %, docs/sh.md) and once with SH lighting at degrees 1, 2, 4
//! and 8, and prints a Markdown row per map and degree: the relative RMS difference of the
//! shaded RGB over the objects' pixels (the spheres and the box, not the ground) with every
//! material made Lambertian (the diffuse light alone) and with the scene's own materials
//! (glossy plastic, metal, rough plastic), over the whole image with its own materials, and the
//! median frame time of the SH pass over 5 frames (GPU timestamps where the adapter has them).
//!
//! ```text
//! cargo run --release --example sh_render_compare -- tests/data/*.hdr
//! ```
//!
//! A file that cannot be read is reported on stderr and skipped; the exit status is then 1.

mod common;

use anyhow::Result;
use envlight::decompose::{DecomposeSettings, Decomposer};
use envlight::render::scene::Scene;
use envlight::render::{Image, RenderSettings, Renderer};
use std::path::Path;

const DEGREES: [usize; 4] = [1, 2, 4, 8];
const WIDTH: u32 = 320;
const HEIGHT: u32 = 180;

/// √(Σ|a − b|² / Σ|b|²) over the pixels where `keep` holds and the reference is opaque.
fn relative_rms(got: &Image, reference: &Image, keep: impl Fn(u32, u32) -> bool) -> f64 {
    let (mut diff, mut norm) = (0.0f64, 0.0f64);
    for y in 0..reference.height {
        for x in 0..reference.width {
            let r = reference.pixel(x, y);
            if r[3] <= 0.0 || !keep(x, y) {
                continue;
            }
            let g = got.pixel(x, y);
            for c in 0..3 {
                diff += f64::from(g[c] - r[c]).powi(2);
                norm += f64::from(r[c]).powi(2);
            }
        }
    }
    (diff / norm.max(f64::MIN_POSITIVE)).sqrt()
}

fn rows(path: &Path) -> Result<Vec<String>> {
    let frame = common::read_latlong_map(path)?;
    let name = path.file_stem().map_or_else(
        || path.display().to_string(),
        |s| s.to_string_lossy().into(),
    );
    let settings = DecomposeSettings {
        lights: 1024,
        filter_taps: None,
        ..DecomposeSettings::default()
    };
    let lights = Decomposer::new(settings)?.decompose(&frame);
    // The objects (three spheres and a box): the pixels that stay opaque when the ground is
    // a shadow catcher, which without shadows is transparent.
    let settings = RenderSettings {
        width: WIDTH,
        height: HEIGHT,
        shadows: false,
        ..RenderSettings::default()
    };
    let (objects, _) = Renderer::new(
        Scene::default_scene(),
        RenderSettings {
            shadow_catcher: true,
            ..settings
        },
    )?
    .render(&lights.lights)?;
    let on_an_object = |x: u32, y: u32| objects.pixel(x, y)[3] > 0.5;
    // The same scene with every material Lambertian (its base colour), for the diffuse light
    // alone.
    let mut lambertian = Scene::default_scene();
    for m in &mut lambertian.materials {
        *m = envlight::render::scene::Material::lambertian(m.base_color);
    }
    let mut diffuse = Renderer::new(lambertian, settings)?;
    let mut full = Renderer::new(Scene::default_scene(), settings)?;
    let (diffuse_reference, _) = diffuse.render(&lights.lights)?;
    let (full_reference, _) = full.render(&lights.lights)?;
    let mut rows = Vec::new();
    for degree in DEGREES {
        let sh = envlight::sh::project(&frame, degree);
        let (diffuse_image, _) = diffuse.render_sh(&sh)?;
        let (full_image, _) = full.render_sh(&sh)?;
        let mut times: Vec<f64> = (0..5)
            .map(|_| full.render_sh_timed(&sh).map(|s| s.frame_ms()))
            .collect::<Result<_, _>>()?;
        times.sort_by(f64::total_cmp);
        rows.push(format!(
            "| {name} | {degree} | {:.4} | {:.4} | {:.4} | {:.1} |",
            relative_rms(&diffuse_image, &diffuse_reference, on_an_object),
            relative_rms(&full_image, &full_reference, on_an_object),
            relative_rms(&full_image, &full_reference, |_, _| true),
            times[2]
        ));
    }
    Ok(rows)
}

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        eprintln!("usage: sh_render_compare MAP.hdr|MAP.exr...");
        std::process::exit(2);
    }
    println!(
        "| map | SH degree | objects, Lambertian | objects, own materials | whole image | SH pass ms (median of 5) |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    let mut failed = false;
    for path in &paths {
        match rows(Path::new(path)) {
            Ok(rows) => rows.iter().for_each(|r| println!("{r}")),
            Err(e) => {
                eprintln!("{path}: {e:#}");
                failed = true;
            }
        }
    }
    if failed {
        std::process::exit(1);
    }
}
