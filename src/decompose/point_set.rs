//! The fixed, progressive point set in the unit square and its Voronoi-cell lookup.
//!
//! Havran et al. 2005 draw the same samples every frame, so light i in frame t is light i in
//! frame t−1, and use a progressive sequence so the light count can change by taking a prefix.
//! Steps:
//! 1. Start from the 2D Halton sequence (bases 2 and 3, index from 1).
//! 2. Relax level by level: for prefix size P = 2, 4, 8, …, the points [P/2, P) move by Lloyd's
//!    algorithm (to the centroid of their Voronoi cell among all P points, computed on a grid of
//!    ~256 samples per cell) while the points [0, P/2) stay fixed. Every prefix of 2^k points is
//!    therefore a relaxed, blue-noise-like set, and adding points never moves earlier ones.
//!
//! The relaxation of all [`MAX_POINTS`] points takes seconds (100 million nearest-point
//! searches: 2.8 s on two cores, 5 s on one), which a daemon asked for thousands of lights paid
//! at every start. So the set ships with envlight, computed: `progressive_points.bin` beside
//! this file holds the [`MAX_POINTS`] points as little-endian f64 pairs, written by
//! `cargo run --release --example point_set_table` from [`relax_progressive_points`], and the
//! test `the_shipped_set_is_the_relaxation` redoes the relaxation and compares every bit.

use rayon::prelude::*;
use std::sync::{Arc, OnceLock};

/// Largest supported light count.
pub const MAX_POINTS: usize = 16384;

const LLOYD_ITERATIONS: usize = 12;
const SAMPLES_PER_CELL: usize = 256;

fn radical_inverse(mut i: u64, base: u64) -> f64 {
    let inv = 1.0 / base as f64;
    let mut f = inv;
    let mut r = 0.0;
    while i > 0 {
        r += f * (i % base) as f64;
        i /= base;
        f *= inv;
    }
    r
}

/// Uniform bucket grid over the unit square for nearest-point queries.
struct NearestGrid<'a> {
    points: &'a [[f64; 2]],
    res: usize,
    buckets: Vec<Vec<u32>>,
}

impl<'a> NearestGrid<'a> {
    fn new(points: &'a [[f64; 2]]) -> Self {
        let res = ((points.len() as f64).sqrt().ceil() as usize).max(1);
        let mut buckets = vec![Vec::new(); res * res];
        for (i, p) in points.iter().enumerate() {
            let (bx, by) = Self::bucket_of(res, *p);
            buckets[by * res + bx].push(i as u32);
        }
        Self {
            points,
            res,
            buckets,
        }
    }

    fn bucket_of(res: usize, p: [f64; 2]) -> (usize, usize) {
        let f = |v: f64| ((v * res as f64) as usize).min(res - 1);
        (f(p[0]), f(p[1]))
    }

    /// Index of the point nearest to q (ties to the lower index).
    fn nearest(&self, q: [f64; 2]) -> usize {
        let (bx, by) = Self::bucket_of(self.res, q);
        let cell = 1.0 / self.res as f64;
        let mut best = (f64::INFINITY, usize::MAX);
        for ring in 0..=self.res {
            // Any point in ring r+1 or beyond is at least r·cell away.
            if ring > 0 && (ring as f64 - 1.0) * cell > best.0.sqrt() {
                break;
            }
            let (x0, x1) = (bx as isize - ring as isize, bx as isize + ring as isize);
            let (y0, y1) = (by as isize - ring as isize, by as isize + ring as isize);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let on_ring = x == x0 || x == x1 || y == y0 || y == y1;
                    if !on_ring
                        || x < 0
                        || y < 0
                        || x >= self.res as isize
                        || y >= self.res as isize
                    {
                        continue;
                    }
                    for &i in &self.buckets[y as usize * self.res + x as usize] {
                        let p = self.points[i as usize];
                        let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
                        if d < best.0 || (d == best.0 && (i as usize) < best.1) {
                            best = (d, i as usize);
                        }
                    }
                }
            }
        }
        best.1
    }
}

/// Lloyd-relaxes points [fixed, len) with points [0, fixed) held in place.
fn relax_level(points: &mut [[f64; 2]], fixed: usize) {
    let n = points.len();
    let res = ((n * SAMPLES_PER_CELL) as f64).sqrt().ceil() as usize;
    let sample =
        |i: usize, j: usize| [(i as f64 + 0.5) / res as f64, (j as f64 + 0.5) / res as f64];
    let mut nearest = vec![0u32; res * res];
    for _ in 0..LLOYD_ITERATIONS {
        // The nearest point of every sample, rows in parallel (the searches are the work: 98%
        // of perf's samples of a 16384-point set), then the sums in raster order on one
        // thread, so the points are the same bits with any number of threads.
        {
            let grid = NearestGrid::new(points);
            nearest
                .par_chunks_mut(res)
                .enumerate()
                .for_each(|(j, row)| {
                    for (i, k) in row.iter_mut().enumerate() {
                        *k = grid.nearest(sample(i, j)) as u32;
                    }
                });
        }
        let mut sums = vec![[0.0f64; 3]; n];
        for (j, row) in nearest.chunks_exact(res).enumerate() {
            for (i, &k) in row.iter().enumerate() {
                let k = k as usize;
                if k >= fixed {
                    let q = sample(i, j);
                    sums[k][0] += q[0];
                    sums[k][1] += q[1];
                    sums[k][2] += 1.0;
                }
            }
        }
        for (p, s) in points.iter_mut().zip(&sums).skip(fixed) {
            if s[2] > 0.0 {
                *p = [s[0] / s[2], s[1] / s[2]];
            }
        }
    }
}

/// The first `n.next_power_of_two()` points (at most [`MAX_POINTS`]) of the progressive set,
/// computed: Halton points relaxed level by level (the module doc). [`progressive_points`]
/// serves the same points from the shipped table.
pub fn relax_progressive_points(n: usize) -> Vec<[f64; 2]> {
    let target = n.next_power_of_two().min(MAX_POINTS);
    let mut points = Vec::with_capacity(target);
    while points.len() < target {
        let fixed = points.len();
        let size = (fixed * 2).max(1);
        for i in fixed..size {
            points.push([
                radical_inverse(i as u64 + 1, 2),
                radical_inverse(i as u64 + 1, 3),
            ]);
        }
        if fixed > 0 {
            relax_level(&mut points, fixed);
        }
    }
    points
}

/// The shipped set ([`relax_progressive_points`] of [`MAX_POINTS`]; the module doc).
static SHIPPED: &[u8; MAX_POINTS * 16] = include_bytes!("progressive_points.bin");

/// The first `n` points (1 ≤ n ≤ [`MAX_POINTS`]) of the progressive relaxed set, from the
/// shipped table (decoded once per process).
pub fn progressive_points(n: usize) -> Arc<[[f64; 2]]> {
    static POINTS: OnceLock<Vec<[f64; 2]>> = OnceLock::new();
    let n = n.clamp(1, MAX_POINTS);
    let points = POINTS.get_or_init(|| {
        SHIPPED
            .chunks_exact(16)
            .map(|p| {
                let (x, y) = p.split_at(8);
                let coordinate = |b: &[u8]| f64::from_le_bytes(b.try_into().unwrap_or_default());
                [coordinate(x), coordinate(y)]
            })
            .collect()
    });
    Arc::from(&points[..n])
}

/// The set as [`progressive_points`]' table stores it: each point's x then y, little-endian
/// f64.
pub fn table_bytes(points: &[[f64; 2]]) -> Vec<u8> {
    points
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The relaxation searches in parallel but sums on one thread: the same points, to the
    /// bit, on one thread and on three.
    #[test]
    fn relaxation_does_not_depend_on_the_number_of_threads() {
        let relaxed = |threads: usize| {
            let mut points: Vec<[f64; 2]> = (1..=128u64)
                .map(|i| [radical_inverse(i, 2), radical_inverse(i, 3)])
                .collect();
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool")
                .install(|| relax_level(&mut points, 64));
            points
        };
        let (one, three) = (relaxed(1), relaxed(3));
        assert!(one
            .iter()
            .flatten()
            .map(|v| v.to_bits())
            .eq(three.iter().flatten().map(|v| v.to_bits())));
        // and the relaxation moved the new points
        assert_ne!(one[100], [radical_inverse(101, 2), radical_inverse(101, 3)]);
    }

    /// Mean squared distance from the square to the nearest point (Lloyd's objective).
    fn quantization_error(points: &[[f64; 2]]) -> f64 {
        let grid = NearestGrid::new(points);
        let res = 256;
        let mut sum = 0.0;
        for j in 0..res {
            for i in 0..res {
                let q = [(i as f64 + 0.5) / res as f64, (j as f64 + 0.5) / res as f64];
                let p = points[grid.nearest(q)];
                sum += (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
            }
        }
        sum / (res * res) as f64
    }

    /// The shipped table is the relaxation's result to the bit: a change of the relaxation
    /// must come with a new table (`cargo run --release --example point_set_table`).
    #[test]
    fn the_shipped_set_is_the_relaxation() {
        let computed = relax_progressive_points(MAX_POINTS);
        assert_eq!(computed.len(), MAX_POINTS);
        let shipped = progressive_points(MAX_POINTS);
        if let Some(i) =
            (0..MAX_POINTS).find(|&i| computed[i].map(f64::to_bits) != shipped[i].map(f64::to_bits))
        {
            panic!(
                "point {i}: relaxed {:?}, shipped {:?} (regenerate the table: cargo run \
                 --release --example point_set_table)",
                computed[i], shipped[i]
            );
        }
        assert_eq!(table_bytes(&computed), SHIPPED.as_slice());
    }

    #[test]
    fn prefixes_are_stable() {
        let a = progressive_points(64);
        let b = progressive_points(256);
        assert_eq!(&a[..], &b[..64]);
        assert!(b
            .iter()
            .all(|p| (0.0..=1.0).contains(&p[0]) && (0.0..=1.0).contains(&p[1])));
    }

    #[test]
    fn relaxation_stratifies_every_power_of_two_prefix() {
        let relaxed = progressive_points(1024);
        for k in 2..=10 {
            let n = 1usize << k;
            let halton: Vec<[f64; 2]> = (1..=n as u64)
                .map(|i| [radical_inverse(i, 2), radical_inverse(i, 3)])
                .collect();
            let e_relaxed = quantization_error(&relaxed[..n]);
            let e_halton = quantization_error(&halton);
            // A hexagonal lattice of n points reaches 5/(18√3)/n ≈ 0.1604/n.
            let hexagonal = 0.1604 / n as f64;
            assert!(
                e_relaxed < e_halton,
                "prefix {n}: {e_relaxed} vs Halton {e_halton}"
            );
            // Boundary effects dominate small prefixes; larger ones come close to the lattice.
            assert!(
                n < 64 || e_relaxed < 1.25 * hexagonal,
                "prefix {n}: {:.3}x hexagonal",
                e_relaxed / hexagonal
            );
        }
    }
}
