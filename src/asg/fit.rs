//! Fitting K ASG lobes to environment-map frames, temporally consistent (Clausen et al. 2024,
//! "Fitting anisotropic spherical Gaussians to dynamic HDRIs").
//!
//! Steps for every frame:
//! 1. **Target** ([`FitTarget::from_frame`], [`super::target`]): the frame is resampled to a
//!    `2h × h` lat-long map (default 512×256, the paper's) by averaging `s × s` sub-samples per
//!    pixel, weighted by their solid angle (an exact box filter when the source is lat-long and
//!    an integer multiple of the size). Non-finite and negative values count as 0. The
//!    ground-truth diffuse map D_GT(n) = Σ_p L_p max(n·d_p, 0) Ω_p is computed once per frame
//!    by direct convolution of a ≤ 64×128 box-downsampled copy, at
//!    [`FitSettings::diffuse_normals`] normals of a Fibonacci sphere. [`AsgFitter`] keeps its
//!    target and refills it frame after frame ([`AsgFitter::prepare`], [`FitTarget::refill`]):
//!    what depends only on the size is made once.
//! 2. **Initialisation** ([`initial_lobes`]), first frame only: greedy peak picking. Repeatedly
//!    the brightest pixel of the residual map becomes a lobe axis, its residual radiance the
//!    amplitude, and the half-maximum radius r of the bright region around it the bandwidth
//!    λ = μ = ln 2 / sin² r; the lobe is subtracted from the residual (clamped at 0).
//!    Deterministic, O(K·N), and it puts narrow lobes on suns and lamps at once.
//! 3. **Loss**, normalised by the map's mean radiance M = (1/4π)∫Σ_c L dω (so a black
//!    prediction has L_R = 1):
//!    `L = L_R + w_D·L_D + w_T·L_T`, with
//!    L_R = (1/4πM) Σ_p Ω_p Σ_c |Î_p − I_p| (L1; [`Norm::L2`] uses squares / M²),
//!    L_D = (1/(N_n π M)) Σ_n Σ_c |D̂(n) − D_GT(n)| with D̂ from the closed-form ASG irradiance
//!    ([`super::Asg::irradiance`]), and, from the second frame on, the paper's temporal term
//!    L_T = Σ_i ‖(g_i^t − g_i^{t−1}) / max_i |g_i^{t−1}|‖₂ over the lobe vector
//!    g = (z, x, ln λ, ln μ, c) (the division per component; 1 for the unit-vector components).
//!    Bandwidths are capped at [`FitTarget::max_bandwidth`] (a lobe at least one pixel wide).
//! 4. **Optimiser**: Adam on (rotation, α, β, σ) per lobe (module doc of [`super`]), analytic
//!    (sub)gradients, cosine-decayed learning rate. The rotation step of a lobe is scaled by
//!    1/√(1 + max(λ, μ)) so a sun-sized lobe moves by a fraction of its width. L_R and its
//!    gradient come from the f32 tiled kernel with per-tile lobe culling ([`super::fast`]); the
//!    exact f64 sums remain for [`loss`] and [`loss_gradient`]. The kernel's fixed tile groups
//!    run on [`FitSettings::threads`] named scoped threads, summed in group order: results do
//!    not depend on the thread count.
//!    **Stratified subsets**: an iteration may take its gradient on 1/s of the tiles (a
//!    diagonal class of the tile grid, [`super::fast::Subset`]) and 1/s of the diffuse
//!    normals, scaled by s, the class rotating every iteration, so s iterations together see
//!    every pixel once at the cost of one full evaluation (stochastic gradients, as in SGD).
//!    The loss of the first frame's start and of its returned lobes are evaluated on the whole
//!    map; a warm refit's returned lobes only when asked ([`FitSettings::warm_loss`]) or
//!    needed to pick the best iterate (whole-map iterations without L_T).
//!    **First frame**: [`FitSettings::iterations`] (8,000) on subsets of
//!    [`FitSettings::first_subset`] (1/4) of the tiles by default, costing about 2,000
//!    whole-map iterations: on the built-in sky at 256×512 this reaches a point that 6,000
//!    more whole-map iterations improve by 0.1 % (1,000 whole-map iterations, the former
//!    default, stopped 5–7 % above; docs/asg.md). Optionally
//!    ([`optimise_pyramid`], [`FitSettings::coarse_height`]) coarse-to-fine: the target is halved
//!    ([`FitTarget::half`], solid-angle-weighted 2×2 averages, same diffuse ground truth) down
//!    to [`FitSettings::coarse_height`] rows; [`FitSettings::iterations`] are split so the
//!    finest level gets [`FitSettings::fine_share`] of them and the coarser levels the rest in
//!    equal parts, coarsest first, with one Adam state and one cosine schedule throughout.
//!    Each level caps the bandwidths at its own [`FitTarget::max_bandwidth`]. A coarse
//!    iteration costs a quarter of the next finer one, so 1,000 iterations cost about as much
//!    as 150 at full size. The best loss seen on the finest level (or the start, if lower) is
//!    returned. It converges better on the smooth sky but worse on maps with small lamps
//!    (docs/asg.md), hence off by default.
//! 5. **Warm start**: each later frame starts from the previous lobes, narrow ones (min(λ, μ)
//!    ≥ 100) first turned onto the centroid of their share of the new frame around them
//!    ([`centroid_step`], a mean-shift step; [`FitSettings::warm_centroid`]: Adam's small warm
//!    steps move a sun-sized lobe by about 1 % of its width per iteration, too slow for a
//!    turning map; L_T below is then measured from the lobes so moved — anchored at the
//!    unmoved previous lobes, its proximal step pulled a turning map's sun lobe back and
//!    doubled the gap to a long fit, docs/asg.md), and runs [`FitSettings::warm_iterations`] at
//!    [`FitSettings::warm_learning_rate`] at full size on subsets of
//!    [`FitSettings::warm_subset`] of the tiles and normals, continuing the previous frame's
//!    Adam state ([`AdamState`], kept by [`AsgFitter`]): a fresh Adam's first bias-corrected steps move every parameter by the full rate, which
//!    from a near-optimal start made the loss worse. L_T is not differentiated but applied as
//!    a proximal step after each gradient step on L_R + w_D·L_D (proximal gradient): the prox
//!    of τ‖u‖₂ is group soft-thresholding, u ← u·max(0, 1 − τ/‖u‖), i.e. each lobe moves back
//!    towards its previous parameters by that factor on all its temporal components, and
//!    stays where it was if ‖u‖ ≤ τ. The step size is Adam's nominal one, τ = w_T·rate (the
//!    preconditioned metric taken as the identity in the scaled units of u). The last iterate
//!    is returned (the lowest total loss is, with L_T's kink at "no change", the previous
//!    lobes themselves, which is what the subgradient version returned).
//!    When the map's mean radiance differs from the previous lobes' (their integral over 4π)
//!    by more than [`WARM_RESCALE`] (2×) either way (an exposure change, in one jump or in
//!    steps), the previous amplitudes are first scaled by that ratio: the warm steps move a
//!    log-amplitude by little, and a 2^30 jump (or a ramp of 3× steps, each compared with the
//!    previous map only) left the lobes at the old scale (loss 2).
//!    After a frame that left no lobe with power (a black one) the next frame is fitted from
//!    scratch: zero lobes sat at the amplitude bound and every later frame came out black.

pub use super::target::{fibonacci_sphere, resample_latlong, resample_latlong_into, FitTarget};
use super::{integral_with_derivatives, rotate, Asg, AsgError, MAX_BANDWIDTH, MIN_BANDWIDTH};
use crate::frame::HdrFrame;
use glam::DVec3;
use std::f64::consts::PI;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// Largest number of lobes.
pub const MAX_LOBES: usize = 64;
/// Default number of lobes (the paper reports about 15 enough).
pub const DEFAULT_LOBES: usize = 16;
/// Default fit-map height (width is twice): 256×512 as the paper.
pub const DEFAULT_HEIGHT: u32 = 256;
/// Row bands the pixel sums are split into (fixed, so results do not depend on threads).
const BANDS: usize = 32;
/// Log-amplitude bounds: c ∈ [e^−120, e^80] ≈ [8e−53, 6e34], past every radiance a frame holds
/// (f32's smallest positive value, 1.4e−45, up to [`crate::frame::MAX_RADIANCE`], 1e30), so the
/// fit does not depend on the map's scale: the loss is normalised by the map's mean, and the
/// bounds were the one absolute quantity (at [e^−60, e^25] a uniform map of 1e15 was fitted
/// with loss 2, worse than black, and one of 1e−30 with loss 2,588).
const SIGMA_RANGE: (f64, f64) = (-120.0, 80.0);

/// Reconstruction norm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Norm {
    /// |Î − I| (the paper's choice).
    #[default]
    L1,
    /// (Î − I)².
    L2,
}

/// Settings of [`AsgFitter`].
#[derive(Clone, Debug, PartialEq)]
pub struct FitSettings {
    /// Number of lobes K, 1..=64.
    pub lobes: usize,
    /// Fit-map height h (width 2h), 4..=1024.
    pub height: u32,
    /// Adam iterations of the first frame (each on 1/[`FitSettings::first_subset`] of the
    /// map).
    pub iterations: usize,
    /// Adam iterations of every warm-started frame (each on 1/[`FitSettings::warm_subset`]
    /// of the map).
    pub warm_iterations: usize,
    /// Initial learning rate of the first frame (log-bandwidth and log-amplitude steps; radians
    /// for a wide lobe's rotation).
    pub learning_rate: f64,
    /// Learning rate of warm-started frames.
    pub warm_learning_rate: f64,
    /// Weight w_D of the diffuse loss (0 disables it).
    pub diffuse_weight: f64,
    /// Weight w_T of the temporal loss (0 disables it).
    pub temporal_weight: f64,
    /// Reconstruction (and diffuse) norm.
    pub norm: Norm,
    /// Normals at which the diffuse maps are compared, 16..=4096.
    pub diffuse_normals: usize,
    /// Worker threads, 0 = all available cores.
    pub threads: usize,
    /// Tie μ to λ: isotropic lobes (a comparison baseline; 6 parameters per lobe instead of 8).
    pub isotropic: bool,
    /// First frame: the coarsest pyramid level's height (the fit starts there and halves the
    /// pixel size level by level up to [`FitSettings::height`]); > `height / 2` (the default,
    /// 1024) fits at full resolution only: on real HDRIs with small bright lamps the pyramid
    /// converged worse (docs/asg.md).
    pub coarse_height: u32,
    /// First frame: share of [`FitSettings::iterations`] run on the finest level, 0..=1.
    pub fine_share: f64,
    /// Warm-started frames: each iteration's gradient is taken on 1/`warm_subset` of the
    /// fit map's tiles and of the diffuse normals (stratified subsets, rotated every
    /// iteration; 1 = all); the reported loss ([`FitSettings::warm_loss`]) is the whole
    /// map's. 1..=16.
    pub warm_subset: usize,
    /// The same for the first frame (its gradients on rotating subsets of 1/`first_subset` of
    /// the tiles and normals; the start's and the returned loss are the whole map's). 1..=16.
    pub first_subset: usize,
    /// Warm-started frames: before the Adam iterations, move each narrow lobe's axis to the
    /// centroid of its share of the map around it ([`centroid_step`]), so suns and lamps that
    /// move faster than Adam's small warm steps are followed; L_T is then measured from the
    /// moved lobes.
    pub warm_centroid: bool,
    /// Warm-started frames: evaluate the whole-map loss of the returned lobes and report it in
    /// [`FitResult::loss`]. Off by default: that evaluation costs about a fifth of a default
    /// refit (it is one whole-map pass; the iterations each see 1/[`FitSettings::warm_subset`]
    /// of the map) and, with L_T on or with subsets, the returned lobes are the last iterate
    /// whatever it says. A warm refit that needs the loss to choose its result (whole-map
    /// iterations without L_T, where the best iterate is returned) evaluates it anyway. The
    /// first frame always does (the start competes with the last iterate).
    pub warm_loss: bool,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            lobes: DEFAULT_LOBES,
            height: DEFAULT_HEIGHT,
            iterations: 8000,
            warm_iterations: 8,
            learning_rate: 0.05,
            warm_learning_rate: 0.01,
            diffuse_weight: 1.0,
            temporal_weight: 0.05,
            norm: Norm::L1,
            diffuse_normals: 256,
            threads: 0,
            isotropic: false,
            coarse_height: 1024,
            fine_share: 0.1,
            warm_subset: 4,
            first_subset: 4,
            warm_centroid: true,
            warm_loss: false,
        }
    }
}

impl FitSettings {
    /// Checks every field.
    pub fn validate(&self) -> Result<(), AsgError> {
        if !(1..=MAX_LOBES).contains(&self.lobes) {
            return Err(AsgError::LobeCount(self.lobes));
        }
        if !(4..=1024).contains(&self.height) {
            return Err(AsgError::MapSize {
                width: self.height.saturating_mul(2),
                height: self.height,
            });
        }
        let bad = |name, value: f64, message| AsgError::Setting {
            name,
            value: value.to_string(),
            message,
        };
        for (name, v) in [
            ("learning_rate", self.learning_rate),
            ("warm_learning_rate", self.warm_learning_rate),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 1.0) {
                return Err(bad(name, v, "must be in (0, 1]"));
            }
        }
        for (name, v) in [
            ("diffuse_weight", self.diffuse_weight),
            ("temporal_weight", self.temporal_weight),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(name, v, "must be finite and >= 0"));
            }
        }
        if !(self.fine_share.is_finite() && (0.0..=1.0).contains(&self.fine_share)) {
            return Err(bad("fine_share", self.fine_share, "must be in [0, 1]"));
        }
        for (name, v) in [
            ("warm_subset", self.warm_subset),
            ("first_subset", self.first_subset),
        ] {
            if !(1..=16).contains(&v) {
                return Err(bad(name, v as f64, "must be in 1..=16"));
            }
        }
        if !(16..=4096).contains(&self.diffuse_normals) {
            return Err(bad(
                "diffuse_normals",
                self.diffuse_normals as f64,
                "must be in 16..=4096",
            ));
        }
        for (name, v) in [
            ("iterations", self.iterations),
            ("warm_iterations", self.warm_iterations),
        ] {
            if v > 10_000_000 {
                return Err(bad(name, v as f64, "must be at most 10^7"));
            }
        }
        Ok(())
    }

    fn thread_count(&self) -> usize {
        if self.threads > 0 {
            self.threads.min(BANDS)
        } else {
            crate::parallel::cores().min(BANDS)
        }
    }
}

/// Greedy peak-picking initialisation of `k` lobes (module doc, step 2).
pub fn initial_lobes(target: &FitTarget, k: usize) -> Vec<Asg> {
    let lum = |p: &[f64; 3]| crate::decompose::luminance_f64(*p);
    let mut residual = target.radiance.clone();
    // Relative to the mean: an absolute floor (1e-36) made every seed of a map of 1e-45
    // radiance that floor, 29,000 times the map (an audit).
    let floor = target.mean * 1e-6;
    let max_init = target.max_bandwidth();
    let spare = fibonacci_sphere(k);
    let mut lobes = Vec::with_capacity(k);
    for i in 0..k {
        let (best, peak) = residual
            .iter()
            .enumerate()
            .map(|(j, p)| (j, lum(p)))
            .fold((0, -1.0), |acc, x| if x.1 > acc.1 { x } else { acc });
        let lobe = if peak > floor {
            let z = target.directions[best];
            let half = 0.5 * peak;
            let mut cos_r: f64 = -1.0;
            for (d, p) in target.directions.iter().zip(&residual) {
                if lum(p) < half {
                    cos_r = cos_r.max(d.dot(z));
                }
            }
            let sin2 = (1.0 - cos_r * cos_r).max(1e-12);
            let sin2 = if cos_r < 0.0 { 1.0 } else { sin2 };
            let lambda = (std::f64::consts::LN_2 / sin2).clamp(MIN_BANDWIDTH * 2.0, max_init);
            let rgb = residual[best].map(|c| c.max(floor));
            Asg::new(z, DVec3::Y, lambda, lambda, rgb)
        } else {
            Asg::new(spare[i], DVec3::Y, 1.0, 1.0, [floor; 3])
        };
        let Some(lobe) = lobe else { continue };
        for (d, p) in target.directions.iter().zip(residual.iter_mut()) {
            let g = lobe.shape(*d);
            if g > 0.0 {
                for c in 0..3 {
                    p[c] = (p[c] - lobe.rgb[c] * g).max(0.0);
                }
            }
        }
        lobes.push(lobe);
    }
    lobes
}

/// Parts of the fit loss (module doc, step 3).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Loss {
    pub reconstruction: f64,
    pub diffuse: f64,
    pub temporal: f64,
    /// L_R + w_D·L_D + w_T·L_T.
    pub total: f64,
}

/// Result of fitting one frame.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FitResult {
    pub lobes: Vec<Asg>,
    /// Loss of the initial (greedy or warm-start) lobes (with [`FitSettings::warm_subset`] > 1,
    /// a warm refit's is the estimate from the first iteration's subset of tiles).
    pub initial_loss: Loss,
    /// Whole-map loss of the returned lobes; `None` where it was not evaluated: on a warm
    /// refit that did not need it to choose its lobes, unless [`FitSettings::warm_loss`] asks
    /// for it (or compute it afterwards with [`loss`], exact f64 sums), and from
    /// [`optimise_stages`] given no stage (no target to judge on). Otherwise `Some`: on a
    /// first frame and on a refit without iterations.
    pub loss: Option<Loss>,
    pub iterations: usize,
    /// Whether this frame was warm-started from the previous one.
    pub warm: bool,
}

/// Optimisation state of one lobe.
#[derive(Clone, Copy, Debug)]
struct Lobe {
    x: DVec3,
    y: DVec3,
    z: DVec3,
    alpha: f64,
    beta: f64,
    sigma: [f64; 3],
}

impl Lobe {
    fn from_asg(a: &Asg) -> Self {
        let (x, y, z) = a.frame();
        let inv =
            |b: f64| (b.clamp(MIN_BANDWIDTH * (1.0 + 1e-9), MAX_BANDWIDTH) - MIN_BANDWIDTH).ln();
        Self {
            x,
            y,
            z,
            alpha: inv(a.lambda),
            beta: inv(a.mu),
            sigma: a
                .rgb
                .map(|c| c.max(1e-300).ln().clamp(SIGMA_RANGE.0, SIGMA_RANGE.1)),
        }
    }
    fn lambda(&self) -> f64 {
        MIN_BANDWIDTH + self.alpha.exp()
    }
    fn mu(&self) -> f64 {
        MIN_BANDWIDTH + self.beta.exp()
    }
    fn rgb(&self) -> [f64; 3] {
        self.sigma.map(f64::exp)
    }
    fn to_asg(self) -> Asg {
        Asg {
            axis: self.z.to_array(),
            tangent: self.x.to_array(),
            bitangent: self.y.to_array(),
            lambda: self.lambda(),
            mu: self.mu(),
            rgb: self.rgb(),
        }
    }
    /// Temporal vector g = (z, x, ln λ, ln μ, c).
    fn temporal_vector(&self) -> [f64; 11] {
        let c = self.rgb();
        [
            self.z.x,
            self.z.y,
            self.z.z,
            self.x.x,
            self.x.y,
            self.x.z,
            self.lambda().ln(),
            self.mu().ln(),
            c[0],
            c[1],
            c[2],
        ]
    }
}

/// Gradient of the loss with respect to one lobe's free quantities.
#[derive(Clone, Copy, Debug, Default)]
struct Grad {
    x: DVec3,
    y: DVec3,
    z: DVec3,
    lambda: f64,
    mu: f64,
    c: [f64; 3],
}

impl Grad {
    fn add(&mut self, o: &Grad) {
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

/// Adam moments of one lobe's 8 parameters (rotation 3, α, β, σ 3).
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    m: [f64; 8],
    v: [f64; 8],
}

/// Adam's state (moments and step count), carried from frame to frame by [`AsgFitter`] so a
/// warm refit continues the previous frame's optimisation instead of restarting Adam (whose
/// first, bias-corrected steps move every parameter by the full learning rate).
#[derive(Clone, Debug, Default)]
pub struct AdamState {
    moments: Vec<Moments>,
    steps: usize,
    /// Once set, the iterations stop early ([`AsgFitter::watch_cancel`]: a daemon shutting
    /// down); the result is then not a fit.
    cancel: Option<Arc<AtomicBool>>,
}

impl AdamState {
    fn cancelled(&self) -> bool {
        self.cancel
            .as_ref()
            .is_some_and(|c| c.load(std::sync::atomic::Ordering::Acquire))
    }
}

/// Evaluation context: derived per-lobe quantities.
struct Derived {
    x: DVec3,
    y: DVec3,
    z: DVec3,
    l: f64,
    m: f64,
    c: [f64; 3],
}

fn derive(lobes: &[Lobe]) -> Vec<Derived> {
    lobes
        .iter()
        .map(|p| Derived {
            x: p.x,
            y: p.y,
            z: p.z,
            l: p.lambda(),
            m: p.mu(),
            c: p.rgb(),
        })
        .collect()
}

/// Reconstruction loss over rows `rows` and, if `grads`, its gradient.
fn reconstruction_band(
    target: &FitTarget,
    lobes: &[Derived],
    norm: Norm,
    rows: std::ops::Range<u32>,
    grads: Option<&mut [Grad]>,
) -> f64 {
    let w = target.width as usize;
    let k = lobes.len();
    let inv_m = 1.0 / target.mean;
    let mut loss = 0.0;
    let mut shape = [0.0f64; MAX_LOBES];
    let mut ab = [(0.0f64, 0.0f64, 0.0f64); MAX_LOBES];
    let mut grads = grads;
    for i in rows.start as usize * w..rows.end as usize * w {
        let d = target.directions[i];
        let mut pred = [0.0; 3];
        for (j, l) in lobes.iter().enumerate() {
            let s = d.dot(l.z);
            shape[j] = 0.0;
            if s <= 0.0 {
                continue;
            }
            let (a, b) = (d.dot(l.x), d.dot(l.y));
            let ex = -l.l * a * a - l.m * b * b;
            if ex < -60.0 {
                continue;
            }
            let e = ex.exp();
            let g = s * e;
            shape[j] = g;
            ab[j] = (a, b, e);
            for c in 0..3 {
                pred[c] += l.c[c] * g;
            }
        }
        let gt = target.radiance[i];
        let wt = target.weights[i] * inv_m;
        let mut r = [0.0; 3];
        for c in 0..3 {
            let diff = pred[c] - gt[c];
            match norm {
                Norm::L1 => {
                    loss += wt * diff.abs();
                    r[c] = if diff > 0.0 {
                        wt
                    } else if diff < 0.0 {
                        -wt
                    } else {
                        0.0
                    };
                }
                Norm::L2 => {
                    loss += wt * inv_m * diff * diff;
                    r[c] = 2.0 * wt * inv_m * diff;
                }
            }
        }
        let Some(grads) = grads.as_deref_mut() else {
            continue;
        };
        for j in 0..k {
            let g = shape[j];
            if g == 0.0 {
                continue;
            }
            let l = &lobes[j];
            let gr = &mut grads[j];
            let rr = r[0] * l.c[0] + r[1] * l.c[1] + r[2] * l.c[2];
            for c in 0..3 {
                gr.c[c] += r[c] * g;
            }
            let (a, b, e) = ab[j];
            gr.x += d * (rr * -2.0 * l.l * a * g);
            gr.y += d * (rr * -2.0 * l.m * b * g);
            gr.z += d * (rr * e);
            gr.lambda -= rr * a * a * g;
            gr.mu -= rr * b * b * g;
        }
    }
    loss
}

/// Diffuse loss and (if `grads`) its gradient; over the normals `phase` modulo `stride` only
/// (the Fibonacci normals run from pole to pole, so that is a stratified subset), scaled by
/// the stride.
fn diffuse_loss(
    target: &FitTarget,
    lobes: &[Derived],
    norm: Norm,
    grads: Option<&mut [Grad]>,
    subset: super::fast::Subset,
) -> f64 {
    let nn = target.normals.len() as f64;
    let stride = subset.stride.clamp(1, target.normals.len().max(1));
    let phase = subset.phase % stride;
    let inv = stride as f64 / (nn * PI * target.mean);
    let per: Vec<(f64, f64, f64, f64)> = lobes
        .iter()
        .map(|l| {
            let (i, di_l, di_m) = integral_with_derivatives(l.l, l.m);
            (i, di_l, di_m, 2.0 * (l.l * l.m).sqrt())
        })
        .collect();
    let mut loss = 0.0;
    let mut grads = grads;
    let mut h = vec![(0.0, 0.0, 0.0); lobes.len()];
    for (n, gt) in target
        .normals
        .iter()
        .zip(&target.diffuse)
        .skip(phase)
        .step_by(stride)
    {
        let mut pred = [0.0; 3];
        for (j, l) in lobes.iter().enumerate() {
            h[j] = super::cosine_convolution(n.dot(l.z), per[j].3);
            let s = per[j].0 * h[j].0;
            for c in 0..3 {
                pred[c] += l.c[c] * s;
            }
        }
        let mut r = [0.0; 3];
        for c in 0..3 {
            let diff = pred[c] - gt[c];
            match norm {
                Norm::L1 => {
                    loss += inv * diff.abs();
                    r[c] = inv * diff.signum() * f64::from(u8::from(diff != 0.0));
                }
                Norm::L2 => {
                    let k2 = inv / (PI * target.mean);
                    loss += k2 * diff * diff;
                    r[c] = 2.0 * k2 * diff;
                }
            }
        }
        let Some(grads) = grads.as_deref_mut() else {
            continue;
        };
        for (j, l) in lobes.iter().enumerate() {
            let (i, di_l, di_m, nu) = per[j];
            let (hv, dh_t, dh_nu) = h[j];
            let rr = r[0] * l.c[0] + r[1] * l.c[1] + r[2] * l.c[2];
            let gr = &mut grads[j];
            for c in 0..3 {
                gr.c[c] += r[c] * i * hv;
            }
            gr.z += *n * (rr * i * dh_t);
            let d_nu = rr * i * dh_nu;
            gr.lambda += rr * di_l * hv + d_nu * nu / (2.0 * l.l);
            gr.mu += rr * di_m * hv + d_nu * nu / (2.0 * l.m);
        }
    }
    loss
}

/// Per-component scales max_i |g_i^{t−1}| of the temporal vector (1 for unit-vector parts).
fn temporal_scales(prev: &[Lobe]) -> [f64; 11] {
    let mut s = [1.0; 11];
    for i in 6..11 {
        s[i] = prev
            .iter()
            .map(|p| p.temporal_vector()[i].abs())
            .fold(0.0, f64::max)
            .max(if i < 8 { 1.0 } else { 1e-30 });
    }
    s
}

/// Temporal loss Σ_i ‖(g_i − g_i^prev)/scale‖₂ and (if `grads`) its gradient.
fn temporal_loss(
    lobes: &[Lobe],
    prev: &[Lobe],
    scales: &[f64; 11],
    grads: Option<&mut [Grad]>,
) -> f64 {
    let mut loss = 0.0;
    let mut grads = grads;
    for (j, (p, q)) in lobes.iter().zip(prev).enumerate() {
        let (g, h) = (p.temporal_vector(), q.temporal_vector());
        let u: Vec<f64> = (0..11).map(|i| (g[i] - h[i]) / scales[i]).collect();
        let norm = u.iter().map(|x| x * x).sum::<f64>().sqrt();
        loss += norm;
        let Some(grads) = grads.as_deref_mut() else {
            continue;
        };
        if norm <= 1e-300 {
            continue;
        }
        let du: Vec<f64> = (0..11).map(|i| u[i] / norm / scales[i]).collect();
        let gr = &mut grads[j];
        gr.z += DVec3::new(du[0], du[1], du[2]);
        gr.x += DVec3::new(du[3], du[4], du[5]);
        gr.lambda += du[6] / p.lambda();
        gr.mu += du[7] / p.mu();
        for c in 0..3 {
            gr.c[c] += du[8 + c];
        }
    }
    loss
}

/// How [`loss_and_grad`] evaluates.
#[derive(Clone, Copy, Debug)]
struct Mode {
    threads: usize,
    want_grad: bool,
    /// The f32 tiled kernel ([`super::fast`]) instead of the exact f64 sums.
    fast: bool,
    /// Whether the gradient includes L_T's (the optimiser uses a proximal step instead).
    temporal_grad: bool,
    /// Tiles visited by the fast kernel and diffuse normals visited (every stride-th).
    subset: super::fast::Subset,
}

/// The whole loss of `lobes` (and its gradient with respect to the free quantities).
fn loss_and_grad(
    target: &FitTarget,
    lobes: &[Lobe],
    prev: Option<(&[Lobe], &[f64; 11])>,
    settings: &FitSettings,
    mode: Mode,
) -> (Loss, Vec<Grad>) {
    let derived = derive(lobes);
    let k = lobes.len();
    let want_grad = mode.want_grad;
    let (rec, mut grads) = if mode.fast {
        let inv_m = 1.0 / target.mean;
        let kl: Vec<super::fast::KLobe> = derived
            .iter()
            .map(|d| super::fast::KLobe {
                x: d.x,
                y: d.y,
                z: d.z,
                lambda: d.l,
                mu: d.m,
                c: d.c.map(|c| c * inv_m),
            })
            .collect();
        let (rec, sums) = super::fast::reconstruction(
            target.tiled(),
            &kl,
            settings.norm,
            mode.threads,
            want_grad,
            mode.subset,
        );
        let grads = sums
            .iter()
            .map(|s| Grad {
                x: s.x,
                y: s.y,
                z: s.z,
                lambda: s.lambda,
                mu: s.mu,
                c: s.c.map(|c| c * inv_m),
            })
            .collect();
        (rec, grads)
    } else {
        exact_reconstruction(target, &derived, settings.norm, mode.threads, want_grad)
    };
    let mut dgrads = vec![Grad::default(); if want_grad { k } else { 0 }];
    let dif = if settings.diffuse_weight > 0.0 {
        diffuse_loss(
            target,
            &derived,
            settings.norm,
            want_grad.then_some(dgrads.as_mut_slice()),
            mode.subset,
        )
    } else {
        0.0
    };
    let mut tgrads = vec![Grad::default(); if want_grad { k } else { 0 }];
    let tmp = match prev {
        Some((p, s)) if settings.temporal_weight > 0.0 => temporal_loss(
            lobes,
            p,
            s,
            (want_grad && mode.temporal_grad).then_some(tgrads.as_mut_slice()),
        ),
        _ => 0.0,
    };
    for j in 0..grads.len() {
        let (d, t) = (dgrads[j], tgrads[j]);
        let wd = settings.diffuse_weight;
        let wt = settings.temporal_weight;
        let g = &mut grads[j];
        g.x += d.x * wd + t.x * wt;
        g.y += d.y * wd + t.y * wt;
        g.z += d.z * wd + t.z * wt;
        g.lambda += d.lambda * wd + t.lambda * wt;
        g.mu += d.mu * wd + t.mu * wt;
        for c in 0..3 {
            g.c[c] += d.c[c] * wd + t.c[c] * wt;
        }
    }
    let loss = Loss {
        reconstruction: rec,
        diffuse: dif,
        temporal: tmp,
        total: rec + settings.diffuse_weight * dif + settings.temporal_weight * tmp,
    };
    (loss, grads)
}

/// L_R by the exact f64 sums over fixed row bands (and its gradient if `want_grad`).
fn exact_reconstruction(
    target: &FitTarget,
    derived: &[Derived],
    norm: Norm,
    threads: usize,
    want_grad: bool,
) -> (f64, Vec<Grad>) {
    let k = derived.len();
    let h = target.height;
    let bands: Vec<std::ops::Range<u32>> = (0..BANDS as u32)
        .map(|b| (b * h / BANDS as u32)..((b + 1) * h / BANDS as u32))
        .filter(|r| !r.is_empty())
        .collect();
    let mut results: Vec<Option<(f64, Vec<Grad>)>> = vec![None; bands.len()];
    let run = |band: &std::ops::Range<u32>| -> (f64, Vec<Grad>) {
        let mut g = if want_grad {
            vec![Grad::default(); k]
        } else {
            Vec::new()
        };
        let loss = reconstruction_band(
            target,
            derived,
            norm,
            band.clone(),
            want_grad.then_some(g.as_mut_slice()),
        );
        (loss, g)
    };
    if threads > 1 {
        let per = bands.len().div_ceil(threads);
        std::thread::scope(|scope| {
            for (ti, (outs, bs)) in results.chunks_mut(per).zip(bands.chunks(per)).enumerate() {
                let run = &run;
                let spawned = std::thread::Builder::new()
                    .name(format!("asg-fit-{ti}"))
                    .spawn_scoped(scope, move || {
                        for (out, band) in outs.iter_mut().zip(bs) {
                            *out = Some(run(band));
                        }
                    });
                if let Err(e) = spawned {
                    // Computed below on this thread.
                    tracing::warn!("cannot start an ASG fitting thread: {e}");
                }
            }
        });
    }
    for (out, band) in results.iter_mut().zip(&bands) {
        if out.is_none() {
            *out = Some(run(band));
        }
    }
    let mut grads = vec![Grad::default(); if want_grad { k } else { 0 }];
    let mut rec = 0.0;
    for (l, g) in results.iter().flatten() {
        rec += l;
        for (a, b) in grads.iter_mut().zip(g) {
            a.add(b);
        }
    }
    (rec, grads)
}

/// Gradient with respect to the optimisation parameters (rotation 3, α, β, σ 3).
fn param_grad(p: &Lobe, g: &Grad) -> [f64; 8] {
    let rot = p.x.cross(g.x) + p.y.cross(g.y) + p.z.cross(g.z);
    let c = p.rgb();
    [
        rot.x,
        rot.y,
        rot.z,
        g.lambda * p.alpha.exp(),
        g.mu * p.beta.exp(),
        g.c[0] * c[0],
        g.c[1] * c[1],
        g.c[2] * c[2],
    ]
}

/// Public analytic gradient of the loss with respect to each lobe's parameters
/// (rotation vector 3, α = ln(λ − λ_min), β = ln(μ − λ_min), σ = ln c per channel), for tests
/// and tools. `prev` enables the temporal term.
pub fn loss_gradient(
    target: &FitTarget,
    lobes: &[Asg],
    prev: Option<&[Asg]>,
    settings: &FitSettings,
) -> (Loss, Vec<[f64; 8]>) {
    parameter_gradient(target, lobes, prev, settings, false)
}

/// As [`loss_gradient`] without a previous frame, but computed by the fast f32 kernel the
/// optimiser uses ([`super::fast`]); for tests and tools.
pub fn fast_loss_gradient(
    target: &FitTarget,
    lobes: &[Asg],
    settings: &FitSettings,
) -> (Loss, Vec<[f64; 8]>) {
    parameter_gradient(target, lobes, None, settings, true)
}

/// Loss and gradient with respect to each lobe's 8 parameters, by the exact f64 path or the
/// fast f32 kernel.
fn parameter_gradient(
    target: &FitTarget,
    lobes: &[Asg],
    prev: Option<&[Asg]>,
    settings: &FitSettings,
    fast: bool,
) -> (Loss, Vec<[f64; 8]>) {
    let ls: Vec<Lobe> = lobes.iter().map(Lobe::from_asg).collect();
    let pv: Option<Vec<Lobe>> = prev.map(|p| p.iter().map(Lobe::from_asg).collect());
    let scales = pv.as_deref().map(temporal_scales);
    let prev = pv.as_deref().zip(scales.as_ref());
    let mode = Mode {
        threads: 1,
        want_grad: true,
        fast,
        temporal_grad: true,
        subset: super::fast::Subset::ALL,
    };
    let (loss, g) = loss_and_grad(target, &ls, prev, settings, mode);
    (
        loss,
        ls.iter().zip(&g).map(|(p, g)| param_grad(p, g)).collect(),
    )
}

/// Loss of `lobes` on `target` (temporal term against `prev` if given).
pub fn loss(
    target: &FitTarget,
    lobes: &[Asg],
    prev: Option<&[Asg]>,
    settings: &FitSettings,
) -> Loss {
    let ls: Vec<Lobe> = lobes.iter().map(Lobe::from_asg).collect();
    let pv: Option<Vec<Lobe>> = prev.map(|p| p.iter().map(Lobe::from_asg).collect());
    let scales = pv.as_deref().map(temporal_scales);
    let prev = pv.as_deref().zip(scales.as_ref());
    let mode = Mode {
        threads: 1,
        want_grad: false,
        fast: false,
        temporal_grad: false,
        subset: super::fast::Subset::ALL,
    };
    loss_and_grad(target, &ls, prev, settings, mode).0
}

/// Applies parameter vector `delta` (rotation 3, α, β, σ 3) to `lobe` (as the optimiser does).
pub fn perturb(lobe: &Asg, delta: [f64; 8]) -> Asg {
    let mut p = Lobe::from_asg(lobe);
    step(&mut p, &delta);
    p.to_asg()
}

fn step(p: &mut Lobe, d: &[f64; 8]) {
    let w = DVec3::new(d[0], d[1], d[2]);
    let z = rotate(p.z, w).normalize();
    let x = rotate(p.x, w);
    let x = (x - z * x.dot(z)).normalize();
    p.z = z;
    p.x = x;
    p.y = z.cross(x);
    let amax = (MAX_BANDWIDTH - MIN_BANDWIDTH).ln();
    p.alpha = (p.alpha + d[3]).min(amax);
    p.beta = (p.beta + d[4]).min(amax);
    for c in 0..3 {
        p.sigma[c] = (p.sigma[c] + d[5 + c]).clamp(SIGMA_RANGE.0, SIGMA_RANGE.1);
    }
}

/// Runs `iterations` Adam steps from `init` on `target`, all at the target's resolution; with
/// `prev`, L_T (if its weight is > 0) is applied as a proximal step after each gradient step
/// (module doc, step 5).
pub fn optimise(
    target: &FitTarget,
    init: &[Asg],
    prev: Option<&[Asg]>,
    iterations: usize,
    learning_rate: f64,
    settings: &FitSettings,
) -> FitResult {
    let mut state = AdamState::default();
    run_stages(
        &[(target, iterations)],
        init,
        prev,
        learning_rate,
        settings,
        &mut state,
    )
}

/// As [`optimise`], continuing from (and updating) Adam's `state` of the previous call.
pub fn optimise_continued(
    target: &FitTarget,
    init: &[Asg],
    prev: Option<&[Asg]>,
    iterations: usize,
    learning_rate: f64,
    settings: &FitSettings,
    state: &mut AdamState,
) -> FitResult {
    run_stages(
        &[(target, iterations)],
        init,
        prev,
        learning_rate,
        settings,
        state,
    )
}

/// The first-frame schedule (module doc, step 4): `iterations` split over the pyramid
/// `target`, `target.half()`, … down to [`FitSettings::coarse_height`] rows.
pub fn optimise_pyramid(
    target: &FitTarget,
    init: &[Asg],
    iterations: usize,
    learning_rate: f64,
    settings: &FitSettings,
) -> FitResult {
    let levels = pyramid(target, settings);
    optimise_stages(
        &levels.stages(iterations, settings.fine_share),
        init,
        learning_rate,
        settings,
        &mut AdamState::default(),
    )
}

/// The levels of the first-frame pyramid: `target.half()`s down to `coarse_height` rows.
struct Pyramid<'a> {
    finest: &'a FitTarget,
    /// Coarsest first.
    coarser: Vec<FitTarget>,
}

fn pyramid<'a>(target: &'a FitTarget, settings: &FitSettings) -> Pyramid<'a> {
    let mut coarser: Vec<FitTarget> = Vec::new();
    loop {
        let t = coarser.last().unwrap_or(target);
        if t.height / 2 < settings.coarse_height.max(4) {
            break;
        }
        match t.half() {
            Some(h) => coarser.push(h),
            None => break,
        }
    }
    coarser.reverse();
    Pyramid {
        finest: target,
        coarser,
    }
}

impl Pyramid<'_> {
    /// `iterations` split: `fine_share` on the finest level, the rest evenly over the others.
    fn stages(&self, iterations: usize, fine_share: f64) -> Vec<(&FitTarget, usize)> {
        let n = self.coarser.len();
        if n == 0 {
            return vec![(self.finest, iterations)];
        }
        let fine = (((iterations as f64) * fine_share).round() as usize).min(iterations);
        let rest = iterations - fine;
        let mut stages: Vec<(&FitTarget, usize)> = self
            .coarser
            .iter()
            .enumerate()
            .map(|(i, t)| (t, rest / n + usize::from(i < rest % n)))
            .collect();
        stages.push((self.finest, fine));
        stages
    }
}

/// Runs `stages` (target, iterations) in order from `init` without a previous frame, leaving
/// Adam's state in `state`; the last target is the one the result is judged on.
pub fn optimise_stages(
    stages: &[(&FitTarget, usize)],
    init: &[Asg],
    learning_rate: f64,
    settings: &FitSettings,
    state: &mut AdamState,
) -> FitResult {
    run_stages(stages, init, None, learning_rate, settings, state)
}

/// Adam over `stages` (target, iterations), the last stage's target being the one the result
/// is judged on.
fn run_stages(
    stages: &[(&FitTarget, usize)],
    init: &[Asg],
    prev: Option<&[Asg]>,
    learning_rate: f64,
    settings: &FitSettings,
    state: &mut AdamState,
) -> FitResult {
    let Some(&(target, _)) = stages.last() else {
        return FitResult {
            lobes: init.to_vec(),
            initial_loss: Loss::default(),
            loss: None,
            iterations: 0,
            warm: prev.is_some(),
        };
    };
    let iterations: usize = stages.iter().map(|s| s.1).sum();
    let mut lobes: Vec<Lobe> = init.iter().map(Lobe::from_asg).collect();
    if settings.isotropic {
        for l in &mut lobes {
            l.beta = l.alpha;
        }
    }
    let pv: Option<Vec<Lobe>> = prev.map(|p| p.iter().map(Lobe::from_asg).collect());
    let scales = pv.as_deref().map(temporal_scales);
    let prevs = pv.as_deref().zip(scales.as_ref());
    let threads = settings.thread_count();
    if !(target.mean > 0.0 && target.mean.is_finite()) {
        // A black map: nothing to fit; lobes keep their place with zero amplitude.
        let lobes: Vec<Asg> = init
            .iter()
            .map(|a| Asg {
                rgb: [0.0; 3],
                ..*a
            })
            .collect();
        return FitResult {
            lobes,
            initial_loss: Loss::default(),
            loss: Some(Loss::default()),
            iterations: 0,
            warm: prev.is_some(),
        };
    }
    // Warm refits may take each gradient on a rotating subset of the tiles (a final loss, where
    // evaluated, is the whole map's).
    let stride = if prev.is_some() {
        settings.warm_subset.max(1)
    } else {
        settings.first_subset.max(1)
    };
    let mode = |want_grad, phase| Mode {
        threads,
        want_grad,
        fast: true,
        temporal_grad: false,
        subset: if want_grad {
            super::fast::Subset::new(stride, phase)
        } else {
            super::fast::Subset::ALL
        },
    };
    let (b1, b2, eps) = (0.9, 0.999, 1e-12);
    if state.moments.len() != lobes.len() {
        state.moments = vec![Moments::default(); lobes.len()];
        state.steps = 0;
    }
    let mut best: Option<(Loss, Vec<Lobe>)> = None;
    let mut initial = None;
    if stages.len() > 1 || (stride > 1 && prev.is_none()) {
        let amax = (target.max_bandwidth() - MIN_BANDWIDTH).ln();
        let clamped: Vec<Lobe> = lobes
            .iter()
            .map(|l| Lobe {
                alpha: l.alpha.min(amax),
                beta: l.beta.min(amax),
                ..*l
            })
            .collect();
        let l = loss_and_grad(target, &clamped, prevs, settings, mode(false, 0)).0;
        initial = Some(l);
        // The coarse levels can end worse than the start: the start stays a candidate.
        best = Some((l, clamped));
    }
    // With L_T as a proximal step, the iterates descend L_R + w_D·L_D + a penalty on the
    // change; the last one is returned (the best total seen would be the unchanged previous
    // lobes, L_T being 0 there). Otherwise the best seen; with subsets only the whole-map
    // losses (the start's, the last one) count.
    let keep_last = prevs.is_some() && settings.temporal_weight > 0.0;
    let mut t = 0usize;
    'stages: for (si, &(stage, its)) in stages.iter().enumerate() {
        let last = si + 1 == stages.len();
        let amax = (stage.max_bandwidth() - MIN_BANDWIDTH).ln();
        for l in &mut lobes {
            l.alpha = l.alpha.min(amax);
            l.beta = l.beta.min(amax);
        }
        for it in 0..=its {
            if state.cancelled() {
                break 'stages;
            }
            let want = it < its;
            if !want && !last {
                break;
            }
            let skip_loss = !settings.warm_loss && prevs.is_some() && initial.is_some();
            if !want && skip_loss && (keep_last || best.is_none()) {
                // The last iterate is returned whatever its loss: the whole-map evaluation
                // would only report it (`FitSettings::warm_loss`).
                best = None;
                break;
            }
            let (loss, grads) = loss_and_grad(
                stage,
                &lobes,
                prevs,
                settings,
                mode(want, state.steps % stride),
            );
            if last {
                if initial.is_none() {
                    initial = Some(loss);
                }
                let exact = !want || stride == 1;
                if exact && (keep_last || best.as_ref().is_none_or(|(b, _)| loss.total < b.total)) {
                    best = Some((loss, lobes.clone()));
                }
            }
            if !want {
                break;
            }
            t += 1;
            state.steps += 1;
            let progress = (t - 1) as f64 / iterations.max(1) as f64;
            let lr = learning_rate * (0.1 + 0.9 * 0.5 * (1.0 + (PI * progress).cos()));
            let tf = state.steps as f64;
            for ((p, g), mo) in lobes.iter_mut().zip(&grads).zip(state.moments.iter_mut()) {
                let mut pg = param_grad(p, g);
                if settings.isotropic {
                    pg[3] += pg[4];
                    pg[4] = pg[3];
                }
                let rot_scale = 1.0 / (1.0 + p.lambda().max(p.mu())).sqrt();
                let mut d = [0.0; 8];
                for i in 0..8 {
                    let gi = if pg[i].is_finite() { pg[i] } else { 0.0 };
                    mo.m[i] = b1 * mo.m[i] + (1.0 - b1) * gi;
                    mo.v[i] = b2 * mo.v[i] + (1.0 - b2) * gi * gi;
                    let mh = mo.m[i] / (1.0 - b1.powf(tf));
                    let vh = mo.v[i] / (1.0 - b2.powf(tf));
                    let scale = if i < 3 { rot_scale } else { 1.0 };
                    d[i] = -lr * scale * mh / (vh.sqrt() + eps);
                }
                step(p, &d);
                p.alpha = p.alpha.min(amax);
                p.beta = p.beta.min(amax);
            }
            if let Some((pl, sc)) = prevs {
                if settings.temporal_weight > 0.0 {
                    let tau = settings.temporal_weight * lr;
                    for (p, q) in lobes.iter_mut().zip(pl) {
                        temporal_prox(p, q, sc, tau);
                    }
                }
            }
        }
    }
    let (loss, best) = match best {
        Some((l, b)) => (Some(l), b),
        None => (None, lobes),
    };
    FitResult {
        lobes: best.into_iter().map(Lobe::to_asg).collect(),
        initial_loss: initial.unwrap_or_default(),
        loss,
        iterations,
        warm: prev.is_some(),
    }
}

/// The proximal step of τ·‖(g − g_prev)/scale‖₂ (group soft-thresholding): the lobe moves back
/// towards `prev` by the factor κ = max(0, 1 − τ/‖u‖) on every component of its temporal vector
/// (axis and tangent re-orthonormalised, ln λ, ln μ and c interpolated).
fn temporal_prox(p: &mut Lobe, prev: &Lobe, scales: &[f64; 11], tau: f64) {
    let (g, h) = (p.temporal_vector(), prev.temporal_vector());
    let norm = (0..11)
        .map(|i| ((g[i] - h[i]) / scales[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    if !(norm.is_finite()) {
        *p = *prev;
        return;
    }
    if norm <= tau {
        *p = *prev;
        return;
    }
    let k = 1.0 - tau / norm;
    let z = (prev.z + (p.z - prev.z) * k).normalize_or(prev.z);
    let x = prev.x + (p.x - prev.x) * k;
    let x = (x - z * x.dot(z)).normalize_or(prev.x);
    let lerp = |a: f64, b: f64| a + (b - a) * k;
    let inv = |b: f64| (b.clamp(MIN_BANDWIDTH * (1.0 + 1e-9), MAX_BANDWIDTH) - MIN_BANDWIDTH).ln();
    let lam = lerp(h[6], g[6]).exp();
    let mu = lerp(h[7], g[7]).exp();
    p.z = z;
    p.x = x;
    p.y = z.cross(x);
    p.alpha = inv(lam);
    p.beta = inv(mu);
    for c in 0..3 {
        p.sigma[c] = lerp(h[8 + c], g[8 + c])
            .max(1e-300)
            .ln()
            .clamp(SIGMA_RANGE.0, SIGMA_RANGE.1);
    }
}

/// Lobes at least this narrow (min(λ, μ)) get the centroid step.
const CENTROID_MIN_BANDWIDTH: f64 = 100.0;
/// The centroid window: where min(λ, μ)·sin²θ ≤ this (3 standard deviations of the lobe's
/// wider direction).
const CENTROID_WINDOW: f64 = 9.0;

/// The warm start's centroid (mean-shift) step (module doc, step 5): every lobe with
/// min(λ, μ) ≥ 100 is turned, frame and all, so that its axis points at the centroid of its
/// share of the map inside a window of 3 standard deviations around the axis: the luminance
/// of `target` minus that of the other lobes, clamped at 0, weighted by solid angle. A sun or
/// lamp that moved by a fraction of its width since the previous frame is then under its lobe
/// again at once (Adam's warm steps move a narrow lobe by about 1 % of its width per
/// iteration). Wider lobes, and lobes with no positive share in their window, are unchanged.
pub fn centroid_step(target: &FitTarget, lobes: &[Asg]) -> Vec<Asg> {
    let lum = crate::decompose::luminance_f64;
    let (w, h) = (target.width as usize, target.height as usize);
    let mut out = lobes.to_vec();
    for (j, lobe) in lobes.iter().enumerate() {
        let b = lobe.lambda.min(lobe.mu);
        if !(b >= CENTROID_MIN_BANDWIDTH && b.is_finite()) {
            continue;
        }
        let z = DVec3::from(lobe.axis);
        let sin_r = (CENTROID_WINDOW / b).sqrt().min(1.0);
        let (rho, cos_r) = (sin_r.asin(), (1.0 - sin_r * sin_r).sqrt());
        let theta = z.y.clamp(-1.0, 1.0).acos();
        let row = |t: f64| (t / PI * h as f64).clamp(0.0, h as f64);
        let (y0, y1) = (
            row(theta - rho).floor() as usize,
            row(theta + rho).ceil() as usize,
        );
        let (mut acc, mut mass) = (DVec3::ZERO, 0.0);
        for i in y0 * w..y1 * w {
            let d = target.directions[i];
            if d.dot(z) < cos_r {
                continue;
            }
            let mut others = [0.0; 3];
            for (k, l) in lobes.iter().enumerate() {
                if k != j {
                    let g = l.shape(d);
                    for c in 0..3 {
                        others[c] += l.rgb[c] * g;
                    }
                }
            }
            let share = (lum(target.radiance[i]) - lum(others)).max(0.0);
            let m = target.weights[i] * share;
            acc += d * m;
            mass += m;
        }
        let centre = acc.normalize_or_zero();
        let axis = z.cross(centre);
        let sin_a = axis.length();
        if !(mass > 0.0 && mass.is_finite()) || centre == DVec3::ZERO || sin_a < 1e-12 {
            continue;
        }
        let turn = axis / sin_a * sin_a.atan2(z.dot(centre));
        let o = &mut out[j];
        o.axis = rotate(z, turn).to_array();
        o.tangent = rotate(DVec3::from(o.tangent), turn).to_array();
        o.bitangent = rotate(DVec3::from(o.bitangent), turn).to_array();
    }
    out
}

/// A warm refit scales the previous amplitudes by the ratio of the map's mean radiance to the
/// previous lobes' (their integral over 4π) when it exceeds this factor either way (an
/// exposure change, in one jump or in steps; [`AsgFitter::fit_target`]).
pub const WARM_RESCALE: f64 = 2.0;

/// Whether any lobe has a positive amplitude in some channel.
fn has_power(lobes: &[Asg]) -> bool {
    lobes.iter().any(|l| l.rgb.iter().any(|&c| c > 0.0))
}

/// Fits frame after frame, warm-starting each from the previous result (from scratch after a
/// frame that left no lobe with power: a black one).
#[derive(Clone, Debug)]
pub struct AsgFitter {
    settings: FitSettings,
    previous: Option<Vec<Asg>>,
    adam: AdamState,
    /// The last frame's target, refilled by the next frame of the same size
    /// ([`FitTarget::refill`]: the size-dependent parts and the buffers are reused).
    target: Option<FitTarget>,
}

impl AsgFitter {
    /// A fitter with validated settings.
    pub fn new(settings: FitSettings) -> Result<Self, AsgError> {
        settings.validate()?;
        Ok(Self {
            settings,
            previous: None,
            adam: AdamState::default(),
            target: None,
        })
    }

    /// The settings.
    pub fn settings(&self) -> &FitSettings {
        &self.settings
    }

    /// Replaces the settings (validated), keeping the previous frame and the optimiser's state
    /// unless the lobe count changes (then the next frame is fitted from scratch).
    pub fn set_settings(&mut self, settings: FitSettings) -> Result<(), AsgError> {
        settings.validate()?;
        if settings.lobes != self.settings.lobes {
            self.reset();
        }
        self.settings = settings;
        Ok(())
    }

    /// Forgets the previous frame: the next one is fitted from scratch.
    pub fn reset(&mut self) {
        self.previous = None;
        self.adam = AdamState {
            cancel: self.adam.cancel.take(),
            ..AdamState::default()
        };
    }

    /// Watches `flag`: once it is set, a fit in progress stops within one iteration and
    /// [`AsgFitter::fit_frame`] returns [`AsgError::Cancelled`] (the daemon's shutdown on a
    /// signal does not wait for a long first fit).
    pub fn watch_cancel(&mut self, flag: Arc<AtomicBool>) {
        self.adam.cancel = Some(flag);
    }

    /// The lobes of the last fitted frame.
    pub fn previous(&self) -> Option<&[Asg]> {
        self.previous.as_deref()
    }

    /// Prepares the target of `frame` (any projection; resampled to the fit-map size) in the
    /// fitter's own buffers: the previous frame's target is refilled when its size and number
    /// of normals match the settings ([`FitTarget::refill`]), else a new one is made. The same
    /// target as [`FitTarget::from_frame`] gives, faster.
    pub fn prepare(&mut self, frame: &HdrFrame) -> Result<&FitTarget, AsgError> {
        let target = self.take_prepared(frame)?;
        Ok(self.target.insert(target))
    }

    /// The target of `frame`, taken out of the fitter (refilled or made anew): on an error no
    /// half-made target is kept.
    fn take_prepared(&mut self, frame: &HdrFrame) -> Result<FitTarget, AsgError> {
        let (height, normals) = (self.settings.height, self.settings.diffuse_normals);
        match self.target.take() {
            Some(mut t) if t.height == height && t.normals.len() == normals => {
                t.refill(frame)?;
                Ok(t)
            }
            _ => FitTarget::from_frame(frame, height, normals),
        }
    }

    /// The target prepared last ([`AsgFitter::prepare`], [`AsgFitter::fit_frame`]).
    pub fn target(&self) -> Option<&FitTarget> {
        self.target.as_ref()
    }

    /// Fits the target prepared last ([`AsgFitter::prepare`]); `None` if there is none.
    pub fn fit_prepared(&mut self) -> Option<FitResult> {
        let target = self.target.take()?;
        let result = self.fit_target(&target);
        self.target = Some(target);
        Some(result)
    }

    /// Fits one frame (any projection; resampled to the fit-map size): [`AsgFitter::prepare`]
    /// and [`AsgFitter::fit_target`].
    pub fn fit_frame(&mut self, frame: &HdrFrame) -> Result<FitResult, AsgError> {
        let target = self.take_prepared(frame)?;
        let result = self.fit_target(&target);
        self.target = Some(target);
        if self.adam.cancelled() {
            return Err(AsgError::Cancelled);
        }
        Ok(result)
    }

    /// Fits one prepared target.
    pub fn fit_target(&mut self, target: &FitTarget) -> FitResult {
        // Lobes without power (those of a black frame) give a warm refit nothing to follow:
        // their log-amplitudes sit at the bound and the warm steps never bring them back.
        if self
            .previous
            .as_deref()
            .is_some_and(|prev| !has_power(prev))
        {
            self.reset();
        }
        let s = &self.settings;
        let result = match &self.previous {
            Some(prev) => {
                // A map whose scale jumped (an exposure change) is followed by scaling the
                // previous amplitudes with it: the warm steps move a log-amplitude by little.
                // Against the scale the lobes hold (their integral), not the previous map's:
                // a ramp of steps each too small to trigger was otherwise never followed.
                let lobes_mean = prev
                    .iter()
                    .map(|l| l.integral().iter().sum::<f64>())
                    .sum::<f64>()
                    / (4.0 * PI);
                let ratio = target.mean / lobes_mean;
                let scaled: Vec<Asg>;
                let prev = if ratio.is_finite()
                    && ratio > 0.0
                    && !(1.0 / WARM_RESCALE..=WARM_RESCALE).contains(&ratio)
                {
                    scaled = prev
                        .iter()
                        .map(|l| Asg {
                            rgb: l.rgb.map(|c| c * ratio),
                            ..*l
                        })
                        .collect();
                    &scaled
                } else {
                    prev
                };
                // L_T is measured from the previous lobes as the centroid step moved them: the
                // step says where a moving light went, L_T damps the rest of the change.
                let start = if s.warm_centroid {
                    centroid_step(target, prev)
                } else {
                    prev.clone()
                };
                optimise_continued(
                    target,
                    &start,
                    Some(&start),
                    s.warm_iterations,
                    s.warm_learning_rate,
                    s,
                    &mut self.adam,
                )
            }
            None => {
                let init = initial_lobes(target, s.lobes);
                let levels = pyramid(target, s);
                optimise_stages(
                    &levels.stages(s.iterations, s.fine_share),
                    &init,
                    s.learning_rate,
                    s,
                    &mut self.adam,
                )
            }
        };
        if !self.adam.cancelled() {
            self.previous = Some(result.lobes.clone());
        }
        result
    }
}
