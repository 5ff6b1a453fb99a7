//! Prints the Markdown tables of docs/wavelets.md: at equal coefficient count K, the error of
//! Haar and of high-order wavelet bases on each given lat-long map, for
//! (a) the environment map itself (relative RGB L2 of the K-term reconstruction against the full
//!     octahedral map, exact by Parseval),
//! (b) diffuse objects: Lambertian irradiance E(n) at the 1024 Fibonacci normals of
//!     `envlight::yardstick::evaluation_directions`, and
//! (c) glossy objects: the normalised Phong convolutions with exponents 16 and 128 at the same
//!     1024 directions (as reflection directions),
//!
//! (b) and (c) as the yardsticks' relative RMS on luminance, against the same quantities of the
//! full (all coefficients) octahedral map, so they measure the truncation alone. Then "K for the
//! same error as Haar at K": the smallest K' at which the basis is as good as Haar at K (exact for
//! (a); for (b), (c) the first K' of a quarter-octave grid, interpolated log-log between grid
//! points). Finally the resampling floor: the yardsticks of the full octahedral map (one light per
//! texel) against the lat-long map itself (`envlight::yardstick`, reference width 256).
//!
//! ```text
//! cargo run --release --example wavelet_table -- tests/data/*.hdr tests/data/KernerEnvLatLong.exr tests/data/StageEnvLatLong.exr
//! ```
//!
//! Options (before the files): `--size N` (octahedral side, default 128), `--all-bases` (every
//! supported basis instead of the issue's Haar, db2, db3, db4, coif1, coif2).

mod common;

use anyhow::Result;
use envlight::frame::LUMINANCE_WEIGHTS;
use envlight::wavelet::approx::Coefficients;
use envlight::wavelet::sphere::OctahedralMap;
use envlight::wavelet::transform::{inverse_2d_with, max_levels, Workspace};
use envlight::wavelet::Basis;
use envlight::yardstick::{evaluate, evaluation_directions, ReferenceMap};
use std::path::Path;

/// Coefficient counts of the tables.
const K_TABLE: [usize; 4] = [64, 256, 1024, 4096];

/// Clamped cosines between the evaluation directions and the texel centres, row per direction.
struct Kernel {
    cos: Vec<f32>,
    texels: usize,
    omega: f64,
}

/// Diffuse, Phong-16 and Phong-128 luminance at each evaluation direction.
type Shading = [Vec<f64>; 3];

impl Kernel {
    /// Needs side² to be a multiple of 16 (side ≥ 4).
    fn new(map: &OctahedralMap) -> Self {
        let side = map.side();
        let dirs: Vec<_> = (0..side * side)
            .map(|i| map.texel_direction(i % side, i / side))
            .collect();
        let mut cos = Vec::with_capacity(1024 * dirs.len());
        for n in evaluation_directions() {
            cos.extend(dirs.iter().map(|d| n.dot(*d).max(0.0) as f32));
        }
        Self {
            cos,
            texels: dirs.len(),
            omega: map.texel_solid_angle(),
        }
    }

    /// Shading of a luminance map (texel radiances).
    fn shade(&self, lum: &[f64]) -> Shading {
        let k16 = 17.0 / (2.0 * std::f64::consts::PI);
        let k128 = 129.0 / (2.0 * std::f64::consts::PI);
        let lum32: Vec<f32> = lum.iter().map(|&v| v as f32).collect();
        let mut out: Shading = std::array::from_fn(|_| Vec::with_capacity(1024));
        const LANES: usize = 16;
        for row in self.cos.chunks_exact(self.texels) {
            // LANES independent partial sums, so the compiler can vectorise the loop.
            let (mut e, mut g16, mut g128) = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
            for (cs, ls) in row.chunks_exact(LANES).zip(lum32.chunks_exact(LANES)) {
                for k in 0..LANES {
                    let (c, l) = (cs[k], ls[k]);
                    let c2 = c * c;
                    let c4 = c2 * c2;
                    let c8 = c4 * c4;
                    let c16 = c8 * c8;
                    let c32 = c16 * c16;
                    let c64 = c32 * c32;
                    e[k] += c * l;
                    g16[k] += c16 * l;
                    g128[k] += c64 * c64 * l;
                }
            }
            let (e, g16, g128): (f32, f32, f32) =
                (e.iter().sum(), g16.iter().sum(), g128.iter().sum());
            out[0].push(f64::from(e) * self.omega);
            out[1].push(f64::from(g16) * self.omega * k16);
            out[2].push(f64::from(g128) * self.omega * k128);
        }
        out
    }
}

fn relative_rms(approx: &[f64], truth: &[f64]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (a, t) in approx.iter().zip(truth) {
        num += (a - t) * (a - t);
        den += t * t;
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        0.0
    }
}

/// Errors of one basis on one map: exact env-map L2 for every K, and the shading errors on the
/// K grid.
struct Curve {
    basis: Basis,
    /// env_l2[k] for k in 0..=side².
    env_l2: Vec<f64>,
    /// (K, [diffuse, glossy16, glossy128]) on the grid.
    shading: Vec<(usize, [f64; 3])>,
}

impl Curve {
    fn shading_at(&self, k: usize) -> [f64; 3] {
        self.shading
            .iter()
            .find(|(g, _)| *g == k)
            .map(|s| s.1)
            .unwrap_or([f64::NAN; 3])
    }

    /// Smallest K' with env_l2 ≤ target.
    fn env_k_for(&self, target: f64) -> usize {
        (0..self.env_l2.len())
            .find(|&k| self.env_l2[k] <= target * (1.0 + 1e-12))
            .unwrap_or(usize::MAX)
    }

    /// K' at which shading error `q` first reaches `target` on the grid, log-log interpolated.
    fn shading_k_for(&self, q: usize, target: f64) -> Option<f64> {
        let pts = &self.shading;
        if pts.first()?.1[q] <= target {
            return Some(pts[0].0 as f64);
        }
        for w in pts.windows(2) {
            let ((k0, e0), (k1, e1)) = ((w[0].0 as f64, w[0].1[q]), (w[1].0 as f64, w[1].1[q]));
            if e1 <= target {
                if e0 <= 0.0 || e1 <= 0.0 || target <= 0.0 {
                    return Some(k1);
                }
                let t = (e0.ln() - target.ln()) / (e0.ln() - e1.ln());
                return Some((k0.ln() + t * (k1.ln() - k0.ln())).exp());
            }
        }
        None
    }
}

/// Four decimals, or two significant digits in scientific notation below 0.001.
fn fmt_error(e: f64) -> String {
    if e >= 1e-3 || e == 0.0 || !e.is_finite() {
        format!("{e:.4}")
    } else {
        format!("{e:.1e}")
    }
}

fn k_grid(n: usize) -> Vec<usize> {
    let mut grid: Vec<usize> = (0..)
        .map(|j| (16.0 * 2f64.powf(j as f64 / 4.0)).round() as usize)
        .take_while(|&k| k <= n)
        .collect();
    grid.extend(K_TABLE.iter().filter(|&&k| k <= n));
    grid.sort_unstable();
    grid.dedup();
    grid
}

fn curve(
    map: &OctahedralMap,
    basis: Basis,
    kernel: &Kernel,
    truth: &Shading,
    grid: &[usize],
) -> Result<Curve> {
    let side = map.side();
    let n = side * side;
    let levels = max_levels(side);
    let coeffs = Coefficients::analyze(map.texels(), side, basis, levels)?;
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        coeffs
            .norm2(b)
            .partial_cmp(&coeffs.norm2(a))
            .unwrap_or(std::cmp::Ordering::Equal)
            .then(a.cmp(&b))
    });
    let total = coeffs.energy();
    let mut env_l2 = Vec::with_capacity(n + 1);
    let mut dropped = total;
    env_l2.push(1.0);
    for &i in &order {
        dropped -= coeffs.norm2(i);
        env_l2.push(if total > 0.0 {
            (dropped.max(0.0) / total).sqrt()
        } else {
            0.0
        });
    }
    let w = LUMINANCE_WEIGHTS.map(f64::from);
    let lum_coef: Vec<f64> = (0..n)
        .map(|i| (0..3).map(|c| w[c] * coeffs.planes[c][i]).sum())
        .collect();
    let mut ws = Workspace::new();
    let mut shading = Vec::with_capacity(grid.len());
    for &k in grid {
        let mut plane = vec![0.0; n];
        for &i in &order[..k] {
            plane[i] = lum_coef[i];
        }
        inverse_2d_with(&mut plane, side, basis, levels, &mut ws)?;
        let s = kernel.shade(&plane);
        shading.push((k, [0, 1, 2].map(|q| relative_rms(&s[q], &truth[q]))));
    }
    Ok(Curve {
        basis,
        env_l2,
        shading,
    })
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut side = 128usize;
    let mut bases: Vec<Basis> = Basis::issue_set().to_vec();
    loop {
        match args.first().map(String::as_str) {
            Some("--size") if args.len() > 1 => {
                side = args[1].parse().unwrap_or(0);
                args.drain(..2);
            }
            Some("--all-bases") => {
                bases = Basis::all();
                args.remove(0);
            }
            _ => break,
        }
    }
    if args.is_empty() || envlight::wavelet::sphere::check_side(side).is_err() || side < 64 {
        eprintln!(
            "usage: wavelet_table [--size N (power of two ≥ 64)] [--all-bases] MAP.hdr|MAP.exr..."
        );
        std::process::exit(2);
    }
    let grid = k_grid(side * side);
    let mut failed = false;
    let mut results: Vec<(String, Vec<Curve>, [f64; 3])> = Vec::new();
    for path in &args {
        let path = Path::new(path);
        let name = path.file_stem().map_or_else(
            || path.display().to_string(),
            |s| s.to_string_lossy().into(),
        );
        let run = || -> Result<(Vec<Curve>, [f64; 3])> {
            let frame = common::read_latlong_map(path)?;
            let map = OctahedralMap::from_frame(&frame, side)?;
            // Resampling floor: the full octahedral map against the lat-long map.
            let reference = ReferenceMap::new(&frame, 256)?;
            let floor = evaluate(&reference, &map.to_lights());
            let kernel = Kernel::new(&map);
            let lum: Vec<f64> = map
                .texels()
                .iter()
                .map(|&t| f64::from(envlight::frame::luminance(t)))
                .collect();
            let truth = kernel.shade(&lum);
            let curves = bases
                .iter()
                .map(|&b| curve(&map, b, &kernel, &truth, &grid))
                .collect::<Result<Vec<_>>>()?;
            Ok((curves, [floor.diffuse, floor.glossy16, floor.glossy128]))
        };
        eprintln!("{name} …");
        match run() {
            Ok((curves, floor)) => results.push((name, curves, floor)),
            Err(e) => {
                eprintln!("{}: {e:#}", path.display());
                failed = true;
            }
        }
    }

    println!("## Error at equal coefficient count (octahedral map {side}², full pyramid)\n");
    println!("Relative errors (0 is perfect): env = RGB L2 of the map; diffuse, glossy16, glossy128 = relative RMS of luminance shading at 1024 directions.\n");
    print!("| map | K | quantity |");
    for c in &results
        .first()
        .map_or(vec![], |r| r.1.iter().map(|c| c.basis).collect())
    {
        print!(" {c} |");
    }
    println!();
    print!("|---|---|---|");
    for _ in &bases {
        print!("---|");
    }
    println!();
    for (name, curves, _) in &results {
        for &k in K_TABLE.iter().filter(|&&k| k <= side * side) {
            for (q, label) in ["env", "diffuse", "glossy16", "glossy128"]
                .iter()
                .enumerate()
            {
                print!("| {name} | {k} | {label} |");
                for c in curves {
                    let e = if q == 0 {
                        c.env_l2[k]
                    } else {
                        c.shading_at(k)[q - 1]
                    };
                    print!(" {} |", fmt_error(e));
                }
                println!();
            }
        }
    }

    println!(
        "\n## Coefficients for the same error as Haar at K (ratio K / K'; > 1: fewer than Haar)\n"
    );
    print!("| map | quantity | K (Haar) |");
    for b in bases.iter().skip(1) {
        print!(" {b} |");
    }
    println!();
    print!("|---|---|---|");
    for _ in bases.iter().skip(1) {
        print!("---|");
    }
    println!();
    let mut ratios: Vec<Vec<Vec<f64>>> = vec![vec![Vec::new(); 4]; bases.len()];
    for (name, curves, _) in &results {
        let haar = &curves[0];
        for (q, label) in ["env", "diffuse", "glossy16", "glossy128"]
            .iter()
            .enumerate()
        {
            for &k in K_TABLE.iter().filter(|&&k| k <= side * side) {
                print!("| {name} | {label} | {k} |");
                for (bi, c) in curves.iter().enumerate().skip(1) {
                    let kp = if q == 0 {
                        let kp = c.env_k_for(haar.env_l2[k]);
                        (kp != usize::MAX).then_some(kp.max(1) as f64)
                    } else {
                        c.shading_k_for(q - 1, haar.shading_at(k)[q - 1])
                    };
                    match kp {
                        Some(kp) => {
                            let r = k as f64 / kp.max(1.0);
                            ratios[bi][q].push(r.ln());
                            print!(" {kp:.0} ({r:.2}×) |");
                        }
                        None => print!(" > {} |", side * side),
                    }
                }
                println!();
            }
        }
    }

    println!("\n## Geometric mean of K / K' over maps and K\n");
    print!("| quantity |");
    for b in bases.iter().skip(1) {
        print!(" {b} |");
    }
    println!();
    print!("|---|");
    for _ in bases.iter().skip(1) {
        print!("---|");
    }
    println!();
    for (q, label) in ["env", "diffuse", "glossy16", "glossy128"]
        .iter()
        .enumerate()
    {
        print!("| {label} |");
        for r in ratios.iter().skip(1) {
            let v = &r[q];
            if v.is_empty() {
                print!(" – |");
            } else {
                print!(" {:.2}× |", (v.iter().sum::<f64>() / v.len() as f64).exp());
            }
        }
        println!();
    }

    println!("\n## Resampling floor: full {side}² octahedral map against the lat-long map (yardsticks)\n");
    println!("| map | diffuse | glossy16 | glossy128 |\n|---|---|---|---|");
    for (name, _, f) in &results {
        println!(
            "| {name} | {} | {} | {} |",
            fmt_error(f[0]),
            fmt_error(f[1]),
            fmt_error(f[2])
        );
    }
    if failed {
        std::process::exit(1);
    }
}
