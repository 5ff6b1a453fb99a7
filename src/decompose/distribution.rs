//! A continuous 2D sampling distribution over an image: `PiecewiseConstant2d`.
//!
//! The density is piecewise constant in x within a row, and the conditional distribution of x is
//! blended linearly between neighbouring row centres (weighted by the rows' masses). That makes
//! the warp from the unit square to the image *continuous*: the standard pbrt-style warp picks a
//! row and then inverts that row's CDF, so a point crossing a row-band boundary in u₁ can jump
//! anywhere along x. Here, within the half-rows around a row centre, the conditional CDF is
//! `F(x | y) = ((1−t)·S_a(x) + t·S_b(x)) / ((1−t)·R_a + t·R_b)` where `S_r` is row r's prefix sum,
//! `R_r` its mass and t ∈ [0, 1] the position of y between the centres of rows a and b. At a row
//! centre the warp is exactly that row's inverse CDF, so `invert` of a pixel centre is O(1).
//!
//! **The seam.** Azimuth is periodic but a CDF needs an origin. With the origin at x = 0 (the
//! lat-long map's seam), a bright source stepping across the seam moves its mass from the end of
//! its rows' CDFs to their start, and every point of those rows jumps by that mass: a spot one
//! pixel across the seam moved lights by up to 104°. So u₀ is taken on a circle: the point goes
//! where F(x | y) = u₀ + c (mod 1), with the origin c the mean of the conditional CDF over a
//! triangular window centred on the seam, F̃ read as F − 1 on the window's left side (x < 0,
//! i.e. x near W), where it continues F across the seam. A source crossing the seam inside the
//! window raises F everywhere else and c by the same mass, gradually as it crosses, so the
//! points stay put; a change of the map outside the window does not touch c (as with a fixed
//! origin). c is linear in the row's prefix sums, so it blends between rows like they do. A
//! window over the whole circle also avoids the jump but couples every change of a row to all
//! of its points, and it drifts points against the content under a pan; the half-width,
//! [`SEAM_WINDOW_HALF_TURNS`], was chosen by the measurements in docs/quality.md ("The seam").
//!
//! Steps: `sample(u)`: invert the marginal row CDF at u₁ (continuous y), find the two rows whose
//! centres bracket y, binary-search the blended prefix sums for u₀ + c (mod 1). `invert(p)` runs
//! the same maps forwards. Naming follows pbrt-v4 (`sample(u) -> (p, pdf)`, `pdf(p)`, `invert(p)`); the
//! domain is the unit square, p = (x/W, y/H).
//!
//! Masses are f64: a sun 10⁴× brighter than the sky must not vanish in rounding.

/// Half-width of the window around the seam over which the rows' CDF origins are averaged,
/// as a fraction of a turn (3/16: 67.5° on either side of the seam).
pub const SEAM_WINDOW_HALF_TURNS: f64 = 3.0 / 16.0;

/// The origin window of rows of `width` cells, as weights on a row's W + 1 prefix sums: a
/// row's origin times its mass is `0.5 · Σ_j g_j · S[j]`, which is Σ_k q_k · (S\[k\] + S\[k+1\]) / 2
/// − (the weight of the seam's left side) · S\[W\] for triangular cell weights q_k (peak at the
/// seam, summing to 1), so g_j = q_j + q_{j−1}, less twice the left side's weight at j = W.
/// The non-zero g are two runs: from the start of the row and up to its end.
#[derive(Clone, Debug, Default)]
struct SeamWindow {
    width: usize,
    /// g_j for j in 0..start.len().
    start: Vec<f64>,
    /// Index of the first weight in `end`.
    end_from: usize,
    /// g_j for j in end_from..=W.
    end: Vec<f64>,
}

impl SeamWindow {
    /// A row too narrow for the window gets the uniform window (every cell, equal weights).
    fn new(width: usize) -> Self {
        let half_width = SEAM_WINDOW_HALF_TURNS * width as f64;
        let triangle = |k: usize| {
            let centre = k as f64 + 0.5;
            (1.0 - centre.min(width as f64 - centre) / half_width).max(0.0)
        };
        let mut cells: Vec<f64> = (0..width).map(triangle).collect();
        if cells.iter().all(|&q| q == 0.0) {
            cells.iter_mut().for_each(|q| *q = 1.0);
        }
        let total: f64 = cells.iter().sum();
        cells.iter_mut().for_each(|q| *q /= total);
        let left_side: f64 = cells[width.div_ceil(2)..].iter().sum();
        let mut g: Vec<f64> = (0..=width)
            .map(|j| {
                cells.get(j).copied().unwrap_or(0.0) + j.checked_sub(1).map_or(0.0, |k| cells[k])
            })
            .collect();
        g[width] -= 2.0 * left_side;
        // The gap of zero weights between the two runs (none in a narrow row).
        let start_len = g.iter().position(|&w| w == 0.0).unwrap_or(width + 1);
        let end_from = g[start_len..]
            .iter()
            .position(|&w| w != 0.0)
            .map_or(width + 1, |i| start_len + i);
        Self {
            width,
            start: g[..start_len].to_vec(),
            end_from,
            end: g[end_from..].to_vec(),
        }
    }

    /// The origin times the mass of the row with prefix sums `prefix` (W + 1 values).
    #[inline]
    fn origin_mass(&self, prefix: &[f64]) -> f64 {
        0.5 * (dot(&self.start, &prefix[..self.start.len()])
            + dot(&self.end, &prefix[self.end_from..]))
    }
}

/// Σ aᵢ·bᵢ with four running sums (so the compiler can vectorise it), in a fixed order: the
/// same sum on every machine and vector width. Also the spherical harmonics' row sums
/// ([`crate::sh`]).
#[inline]
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut sums = [0.0f64; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = a4
        .remainder()
        .iter()
        .zip(b4.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in a4.zip(b4) {
        for i in 0..4 {
            sums[i] += x[i] * y[i];
        }
    }
    (sums[0] + sums[1]) + (sums[2] + sums[3]) + tail
}

/// Continuous 2D distribution on \[0,1\]² from a non-negative W×H weight image.
#[derive(Clone, Debug)]
pub struct PiecewiseConstant2d {
    width: usize,
    height: usize,
    /// Per row, W+1 prefix sums of the row's weights (row r at `r*(W+1)..`).
    prefix: Vec<f64>,
    /// H+1 prefix sums of the row masses, normalised to end at 1.
    marginal_cdf: Vec<f64>,
    /// Per row, its CDF's origin times its mass: the window-weighted mean of S̃_r, the prefix
    /// sum read as S_r − R_r on the seam's left side (see the module doc).
    origin_mass: Vec<f64>,
    /// The window of the current width.
    window: SeamWindow,
    total: f64,
}

impl PiecewiseConstant2d {
    /// Builds the distribution from `width*height` non-negative finite weights, row-major.
    /// Negative or non-finite weights count as 0. An all-zero image gives the uniform
    /// distribution (and `total() == 0`).
    pub fn new(weights: &[f64], width: usize, height: usize) -> Self {
        let mut dist = Self {
            width,
            height,
            prefix: Vec::new(),
            marginal_cdf: Vec::new(),
            origin_mass: Vec::new(),
            window: SeamWindow::default(),
            total: 0.0,
        };
        dist.rebuild(weights, width, height);
        dist
    }

    /// Rebuilds the distribution in place for new weights (as [`Self::new`]), reusing its
    /// buffers. Compiled for the CPU's widest vector unit (runtime detection).
    pub fn rebuild(&mut self, weights: &[f64], width: usize, height: usize) {
        pulp::Arch::new().dispatch(Rebuild {
            dist: self,
            weights,
            width,
            height,
        });
    }

    #[inline(always)]
    fn rebuild_inline(&mut self, weights: &[f64], width: usize, height: usize) {
        assert_eq!(
            weights.len(),
            width * height,
            "weights must be width*height"
        );
        self.rebuild_rows_inline(width, height, |y, row| {
            row.copy_from_slice(&weights[y * width..(y + 1) * width]);
        });
    }

    /// Rebuilds the distribution in place for the weights that `fill(y, row)` writes into each
    /// row `y` (`row` has `width` cells), with no weight image in between: the caller's density
    /// goes straight into the buffer that becomes the prefix sums. Negative or non-finite
    /// weights count as 0, as in [`Self::new`]. Inlined into the caller, so that a caller
    /// compiled for a vector unit (`pulp`) compiles `fill` and the sums for it too.
    #[inline(always)]
    pub(crate) fn rebuild_rows_inline(
        &mut self,
        width: usize,
        height: usize,
        mut fill: impl FnMut(usize, &mut [f64]),
    ) {
        assert!(
            width > 0 && height > 0,
            "distribution needs a non-empty image"
        );
        self.width = width;
        self.height = height;
        let prefix = &mut self.prefix;
        let marginal_cdf = &mut self.marginal_cdf;
        prefix.resize(height * (width + 1), 0.0);
        marginal_cdf.resize(height + 1, 0.0);
        marginal_cdf[0] = 0.0;
        for (y, out) in prefix.chunks_exact_mut(width + 1).enumerate() {
            out[0] = 0.0;
            fill(y, &mut out[1..]);
            // The clean-up (vectorised, while the row is in the L1 cache): NaN, ±∞ and negative
            // weights count as 0.
            for w in &mut out[1..] {
                *w = if (*w > 0.0) & (*w < f64::INFINITY) {
                    *w
                } else {
                    0.0
                };
            }
        }
        // The running sums, four rows at a time: four independent chains of adds instead of one
        // (each row's sum is still in order, so the result is the same).
        let mut quads = prefix.chunks_exact_mut(4 * (width + 1));
        for quad in &mut quads {
            let (r0, rest) = quad.split_at_mut(width + 1);
            let (r1, rest) = rest.split_at_mut(width + 1);
            let (r2, r3) = rest.split_at_mut(width + 1);
            let mut s = [0.0f64; 4];
            for (((a, b), c), d) in r0.iter_mut().zip(r1).zip(r2).zip(r3).skip(1) {
                s[0] += *a;
                *a = s[0];
                s[1] += *b;
                *b = s[1];
                s[2] += *c;
                *c = s[2];
                s[3] += *d;
                *d = s[3];
            }
        }
        for row in quads.into_remainder().chunks_exact_mut(width + 1) {
            let mut sum = 0.0f64;
            for p in &mut row[1..] {
                sum += *p;
                *p = sum;
            }
        }
        // The rows' origins, from the window over the seam (made again only when the width
        // changes; the default window's width 0 is never a valid one).
        if self.window.width != width {
            self.window = SeamWindow::new(width);
        }
        self.origin_mass.resize(height, 0.0);
        for (row, origin) in prefix.chunks_exact(width + 1).zip(&mut self.origin_mass) {
            *origin = self.window.origin_mass(row);
        }
        let mut running_total = 0.0f64;
        for (row, cdf) in prefix.chunks_exact(width + 1).zip(&mut marginal_cdf[1..]) {
            running_total += row[width];
            *cdf = running_total;
        }
        let total = running_total;
        if total > 0.0 {
            for c in marginal_cdf.iter_mut() {
                *c /= total;
            }
        } else {
            for (i, c) in marginal_cdf.iter_mut().enumerate() {
                *c = i as f64 / height as f64;
            }
        }
        self.total = total;
    }

    /// Sum of all weights.
    pub fn total(&self) -> f64 {
        self.total
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    #[inline]
    fn row_prefix(&self, row: usize) -> &[f64] {
        &self.prefix[row * (self.width + 1)..(row + 1) * (self.width + 1)]
    }

    #[inline]
    fn row_mass(&self, row: usize) -> f64 {
        self.prefix[row * (self.width + 1) + self.width]
    }

    /// The rows whose centres bracket continuous row coordinate `y` and the blend factor t.
    #[inline]
    fn bracket(&self, y: f64) -> (usize, usize, f64) {
        let s = y - 0.5;
        if s <= 0.0 {
            return (0, 0, 0.0);
        }
        let a = s.floor() as usize;
        if a + 1 >= self.height {
            return (self.height - 1, self.height - 1, 0.0);
        }
        (a, a + 1, s - a as f64)
    }

    /// Weights (wa, wb) such that `wa·S_a(k) + wb·S_b(k)` is the blended, normalised prefix sum
    /// at t; `None` when both rows are empty (then x is uniform).
    #[inline]
    fn blend(&self, a: usize, b: usize, t: f64) -> Option<(f64, f64)> {
        let d = (1.0 - t) * self.row_mass(a) + t * self.row_mass(b);
        (d > 0.0).then(|| ((1.0 - t) / d, t / d))
    }

    /// The origin c ∈ [−1, 1] of the blended conditional CDF (weights from [`Self::blend`]):
    /// u₀ goes where that CDF equals u₀ + c (mod 1).
    #[inline]
    fn origin(&self, a: usize, b: usize, (wa, wb): (f64, f64)) -> f64 {
        (wa * self.origin_mass[a] + wb * self.origin_mass[b]).clamp(-1.0, 1.0)
    }

    /// Continuous row coordinate y ∈ [0, H] for u₁.
    #[inline]
    fn sample_row(&self, u1: f64) -> (f64, f64) {
        let cdf = &self.marginal_cdf;
        // Largest row r with cdf[r] <= u1, among rows of non-zero width.
        let mut r = cdf
            .partition_point(|&c| c <= u1)
            .saturating_sub(1)
            .min(self.height - 1);
        while r > 0 && cdf[r + 1] - cdf[r] <= 0.0 && cdf[r] >= u1 {
            r -= 1;
        }
        let width = cdf[r + 1] - cdf[r];
        let frac = if width > 0.0 {
            ((u1 - cdf[r]) / width).clamp(0.0, 1.0)
        } else {
            0.5
        };
        (r as f64 + frac, width * self.height as f64)
    }

    /// Maps u ∈ \[0,1\]² to p ∈ \[0,1\]² and returns the density of p (per unit area of \[0,1\]²).
    pub fn sample(&self, u: [f64; 2]) -> ([f64; 2], f64) {
        let u0 = u[0].clamp(0.0, 1.0);
        let u1 = u[1].clamp(0.0, 1.0);
        let (y, pdf_y) = self.sample_row(u1);
        let (a, b, t) = self.bracket(y);
        let w = self.width;
        let (x, pdf_x) = match self.blend(a, b, t) {
            None => (u0 * w as f64, 1.0),
            Some((wa, wb)) => {
                let pa = self.row_prefix(a);
                let pb = self.row_prefix(b);
                let blended = |k: usize| wa * pa[k] + wb * pb[k];
                let u0 = wrap_unit(u0 + self.origin(a, b, (wa, wb)));
                // Largest k in [0, W) with blended(k) <= u0 and a non-empty cell.
                let (mut lo, mut hi) = (0usize, w);
                while hi - lo > 1 {
                    let mid = (lo + hi) / 2;
                    if blended(mid) <= u0 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                // An empty cell here can only be a trailing one (u0 at the very end): step back
                // to the last non-empty cell.
                let mut k = lo;
                let mut cell = blended(k + 1) - blended(k);
                while cell <= 0.0 && k > 0 {
                    k -= 1;
                    cell = blended(k + 1) - blended(k);
                }
                if cell > 0.0 {
                    let frac = ((u0 - blended(k)) / cell).clamp(0.0, 1.0);
                    (k as f64 + frac, cell * w as f64)
                } else {
                    (k as f64 + 0.5, 0.0)
                }
            }
        };
        ([x / w as f64, y / self.height as f64], pdf_x * pdf_y)
    }

    /// Density at p ∈ \[0,1\]² (per unit area of \[0,1\]²), consistent with `sample`.
    pub fn pdf(&self, p: [f64; 2]) -> f64 {
        let x = (p[0].clamp(0.0, 1.0) * self.width as f64).min(self.width as f64 - 1e-9);
        let y = (p[1].clamp(0.0, 1.0) * self.height as f64).min(self.height as f64 - 1e-9);
        let row = y as usize;
        let pdf_y = (self.marginal_cdf[row + 1] - self.marginal_cdf[row]) * self.height as f64;
        let (a, b, t) = self.bracket(y);
        let k = x as usize;
        let pdf_x = match self.blend(a, b, t) {
            None => 1.0,
            Some((wa, wb)) => {
                let pa = self.row_prefix(a);
                let pb = self.row_prefix(b);
                (wa * (pa[k + 1] - pa[k]) + wb * (pb[k + 1] - pb[k])) * self.width as f64
            }
        };
        pdf_x * pdf_y
    }

    /// Inverse of `sample`: the u that maps to p.
    pub fn invert(&self, p: [f64; 2]) -> [f64; 2] {
        let x = p[0].clamp(0.0, 1.0) * self.width as f64;
        let y = p[1].clamp(0.0, 1.0) * self.height as f64;
        self.invert_pixel(x, y)
    }

    /// Inverse of `sample` at continuous pixel coordinates (x ∈ \[0,W\], y ∈ \[0,H\]).
    #[inline]
    pub fn invert_pixel(&self, x: f64, y: f64) -> [f64; 2] {
        let row = (y as usize).min(self.height - 1);
        let frac_y = (y - row as f64).clamp(0.0, 1.0);
        let c0 = self.marginal_cdf[row];
        let u1 = c0 + frac_y * (self.marginal_cdf[row + 1] - c0);
        let (a, b, t) = self.bracket(y);
        let k = (x as usize).min(self.width - 1);
        let frac_x = (x - k as f64).clamp(0.0, 1.0);
        let u0 = match self.blend(a, b, t) {
            None => x / self.width as f64,
            Some((wa, wb)) => {
                let pa = self.row_prefix(a);
                let pb = self.row_prefix(b);
                let lo = wa * pa[k] + wb * pb[k];
                let hi = wa * pa[k + 1] + wb * pb[k + 1];
                wrap_unit(lo + frac_x * (hi - lo) - self.origin(a, b, (wa, wb)))
            }
        };
        [u0.clamp(0.0, 1.0), u1.clamp(0.0, 1.0)]
    }
}

/// `v` ∈ [−1, 2] moved into [0, 1] by adding or subtracting 1 (2 gives 1, which the callers
/// treat as the end of the row).
#[inline]
fn wrap_unit(v: f64) -> f64 {
    if v < 0.0 {
        v + 1.0
    } else if v >= 1.0 {
        v - 1.0
    } else {
        v
    }
}

/// [`PiecewiseConstant2d::rebuild`]'s arguments, run through [`pulp::Arch::dispatch`] so that
/// the clean-up and the sums are compiled for the CPU's vector unit.
struct Rebuild<'a> {
    dist: &'a mut PiecewiseConstant2d,
    weights: &'a [f64],
    width: usize,
    height: usize,
}

impl pulp::WithSimd for Rebuild<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        self.dist
            .rebuild_inline(self.weights, self.width, self.height);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    fn random_map(w: usize, h: usize, seed: u64, zero_fraction: f64) -> Vec<f64> {
        let mut s = seed;
        (0..w * h)
            .map(|_| {
                let z = lcg(&mut s);
                let v = lcg(&mut s);
                if z < zero_fraction {
                    0.0
                } else {
                    v * v * 10.0
                }
            })
            .collect()
    }

    #[test]
    fn inverse_randoms() {
        // pbrt's InverseRandoms: invert(sample(u)) ≈ u wherever the density is positive.
        for (seed, zeros) in [(1u64, 0.0), (2, 0.3), (3, 0.7)] {
            let (w, h) = (37, 19);
            let dist = PiecewiseConstant2d::new(&random_map(w, h, seed, zeros), w, h);
            let mut s = seed * 99;
            for _ in 0..5000 {
                let u = [lcg(&mut s), lcg(&mut s)];
                let (p, pdf) = dist.sample(u);
                if pdf <= 0.0 {
                    continue;
                }
                let v = dist.invert(p);
                // u₀ lives on a circle (the origin c wraps it): compare it there.
                let du0 = (u[0] - v[0]).abs();
                assert!(
                    du0.min(1.0 - du0) < 1e-9 && (u[1] - v[1]).abs() < 1e-9,
                    "{u:?} -> {p:?} -> {v:?}"
                );
            }
        }
    }

    #[test]
    fn sampled_points_have_positive_density() {
        let (w, h) = (16, 8);
        let dist = PiecewiseConstant2d::new(&random_map(w, h, 5, 0.6), w, h);
        let mut s = 7;
        for _ in 0..10000 {
            let (p, pdf) = dist.sample([lcg(&mut s), lcg(&mut s)]);
            assert!(pdf > 0.0);
            assert!(
                (dist.pdf(p) - pdf).abs() <= 1e-9 * pdf.max(1.0),
                "pdf mismatch at {p:?}"
            );
        }
    }

    #[test]
    fn pdf_integrates_to_one() {
        let (w, h) = (12, 7);
        let dist = PiecewiseConstant2d::new(&random_map(w, h, 11, 0.2), w, h);
        let n = 600;
        let mut sum = 0.0;
        for j in 0..n {
            for i in 0..n {
                sum += dist.pdf([(i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64]);
            }
        }
        sum /= (n * n) as f64;
        assert!((sum - 1.0).abs() < 1e-3, "∫pdf = {sum}");
    }

    /// Largest step of the warped point along a sweep of u1 at fixed u0.
    fn largest_step(dist: &PiecewiseConstant2d, steps: usize) -> f64 {
        let mut prev = dist.sample([0.5, 0.0]).0;
        let mut max_step = 0.0f64;
        for i in 1..=steps {
            let p = dist.sample([0.5, i as f64 / steps as f64]).0;
            max_step = max_step.max((p[0] - prev[0]).abs() + (p[1] - prev[1]).abs());
            prev = p;
        }
        max_step
    }

    #[test]
    fn warp_is_continuous_across_row_bands() {
        // Two rows with opposite conditionals over a dim background: the standard warp (row
        // chosen, then that row's CDF inverted) jumps across the image at the band edge.
        let w = 8;
        let mut weights = vec![0.01; w * 2];
        weights[0] = 1.0;
        weights[w + w - 1] = 1.0;
        let dist = PiecewiseConstant2d::new(&weights, w, 2);
        let coarse = largest_step(&dist, 10_000);
        let fine = largest_step(&dist, 40_000);
        // Continuous: the largest step shrinks with the step size (a jump would not).
        assert!(coarse < 5e-3, "largest step {coarse}");
        assert!(
            fine < 0.3 * coarse,
            "largest step {fine} at 4x finer sweep vs {coarse}"
        );
    }

    /// A map of `w`×4 cells: a dim background with a gentle slope along x (1 to 2) and, in rows
    /// 1 and 2, a spot at column `spot` (wrapping) holding half of its row's mass.
    fn map_with_spot(w: usize, spot: usize) -> Vec<f64> {
        let mut weights: Vec<f64> = (0..w * 4)
            .map(|i| 1.0 + (i % w) as f64 / w as f64)
            .collect();
        for row in 1..3 {
            weights[row * w + spot % w] = 1.5 * w as f64;
        }
        weights
    }

    /// Largest distance on the circle (in turns) between the points that `before` and `after`
    /// make of the same u, over a grid of u.
    fn largest_azimuth_move(before: &PiecewiseConstant2d, after: &PiecewiseConstant2d) -> f64 {
        let mut largest = 0.0f64;
        for j in 0..64 {
            for i in 0..64 {
                let u = [(i as f64 + 0.5) / 64.0, (j as f64 + 0.5) / 64.0];
                let (a, b) = (before.sample(u).0, after.sample(u).0);
                let d = (a[0] - b[0]).abs();
                largest = largest.max(d.min(1.0 - d));
            }
        }
        largest
    }

    /// The largest point move of a one-cell step of the spot across the seam, and of steps
    /// elsewhere (near the seam on either side, a quarter and half a turn away), at width `w`.
    fn spot_step_moves(w: usize) -> (f64, f64) {
        let step = |from: usize| {
            let before = PiecewiseConstant2d::new(&map_with_spot(w, from), w, 4);
            let after = PiecewiseConstant2d::new(&map_with_spot(w, from + 1), w, 4);
            largest_azimuth_move(&before, &after)
        };
        let elsewhere = [w - 3, w - 2, 0, 1, 2, w / 8, w / 4, w / 2]
            .into_iter()
            .map(step)
            .fold(0.0, f64::max);
        (step(w - 1), elsewhere)
    }

    #[test]
    fn a_spot_stepping_across_the_seam_moves_points_continuously() {
        // With the CDFs' origin fixed at x = 0 (c held at 0), the spot's step from the last column
        // to the first moves its rows' points by half a turn at both widths (a jump: measured
        // 0.4999 and 0.5000 turn), steps elsewhere by 0.0155 and 0.0020. With the windowed origin
        // the step across the seam moves them as far as steps elsewhere, and that shrinks with
        // the cell (continuity): across / elsewhere 0.1123 / 0.1060 turn at width 64, 0.0153 /
        // 0.0153 at 512. The price: while the spot is inside the window, each of its steps
        // slides its rows' other points a little (0.106 against 0.0155 turn at width 64).
        let (across_coarse, elsewhere_coarse) = spot_step_moves(64);
        let (across_fine, elsewhere_fine) = spot_step_moves(512);
        eprintln!(
            "largest move (turns), across the seam / elsewhere: width 64 {across_coarse:.4} / \
             {elsewhere_coarse:.4}, width 512 {across_fine:.4} / {elsewhere_fine:.4}"
        );
        assert!(
            across_fine < 0.25 * across_coarse.max(elsewhere_coarse),
            "across the seam: {across_fine} at 8× finer cells vs {across_coarse}"
        );
        assert!(
            across_fine <= 1.5 * elsewhere_fine && across_coarse <= 1.5 * elsewhere_coarse,
            "the step across the seam moves points more than 1.5× the steps elsewhere"
        );
    }

    #[test]
    fn all_zero_map_is_uniform() {
        let dist = PiecewiseConstant2d::new(&[0.0; 6], 3, 2);
        assert_eq!(dist.total(), 0.0);
        let (p, pdf) = dist.sample([0.25, 0.75]);
        assert!((p[0] - 0.25).abs() < 1e-12 && (p[1] - 0.75).abs() < 1e-12);
        assert!((pdf - 1.0).abs() < 1e-12);
    }
}
