// Supersampling's resolve (compute pass: cs_resolve, 8×8 workgroups): the frame was rendered at
// s times the output's width and height; each output pixel is the mean of its s × s block of
// samples — a box filter over the pixel's footprint, in linear HDR with premultiplied alpha (so
// the alpha is the covered fraction, and composites as the rest of the frame does). Each sample
// is scaled before the sum, so that samples near f32's largest value do not overflow it.
// src/render/supersample.rs builds it.

@group(0) @binding(0) var samples: texture_2d<f32>;
@group(0) @binding(1) var output: texture_storage_2d<rgba32float, write>;

@compute @workgroup_size(8, 8)
fn cs_resolve(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(output);
    if id.x >= size.x || id.y >= size.y {
        return;
    }
    let s = textureDimensions(samples).x / size.x;
    let weight = 1.0 / f32(s * s);
    var sum = vec4<f32>(0.0);
    for (var j = 0u; j < s; j = j + 1u) {
        for (var i = 0u; i < s; i = i + 1u) {
            let at = vec2<i32>(id.xy * s + vec2<u32>(i, j));
            sum = sum + textureLoad(samples, at, 0) * weight;
        }
    }
    textureStore(output, vec2<i32>(id.xy), sum);
}
