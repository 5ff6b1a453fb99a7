// Fast approximate anti-aliasing (compute pass: cs_fxaa, 8×8 workgroups), after the shading
// (and the supersampling's resolve): the quality variant of Lottes's FXAA 3.11 (NVIDIA, 2011),
// in the step-by-step form of Rodriguez's walkthrough ("Implementing FXAA", 2014), on the
// linear HDR frame with premultiplied alpha. src/render/post.rs builds it.
//
// Per pixel:
//  1. The edge signal: perceptual luma, the square root of linear luma divided by the largest
//     luma of the pixel's 3 × 3 neighbourhood (so the thresholds do not depend on the frame's
//     exposure, which an HDR frame does not have yet), or the alpha where that varies more
//     across the 3 × 3 than the luma (silhouettes over the transparent background, whose
//     colour may be as dark as the background; a shadow catcher's shadow, which is alpha only).
//  2. Pixels whose signal range over the cross is below EDGE_THRESHOLD of its maximum (and
//     EDGE_THRESHOLD_MIN) are left as they are.
//  3. The edge's orientation from the 3 × 3 second differences; the steeper side across it.
//  4. Search along the edge both ways, in growing steps (QUALITY), for where the signal leaves
//     the edge's mean by a quarter of the gradient: the edge's ends.
//  5. The pixel's offset across the edge from its place between the ends (0.5 at an end, 0 in
//     the middle), or from the sub-pixel contrast of the 3 × 3 (thin features), the larger.
//  6. The output is the frame read bilinearly at that offset across the edge: a mix of the
//     pixel and its neighbour, colour and alpha alike, so the result composites as the frame.

@group(0) @binding(0) var frame_in: texture_2d<f32>;
@group(0) @binding(1) var frame_out: texture_storage_2d<rgba32float, write>;

const LUMA: vec3<f32> = vec3<f32>(0.2126, 0.7152, 0.0722);
// A pixel is on an edge where the signal's range over its cross is at least this fraction of
// the cross's maximum (FXAA's "quality" preset value), and at least EDGE_THRESHOLD_MIN.
const EDGE_THRESHOLD: f32 = 0.125;
const EDGE_THRESHOLD_MIN: f32 = 0.0312;
// How much of the sub-pixel contrast is blended (FXAA's default).
const SUBPIXEL_QUALITY: f32 = 0.75;
const ITERATIONS: u32 = 12u;
var<private> QUALITY: array<f32, 12> = array<f32, 12>(1.0, 1.0, 1.0, 1.0, 1.0, 1.5, 2.0, 2.0,
                                                       2.0, 2.0, 4.0, 8.0);

// The signal of step 1: alpha, or the square root of luma over the neighbourhood's largest.
var<private> signal_is_alpha: bool;
var<private> inverse_luma_max: f32;

fn signal(c: vec4<f32>) -> f32 {
    if signal_is_alpha {
        return clamp(c.a, 0.0, 1.0);
    }
    return sqrt(clamp(dot(c.rgb, LUMA) * inverse_luma_max, 0.0, 1.0));
}

// The range of the signal values `v` over a pixel's cross (its first five: the pixel and its
// four neighbours).
fn cross_range(v: array<f32, 9>) -> f32 {
    var lo = v[0];
    var hi = v[0];
    for (var i = 1u; i < 5u; i = i + 1u) {
        lo = min(lo, v[i]);
        hi = max(hi, v[i]);
    }
    return hi - lo;
}

// The frame's texel `p`, clamped to the image.
fn texel(p: vec2<i32>) -> vec4<f32> {
    let last = vec2<i32>(textureDimensions(frame_in)) - vec2<i32>(1);
    return textureLoad(frame_in, clamp(p, vec2<i32>(0), last), 0);
}

// The frame read bilinearly at `at`, in pixels (pixel (x, y)'s centre at (x + 0.5, y + 0.5)),
// by hand: Rgba32Float is not filterable everywhere.
fn bilinear(at: vec2<f32>) -> vec4<f32> {
    let t = at - vec2<f32>(0.5);
    let cell = floor(t);
    let f = t - cell;
    let p = vec2<i32>(cell);
    let top = mix(texel(p), texel(p + vec2<i32>(1, 0)), f.x);
    let bottom = mix(texel(p + vec2<i32>(0, 1)), texel(p + vec2<i32>(1, 1)), f.x);
    return mix(top, bottom, f.y);
}

@compute @workgroup_size(8, 8)
fn cs_fxaa(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(frame_out);
    if id.x >= size.x || id.y >= size.y {
        return;
    }
    let p = vec2<i32>(id.xy);
    let centre = texel(p);
    // The 3 × 3: north is up the image (−y).
    let cn = texel(p + vec2<i32>(0, -1));
    let cs = texel(p + vec2<i32>(0, 1));
    let ce = texel(p + vec2<i32>(1, 0));
    let cw = texel(p + vec2<i32>(-1, 0));
    let cnw = texel(p + vec2<i32>(-1, -1));
    let cne = texel(p + vec2<i32>(1, -1));
    let csw = texel(p + vec2<i32>(-1, 1));
    let cse = texel(p + vec2<i32>(1, 1));

    // Step 1: the normaliser, both signals over the 3 × 3 (the cross first: centre, north,
    // south, east, west; then the corners), and the one that varies more over the cross.
    let texels = array<vec4<f32>, 9>(centre, cn, cs, ce, cw, cnw, cne, csw, cse);
    var luma_max = 0.0;
    for (var i = 0u; i < 9u; i = i + 1u) {
        luma_max = max(luma_max, dot(texels[i].rgb, LUMA));
    }
    inverse_luma_max = select(0.0, 1.0 / luma_max, luma_max > 0.0);
    var by_luma: array<f32, 9>;
    var by_alpha: array<f32, 9>;
    for (var i = 0u; i < 9u; i = i + 1u) {
        signal_is_alpha = false;
        by_luma[i] = signal(texels[i]);
        signal_is_alpha = true;
        by_alpha[i] = signal(texels[i]);
    }
    signal_is_alpha = cross_range(by_alpha) > cross_range(by_luma);
    var v = by_luma;
    if signal_is_alpha {
        v = by_alpha;
    }

    // Step 2: edges only.
    let s = v[0];
    let sn = v[1];
    let ss = v[2];
    let se = v[3];
    let sw = v[4];
    let s_min = min(s, min(min(sn, ss), min(se, sw)));
    let s_max = max(s, max(max(sn, ss), max(se, sw)));
    let range = s_max - s_min;
    if range < max(EDGE_THRESHOLD_MIN, s_max * EDGE_THRESHOLD) {
        textureStore(frame_out, p, centre);
        return;
    }
    let snw = v[5];
    let sne = v[6];
    let ssw = v[7];
    let sse = v[8];

    // Step 3: a horizontal edge (signal changing along y) or a vertical one.
    let edge_horizontal = abs(-2.0 * sw + snw + ssw) + 2.0 * abs(-2.0 * s + sn + ss)
        + abs(-2.0 * se + sne + sse);
    let edge_vertical = abs(-2.0 * sn + snw + sne) + 2.0 * abs(-2.0 * s + sw + se)
        + abs(-2.0 * ss + ssw + sse);
    let horizontal = edge_horizontal >= edge_vertical;
    // Across the edge (towards +y or +x) and along it.
    let across = select(vec2<f32>(1.0, 0.0), vec2<f32>(0.0, 1.0), horizontal);
    let along = select(vec2<f32>(0.0, 1.0), vec2<f32>(1.0, 0.0), horizontal);
    let s_before = select(sw, sn, horizontal);
    let s_after = select(se, ss, horizontal);
    let gradient_before = s_before - s;
    let gradient_after = s_after - s;
    let before_steeper = abs(gradient_before) >= abs(gradient_after);
    let gradient_scaled = 0.25 * max(abs(gradient_before), abs(gradient_after));
    let step = select(1.0, -1.0, before_steeper);
    let local_mean = 0.5 * (select(s_after, s_before, before_steeper) + s);

    // Step 4: the edge's ends, half a pixel towards the steeper side.
    let centre_at = vec2<f32>(p) + vec2<f32>(0.5);
    let on_edge = centre_at + across * (0.5 * step);
    var at1 = on_edge - along * QUALITY[0];
    var at2 = on_edge + along * QUALITY[0];
    var end1 = signal(bilinear(at1)) - local_mean;
    var end2 = signal(bilinear(at2)) - local_mean;
    var reached1 = abs(end1) >= gradient_scaled;
    var reached2 = abs(end2) >= gradient_scaled;
    for (var i = 1u; i < ITERATIONS && !(reached1 && reached2); i = i + 1u) {
        if !reached1 {
            at1 = at1 - along * QUALITY[i];
            end1 = signal(bilinear(at1)) - local_mean;
            reached1 = abs(end1) >= gradient_scaled;
        }
        if !reached2 {
            at2 = at2 + along * QUALITY[i];
            end2 = signal(bilinear(at2)) - local_mean;
            reached2 = abs(end2) >= gradient_scaled;
        }
    }

    // Step 5: the offset across the edge.
    let distance1 = dot(centre_at - at1, along);
    let distance2 = dot(at2 - centre_at, along);
    let nearer1 = distance1 < distance2;
    let distance = min(distance1, distance2);
    let pixel_offset = 0.5 - distance / (distance1 + distance2);
    // Only where the signal at the nearer end varies the way it does at the centre.
    let centre_smaller = s < local_mean;
    let end = select(end2, end1, nearer1);
    var offset = select(0.0, pixel_offset, (end < 0.0) != centre_smaller);
    let mean = (2.0 * (sn + ss + se + sw) + snw + sne + ssw + sse) / 12.0;
    let sub1 = clamp(abs(mean - s) / range, 0.0, 1.0);
    let sub2 = (-2.0 * sub1 + 3.0) * sub1 * sub1;
    offset = max(offset, sub2 * sub2 * SUBPIXEL_QUALITY);

    // Step 6.
    textureStore(frame_out, p, bilinear(centre_at + across * (offset * step)));
}
