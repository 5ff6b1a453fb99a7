//! Experiments behind docs/quality.md's "Why the five rows lose": a slow re-implementation of
//! the decomposition (brute-force nearest-light search in f64, no temporal filter or merge) with
//! switches, compared with median cut on the maps of the quality table.
//!
//! ```text
//! cargo run --release --example quality_probe -- g=0.75 / g=0.75 lloyd=1 / lib=1
//! ```
//!
//! Arguments: variants separated by `/`, each a list of `key=value` switches. Prints per variant
//! the rows won of 72 (diffuse, glossy-16, glossy-128, ground-shadow), the geometric mean of
//! envlight ÷ median cut per yardstick, and the rows lost. Switches: `g` density exponent γ;
//! `a` mixture weight of the uniform density; `m`, `g2` mixture weight and exponent of a second
//! density; `mx` every working pixel gets at least this × its energy share of the points (`mxc=1`:
//! concentrated pixels only; `mxb=B`: per block of B×B working pixels instead of per pixel, and
//! with `mxc=1` the blocks holding a concentrated pixel are left alone); `hw=1` the hierarchical
//! warp instead of the row-by-row one (also with `lib=1`); `pw=K` after the regions, a power
//! diagram (pixel → argmax d·s_i + w_i) whose weights shrink every light holding more than K ×
//! the mean energy (`pwi` iterations, 8; `pws` step, 1 × 2/N per unit of log energy ratio;
//! `pwc=1` leaves the lights holding concentrated input pixels alone; it redraws every region
//! from scratch and places lights at plain luminance centroids, so it ignores `p` and `hz`); `c`
//! concentrated share (× 1/N); `w` working width; `p` centroid weighted by radiance^p; `hz=1`
//! regions kept on one side of the horizon; `up` density factor of the upper hemisphere; `fw` fine warp inside concentrated
//! pixels with this exponent; `gc` density exponent inside concentrated working pixels only;
//! `lc=1` Lloyd steps move only the lights whose regions hold concentrated input pixels
//! (`LCSTAT=1` in the environment prints how many lights move and how much of the sphere their
//! regions cover);
//! `lloyd` Lloyd steps on the working map; `cl` one Lloyd step on a map coarser by this factor
//! (`cc=1`: coarse pixels at their luminance centroids, `cc=2`: assigned from their centres
//! with exact centroids; `cf=0`: without the concentrated pixels' input pixels); `fl=1`
//! (diagnostic, more than N lights) every input pixel of a concentrated working pixel is a
//! light of its own; `lib=1` the library's decomposition with `g`, `w` and `lc`
//! (`lc=1`: [`DecomposeSettings::concentrated_lloyd`], `lf=1`:
//! [`DecomposeSettings::refine_concentrated`], off unless given); `lf=1` with `lloyd=1 lc=1`:
//! after the Lloyd step only the concentrated input pixels are assigned again (the working
//! pixels keep their first regions); `sp=K` after the regions, lights holding concentrated
//! input pixels and more than K × the mean energy split into up to `spm` (8) pieces by k-means,
//! the weakest lights giving up their slots (`spa=1`: every light above K, concentrated or
//! not; `spw=1`: only the concentrated input pixels are clustered, the working pixels go as one
//! lump to the nearest piece; `spr=1`: a removed light goes whole to the nearest light; with
//! `lib=1`, `sp=K` is [`DecomposeSettings::split_factor`]; `SPSTAT=1`, without `lib`, prints
//! how many lights split); `spb=D` a fixed budget instead: the decomposition into N − N/D
//! lights, then N/D extra pieces given one at a time to the light of the largest energy per
//! piece (holding concentrated input pixels unless `spa=1`), no light removed.
//!
//! Environment: `NS=128,512` other light counts; `V=1` every cell; `DIAG=MAP:N` the lights with
//! the largest ground-shadow error of the first variant; `PNG=MAP:N` writes /tmp/probe.png with
//! the first variant's lights (red) and median cut's (green); `SKY=1` how far lights move
//! between two frames of the built-in sky 1/30 s apart; `PROF=c|s:GAMMA:ITERATIONS` times the
//! library's decomposition of rooitou_park (centroid or sample-point placement).
//!
//! Errors in arguments end the program with a message; this is a tool for experiments.
#[path = "../tests/test_data/mod.rs"]
mod test_data;
use anyhow::{Context, Result};
use envlight::capture::image_file::read_hdr_image;
use envlight::decompose::point_set::progressive_points;
use envlight::decompose::working_map::Resampler;
use envlight::decompose::{luminance_f64, DecomposeSettings, Decomposer, PiecewiseConstant2d};
use envlight::envmap::Projection;
use envlight::yardstick::{evaluate, median_cut, QualityReport, ReferenceMap};
use envlight::{HdrFrame, Light};
use glam::DVec3;
use std::path::Path;

#[derive(Clone, Debug)]
struct Opts {
    gamma: f64,
    alpha: f64,
    conc: f64,
    width: u32,
    cpow: f64,
    horizon: bool,
    finedir: bool,
    lib: bool,
    /// Extra density multiplier for the upper hemisphere.
    upper: f64,
    /// Iterations of Lloyd on top.
    lloyd: usize,
    /// Mixture weight of the second exponent's density.
    mix: f64,
    gamma2: f64,
    /// Diagnostic: fine samples become lights of their own (more than N lights).
    fine_lights: bool,
    /// Each pixel gets at least beta × its energy share of the samples.
    beta: f64,
    /// ... only concentrated pixels.
    beta_conc: bool,
    /// Apply beta per block of this many working pixels square (0 = per pixel); with `mxc=1`,
    /// blocks holding a concentrated pixel are left alone.
    beta_block: usize,
    /// The hierarchical warp instead of the row-by-row one.
    hierarchical: bool,
    /// Energy cap (× the mean light energy) of a power-diagram pass after the regions (0 = off).
    power_cap: f64,
    /// Iterations of that pass.
    power_iterations: usize,
    /// Step of that pass (× 2/N per unit of log energy ratio).
    power_step: f64,
    /// The pass leaves the lights that hold concentrated input pixels alone.
    power_skip_conc: bool,
    /// Second-level warp inside concentrated working pixels with this exponent (0 = off).
    fine_warp: f64,
    /// Lloyd step on a working map coarsened by this factor (0 = off).
    coarse_lloyd: usize,
    /// Coarse pixels at their luminance centroid (1), or assigned by centre with exact moments (2).
    coarse_centroid: u8,
    /// Keep fine samples in the coarse pass.
    coarse_fine: bool,
    /// Density exponent inside concentrated working pixels (0 = the same as `gamma`).
    gamma_conc: f64,
    /// Lloyd steps move only the lights whose regions hold concentrated input pixels.
    lloyd_conc: bool,
    /// After a Lloyd step only the concentrated input pixels are assigned again.
    lloyd_fine_only: bool,
    /// Split lights holding concentrated input pixels and more than this × the mean energy,
    /// taking their extra lights from the weakest ones (0 = off).
    split: f64,
    /// At most this many pieces per split light.
    split_max: usize,
    /// Split every light above the threshold, not only those holding concentrated pixels.
    split_all: bool,
    /// Only the concentrated input pixels of a split light are clustered; its working pixels
    /// go as one lump to the piece nearest their centroid.
    split_fine_only: bool,
    /// A removed light goes whole to the light nearest its direction.
    split_merge_whole: bool,
    /// `spb=D`: decompose into n − n/D lights, then split the brightest lights into exactly
    /// n/D extra pieces (one at a time to the light of the largest energy per piece), none
    /// removed (0: off).
    split_budget: usize,
    /// `spd=1`: an adaptive budget: the split rule (`sp=K`) run on an n-light decomposition
    /// counts the extra pieces E it wants; then the decomposition into n − E lights (a prefix of
    /// the point set) and E extra pieces as with `spb`, none removed.
    split_adaptive: bool,
    /// The budget of `spd=1`'s second pass (set internally).
    split_budget_abs: usize,
}

impl Default for Opts {
    fn default() -> Self {
        Self {
            gamma: 0.75,
            alpha: 0.0,
            conc: 0.25,
            width: 256,
            cpow: 1.0,
            horizon: false,
            finedir: false,
            lib: false,
            upper: 1.0,
            lloyd: 0,
            mix: 0.0,
            gamma2: 1.0,
            fine_lights: false,
            beta: 0.0,
            beta_conc: false,
            beta_block: 0,
            hierarchical: false,
            power_cap: 0.0,
            power_iterations: 8,
            power_step: 1.0,
            power_skip_conc: false,
            fine_warp: 0.0,
            coarse_lloyd: 0,
            coarse_centroid: 0,
            coarse_fine: true,
            gamma_conc: 0.0,
            lloyd_conc: false,
            lloyd_fine_only: false,
            split: 0.0,
            split_max: 8,
            split_all: false,
            split_fine_only: false,
            split_merge_whole: false,
            split_budget: 0,
            split_adaptive: false,
            split_budget_abs: 0,
        }
    }
}

fn read_map(path: &Path) -> Result<HdrFrame> {
    let image = read_hdr_image(path)?;
    let mut frame = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .context("empty")?;
    frame.sanitize();
    Ok(frame)
}

struct Px {
    /// Luminance-weighted moment override for the Lloyd centroid (cc=2).
    moment: Option<DVec3>,
    dir: DVec3,
    energy: [f64; 3],
    omega: f64,
}

fn decompose(frame: &HdrFrame, n: usize, o: &Opts) -> Vec<Light> {
    decompose_full(frame, n, o).0
}

fn decompose_full(frame: &HdrFrame, n: usize, o: &Opts) -> (Vec<Light>, Vec<Px>, Vec<usize>) {
    if o.lib {
        let s = DecomposeSettings {
            lights: n,
            pdf_exponent: o.gamma,
            working_width: o.width,
            concentrated_lloyd: o.lloyd_conc,
            refine_concentrated: o.lloyd_fine_only,
            warp: if o.hierarchical {
                envlight::decompose::Warp::Hierarchical
            } else {
                envlight::decompose::Warp::Rows
            },
            filter_taps: None,
            merge_spacing_fraction: None,
            split_factor: (o.split > 0.0).then_some(o.split),
            ..DecomposeSettings::default()
        };
        return (
            match Decomposer::new(s) {
                Ok(mut d) => d.decompose(frame).lights,
                Err(e) => {
                    eprintln!("lib=1: {e}");
                    Vec::new()
                }
            },
            vec![],
            vec![],
        );
    }
    if o.split_adaptive {
        let first = Opts {
            split_adaptive: false,
            ..o.clone()
        };
        let _ = decompose_full(frame, n, &first);
        let extra = LAST_EXTRA.load(std::sync::atomic::Ordering::Relaxed);
        let second = Opts {
            split_adaptive: false,
            split_budget_abs: extra,
            ..o.clone()
        };
        return decompose_full(frame, n, &second);
    }
    let requested = n;
    let n = n - n.checked_div(o.split_budget).unwrap_or(0) - o.split_budget_abs.min(n - 1);
    let mut rs = Resampler::new(Projection::LatLong, frame.width, frame.height, o.width);
    let map = rs.resample(frame, o.conc / n as f64, None).clone();
    let (w, h) = (map.width, map.height);
    let f = frame.width as usize / w;
    // Pixels (working or fine) with directions.
    let mut pixels = Vec::new();
    let fw = frame.width as usize;
    let omegas = Projection::LatLong.solid_angles(frame.width, frame.height);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if map.concentrated[i] {
                continue;
            }
            let (st, ct) = map.row_trig_f64[y];
            let (sp, cp) = map.column_trig_f64[x];
            let mut dir = DVec3::new(st * sp, ct, -st * cp);
            if o.finedir {
                let mut acc = DVec3::ZERO;
                for yy in y * f..(y + 1) * f {
                    for xx in x * f..(x + 1) * f {
                        let p = frame.pixels[yy * fw + xx];
                        let l = luminance_f64(p.map(f64::from)) * omegas[yy * fw];
                        let d = Projection::LatLong
                            .pixel_to_direction(
                                frame.width,
                                frame.height,
                                xx as f64 + 0.5,
                                yy as f64 + 0.5,
                            )
                            .unwrap_or(DVec3::Y);
                        acc += d * l;
                    }
                }
                if let Some(d) = acc.try_normalize() {
                    dir = d;
                }
            }
            pixels.push(Px {
                moment: None,
                dir,
                energy: map.energy[i].map(f64::from),
                omega: map.row_solid_angle[y],
            });
        }
    }
    let nwork = pixels.len();
    let mut extra = Vec::new();
    for s in &map.fine {
        if o.fine_lights {
            extra.push(Light {
                id: 100000,
                dir: s.dir,
                rgb: s.energy,
                solid_angle: s.solid_angle,
            });
            continue;
        }
        pixels.push(Px {
            moment: None,
            dir: DVec3::from_array(s.dir.map(f64::from)),
            energy: s.energy.map(f64::from),
            omega: f64::from(s.solid_angle),
        });
    }
    // Density.
    let mut weights = vec![0.0f64; w * h];
    let mut total = 0.0;
    for y in 0..h {
        let om = map.row_solid_angle[y];
        for x in 0..w {
            let l = f64::from(map.luminance[y * w + x]);
            let g = if o.gamma_conc > 0.0 && map.concentrated[y * w + x] {
                o.gamma_conc
            } else {
                o.gamma
            };
            let mut v = (l / om).powf(g) * om;
            if y < h / 2 {
                v *= o.upper;
            }
            weights[y * w + x] = v;
            total += v;
        }
    }
    if o.mix > 0.0 && total > 0.0 {
        let mut w2 = vec![0.0f64; w * h];
        let mut t2 = 0.0;
        for y in 0..h {
            let om = map.row_solid_angle[y];
            for x in 0..w {
                let l = f64::from(map.luminance[y * w + x]);
                let v = (l / om).powf(o.gamma2) * om;
                w2[y * w + x] = v;
                t2 += v;
            }
        }
        for (a, b) in weights.iter_mut().zip(&w2) {
            *a = (1.0 - o.mix) * *a / total + o.mix * b / t2;
        }
        total = 1.0;
    }
    if o.beta > 0.0 && total > 0.0 && o.beta_block > 0 {
        let etot: f64 = map.luminance.iter().map(|&l| f64::from(l)).sum();
        let b = o.beta_block;
        for by in (0..h).step_by(b) {
            for bx in (0..w).step_by(b) {
                let (mut ws, mut es, mut conc) = (0.0, 0.0, false);
                for y in by..(by + b).min(h) {
                    for x in bx..(bx + b).min(w) {
                        ws += weights[y * w + x] / total;
                        es += f64::from(map.luminance[y * w + x]) / etot;
                        conc |= map.concentrated[y * w + x];
                    }
                }
                if (o.beta_conc && conc) || ws <= 0.0 {
                    continue;
                }
                let scale = (o.beta * es / ws).max(1.0);
                for y in by..(by + b).min(h) {
                    for x in bx..(bx + b).min(w) {
                        weights[y * w + x] *= scale;
                    }
                }
            }
        }
    } else if o.beta > 0.0 && total > 0.0 {
        let etot: f64 = map.luminance.iter().map(|&l| f64::from(l)).sum();
        for (i, v) in weights.iter_mut().enumerate() {
            if o.beta_conc && !map.concentrated[i] {
                *v /= total;
                continue;
            }
            *v = (*v / total).max(o.beta * f64::from(map.luminance[i]) / etot);
        }
        total = 1.0;
    }
    if o.alpha > 0.0 && total > 0.0 {
        for y in 0..h {
            let om = map.row_solid_angle[y];
            for x in 0..w {
                let v = &mut weights[y * w + x];
                *v = (1.0 - o.alpha) * *v / total + o.alpha * om / (4.0 * std::f64::consts::PI);
            }
        }
    }
    let dist = PiecewiseConstant2d::new(&weights, w, h);
    let hier = o
        .hierarchical
        .then(|| envlight::decompose::HierarchicalWarp::new(&weights, w, h));
    let points = progressive_points(n);
    // Fine distributions of concentrated pixels.
    let mut fine_dist: std::collections::HashMap<usize, PiecewiseConstant2d> = Default::default();
    if o.fine_warp > 0.0 {
        let mut by_pixel: std::collections::HashMap<usize, Vec<f64>> = Default::default();
        for s in &map.fine {
            let e = luminance_f64(s.energy.map(f64::from));
            let om = f64::from(s.solid_angle);
            by_pixel
                .entry(s.pixel as usize)
                .or_default()
                .push((e / om).powf(o.fine_warp) * om);
        }
        for (k, v) in by_pixel {
            if v.len() == f * f {
                fine_dist.insert(k, PiecewiseConstant2d::new(&v, f, f));
            }
        }
    }
    let mut sample_dirs: Vec<DVec3> = points
        .iter()
        .map(|u| {
            let p = match &hier {
                Some(hw) => hw.sample(*u),
                None => dist.sample(*u).0,
            };
            let (px, py) = (p[0] * w as f64, p[1] * h as f64);
            let (ix, iy) = ((px as usize).min(w - 1), (py as usize).min(h - 1));
            if let Some(fd) = fine_dist.get(&(iy * w + ix)) {
                let q = fd.sample([px - ix as f64, py - iy as f64]).0;
                return Projection::LatLong
                    .pixel_to_direction(w as u32, h as u32, ix as f64 + q[0], iy as f64 + q[1])
                    .unwrap_or(DVec3::Y);
            }
            Projection::LatLong
                .pixel_to_direction(w as u32, h as u32, px, py)
                .unwrap_or(DVec3::Y)
        })
        .collect();
    if o.coarse_lloyd > 0 {
        let k = o.coarse_lloyd;
        let (cw, ch) = (w / k, h / k);
        let mut coarse: Vec<Px> = Vec::new();
        for cy in 0..ch {
            for cx in 0..cw {
                let mut e = [0.0; 3];
                let mut om = 0.0;
                let mut ld = DVec3::ZERO;
                for y in cy * k..(cy + 1) * k {
                    for x in cx * k..(cx + 1) * k {
                        let i = y * w + x;
                        om += map.row_solid_angle[y];
                        if map.concentrated[i] && o.coarse_fine {
                            continue;
                        }
                        let (st, ct) = map.row_trig_f64[y];
                        let (sp, cp) = map.column_trig_f64[x];
                        let d = DVec3::new(st * sp, ct, -st * cp);
                        for (acc, v) in e.iter_mut().zip(map.energy[i].map(f64::from)) {
                            *acc += v;
                        }
                        ld += d * luminance_f64(map.energy[i].map(f64::from));
                    }
                }
                let centre = Projection::LatLong
                    .pixel_to_direction(cw as u32, ch as u32, cx as f64 + 0.5, cy as f64 + 0.5)
                    .unwrap_or(DVec3::Y);
                let dir = if o.coarse_centroid == 1 {
                    ld.try_normalize().unwrap_or(centre)
                } else {
                    centre
                };
                coarse.push(Px {
                    moment: (o.coarse_centroid == 2).then_some(ld),
                    dir,
                    energy: e,
                    omega: om,
                });
            }
        }
        if o.coarse_fine {
            for s in &map.fine {
                coarse.push(Px {
                    moment: None,
                    dir: DVec3::from_array(s.dir.map(f64::from)),
                    energy: s.energy.map(f64::from),
                    omega: f64::from(s.solid_angle),
                });
            }
        }
        let mut wd = vec![DVec3::ZERO; n];
        for p in &coarse {
            let mut best = 0;
            let mut bd = f64::NEG_INFINITY;
            for (i, s) in sample_dirs.iter().enumerate() {
                let d = s.dot(p.dir);
                if d > bd {
                    bd = d;
                    best = i;
                }
            }
            wd[best] += p.moment.unwrap_or(p.dir * luminance_f64(p.energy));
        }
        for i in 0..n {
            if let Some(d) = wd[i].try_normalize() {
                sample_dirs[i] = d;
            }
        }
    }
    let mut lights = Vec::new();
    let mut assign = vec![0usize; pixels.len()];
    let mut first_assign = Vec::new();
    let mut moved = vec![false; n];
    for it in 0..=o.lloyd {
        let mut rgb = vec![[0.0f64; 3]; n];
        let mut wd = vec![DVec3::ZERO; n];
        let mut sa = vec![0.0f64; n];
        let mut holds_conc = vec![false; n];
        for (pi, p) in pixels.iter().enumerate() {
            let mut best = 0;
            let mut bd = f64::NEG_INFINITY;
            let up = p.dir.y > 0.0;
            let keep = it > 0 && o.lloyd_fine_only && pi < nwork;
            if keep {
                best = first_assign[pi];
                bd = 1.0;
            }
            for (i, s) in sample_dirs.iter().enumerate().filter(|_| !keep) {
                if o.horizon && (s.y > 0.0) != up {
                    continue;
                }
                let d = s.dot(p.dir);
                if d > bd {
                    bd = d;
                    best = i;
                }
            }
            if bd == f64::NEG_INFINITY {
                for (i, s) in sample_dirs.iter().enumerate() {
                    let d = s.dot(p.dir);
                    if d > bd {
                        bd = d;
                        best = i;
                    }
                }
            }
            let l = luminance_f64(p.energy);
            let wl = if o.cpow == 1.0 || l <= 0.0 {
                l
            } else {
                l * (l / p.omega).powf(o.cpow - 1.0)
            };
            assign[pi] = best;
            holds_conc[best] |= pi >= nwork;
            for (acc, v) in rgb[best].iter_mut().zip(p.energy) {
                *acc += v;
            }
            wd[best] += p.dir * wl;
            sa[best] += p.omega;
        }
        if it < o.lloyd {
            if it == 0 {
                first_assign = assign.clone();
            }
            for i in 0..n {
                if o.lloyd_conc && !holds_conc[i] {
                    continue;
                }
                moved[i] = true;
                if let Some(d) = wd[i].try_normalize() {
                    sample_dirs[i] = d;
                }
            }
            continue;
        }
        lights = (0..n)
            .map(|i| {
                let d = wd[i].try_normalize().unwrap_or(sample_dirs[i]);
                Light {
                    id: i as u32,
                    dir: d.as_vec3().to_array(),
                    rgb: rgb[i].map(|c| c as f32),
                    solid_angle: sa[i] as f32,
                }
            })
            .collect();
    }
    if o.power_cap > 0.0 {
        // Power diagram: pixel → argmax(d·s_i + w_i); lights above the cap shrink (w_i falls)
        // until their energy is at most cap × the mean, or the iterations run out.
        let total: f64 = pixels.iter().map(|p| luminance_f64(p.energy)).sum();
        let cap = o.power_cap * total / n as f64;
        let mut wts = vec![0.0f64; n];
        for it in 0..=o.power_iterations {
            let mut e = vec![0.0f64; n];
            let mut conc_light = vec![false; n];
            for (pi, p) in pixels.iter().enumerate() {
                let mut best = 0;
                let mut bd = f64::NEG_INFINITY;
                for (i, s) in sample_dirs.iter().enumerate() {
                    let d = s.dot(p.dir) + wts[i];
                    if d > bd {
                        bd = d;
                        best = i;
                    }
                }
                assign[pi] = best;
                e[best] += luminance_f64(p.energy);
                conc_light[best] |= pi >= nwork;
            }
            if it == o.power_iterations {
                break;
            }
            for i in 0..n {
                if o.power_skip_conc && conc_light[i] {
                    continue;
                }
                if e[i] > cap {
                    wts[i] -= o.power_step * 2.0 / n as f64 * (e[i] / cap).ln();
                } else if wts[i] < 0.0 {
                    // Relax back toward the plain Voronoi cell where there is room.
                    wts[i] = (wts[i]
                        + o.power_step * 2.0 / n as f64 * (cap / e[i].max(1e-300)).ln().min(1.0))
                    .min(0.0);
                }
            }
        }
        let mut rgb = vec![[0.0f64; 3]; n];
        let mut wd = vec![DVec3::ZERO; n];
        let mut sa = vec![0.0f64; n];
        for (pi, p) in pixels.iter().enumerate() {
            let best = assign[pi];
            for (acc, v) in rgb[best].iter_mut().zip(p.energy) {
                *acc += v;
            }
            wd[best] += p.dir * luminance_f64(p.energy);
            sa[best] += p.omega;
        }
        lights = (0..n)
            .map(|i| Light {
                id: i as u32,
                dir: wd[i]
                    .try_normalize()
                    .unwrap_or(sample_dirs[i])
                    .as_vec3()
                    .to_array(),
                rgb: rgb[i].map(|c| c as f32),
                solid_angle: sa[i] as f32,
            })
            .collect();
    }
    if o.lloyd_conc && std::env::var("LCSTAT").is_ok() && !first_assign.is_empty() {
        // What a Lloyd step on the concentrated sources' lights would have to redraw: the
        // working pixels of the moved lights' old regions, and those whose light changed.
        let total: f64 = pixels[..nwork].iter().map(|p| p.omega).sum();
        let (mut in_moved, mut changed) = (0.0, 0.0);
        for (pi, p) in pixels[..nwork].iter().enumerate() {
            if moved[first_assign[pi]] || moved[assign[pi]] {
                in_moved += p.omega;
            }
            if first_assign[pi] != assign[pi] {
                changed += p.omega;
            }
        }
        eprintln!(
            "LCSTAT n={n} moved lights {} ({:.1}%), sphere in their regions {:.2}%, relabelled {:.2}%",
            moved.iter().filter(|&&m| m).count(),
            100.0 * moved.iter().filter(|&&m| m).count() as f64 / n as f64,
            100.0 * in_moved / total,
            100.0 * changed / total
        );
    }
    if o.split > 0.0 || o.split_budget > 0 {
        let budget = (o.split_budget > 0 || o.split_budget_abs > 0).then_some(requested - n);
        lights = split_heavy(&pixels, &mut assign, nwork, n, budget, o);
    }
    lights.extend(extra);
    (lights, pixels, assign)
}

/// The `sp` switch: lights above `o.split` × the mean energy (holding concentrated input
/// pixels unless `spa=1`) split into up to ceil(E / (sp·mean)) pieces by weighted k-means on
/// their region's pixels; as many of the weakest other lights give their regions to the
/// nearest remaining lights, so the count stays n.
/// The extra pieces the last `split_heavy` made (for `spd=1`'s first pass).
static LAST_EXTRA: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

fn split_heavy(
    pixels: &[Px],
    assign: &mut [usize],
    nwork: usize,
    n: usize,
    budget: Option<usize>,
    o: &Opts,
) -> Vec<Light> {
    let lum: Vec<f64> = pixels.iter().map(|p| luminance_f64(p.energy)).collect();
    let mut e = vec![0.0f64; n];
    let mut conc = vec![false; n];
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (pi, &a) in assign.iter().enumerate() {
        e[a] += lum[pi];
        conc[a] |= pi >= nwork;
        members[a].push(pi);
    }
    let total: f64 = e.iter().sum();
    let mean = total / n as f64;
    let mut pieces = vec![1usize; n];
    let mut extra = 0;
    if let Some(budget) = budget {
        let cap = |i: usize| o.split_max.min(members[i].len()).max(1);
        for _ in 0..budget {
            let pick = |eligible: &dyn Fn(usize) -> bool| {
                (0..n)
                    .filter(|&i| eligible(i) && pieces[i] < cap(i))
                    .max_by(|&a, &b| {
                        (e[a] / pieces[a] as f64).total_cmp(&(e[b] / pieces[b] as f64))
                    })
            };
            let Some(i) = pick(&|i| conc[i] || o.split_all).or_else(|| pick(&|_| true)) else {
                break;
            };
            pieces[i] += 1;
            extra += 1;
        }
    } else {
        for i in 0..n {
            if (conc[i] || o.split_all) && e[i] > o.split * mean {
                let k = ((e[i] / (o.split * mean)).ceil() as usize)
                    .min(o.split_max)
                    .min(members[i].len())
                    .max(1);
                pieces[i] = k;
                extra += k - 1;
            }
        }
    }
    LAST_EXTRA.store(extra, std::sync::atomic::Ordering::Relaxed);
    if std::env::var("SPSTAT").is_ok() {
        eprintln!(
            "SPSTAT n={n} split {} lights into {} extra; largest share {:.4}",
            pieces.iter().filter(|&&k| k > 1).count(),
            extra,
            e.iter().cloned().fold(0.0, f64::max) / total
        );
    }
    // The weakest unsplit lights give up their slots (a budget's pieces have slots of their
    // own: the lights left out of the decomposition).
    let removals = if budget.is_some() { 0 } else { extra };
    let mut order: Vec<usize> = (0..n).filter(|&i| pieces[i] == 1).collect();
    order.sort_by(|&a, &b| e[a].total_cmp(&e[b]));
    let removed: std::collections::HashSet<usize> = order.into_iter().take(removals).collect();
    let centroid = |idx: &[usize]| -> DVec3 {
        let mut d = DVec3::ZERO;
        for &pi in idx {
            d += pixels[pi].dir * lum[pi].max(1e-300);
        }
        d.normalize_or(DVec3::Y)
    };
    let dirs: Vec<DVec3> = (0..n).map(|i| centroid(&members[i])).collect();
    let keep: Vec<usize> = (0..n).filter(|i| !removed.contains(i)).collect();
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for &i in &keep {
        if pieces[i] == 1 {
            groups.push(members[i].clone());
        }
    }
    for &r in &removed {
        for &pi in &members[r] {
            let mut best = 0;
            let mut bd = f64::NEG_INFINITY;
            let from = if o.split_merge_whole {
                dirs[r]
            } else {
                pixels[pi].dir
            };
            for (gi, &i) in keep.iter().filter(|&&i| pieces[i] == 1).enumerate() {
                let d = dirs[i].dot(from);
                if d > bd {
                    bd = d;
                    best = gi;
                }
            }
            groups[best].push(pi);
        }
    }
    for &i in &keep {
        let k = pieces[i];
        if k == 1 {
            continue;
        }
        // Seeds: the k brightest pixels spread by farthest-point choice, then Lloyd.
        let all_idx = &members[i];
        let fine_idx: Vec<usize> = all_idx.iter().copied().filter(|&pi| pi >= nwork).collect();
        let idx = if o.split_fine_only {
            &fine_idx
        } else {
            all_idx
        };
        let k = k.min(idx.len()).max(1);
        let mut seeds = vec![*idx
            .iter()
            .max_by(|&&a, &&b| lum[a].total_cmp(&lum[b]))
            .unwrap()];
        while seeds.len() < k {
            let next = *idx
                .iter()
                .max_by(|&&a, &&b| {
                    let da = seeds
                        .iter()
                        .map(|&s| 1.0 - pixels[s].dir.dot(pixels[a].dir))
                        .fold(f64::MAX, f64::min)
                        * lum[a];
                    let db = seeds
                        .iter()
                        .map(|&s| 1.0 - pixels[s].dir.dot(pixels[b].dir))
                        .fold(f64::MAX, f64::min)
                        * lum[b];
                    da.total_cmp(&db)
                })
                .unwrap();
            seeds.push(next);
        }
        let mut centres: Vec<DVec3> = seeds.iter().map(|&s| pixels[s].dir).collect();
        let mut part = vec![Vec::new(); k];
        for _ in 0..10 {
            part = vec![Vec::new(); k];
            for &pi in idx {
                let mut best = 0;
                let mut bd = f64::NEG_INFINITY;
                for (c, cd) in centres.iter().enumerate() {
                    let d = cd.dot(pixels[pi].dir);
                    if d > bd {
                        bd = d;
                        best = c;
                    }
                }
                part[best].push(pi);
            }
            for (c, p) in part.iter().enumerate() {
                if !p.is_empty() {
                    centres[c] = centroid(p);
                }
            }
        }
        if o.split_fine_only {
            let work: Vec<usize> = all_idx.iter().copied().filter(|&pi| pi < nwork).collect();
            if !work.is_empty() {
                let c = centroid(&work);
                let best = (0..k)
                    .max_by(|&a, &b| centres[a].dot(c).total_cmp(&centres[b].dot(c)))
                    .unwrap_or(0);
                part[best].extend(work);
            }
        }
        groups.extend(part.into_iter().filter(|p| !p.is_empty()));
    }
    groups
        .iter()
        .enumerate()
        .map(|(gi, g)| {
            let mut rgb = [0.0f64; 3];
            let mut sa = 0.0;
            for &pi in g {
                for (acc, v) in rgb.iter_mut().zip(pixels[pi].energy) {
                    *acc += v;
                }
                sa += pixels[pi].omega;
            }
            Light {
                id: gi as u32,
                dir: centroid(g).as_vec3().to_array(),
                rgb: rgb.map(|c| c as f32),
                solid_angle: sa as f32,
            }
        })
        .collect()
}

fn ground_of(sources: &[(DVec3, f64)]) -> Vec<f64> {
    envlight::yardstick::ground_points()
        .into_iter()
        .map(|p| {
            let c = DVec3::new(0.0, 1.0, 0.0) - p;
            let d2 = c.length_squared();
            let cos_half = (1.0 - 1.0 / d2.max(1.0)).sqrt();
            let axis = c / d2.sqrt();
            sources
                .iter()
                .filter(|(d, _)| d.y > 0.0 && d.dot(axis) <= cos_half)
                .map(|(d, e)| e * d.y)
                .sum()
        })
        .collect()
}

fn diag(frame: &HdrFrame, n: usize, o: &Opts) {
    let (lights, pixels, assign) = decompose_full(frame, n, o);
    let mut members: Vec<Vec<(DVec3, f64)>> = vec![Vec::new(); n];
    for (p, &a) in pixels.iter().zip(&assign) {
        members[a].push((p.dir, luminance_f64(p.energy)));
    }
    let all: Vec<(DVec3, f64)> = members.iter().flatten().copied().collect();
    let truth = ground_of(&all);
    let tnorm: f64 = truth.iter().map(|t| t * t).sum::<f64>().sqrt();
    let approx = ground_of(
        &lights
            .iter()
            .map(|l| {
                (
                    DVec3::from_array(l.dir.map(f64::from)),
                    f64::from(l.luminance()),
                )
            })
            .collect::<Vec<_>>(),
    );
    let err: f64 = approx
        .iter()
        .zip(&truth)
        .map(|(a, t)| (a - t) * (a - t))
        .sum::<f64>()
        .sqrt();
    println!("total ground err (vs own pixels) {:.4}", err / tnorm);
    let total: f64 = all.iter().map(|x| x.1).sum();
    let mut rows = Vec::new();
    for (i, l) in lights.iter().enumerate() {
        let d = DVec3::from_array(l.dir.map(f64::from));
        if d.y <= 0.0 && members[i].iter().all(|m| m.0.y <= 0.0) {
            continue;
        }
        let t = ground_of(&members[i]);
        let a = ground_of(&[(d, f64::from(l.luminance()))]);
        let e: f64 = a
            .iter()
            .zip(&t)
            .map(|(a, t)| (a - t) * (a - t))
            .sum::<f64>()
            .sqrt();
        let e_sum: f64 = members[i].iter().map(|m| m.1).sum();
        let spread = (members[i]
            .iter()
            .map(|m| m.1 * m.0.angle_between(d).powi(2))
            .sum::<f64>()
            / e_sum.max(1e-30))
        .sqrt()
        .to_degrees();
        rows.push((
            e / tnorm,
            i,
            d.y.asin().to_degrees(),
            e_sum / total,
            spread,
            members[i].len(),
        ));
    }
    rows.sort_by(|a, b| b.0.total_cmp(&a.0));
    let upper: usize = rows.len();
    println!("{upper} regions touch the upper hemisphere");
    for r in rows.iter().take(25) {
        println!(
            "err {:.4} id {:3} elev {:5.1} share {:.4} spread {:5.2}° px {}",
            r.0, r.1, r.2, r.3, r.4, r.5
        );
    }
}

fn unshadowed(map: &ReferenceMap, lights: &[Light]) -> f64 {
    let t: f64 = map
        .directions()
        .iter()
        .zip(map.energies())
        .map(|(d, e)| luminance_f64(*e) * d.y.max(0.0))
        .sum();
    let a: f64 = lights
        .iter()
        .map(|l| f64::from(l.luminance()) * f64::from(l.dir[1]).max(0.0))
        .sum();
    (a - t) / t
}

fn parse(args: &[String]) -> Result<Vec<(String, Opts)>> {
    // Variants separated by "--": key=value tokens.
    let mut out = Vec::new();
    for group in args.split(|a| a == "/") {
        let mut o = Opts::default();
        for kv in group {
            let (k, v) = kv
                .split_once('=')
                .with_context(|| format!("{kv}: not key=value"))?;
            match k {
                "g" => o.gamma = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "a" => o.alpha = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "c" => o.conc = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "w" => o.width = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "p" => o.cpow = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "hz" => o.horizon = v == "1",
                "fd" => o.finedir = v == "1",
                "lib" => o.lib = v == "1",
                "up" => o.upper = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "lloyd" => o.lloyd = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "m" => o.mix = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "g2" => o.gamma2 = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "fl" => o.fine_lights = v == "1",
                "mx" => o.beta = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "mxc" => o.beta_conc = v == "1",
                "hw" => o.hierarchical = v == "1",
                "pw" => o.power_cap = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "pwi" => {
                    o.power_iterations = v.parse().with_context(|| format!("{kv}: not a number"))?
                }
                "pwc" => o.power_skip_conc = v == "1",
                "pws" => o.power_step = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "mxb" => o.beta_block = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "fw" => o.fine_warp = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "cl" => {
                    o.coarse_lloyd = v.parse().with_context(|| format!("{kv}: not a number"))?
                }
                "cc" => {
                    o.coarse_centroid = v.parse().with_context(|| format!("{kv}: not a number"))?
                }
                "cf" => o.coarse_fine = v == "1",
                "gc" => o.gamma_conc = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "lc" => o.lloyd_conc = v == "1",
                "lf" => o.lloyd_fine_only = v == "1",
                "sp" => o.split = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "spm" => o.split_max = v.parse().with_context(|| format!("{kv}: not a number"))?,
                "spa" => o.split_all = v == "1",
                "spw" => o.split_fine_only = v == "1",
                "spr" => o.split_merge_whole = v == "1",
                "spd" => o.split_adaptive = v == "1",
                "spb" => {
                    o.split_budget = v.parse().with_context(|| format!("{kv}: not a number"))?
                }
                _ => anyhow::bail!("unknown switch {k}"),
            }
        }
        out.push((group.join(" "), o));
    }
    Ok(out)
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let variants = parse(&args)?;
    let maps = test_data::QUALITY_MAPS;
    let verbose = std::env::var("V").is_ok();
    if std::env::var("SKY").is_ok() {
        use envlight::capture::sky::{render_sky, SkyOptions};
        let options = SkyOptions {
            // The sky the documented figures were measured on (seed 0, the default until 2026-11-23).
            seed: 0,
            ..SkyOptions::default()
        };
        let a = render_sky(&options, 10.0);
        let b = render_sky(&options, 10.0 + 1.0 / 30.0);
        for (name, o) in &variants {
            let la = decompose(&a, 256, o);
            let lb = decompose(&b, 256, o);
            let mut ang: Vec<f64> = la
                .iter()
                .zip(&lb)
                .map(|(x, y)| {
                    DVec3::from_array(x.dir.map(f64::from))
                        .angle_between(DVec3::from_array(y.dir.map(f64::from)))
                        .to_degrees()
                })
                .collect();
            ang.sort_by(f64::total_cmp);
            if ang.len() < 3 {
                println!("{name:30} sky: too few lights");
                continue;
            }
            println!(
                "{name:30} sky: max {:.2} p99 {:.2} >1°: {}",
                ang[ang.len() - 1],
                ang[ang.len() - 3],
                ang.iter().filter(|&&x| x > 1.0).count()
            );
        }
        return Ok(());
    }
    if let Ok(spec) = std::env::var("PROF") {
        // placement(c|s):gamma:iterations
        let parts: Vec<&str> = spec.split(':').collect();
        anyhow::ensure!(parts.len() == 3, "PROF: expected c|s:GAMMA:ITERATIONS");
        let frame = read_map(Path::new("tests/data/rooitou_park_1k.hdr"))?;
        let settings = DecomposeSettings {
            placement: if parts[0] == "s" {
                envlight::decompose::LightPlacement::SamplePoint
            } else {
                envlight::decompose::LightPlacement::Centroid
            },
            pdf_exponent: parts[1].parse()?,
            ..DecomposeSettings::default()
        };
        let iterations: usize = parts[2].parse::<usize>()?.max(1);
        let mut d = Decomposer::new(settings)?;
        d.decompose(&frame);
        let mut times = Vec::new();
        for _ in 0..iterations {
            let t = std::time::Instant::now();
            std::hint::black_box(d.decompose(&frame));
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        times.sort_by(f64::total_cmp);
        println!(
            "{spec}: median {:.3} ms, min {:.3} ms",
            times[times.len() / 2],
            times[0]
        );
        return Ok(());
    }
    if let Ok(spec) = std::env::var("DIAG") {
        let (m, n) = spec.split_once(':').context("expected MAP:N")?;
        let frame = read_map(&Path::new("tests/data").join(m))?;
        for (name, o) in &variants {
            println!("== {name}");
            diag(&frame, n.parse()?, o);
        }
        return Ok(());
    }
    if let Ok(spec) = std::env::var("PNG") {
        let (m, n) = spec.split_once(':').context("expected MAP:N")?;
        let n: usize = n.parse()?;
        let frame = read_map(&Path::new("tests/data").join(m))?;
        let mc = median_cut(&frame, n)?;
        let el = decompose(&frame, n, &variants[0].1);
        dump_png(
            &frame,
            &[(&mc.lights, [0, 255, 0]), (&el, [255, 0, 0])],
            "/tmp/probe.png",
        )?;
        return Ok(());
    }
    let mut wins = vec![[0usize; 4]; variants.len()];
    let mut logsum = vec![[0.0f64; 4]; variants.len()];
    let mut losses: Vec<Vec<String>> = vec![Vec::new(); variants.len()];
    for m in maps {
        let frame = read_map(&Path::new("tests/data").join(m))?;
        let rmap = ReferenceMap::new(&frame, 256)?;
        let ns: Vec<usize> = std::env::var("NS")
            .map(|s| s.split(',').map(|x| x.parse()).collect())
            .unwrap_or(Ok(vec![64, 256]))
            .context("NS: light counts separated by commas")?;
        for &n in &ns {
            let mc = median_cut(&frame, n)?;
            let rm = evaluate(&rmap, &mc.lights);
            let mcu = unshadowed(&rmap, &mc.lights);
            let arr = |r: &QualityReport| [r.diffuse, r.glossy16, r.glossy128, r.ground_shadow];
            let am = arr(&rm);
            if verbose {
                println!(
                    "{m:32} {n:3} median cut      {:?} unsh {mcu:+.4}",
                    am.map(|v| (v * 1e4).round() / 1e4)
                );
            }
            for (vi, (name, o)) in variants.iter().enumerate() {
                let lights = decompose(&frame, n, o);
                let r = evaluate(&rmap, &lights);
                let a = arr(&r);
                for k in 0..4 {
                    if a[k] < am[k] {
                        wins[vi][k] += 1;
                    } else {
                        losses[vi].push(format!(
                            "{}@{n} {} {:.4}/{:.4}",
                            &m[..8],
                            ["dif", "g16", "g128", "gnd"][k],
                            a[k],
                            am[k]
                        ));
                    }
                    logsum[vi][k] += (a[k] / am[k]).ln();
                }
                if verbose {
                    println!(
                        "{m:32} {n:3} {name:15} {:?} unsh {:+.4}",
                        a.map(|v| (v * 1e4).round() / 1e4),
                        unshadowed(&rmap, &lights)
                    );
                }
            }
        }
    }
    for (vi, (name, _)) in variants.iter().enumerate() {
        let total: usize = wins[vi].iter().sum();
        let gm = logsum[vi].map(|s| ((s / 18.0).exp() * 100.0).round() / 100.0);
        println!(
            "{name:40} wins {total}/72 {:?} gm {:?} lost: {}",
            wins[vi],
            gm,
            losses[vi].join(", ")
        );
    }
    Ok(())
}

/// Writes a tonemapped PNG of the map with light markers (envlight red, median cut green).
#[allow(dead_code)]
pub fn dump_png(frame: &HdrFrame, sets: &[(&[Light], [u8; 3])], path: &str) -> Result<()> {
    let (w, h) = (frame.width, frame.height);
    let lums: Vec<f32> = frame
        .pixels
        .iter()
        .map(|p| envlight::frame::luminance(*p))
        .collect();
    let mut sorted = lums.clone();
    sorted.sort_by(f32::total_cmp);
    let scale = 1.0 / sorted[sorted.len() / 2].max(1e-6) * 0.18;
    let mut img = image::RgbImage::new(w, h);
    for (i, p) in frame.pixels.iter().enumerate() {
        let c = p.map(|v| {
            let v = v * scale;
            ((v / (1.0 + v)).powf(1.0 / 2.2) * 255.0) as u8
        });
        img.put_pixel(i as u32 % w, i as u32 / w, image::Rgb(c));
    }
    for (lights, colour) in sets {
        for l in lights.iter() {
            let d = DVec3::from_array(l.dir.map(f64::from));
            if let Some((x, y)) = Projection::LatLong.direction_to_pixel(w, h, d) {
                let (x, y) = (x as i64, y as i64);
                for dx in -2i64..=2 {
                    for dy in -2i64..=2 {
                        if dx.abs() + dy.abs() > 2 {
                            continue;
                        }
                        let (px, py) = (
                            (x + dx).rem_euclid(w as i64),
                            (y + dy).clamp(0, h as i64 - 1),
                        );
                        img.put_pixel(px as u32, py as u32, image::Rgb(*colour));
                    }
                }
            }
        }
    }
    img.save(path)?;
    Ok(())
}
