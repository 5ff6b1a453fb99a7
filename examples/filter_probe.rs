//! Where the per-light temporal filter's flicker comes from: the default FIR filter against
//! other ways to low-pass the same light lists, on the temporal table's four sequences
//! (docs/quality.md, "Temporal stability": "What the filter's flicker is").
//!
//! Every variant filters the same unfiltered light lists (256 lights, default settings) with the
//! default taps, except `pixels`, which filters the input frames pixel by pixel and decomposes
//! them unfiltered:
//!
//! - `none`: no filter;
//! - `fir, blend`: the library's per-id filter ([`FirFilter`]) with [`BrightHistory::Blend`],
//!   one light per id, a per-id mean for every light (the filter before 2026-12-01);
//! - `cluster A°`: per id, the window's samples are grouped into cones of A° (each sample joins
//!   the first group whose power-weighted mean lies within A°); the group holding the newest
//!   sample keeps the id and the others are emitted as extra, fading lights. Role changes (a
//!   light jumping from the sun to the sky) are then never blended into one direction;
//! - `fir, fold` (the default) and `fir, fade`: the library's filter with
//!   [`BrightHistory::Fold`] / [`BrightHistory::Fade`]: `cluster 0.1°` for the lights brighter
//!   than 10 × the frame's mean light (a sun's), the per-id mean for the others; the older
//!   groups go to the nearest light (`fold`) or are extra lights (`fade`). (The probe's own
//!   version of both, before they were in the library, gave the same table to the last digit.)
//! - `union`: every sample of the window is its own light, scaled by its tap — the exact
//!   linear filter of the light lists (≈ 7 × the lights);
//! - `rebin`: each sample of the window goes to the current frame's nearest light, which takes
//!   the sum and the power-weighted centroid (the energy is filtered per place, not per id);
//! - `pixels`: the input frames filtered pixel by pixel, then decomposed without a filter.
//!
//! Columns: the ground-shadow flicker of the temporal table (against the truth; against the
//! truth delayed by the filter's delay, 3 frames), the same against the *equally filtered truth*
//! (Σ_k w_k truth(t−k): what a perfect low-pass of the map would show, so a filter is not
//! charged for smoothing the truth's own changes), the same against the equally filtered
//! *areal* truth, the mean number of lights per frame, and the largest move per frame of a
//! light that keeps its id. (Unfiltered rows compare with the plain truths.)
//!
//! The areal truth ([`ReferenceMap::with_areal_bright_pixels`], 8 × 8 sub-pixels): the
//! yardstick's reference sums a bright pixel (a sun pixel) as one point at its centre, and an
//! unfiltered light that holds exactly one sun pixel sits exactly there, so it matches the
//! reference's hard shadow exactly, while a light anywhere else inside the pixel (a filtered
//! one, say) is charged for it. The areal truth reads the bright pixels as areas.
//!
//! ```text
//! cargo run --release --example filter_probe                 # all four sequences, ~80 s
//! SEQ=sky cargo run --release --example filter_probe         # one of sky, cloud, pan, subpixel
//! SEQ=sky TRACE=1 cargo run --release --example filter_probe # the sun's lights, frames 20–33
//! ```
//!
//! `TRACE=1` prints how many input pixels of frame 20 are above 1% of the brightest (the sun's
//! size in pixels), then, for the lights within 1° of the sun in frame 20, each one's offset
//! from the sun's centroid (in tenths of a degree) and its luminance, frame by frame: it shows
//! the sun's few input pixels changing hands between ids.
use anyhow::{Context, Result};
use envlight::capture::image_file::read_hdr_image;
use envlight::capture::sky::{render_sky, SkyOptions};
use envlight::decompose::filter::{DEFAULT_TAPS, FADING_ID_BASE, MAX_TAPS};
use envlight::decompose::{
    luminance_f64 as lum, BrightHistory, DecomposeSettings, Decomposer, FirFilter,
};
use envlight::envmap::Projection;
use envlight::light::Light;
use envlight::yardstick::{flicker, light_irradiance, low_passed, ReferenceMap};
use envlight::HdrFrame;
use glam::DVec3;

const LIGHTS: usize = 256;
/// Sub-pixels per side of the areal truth's bright pixels (4 and 8 agreed to 0.0001 on the sky
/// sequence, measured with a first version of the areal truth).
const AREAL_SPLIT: u32 = 8;

/// Irradiance at the evaluation points of every frame.
type Series = Vec<Vec<[f64; 3]>>;

fn direction(l: &Light) -> DVec3 {
    DVec3::from_array(l.dir.map(f64::from))
}

fn light_at(id: usize, dir: DVec3, rgb: [f64; 3], solid_angle: f64) -> Light {
    Light {
        id: id as u32,
        dir: dir.as_vec3().to_array(),
        rgb: rgb.map(|v| v as f32),
        solid_angle: solid_angle as f32,
    }
}

/// Power-weighted direction, rgb and solid angle accumulated over samples.
#[derive(Clone, Copy, Default)]
struct Sum {
    weighted_dir: DVec3,
    rgb: [f64; 3],
    solid_angle: f64,
}

impl Sum {
    fn add(&mut self, w: f64, sample: &Light) {
        let rgb = sample.rgb.map(f64::from);
        self.weighted_dir += w * lum(rgb).max(1e-30) * direction(sample);
        for (sum, c) in self.rgb.iter_mut().zip(rgb) {
            *sum += w * c;
        }
        self.solid_angle += w * f64::from(sample.solid_angle);
    }
}

/// Light `id`'s samples, newest first, one per tap: before the id's first frame, its oldest
/// sample repeats (as [`FirFilter`] starts). Empty when the newest frame lacks the id.
fn window_of(history: &[Vec<Light>], id: u32, taps: usize) -> Vec<Light> {
    let t = history.len() - 1;
    let mut out: Vec<Light> = Vec::with_capacity(taps);
    for k in 0..taps {
        let found = (k <= t)
            .then(|| history[t - k].iter().find(|m| m.id == id).copied())
            .flatten();
        match (found, out.last()) {
            (Some(s), _) => out.push(s),
            (None, Some(&last)) => out.push(last),
            (None, None) => break,
        }
    }
    out
}

/// The `cluster` variants for the newest frame of `history`: each light's window is grouped in
/// cones whose cosine `cos_max` gives for that light (1: `union`; −1: one group, the per-id
/// filter).
fn cluster_filter(
    history: &[Vec<Light>],
    taps: &[f64],
    cos_max: impl Fn(&Light) -> f64,
) -> Vec<Light> {
    let mut out = Vec::new();
    for newest in &history[history.len() - 1] {
        let cos_max = cos_max(newest);
        let mut groups: Vec<Sum> = Vec::new();
        for (w, sample) in taps.iter().zip(window_of(history, newest.id, taps.len())) {
            let d = direction(&sample);
            let slot = groups
                .iter()
                .position(|g| g.weighted_dir.try_normalize().unwrap_or(d).dot(d) >= cos_max);
            let i = slot.unwrap_or_else(|| {
                groups.push(Sum::default());
                groups.len() - 1
            });
            groups[i].add(*w, &sample);
        }
        for (i, g) in groups.iter().enumerate() {
            let id = if i == 0 {
                newest.id as usize
            } else {
                FADING_ID_BASE as usize + newest.id as usize * MAX_TAPS + i
            };
            let dir = g.weighted_dir.try_normalize().unwrap_or(direction(newest));
            out.push(light_at(id, dir, g.rgb, g.solid_angle));
        }
    }
    out
}

/// The `rebin` variant for the newest frame of `history`.
fn rebin_filter(history: &[Vec<Light>], taps: &[f64]) -> Vec<Light> {
    let t = history.len() - 1;
    let current = &history[t];
    let dirs: Vec<DVec3> = current.iter().map(direction).collect();
    let mut sums = vec![Sum::default(); current.len()];
    for (k, w) in taps.iter().enumerate() {
        for sample in &history[t.saturating_sub(k)] {
            let d = direction(sample);
            let nearest = (0..dirs.len())
                .max_by(|&a, &b| dirs[a].dot(d).total_cmp(&dirs[b].dot(d)))
                .unwrap_or(0);
            sums[nearest].add(*w, sample);
        }
    }
    current
        .iter()
        .zip(&sums)
        .map(|(l, s)| {
            let dir = s.weighted_dir.try_normalize().unwrap_or(direction(l));
            light_at(l.id as usize, dir, s.rgb, s.solid_angle)
        })
        .collect()
}

/// The frames filtered pixel by pixel with `taps` (the first frame repeating before the start).
fn pixel_filtered(frames: &[HdrFrame], taps: &[f64]) -> Vec<HdrFrame> {
    (0..frames.len())
        .map(|t| {
            let mut frame = frames[t].clone();
            for (i, p) in frame.pixels.iter_mut().enumerate() {
                let mut acc = [0.0f64; 3];
                for (k, w) in taps.iter().enumerate() {
                    let q = frames[t.saturating_sub(k)].pixels[i];
                    for (a, q) in acc.iter_mut().zip(q) {
                        *a += w * f64::from(q);
                    }
                }
                *p = acc.map(|v| v as f32);
            }
            frame
        })
        .collect()
}

fn unfiltered(frames: &[HdrFrame]) -> Result<Vec<Vec<Light>>> {
    let mut decomposer = Decomposer::new(DecomposeSettings {
        lights: LIGHTS,
        filter_taps: None,
        ..DecomposeSettings::default()
    })?;
    Ok(frames
        .iter()
        .map(|f| decomposer.decompose(f).lights)
        .collect())
}

fn trace_sun(raw: &[Vec<Light>]) {
    let brightest = |l: &[Light]| {
        l.iter()
            .max_by(|a, b| a.luminance().total_cmp(&b.luminance()))
            .map(direction)
            .unwrap_or(DVec3::Y)
    };
    let Some(first) = raw.get(20) else { return };
    let sun0 = brightest(first);
    let ids: Vec<u32> = first
        .iter()
        .filter(|x| direction(x).dot(sun0) > 1f64.to_radians().cos())
        .map(|x| x.id)
        .take(8)
        .collect();
    for (t, lights) in raw.iter().enumerate().skip(20).take(14) {
        let centroid = lights
            .iter()
            .filter(|x| direction(x).dot(sun0) > 2f64.to_radians().cos())
            .map(|x| f64::from(x.luminance()) * direction(x))
            .sum::<DVec3>()
            .normalize();
        let e1 = DVec3::Y.cross(centroid).normalize();
        let e2 = centroid.cross(e1);
        let mut line = format!("frame {t}:");
        for id in &ids {
            if let Some(x) = lights.iter().find(|x| x.id == *id) {
                let d = direction(x);
                line += &format!(
                    " {id}({:+.1},{:+.1}; {:.0})",
                    d.dot(e1).asin().to_degrees() * 10.0,
                    d.dot(e2).asin().to_degrees() * 10.0,
                    x.luminance()
                );
            }
        }
        println!("{line}");
    }
}

fn main() -> Result<()> {
    let image = read_hdr_image(std::path::Path::new("tests/data/rooitou_park_1k.hdr"))?;
    let still = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .context("empty image")?;
    let sky = SkyOptions::default();
    let sequences: Vec<(&str, Vec<HdrFrame>)> = vec![
        (
            "sky",
            (0..90)
                .map(|t| render_sky(&sky, f64::from(t) / 30.0))
                .collect(),
        ),
        (
            "cloud",
            (0..90)
                .map(|t| render_sky(&sky, 6.0 + f64::from(t) / 30.0))
                .collect(),
        ),
        ("pan", (0..60).map(|t| still.turned_columns(t)).collect()),
        (
            "subpixel",
            (0..60)
                .map(|t| still.turned_by(0.37 * f64::from(t)))
                .collect(),
        ),
    ];
    let only = std::env::var("SEQ").ok();
    let sum: f64 = DEFAULT_TAPS.iter().sum();
    let taps: Vec<f64> = DEFAULT_TAPS.iter().map(|t| t / sum).collect();
    println!("| sequence | filter | ground flicker | lag removed | against the filtered truth | against the filtered areal truth | lights/frame | max move |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    for (name, frames) in &sequences {
        if only
            .as_deref()
            .is_some_and(|o| !o.split(',').any(|s| s == *name))
        {
            continue;
        }
        let (mut truth, mut areal_truth): (Series, Series) = (vec![], vec![]);
        for frame in frames {
            truth.push(ReferenceMap::new(frame, 256)?.truth().ground.clone());
            let areal = ReferenceMap::with_areal_bright_pixels(frame, 256, AREAL_SPLIT)?;
            areal_truth.push(areal.truth().ground.clone());
        }
        let filtered_truth = low_passed(&truth, &taps);
        let filtered_areal_truth = low_passed(&areal_truth, &taps);
        let raw = unfiltered(frames)?;
        if std::env::var("TRACE").is_ok() {
            if let Some(frame) = frames.get(20) {
                let lums: Vec<f32> = frame
                    .pixels
                    .iter()
                    .map(|&p| envlight::frame::luminance(p))
                    .collect();
                let brightest = lums.iter().copied().fold(0.0f32, f32::max);
                let sun = lums.iter().filter(|&&l| l > 0.01 * brightest).count();
                println!(
                    "frame 20: {}×{}, {sun} pixels above 1% of the brightest",
                    frame.width, frame.height
                );
            }
            trace_sun(&raw);
        }
        let library = |bright: BrightHistory| -> Vec<Vec<Light>> {
            let mut fir = FirFilter::with_default_taps().with_bright_history(bright);
            raw.iter()
                .map(|l| {
                    let mut l = l.clone();
                    fir.apply(&mut l);
                    l
                })
                .collect()
        };
        let delay_frames = FirFilter::with_default_taps().delay_frames().round() as usize;
        let fir_lights = library(BrightHistory::Blend);
        let each_frame = |f: &dyn Fn(&[Vec<Light>]) -> Vec<Light>| {
            (0..raw.len()).map(|t| f(&raw[..=t])).collect::<Vec<_>>()
        };
        let mut variants: Vec<(String, Vec<Vec<Light>>)> = vec![
            ("none".into(), raw.clone()),
            ("fir, blend".into(), fir_lights),
        ];
        for angle in [2.0f64, 10.0, 30.0] {
            let cos = angle.to_radians().cos();
            variants.push((
                format!("cluster {angle}°"),
                each_frame(&|h| cluster_filter(h, &taps, |_| cos)),
            ));
        }
        variants.push(("fir, fold".into(), library(BrightHistory::Fold)));
        variants.push(("fir, fade".into(), library(BrightHistory::Fade)));
        variants.push((
            "union".into(),
            each_frame(&|h| cluster_filter(h, &taps, |_| 1.0)),
        ));
        variants.push(("rebin".into(), each_frame(&|h| rebin_filter(h, &taps))));
        variants.push(("pixels".into(), unfiltered(&pixel_filtered(frames, &taps))?));
        for (variant, lists) in &variants {
            let ground: Series = lists.iter().map(|l| light_irradiance(l).1).collect();
            let mut max_move: f64 = 0.0;
            for pair in lists.windows(2) {
                for l in pair[1].iter().filter(|l| l.id < FADING_ID_BASE) {
                    if let Some(p) = pair[0].iter().find(|p| p.id == l.id) {
                        let cos = direction(l).dot(direction(p)).clamp(-1.0, 1.0);
                        max_move = max_move.max(cos.acos().to_degrees());
                    }
                }
            }
            let is_filtered = variant != "none";
            let delay = if is_filtered { delay_frames } else { 0 };
            let (reference, areal_reference) = if is_filtered {
                (&filtered_truth, &filtered_areal_truth)
            } else {
                (&truth, &areal_truth)
            };
            let count: usize = lists.iter().map(Vec::len).sum();
            println!(
                "| {name} | {variant} | {:.4} | {:.4} | {:.4} | {:.4} | {:.0} | {max_move:.1}° |",
                flicker(&ground, &truth),
                flicker(&ground[delay..], &truth[..truth.len() - delay]),
                flicker(&ground, reference),
                flicker(&ground, areal_reference),
                count as f64 / lists.len() as f64,
            );
        }
    }
    Ok(())
}
