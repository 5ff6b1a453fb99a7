// Shared by the passes that read the shadow maps, shade.wgsl (directional lights) and asg.wgsl
// (a shadow map along each ASG lobe's axis): the light records, the PCF lookup and the
// comparison of one tap on either kind of map (the depth texture array of the render passes or
// the compute rasteriser's buffer). Not a pipeline of its own: src/render prepends it, after
// surface.wgsl, to those two files. Each pass declares the bindings `lights`, `shadow_maps`,
// `shadow_sampler` and `shadow_depths`, and a function `shadow_state()` that returns its
// `ShadowState` (from its own globals).

const PCF_TAPS: u32 = 12u;

struct Light {
    // xyz: unit direction towards the light; w: angular radius (rad).
    dir: vec4<f32>,
    // rgb: integrated radiance; w: shadow-map layer, negative for none.
    rgb: vec4<f32>,
    view_proj: mat4x4<f32>,
    // x: PCF radius in shadow-map uv; y, z, w: unused.
    params: vec4<f32>,
};

// How the pass reads the shadow maps.
struct ShadowState {
    // Whether shadows are drawn at all.
    on: bool,
    // Where the maps are: 0 the depth texture array (render passes), 1 the compute
    // rasteriser's buffer (shadow_raster.wgsl).
    source: u32,
    // x: normal offset (world units), y: depth bias (NDC depth), z: map side in texels.
    params: vec4<f32>,
};

// A 12-tap Poisson disk in the unit circle.
var<private> POISSON: array<vec2<f32>, 12> = array<vec2<f32>, 12>(
    vec2<f32>(-0.326, -0.406), vec2<f32>(-0.840, -0.074), vec2<f32>(-0.696, 0.457),
    vec2<f32>(-0.203, 0.621), vec2<f32>(0.962, -0.195), vec2<f32>(0.473, -0.480),
    vec2<f32>(0.519, 0.767), vec2<f32>(0.185, -0.893), vec2<f32>(0.507, 0.064),
    vec2<f32>(0.896, 0.412), vec2<f32>(-0.322, -0.933), vec2<f32>(-0.792, -0.598),
);

// One bilinear depth comparison of map `layer` at `uv` against `depth`: the fraction of the
// 2×2 texels around uv with depth ≤ the stored one, weighted bilinearly, with the edge texels
// clamped — what the LessEqual comparison sampler gives on the texture array, done by hand on
// the compute rasteriser's buffer.
fn compare_tap(uv: vec2<f32>, layer: i32, depth: f32) -> f32 {
    if shadow_state().source == 0u {
        return textureSampleCompareLevel(shadow_maps, shadow_sampler, uv, layer, depth);
    }
    let res = i32(shadow_state().params.z);
    let t = uv * shadow_state().params.z - vec2<f32>(0.5);
    let cell = floor(t);
    let f = t - cell;
    let last = res - 1;
    let x0 = clamp(i32(cell.x), 0, last);
    let x1 = clamp(i32(cell.x) + 1, 0, last);
    let y0 = clamp(i32(cell.y), 0, last);
    let y1 = clamp(i32(cell.y) + 1, 0, last);
    let base = u32(layer) * u32(res) * u32(res);
    let r0 = base + u32(y0 * res);
    let r1 = base + u32(y1 * res);
    let s00 = select(0.0, 1.0, depth <= bitcast<f32>(shadow_depths[r0 + u32(x0)]));
    let s10 = select(0.0, 1.0, depth <= bitcast<f32>(shadow_depths[r0 + u32(x1)]));
    let s01 = select(0.0, 1.0, depth <= bitcast<f32>(shadow_depths[r1 + u32(x0)]));
    let s11 = select(0.0, 1.0, depth <= bitcast<f32>(shadow_depths[r1 + u32(x1)]));
    return mix(mix(s00, s10, f.x), mix(s01, s11, f.x), f.y);
}

// Visibility of light `i` at world point `p` with normal `n`: 1 lit, 0 shadowed.
fn visibility(i: u32, p: vec3<f32>, n: vec3<f32>, l: vec3<f32>, layer: i32, full: bool) -> f32 {
    if !shadow_state().on || layer < 0 {
        return 1.0;
    }
    let q = p + n * shadow_state().params.x;
    let c = lights[i].view_proj * vec4<f32>(q, 1.0);
    let uv = vec2<f32>(c.x * 0.5 + 0.5, 0.5 - c.y * 0.5);
    if any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) {
        return 1.0;
    }
    // The kernel reaches `radius` across a receiver tilted by θ from the light: bias the
    // reference by radius·tan θ (depth and uv both span 2R, so the units agree), capped.
    let radius = lights[i].params.x;
    let ndl = clamp(dot(n, l), 0.05, 1.0);
    let tan_theta = min(sqrt(1.0 - ndl * ndl) / ndl, 10.0);
    // Receivers beyond the far plane compare as just inside it: lit unless a caster is there.
    let depth = min(c.z, 0.99999) - shadow_state().params.y - radius * tan_theta;
    if !full {
        // Cheap path: 4 bilinear taps on the kernel's half radius.
        let h = 0.5 * radius;
        var cheap = compare_tap(uv + vec2<f32>(h, h), layer, depth);
        cheap = cheap + compare_tap(uv + vec2<f32>(-h, h), layer, depth);
        cheap = cheap + compare_tap(uv + vec2<f32>(h, -h), layer, depth);
        cheap = cheap + compare_tap(uv + vec2<f32>(-h, -h), layer, depth);
        return 0.25 * cheap;
    }
    var sum = 0.0;
    for (var k = 0u; k < PCF_TAPS; k = k + 1u) {
        sum = sum + compare_tap(uv + POISSON[k] * radius, layer, depth);
    }
    return sum / f32(PCF_TAPS);
}
