// SH lighting pass: Lambertian diffuse + GGX specular (metallic-roughness) under an environment
// given as real spherical-harmonic coefficients up to a degree L (src/sh), in linear HDR
// (rgba32float target). No shadows: SH light is the unshadowed environment (ambient); only a
// material's occlusion texture occludes it. Emission is added as in shade.wgsl.
//
// The same maths as the CPU (src/sh/mod.rs, src/render/sh.rs):
//  * irradiance (Ramamoorthi & Hanrahan 2001): E(n) = Σ_l Â_l Σ_m L_lm Y_lm(n), the clamped
//    cosine's band factors Â_l taken from the CPU (`sh::cosine_lobe_factor`), clamped at 0
//    (a truncated series rings below zero behind a sun);
//  * specular (the split sum): f0 · A(n·v, α) · R(r), with R the radiance around the mirror
//    direction r prefiltered by a normalised spherical Gaussian of sharpness λ = 1/(2α²)
//    (the GGX lobe as a Gaussian in the reflected direction, its across-plane stretch
//    ignored): R(r) = Σ_l g_l Σ_m L_lm Y_lm(r), g_l = exp(−l(l + 1)/(2λ))
//    (`sh::gaussian_lobe_factor`), clamped at 0; A the GGX directional albedo for F = 1
//    (Smith height-correlated G2, as the lights' and lobes' BRDF), tabulated on the CPU
//    (`render::sh::albedo_table`), F = f0 as in asg.wgsl;
//  * clear coat: the same on its own normal and α, with its Fresnel weight as asg.wgsl's;
//  * sheen: its directional albedo (the layer's own table, `sheen_at`) times E(n)/π, the
//    uniform radiance of the same irradiance.
// The basis is evaluated as `sh::Basis::evaluate` does — Re, Im of (x + iy)^m by complex
// products, P_l^m / sin^m θ by the three-term recurrence in l — and summed on the fly.
// A shadow-catcher material outputs transparent black: there is no shadow to catch.
// Blended materials (glTF's BLEND): fs_blended, drawn after the opaque surfaces in the same
// pass, back to front, over them (premultiplied alpha).
// Prepended: surface.wgsl (vertex layout, materials, the shaded point's set-up); appended:
// closed_form.wgsl (the entry points, which call `shaded`).

// The highest degree (`sh::MAX_DEGREE`): the band tables below hold MAX_DEGREE + 1 entries.
const MAX_DEGREE: u32 = 15u;
// The albedo table's nodes (`render::sh::ALBEDO_TABLE_COSINES`, `ALBEDO_TABLE_ROUGHNESS`).
const ALBEDO_COSINES: u32 = 32u;
const ALBEDO_ROUGHNESS: u32 = 32u;

struct Globals {
    view_proj: mat4x4<f32>,
    // The viewer: the eye (w = 1) or, for an orthographic camera, the direction towards it (w = 0).
    viewer: vec4<f32>,
    degree: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
};

@group(0) @binding(0) var<uniform> globals: Globals;
// L_lm at l² + l + m: rgb, w unused.
@group(0) @binding(1) var<storage, read> coefficients: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> materials: array<Material>;
// [0, MAX_DEGREE]: Â_l; then K_l^m (×√2 for m > 0) at MAX_DEGREE + 1 + l(l + 1)/2 + m.
@group(0) @binding(3) var<storage, read> basis_table: array<f32>;
// The GGX directional albedo (F = 1) at n·v = i/31 and √α = j/31, at j · 32 + i.
@group(0) @binding(4) var<storage, read> albedo_table: array<f32>;

// The weight of band l: Â_l (`cosine` true) or the Gaussian lobe's g_l of sharpness λ.
fn band_weight(l: u32, cosine: bool, sharpness: f32) -> f32 {
    if cosine {
        return basis_table[l];
    }
    if l == 0u {
        return 1.0;
    }
    if !(sharpness > 0.0) {
        return 0.0;
    }
    return exp(-f32(l * (l + 1u)) / (2.0 * sharpness));
}

// Σ_l w_l Σ_m L_lm Y_lm(d) for unit `d`, w_l = band_weight(l, cosine, sharpness).
fn sh_sum(d: vec3<f32>, cosine: bool, sharpness: f32) -> vec3<f32> {
    let degree = min(globals.degree, MAX_DEGREE);
    var sum = vec3<f32>(0.0);
    var re = 1.0;
    var im = 0.0;
    var q_diagonal = 1.0;
    for (var m = 0u; m <= degree; m = m + 1u) {
        if m > 0u {
            let re_next = re * d.x - im * d.y;
            im = re * d.y + im * d.x;
            re = re_next;
            q_diagonal = q_diagonal * f32(2u * m - 1u);
        }
        var q_before = 0.0;
        var q = q_diagonal;
        for (var l = m; l <= degree; l = l + 1u) {
            if l > m {
                let next = (f32(2u * l - 1u) * d.z * q - f32(l + m - 1u) * q_before) / f32(l - m);
                q_before = q;
                q = next;
            }
            let nq = band_weight(l, cosine, sharpness)
                * basis_table[MAX_DEGREE + 1u + l * (l + 1u) / 2u + m] * q;
            let centre = l * l + l;
            if m == 0u {
                sum = sum + coefficients[centre].rgb * nq;
            } else {
                sum = sum + (coefficients[centre + m].rgb * re + coefficients[centre - m].rgb * im) * nq;
            }
        }
    }
    return sum;
}

// The GGX directional albedo for F = 1 at cosine `n_v` and α = `alpha`: the CPU's table
// (`render::sh::albedo_table`, n·v × √α) interpolated bilinearly, as `render::sh::ggx_albedo`.
fn ggx_albedo(n_v: f32, alpha: f32) -> f32 {
    let x = clamp(n_v, 0.0, 1.0) * f32(ALBEDO_COSINES - 1u);
    let y = sqrt(clamp(alpha, 0.0, 1.0)) * f32(ALBEDO_ROUGHNESS - 1u);
    let i = min(u32(x), ALBEDO_COSINES - 2u);
    let j = min(u32(y), ALBEDO_ROUGHNESS - 2u);
    let fx = x - f32(i);
    let fy = y - f32(j);
    let a00 = albedo_table[j * ALBEDO_COSINES + i];
    let a10 = albedo_table[j * ALBEDO_COSINES + i + 1u];
    let a01 = albedo_table[(j + 1u) * ALBEDO_COSINES + i];
    let a11 = albedo_table[(j + 1u) * ALBEDO_COSINES + i + 1u];
    let a0 = a00 + (a10 - a00) * fx;
    let a1 = a01 + (a11 - a01) * fx;
    return a0 + (a1 - a0) * fy;
}

// Specular radiance per unit f0 at normal `n` seen from `v` with GGX α `alpha`.
fn sh_specular(n: vec3<f32>, v: vec3<f32>, alpha: f32) -> vec3<f32> {
    let n_v = dot(n, v);
    if n_v <= 1e-6 {
        return vec3<f32>(0.0);
    }
    let r = normalize(2.0 * n_v * n - v);
    let prefiltered = max(sh_sum(r, false, 1.0 / (2.0 * alpha * alpha)), vec3<f32>(0.0));
    return prefiltered * ggx_albedo(n_v, alpha);
}

// The radiance (RGBA, opaque; transparent black for a shadow catcher) at the point `world` of
// material `mat`, whose parameters there are `p` (`surface_params`).
fn shaded(world: vec3<f32>, mat: Material, p: SurfaceParams) -> vec4<f32> {
    if is_unlit(mat.params.w) {
        return vec4<f32>(p.base_color, 1.0);
    }
    let s = surface_at(world, p.normal, p, mat.params.w, globals.viewer);
    if s.catcher {
        return vec4<f32>(0.0);
    }
    let n = s.n;
    let v = s.v;
    let irradiance = max(sh_sum(n, true, 0.0), vec3<f32>(0.0));
    var specular = vec3<f32>(0.0);
    if s.has_specular {
        specular = sh_specular(n, v, s.alpha);
    }
    var coat = vec3<f32>(0.0);
    if s.coat > 0.0 {
        coat = sh_specular(s.n_coat, v, s.coat_alpha);
    }
    // The sheen's directional albedo E_s(n·v) from the factor on the layer beneath,
    // 1 − max(colour) · E_s.
    let sheen = sheen_at(mat.sheen, mat.sheen_albedo, dot(n, v));
    var fibres = vec3<f32>(0.0);
    let strongest = max(sheen.colour.r, max(sheen.colour.g, sheen.colour.b));
    if sheen.alpha > 0.0 && strongest > 0.0 {
        fibres = sheen.colour * ((1.0 - sheen.beneath) / strongest) * irradiance / PI;
    }
    let fc = s.coat * coat_fresnel(dot(s.n_coat, v));
    let base = (s.diffuse * irradiance + s.f0 * specular) * sheen.beneath + fibres;
    let beneath = base * p.occlusion + p.emission;
    return vec4<f32>(beneath * (1.0 - fc) + fc * coat * p.occlusion, 1.0);
}
