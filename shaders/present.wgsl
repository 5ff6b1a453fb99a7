// Present pass (windowed mode): draws the linear HDR frame (rgba32float, premultiplied alpha)
// to the window with a fullscreen triangle: exposure, Narkowicz's ACES fit, composited over
// black. The surface format is sRGB, so the hardware applies the transfer function.

struct Params {
    // x: exposure; y, z: source size in pixels; w: unused.
    values: vec4<f32>,
};

@group(0) @binding(0) var frame: texture_2d<f32>;
@group(0) @binding(1) var<uniform> params: Params;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) uv: vec2<f32>,
};

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> VertexOut {
    // (0,0), (2,0), (0,2) in uv: one triangle covering the screen.
    let uv = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    var out: VertexOut;
    out.clip = vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, 0.0, 1.0);
    out.uv = uv;
    return out;
}

// Narkowicz's ACES fit, its input held at 1e4 (where it is 1 already): past about 1e19 the
// products overflow to inf/inf = NaN (src/render/output.rs does the same).
fn aces(v: vec3<f32>) -> vec3<f32> {
    let x = min(v, vec3<f32>(1.0e4));
    return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), vec3<f32>(0.0), vec3<f32>(1.0));
}

@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    let size = params.values.yz;
    let p = vec2<i32>(clamp(in.uv * size, vec2<f32>(0.0), size - vec2<f32>(1.0)));
    let c = textureLoad(frame, p, 0);
    return vec4<f32>(aces(max(c.rgb, vec3<f32>(0.0)) * params.values.x), 1.0);
}
