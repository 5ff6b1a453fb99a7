//! Hierarchical refinement for inverse rendering (Michiels et al. 2013): lighting coefficients
//! from observed radiance of a known object, growing the wavelet tree only where the
//! least-squares system stays full rank.
//!
//! # Model
//!
//! Each observation o (a vertex seen from a view) has a known transport T_o (visibility times
//! BRDF slice, projected on the basis as in [`relight`](super::relight)), and radiance
//! `b_o = Σ_k T_o[k] l_k` (per channel) for the unknown lighting coefficients l. The design
//! matrix M has one row per observation and one column per coefficient; only the columns of the
//! active wavelet-tree nodes enter the system.
//!
//! # Algorithm (the poster's, with the tree of the nonstandard pyramid)
//!
//! ```text
//! M ← columns of the roots (coarsest scaling block and the coarsest details)
//! repeat
//!   solve M l = b in the least-squares sense
//!   K ← children of the nodes added last whose |l| (RGB norm) ≥ split_fraction · max |l| among them
//!   for k in K (largest parent first):
//!     append column k to M; if rank(M) is no longer full, remove k again
//! until no node was added (or the finest level is reached)
//! ```
//!
//! A node at detail level l, quadrant (qy, qx) and local position (r, c) has four children at
//! level l − 1 in the same quadrant, at (2r + dy, 2c + dx).
//!
//! The rank test is a rank-revealing, column-by-column QR (modified Gram–Schmidt with one
//! re-orthogonalisation pass, "twice is enough"): the new column's component orthogonal to the
//! current columns, must exceed `rank_tol` times the largest column norm (the numerical rank of a rank-revealing QR). A column that fails would make
//! M rank-deficient (or so ill-conditioned that noise is amplified by more than 1/rank_tol), so
//! it is dropped, as in the poster. Because the QR is kept, each test costs O(m·n) and the
//! least-squares solve is a back substitution `R l = Qᵀ b`.

use super::relight::{Brdf, Grid, TransportError, View};
use super::visibility::{Mesh, Visibility};
use rayon::prelude::*;

/// Options of the refinement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineOptions {
    /// Minimum relative norm of a new column orthogonal to the current ones.
    pub rank_tol: f64,
    /// Split a node when its |l| is at least this fraction of the largest among the nodes added
    /// in the same step (0 splits every node).
    pub split_fraction: f64,
    /// Finest detail level allowed (1 = the finest of the pyramid).
    pub finest_level: u32,
    /// Keep a level only if it lowers the Bayesian information criterion
    /// `n ln(RSS/n) + p ln n` (n = 3 × observations, p = 3 × active nodes); otherwise roll it
    /// back and stop. Not in the poster (whose only test is the rank): with noisy observations
    /// the rank test alone lets fine levels fit the noise.
    pub bic: bool,
}

impl Default for RefineOptions {
    fn default() -> Self {
        Self {
            rank_tol: 1e-3,
            split_fraction: 0.05,
            finest_level: 1,
            bic: true,
        }
    }
}

/// Observations and their transport: one row per observation.
#[derive(Clone, Debug)]
pub struct Observations {
    /// Unknowns (side² coefficients).
    pub coeffs: usize,
    /// Column-major design matrix: `columns[k][o]`.
    columns: Vec<Vec<f64>>,
    /// Observed radiance per observation (RGB).
    pub radiance: Vec<[f64; 3]>,
}

impl Observations {
    /// From dense transport rows (`coeffs` each) and radiance.
    pub fn new(
        coeffs: usize,
        rows: &[Vec<f64>],
        radiance: Vec<[f64; 3]>,
    ) -> Result<Self, TransportError> {
        if rows.len() != radiance.len() {
            return Err(TransportError::Length {
                what: "observed radiance",
                expected: rows.len(),
                got: radiance.len(),
            });
        }
        if let Some((o, r)) = rows.iter().enumerate().find(|(_, r)| r.len() != coeffs) {
            return Err(TransportError::Length {
                what: if o == 0 {
                    "transport row 0"
                } else {
                    "transport row"
                },
                expected: coeffs,
                got: r.len(),
            });
        }
        if rows.iter().flatten().any(|v| !v.is_finite())
            || radiance.iter().flatten().any(|v| !v.is_finite())
        {
            return Err(TransportError::Invalid(
                "observations contain a non-finite value".into(),
            ));
        }
        let columns = (0..coeffs)
            .map(|k| rows.iter().map(|r| r[k]).collect())
            .collect();
        Ok(Self {
            coeffs,
            columns,
            radiance,
        })
    }

    /// Number of observations.
    pub fn len(&self) -> usize {
        self.radiance.len()
    }

    /// Whether there are no observations.
    pub fn is_empty(&self) -> bool {
        self.radiance.is_empty()
    }

    /// Predicted radiance of observation `o` for dense coefficient planes.
    pub fn predict(&self, o: usize, planes: &[Vec<f64>; 3]) -> [f64; 3] {
        let mut acc = [0.0; 3];
        for (k, col) in self.columns.iter().enumerate() {
            let t = col[o];
            if t != 0.0 {
                for c in 0..3 {
                    acc[c] += t * planes[c][k];
                }
            }
        }
        acc
    }
}

/// What one refinement step did.
#[derive(Clone, Debug, PartialEq)]
pub struct RefineStep {
    /// Detail level of the nodes tried (the first step: the roots, at the coarsest level).
    pub level: u32,
    /// Nodes tried.
    pub candidates: usize,
    /// Nodes added (full rank kept).
    pub added: usize,
    /// Nodes dropped by the rank test.
    pub rejected: usize,
    /// Active nodes after the step.
    pub active: usize,
    /// RMS residual of the observations after solving.
    pub residual_rms: f64,
}

/// Result of the refinement.
#[derive(Clone, Debug)]
pub struct Recovery {
    /// Dense coefficient planes (inactive nodes are 0), basis of [`Grid::project`].
    pub planes: [Vec<f64>; 3],
    /// Active node indices, in the order they were added.
    pub active: Vec<u32>,
    pub steps: Vec<RefineStep>,
}

/// Column-by-column QR with a rank test.
struct IncrementalQr {
    scale: f64,
    q: Vec<Vec<f64>>,
    r: Vec<Vec<f64>>,
    qtb: Vec<[f64; 3]>,
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl IncrementalQr {
    /// Appends column `a` when its component orthogonal to the current columns exceeds
    /// `tol` times the largest column norm seen (`scale`, updated here): the numerical rank test
    /// of a rank-revealing QR (|R_kk| > tol·|R_11|-like), which bounds how much noise the new
    /// unknown can amplify.
    fn try_add(&mut self, a: &[f64], b: &[[f64; 3]], tol: f64) -> bool {
        let norm = dot(a, a).sqrt();
        if norm == 0.0 || !norm.is_finite() {
            return false;
        }
        self.scale = self.scale.max(norm);
        let mut w = a.to_vec();
        let mut rcol = vec![0.0; self.q.len() + 1];
        for _pass in 0..2 {
            for (j, qj) in self.q.iter().enumerate() {
                let d = dot(qj, &w);
                rcol[j] += d;
                w.iter_mut().zip(qj).for_each(|(x, q)| *x -= d * q);
            }
        }
        let rest = dot(&w, &w).sqrt();
        if rest <= tol * self.scale {
            return false;
        }
        w.iter_mut().for_each(|x| *x /= rest);
        rcol[self.q.len()] = rest;
        let mut qb = [0.0; 3];
        for (wi, bi) in w.iter().zip(b) {
            for c in 0..3 {
                qb[c] += wi * bi[c];
            }
        }
        self.q.push(w);
        self.r.push(rcol);
        self.qtb.push(qb);
        true
    }

    /// Keeps the first `n` columns.
    fn truncate(&mut self, n: usize) {
        self.q.truncate(n);
        self.r.truncate(n);
        self.qtb.truncate(n);
    }

    /// Back substitution R x = Qᵀ b.
    fn solve(&self) -> Vec<[f64; 3]> {
        let n = self.q.len();
        let mut x = vec![[0.0; 3]; n];
        for i in (0..n).rev() {
            let mut s = self.qtb[i];
            for j in i + 1..n {
                for c in 0..3 {
                    s[c] -= self.r[j][i] * x[j][c];
                }
            }
            x[i] = s.map(|v| v / self.r[i][i]);
        }
        x
    }
}

/// Solves for the active nodes: dense planes and the residual sum of squares.
fn solve_planes(
    qr: &IncrementalQr,
    active: &[u32],
    obs: &Observations,
    coeffs: usize,
) -> ([Vec<f64>; 3], f64) {
    let x = qr.solve();
    let mut planes: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; coeffs]);
    for (&k, v) in active.iter().zip(&x) {
        for c in 0..3 {
            planes[c][k as usize] = v[c];
        }
    }
    let mut sq = 0.0;
    for o in 0..obs.len() {
        let p = obs.predict(o, &planes);
        for c in 0..3 {
            sq += (p[c] - obs.radiance[o][c]).powi(2);
        }
    }
    (planes, sq)
}

/// The roots of the tree: the coarsest scaling block and the coarsest details.
pub fn roots(side: usize, levels: u32) -> Vec<u32> {
    let b = if levels == 0 {
        side
    } else {
        side >> (levels - 1)
    };
    (0..b)
        .flat_map(|r| (0..b).map(move |c| (r * side + c) as u32))
        .collect()
}

/// Detail level of Mallat position index `i` (0 for the coarsest scaling block).
pub fn detail_level(side: usize, levels: u32, i: u32) -> u32 {
    let (r, c) = (i as usize / side, i as usize % side);
    let p = r.max(c);
    if p < side >> levels {
        return 0;
    }
    let mut l = levels;
    while l > 1 && p >= side >> (l - 1) {
        l -= 1;
    }
    l
}

/// The four children of a detail node (none for level-1 details and the scaling block).
pub fn children(side: usize, levels: u32, i: u32) -> Vec<u32> {
    let l = detail_level(side, levels, i);
    if l <= 1 {
        return Vec::new();
    }
    let h = side >> l;
    let (r, c) = (i as usize / side, i as usize % side);
    let (qr, qc) = ((r >= h) as usize, (c >= h) as usize);
    let (lr, lc) = (r - qr * h, c - qc * h);
    let h2 = 2 * h;
    let mut out = Vec::with_capacity(4);
    for dy in 0..2 {
        for dx in 0..2 {
            let rr = qr * h2 + 2 * lr + dy;
            let cc = qc * h2 + 2 * lc + dx;
            out.push((rr * side + cc) as u32);
        }
    }
    out
}

/// Runs the hierarchical refinement.
pub fn refine(
    grid: &Grid,
    obs: &Observations,
    opts: RefineOptions,
) -> Result<Recovery, TransportError> {
    if obs.coeffs != grid.len() {
        return Err(TransportError::Length {
            what: "observation transport",
            expected: grid.len(),
            got: obs.coeffs,
        });
    }
    if obs.is_empty() {
        return Err(TransportError::Invalid("no observations".into()));
    }
    if !(opts.rank_tol.is_finite() && opts.rank_tol > 0.0 && opts.rank_tol < 1.0) {
        return Err(TransportError::Invalid(format!(
            "rank tolerance must be in (0, 1), got {}",
            opts.rank_tol
        )));
    }
    if !(opts.split_fraction.is_finite() && (0.0..=1.0).contains(&opts.split_fraction)) {
        return Err(TransportError::Invalid(format!(
            "split fraction must be in [0, 1], got {}",
            opts.split_fraction
        )));
    }
    let (side, levels) = (grid.side, grid.levels);
    let b = &obs.radiance;
    let mut qr = IncrementalQr {
        scale: 0.0,
        q: Vec::new(),
        r: Vec::new(),
        qtb: Vec::new(),
    };
    let mut active: Vec<u32> = Vec::new();
    let mut steps = Vec::new();
    let mut candidates = roots(side, levels);
    let mut level = levels;
    let mut prev_sq = f64::INFINITY;
    loop {
        let mut added = Vec::new();
        let mut rejected = 0;
        for &k in &candidates {
            if qr.try_add(&obs.columns[k as usize], b, opts.rank_tol) {
                added.push(k);
            } else {
                rejected += 1;
            }
        }
        let before = active.len();
        active.extend_from_slice(&added);
        let (planes, sq) = solve_planes(&qr, &active, obs, grid.len());
        let n = (3 * obs.len()) as f64;
        let bic = |rss: f64, params: usize| n * (rss / n).max(1e-300).ln() + params as f64 * n.ln();
        if opts.bic && !steps.is_empty() && bic(sq, 3 * active.len()) >= bic(prev_sq, 3 * before) {
            // The level does not explain the observations better than its extra unknowns
            // would explain noise: roll it back and stop.
            qr.truncate(before);
            active.truncate(before);
            let (planes, sq) = solve_planes(&qr, &active, obs, grid.len());
            steps.push(RefineStep {
                level,
                candidates: candidates.len(),
                added: 0,
                rejected: candidates.len(),
                active: active.len(),
                residual_rms: (sq / n).sqrt(),
            });
            return Ok(Recovery {
                planes,
                active,
                steps,
            });
        }
        prev_sq = sq;
        steps.push(RefineStep {
            level,
            candidates: candidates.len(),
            added: added.len(),
            rejected,
            active: active.len(),
            residual_rms: (sq / n).sqrt(),
        });
        let norm = |k: u32| -> f64 {
            (0..3)
                .map(|c| planes[c][k as usize].powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let splittable: Vec<u32> = added
            .iter()
            .copied()
            .filter(|&k| detail_level(side, levels, k) > opts.finest_level.max(1))
            .collect();
        let max = splittable.iter().map(|&k| norm(k)).fold(0.0, f64::max);
        let mut parents: Vec<(f64, u32)> = splittable
            .iter()
            .map(|&k| (norm(k), k))
            .filter(|(n, _)| *n > 0.0 && *n >= opts.split_fraction * max)
            .collect();
        parents.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        candidates = parents
            .iter()
            .flat_map(|&(_, k)| children(side, levels, k))
            .collect();
        if candidates.is_empty() || added.is_empty() {
            return Ok(Recovery {
                planes,
                active,
                steps,
            });
        }
        level = candidates
            .iter()
            .map(|&k| detail_level(side, levels, k))
            .max()
            .unwrap_or(0);
    }
}

/// Which vertices are observed, with which BRDF, from where.
#[derive(Clone, Debug, PartialEq)]
pub struct ObservationSetup {
    pub brdf: Brdf,
    pub view: View,
    pub vertices: Vec<usize>,
}

/// Dense transport rows `W((V·ρ) √dω)` of every (setup, vertex), in order, in parallel.
pub fn transport_rows(
    grid: &Grid,
    mesh: &Mesh,
    vis: &Visibility,
    setups: &[ObservationSetup],
) -> Result<Vec<Vec<f64>>, TransportError> {
    if vis.texels != grid.len() || vis.vertices() != mesh.positions.len() {
        return Err(TransportError::Length {
            what: "visibility (texels × vertices)",
            expected: grid.len() * mesh.positions.len(),
            got: vis.texels * vis.vertices(),
        });
    }
    let mut jobs = Vec::new();
    for s in setups {
        s.brdf.validate()?;
        for &v in &s.vertices {
            if v >= mesh.positions.len() {
                return Err(TransportError::Invalid(format!(
                    "observed vertex {v} out of range (mesh has {})",
                    mesh.positions.len()
                )));
            }
            jobs.push((s.brdf, s.view, v));
        }
    }
    jobs.par_iter()
        .map(|&(brdf, view, v)| {
            let p = mesh.positions[v];
            let slice = grid.brdf_slice(brdf, mesh.normals[v], view.at(p));
            let values: Vec<f64> = slice
                .iter()
                .enumerate()
                .map(|(t, r)| if vis.get(v, t) { *r } else { 0.0 })
                .collect();
            grid.project(&values)
        })
        .collect()
}

/// The most noise [`synthesize`] adds: 100 × the RMS clean radiance.
pub const MAX_NOISE: f64 = 100.0;

/// Observations of a lighting `truth` (coefficient planes) through `rows`, with Gaussian noise
/// of standard deviation `noise` (0..=[`MAX_NOISE`]) times the RMS clean radiance.
pub fn synthesize(
    rows: &[Vec<f64>],
    truth: &[Vec<f64>; 3],
    noise: f64,
    seed: u64,
) -> Result<Observations, TransportError> {
    let coeffs = truth[0].len();
    if truth.iter().any(|p| p.len() != coeffs) {
        return Err(TransportError::Invalid(
            "lighting planes differ in length".into(),
        ));
    }
    // Above 100 × the signal the observations are noise (and 1e300 overflowed the sums,
    // leaving every error NaN).
    if !(0.0..=MAX_NOISE).contains(&noise) {
        return Err(TransportError::Invalid(format!(
            "noise must be in 0..={MAX_NOISE} (a fraction of the RMS radiance), got {}",
            crate::config::shown_number(noise)
        )));
    }
    let clean: Vec<[f64; 3]> = rows
        .iter()
        .map(|r| std::array::from_fn(|c| dot(r, &truth[c])))
        .collect();
    let n = (3 * clean.len()).max(1) as f64;
    let rms = (clean.iter().flatten().map(|v| v * v).sum::<f64>() / n).sqrt();
    let mut rng = NoiseRng::new(seed);
    let radiance = clean
        .iter()
        .map(|b| b.map(|v| v + noise * rms * rng.normal()))
        .collect();
    Observations::new(coeffs, rows, radiance)
}

/// A small deterministic generator for synthetic noise (xorshift64* and Box–Muller).
#[derive(Clone, Debug)]
pub struct NoiseRng(u64);

impl NoiseRng {
    pub fn new(seed: u64) -> Self {
        Self(seed.max(1))
    }

    fn next_f64(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d);
        ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    /// A standard normal sample.
    pub fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.next_f64(), self.next_f64());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Relative L2 error of recovered coefficient planes against the truth (= relative L2 error of
/// the lighting on the sphere, by Parseval).
pub fn relative_error(recovered: &[Vec<f64>; 3], truth: &[Vec<f64>; 3]) -> f64 {
    let mut num = 0.0;
    let mut den = 0.0;
    for c in 0..3 {
        for (a, b) in recovered[c].iter().zip(&truth[c]) {
            num += (a - b).powi(2);
            den += b * b;
        }
    }
    if den == 0.0 {
        num.sqrt()
    } else {
        (num / den).sqrt()
    }
}

/// Relative L2 error of the recovered lighting over the upper hemisphere only (texels with
/// direction y > 0): the directions an object standing on the ground can see. `None` when no
/// texel centre lies above the horizon (a 2×2 grid): there is nothing to measure, which is no
/// error of 0.
pub fn upper_hemisphere_error(
    grid: &Grid,
    recovered: &[Vec<f64>; 3],
    truth: &[Vec<f64>; 3],
) -> Result<Option<f64>, TransportError> {
    if !grid.dirs.iter().any(|d| d.y > 0.0) {
        return Ok(None);
    }
    let mut num = 0.0;
    let mut den = 0.0;
    for c in 0..3 {
        let r = grid.reconstruct(&recovered[c])?;
        let t = grid.reconstruct(&truth[c])?;
        for (i, d) in grid.dirs.iter().enumerate() {
            if d.y > 0.0 {
                num += (r[i] - t[i]).powi(2);
                den += t[i] * t[i];
            }
        }
    }
    Ok(Some(if den == 0.0 {
        num.sqrt()
    } else {
        (num / den).sqrt()
    }))
}

/// Relative RMS error of the radiance that `recovered` predicts for transport `rows` against
/// what `truth` gives (noise-free): how well the recovered lighting relights the object.
pub fn prediction_error(
    rows: &[Vec<f64>],
    recovered: &[Vec<f64>; 3],
    truth: &[Vec<f64>; 3],
) -> f64 {
    let mut num = 0.0;
    let mut den = 0.0;
    for r in rows {
        for c in 0..3 {
            let t = dot(r, &truth[c]);
            num += (dot(r, &recovered[c]) - t).powi(2);
            den += t * t;
        }
    }
    if den == 0.0 {
        num.sqrt()
    } else {
        (num / den).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::super::basis::Basis;
    use super::super::visibility::{vertex_visibility, Bvh};
    use super::*;
    use glam::Vec3;

    /// A sphere on a plane: Lambertian ground (it sees the shadow) and a glossy sphere seen from
    /// four sides; lighting limited to the coarse tree (the top-left 4×4 Mallat block).
    fn setup(grid: &Grid) -> (Vec<Vec<f64>>, [Vec<f64>; 3]) {
        let mesh = Mesh::sphere_on_plane(24, 12);
        let bvh = Bvh::build(&mesh).unwrap();
        let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);
        let sphere: Vec<usize> = (0..mesh.positions.len())
            .filter(|&v| mesh.positions[v].y > 0.01)
            .collect();
        let ground: Vec<usize> = (0..mesh.positions.len())
            .filter(|&v| mesh.positions[v].y <= 0.01)
            .collect();
        let mut setups = vec![ObservationSetup {
            brdf: Brdf::Lambert,
            view: View::Direction(Vec3::Y),
            vertices: ground,
        }];
        for eye in [
            Vec3::new(0.0, 1.0, 4.0),
            Vec3::new(4.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, -4.0),
            Vec3::new(-4.0, 1.0, 0.0),
        ] {
            setups.push(ObservationSetup {
                brdf: Brdf::Phong { exponent: 32.0 },
                view: View::Eye(eye),
                vertices: sphere.clone(),
            });
        }
        let rows = transport_rows(grid, &mesh, &vis, &setups).unwrap();
        let truth: [Vec<f64>; 3] = std::array::from_fn(|c| {
            let f: Vec<f64> = grid
                .dirs
                .iter()
                .map(|d| {
                    let s = f64::from(d.dot(Vec3::new(0.6, 0.6, -0.5).normalize())).max(0.0);
                    1.0 + 0.5 * f64::from(d.y) + 8.0 * s.powi(4) * (1.0 + 0.1 * c as f64)
                })
                .collect();
            let mut p = grid.project(&f).unwrap();
            for (k, v) in p.iter_mut().enumerate() {
                if k / grid.side >= 4 || k % grid.side >= 4 {
                    *v = 0.0;
                }
            }
            p
        });
        (rows, truth)
    }

    #[test]
    fn recovers_a_known_lighting() {
        let grid = Grid::new(16, Basis::Coiflet(1), None).unwrap();
        let (rows, truth) = setup(&grid);
        let opts = RefineOptions {
            split_fraction: 0.0,
            ..Default::default()
        };
        let clean = synthesize(&rows, &truth, 0.0, 1).unwrap();
        let rec = refine(&grid, &clean, opts).unwrap();
        let err = relative_error(&rec.planes, &truth);
        assert!(err < 1e-6, "noiseless error {err}, steps {:?}", rec.steps);
        let noisy = synthesize(&rows, &truth, 0.01, 7).unwrap();
        let rec = refine(&grid, &noisy, RefineOptions::default()).unwrap();
        let err = relative_error(&rec.planes, &truth);
        assert!(err < 0.02, "1 % noise: error {err}, steps {:?}", rec.steps);
        // Without the information criterion the rank test alone lets fine levels fit noise.
        let loose = RefineOptions {
            rank_tol: 1e-3,
            split_fraction: 0.0,
            bic: false,
            ..Default::default()
        };
        let overfit = relative_error(&refine(&grid, &noisy, loose).unwrap().planes, &truth);
        assert!(overfit > 10.0 * err, "{overfit} vs {err}");
        // Refinement stopped short of the full tree.
        assert!(rec.active.len() < grid.len());
    }

    #[test]
    fn tree_covers_every_node_once() {
        for levels in [1, 2, 4] {
            let side = 16;
            let mut seen = vec![0u32; side * side];
            let mut stack = roots(side, levels);
            while let Some(k) = stack.pop() {
                seen[k as usize] += 1;
                stack.extend(children(side, levels, k));
            }
            assert!(seen.iter().all(|&s| s == 1), "levels {levels}");
        }
    }

    #[test]
    fn rank_test_drops_dependent_columns() {
        let mut qr = IncrementalQr {
            scale: 0.0,
            q: Vec::new(),
            r: Vec::new(),
            qtb: Vec::new(),
        };
        let b = vec![[1.0, 2.0, 3.0]; 3];
        assert!(qr.try_add(&[1.0, 0.0, 1.0], &b, 1e-6));
        assert!(qr.try_add(&[0.0, 1.0, 0.0], &b, 1e-6));
        assert!(!qr.try_add(&[2.0, 3.0, 2.0], &b, 1e-6));
        assert!(!qr.try_add(&[0.0, 0.0, 0.0], &b, 1e-6));
        assert!(qr.try_add(&[0.0, 0.0, 1.0], &b, 1e-6));
        let x = qr.solve();
        // Exact solve of the now square system: columns e0+e2, e1, e2.
        assert!((x[0][0] - 1.0).abs() < 1e-12 && (x[1][0] - 1.0).abs() < 1e-12);
        assert!(x[2][0].abs() < 1e-12);
    }

    #[test]
    fn bad_options_are_errors() {
        let grid = Grid::new(4, Basis::Haar, None).unwrap();
        let obs = Observations::new(16, &[vec![1.0; 16]], vec![[1.0; 3]]).unwrap();
        for opts in [
            RefineOptions {
                rank_tol: 0.0,
                ..Default::default()
            },
            RefineOptions {
                split_fraction: f64::NAN,
                ..Default::default()
            },
        ] {
            assert!(refine(&grid, &obs, opts).is_err());
        }
        assert!(Observations::new(16, &[vec![1.0; 15]], vec![[1.0; 3]]).is_err());
        assert!(Observations::new(16, &[vec![1.0; 16]], vec![]).is_err());
        assert!(Observations::new(16, &[vec![f64::NAN; 16]], vec![[1.0; 3]]).is_err());
    }
}
