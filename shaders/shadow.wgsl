// Shadow pass: depth only, one render pass per light into one layer of the shadow-map array.
// The light's orthographic view-projection (fitted to the casters' bounding sphere, see
// src/render/shadow.rs) is bound with a dynamic offset per layer.

struct LightCamera {
    view_proj: mat4x4<f32>,
};

@group(0) @binding(0) var<uniform> light_camera: LightCamera;

@vertex
fn vs_main(@location(0) position: vec3<f32>) -> @builtin(position) vec4<f32> {
    return light_camera.view_proj * vec4<f32>(position, 1.0);
}
