// Main passes: Lambertian diffuse + GGX specular (metallic-roughness) under N directional lights,
// each with its own PCF-filtered shadow map layer, in linear HDR, shaded deferred:
//  * G-buffer (render pass: vs_main + fs_gbuffer): the scene rasterised into four Rgba32Float
//    targets: world position with material index + 1 (0: no surface), the shading normal with
//    the roughness, the base colour with the metallic, and the emission with the occlusion
//    (factors times textures); where the scene needs it (`LAYERED_GBUFFER`,
//    fs_gbuffer_layered), one Rgba32Uint target of 16-bit fields: the dielectric Fresnel
//    terms, the clear coat's strength and roughness, and its normal (`LayeredGBuffer`).
//  * Shading (compute pass: cs_shade, 8×8 workgroups): one invocation per pixel reads the
//    G-buffer, sums the lights and writes the frame (rgba32float storage texture).
//  * Blended surfaces (glTF's alpha mode BLEND; render pass: vs_main + fs_blended), after the
//    shading: drawn over the frame back to front (the renderer sorts their triangles),
//    depth-tested against the G-buffer pass's depth without writing it, each fragment shaded
//    as cs_shade shades a pixel and premultiplied by its alpha for the over operator.
// So every pixel is shaded once whatever the overdraw, and the light loop runs as compute work,
// on every multiprocessor of a GPU (on a compute part such as the H200 the graphics pipeline has
// a small part of the chip; docs/performance.md).
//
// Per-pixel light culling (src/render/mod.rs documents the scheme and its tolerance):
//  * n·l ≤ 0: the light adds nothing; with culling on it costs no shading and no shadow lookup.
//  * glossy pixels: lights inside a cone around the mirror direction (where the GGX lobe, widened
//    by the light's own angular radius, is above ~1% of its peak) get the full path, a PCF_TAPS-tap Poisson-disk PCF; the
//    others get the cheap path, 4 bilinear (2×2) comparison taps.
// With culling off every light takes the full path (and the shadow lookup is made even where
// n·l ≤ 0, the plain loop a renderer without culling runs).
//
// Prepended: surface.wgsl (vertex layout, materials, the shaded point's set-up) and
// shadow_lookup.wgsl (lights, PCF shadow lookup).
//
// The ground's material may be a shadow catcher: it then outputs premultiplied RGBA
// (0, 0, 0, α) with α = 1 − E_shadowed / E_unshadowed, to darken the camera image beneath.

struct Globals {
    view_proj: mat4x4<f32>,
    // The viewer: the eye (w = 1) or, for an orthographic camera, the direction towards it (w = 0).
    viewer: vec4<f32>,
    light_count: u32,
    culling: u32,
    shadows: u32,
    // Where the maps are: 0 the depth texture array (render passes), 1 the compute
    // rasteriser's buffer (shadow_raster.wgsl).
    shadow_source: u32,
    // x: normal offset (world units), y: depth bias (NDC depth), z: map side in texels,
    // w: unused.
    shadow_params: vec4<f32>,
};

@group(0) @binding(0) var<uniform> globals: Globals;
@group(0) @binding(1) var<storage, read> lights: array<Light>;
@group(0) @binding(2) var<storage, read> materials: array<Material>;
@group(0) @binding(3) var shadow_maps: texture_depth_2d_array;
@group(0) @binding(4) var shadow_sampler: sampler_comparison;
// The compute rasteriser's maps: map k's texel (x, y) at k·res² + y·res + x, f32 depth bits.
@group(0) @binding(5) var<storage, read> shadow_depths: array<u32>;
@group(1) @binding(0) var gbuffer_position: texture_2d<f32>;
@group(1) @binding(1) var gbuffer_normal: texture_2d<f32>;
@group(1) @binding(2) var frame: texture_storage_2d<rgba32float, write>;
@group(1) @binding(3) var gbuffer_surface: texture_2d<f32>;
@group(1) @binding(4) var gbuffer_emission: texture_2d<f32>;
@group(1) @binding(5) var gbuffer_layers: texture_2d<u32>;

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    return surface_vertex(globals.view_proj, v);
}

fn shadow_state() -> ShadowState {
    return ShadowState(globals.shadows != 0u, globals.shadow_source, globals.shadow_params);
}

// The half vector of v and l. Opposite v and l have none (normalize(0) is NaN, and one NaN
// pixel blackened the image's sum): n stands in.
fn half_vector(v: vec3<f32>, l: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let s = v + l;
    let len2 = dot(s, s);
    if len2 < 1e-12 {
        return n;
    }
    return s * inverseSqrt(len2);
}

// GGX normal distribution (of roughness `alpha_d`, the surface's widened by the light's size)
// × height-correlated Smith visibility (of the surface's own `alpha`: a light's size blurs
// where the half vector falls, not the surface's masking) × Schlick Fresnel. The cosines are
// clamped to [0, 1]: v·h rounds to just above 1 where the light lies along the view ray, and
// pow(1 − v·h, 5) of a negative base is NaN.
// `h`: the half vector of v and l (`half_vector`).
fn ggx_specular(n: vec3<f32>, v: vec3<f32>, l: vec3<f32>, h: vec3<f32>, alpha_d: f32, alpha: f32,
                f0: vec3<f32>, f90: f32) -> vec3<f32> {
    let vdh = clamp(dot(v, h), 0.0, 1.0);
    let f = f0 + (vec3<f32>(f90) - f0) * pow(1.0 - vdh, 5.0);
    return ggx_lobe(n, v, l, h, alpha_d, alpha) * f;
}

// The GGX lobe without its Fresnel factor: D (of roughness `alpha_d`) × the height-correlated
// Smith visibility (of `alpha`); `h` the half vector of v and l.
fn ggx_lobe(n: vec3<f32>, v: vec3<f32>, l: vec3<f32>, h: vec3<f32>, alpha_d: f32, alpha: f32) -> f32 {
    let ndl = clamp(dot(n, l), 0.0, 1.0);
    let ndv = clamp(dot(n, v), 1e-4, 1.0);
    let ndh = clamp(dot(n, h), 0.0, 1.0);
    let ad2 = alpha_d * alpha_d;
    let dd = ndh * ndh * (ad2 - 1.0) + 1.0;
    let d = ad2 / (PI * dd * dd);
    let a2 = alpha * alpha;
    let vis = 0.5 / max(ndl * sqrt(ndv * ndv * (1.0 - a2) + a2) + ndv * sqrt(ndl * ndl * (1.0 - a2) + a2), 1e-6);
    return d * vis;
}

// Whether the G-buffer has its fifth target, `layers` (`fs_gbuffer_layered`), which the scene
// needs where a material's Fresnel terms or clear coat vary over its surface (their textures),
// or a clear coat lies over a normal texture (the coat keeps the interpolated normal, which
// the G-buffer does not otherwise hold). Without it (`fs_gbuffer`) `cs_shade` takes them from
// the material's factors. Set by src/render/mod.rs.
override LAYERED_GBUFFER: bool = true;

struct GBuffer {
    // xyz: world position; w: material index + 1 (cleared to 0 where no surface is).
    @location(0) position: vec4<f32>,
    // xyz: the shading normal (the interpolated vertex normal, turned by the normal texture);
    // w: roughness.
    @location(1) normal: vec4<f32>,
    // rgb: base colour; a: metallic.
    @location(2) surface: vec4<f32>,
    // rgb: emitted radiance; a: occlusion.
    @location(3) emission: vec4<f32>,
};

// `GBuffer` and its fifth target.
struct LayeredGBuffer {
    @location(0) position: vec4<f32>,
    @location(1) normal: vec4<f32>,
    @location(2) surface: vec4<f32>,
    @location(3) emission: vec4<f32>,
    // The layers over the base, 16 bits a value (`pack_layers`): the dielectric F0 (rgb) and
    // F90, the clear coat's strength and roughness (unorm), its unit normal (octahedral,
    // snorm).
    @location(4) layers: vec4<u32>,
};

// A unit vector on the octahedron folded into [−1, 1]² (Cigolle et al. 2014).
fn octahedral_encode(n: vec3<f32>) -> vec2<f32> {
    let p = n.xy / (abs(n.x) + abs(n.y) + abs(n.z));
    if n.z >= 0.0 {
        return p;
    }
    return (vec2<f32>(1.0) - abs(p.yx)) * select(vec2<f32>(-1.0), vec2<f32>(1.0), p >= vec2<f32>(0.0));
}

// The unit vector of `octahedral_encode`'s `e`.
fn octahedral_decode(e: vec2<f32>) -> vec3<f32> {
    var n = vec3<f32>(e, 1.0 - abs(e.x) - abs(e.y));
    let t = max(-n.z, 0.0);
    n.x = n.x + select(t, -t, n.x >= 0.0);
    n.y = n.y + select(t, -t, n.y >= 0.0);
    return normalize(n);
}

// The G-buffer's `layers` of surface parameters `p`.
fn pack_layers(p: SurfaceParams) -> vec4<u32> {
    let f = clamp(p.specular, vec4<f32>(0.0), vec4<f32>(1.0));
    var coat_normal = vec2<f32>(0.0);
    if p.coat > 0.0 && dot(p.coat_normal, p.coat_normal) > 1e-12 {
        coat_normal = octahedral_encode(normalize(p.coat_normal));
    }
    return vec4<u32>(pack2x16unorm(f.xy), pack2x16unorm(f.zw),
                     pack2x16unorm(clamp(vec2<f32>(p.coat, p.coat_roughness), vec2<f32>(0.0), vec2<f32>(1.0))),
                     pack2x16snorm(coat_normal));
}

// The layers of a material without their textures, as `pack_layers` would give them (where
// `LAYERED_GBUFFER` is false): the factors, and the coat on the shading normal `normal`, which
// is then the interpolated one.
// Field by field: copying the whole Material costs on CPU rasterisers.
fn material_layers(material: u32, normal: vec3<f32>, p: ptr<function, SurfaceParams>) {
    let specular = materials[material].specular;
    let coat = materials[material].coat;
    (*p).specular = vec4<f32>(min(specular.rgb, vec3<f32>(1.0)) * specular.w, specular.w);
    (*p).coat = coat.x;
    (*p).coat_roughness = coat.y;
    (*p).coat_normal = normal;
}

// `pack_layers` undone into `p`; a coat without a normal takes `normal`.
fn unpack_layers(layers: vec4<u32>, normal: vec3<f32>, p: ptr<function, SurfaceParams>) {
    (*p).specular = vec4<f32>(unpack2x16unorm(layers.x), unpack2x16unorm(layers.y));
    let coat = unpack2x16unorm(layers.z);
    (*p).coat = coat.x;
    (*p).coat_roughness = coat.y;
    (*p).coat_normal = normal;
    if coat.x > 0.0 {
        (*p).coat_normal = octahedral_decode(unpack2x16snorm(layers.w));
    }
}

// A fragment's surface parameters for the G-buffer; cut-out and hidden back faces discarded.
fn gbuffer_params(in: VertexOut, front: bool) -> SurfaceParams {
    let mat = materials[in.material];
    let tc = fragment_coordinates(in.uv, in.uv1);
    if !fragment_drawn(mat, front, tc, in.color.a) {
        discard;
    }
    return surface_params(mat, tc, in.normal, in.tangent, in.color, front);
}

// The four targets of a fragment of `in` with parameters `p`.
fn gbuffer_targets(in: VertexOut, p: SurfaceParams) -> GBuffer {
    var out: GBuffer;
    out.position = vec4<f32>(in.world, f32(in.material) + 1.0);
    out.normal = vec4<f32>(p.normal, p.roughness);
    out.surface = vec4<f32>(p.base_color, p.metallic);
    out.emission = vec4<f32>(p.emission, p.occlusion);
    return out;
}

@fragment
fn fs_gbuffer(in: VertexOut, @builtin(front_facing) front: bool) -> GBuffer {
    return gbuffer_targets(in, gbuffer_params(in, front));
}

@fragment
fn fs_gbuffer_layered(in: VertexOut, @builtin(front_facing) front: bool) -> LayeredGBuffer {
    let p = gbuffer_params(in, front);
    let g = gbuffer_targets(in, p);
    return LayeredGBuffer(g.position, g.normal, g.surface, g.emission, pack_layers(p));
}

@fragment
fn fs_blended(in: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    let p = blended_params(materials[in.material], in, front);
    return premultiplied(shade_point(in.world, p.normal, in.material, p).rgb, p.alpha);
}

@compute @workgroup_size(8, 8)
fn cs_shade(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(frame);
    if id.x >= size.x || id.y >= size.y {
        return;
    }
    let texel = vec2<i32>(id.xy);
    let g = textureLoad(gbuffer_position, texel, 0);
    if g.w < 0.5 {
        textureStore(frame, texel, vec4<f32>(0.0));
        return;
    }
    let normal = textureLoad(gbuffer_normal, texel, 0);
    let surface = textureLoad(gbuffer_surface, texel, 0);
    let emission = textureLoad(gbuffer_emission, texel, 0);
    var p: SurfaceParams;
    p.base_color = surface.rgb;
    p.roughness = normal.w;
    p.metallic = surface.a;
    p.normal = normal.xyz;
    p.emission = emission.rgb;
    p.occlusion = emission.a;
    p.alpha = 1.0;
    let material = u32(g.w) - 1u;
    if LAYERED_GBUFFER {
        unpack_layers(textureLoad(gbuffer_layers, texel, 0), normal.xyz, &p);
    } else {
        material_layers(material, normal.xyz, &p);
    }
    textureStore(frame, texel, shade_point(g.xyz, normal.xyz, material, p));
}

// The shaded colour (premultiplied RGBA) of the surface point `world` with interpolated normal
// `normal`, material `material` and its parameters there `p`.
fn shade_point(world: vec3<f32>, normal: vec3<f32>, material: u32, p: SurfaceParams) -> vec4<f32> {
    if is_unlit(materials[material].params.w) {
        return vec4<f32>(p.base_color, 1.0);
    }
    let s = surface_at(world, normal, p, materials[material].params.w, globals.viewer);
    let n = s.n;
    let v = s.v;
    let alpha = s.alpha;
    let diffuse = s.diffuse;
    let f0 = s.f0;
    let has_specular = s.has_specular;
    let catcher = s.catcher;
    let culling = globals.culling != 0u;
    // A sheen (KHR_materials_sheen) over the base, beneath any clear coat. Its albedo table
    // is read only where there is one (copying it costs on CPU rasterisers).
    var sheen = Sheen(vec3<f32>(0.0), 0.0, 1.0);
    if materials[material].sheen.w > 0.0 {
        sheen = sheen_at(materials[material].sheen, materials[material].sheen_albedo, dot(n, v));
    }

    var radiance = vec3<f32>(0.0);
    var e_lit = 0.0;
    var e_all = 0.0;
    for (var i = 0u; i < globals.light_count; i = i + 1u) {
        // Field by field: copying the whole Light (with its matrix) costs on CPU rasterisers.
        let dir = lights[i].dir;
        let l = dir.xyz;
        let ndl_raw = dot(n, l);
        // A clear coat with a normal of its own may face a light the base turns from.
        let ndl_coat = select(0.0, max(dot(s.n_coat, l), 0.0), s.coat > 0.0);
        if culling && ndl_raw <= 0.0 && ndl_coat <= 0.0 {
            continue;
        }
        let rgb = lights[i].rgb;
        let ndl = max(ndl_raw, 0.0);
        let rho = dir.w;
        // The light's own size widens the lobe (after Karis 2013): its light spread over a cone
        // of half-angle ρ moves the half vector by up to ρ/2. The widened lobe is GGX's own
        // distribution and so keeps the energy; Karis's (α/α')² belongs to his representative-
        // point method, which keeps the narrow lobe, and here took that much energy away.
        let alpha_l = min(alpha + 0.5 * rho, 1.0);
        let coat_alpha_l = min(s.coat_alpha + 0.5 * rho, 1.0);
        let glossy = has_specular || s.coat > 0.0;
        // The half vector, once per light, where a lobe or the sheen needs it.
        var h = n;
        if glossy || sheen.alpha > 0.0 {
            h = half_vector(v, l, n);
        }
        var full = true;
        if culling && glossy {
            // The GGX lobe is below ~1% of its peak beyond tan θ_h = 3α′ (θ_h: the half vector's
            // angle to n), i.e. outside a cone of half-angle ≈ 2θ_h around the mirror direction.
            // cos θ_h ≥ 1/√(1 + 9α′²) needs no transcendental per light. A clear coat's lobe
            // counts too.
            let nh = max(dot(n, h), 0.0);
            full = has_specular && nh * nh * (1.0 + 9.0 * alpha_l * alpha_l) >= 1.0;
            if s.coat > 0.0 {
                let ch = max(dot(s.n_coat, h), 0.0);
                full = full || ch * ch * (1.0 + 9.0 * coat_alpha_l * coat_alpha_l) >= 1.0;
            }
        }
        let vis = visibility(i, world, n, l, i32(rgb.w), full);
        let e = rgb.rgb * ndl;
        var brdf = diffuse;
        if has_specular {
            brdf = brdf + ggx_specular(n, v, l, h, alpha_l, alpha, f0, s.f90);
        }
        if sheen.alpha > 0.0 {
            // The sheen's fibres take their albedo's share from the base beneath them.
            let fibres = sheen_brdf(sheen.alpha, max(dot(n, h), 0.0), dot(n, v), ndl);
            brdf = brdf * sheen.beneath + sheen.colour * fibres;
        }
        var reflected = brdf * ndl;
        if s.coat > 0.0 {
            // The clear coat (glTF's KHR_materials_clearcoat), on its own normal: its Fresnel
            // reflectance takes that fraction of the light from the layer beneath.
            let fc = s.coat * coat_fresnel(dot(v, h));
            let coat_lobe = ggx_lobe(s.n_coat, v, l, h, coat_alpha_l, s.coat_alpha);
            reflected = reflected * (1.0 - fc) + vec3<f32>(fc * coat_lobe * ndl_coat);
        }
        radiance = radiance + reflected * rgb.rgb * vis;
        let lum = dot(e, vec3<f32>(0.2126, 0.7152, 0.0722));
        e_lit = e_lit + lum * vis;
        e_all = e_all + lum;
    }
    if catcher {
        var shadow = 0.0;
        if e_all > 0.0 {
            shadow = clamp(1.0 - e_lit / e_all, 0.0, 1.0);
        }
        return vec4<f32>(0.0, 0.0, 0.0, shadow);
    }
    // The occlusion texture darkens the light from the environment (the lights), not the
    // surface's own emission; a clear coat reflects its Fresnel share of the emission away.
    let emission = p.emission * (1.0 - s.coat * coat_fresnel(dot(s.n_coat, v)));
    return vec4<f32>(radiance * p.occlusion + emission, 1.0);
}
