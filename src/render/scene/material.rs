//! Materials of a scene: the metallic-roughness PBR factors, their texture slots and
//! coordinate transforms, alpha modes, and the decoded texture images.

/// A metallic-roughness material (glTF's model).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Linear base colour (albedo for dielectrics, F0 for metals).
    pub base_color: [f32; 3],
    /// Perceptual roughness in [0, 1]; GGX α = roughness².
    pub roughness: f32,
    /// 0: dielectric, 1: metal.
    pub metallic: f32,
    /// Dielectric specular level (Filament's): F0 = 0.16 · specular²; 0.5 gives F0 = 0.04
    /// (glTF's default index of refraction, 1.5; `KHR_materials_ior` sets it). 0 makes a
    /// dielectric purely Lambertian.
    pub specular: f32,
    /// Tint of the dielectric F0 (`KHR_materials_specular`'s `specularColorFactor`; white by
    /// default): F0 = min(0.16 · specular² · tint, 1) · `specular_factor`.
    pub specular_color: [f32; 3],
    /// Strength of the dielectric specular (`KHR_materials_specular`'s `specularFactor`, in
    /// [0, 1]; 1 by default): scales F0 and the grazing reflectance F90.
    pub specular_factor: f32,
    /// Strength of a clear coat over the material (`KHR_materials_clearcoat`'s
    /// `clearcoatFactor`, in [0, 1]; 0: none): a dielectric GGX layer of F0 0.04 whose
    /// Fresnel reflectance Fc takes the fraction `clearcoat` · Fc of the light from the
    /// material beneath.
    pub clearcoat: f32,
    /// The clear coat's perceptual roughness (`clearcoatRoughnessFactor`, in [0, 1]).
    pub clearcoat_roughness: f32,
    /// The colour of a velvet-like sheen over the base (glTF's `KHR_materials_sheen`
    /// `sheenColorFactor`, linear, each in [0, 1]; black: none), beneath any clear coat
    /// ([`crate::render::sheen`]).
    pub sheen_color: [f32; 3],
    /// The sheen's perceptual roughness (`sheenRoughnessFactor`, in [0, 1]; drawn at least
    /// [`crate::render::sheen::MIN_ROUGHNESS`]).
    pub sheen_roughness: f32,
    /// Emitted radiance (linear RGB, W·sr⁻¹·m⁻² in the lights' units), added to the light the
    /// surface reflects: glTF's `emissiveFactor` times `KHR_materials_emissive_strength`.
    /// Zero for a surface that does not glow.
    pub emission: [f32; 3],
    /// The base colour's alpha (glTF's `baseColorFactor[3]`), times the base-colour texture's
    /// A where there is one.
    pub alpha: f32,
    /// What the alpha does (glTF's `alphaMode`): nothing, cut the surface out, or blend it
    /// over what lies behind.
    pub alpha_mode: AlphaMode,
    /// glTF's `doubleSided`: seen from behind (its triangles winding clockwise on screen), the
    /// surface is shaded with its normal reversed; single-sided, its back is not drawn (it
    /// still casts shadows). OBJ and built-in materials are double-sided.
    pub double_sided: bool,
    /// glTF's `KHR_materials_unlit`: the surface shows its base colour (times its texture and
    /// vertex colour) as its radiance, whatever the lights, as a photogrammetric scan with its
    /// lighting baked in wants; its other factors and textures are not drawn. It still casts
    /// shadows.
    pub unlit: bool,
    /// Textures multiplying `base_color`, `roughness`, `metallic` and `emission`, the normal
    /// texture and the occlusion texture.
    pub textures: MaterialTextures,
}

impl Default for Material {
    fn default() -> Self {
        Self {
            base_color: [0.8, 0.8, 0.8],
            roughness: 0.5,
            metallic: 0.0,
            specular: 0.5,
            specular_color: [1.0; 3],
            specular_factor: 1.0,
            clearcoat: 0.0,
            clearcoat_roughness: 0.0,
            sheen_color: [0.0; 3],
            sheen_roughness: 0.0,
            emission: [0.0; 3],
            alpha: 1.0,
            alpha_mode: AlphaMode::Opaque,
            double_sided: true,
            unlit: false,
            textures: MaterialTextures::default(),
        }
    }
}

impl Material {
    /// A purely Lambertian material of the given albedo.
    pub fn lambertian(albedo: [f32; 3]) -> Self {
        Self {
            base_color: albedo,
            roughness: 1.0,
            metallic: 0.0,
            specular: 0.0,
            ..Self::default()
        }
    }

    /// Whether the G-buffer must carry this material's dielectric Fresnel terms and clear coat
    /// per pixel (its fifth target): their textures vary them over the surface, or a clear
    /// coat lies over a normal texture (the coat keeps the interpolated normal, which the
    /// G-buffer does not otherwise hold). Otherwise the shading takes them from the factors.
    pub fn needs_layered_gbuffer(&self) -> bool {
        let t = &self.textures;
        t.specular.is_some()
            || t.specular_color.is_some()
            || (self.clearcoat > 0.0
                && (t.normal.is_some()
                    || t.clearcoat.is_some()
                    || t.clearcoat_roughness.is_some()
                    || t.clearcoat_normal.is_some()))
    }
}

/// What a material's alpha does (glTF's `alphaMode`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum AlphaMode {
    /// The alpha is not read: the surface is opaque.
    #[default]
    Opaque,
    /// glTF's MASK with its `alphaCutoff`: where the alpha is below the cutoff the surface is
    /// not there — not drawn, and casting no shadow.
    Mask(f32),
    /// glTF's BLEND: the surface is drawn over what lies behind it by the over operator
    /// (colour · α + behind · (1 − α)), after the opaque surfaces, back to front. Its shadow
    /// blocks the fraction α of the light (glTF's alpha is coverage): in the shadow maps it
    /// covers the fraction α of the texels in an ordered-dither pattern, which the shadow
    /// filter averages (a shadow map holds one depth, not a transmittance).
    Blend,
}

/// The textures of a material, each multiplying its factor (glTF's metallic-roughness model),
/// its tangent-space normal texture, its ambient-occlusion texture and its emission texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaterialTextures {
    /// sRGB-encoded base colour (RGB), and in A a linear alpha (read where
    /// [`Material::alpha_mode`] is not opaque).
    pub base_color: Option<TextureRef>,
    /// Linear; roughness in G, metallic in B.
    pub metallic_roughness: Option<TextureRef>,
    /// Linear; a tangent-space normal (x right, y up the image, z out of the surface) as
    /// RGB = (n + 1)/2.
    pub normal: Option<TextureRef>,
    /// Scales the normal's x and y (glTF's `normalTexture.scale`).
    pub normal_scale: f32,
    /// Linear; in R, the fraction of the environment's light that reaches the surface (glTF's
    /// `occlusionTexture`: 0 fully occluded, 1 open).
    pub occlusion: Option<TextureRef>,
    /// How much of the occlusion applies (glTF's `occlusionTexture.strength`, in [0, 1]): the
    /// light is scaled by 1 + strength · (R − 1).
    pub occlusion_strength: f32,
    /// sRGB-encoded emission (RGB), multiplying [`Material::emission`].
    pub emissive: Option<TextureRef>,
    /// Linear; in A, the strength of the dielectric specular, multiplying
    /// [`Material::specular_factor`] (glTF's `KHR_materials_specular.specularTexture`).
    pub specular: Option<TextureRef>,
    /// sRGB-encoded tint of the dielectric F0 (RGB), multiplying [`Material::specular_color`]
    /// (`KHR_materials_specular.specularColorTexture`).
    pub specular_color: Option<TextureRef>,
    /// Linear; in R, the clear coat's strength, multiplying [`Material::clearcoat`]
    /// (`KHR_materials_clearcoat.clearcoatTexture`).
    pub clearcoat: Option<TextureRef>,
    /// Linear; in G, the clear coat's roughness, multiplying [`Material::clearcoat_roughness`]
    /// (`clearcoatRoughnessTexture`).
    pub clearcoat_roughness: Option<TextureRef>,
    /// Linear; the clear coat's own tangent-space normal, as [`MaterialTextures::normal`]
    /// (`clearcoatNormalTexture`). Without it the coat follows the interpolated vertex normal,
    /// not the base's normal texture (as the extension asks).
    pub clearcoat_normal: Option<TextureRef>,
    /// Scales the clear-coat normal's x and y (`clearcoatNormalTexture.scale`).
    pub clearcoat_normal_scale: f32,
}

impl MaterialTextures {
    /// The textures in slot order: base colour, metallic-roughness, normal, occlusion,
    /// emissive, specular, specular colour, clear coat, clear-coat roughness, clear-coat
    /// normal ([`SLOT_NAMES`]; the shaders' `TEX_*` slots, `textures::TEXTURE_SLOTS`).
    pub fn slots(&self) -> [Option<TextureRef>; 10] {
        [
            self.base_color,
            self.metallic_roughness,
            self.normal,
            self.occlusion,
            self.emissive,
            self.specular,
            self.specular_color,
            self.clearcoat,
            self.clearcoat_roughness,
            self.clearcoat_normal,
        ]
    }

    /// [`MaterialTextures::slots`], to change.
    pub fn slots_mut(&mut self) -> [&mut Option<TextureRef>; 10] {
        [
            &mut self.base_color,
            &mut self.metallic_roughness,
            &mut self.normal,
            &mut self.occlusion,
            &mut self.emissive,
            &mut self.specular,
            &mut self.specular_color,
            &mut self.clearcoat,
            &mut self.clearcoat_roughness,
            &mut self.clearcoat_normal,
        ]
    }
}

impl Default for MaterialTextures {
    fn default() -> Self {
        Self {
            base_color: None,
            metallic_roughness: None,
            normal: None,
            normal_scale: 1.0,
            occlusion: None,
            occlusion_strength: 1.0,
            emissive: None,
            specular: None,
            specular_color: None,
            clearcoat: None,
            clearcoat_roughness: None,
            clearcoat_normal: None,
            clearcoat_normal_scale: 1.0,
        }
    }
}

/// The names of a material's texture slots ([`MaterialTextures::slots`]' order), for messages.
pub const SLOT_NAMES: [&str; 10] = [
    "base colour",
    "metallic-roughness",
    "normal",
    "occlusion",
    "emissive",
    "specular",
    "specular colour",
    "clear-coat",
    "clear-coat roughness",
    "clear-coat normal",
];

/// A material's use of a texture image: which image of [`Scene::textures`](super::Scene::textures), how its
/// coordinates wrap (u, v), the affine map from the vertex's texture coordinates to the
/// image's (glTF's `KHR_texture_transform`), and which of the vertex's coordinates it reads.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    pub image: u32,
    pub wrap: [Wrap; 2],
    /// Rows of the 2 × 3 matrix M: the image is read at M · (u, v, 1).
    pub transform: [[f32; 3]; 2],
    /// 0: [`Vertex::uv`](super::Vertex::uv); 1: [`Vertex::uv1`](super::Vertex::uv1).
    pub channel: u32,
}

impl TextureRef {
    /// Image `image` repeating both ways, untransformed (an OBJ map's, glTF's defaults).
    pub fn repeating(image: u32) -> Self {
        Self {
            image,
            wrap: [Wrap::Repeat; 2],
            transform: NO_UV_TRANSFORM,
            channel: 0,
        }
    }

    /// Where the image is read for texture coordinates `uv`: [`TextureRef::transform`] applied.
    pub fn image_coordinates(&self, uv: [f32; 2]) -> [f32; 2] {
        self.transform.map(|[a, b, c]| a * uv[0] + b * uv[1] + c)
    }
}

/// How a texture coordinate outside [0, 1] is read (glTF's sampler wrap modes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Wrap {
    #[default]
    Repeat,
    ClampToEdge,
    MirroredRepeat,
}

/// The identity [`TextureRef::transform`].
pub const NO_UV_TRANSFORM: [[f32; 3]; 2] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

/// [`Vertex::color`](super::Vertex::color) of a vertex without colour.
pub const WHITE: [u16; 4] = [u16::MAX; 4];

/// A texture image of a scene, decoded to 8-bit RGBA (still in its own encoding: sRGB for base
/// colours, linear for metallic-roughness).
#[derive(Clone, Debug, PartialEq)]
pub struct TextureImage {
    /// Where it came from, for messages ("image 2 (bricks.png)").
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Row-major RGBA, `width × height × 4` bytes.
    pub rgba: Vec<u8>,
}

impl TextureImage {
    /// The linear RGB of an sRGB-encoded image at texture coordinates `uv` (texel centres at
    /// (i + 0.5)/width), filtered bilinearly with the wrap modes applied texel by texel. Black
    /// for an image whose bytes do not match its size.
    pub fn sample_srgb(&self, uv: [f32; 2], wrap: [Wrap; 2]) -> [f32; 3] {
        let (w, h) = (self.width as usize, self.height as usize);
        if w == 0 || h == 0 || self.rgba.len() != w * h * 4 {
            return [0.0; 3];
        }
        let texel_index = |i: i64, n: usize, mode: Wrap| -> usize {
            let n = n as i64;
            (match mode {
                Wrap::Repeat => i.rem_euclid(n),
                Wrap::ClampToEdge => i.clamp(0, n - 1),
                Wrap::MirroredRepeat => {
                    let m = i.rem_euclid(2 * n);
                    if m < n {
                        m
                    } else {
                        2 * n - 1 - m
                    }
                }
            }) as usize
        };
        let decode = |byte: u8| crate::render::output::srgb_eotf(f32::from(byte) / 255.0);
        // Texel-space position, centres at integers; far-out coordinates are reduced first
        // (f32 texel positions past 2^24 have no fraction left).
        let axis = |t: f32, n: usize| {
            let x = f64::from(t) * n as f64 - 0.5;
            let base = x.floor();
            (base as i64, (x - base) as f32)
        };
        let (x0, fx) = axis(uv[0], w);
        let (y0, fy) = axis(uv[1], h);
        let mut out = [0.0f32; 3];
        for (dy, wy) in [(0, 1.0 - fy), (1, fy)] {
            for (dx, wx) in [(0, 1.0 - fx), (1, fx)] {
                let x = texel_index(x0.saturating_add(dx), w, wrap[0]);
                let y = texel_index(y0.saturating_add(dy), h, wrap[1]);
                let p = &self.rgba[(y * w + x) * 4..][..3];
                for c in 0..3 {
                    out[c] += wx * wy * decode(p[c]);
                }
            }
        }
        out
    }
}

/// The largest side of a scene's texture image, in pixels.
pub const MAX_TEXTURE_SIDE: u32 = 8192;

/// Decodes a PNG, JPEG or WebP texture image to RGBA8, at most [`MAX_TEXTURE_SIDE`] a side. Errors
/// begin with `name`.
pub(super) fn decode_texture(bytes: &[u8], name: String) -> Result<TextureImage, String> {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("{name}: {e}"))?;
    if !matches!(
        reader.format(),
        Some(image::ImageFormat::Png | image::ImageFormat::Jpeg | image::ImageFormat::WebP)
    ) {
        return Err(format!(
            "{name}: not a PNG, JPEG or WebP image (the formats of a glTF core texture, and \
             of EXT_texture_webp)"
        ));
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIDE);
    limits.max_image_height = Some(MAX_TEXTURE_SIDE);
    // A 16-bit RGBA image of the largest size, decoded and converted.
    limits.max_alloc = Some(u64::from(MAX_TEXTURE_SIDE).pow(2) * 12);
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| format!("{name}: {e}"))?;
    let rgba = decoded.to_rgba8();
    Ok(TextureImage {
        name,
        width: rgba.width(),
        height: rgba.height(),
        rgba: rgba.into_raw(),
    })
}
