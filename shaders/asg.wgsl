// ASG lighting pass: Lambertian diffuse + GGX specular (metallic-roughness) under a set of
// anisotropic spherical Gaussians, in closed form, in linear HDR (rgba32float target). No shadows
// and no occlusion: every lobe lights every surface facing it.
//
// The same maths as src/asg/mod.rs (docs/asg.md; Xu et al. 2013):
//  * irradiance: E(n) = c · ∫G · H(n·z, ν), ν = 2√(λμ), with H the normalised cosine convolution
//    of an isotropic lobe, tabulated on the CPU (129 values of t = n·z × 72 of ln ν, exactly the
//    table of `asg::cosine_convolution`) and interpolated bilinearly here;
//  * specular: the GGX lobe warped to light directions as an anisotropic Gaussian around the
//    mirror direction r (bandwidth 1/(4α²) in the plane of incidence, 1/(4α²(n·v)²) across
//    it), its product with the ASG integrated in the ASG's tangent plane (where the warped
//    lobe is foreshortened), times Smith's
//    height-correlated G2 / (4 n·v) and F = f0 (`Asg::ggx_specular`).
// A shadow-catcher material outputs (0, 0, 0, 0): without shadows there is nothing to catch.
// Prepended: surface.wgsl (vertex layout, materials, the shaded point's set-up).

const TABLE_T: u32 = 129u;
const TABLE_NU: u32 = 72u;
const TABLE_NU_MIN: f32 = 0.5;
const TABLE_NU_MAX: f32 = 400000.0;

struct Globals {
    view_proj: mat4x4<f32>,
    camera_pos: vec4<f32>,
    lobe_count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
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

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    return surface_vertex(globals.view_proj, v);
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
    // Below this cosine between r and the lobe's axis the lobe reflects nothing
    // (`asg::MIN_PRODUCT_COSINE`).
    let s = dot(r, z);
    if s < 1e-4 {
        return 0.0;
    }
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
    // Its product with the lobe in the lobe's tangent plane (`asg::product_integral`): the
    // gradients g = (e·x, e·y) − (e·z / s)·a of the warped lobe's coordinates there.
    let l = lobe.x.w;
    let m = lobe.y.w;
    let ax = dot(r, x);
    let ay = dot(r, y);
    let ez = vec2<f32>(dot(across, z), dot(along, z)) / s;
    let gx = vec2<f32>(dot(across, x), dot(along, x)) - ez * ax;
    let gy = vec2<f32>(dot(across, y), dot(along, y)) - ez * ay;
    let bw = vec2<f32>(b_across, b_along);
    let b_xx = dot(bw, gx * gx);
    let b_yy = dot(bw, gy * gy);
    let b_zz = dot(bw, ez * ez);
    let det_b = b_across * b_along / (s * s);
    let det = l * m + l * b_yy + m * b_xx + det_b;
    let quad = (l * m * b_zz + det_b * (l * ax * ax + m * ay * ay)) / det;
    let conv = PI / sqrt(det) * exp(-quad);
    let lambda_v = (sqrt(1.0 + a2 * (1.0 / (n_v * n_v) - 1.0)) - 1.0) * 0.5;
    let g2 = 1.0 / (1.0 + 2.0 * lambda_v);
    return conv / (PI * a2) * g2 / (4.0 * n_v);
}

@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    let s = surface_at(in.world, in.normal, materials[in.material], globals.camera_pos.xyz);
    if s.catcher {
        return vec4<f32>(0.0);
    }
    let n = s.n;
    let v = s.v;
    let alpha = s.alpha;
    let diffuse = s.diffuse;
    let f0 = s.f0;
    let has_specular = s.has_specular;

    var irradiance = vec3<f32>(0.0);
    var specular = vec3<f32>(0.0);
    for (var k = 0u; k < globals.lobe_count; k = k + 1u) {
        let c = lobes[k].rgb;
        let h = cosine_h(dot(n, lobes[k].z.xyz), lobes[k].z.w);
        irradiance = irradiance + c.rgb * (c.w * h);
        if has_specular {
            specular = specular + c.rgb * ggx_response(k, n, v, alpha);
        }
    }
    return vec4<f32>(diffuse * irradiance + f0 * specular, 1.0);
}
