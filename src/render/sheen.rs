//! The sheen layer of glTF's `KHR_materials_sheen`: the back-scattering of velvet-like
//! fabrics, a forest of fibres standing from the surface, layered over the metallic-roughness
//! base.
//!
//! - The fibres' distribution is Conty and Kulla's "Charlie" (Production Friendly Microfacet
//!   Sheen BRDF, SIGGRAPH 2017): D(h) = (2 + 1/α) sin(θ_h)^(1/α) / 2π, with α = roughness²
//!   (glTF's perceptual sheen roughness, floored at [`MIN_ROUGHNESS`]).
//! - Their visibility is the same paper's, with its fitted Λ
//!   (V = 1 / ((1 + Λ(n·v) + Λ(n·l)) · 4 (n·v)(n·l))), no Fresnel term: f_sheen =
//!   sheen colour · D · V.
//! - The base beneath is scaled by 1 − max(sheen colour) · E(n·v), E the sheen's directional
//!   albedo (the share of light from all directions it reflects towards v; the extension's
//!   "albedo scaling", in its view-only form), so the two layers together reflect no more than
//!   arrives. E is integrated numerically here, per material at 16 cosines
//!   ([`albedo_table`]), and interpolated in the shaders (`sheen_albedo` in
//!   shaders/surface.wgsl, which evaluates the same BRDF).

use glam::Vec3;

/// The smallest sheen roughness drawn: below it the distribution's exponent 1/α² overflows
/// in f32 (as in Khronos's sample viewer and three.js: a sheen of roughness 0 is as sharp as
/// 0.07).
pub const MIN_ROUGHNESS: f32 = 0.07;

/// How many cosines n·v the directional albedo table holds, evenly spaced over [0, 1].
pub const ALBEDO_SAMPLES: usize = 16;

/// The fibres' distribution α for a perceptual sheen roughness.
pub fn alpha(roughness: f32) -> f32 {
    let r = roughness.clamp(MIN_ROUGHNESS, 1.0);
    r * r
}

/// Conty and Kulla's "Charlie" distribution at the cosine `n_h` between the normal and the half
/// vector.
pub fn charlie_distribution(alpha: f64, n_h: f64) -> f64 {
    let inv = 1.0 / alpha;
    let sin2 = (1.0 - n_h * n_h).max(0.0);
    (2.0 + inv) * sin2.powf(0.5 * inv) / (2.0 * std::f64::consts::PI)
}

/// Conty and Kulla's fitted exponent of Λ, interpolated between their fits at α = 0 and 1.
fn lambda_exponent(x: f64, alpha: f64) -> f64 {
    let t = (1.0 - alpha) * (1.0 - alpha);
    let mix = |a: f64, b: f64| a + (b - a) * t;
    let a = mix(21.5473, 25.3245);
    let b = mix(3.82987, 3.32435);
    let c = mix(0.19823, 0.16801);
    let d = mix(-1.97760, -1.27393);
    let e = mix(-4.32054, -4.85967);
    a / (1.0 + b * x.powf(c)) + d * x + e
}

/// Λ of the sheen's masking at cosine `cos` (the fit below cos = 0.5, its reflection above).
fn lambda(cos: f64, alpha: f64) -> f64 {
    if cos < 0.5 {
        lambda_exponent(cos, alpha).exp()
    } else {
        (2.0 * lambda_exponent(0.5, alpha) - lambda_exponent(1.0 - cos, alpha)).exp()
    }
}

/// The sheen BRDF without its colour, D · V, for unit normal `n`, view `v` and light `l`;
/// 0 where either lies below the surface.
pub fn brdf(alpha: f64, n: glam::DVec3, v: glam::DVec3, l: glam::DVec3) -> f64 {
    let (n_v, n_l) = (n.dot(v), n.dot(l));
    if n_v <= 0.0 || n_l <= 0.0 {
        return 0.0;
    }
    let h = (v + l).normalize_or_zero();
    let d = charlie_distribution(alpha, n.dot(h).clamp(0.0, 1.0));
    let visibility =
        (1.0 / ((1.0 + lambda(n_v, alpha) + lambda(n_l, alpha)) * 4.0 * n_v * n_l)).min(1.0);
    d * visibility
}

/// The sheen's directional albedo E(n·v): ∫ f_sheen (n·l) dω over the hemisphere, for a white
/// sheen of distribution `alpha` seen at cosine `n_v` (floored at 1e-3), by the midpoint rule
/// over θ_l and φ_l (`steps` × 2·`steps` cells).
pub fn directional_albedo(alpha: f64, n_v: f64, steps: usize) -> f64 {
    use std::f64::consts::PI;
    let n_v = n_v.clamp(1e-3, 1.0);
    let n = glam::DVec3::Z;
    let v = glam::DVec3::new((1.0 - n_v * n_v).sqrt(), 0.0, n_v);
    let (dt, dp) = (0.5 * PI / steps as f64, PI / steps as f64);
    let mut sum = 0.0;
    for i in 0..steps {
        let theta = (i as f64 + 0.5) * dt;
        let (sin_t, cos_t) = theta.sin_cos();
        for j in 0..2 * steps {
            let phi = (j as f64 + 0.5) * dp;
            let l = glam::DVec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t);
            sum += brdf(alpha, n, v, l) * cos_t * sin_t;
        }
    }
    sum * dt * dp
}

/// E(n·v) for the sheen roughness `roughness` at n·v = i / ([`ALBEDO_SAMPLES`] − 1), each
/// clamped to [0, 1] (the shaders interpolate linearly between them).
pub fn albedo_table(roughness: f32) -> [f32; ALBEDO_SAMPLES] {
    let alpha = f64::from(alpha(roughness));
    std::array::from_fn(|i| {
        let n_v = i as f64 / (ALBEDO_SAMPLES - 1) as f64;
        directional_albedo(alpha, n_v, 96).clamp(0.0, 1.0) as f32
    })
}

/// The sheen's BRDF with its colour, colour · D · V, for unit normal `n`, view `v` and light
/// `l` — a CPU reference of the shaders' sheen, for tests and tools.
pub fn fibres(colour: [f32; 3], roughness: f32, n: Vec3, v: Vec3, l: Vec3) -> [f32; 3] {
    let f = brdf(
        f64::from(alpha(roughness)),
        n.as_dvec3(),
        v.as_dvec3(),
        l.as_dvec3(),
    ) as f32;
    colour.map(|c| c * f)
}

/// The factor on the base beneath a sheen seen at cosine `n_v`: 1 − max(colour) · E(n·v),
/// with E integrated at that cosine (the shaders interpolate [`albedo_table`]).
pub fn beneath(colour: [f32; 3], roughness: f32, n_v: f32) -> f32 {
    let e = directional_albedo(f64::from(alpha(roughness)), f64::from(n_v), 64) as f32;
    let strongest = colour.iter().fold(0.0f32, |m, &c| m.max(c));
    1.0 - strongest * e.clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The distribution is normalised: ∫ D(h) (n·h) dω_h = 1 over the hemisphere, for smooth
    /// and rough fibres alike.
    #[test]
    fn the_distribution_projects_to_unit_area() {
        for roughness in [0.1f32, 0.3, 0.6, 1.0] {
            let a = f64::from(alpha(roughness));
            let steps = 4000;
            let dt = 0.5 * std::f64::consts::PI / steps as f64;
            let area: f64 = (0..steps)
                .map(|i| {
                    let t = (i as f64 + 0.5) * dt;
                    charlie_distribution(a, t.cos()) * t.cos() * t.sin() * dt
                })
                .sum::<f64>()
                * 2.0
                * std::f64::consts::PI;
            assert!((area - 1.0).abs() < 1e-3, "roughness {roughness}: {area}");
        }
    }

    /// The directional albedo converges (two resolutions agree within 0.5% + 10⁻⁴), lies in (0, 1) from
    /// n·v = 0.05 on — the sheen alone reflects no more than arrives; closer to grazing, the
    /// fitted masking of smooth fibres lets it pass 1 (1.35 at n·v = 0.02 and roughness 0.07),
    /// which the table clamps — and grows towards grazing views, where a velvet's sheen
    /// shows.
    #[test]
    fn the_albedo_is_converged_bounded_and_grows_towards_grazing() {
        for roughness in [0.07f32, 0.3, 0.6, 1.0] {
            let a = f64::from(alpha(roughness));
            for n_v in [0.05, 0.3, 0.7, 1.0] {
                let coarse = directional_albedo(a, n_v, 96);
                let fine = directional_albedo(a, n_v, 384);
                assert!(
                    (coarse - fine).abs() <= 0.005 * fine + 1e-4,
                    "roughness {roughness}, n·v {n_v}: {coarse} vs {fine}"
                );
                assert!(
                    fine > 0.0 && fine < 1.0,
                    "roughness {roughness}: E = {fine}"
                );
            }
            let table = albedo_table(roughness);
            assert!(
                table[1] > table[ALBEDO_SAMPLES - 1],
                "roughness {roughness}: {table:?}"
            );
        }
    }
}
