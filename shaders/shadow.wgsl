// Shadow pass: depth only, one render pass per light into one layer of the shadow-map array.
// The light's orthographic view-projection (fitted to the casters' bounding sphere, see
// src/render/shadow.rs) is bound with a dynamic offset per layer.
//
//  * vs_main (no fragment stage): the opaque casters, positions only.
//  * vs_masked + fs_masked: the casters whose material is cut out by its alpha (glTF's MASK):
//    a fragment whose alpha is below the cutoff writes no depth; and the blended ones (BLEND),
//    dithered by their alpha (`shadow_cut_out`, surface.wgsl, with the mip level of the
//    texture's footprint in the map).
//
// Prepended: surface.wgsl (vertex layout, materials and their textures).

struct LightCamera {
    view_proj: mat4x4<f32>,
};

@group(0) @binding(0) var<uniform> light_camera: LightCamera;
@group(0) @binding(1) var<storage, read> shadow_materials: array<Material>;

@vertex
fn vs_main(@location(0) position: vec3<f32>) -> @builtin(position) vec4<f32> {
    return light_camera.view_proj * vec4<f32>(position, 1.0);
}

struct MaskedIn {
    @location(0) position: vec3<f32>,
    @location(2) material: u32,
    @location(3) uv: vec2<f32>,
    @location(5) uv1: vec2<f32>,
    @location(6) color: vec4<f32>,
};

struct MaskedOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) material: u32,
    @location(1) uv: vec2<f32>,
    @location(2) uv1: vec2<f32>,
    // The vertex colour's alpha.
    @location(3) alpha: f32,
};

@vertex
fn vs_masked(v: MaskedIn) -> MaskedOut {
    var out: MaskedOut;
    out.clip = light_camera.view_proj * vec4<f32>(v.position, 1.0);
    out.material = v.material;
    out.uv = v.uv;
    out.uv1 = v.uv1;
    out.alpha = v.color.a;
    return out;
}

@fragment
fn fs_masked(in: MaskedOut, @builtin(front_facing) front: bool) {
    let tc = fragment_coordinates(in.uv, in.uv1);
    let pattern = dither_pattern(in.material, front);
    if shadow_cut_out(shadow_materials[in.material], tc, in.alpha, vec2<u32>(in.clip.xy), pattern) {
        discard;
    }
}
