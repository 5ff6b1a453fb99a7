// Shared by the main passes (shade.wgsl), the ASG pass (asg.wgsl) and the shadow passes
// (shadow.wgsl, shadow_raster.wgsl, for the cut-out casters' alpha): the vertex layout, the
// material table and its textures, their sampling (`sample_slot`, `cut_out`), and the
// metallic-roughness set-up of a shaded point. Not a pipeline of its own: src/render prepends
// it to each of those files (`render::SHADERS` lists the composed sources). Each pass declares
// its own `Globals` and bindings; the surface passes call `surface_vertex` from `vs_main`.

const PI: f32 = 3.14159265358979;
const FLAG_CATCHER: u32 = 1u;
const FLAG_DOUBLE_SIDED: u32 = 2u;
const FLAG_UNLIT: u32 = 4u;

// A material's texture slots (src/render/textures.rs, `texture_slots`).
const TEX_BASE_COLOR: u32 = 0u;
const TEX_METALLIC_ROUGHNESS: u32 = 1u;
const TEX_NORMAL: u32 = 2u;
const TEX_OCCLUSION: u32 = 3u;
const TEX_EMISSIVE: u32 = 4u;
const TEX_SPECULAR: u32 = 5u;
const TEX_SPECULAR_COLOR: u32 = 6u;
const TEX_CLEARCOAT: u32 = 7u;
const TEX_CLEARCOAT_ROUGHNESS: u32 = 8u;
const TEX_CLEARCOAT_NORMAL: u32 = 9u;

struct Material {
    // rgb: base colour; a: its alpha.
    base_color: vec4<f32>,
    // x: roughness, y: metallic, z: unused, w: flags (bit 0: shadow catcher, bit 1:
    // double-sided, bit 2: unlit).
    params: vec4<f32>,
    // Slot k's layer at layers[k / 4][k % 4] (negative: none): of the base-colour array for
    // the base-colour, emissive and specular-colour slots, of the data array for the others.
    // src/render/textures.rs, `MaterialLayers`.
    layers: array<vec4<f32>, 3>,
    // x, y: the wrap modes, slot k's at bits 4(k % 8)..4(k % 8) + 4 of word k / 8, as u + 4·v
    // (0 repeat, 1 clamp to edge, 2 mirrored repeat); z: bit k set, slot k reads the second
    // texture coordinates; w: unused.
    texture_modes: vec4<u32>,
    // x: the normal texture's scale; y: the occlusion texture's strength; z: the alpha cutoff,
    // below which the surface casts no shadow and (glTF's MASK) is not drawn: MASK's cutoff,
    // negative for an opaque material, positive (unused) for BLEND, whose surfaces the blended
    // passes draw without testing it; w: 1 for BLEND (its shadow dithered by its alpha:
    // `shadow_cut_out`), else 0.
    extra: vec4<f32>,
    // rgb: emitted radiance, times the emissive texture; w: unused.
    emission: vec4<f32>,
    // The texture-coordinate transforms (KHR_texture_transform) of the slots, two rows each:
    // slot k's image is read at (dot(row0.xyz, (u, v, 1)), dot(row1.xyz, (u, v, 1))) with
    // row0 = uv_transforms[2k], row1 = uv_transforms[2k + 1].
    uv_transforms: array<vec4<f32>, 20>,
    // rgb: the dielectric reflectance at normal incidence before its tint texture and clamp,
    // 0.16 · level² · tint; w: the specular strength (glTF's KHR_materials_ior and
    // KHR_materials_specular): F0 = min(rgb · tint texture, 1) · strength, F90 = strength,
    // the strength times the specular texture's A (`surface_params`).
    specular: vec4<f32>,
    // x: the clear coat's strength (KHR_materials_clearcoat; 0: none); y: its roughness;
    // z: the scale of its normal texture; w: unused.
    coat: vec4<f32>,
    // rgb: the sheen's colour (KHR_materials_sheen); w: its distribution's α, 0 for none.
    sheen: vec4<f32>,
    // The sheen's directional albedo E(n·v) at n·v = k/15, k = 0…15: sheen_albedo[k / 4][k % 4]
    // (src/render/sheen.rs, `albedo_table`).
    sheen_albedo: array<vec4<f32>, 4>,
};

// The materials' textures (src/render/textures.rs): sRGB colours (base colours, emission,
// specular tints), and linear data (metallic-roughness: roughness in G, metallic in B;
// tangent-space normals; occlusion in R; specular strength in A; clear coat in R, its
// roughness in G), one layer per image, all layers of one square side with full mip chains.
// The sampler repeats; clamping and mirroring are done by `wrap_coordinate`. Bound by the
// fragment passes (G-buffer, ASG) only.
@group(2) @binding(0) var base_color_textures: texture_2d_array<f32>;
@group(2) @binding(1) var data_textures: texture_2d_array<f32>;
@group(2) @binding(2) var texture_sampler: sampler;

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) material: u32,
    @location(3) uv: vec2<f32>,
    // xyz: tangent along increasing u; w: handedness (bitangent = cross(normal, tangent) · w).
    // Zero without a normal texture.
    @location(4) tangent: vec4<f32>,
    // The second texture coordinates (zero where the material has no second set).
    @location(5) uv1: vec2<f32>,
    // Linear RGBA multiplying the base colour and its alpha (glTF's COLOR_0; white without).
    @location(6) color: vec4<f32>,
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) @interpolate(flat) material: u32,
    @location(3) uv: vec2<f32>,
    @location(4) tangent: vec4<f32>,
    @location(5) uv1: vec2<f32>,
    @location(6) color: vec4<f32>,
};

// World-space geometry is passed through; only the clip position is transformed.
fn surface_vertex(view_proj: mat4x4<f32>, v: VertexIn) -> VertexOut {
    var out: VertexOut;
    out.clip = view_proj * vec4<f32>(v.position, 1.0);
    out.world = v.position;
    out.normal = v.normal;
    out.material = v.material;
    out.uv = v.uv;
    out.uv1 = v.uv1;
    out.color = v.color;
    out.tangent = v.tangent;
    return out;
}

// A material's parameters at a point: its factors times its textures, and the shading normal.
struct SurfaceParams {
    base_color: vec3<f32>,
    // The base colour's alpha (the blended passes' coverage).
    alpha: f32,
    roughness: f32,
    metallic: f32,
    // The interpolated normal, turned by the normal texture where there is one (any length).
    normal: vec3<f32>,
    // The fraction of the environment's light that reaches the point (the occlusion texture
    // at its strength; 1 without one).
    occlusion: f32,
    // Emitted radiance.
    emission: vec3<f32>,
    // The dielectric Fresnel reflectance at normal (rgb) and grazing (w) incidence.
    specular: vec4<f32>,
    // The clear coat's strength (0: none) and roughness.
    coat: f32,
    coat_roughness: f32,
    // The clear coat's normal (any length): the interpolated one, turned by the coat's own
    // normal texture where there is one.
    coat_normal: vec3<f32>,
};

// A texture coordinate wrapped by `mode` for a layer of `texels` a side, for the repeating
// sampler: clamping and mirroring stop at the edge texels' centres, so that bilinear filtering
// does not reach around to the opposite edge (at the full-resolution level).
fn wrap_coordinate(t: f32, mode: u32, texels: f32) -> f32 {
    let edge = 0.5 / texels;
    if mode == 1u {
        return clamp(t, edge, 1.0 - edge);
    }
    if mode == 2u {
        let m = t - 2.0 * floor(t * 0.5);
        return clamp(select(m, 2.0 - m, m > 1.0), edge, 1.0 - edge);
    }
    return t;
}

// Slot `k`'s layer (negative: none).
fn texture_layer(mat: Material, k: u32) -> f32 {
    return mat.layers[k / 4u][k % 4u];
}

// A point's texture coordinates, both sets, with their screen derivatives.
struct TextureCoordinates {
    uv0: vec2<f32>,
    ddx0: vec2<f32>,
    ddy0: vec2<f32>,
    uv1: vec2<f32>,
    ddx1: vec2<f32>,
    ddy1: vec2<f32>,
};

// Slot `k`'s texel at its texture coordinates in `tc` (the set its channel bit picks): its
// transform applied to them and their derivatives, wrapped by its modes, read from the
// base-colour array (`srgb`) or the data array with explicit gradients. The slot must have a
// layer.
fn sample_slot(mat: Material, k: u32, srgb: bool, tc: TextureCoordinates) -> vec4<f32> {
    let second = ((mat.texture_modes.z >> k) & 1u) == 1u;
    let uv = select(tc.uv0, tc.uv1, second);
    let ddx = select(tc.ddx0, tc.ddx1, second);
    let ddy = select(tc.ddy0, tc.ddy1, second);
    let r0 = mat.uv_transforms[2u * k];
    let r1 = mat.uv_transforms[2u * k + 1u];
    let t = vec2<f32>(dot(r0.xy, uv) + r0.z, dot(r1.xy, uv) + r1.z);
    let tdx = vec2<f32>(dot(r0.xy, ddx), dot(r1.xy, ddx));
    let tdy = vec2<f32>(dot(r0.xy, ddy), dot(r1.xy, ddy));
    let mode = (mat.texture_modes[k / 8u] >> (4u * (k % 8u))) & 15u;
    let layer = i32(texture_layer(mat, k));
    if srgb {
        let texels = f32(textureDimensions(base_color_textures).x);
        let st = vec2<f32>(wrap_coordinate(t.x, mode % 4u, texels), wrap_coordinate(t.y, mode / 4u, texels));
        return textureSampleGrad(base_color_textures, texture_sampler, st, layer, tdx, tdy);
    }
    let texels = f32(textureDimensions(data_textures).x);
    let st = vec2<f32>(wrap_coordinate(t.x, mode % 4u, texels), wrap_coordinate(t.y, mode / 4u, texels));
    return textureSampleGrad(data_textures, texture_sampler, st, layer, tdx, tdy);
}

// A fragment's texture coordinates with their screen derivatives. Fragment stages only, called
// outside any branch (the derivatives need uniform control flow); the samples use them
// explicitly so that they may sit inside the per-material branches.
fn fragment_coordinates(uv: vec2<f32>, uv1: vec2<f32>) -> TextureCoordinates {
    return TextureCoordinates(uv, dpdx(uv), dpdy(uv), uv1, dpdx(uv1), dpdy(uv1));
}

// Whether a fragment is drawn: not where a single-sided material is seen from behind
// (`side_drawn`), nor where it is cut out (`cut_out`, with the vertex colour's alpha
// `vertex_alpha`).
fn fragment_drawn(mat: Material, front: bool, tc: TextureCoordinates, vertex_alpha: f32) -> bool {
    return side_drawn(mat, front) && !cut_out(mat, tc, vertex_alpha);
}

// Whether the side of the surface the fragment shows is drawn: the front (`front`: wound
// counter-clockwise on screen) always, the back only for a double-sided material.
fn side_drawn(mat: Material, front: bool) -> bool {
    return front || (u32(mat.params.w) & FLAG_DOUBLE_SIDED) != 0u;
}

// The material's alpha at `tc`: the factor's times the base-colour texture's times the vertex
// colour's `vertex_alpha`.
fn surface_alpha(mat: Material, tc: TextureCoordinates, vertex_alpha: f32) -> f32 {
    var alpha = mat.base_color.a * vertex_alpha;
    if texture_layer(mat, TEX_BASE_COLOR) >= 0.0 {
        alpha = alpha * sample_slot(mat, TEX_BASE_COLOR, true, tc).a;
    }
    return alpha;
}

// Whether the material is cut out at `tc` (glTF's alpha mode MASK): its alpha
// (`surface_alpha`) is below its cutoff. Always false for an opaque material.
fn cut_out(mat: Material, tc: TextureCoordinates, vertex_alpha: f32) -> bool {
    if mat.extra.z < 0.0 {
        return false;
    }
    return surface_alpha(mat, tc, vertex_alpha) < mat.extra.z;
}

// Whether a shadow caster leaves shadow-map texel `texel` (its integer coordinates) empty: a
// masked material where it is cut out (`cut_out`); a blended one where its alpha is at or
// below the texel's threshold in a 4 × 4 ordered-dither pattern, so that it covers the
// fraction α of the texels (round(16α)/16 of each 4 × 4 block), and the shadow filter, which
// averages the comparisons over several texels, darkens the receiver by about α.
// `pattern` (`dither_pattern`) picks one of two patterns: 0 the Bayer matrix, value
// b = 4h + l; 1 its twin 4·((h + l) mod 4) + l, as dispersed (one of each four values in every
// 2 × 2 block) and independent of it — the texels the two cover at alphas that are multiples
// of 1/4 overlap as the product of the alphas, within 1.25 texels of 16 at any other pair — so
// that two blended layers of different patterns in line block 1 − (1 − α₁)(1 − α₂) of the
// light, as stacked translucent surfaces do, not the larger α.
fn shadow_cut_out(mat: Material, tc: TextureCoordinates, vertex_alpha: f32, texel: vec2<u32>,
                  pattern: u32) -> bool {
    if mat.extra.w <= 0.0 {
        return cut_out(mat, tc, vertex_alpha);
    }
    var bayer = array<u32, 16>(0u, 8u, 2u, 10u, 12u, 4u, 14u, 6u,
                               3u, 11u, 1u, 9u, 15u, 7u, 13u, 5u);
    var b = bayer[(texel.y % 4u) * 4u + texel.x % 4u];
    if pattern == 1u {
        b = 4u * (((b >> 2u) + (b & 3u)) & 3u) + (b & 3u);
    }
    let threshold = (f32(b) + 0.5) / 16.0;
    return surface_alpha(mat, tc, vertex_alpha) <= threshold;
}

// The dither pattern of a blended caster's triangle (`shadow_cut_out`): by its material's
// index and by whether it faces the light (`front`: counter-clockwise in the map as on screen),
// so that the two sides of one translucent object, and two objects of neighbouring materials,
// take different patterns.
fn dither_pattern(material: u32, front: bool) -> u32 {
    return (material + select(1u, 0u, front)) & 1u;
}

// The material's parameters at texture coordinates `tc` (`fragment_coordinates`) of a point
// with interpolated `normal`, `tangent` and vertex colour `color` (multiplying the base colour
// and its alpha: `alpha` is `surface_alpha`'s, from the same texel),
// seen from the front or (`front` false) from behind,
// where the shading normal is reversed (glTF's double-sided materials: the whole tangent frame
// turned); the mip levels follow the coordinates' screen derivatives.
fn surface_params(mat: Material, tc: TextureCoordinates, normal: vec3<f32>, tangent: vec4<f32>,
                  color: vec4<f32>, front: bool) -> SurfaceParams {
    var p: SurfaceParams;
    p.base_color = mat.base_color.rgb * color.rgb;
    p.alpha = mat.base_color.a * color.a;
    p.roughness = mat.params.x;
    p.metallic = mat.params.y;
    p.normal = normal;
    p.occlusion = 1.0;
    p.emission = mat.emission.rgb;
    if texture_layer(mat, TEX_BASE_COLOR) >= 0.0 {
        let texel = sample_slot(mat, TEX_BASE_COLOR, true, tc);
        p.base_color = p.base_color * texel.rgb;
        p.alpha = p.alpha * texel.a;
    }
    if texture_layer(mat, TEX_METALLIC_ROUGHNESS) >= 0.0 {
        let mr = sample_slot(mat, TEX_METALLIC_ROUGHNESS, false, tc);
        p.roughness = p.roughness * mr.g;
        p.metallic = p.metallic * mr.b;
    }
    if texture_layer(mat, TEX_OCCLUSION) >= 0.0 {
        let ao = sample_slot(mat, TEX_OCCLUSION, false, tc).r;
        p.occlusion = 1.0 + mat.extra.y * (ao - 1.0);
    }
    if texture_layer(mat, TEX_EMISSIVE) >= 0.0 && any(p.emission > vec3<f32>(0.0)) {
        p.emission = p.emission * sample_slot(mat, TEX_EMISSIVE, true, tc).rgb;
    }
    var strength = mat.specular.w;
    var tint = mat.specular.rgb;
    if strength > 0.0 {
        if texture_layer(mat, TEX_SPECULAR) >= 0.0 {
            strength = strength * sample_slot(mat, TEX_SPECULAR, false, tc).a;
        }
        if texture_layer(mat, TEX_SPECULAR_COLOR) >= 0.0 {
            tint = tint * sample_slot(mat, TEX_SPECULAR_COLOR, true, tc).rgb;
        }
    }
    p.specular = vec4<f32>(min(tint, vec3<f32>(1.0)) * strength, strength);
    p.coat = mat.coat.x;
    p.coat_roughness = mat.coat.y;
    p.coat_normal = normal;
    if p.coat > 0.0 {
        if texture_layer(mat, TEX_CLEARCOAT) >= 0.0 {
            p.coat = p.coat * sample_slot(mat, TEX_CLEARCOAT, false, tc).r;
        }
        if texture_layer(mat, TEX_CLEARCOAT_ROUGHNESS) >= 0.0 {
            p.coat_roughness = p.coat_roughness * sample_slot(mat, TEX_CLEARCOAT_ROUGHNESS, false, tc).g;
        }
        p.coat_normal = turned_normal(mat, TEX_CLEARCOAT_NORMAL, mat.coat.z, tc, normal, tangent);
    }
    p.normal = turned_normal(mat, TEX_NORMAL, mat.extra.x, tc, normal, tangent);
    if !front {
        p.normal = -p.normal;
        p.coat_normal = -p.coat_normal;
    }
    return p;
}

// The interpolated `normal` turned by the tangent-space normal texture of slot `k` (its x and
// y times `scale`) where the material has one: the tangent made perpendicular to the normal
// (Gram-Schmidt), the bitangent cross(n, t) · w (glTF); without a texture, or with a tangent
// along the normal, the normal as it is.
fn turned_normal(mat: Material, k: u32, scale: f32, tc: TextureCoordinates, normal: vec3<f32>,
                 tangent: vec4<f32>) -> vec3<f32> {
    if texture_layer(mat, k) < 0.0 {
        return normal;
    }
    let n = normalize(normal);
    let t_perp = tangent.xyz - n * dot(n, tangent.xyz);
    if dot(t_perp, t_perp) <= 1e-12 {
        return normal;
    }
    let m = sample_slot(mat, k, false, tc).xyz * 2.0 - 1.0;
    let t = normalize(t_perp);
    let b = cross(n, t) * select(1.0, -1.0, tangent.w < 0.0);
    let turned = t * (m.x * scale) + b * (m.y * scale) + n * m.z;
    if dot(turned, turned) > 1e-12 {
        return turned;
    }
    return normal;
}

// A shaded point: unit normal n, unit direction to the camera v, GGX α = roughness² (floored),
// Lambertian albedo/π and Schlick's Fresnel terms f0 and f90 (the material's dielectric ones,
// or the base colour and 1 for metals).
struct Surface {
    n: vec3<f32>,
    v: vec3<f32>,
    alpha: f32,
    diffuse: vec3<f32>,
    f0: vec3<f32>,
    f90: f32,
    has_specular: bool,
    catcher: bool,
    // The clear coat: strength (0: none), GGX α = roughness² (floored), of F0 0.04, and its
    // unit normal.
    coat: f32,
    coat_alpha: f32,
    n_coat: vec3<f32>,
};

// The sheen of a material at a point (src/render/sheen.rs): its colour, its distribution's α
// (0: none), and the factor on the layer beneath, 1 − max(colour) · E(n·v).
struct Sheen {
    colour: vec3<f32>,
    alpha: f32,
    beneath: f32,
};

// The sheen of a material whose `sheen` and `sheen_albedo` these are, seen at cosine `n_v`.
fn sheen_at(sheen: vec4<f32>, albedo: array<vec4<f32>, 4>, n_v: f32) -> Sheen {
    var s: Sheen;
    s.colour = sheen.rgb;
    s.alpha = sheen.w;
    s.beneath = 1.0;
    if sheen.w > 0.0 {
        let x = clamp(n_v, 0.0, 1.0) * 15.0;
        let k = min(u32(x), 14u);
        let e0 = albedo[k / 4u][k % 4u];
        let e1 = albedo[(k + 1u) / 4u][(k + 1u) % 4u];
        let e = mix(e0, e1, x - f32(k));
        s.beneath = 1.0 - max(sheen.r, max(sheen.g, sheen.b)) * e;
    }
    return s;
}

// Conty and Kulla's fitted exponent of the sheen's Λ (src/render/sheen.rs, `lambda_exponent`).
fn sheen_lambda_exponent(x: f32, alpha: f32) -> f32 {
    let t = (1.0 - alpha) * (1.0 - alpha);
    let a = mix(21.5473, 25.3245, t);
    let b = mix(3.82987, 3.32435, t);
    let c = mix(0.19823, 0.16801, t);
    let d = mix(-1.97760, -1.27393, t);
    let e = mix(-4.32054, -4.85967, t);
    return a / (1.0 + b * pow(x, c)) + d * x + e;
}

fn sheen_lambda(cos: f32, alpha: f32) -> f32 {
    if cos < 0.5 {
        return exp(sheen_lambda_exponent(cos, alpha));
    }
    return exp(2.0 * sheen_lambda_exponent(0.5, alpha) - sheen_lambda_exponent(1.0 - cos, alpha));
}

// The sheen BRDF without its colour (src/render/sheen.rs, `brdf`): the Charlie distribution
// of α at the half vector's cosine `n_h` times its visibility (capped at 1), 0 where the view
// or the light lies below the surface.
fn sheen_brdf(alpha: f32, n_h: f32, n_v: f32, n_l: f32) -> f32 {
    if n_v <= 0.0 || n_l <= 0.0 {
        return 0.0;
    }
    let inv = 1.0 / alpha;
    let sin2 = max(1.0 - n_h * n_h, 0.0);
    let d = (2.0 + inv) * pow(sin2, 0.5 * inv) / (2.0 * PI);
    let v = 1.0 / ((1.0 + sheen_lambda(n_v, alpha) + sheen_lambda(n_l, alpha)) * 4.0 * n_v * n_l);
    return d * min(v, 1.0);
}

// The clear coat's Fresnel reflectance (Schlick, F0 0.04, F90 1) at cosine `c`.
fn coat_fresnel(c: f32) -> f32 {
    return 0.04 + 0.96 * pow(1.0 - clamp(c, 0.0, 1.0), 5.0);
}

// `world`: the point; `normal`: the shading normal (any length); `p`: the material's
// parameters there (`surface_params`); `flags`: the material's (`Material::params.w`).
fn surface_at(world: vec3<f32>, normal: vec3<f32>, p: SurfaceParams, flags: f32,
              viewer: vec4<f32>) -> Surface {
    var s: Surface;
    s.n = normalize(normal);
    s.v = normalize(viewer.xyz - viewer.w * world);
    let roughness = clamp(p.roughness, 0.0, 1.0);
    let metallic = clamp(p.metallic, 0.0, 1.0);
    s.alpha = max(roughness * roughness, 0.002);
    s.diffuse = p.base_color * (1.0 - metallic) / PI;
    s.f0 = mix(p.specular.rgb, p.base_color, metallic);
    s.f90 = mix(p.specular.w, 1.0, metallic);
    s.has_specular = any(s.f0 > vec3<f32>(0.0)) || s.f90 > 0.0;
    s.coat = clamp(p.coat, 0.0, 1.0);
    let coat_roughness = clamp(p.coat_roughness, 0.0, 1.0);
    s.coat_alpha = max(coat_roughness * coat_roughness, 0.002);
    s.n_coat = s.n;
    if s.coat > 0.0 && dot(p.coat_normal, p.coat_normal) > 1e-12 {
        s.n_coat = normalize(p.coat_normal);
    }
    s.catcher = (u32(flags) & FLAG_CATCHER) != 0u;
    return s;
}

// Whether a material of `flags` (`Material::params.w`) is unlit (`KHR_materials_unlit`): its
// radiance is its base colour there (times texture and vertex colour), whatever the lights.
fn is_unlit(flags: f32) -> bool {
    return (u32(flags) & FLAG_UNLIT) != 0u;
}

// The parameters of a blended fragment (glTF's BLEND) of material `mat`, discarded where its
// side is not drawn (a blended surface is not cut out: its alpha blends).
fn blended_params(mat: Material, in: VertexOut, front: bool) -> SurfaceParams {
    let tc = fragment_coordinates(in.uv, in.uv1);
    if !side_drawn(mat, front) {
        discard;
    }
    return surface_params(mat, tc, in.normal, in.tangent, in.color, front);
}

// Radiance `c` premultiplied by the clamped `alpha`, for the over operator.
fn premultiplied(c: vec3<f32>, alpha: f32) -> vec4<f32> {
    let a = clamp(alpha, 0.0, 1.0);
    return vec4<f32>(c * a, a);
}
