// ASG lighting pass: Lambertian diffuse + GGX specular (metallic-roughness) under a set of
// anisotropic spherical Gaussians, in closed form, in linear HDR (rgba32float target). Each
// lobe's light is shadowed by a shadow map along its axis (the renderer treats the lobe as a
// directional light of its solid angle, so a wide lobe's PCF kernel, and its shadow, is soft):
// its diffuse and specular terms both times that visibility. Emission is added as in shade.wgsl.
//
// The same maths as src/asg/mod.rs (docs/asg.md; Xu et al. 2013):
//  * irradiance: E(n) = c · ∫G · H(n·z, ν), ν = 2√(λμ), with H the normalised cosine convolution
//    of an isotropic lobe, tabulated on the CPU (129 values of t = n·z × 72 of ln ν, exactly the
//    table of `asg::cosine_convolution`) and interpolated bilinearly here;
//  * specular: the GGX NDF as two Gaussians, each warped to light directions as an anisotropic
//    Gaussian around the mirror direction r (bandwidth 1/(4α²) in the plane of incidence,
//    1/(4α²(n·v)²) across it, scaled per Gaussian), its product with the ASG integrated in the
//    ASG's tangent plane (where the warped lobe is foreshortened) and in r's tangent plane
//    (where the ASG is linearised), the two blended by the lobes' widths, times Smith's
//    height-correlated G2 / (4 n·v) and F = f0 (`Asg::ggx_specular`).
// A shadow-catcher material outputs premultiplied (0, 0, 0, α), α = 1 − E_shadowed/E_unshadowed
// (luminance of the lobes' diffuse irradiance), as shade.wgsl's does.
// Blended materials (glTF's BLEND): fs_blended, drawn after the opaque surfaces in the same
// pass, back to front, over them (premultiplied alpha).
// Prepended: surface.wgsl (vertex layout, materials, the shaded point's set-up) and
// shadow_lookup.wgsl (the lobes' shadow maps: `lights[k]` is lobe k's); appended:
// closed_form.wgsl (the entry points, which call `shaded`).

const TABLE_T: u32 = 129u;
const TABLE_NU: u32 = 72u;
const TABLE_NU_MIN: f32 = 0.5;
const TABLE_NU_MAX: f32 = 400000.0;

struct Globals {
    view_proj: mat4x4<f32>,
    // The viewer: the eye (w = 1) or, for an orthographic camera, the direction towards it (w = 0).
    viewer: vec4<f32>,
    lobe_count: u32,
    shadows: u32,
    // As shade.wgsl's Globals: where the maps are, and the lookup's offsets and map side.
    shadow_source: u32,
    _pad: u32,
    shadow_params: vec4<f32>,
};

struct Lobe {
    // xyz: tangent x; w: λ.
    x: vec4<f32>,
    // xyz: bitangent y = z × x; w: μ.
    y: vec4<f32>,
    // xyz: axis z; w: ν = 2√(λμ).
    z: vec4<f32>,
    // rgb: amplitude c; w: ∫ of the unit-amplitude lobe (sr).
    rgb: vec4<f32>,
};

@group(0) @binding(0) var<uniform> globals: Globals;
@group(0) @binding(1) var<storage, read> lobes: array<Lobe>;
@group(0) @binding(2) var<storage, read> materials: array<Material>;
@group(0) @binding(3) var<storage, read> cosine_table: array<f32>;
// Lobe k's shadow map: `lights[k]` (the renderer's light buffer, one record per lobe).
@group(0) @binding(4) var<storage, read> lights: array<Light>;
@group(0) @binding(5) var shadow_maps: texture_depth_2d_array;
@group(0) @binding(6) var shadow_sampler: sampler_comparison;
@group(0) @binding(7) var<storage, read> shadow_depths: array<u32>;

fn shadow_state() -> ShadowState {
    return ShadowState(globals.shadows != 0u, globals.shadow_source, globals.shadow_params);
}

// H(t, ν): bilinear in t and ln ν on the table (clamped at its ends), as
// `asg::cosine_convolution`.
fn cosine_h(t: f32, nu: f32) -> f32 {
    let dt = 2.0 / f32(TABLE_T - 1u);
    let dl = log(TABLE_NU_MAX / TABLE_NU_MIN) / f32(TABLE_NU - 1u);
    let ut = clamp((clamp(t, -1.0, 1.0) + 1.0) / dt, 0.0, f32(TABLE_T - 1u));
    let un = clamp(log(max(nu, 1e-30) / TABLE_NU_MIN) / dl, 0.0, f32(TABLE_NU - 1u));
    let i = min(u32(floor(ut)), TABLE_T - 2u);
    let j = min(u32(floor(un)), TABLE_NU - 2u);
    let ft = ut - f32(i);
    let fv = un - f32(j);
    let h00 = cosine_table[j * TABLE_T + i];
    let h10 = cosine_table[j * TABLE_T + i + 1u];
    let h01 = cosine_table[(j + 1u) * TABLE_T + i];
    let h11 = cosine_table[(j + 1u) * TABLE_T + i + 1u];
    let h0 = h00 + (h10 - h00) * ft;
    let h1 = h01 + (h11 - h01) * ft;
    return h0 + (h1 - h0) * fv;
}

// The GGX NDF's profile 1/(1 + x)², x = tan²θ_h/α², as two Gaussians: (weight, bandwidth
// scale), `asg::GGX_NDF_MIXTURE`.
const NDF_MIXTURE = array<vec2<f32>, 2>(
    vec2<f32>(0.81578931, 1.77638657),
    vec2<f32>(0.14377074, 0.26586835),
);

// Φ(t) by Abramowitz and Stegun 7.1.26 (`asg::normal_cdf`).
fn normal_cdf(t: f32) -> f32 {
    let u = abs(t) * 0.70710678;
    let k = 1.0 / (1.0 + 0.3275911 * u);
    let poly = ((((1.061405429 * k - 1.453152027) * k + 1.421413741) * k - 0.284496736) * k
        + 0.254829592) * k;
    let erf_u = 1.0 - poly * exp(-u * u);
    return 0.5 * (1.0 + select(-erf_u, erf_u, t >= 0.0));
}

// E[max(X, 0)] for X normal (mean, spread), at most 1 (`asg::ramp_mean`).
fn ramp_mean(mean: f32, spread: f32) -> f32 {
    var value = mean;
    if spread > 0.0 {
        let t = mean / spread;
        value = mean * normal_cdf(t) + spread * exp(-0.5 * t * t) * 0.39894228;
    }
    return clamp(value, 0.0, 1.0);
}

// The warped GGX lobe (orthonormal axes `across`, `along` ⟂ r with bandwidths `bw`) times the
// ASG (frame x, y, z; bandwidths l, m), integrated in the ASG's tangent plane
// (`asg::product_integral`): the gradients g = (e·x, e·y) − (e·z / s)·a of the warped lobe's
// coordinates there.
fn product_in_lobe_plane(l: f32, m: f32, x: vec3<f32>, y: vec3<f32>, z: vec3<f32>,
                         r: vec3<f32>, across: vec3<f32>, along: vec3<f32>, bw: vec2<f32>) -> f32 {
    // Below this cosine between r and the lobe's axis the product is zero here
    // (`asg::MIN_PRODUCT_COSINE`).
    let s = dot(r, z);
    if s < 1e-4 {
        return 0.0;
    }
    let ax = dot(r, x);
    let ay = dot(r, y);
    let ez = vec2<f32>(dot(across, z), dot(along, z)) / s;
    let gx = vec2<f32>(dot(across, x), dot(along, x)) - ez * ax;
    let gy = vec2<f32>(dot(across, y), dot(along, y)) - ez * ay;
    let b_xx = dot(bw, gx * gx);
    let b_yy = dot(bw, gy * gy);
    let b_zz = dot(bw, ez * ez);
    let det_b = bw.x * bw.y / (s * s);
    let det = l * m + l * b_yy + m * b_xx + det_b;
    let quad = (l * m * b_zz + det_b * (l * ax * ax + m * ay * ay)) / det;
    return PI / sqrt(det) * exp(-quad);
}

// The same product in the mirror direction's tangent plane, the ASG linearised there
// (`asg::product_integral_at_mirror`).
fn product_at_mirror(l: f32, m: f32, x: vec3<f32>, y: vec3<f32>, z: vec3<f32>,
                     r: vec3<f32>, across: vec3<f32>, along: vec3<f32>, bw: vec2<f32>) -> f32 {
    let gx = vec2<f32>(dot(across, x), dot(along, x));
    let gy = vec2<f32>(dot(across, y), dot(along, y));
    let gz = vec2<f32>(dot(across, z), dot(along, z));
    let ax = dot(r, x);
    let ay = dot(r, y);
    let m00 = bw.x + l * gx.x * gx.x + m * gy.x * gy.x;
    let m11 = bw.y + l * gx.y * gx.y + m * gy.y * gy.y;
    let m01 = l * gx.x * gx.y + m * gy.x * gy.y;
    let det = max(m00 * m11 - m01 * m01, bw.x * bw.y);
    let h = l * ax * gx + m * ay * gy;
    let m_inv_h = vec2<f32>(m11 * h.x - m01 * h.y, m00 * h.y - m01 * h.x) / det;
    let exponent = min(dot(h, m_inv_h) - (l * ax * ax + m * ay * ay), 0.0);
    let m_inv_g = vec2<f32>(m11 * gz.x - m01 * gz.y, m00 * gz.y - m01 * gz.x) / det;
    let spread = sqrt(max(0.5 * dot(gz, m_inv_g), 0.0));
    let mean = dot(r, z) - dot(gz, m_inv_h);
    return PI / sqrt(det) * exp(exponent) * ramp_mean(mean, spread);
}

// Specular response to lobe `k` per unit f0 (`Asg::ggx_specular` with f0 = 1), without the
// lobe's colour.
fn ggx_response(k: u32, n: vec3<f32>, v: vec3<f32>, alpha_in: f32) -> f32 {
    let n_v = dot(n, v);
    if n_v <= 1e-6 {
        return 0.0;
    }
    let alpha = max(alpha_in, 1e-3);
    let a2 = alpha * alpha;
    let r = normalize(2.0 * n_v * n - v);
    let lobe = lobes[k];
    let x = lobe.x.xyz;
    let y = lobe.y.xyz;
    let z = lobe.z.xyz;
    // The GGX lobe warped around r (`asg::ggx_warp`): bandwidth 1/(4α²) in the plane of
    // incidence, 1/(4α²(n·v)²) across it (n·v at least `asg::MIN_WARP_COSINE`).
    var across = cross(n, r);
    let across_len2 = dot(across, across);
    if across_len2 > 1e-12 {
        across = across * inverseSqrt(across_len2);
    } else {
        // n = v: the lobe is isotropic and any frame will do.
        across = normalize(select(vec3<f32>(0.0, -r.z, r.y), vec3<f32>(-r.y, r.x, 0.0), abs(r.z) < 0.9));
    }
    let along = cross(r, across);
    let b_along = 1.0 / (4.0 * a2);
    let n_v_warp = max(n_v, 1e-3);
    let b_across = b_along / (n_v_warp * n_v_warp);
    let l = lobe.x.w;
    let m = lobe.y.w;
    let lobe_width = sqrt(l * m);
    var conv = 0.0;
    for (var i = 0u; i < 2u; i = i + 1u) {
        let term = NDF_MIXTURE[i];
        let bw = vec2<f32>(b_across, b_along) * term.y;
        // The plane of the narrower lobe is the better one; blend by the widths.
        let in_lobe_plane = lobe_width / (lobe_width + sqrt(bw.x * bw.y));
        conv = conv + term.x * (in_lobe_plane * product_in_lobe_plane(l, m, x, y, z, r, across, along, bw)
            + (1.0 - in_lobe_plane) * product_at_mirror(l, m, x, y, z, r, across, along, bw));
    }
    let lambda_v = (sqrt(1.0 + a2 * (1.0 / (n_v * n_v) - 1.0)) - 1.0) * 0.5;
    let g2 = 1.0 / (1.0 + 2.0 * lambda_v);
    return conv / (PI * a2) * g2 / (4.0 * n_v);
}

// The radiance (RGBA, opaque; a shadow catcher's premultiplied shadow) at the point `world`
// of material `mat`, whose parameters there are `p` (`surface_params`).
fn shaded(world: vec3<f32>, mat: Material, p: SurfaceParams) -> vec4<f32> {
    if is_unlit(mat.params.w) {
        return vec4<f32>(p.base_color, 1.0);
    }
    let s = surface_at(world, p.normal, p, mat.params.w, globals.viewer);
    let n = s.n;
    let v = s.v;
    let alpha = s.alpha;
    let diffuse = s.diffuse;
    let f0 = s.f0;
    let has_specular = s.has_specular;

    // A sheen (KHR_materials_sheen): each lobe as a directional light of its power along its
    // axis, as its shadow is (the sheen's lobe is broad; no closed form over the lobe's shape;
    // the lobe's irradiance times the BRDF at its axis jumped where a wide lobe's axis crossed
    // the horizon).
    let sheen = sheen_at(mat.sheen, mat.sheen_albedo, dot(n, v));
    var irradiance = vec3<f32>(0.0);
    var specular = vec3<f32>(0.0);
    var coat = vec3<f32>(0.0);
    var fibres = vec3<f32>(0.0);
    var e_lit = 0.0;
    var e_all = 0.0;
    for (var k = 0u; k < globals.lobe_count; k = k + 1u) {
        let axis = lobes[k].z;
        let vis = visibility(k, world, n, axis.xyz, i32(lights[k].rgb.w), true);
        let c = lobes[k].rgb;
        let e = c.rgb * (c.w * cosine_h(dot(n, axis.xyz), axis.w));
        irradiance = irradiance + e * vis;
        let lum = dot(e, vec3<f32>(0.2126, 0.7152, 0.0722));
        e_lit = e_lit + lum * vis;
        e_all = e_all + lum;
        if s.catcher {
            continue;
        }
        if has_specular {
            specular = specular + c.rgb * (ggx_response(k, n, v, alpha) * vis);
        }
        if s.coat > 0.0 {
            coat = coat + c.rgb * (ggx_response(k, s.n_coat, v, s.coat_alpha) * vis);
        }
        if sheen.alpha > 0.0 {
            let l = axis.xyz;
            var h = n;
            let vl = v + l;
            if dot(vl, vl) > 1e-12 {
                h = normalize(vl);
            }
            let n_l = dot(n, l);
            let f = sheen_brdf(sheen.alpha, max(dot(n, h), 0.0), dot(n, v), n_l);
            fibres = fibres + c.rgb * (c.w * f * max(n_l, 0.0) * vis);
        }
    }
    if s.catcher {
        var shadow = 0.0;
        if e_all > 0.0 {
            shadow = clamp(1.0 - e_lit / e_all, 0.0, 1.0);
        }
        return vec4<f32>(0.0, 0.0, 0.0, shadow);
    }
    // A clear coat, on its own normal, with its Fresnel reflectance at n·v (as F = f0 stands
    // for the base's): it reflects that share and takes it from the layer beneath, emission
    // included.
    let fc = s.coat * coat_fresnel(dot(s.n_coat, v));
    let base = (diffuse * irradiance + f0 * specular) * sheen.beneath + sheen.colour * fibres;
    let beneath = base * p.occlusion + p.emission;
    return vec4<f32>(beneath * (1.0 - fc) + fc * coat * p.occlusion, 1.0);
}
