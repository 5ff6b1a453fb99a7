//! Fast evaluation of the reconstruction loss L_R and its gradient, used by the optimiser.
//!
//! The exact reference (`fit::loss`, `fit::loss_gradient`) evaluates every lobe at every pixel
//! in f64. This module computes the same sums faster:
//! 1. **Layout**: the target's pixels are regrouped once into tiles of 4 rows × 16 columns
//!    (64 pixels), stored as f32 structure-of-arrays blocks of 8 pixels (directions, weights
//!    Ω/4π, radiance / M); partial tiles are padded with weight-0 pixels.
//! 2. **Culling**: for each tile and lobe, a bound on the angle between the lobe axis and any
//!    pixel of the tile (the tile's bounding cone) decides whether the lobe can matter there:
//!    since λa² + μb² ≥ min(λ, μ)·sin²θ, a lobe is skipped on a tile when the whole tile lies
//!    beyond its horizon or where min(λ, μ)·sin²θ > [`CULL`] (the lobe is below e^−16 ≈ 10⁻⁷
//!    of its peak; per pixel, values below e^−24 are set to 0, which also keeps the arithmetic
//!    away from slow subnormal floats). Narrow lobes (suns, lamps) then cost a few tiles instead of the whole map.
//! 3. **Kernel**: per tile, a value pass accumulates the prediction of the active lobes, a
//!    residual pass forms the loss and the per-pixel derivative of the norm, and a gradient
//!    pass accumulates 14 sums per lobe. The residual pass takes the sign of the L1 residual
//!    without a branch (two 0/1 selections), so it vectorises too. Loops run over blocks of 8
//!    f32 lanes with a branch-free exp (range reduction to 2^n · 2^f and a degree-6 polynomial, relative error
//!    ≈ 2·10⁻⁷), so the compiler vectorises them; on x86-64 with AVX2 the same code is compiled
//!    a second time with AVX2 enabled and chosen at run time. No fused multiply-adds are used,
//!    so both builds give identical bits.
//! 4. **Sums**: per tile in f32, per lobe across tiles in f64; tiles form 32 fixed groups
//!    summed in group order, so results do not depend on the number of threads.
//!
//! 5. **Subsets** ([`Subset`]): an evaluation may visit only the tiles whose diagonal index
//!    (tile row + tile column) is `phase` modulo `stride`, and scale its sums by `stride`: a
//!    stratified estimate of the whole map's loss and gradient (every tile row contributes the
//!    same share of its tiles when `stride` divides the tile columns) at 1/`stride` of the
//!    cost; the stride is capped at the number of diagonals so no subset is empty. The
//!    optimiser rotates `phase` from iteration to iteration (`FitSettings::warm_subset`,
//!    `FitSettings::first_subset`), so over `stride` iterations every tile counts once.
//!
//! Relative accuracy against the f64 reference: about 10⁻⁶ on the loss and 10⁻⁴ on the gradient
//! (`tests/asg.rs::fast_kernel_matches_the_exact_loss_and_gradient`).

use super::fit::{FitTarget, Norm};
use glam::DVec3;

/// Lanes per block.
const LANES: usize = 8;
/// Tile size in pixels (rows × columns).
const TILE_ROWS: u32 = 4;
const TILE_COLS: u32 = 16;
/// Blocks per tile at most.
const TILE_BLOCKS: usize = (TILE_ROWS * TILE_COLS) as usize / LANES;
/// A lobe is skipped where its exponent is below −CULL everywhere on a tile.
pub const CULL: f64 = 16.0;
/// Per pixel, a lobe below e^−CUT of its peak counts as 0.
const CUT: f32 = 24.0;
/// Fixed groups of tiles (the unit of work of a thread).
const GROUPS: usize = 32;

type Block = [f32; LANES];

/// One tile: its blocks and bounding cone.
#[derive(Clone, Debug)]
struct Tile {
    first: usize,
    /// Tile row + tile column: the tile is in subset `diagonal % stride` (step 5).
    diagonal: usize,
    blocks: usize,
    centre: DVec3,
    cos_rho: f64,
    sin_rho: f64,
}

/// The target's pixels in tiled f32 blocks.
#[derive(Clone, Debug)]
pub struct Pixels {
    dx: Vec<Block>,
    dy: Vec<Block>,
    dz: Vec<Block>,
    w: Vec<Block>,
    rad: [Vec<Block>; 3],
    tiles: Vec<Tile>,
    groups: Vec<std::ops::Range<usize>>,
    /// Number of tile diagonals (tile rows + tile columns − 1): the largest useful stride.
    diagonals: usize,
    /// The target pixel of every lane of every block (padding lanes repeat the tile's first
    /// pixel), so [`Pixels::refill`] can redo the radiance alone.
    source: Vec<[u32; LANES]>,
}

/// A lobe in the kernel's units (amplitude divided by the map's mean M).
#[derive(Clone, Copy, Debug)]
pub struct KLobe {
    pub x: DVec3,
    pub y: DVec3,
    pub z: DVec3,
    pub lambda: f64,
    pub mu: f64,
    /// c / M.
    pub c: [f64; 3],
}

/// Gradient sums of one lobe: ∂L_R/∂x, ∂y, ∂z (frame vectors free), ∂λ, ∂μ, ∂(c/M).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sums {
    pub x: DVec3,
    pub y: DVec3,
    pub z: DVec3,
    pub lambda: f64,
    pub mu: f64,
    pub c: [f64; 3],
}

impl Sums {
    fn scale(&mut self, f: f64) {
        self.x *= f;
        self.y *= f;
        self.z *= f;
        self.lambda *= f;
        self.mu *= f;
        for c in &mut self.c {
            *c *= f;
        }
    }
    fn add(&mut self, o: &Sums) {
        self.x += o.x;
        self.y += o.y;
        self.z += o.z;
        self.lambda += o.lambda;
        self.mu += o.mu;
        for c in 0..3 {
            self.c[c] += o.c[c];
        }
    }
}

impl Pixels {
    /// Tiles `target` (module doc, step 1).
    pub fn new(target: &FitTarget) -> Self {
        let (w, h) = (target.width, target.height);
        let (tr, tc) = (TILE_ROWS.min(h), TILE_COLS.min(w));
        let mut px = Pixels {
            dx: Vec::new(),
            dy: Vec::new(),
            dz: Vec::new(),
            w: Vec::new(),
            rad: [Vec::new(), Vec::new(), Vec::new()],
            tiles: Vec::new(),
            groups: Vec::new(),
            diagonals: 1,
            source: Vec::new(),
        };
        let mut idx = Vec::with_capacity((tr * tc) as usize);
        for (tyi, ty) in (0..h).step_by(tr as usize).enumerate() {
            for (txi, tx) in (0..w).step_by(tc as usize).enumerate() {
                idx.clear();
                for y in ty..(ty + tr).min(h) {
                    for x in tx..(tx + tc).min(w) {
                        idx.push((y * w + x) as usize);
                    }
                }
                let mut centre = DVec3::ZERO;
                for &i in &idx {
                    centre += target.directions[i];
                }
                let centre = centre.normalize_or(target.directions[idx[0]]);
                let cos_rho = idx
                    .iter()
                    .map(|&i| target.directions[i].dot(centre))
                    .fold(1.0f64, f64::min)
                    .clamp(-1.0, 1.0);
                // A small margin for rounding.
                let rho = (cos_rho.acos() + 1e-6).min(std::f64::consts::PI);
                let blocks = idx.len().div_ceil(LANES);
                px.tiles.push(Tile {
                    first: px.dx.len(),
                    diagonal: tyi + txi,
                    blocks,
                    centre,
                    cos_rho: rho.cos(),
                    sin_rho: rho.sin(),
                });
                for b in 0..blocks {
                    let mut blk = [[0.0f32; LANES]; 4];
                    let mut src = [0u32; LANES];
                    for l in 0..LANES {
                        // Padding repeats the tile's first pixel with weight 0.
                        let (i, wt) = match idx.get(b * LANES + l) {
                            Some(&i) => (i, target.weights[i]),
                            None => (idx[0], 0.0),
                        };
                        let d = target.directions[i];
                        blk[0][l] = d.x as f32;
                        blk[1][l] = d.y as f32;
                        blk[2][l] = d.z as f32;
                        blk[3][l] = wt as f32;
                        src[l] = i as u32;
                    }
                    px.dx.push(blk[0]);
                    px.dy.push(blk[1]);
                    px.dz.push(blk[2]);
                    px.w.push(blk[3]);
                    px.source.push(src);
                }
            }
        }
        px.diagonals = px.tiles.iter().map(|t| t.diagonal + 1).max().unwrap_or(1);
        let n = px.tiles.len();
        px.groups = (0..GROUPS)
            .map(|g| (g * n / GROUPS)..((g + 1) * n / GROUPS))
            .filter(|r| !r.is_empty())
            .collect();
        px.refill(&target.radiance, target.mean);
        px
    }

    /// Redoes the tiles' radiance (radiance / M) for a new frame of the same size: everything
    /// else depends only on the size (`target` module doc, step 4).
    pub(crate) fn refill(&mut self, radiance: &[[f64; 3]], mean: f64) {
        let inv_m = if mean > 0.0 && mean.is_finite() {
            1.0 / mean
        } else {
            0.0
        };
        for c in 0..3 {
            self.rad[c].clear();
            self.rad[c].resize(self.source.len(), [0.0; LANES]);
        }
        let [r0, r1, r2] = &mut self.rad;
        for (((src, b0), b1), b2) in self.source.iter().zip(r0).zip(r1).zip(r2) {
            for l in 0..LANES {
                let p = radiance.get(src[l] as usize).copied().unwrap_or([0.0; 3]);
                b0[l] = (p[0] * inv_m) as f32;
                b1[l] = (p[1] * inv_m) as f32;
                b2[l] = (p[2] * inv_m) as f32;
            }
        }
    }
}

/// e^x for x ≤ 0 (x < −87 gives ≈ e^−87), branch-free (module doc, step 3).
#[inline(always)]
fn exp_neg(x: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5 · 2^23: adding it rounds to an integer.
    let t = x.max(-87.0) * std::f32::consts::LOG2_E;
    let shifted = t + MAGIC;
    let n = shifted - MAGIC;
    let f = (t - n) * std::f32::consts::LN_2; // |f| ≤ ln2 / 2
    let p = 1.0
        + f * (1.0
            + f * (0.5
                + f * (1.0 / 6.0 + f * (1.0 / 24.0 + f * (1.0 / 120.0 + f * (1.0 / 720.0))))));
    let ni = (shifted.to_bits() as i32).wrapping_sub(MAGIC.to_bits() as i32);
    let scale = f32::from_bits(((ni + 127) << 23) as u32);
    p * scale
}

/// Scratch of one tile.
struct Scratch {
    a: Vec<Block>,
    b: Vec<Block>,
    e: Vec<Block>,
    g: Vec<Block>,
    pred: [[Block; TILE_BLOCKS]; 3],
    r: [[Block; TILE_BLOCKS]; 3],
    active: Vec<usize>,
}

impl Scratch {
    fn new(k: usize) -> Self {
        let n = k * TILE_BLOCKS;
        Self {
            a: vec![[0.0; LANES]; n],
            b: vec![[0.0; LANES]; n],
            e: vec![[0.0; LANES]; n],
            g: vec![[0.0; LANES]; n],
            pred: [[[0.0; LANES]; TILE_BLOCKS]; 3],
            r: [[[0.0; LANES]; TILE_BLOCKS]; 3],
            active: Vec::with_capacity(k),
        }
    }
}

/// Whether `lobe` can exceed e^−CULL of its peak somewhere on `tile` (module doc, step 2).
#[inline]
fn visible(tile: &Tile, lobe: &KLobe) -> bool {
    let ct = tile.centre.dot(lobe.z).clamp(-1.0, 1.0);
    if ct >= tile.cos_rho {
        return true; // the axis is inside the cone
    }
    let st = (1.0 - ct * ct).max(0.0).sqrt();
    // cos of the smallest angle between the axis and the cone.
    let cmin = ct * tile.cos_rho + st * tile.sin_rho;
    if cmin <= 0.0 {
        return false;
    }
    lobe.lambda.min(lobe.mu) * (1.0 - cmin * cmin) <= CULL
}

/// Loss and gradient sums over the tiles of `groups` (module doc, step 3).
#[inline(always)]
fn run_groups(
    px: &Pixels,
    lobes: &[KLobe],
    norm: Norm,
    want_grad: bool,
    subset: Subset,
    groups: &[std::ops::Range<usize>],
    out: &mut [Option<(f64, Vec<Sums>)>],
) {
    let k = lobes.len();
    let mut s = Scratch::new(k);
    for (range, slot_out) in groups.iter().zip(out.iter_mut()) {
        let mut loss = 0.0f64;
        let mut sums = vec![Sums::default(); if want_grad { k } else { 0 }];
        for tile in &px.tiles[range.clone()] {
            if tile.diagonal % subset.stride != subset.phase {
                continue;
            }
            s.active.clear();
            s.active
                .extend((0..k).filter(|&j| visible(tile, &lobes[j])));
            let nb = tile.blocks;
            let t0 = tile.first;
            let (dx, dy, dz) = (
                &px.dx[t0..t0 + nb],
                &px.dy[t0..t0 + nb],
                &px.dz[t0..t0 + nb],
            );
            for c in 0..3 {
                s.pred[c] = [[0.0; LANES]; TILE_BLOCKS];
            }
            // Value pass.
            for (slot, &j) in s.active.iter().enumerate() {
                let lb = &lobes[j];
                let (x, y, z) = (
                    lb.x.as_vec3().to_array(),
                    lb.y.as_vec3().to_array(),
                    lb.z.as_vec3().to_array(),
                );
                let (lam, mu) = (lb.lambda as f32, lb.mu as f32);
                let cc = lb.c.map(|v| v as f32);
                let base = slot * TILE_BLOCKS;
                for bi in 0..nb {
                    let (bx, by, bz) = (&dx[bi], &dy[bi], &dz[bi]);
                    let (mut ab, mut bb, mut eb, mut gb) = (
                        [0.0f32; LANES],
                        [0.0f32; LANES],
                        [0.0f32; LANES],
                        [0.0f32; LANES],
                    );
                    for l in 0..LANES {
                        let sv = bx[l] * z[0] + by[l] * z[1] + bz[l] * z[2];
                        let a = bx[l] * x[0] + by[l] * x[1] + bz[l] * x[2];
                        let b = bx[l] * y[0] + by[l] * y[1] + bz[l] * y[2];
                        let ex = -(lam * a * a + mu * b * b);
                        // Below e^−CUT the lobe counts as 0 (also keeps products away from
                        // subnormal floats, which are slow).
                        let e = if sv > 0.0 && ex > -CUT {
                            exp_neg(ex)
                        } else {
                            0.0
                        };
                        ab[l] = a;
                        bb[l] = b;
                        eb[l] = e;
                        gb[l] = sv * e;
                    }
                    for c in 0..3 {
                        let p = &mut s.pred[c][bi];
                        for l in 0..LANES {
                            p[l] += cc[c] * gb[l];
                        }
                    }
                    s.a[base + bi] = ab;
                    s.b[base + bi] = bb;
                    s.e[base + bi] = eb;
                    s.g[base + bi] = gb;
                }
            }
            // Residual pass: branch-free, so it vectorises (the sign of d as the difference of
            // two 0/1 selections: w·(±1) and w·0 are exact, so r is ±w or 0 as a branch gives).
            let mut lacc = [0.0f32; LANES];
            for bi in 0..nb {
                let wb = &px.w[t0 + bi];
                for c in 0..3 {
                    let (p, t) = (&s.pred[c][bi], &px.rad[c][t0 + bi]);
                    let r = &mut s.r[c][bi];
                    match norm {
                        Norm::L1 => {
                            let d: Block = std::array::from_fn(|l| p[l] - t[l]);
                            for l in 0..LANES {
                                lacc[l] += wb[l] * d[l].abs();
                            }
                            *r = std::array::from_fn(|l| {
                                let pos = if d[l] > 0.0 { 1.0f32 } else { 0.0 };
                                let neg = if d[l] < 0.0 { 1.0f32 } else { 0.0 };
                                wb[l] * (pos - neg)
                            });
                        }
                        Norm::L2 => {
                            for l in 0..LANES {
                                let d = p[l] - t[l];
                                lacc[l] += wb[l] * d * d;
                                r[l] = 2.0 * wb[l] * d;
                            }
                        }
                    }
                }
            }
            loss += lacc.iter().map(|&v| f64::from(v)).sum::<f64>();
            if !want_grad {
                continue;
            }
            // Gradient pass.
            for (slot, &j) in s.active.iter().enumerate() {
                let lb = &lobes[j];
                let cc = lb.c.map(|v| v as f32);
                let base = slot * TILE_BLOCKS;
                let mut acc = [[0.0f32; LANES]; 14];
                for bi in 0..nb {
                    let (bx, by, bz) = (&dx[bi], &dy[bi], &dz[bi]);
                    let (ab, bb, eb, gb) = (
                        &s.a[base + bi],
                        &s.b[base + bi],
                        &s.e[base + bi],
                        &s.g[base + bi],
                    );
                    let (r0, r1, r2) = (&s.r[0][bi], &s.r[1][bi], &s.r[2][bi]);
                    for l in 0..LANES {
                        let rr = r0[l] * cc[0] + r1[l] * cc[1] + r2[l] * cc[2];
                        let g = gb[l];
                        acc[0][l] += r0[l] * g;
                        acc[1][l] += r1[l] * g;
                        acc[2][l] += r2[l] * g;
                        let qa = rr * ab[l] * g;
                        let qb = rr * bb[l] * g;
                        let qe = rr * eb[l];
                        acc[3][l] += bx[l] * qa;
                        acc[4][l] += by[l] * qa;
                        acc[5][l] += bz[l] * qa;
                        acc[6][l] += bx[l] * qb;
                        acc[7][l] += by[l] * qb;
                        acc[8][l] += bz[l] * qb;
                        acc[9][l] += bx[l] * qe;
                        acc[10][l] += by[l] * qe;
                        acc[11][l] += bz[l] * qe;
                        acc[12][l] += qa * ab[l];
                        acc[13][l] += qb * bb[l];
                    }
                }
                let t: Vec<f64> = acc
                    .iter()
                    .map(|a| a.iter().map(|&v| f64::from(v)).sum())
                    .collect();
                let sm = &mut sums[j];
                for c in 0..3 {
                    sm.c[c] += t[c];
                }
                sm.x += DVec3::new(t[3], t[4], t[5]) * (-2.0 * lb.lambda);
                sm.y += DVec3::new(t[6], t[7], t[8]) * (-2.0 * lb.mu);
                sm.z += DVec3::new(t[9], t[10], t[11]);
                sm.lambda -= t[12];
                sm.mu -= t[13];
            }
        }
        *slot_out = Some((loss, sums));
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn run_groups_avx2(
    px: &Pixels,
    lobes: &[KLobe],
    norm: Norm,
    want_grad: bool,
    subset: Subset,
    groups: &[std::ops::Range<usize>],
    out: &mut [Option<(f64, Vec<Sums>)>],
) {
    run_groups(px, lobes, norm, want_grad, subset, groups, out);
}

fn run_groups_dispatch(
    px: &Pixels,
    lobes: &[KLobe],
    norm: Norm,
    want_grad: bool,
    subset: Subset,
    groups: &[std::ops::Range<usize>],
    out: &mut [Option<(f64, Vec<Sums>)>],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { run_groups_avx2(px, lobes, norm, want_grad, subset, groups, out) };
            return;
        }
    }
    run_groups(px, lobes, norm, want_grad, subset, groups, out);
}

/// Which tiles an evaluation visits (module doc, step 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Subset {
    /// Every `stride`-th tile diagonal (1 = all tiles).
    pub stride: usize,
    /// Which diagonal class, `0..stride`.
    pub phase: usize,
}

impl Subset {
    /// All tiles.
    pub const ALL: Subset = Subset {
        stride: 1,
        phase: 0,
    };

    /// Subset `phase % stride` of `stride` (stride 0 counts as 1).
    pub fn new(stride: usize, phase: usize) -> Self {
        let stride = stride.max(1);
        Self {
            stride,
            phase: phase % stride,
        }
    }
}

/// L_R (normalised as `fit`'s) and, if `want_grad`, the gradient sums of every lobe, on
/// `threads` named scoped threads; over the tiles of `subset` only, scaled by its stride (an
/// estimate of the whole map's sums).
pub fn reconstruction(
    px: &Pixels,
    lobes: &[KLobe],
    norm: Norm,
    threads: usize,
    want_grad: bool,
    subset: Subset,
) -> (f64, Vec<Sums>) {
    // A stride above the number of diagonals would leave some subsets empty.
    let subset = Subset::new(subset.stride.min(px.diagonals), subset.phase);
    let k = lobes.len();
    let mut results: Vec<Option<(f64, Vec<Sums>)>> = vec![None; px.groups.len()];
    if threads <= 1 || px.groups.len() <= 1 {
        run_groups_dispatch(px, lobes, norm, want_grad, subset, &px.groups, &mut results);
    } else {
        let per = px.groups.len().div_ceil(threads);
        std::thread::scope(|scope| {
            for (ti, (outs, gs)) in results
                .chunks_mut(per)
                .zip(px.groups.chunks(per))
                .enumerate()
            {
                let spawned = std::thread::Builder::new()
                    .name(format!("asg-fit-{ti}"))
                    .spawn_scoped(scope, move || {
                        run_groups_dispatch(px, lobes, norm, want_grad, subset, gs, outs)
                    });
                if let Err(e) = spawned {
                    // No thread: this group set is computed below on the caller's thread.
                    tracing::warn!("cannot start an ASG fitting thread: {e}");
                }
            }
        });
        // Any group left empty (thread start failed) is computed here.
        for (out, g) in results.iter_mut().zip(&px.groups) {
            if out.is_none() {
                run_groups_dispatch(
                    px,
                    lobes,
                    norm,
                    want_grad,
                    subset,
                    std::slice::from_ref(g),
                    std::slice::from_mut(out),
                );
            }
        }
    }
    let mut loss = 0.0;
    let mut sums = vec![Sums::default(); if want_grad { k } else { 0 }];
    for (l, s) in results.iter().flatten() {
        loss += l;
        for (a, b) in sums.iter_mut().zip(s) {
            a.add(b);
        }
    }
    if subset.stride > 1 {
        let f = subset.stride as f64;
        loss *= f;
        for s in &mut sums {
            s.scale(f);
        }
    }
    (loss, sums)
}
