// Shared by the main passes (shade.wgsl) and the ASG pass (asg.wgsl): the vertex layout, the
// material table and the metallic-roughness set-up of a shaded point. Not a pipeline of its own:
// src/render prepends it to each of those files (`render::SHADERS` lists the composed sources).
// Each pass declares its own `Globals` and bindings and calls `surface_vertex` from `vs_main`.

const PI: f32 = 3.14159265358979;
const FLAG_CATCHER: u32 = 1u;

struct Material {
    base_color: vec4<f32>,
    // x: roughness, y: metallic, z: specular level, w: flags (bit 0: shadow catcher).
    params: vec4<f32>,
};

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) material: u32,
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) @interpolate(flat) material: u32,
};

// World-space geometry is passed through; only the clip position is transformed.
fn surface_vertex(view_proj: mat4x4<f32>, v: VertexIn) -> VertexOut {
    var out: VertexOut;
    out.clip = view_proj * vec4<f32>(v.position, 1.0);
    out.world = v.position;
    out.normal = v.normal;
    out.material = v.material;
    return out;
}

// A shaded point: unit normal n, unit direction to the camera v, GGX α = roughness² (floored),
// Lambertian albedo/π and specular f0 (dielectric 0.16·level², or the base colour for metals).
struct Surface {
    n: vec3<f32>,
    v: vec3<f32>,
    alpha: f32,
    diffuse: vec3<f32>,
    f0: vec3<f32>,
    has_specular: bool,
    catcher: bool,
};

// `world`: the point; `normal`: the interpolated vertex normal (any length).
fn surface_at(world: vec3<f32>, normal: vec3<f32>, mat: Material, camera_pos: vec3<f32>) -> Surface {
    var s: Surface;
    s.n = normalize(normal);
    s.v = normalize(camera_pos - world);
    let roughness = clamp(mat.params.x, 0.0, 1.0);
    let metallic = clamp(mat.params.y, 0.0, 1.0);
    let spec_level = mat.params.z;
    s.alpha = max(roughness * roughness, 0.002);
    s.diffuse = mat.base_color.rgb * (1.0 - metallic) / PI;
    s.f0 = mix(vec3<f32>(0.16 * spec_level * spec_level), mat.base_color.rgb, metallic);
    s.has_specular = any(s.f0 > vec3<f32>(0.0));
    s.catcher = (u32(mat.params.w) & FLAG_CATCHER) != 0u;
    return s;
}
