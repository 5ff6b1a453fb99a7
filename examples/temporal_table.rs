//! Prints a Markdown table of temporal stability (DESIGN.md's temporal yardsticks) for each
//! light-generation method on slowly changing sequences:
//!
//! - **sky**: the built-in sky, 90 frames at 30 frames/s from its start (sun moving in a clear
//!   patch of sky, clouds drifting);
//! - **cloud over the sun**: the built-in sky from 6 s to 9 s, 90 frames, while a cloud drifts
//!   over the sun and its direct light falls to about a sixth;
//! - **pan**: a real HDRI turned about the vertical axis by one input pixel (0.35°) per frame,
//!   60 frames, as a camera panning slowly would see it;
//! - **sub-pixel pan**: the same turned by 0.37 input pixel per frame (linear interpolation), so
//!   that no frame is an exact pixel shift of the previous one (an exact shift favours methods
//!   whose splits are pixel-aligned, such as median cut).
//!
//! Columns: flicker of the diffuse irradiance and of the shadowed ground irradiance (the change
//! from frame to frame beyond the change of the truth, relative to the truth; 0 is perfectly
//! steady); the ground flicker again against the truth delayed by the filter's delay (what is
//! left is flicker that is not lag); the ground flicker against the *areal* truth (the map's
//! bright pixels read as areas, [`ReferenceMap::with_areal_bright_pixels`]) passed through the
//! method's own filter taps (unfiltered methods: the areal truth itself), so that a filter is
//! charged neither for its lag nor for smoothing the truth's own changes, nor for lights that
//! do not sit at a sun pixel's centre; and how far lights with the same id move per frame (mean,
//! 99th percentile and maximum over ids and frames; with `fade`, its fading lights count too).
//! Median cut has no stable ids, so its movement is not given. The truth is computed once per
//! sequence. "envlight (filter on)" is the default, whose filter folds the windows of bright
//! lights (`bright_history = "fold"`); the `fade` and `blend` rows are its alternatives.
//!
//! ```text
//! cargo run --release --example temporal_table -- tests/data/rooitou_park_1k.hdr
//! cargo run --release --example temporal_table -- tests/data/rooitou_park_1k.hdr sky,cloud
//! ```
//!
//! The optional second argument picks sequences (comma-separated, of `sky`, `cloud`, `pan`,
//! `subpixel`; default all). `METHODS="(filter on);split"` in the environment keeps only the
//! methods whose names contain one of the `;`-separated strings (and median cut).

use anyhow::{Context, Result};
use envlight::capture::image_file::read_hdr_image;
use envlight::capture::sky::{render_sky, SkyOptions};
use envlight::decompose::{
    BrightHistory, DecomposeSettings, Decomposer, LightPlacement, Warp, DEFAULT_PDF_EXPONENT,
};
use envlight::envmap::Projection;
use envlight::yardstick::{flicker, light_irradiance, low_passed, median_cut, ReferenceMap};
use envlight::{HdrFrame, LightFrame};

const LIGHTS: usize = 256;

/// Start of the "cloud over the sun" sequence: the default sky's sun is clear until about 6 s,
/// then a cloud passes it (src/capture/sky.rs, `the_default_sky_starts_with_a_clear_sun…`).
const CLOUD_START_S: f64 = 6.0;

/// A light-generation method over a sequence: `None` = median cut, else envlight settings.
struct Method {
    name: &'static str,
    settings: Option<DecomposeSettings>,
}

fn envlight(
    filter: bool,
    placement: LightPlacement,
    pdf_exponent: f64,
) -> Option<DecomposeSettings> {
    envlight_warp(filter, placement, pdf_exponent, Warp::Rows)
}

fn envlight_warp(
    filter: bool,
    placement: LightPlacement,
    pdf_exponent: f64,
    warp: Warp,
) -> Option<DecomposeSettings> {
    let defaults = DecomposeSettings::default();
    Some(DecomposeSettings {
        lights: LIGHTS,
        placement,
        pdf_exponent,
        warp,
        filter_taps: if filter {
            defaults.filter_taps.clone()
        } else {
            None
        },
        ..defaults
    })
}

/// The same settings with [`DecomposeSettings::concentrated_lloyd`] on.
fn with_concentrated_lloyd(settings: Option<DecomposeSettings>) -> Option<DecomposeSettings> {
    settings.map(|s| DecomposeSettings {
        concentrated_lloyd: true,
        ..s
    })
}

/// The default with the filter treating bright lights' windows as `bright` says.
fn with_bright_history(bright: BrightHistory) -> Option<DecomposeSettings> {
    envlight(true, LightPlacement::Centroid, DEFAULT_PDF_EXPONENT).map(|s| DecomposeSettings {
        bright_history: bright,
        ..s
    })
}

/// The default with the split of bright lights (`--split`).
fn with_split(filter: bool) -> Option<DecomposeSettings> {
    envlight(filter, LightPlacement::Centroid, DEFAULT_PDF_EXPONENT).map(|s| DecomposeSettings {
        split_factor: Some(envlight::decompose::split::DEFAULT_SPLIT_FACTOR),
        ..s
    })
}

/// Input pixels the sub-pixel pan turns per frame: not a whole pixel, so no method sees an exact
/// copy of the previous frame shifted.
const SUB_PIXEL_STEP: f64 = 0.37;

fn angle_deg(a: [f32; 3], b: [f32; 3]) -> f64 {
    let dot: f64 = a
        .iter()
        .zip(&b)
        .map(|(x, y)| f64::from(*x) * f64::from(*y))
        .sum();
    dot.clamp(-1.0, 1.0).acos().to_degrees()
}

/// Irradiance at the evaluation points, per frame.
type Series = Vec<Vec<[f64; 3]>>;

/// Per frame, the true diffuse and shadowed-ground irradiance, and the ground irradiance with
/// the bright pixels read as areas ([`ReferenceMap::with_areal_bright_pixels`]).
struct Truths {
    diffuse: Series,
    ground: Series,
    areal_ground: Series,
}

/// Sub-pixels per side of the areal truth's bright pixels.
const AREAL_SPLIT: u32 = 8;

fn truths(frames: &[HdrFrame]) -> Result<Truths> {
    let mut truths = Truths {
        diffuse: vec![],
        ground: vec![],
        areal_ground: vec![],
    };
    for frame in frames {
        let reference = ReferenceMap::new(frame, 256)?;
        let truth = reference.truth();
        truths.diffuse.push(truth.diffuse.clone());
        truths.ground.push(truth.ground.clone());
        let areal = ReferenceMap::with_areal_bright_pixels(frame, 256, AREAL_SPLIT)?;
        truths.areal_ground.push(areal.truth().ground.clone());
    }
    Ok(truths)
}

fn row(sequence: &str, frames: &[HdrFrame], truths: &Truths, method: &Method) -> Result<String> {
    let mut decomposer = method.settings.clone().map(Decomposer::new).transpose()?;
    let (mut approx_d, mut approx_g) = (vec![], vec![]);
    let mut moves = Vec::new();
    let mut previous: Option<LightFrame> = None;
    for frame in frames {
        let lights = match &mut decomposer {
            Some(d) => d.decompose(frame),
            None => median_cut(frame, LIGHTS)?,
        };
        let (d, g) = light_irradiance(&lights.lights);
        approx_d.push(d);
        approx_g.push(g);
        if let (Some(prev), true) = (&previous, decomposer.is_some()) {
            for l in &lights.lights {
                if let Some(p) = prev.lights.iter().find(|p| p.id == l.id) {
                    moves.push(angle_deg(p.dir, l.dir));
                }
            }
        }
        previous = Some(lights);
    }
    let movement = if moves.is_empty() {
        "— | — | —".to_string()
    } else {
        moves.sort_by(f64::total_cmp);
        let mean = moves.iter().sum::<f64>() / moves.len() as f64;
        let p99 = moves[(moves.len() - 1) * 99 / 100];
        let max = moves[moves.len() - 1];
        format!("{mean:.3}° | {p99:.2}° | {max:.1}°")
    };
    // The same flicker against the truth delayed by the filter's lag: what is left is the
    // flicker that is not lag.
    let delay = decomposer
        .as_ref()
        .map_or(0, |d| d.filter_delay_frames().round() as usize)
        .min(approx_g.len());
    let truth_g = &truths.ground;
    let lag_free = flicker(&approx_g[delay..], &truth_g[..truth_g.len() - delay]);
    // Against the areal truth passed through the method's own filter: neither lag nor the
    // smoothing of the truth's own changes counts, nor the point reading of the sun's pixels.
    let taps = method
        .settings
        .as_ref()
        .and_then(|s| s.filter_taps.as_deref());
    let areal_reference = match taps {
        Some(taps) => low_passed(&truths.areal_ground, taps),
        None => truths.areal_ground.clone(),
    };
    Ok(format!(
        "| {sequence} | {} | {:.4} | {:.4} | {lag_free:.4} | {:.4} | {movement} |",
        method.name,
        flicker(&approx_d, &truths.diffuse),
        flicker(&approx_g, truth_g),
        flicker(&approx_g, &areal_reference),
    ))
}

/// The sequences' keys, in the table's order.
const SEQUENCE_KEYS: [&str; 4] = ["sky", "cloud", "pan", "subpixel"];

fn main() -> Result<()> {
    let chosen: Vec<String> = match std::env::args().nth(2) {
        Some(list) => list.split(',').map(str::to_owned).collect(),
        None => SEQUENCE_KEYS.map(String::from).to_vec(),
    };
    for key in &chosen {
        anyhow::ensure!(
            SEQUENCE_KEYS.contains(&key.as_str()),
            "unknown sequence {key:?} (expected sky, cloud, pan or subpixel)"
        );
    }
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "tests/data/rooitou_park_1k.hdr".into());
    let image = read_hdr_image(std::path::Path::new(&path))?;
    let still = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .context("empty image")?;
    let pan: Vec<HdrFrame> = (0..60).map(|t| still.turned_columns(t)).collect();
    let slow_pan: Vec<HdrFrame> = (0..60)
        .map(|t| still.turned_by(SUB_PIXEL_STEP * f64::from(t)))
        .collect();
    let options = SkyOptions::default();
    let sky: Vec<HdrFrame> = (0..90)
        .map(|t| render_sky(&options, f64::from(t) / 30.0))
        .collect();
    let cloud: Vec<HdrFrame> = (0..90)
        .map(|t| render_sky(&options, CLOUD_START_S + f64::from(t) / 30.0))
        .collect();
    let sequences = [
        ("sky", "sky (90 frames)", &sky),
        ("cloud", "cloud over the sun (90 frames)", &cloud),
        ("pan", "pan of the map (60 frames)", &pan),
        ("subpixel", "sub-pixel pan (60 frames)", &slow_pan),
    ];

    let methods = [
        Method {
            name: "median cut",
            settings: None,
        },
        Method {
            name: "envlight (filter on)",
            settings: envlight(true, LightPlacement::Centroid, DEFAULT_PDF_EXPONENT),
        },
        Method {
            name: "envlight, filter with `fade`",
            settings: with_bright_history(BrightHistory::Fade),
        },
        Method {
            name: "envlight, filter with `blend` (before 2026-12-01)",
            settings: with_bright_history(BrightHistory::Blend),
        },
        Method {
            name: "envlight, no filter",
            settings: envlight(false, LightPlacement::Centroid, DEFAULT_PDF_EXPONENT),
        },
        Method {
            name: "envlight, split, filter on",
            settings: with_split(true),
        },
        Method {
            name: "envlight, split, no filter",
            settings: with_split(false),
        },
        Method {
            name: "envlight, hierarchical warp, filter on",
            settings: envlight_warp(
                true,
                LightPlacement::Centroid,
                DEFAULT_PDF_EXPONENT,
                Warp::Hierarchical,
            ),
        },
        Method {
            name: "envlight, hierarchical warp, no filter",
            settings: envlight_warp(
                false,
                LightPlacement::Centroid,
                DEFAULT_PDF_EXPONENT,
                Warp::Hierarchical,
            ),
        },
        Method {
            name: "envlight, concentrated Lloyd step, filter on",
            settings: with_concentrated_lloyd(envlight(
                true,
                LightPlacement::Centroid,
                DEFAULT_PDF_EXPONENT,
            )),
        },
        Method {
            name: "envlight, concentrated Lloyd step, no filter",
            settings: with_concentrated_lloyd(envlight(
                false,
                LightPlacement::Centroid,
                DEFAULT_PDF_EXPONENT,
            )),
        },
        Method {
            name: "envlight, γ=0.5, filter on",
            settings: envlight(true, LightPlacement::Centroid, 0.5),
        },
        Method {
            name: "Havran-style (γ=1, sample point, filter on)",
            settings: envlight(true, LightPlacement::SamplePoint, 1.0),
        },
    ];
    // METHODS="a;b": only the methods whose names contain one of these (median cut always).
    let only: Option<Vec<String>> = std::env::var("METHODS")
        .ok()
        .map(|m| m.split(';').map(str::to_owned).collect());
    let methods: Vec<&Method> = methods
        .iter()
        .filter(|m| {
            m.settings.is_none()
                || only
                    .as_ref()
                    .is_none_or(|o| o.iter().any(|k| m.name.contains(k.as_str())))
        })
        .collect();
    println!("| sequence | method | diffuse flicker | ground flicker | ground flicker, lag removed | ground flicker against the filtered areal truth | mean move/frame | p99 move | max move |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for (_, name, frames) in sequences
        .iter()
        .filter(|(key, _, _)| chosen.iter().any(|c| c == key))
    {
        let truths = truths(frames)?;
        for method in &methods {
            println!("{}", row(name, frames, &truths, method)?);
        }
    }
    Ok(())
}
