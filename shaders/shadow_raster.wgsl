// Shadow maps rasterised by compute shaders (`ShadowRaster::Compute`, src/render/shadow_raster.rs):
// the same maps as shadow.wgsl's depth-only render passes, written into one storage buffer of
// u32 depths (map k's texel (x, y) at k·res² + y·res + x), with no raster pipeline involved.
//
//  * cs_clear: every texel of the frame's maps to the far plane (depth 1.0).
//  * cs_rasterize_small: one invocation per (small shadow-casting triangle, map). It transforms
//    the triangle by the map's orthographic view-projection (shadow.rs: `light_view_proj`; no
//    perspective divide, w = 1), then walks the rows of its bounding box in texel space: on each
//    row the three edge functions bound the covered span exactly, so the loop visits only texel
//    centres inside the triangle (both windings: casters are drawn without culling, as in the
//    render pass). Each covered texel gets the plane's depth at its centre plus the render
//    pass's bias (2 units of the depth's last place + 1.5 × the plane's largest slope per
//    texel) by atomicMin on the depth's bits — non-negative f32s order as their bit patterns.
//  * cs_rasterize_large: the same for the triangles that may cover many texels (a floor, a
//    wall), one workgroup per (triangle, map) whose 64 invocations share its rows and columns,
//    so one big triangle is not one invocation's long serial loop.
//  * A triangle whose material is cut out by its alpha (glTF's MASK) skips the texels where
//    the alpha at the texel centre (texture coordinates interpolated by the barycentrics, mip
//    level from their derivatives across the map) is below the cutoff, as the render pass's
//    fs_masked discards them.
//
// Prepended: surface.wgsl (materials and their textures, `cut_out`).
//
// Why: a depth-only render pass is bounded by the raster pipeline's fill rate, which on a
// compute part such as the H200 is a small part of the chip (docs/performance.md); these
// invocations run on every multiprocessor, and the clear is a plain buffer write.

struct Params {
    // Side of each map in texels.
    resolution: u32,
    // Maps this frame.
    maps: u32,
    // Shadow-casting triangles whose bounding box in a map spans at most LARGE_TEXELS
    // (src/render/shadow_raster.rs) on a side, whatever the light, and the others.
    small_triangles: u32,
    large_triangles: u32,
};

@group(0) @binding(0) var<uniform> params: Params;
// The scene's vertices as words, VERTEX_WORDS each (src/render/scene/mod.rs `Vertex`: position,
// normal, material, uv, uv1, tangent).
// As u32 words (the colour's and material's bits are no f32s: read as floats, a NaN pattern
// might not survive the load).
@group(0) @binding(1) var<storage, read> vertex_words: array<u32>;
@group(0) @binding(2) var<storage, read> indices: array<u32>;
// Map k's view-projection.
@group(0) @binding(3) var<storage, read> light_cameras: array<mat4x4<f32>>;
@group(0) @binding(4) var<storage, read_write> depths: array<atomic<u32>>;
// Shadow-casting triangles (indices into the index buffer's triangles): the small ones, then the
// large ones.
@group(0) @binding(5) var<storage, read> triangle_ids: array<u32>;
@group(0) @binding(6) var<storage, read> raster_materials: array<Material>;

// The words of a vertex (src/render/scene/mod.rs, `Vertex`): its position is the first three, its
// material the seventh, its texture coordinates the next two pairs, its colour the last two.
const VERTEX_WORDS: u32 = 17u;
const MATERIAL_WORD: u32 = 6u;
const UV_WORD: u32 = 7u;
const UV1_WORD: u32 = 9u;
// The colour: RGBA as four 16-bit unorms in two words, alpha in the second's high half.
const COLOR_BA_WORD: u32 = 16u;
// The render pass's DepthBiasState: constant 2, slope scale 1.5 (src/render/mod.rs). One unit
// of the constant is the depth's last place near its largest value (< 1): 2^-24.
const BIAS_CONSTANT: f32 = 5.9604645e-8;
const BIAS_SLOPE: f32 = 1.5;
const FAR_DEPTH_BITS: u32 = 0x3f800000u;

@compute @workgroup_size(256)
fn cs_clear(@builtin(global_invocation_id) id: vec3<u32>,
            @builtin(num_workgroups) groups: vec3<u32>) {
    let total = params.maps * params.resolution * params.resolution;
    let stride = groups.x * 256u;
    for (var i = id.x; i < total; i = i + stride) {
        atomicStore(&depths[i], FAR_DEPTH_BITS);
    }
}

fn texel_space(p: vec3<f32>, m: mat4x4<f32>, res: f32) -> vec3<f32> {
    let c = m * vec4<f32>(p, 1.0);
    // Texel space: x right, y down (as the shading pass's uv), texel centres at i + 0.5.
    return vec3<f32>((c.x * 0.5 + 0.5) * res, (0.5 - c.y * 0.5) * res, c.z);
}

fn position(i: u32) -> vec3<f32> {
    let w = VERTEX_WORDS * i;
    return bitcast<vec3<f32>>(vec3<u32>(vertex_words[w], vertex_words[w + 1u], vertex_words[w + 2u]));
}

fn vertex_alpha(i: u32) -> f32 {
    return unpack2x16unorm(vertex_words[VERTEX_WORDS * i + COLOR_BA_WORD]).y;
}

fn vertex_pair(i: u32, word: u32) -> vec2<f32> {
    let w = VERTEX_WORDS * i + word;
    return bitcast<vec2<f32>>(vec2<u32>(vertex_words[w], vertex_words[w + 1u]));
}

// Rasterises triangle `tri` into map `map`: the rows y_first + row_lane, + row_lanes, … of its
// bounding box and, on each, the covered texels x0 + col_lane, + col_lanes, … — one invocation
// takes them all (lanes 0 of 1 × 1), a workgroup of 64 splits a large triangle 8 × 8.
fn rasterize(tri: u32, map: u32, row_lane: i32, row_lanes: i32, col_lane: f32, col_lanes: f32) {
    let res = params.resolution;
    let resf = f32(res);
    let m = light_cameras[map];
    let a = texel_space(position(indices[3u * tri]), m, resf);
    let b = texel_space(position(indices[3u * tri + 1u]), m, resf);
    let c = texel_space(position(indices[3u * tri + 2u]), m, resf);
    // Twice the signed area; the edge functions are made positive inside.
    let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
    if !(abs(area) > 1e-12) {
        return;
    }
    let s = sign(area);
    // Edge i is opposite vertex i: e_i(x, y) = s·(A_i·x + B_i·y + C_i) ≥ 0 inside, and equals
    // s·area at vertex i.
    let ea = s * vec3<f32>(b.y - c.y, c.x - b.x, b.x * c.y - b.y * c.x);
    let eb = s * vec3<f32>(c.y - a.y, a.x - c.x, c.x * a.y - c.y * a.x);
    let ec = s * vec3<f32>(a.y - b.y, b.x - a.x, a.x * b.y - a.y * b.x);
    // Depth plane z = zx·x + zy·y + z0 from the barycentrics e_i / |area|.
    let inv = 1.0 / abs(area);
    let zx = (ea.x * a.z + eb.x * b.z + ec.x * c.z) * inv;
    let zy = (ea.y * a.z + eb.y * b.z + ec.y * c.z) * inv;
    let z0 = (ea.z * a.z + eb.z * b.z + ec.z * c.z) * inv;
    let bias = 2.0 * BIAS_CONSTANT + BIAS_SLOPE * max(abs(zx), abs(zy));
    let lo = min(a.xy, min(b.xy, c.xy));
    let hi = max(a.xy, max(b.xy, c.xy));
    // Texel rows and columns whose centres (i + 0.5) may lie inside.
    let y_first = i32(max(ceil(lo.y - 0.5), 0.0));
    let y_last = i32(min(floor(hi.y - 0.5), resf - 1.0));
    let x_min = max(ceil(lo.x - 0.5), 0.0);
    let x_max = min(floor(hi.x - 0.5), resf - 1.0);
    let base = map * res * res;
    // A cut-out caster: its texture coordinates as planes over the map, like the depth.
    let ia = indices[3u * tri];
    let ib = indices[3u * tri + 1u];
    let ic = indices[3u * tri + 2u];
    let material = vertex_words[VERTEX_WORDS * ia + MATERIAL_WORD];
    let masked = raster_materials[material].extra.z > 0.0;
    // Texel space has y down: a triangle counter-clockwise as the render passes see it (front
    // facing) has a negative area here.
    let pattern = dither_pattern(material, area < 0.0);
    var mat: Material;
    var uv_plane: array<vec2<f32>, 6>;
    // The vertex colours' alpha: d/dx, d/dy, the value at (0, 0).
    var alpha_plane = vec3<f32>(0.0, 0.0, 1.0);
    if masked {
        mat = raster_materials[material];
        // Per channel: d/dx, d/dy, the value at (0, 0).
        for (var channel = 0u; channel < 2u; channel = channel + 1u) {
            let word = select(UV_WORD, UV1_WORD, channel == 1u);
            let ua = vertex_pair(ia, word);
            let ub = vertex_pair(ib, word);
            let uc = vertex_pair(ic, word);
            uv_plane[3u * channel] = (ea.x * ua + eb.x * ub + ec.x * uc) * inv;
            uv_plane[3u * channel + 1u] = (ea.y * ua + eb.y * ub + ec.y * uc) * inv;
            uv_plane[3u * channel + 2u] = (ea.z * ua + eb.z * ub + ec.z * uc) * inv;
        }
        let aa = vertex_alpha(ia);
        let ab = vertex_alpha(ib);
        let ac = vertex_alpha(ic);
        alpha_plane = vec3<f32>(ea.x * aa + eb.x * ab + ec.x * ac, ea.y * aa + eb.y * ab + ec.y * ac,
                                ea.z * aa + eb.z * ab + ec.z * ac) * inv;
    }
    for (var y = y_first + row_lane; y <= y_last; y = y + row_lanes) {
        let yc = f32(y) + 0.5;
        // Each edge e = A·x + (B·yc + C) ≥ 0 bounds x on one side (or excludes the row).
        var x0 = x_min;
        var x1 = x_max;
        for (var k = 0; k < 3; k = k + 1) {
            var e = ea;
            if k == 1 {
                e = eb;
            } else if k == 2 {
                e = ec;
            }
            let rest = e.y * yc + e.z;
            if e.x > 0.0 {
                x0 = max(x0, ceil(-rest / e.x - 0.5));
            } else if e.x < 0.0 {
                x1 = min(x1, floor(-rest / e.x - 0.5));
            } else if rest < 0.0 {
                x1 = -1.0;
            }
        }
        let row = base + u32(y) * res;
        for (var x = x0 + col_lane; x <= x1; x = x + col_lanes) {
            if masked {
                let xc = x + 0.5;
                let tc = TextureCoordinates(
                    uv_plane[0] * xc + uv_plane[1] * yc + uv_plane[2], uv_plane[0], uv_plane[1],
                    uv_plane[3] * xc + uv_plane[4] * yc + uv_plane[5], uv_plane[3], uv_plane[4]);
                let texel = vec2<u32>(u32(x), u32(y));
                let alpha = dot(alpha_plane, vec3<f32>(xc, yc, 1.0));
                if shadow_cut_out(mat, tc, alpha, texel, pattern) {
                    continue;
                }
            }
            let z = clamp(zx * (x + 0.5) + zy * yc + z0 + bias, 0.0, 1.0);
            atomicMin(&depths[row + u32(x)], bitcast<u32>(z));
        }
    }
}

// The small triangles (`triangle_ids[0 .. small_triangles]`): one invocation per (triangle,
// map).
@compute @workgroup_size(64)
fn cs_rasterize_small(@builtin(global_invocation_id) id: vec3<u32>,
                      @builtin(num_workgroups) groups: vec3<u32>) {
    let map = id.y;
    if map >= params.maps {
        return;
    }
    for (var k = id.x; k < params.small_triangles; k = k + groups.x * 64u) {
        rasterize(triangle_ids[k], map, 0, 1, 0.0, 1.0);
    }
}

// The large triangles (the ids after the small ones): one workgroup per (triangle, map), its 64
// invocations on an 8 × 8 lattice of rows and columns.
@compute @workgroup_size(64)
fn cs_rasterize_large(@builtin(workgroup_id) group: vec3<u32>,
                      @builtin(local_invocation_index) lane: u32,
                      @builtin(num_workgroups) groups: vec3<u32>) {
    let map = group.y;
    if map >= params.maps {
        return;
    }
    for (var k = group.x; k < params.large_triangles; k = k + groups.x) {
        rasterize(triangle_ids[params.small_triangles + k], map, i32(lane / 8u), 8,
                  f32(lane % 8u), 8.0);
    }
}
