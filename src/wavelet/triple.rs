//! The sparse triple-product binding tensor `C_ijk = ∫ Ψ_i Ψ_j Ψ_k dω` of the 2-D wavelet basis
//! on the octahedral map, and triple-product integrals `B = Σ V_i L_j ρ_k C_ijk` (Ng,
//! Ramamoorthi and Hanrahan 2004, "Triple product wavelet integrals"; Michiels et al. 2013 for
//! high-order bases).
//!
//! # Exact in the discrete setting
//!
//! Functions on the sphere are piecewise constant on the `side²` equal-area texels (that is what
//! the map stores), and the basis functions are `Ψ_i(t) = W_i(t) / √dω` with `W_i` the rows of
//! the orthonormal transform. So `C_ijk = Σ_t W_i(t) W_j(t) W_k(t) / √dω`, a finite sum over the
//! finest level: no quadrature, no refinement-equation truncation, exact to rounding for every
//! basis (Haar or not), and `Σ V_i L_j ρ_k C_ijk = Σ_t V_t L_t ρ_t dω` holds exactly when all
//! coefficients are kept.
//!
//! # Separable structure (never an O(N³) enumeration)
//!
//! The nonstandard pyramid's 2-D functions are products `W_i(x, y) = a_i(y) · b_i(x)` of two 1-D
//! periodic functions of the same level: for the coefficient at Mallat row r, column c of level
//! l (block half size h = side >> l), the row factor is the scaling function φ_{l,r} if r < h and
//! the wavelet ψ_{l,r−h} otherwise, likewise the column factor (the coarsest block: φ_L ⊗ φ_L).
//! Hence `C_ijk = T(a_i, a_j, a_k) · T(b_i, b_j, b_k) / √dω` with the 1-D table
//! `T(f, g, h) = Σ_x f(x) g(x) h(x)` over ~2·side distinct 1-D functions. Steps:
//! 1. Synthesise each 1-D function once (inverse 1-D transform of a unit vector, the same
//!    transform as the 2-D one) and record its support as a bit mask on the periodic grid.
//! 2. Enumerate triples f ≤ g ≤ h (symmetry: T is invariant under permutation, so one sixth)
//!    whose three supports intersect (one AND of masks; wavelets of distant positions or of very
//!    different positions at fine levels are skipped without a sum), and sum only over the common
//!    support.
//! 3. Prune entries with |T| ≤ `tol · max|T|`: for Haar this removes exactly the entries that Ng
//!    et al.'s rule says vanish (the product of coarser functions is constant on a finer
//!    wavelet's support and the wavelet has a vanishing moment; tested), for high-order bases it
//!    removes the entries that the vanishing moments make zero or negligible (a finer wavelet
//!    against a product of coarser functions that is nearly polynomial on its support).
//! 4. Store, for every ordered pair (f, g), the list of (h, T): the 2-D tensor is never built;
//!    for a pair of 2-D indices (i, j) the candidates k come from the product of the row list of
//!    (a_i, a_j) and the column list of (b_i, b_j), kept when (a_k, b_k) is a valid 2-D function.
//!
//! The triple product then costs `Σ_{(i,j) ∈ V×L} |list(a_i,a_j)| · |list(b_i,b_j)|`.

use super::basis::Basis;
use super::relight::{Grid, TransportError};
use super::transform;

/// Largest side the tensor supports (support masks are u128).
pub const MAX_TRIPLE_SIDE: usize = 128;

/// Default pruning tolerance relative to the largest 1-D entry.
pub const DEFAULT_PRUNE: f64 = 1e-12;

/// Counts of the tensor's construction.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TensorStats {
    /// Distinct 1-D functions.
    pub functions: usize,
    /// 1-D triples f ≤ g ≤ h in all: n(n+1)(n+2)/6.
    pub triples_total: usize,
    /// 1-D triples whose supports intersect (summed).
    pub triples_overlapping: usize,
    /// 1-D triples kept after pruning.
    pub triples_kept: usize,
}

/// The binding tensor in factored form.
#[derive(Clone, Debug)]
pub struct TripleTensor {
    pub side: usize,
    pub basis: Basis,
    pub levels: u32,
    /// 1-D functions (length `side` each).
    functions: Vec<Vec<f64>>,
    /// Row and column 1-D function of every 2-D index.
    row_fn: Vec<u32>,
    col_fn: Vec<u32>,
    /// 2-D index of (row fn, col fn), or u32::MAX.
    map: Vec<u32>,
    /// For ordered pair (f, g) at f·n + g: (h, T(f, g, h)).
    pairs: Vec<Vec<(u32, f64)>>,
    inv_sqrt_domega: f64,
    pub stats: TensorStats,
}

/// 1-D function of Mallat index p at level l (h = side >> l): (is wavelet, shift).
fn fn_key(p: usize, h: usize) -> (bool, usize) {
    if p < h {
        (false, p)
    } else {
        (true, p - h)
    }
}

/// Level of 2-D Mallat position (r, c) for `levels` levels: the coarsest block is level `levels`.
fn level_of(side: usize, levels: u32, r: usize, c: usize) -> u32 {
    let p = r.max(c);
    if p < side >> levels {
        return levels;
    }
    // p in [side >> l, side >> (l-1)).
    let mut l = levels;
    while l > 1 && p >= side >> (l - 1) {
        l -= 1;
    }
    l
}

impl TripleTensor {
    /// Builds the factored tensor for a grid; `prune` is the relative tolerance of step 3.
    pub fn new(grid: &Grid, prune: f64) -> Result<Self, TransportError> {
        let side = grid.side;
        if side > MAX_TRIPLE_SIDE {
            return Err(TransportError::SideTooLarge {
                what: "triple-product tensor",
                side,
                max: MAX_TRIPLE_SIDE,
            });
        }
        if !(prune.is_finite() && prune >= 0.0) {
            return Err(TransportError::Invalid(format!(
                "prune tolerance must be finite and ≥ 0, got {prune}"
            )));
        }
        let levels = grid.levels;
        // Step 1: the 1-D functions, keyed by (level, wavelet?, shift).
        let mut ids = std::collections::HashMap::new();
        let mut functions: Vec<Vec<f64>> = Vec::new();
        let mut get = |l: u32, key: (bool, usize)| -> Result<u32, TransportError> {
            if let Some(&id) = ids.get(&(l, key)) {
                return Ok(id);
            }
            let h = side >> l;
            let mut e = vec![0.0; side];
            e[if key.0 { h + key.1 } else { key.1 }] = 1.0;
            transform::inverse_1d(&mut e, grid.basis, l)?;
            functions.push(e);
            let id = (functions.len() - 1) as u32;
            ids.insert((l, key), id);
            Ok(id)
        };
        let n2 = side * side;
        let mut row_fn = Vec::with_capacity(n2);
        let mut col_fn = Vec::with_capacity(n2);
        for r in 0..side {
            for c in 0..side {
                let l = level_of(side, levels, r, c);
                let h = side >> l;
                row_fn.push(get(l, fn_key(r, h))?);
                col_fn.push(get(l, fn_key(c, h))?);
            }
        }
        let n = functions.len();
        let mut map = vec![u32::MAX; n * n];
        for i in 0..n2 {
            map[row_fn[i] as usize * n + col_fn[i] as usize] = i as u32;
        }
        let scale = functions
            .iter()
            .flat_map(|f| f.iter())
            .fold(0.0f64, |m, v| m.max(v.abs()));
        let masks: Vec<u128> = functions
            .iter()
            .map(|f| {
                f.iter().enumerate().fold(0u128, |m, (x, v)| {
                    if v.abs() > 1e-15 * scale {
                        m | 1 << x
                    } else {
                        m
                    }
                })
            })
            .collect();
        // Step 2: triples with intersecting supports, summed on the common support.
        let mut raw: Vec<(u32, u32, u32, f64)> = Vec::new();
        let mut stats = TensorStats {
            functions: n,
            triples_total: n * (n + 1) * (n + 2) / 6,
            ..Default::default()
        };
        for a in 0..n {
            for b in a..n {
                let ab = masks[a] & masks[b];
                if ab == 0 {
                    continue;
                }
                for c in b..n {
                    let mut m = ab & masks[c];
                    if m == 0 {
                        continue;
                    }
                    stats.triples_overlapping += 1;
                    let mut s = 0.0;
                    while m != 0 {
                        let x = m.trailing_zeros() as usize;
                        m &= m - 1;
                        s += functions[a][x] * functions[b][x] * functions[c][x];
                    }
                    raw.push((a as u32, b as u32, c as u32, s));
                }
            }
        }
        // Step 3: prune.
        let max = raw.iter().fold(0.0f64, |m, t| m.max(t.3.abs()));
        let tol = prune * max;
        let mut pairs: Vec<Vec<(u32, f64)>> = vec![Vec::new(); n * n];
        for &(a, b, c, s) in &raw {
            if s.abs() <= tol {
                continue;
            }
            stats.triples_kept += 1;
            // Step 4: every distinct ordered permutation.
            let mut perms = [
                (a, b, c),
                (a, c, b),
                (b, a, c),
                (b, c, a),
                (c, a, b),
                (c, b, a),
            ];
            perms.sort_unstable();
            let mut last = None;
            for p in perms {
                if last == Some(p) {
                    continue;
                }
                last = Some(p);
                pairs[p.0 as usize * n + p.1 as usize].push((p.2, s));
            }
        }
        Ok(Self {
            side,
            basis: grid.basis,
            levels,
            functions,
            row_fn,
            col_fn,
            map,
            pairs,
            inv_sqrt_domega: 1.0 / grid.d_omega().sqrt(),
            stats,
        })
    }

    /// Number of nonzero C_ijk over all ordered 2-D triples (i, j, k), enumerated pair by pair
    /// from the 1-D lists: O(side⁴ · list lengths), meant for reports at small sides.
    pub fn count_nonzero_2d(&self) -> u64 {
        let n2 = self.side * self.side;
        let mut count = 0u64;
        for i in 0..n2 {
            for j in 0..n2 {
                count += self.for_each_k(i, j, |_, _| {}) as u64;
            }
        }
        count
    }

    /// Calls `f(k, C_ijk)` for every nonzero entry of the pair (i, j); returns how many.
    #[inline]
    fn for_each_k(&self, i: usize, j: usize, mut f: impl FnMut(usize, f64)) -> usize {
        let n = self.functions.len();
        let rows = &self.pairs[self.row_fn[i] as usize * n + self.row_fn[j] as usize];
        if rows.is_empty() {
            return 0;
        }
        let cols = &self.pairs[self.col_fn[i] as usize * n + self.col_fn[j] as usize];
        let mut count = 0;
        for &(ra, ta) in rows {
            let base = ra as usize * n;
            for &(cb, tb) in cols {
                let k = self.map[base + cb as usize];
                if k != u32::MAX {
                    f(k as usize, ta * tb * self.inv_sqrt_domega);
                    count += 1;
                }
            }
        }
        count
    }

    /// The entry C_ijk (for tests and inspection; O(list length)).
    pub fn entry(&self, i: usize, j: usize, k: usize) -> f64 {
        let n2 = self.side * self.side;
        if i >= n2 || j >= n2 || k >= n2 {
            return 0.0;
        }
        let mut v = 0.0;
        self.for_each_k(i, j, |kk, c| {
            if kk == k {
                v += c;
            }
        });
        v
    }

    /// The 1-D functions: row factor and column factor of 2-D index `i` (for tests).
    pub fn factors(&self, i: usize) -> Option<(&[f64], &[f64])> {
        Some((
            self.functions.get(*self.row_fn.get(i)? as usize)?,
            self.functions.get(*self.col_fn.get(i)? as usize)?,
        ))
    }

    /// The projected product: `P_k = Σ_ij a_i b_j C_ijk` for sparse `a` and `b` (dense output of
    /// `side²`). `∫ a b c dω = Σ_k P_k c_k` for any third function c, so one product serves every
    /// BRDF slice.
    pub fn product(&self, a: &[(u32, f64)], b: &[(u32, f64)]) -> Result<Vec<f64>, TransportError> {
        let n2 = self.side * self.side;
        self.check(a)?;
        self.check(b)?;
        let mut p = vec![0.0; n2];
        for &(i, ai) in a {
            for &(j, bj) in b {
                let w = ai * bj;
                self.for_each_k(i as usize, j as usize, |k, c| p[k] += w * c);
            }
        }
        Ok(p)
    }

    /// `B = Σ V_i L_j ρ_k C_ijk` for sparse V and L and a dense ρ (`side²`).
    pub fn triple(
        &self,
        v: &[(u32, f64)],
        l: &[(u32, f64)],
        rho: &[f64],
    ) -> Result<f64, TransportError> {
        let n2 = self.side * self.side;
        if rho.len() != n2 {
            return Err(TransportError::Length {
                what: "BRDF coefficients",
                expected: n2,
                got: rho.len(),
            });
        }
        self.check(v)?;
        self.check(l)?;
        let mut sum = 0.0;
        for &(i, vi) in v {
            for &(j, lj) in l {
                let mut s = 0.0;
                self.for_each_k(i as usize, j as usize, |k, c| s += rho[k] * c);
                sum += vi * lj * s;
            }
        }
        Ok(sum)
    }

    fn check(&self, sparse: &[(u32, f64)]) -> Result<(), TransportError> {
        let n2 = self.side * self.side;
        match sparse
            .iter()
            .find(|(i, v)| *i as usize >= n2 || !v.is_finite())
        {
            Some((i, v)) => Err(TransportError::Invalid(format!(
                "sparse coefficient ({i}, {v}) out of range 0..{n2} or not finite"
            ))),
            None => Ok(()),
        }
    }
}

/// The `k` largest coefficients of a dense vector as a sparse list (sorted by index).
pub fn sparse_largest(c: &[f64], k: usize) -> Vec<(u32, f64)> {
    super::relight::largest_indices(c, k)
        .into_iter()
        .filter(|&i| c[i] != 0.0)
        .map(|i| (i as u32, c[i]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn factors_match_the_2d_inverse_transform() {
        for basis in [Basis::Haar, Basis::Daubechies(3), Basis::Coiflet(2)] {
            for levels in [None, Some(2)] {
                let grid = Grid::new(8, basis, levels).unwrap();
                let t = TripleTensor::new(&grid, DEFAULT_PRUNE).unwrap();
                for i in 0..64 {
                    let mut e = vec![0.0; 64];
                    e[i] = 1.0;
                    transform::inverse_2d(&mut e, 8, basis, grid.levels).unwrap();
                    let (a, b) = t.factors(i).unwrap();
                    for y in 0..8 {
                        for x in 0..8 {
                            assert!(
                                (e[y * 8 + x] - a[y] * b[x]).abs() < 1e-12,
                                "{basis} levels {levels:?} index {i}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn entries_equal_the_texel_sum() {
        let grid = Grid::new(8, Basis::Daubechies(2), None).unwrap();
        let t = TripleTensor::new(&grid, 0.0).unwrap();
        let fns: Vec<Vec<f64>> = (0..64)
            .map(|i| {
                let mut e = vec![0.0; 64];
                e[i] = 1.0;
                transform::inverse_2d(&mut e, 8, grid.basis, grid.levels).unwrap();
                e
            })
            .collect();
        let s = 1.0 / grid.d_omega().sqrt();
        for (i, j, k) in [(0, 0, 0), (1, 9, 10), (5, 5, 63), (17, 18, 3), (40, 41, 42)] {
            let direct: f64 = (0..64)
                .map(|t| fns[i][t] * fns[j][t] * fns[k][t])
                .sum::<f64>()
                * s;
            assert!((t.entry(i, j, k) - direct).abs() < 1e-12, "({i},{j},{k})");
        }
    }

    /// Ng et al.'s rule, in 1-D with scaling functions at every level: T(f, g, h) ≠ 0 exactly
    /// when the supports are nested and the functions with the smallest support contain an even
    /// number of wavelets.
    #[test]
    fn haar_tensor_follows_the_nesting_rule() {
        let grid = Grid::new(16, Basis::Haar, None).unwrap();
        let t = TripleTensor::new(&grid, 1e-9).unwrap();
        // Recover each 1-D function's support and kind from the vectors.
        let n = t.functions.len();
        let support =
            |f: &Vec<f64>| -> Vec<usize> { (0..f.len()).filter(|&x| f[x].abs() > 1e-12).collect() };
        let is_wavelet = |f: &Vec<f64>| f.iter().sum::<f64>().abs() < 1e-12;
        let mut nonzero = 0;
        for a in 0..n {
            for b in a..n {
                for c in b..n {
                    let trio = [a, b, c];
                    let sups: Vec<Vec<usize>> =
                        trio.iter().map(|&f| support(&t.functions[f])).collect();
                    let smallest = sups.iter().map(|s| s.len()).min().unwrap();
                    let inner = sups.iter().position(|s| s.len() == smallest).unwrap();
                    let nested = sups
                        .iter()
                        .all(|s| sups[inner].iter().all(|x| s.contains(x)));
                    let wavelets_at_finest = trio
                        .iter()
                        .zip(&sups)
                        .filter(|(&f, s)| s.len() == smallest && is_wavelet(&t.functions[f]))
                        .count();
                    let rule = nested
                        && sups
                            .iter()
                            .filter(|s| s.len() == smallest)
                            .all(|s| *s == sups[inner])
                        && wavelets_at_finest % 2 == 0;
                    let stored = t.pairs[a * n + b].iter().any(|&(h, _)| h as usize == c);
                    assert_eq!(stored, rule, "triple ({a}, {b}, {c})");
                    nonzero += stored as usize;
                }
            }
        }
        assert_eq!(nonzero, t.stats.triples_kept);
        assert!(t.stats.triples_kept < t.stats.triples_overlapping);
    }

    #[test]
    fn triple_product_with_all_coefficients_is_exact() {
        for basis in [Basis::Haar, Basis::Daubechies(4), Basis::Coiflet(2)] {
            let grid = Grid::new(8, basis, None).unwrap();
            let t = TripleTensor::new(&grid, DEFAULT_PRUNE).unwrap();
            let f = |k: f32| -> Vec<f64> {
                grid.dirs
                    .iter()
                    .map(|d| f64::from((k * d.x).sin() + d.y * d.y + 0.5 * d.z).max(0.0))
                    .collect()
            };
            let (v, l, r) = (f(1.0), f(3.0), f(5.0));
            let brute: f64 =
                (0..grid.len()).map(|x| v[x] * l[x] * r[x]).sum::<f64>() * grid.d_omega();
            let (cv, cl, cr) = (
                grid.project(&v).unwrap(),
                grid.project(&l).unwrap(),
                grid.project(&r).unwrap(),
            );
            let all = grid.len();
            let b = t
                .triple(&sparse_largest(&cv, all), &sparse_largest(&cl, all), &cr)
                .unwrap();
            assert!(
                (b - brute).abs() < 1e-9 * brute.abs(),
                "{basis}: {b} vs {brute}"
            );
            let p = t
                .product(&sparse_largest(&cv, all), &sparse_largest(&cl, all))
                .unwrap();
            let b2: f64 = p.iter().zip(&cr).map(|(a, b)| a * b).sum();
            assert!((b2 - brute).abs() < 1e-9 * brute.abs());
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let grid = Grid::new(8, Basis::Haar, None).unwrap();
        let t = TripleTensor::new(&grid, DEFAULT_PRUNE).unwrap();
        assert!(t.triple(&[(64, 1.0)], &[], &[0.0; 64]).is_err());
        assert!(t.triple(&[(0, f64::NAN)], &[], &[0.0; 64]).is_err());
        assert!(t.triple(&[], &[], &[0.0; 3]).is_err());
        assert!(TripleTensor::new(&grid, -1.0).is_err());
        let big = Grid::new(256, Basis::Haar, None).unwrap();
        assert!(TripleTensor::new(&big, DEFAULT_PRUNE).is_err());
    }
}
