//! The scene's texture images on the GPU.
//!
//! The scene is drawn in one draw call, so a material's textures cannot be bound per draw:
//! they are layers of two 2D array textures, one of sRGB colours (`Rgba8UnormSrgb`, filtered
//! in linear light by the sampler: base colours, emission, specular tints) and one of linear data
//! (`Rgba8Unorm`: metallic-roughness, roughness in G and metallic in B; tangent-space normals;
//! occlusion in R; the specular strength in A; the clear coat in R and its roughness in G),
//! each layer one image resampled to the arrays' common square side. A
//! material has up to [`TEXTURE_SLOTS`] textures; the materials' table carries each one's
//! layer and wrap modes ([`material_layers`]); `shaders/surface.wgsl` (`surface_params`)
//! samples them in the fragment stages (the G-buffer and ASG passes), with explicit gradients
//! so that the mip level follows the screen footprint whatever the material.
//!
//! Steps, once per scene:
//! 1. [`plan_layers`]: which images each array needs (an image used both as a colour and as
//!    data gets a layer in each) and the side: the largest image's longer side rounded up
//!    to a power of two, at most [`MAX_LAYER_SIDE`] and the device's limit, halved until all
//!    layers with their mip chains fit [`MAX_TEXTURE_BYTES`] (logged when it shrinks).
//! 2. Each image is decoded to linear light (sRGB for colours), resampled to the side
//!    with a triangle filter (`image::imageops`, which widens the filter when shrinking), and
//!    its mip chain built by 2 × 2 box averages, all in linear light (a cut-out's base colour
//!    with its alpha scaled per level to keep the cutoff's coverage, [`mip_chain`]); then
//!    encoded back to 8 bits and uploaded. The chains are made on rayon's threads, as many
//!    images at a time as there are threads; the layers, their side, their memory and the
//!    time are logged.
//!
//! A scene without textures binds 1 × 1 placeholder arrays that no material reads.

use super::output::srgb_eotf;
use super::scene::{AlphaMode, Scene, TextureImage, Wrap};

/// The largest side of a texture layer, in texels (a 2048² layer and its mips take 21 MiB).
pub const MAX_LAYER_SIDE: u32 = 2048;

/// The sampler's anisotropy clamp (wgpu's, and most GPUs', largest).
pub const MAX_ANISOTROPY: u16 = 16;

/// The most memory the texture arrays may take, mip chains included: 1 GiB.
pub const MAX_TEXTURE_BYTES: u64 = 1 << 30;

/// Which scene images go into which array, and the layers' side.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerPlan {
    /// Images of [`Scene::textures`] in the sRGB colour array (base colour and emissive
    /// textures), layer by layer.
    pub base_color: Vec<u32>,
    /// Per base-colour layer, the alpha cutoff of the first cut-out material that uses it
    /// (its mips keep the cut-out's coverage, [`mip_chain`]); `None`: no cut-out uses it.
    pub cutoffs: Vec<Option<f32>>,
    /// The same for the data array (metallic-roughness, normal and occlusion textures).
    pub data: Vec<u32>,
    /// The layers' side in texels (1 when there are no textures).
    pub side: u32,
}

/// Why the textures could not be put on the GPU.
#[derive(Debug, thiserror::Error)]
pub enum TextureError {
    #[error(
        "the scene's materials use {layers} texture layers in one array, more than the \
         {limit} this GPU allows"
    )]
    TooManyLayers { layers: usize, limit: u32 },
}

/// Step 1 of the module doc: the arrays' images and side for `scene`, on a device whose 2D
/// textures are at most `max_side` a side.
pub fn plan_layers(scene: &Scene, max_side: u32) -> LayerPlan {
    let mut base_color = Vec::new();
    let mut data = Vec::new();
    let mut cutoffs = Vec::new();
    for m in &scene.materials {
        for (slot, texture) in m.textures.slots().into_iter().enumerate() {
            let Some(t) = texture else { continue };
            let list = if SRGB_SLOTS[slot] {
                &mut base_color
            } else {
                &mut data
            };
            let layer = list.iter().position(|&i| i == t.image).unwrap_or_else(|| {
                list.push(t.image);
                list.len() - 1
            });
            if SRGB_SLOTS[slot] {
                cutoffs.resize(base_color.len(), None);
                let cutoff = match m.alpha_mode {
                    AlphaMode::Mask(c) if c > 0.0 => Some(c),
                    _ => None,
                };
                if slot == 0 && cutoffs[layer].is_none() {
                    cutoffs[layer] = cutoff;
                }
            }
        }
    }
    let largest = base_color
        .iter()
        .chain(&data)
        .filter_map(|&i| scene.textures.get(i as usize))
        .map(|t| t.width.max(t.height))
        .max()
        .unwrap_or(1);
    let cap = MAX_LAYER_SIDE.min(max_side).max(1);
    // The largest power of two within the cap.
    let mut side = largest.next_power_of_two().min(1 << cap.ilog2());
    let layers = (base_color.len() + data.len()) as u64;
    let bytes = |side: u32| layers * u64::from(side).pow(2) * 4 * 4 / 3;
    let wanted = side;
    while side > 1 && bytes(side) > MAX_TEXTURE_BYTES {
        side /= 2;
    }
    if side < wanted {
        tracing::info!(
            "{layers} texture layers of {wanted}² would take {} MiB: drawn at {side}² ({} MiB)",
            bytes(wanted) >> 20,
            bytes(side) >> 20
        );
    }
    LayerPlan {
        base_color,
        cutoffs,
        data,
        side,
    }
}

/// How many textures a material may have: base colour, metallic-roughness, normal,
/// occlusion, emissive, specular, specular colour, clear coat, clear-coat roughness and
/// clear-coat normal, in that order ([`super::scene::MaterialTextures::slots`]; the slots of
/// `shaders/surface.wgsl`, `TEX_*`).
pub const TEXTURE_SLOTS: usize = 10;

/// Which slots hold sRGB colours (the base-colour array: base colour, emission, specular
/// colour); the others hold linear data.
const SRGB_SLOTS: [bool; TEXTURE_SLOTS] = [
    true, false, false, false, true, false, true, false, false, false,
];

/// Where a material's textures are on the GPU, as `MaterialRaw::layers` holds them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaterialLayers {
    /// Per slot, the layer of its array (the base-colour array for sRGB slots, the data array
    /// for the others); −1: none.
    pub layers: [f32; TEXTURE_SLOTS],
    /// Per slot k, its wrap modes at bits 4(k mod 8)..4(k mod 8) + 4 of word k / 8, as u + 4·v
    /// with 0 repeat, 1 clamp to edge, 2 mirrored repeat (`surface.wgsl`, `wrap_coordinate`).
    pub wrap_modes: [u32; 2],
    /// Bit k set: slot k reads the vertex's second texture coordinates ([`super::scene::TextureRef::channel`]).
    pub channels: u32,
}

/// Per material: its textures' layers, wrap modes and texture-coordinate channels.
pub fn material_layers(scene: &Scene, plan: &LayerPlan) -> Vec<MaterialLayers> {
    let code = |w: Wrap| match w {
        Wrap::Repeat => 0,
        Wrap::ClampToEdge => 1,
        Wrap::MirroredRepeat => 2,
    };
    scene
        .materials
        .iter()
        .map(|m| {
            let slots = m.textures.slots();
            let (mut wrap_modes, mut channels) = ([0; 2], 0);
            for (slot, t) in slots.iter().enumerate() {
                if let Some(t) = t {
                    wrap_modes[slot / 8] |=
                        (code(t.wrap[0]) + 4 * code(t.wrap[1])) << (4 * (slot % 8));
                    channels |= u32::from(t.channel == 1) << slot;
                }
            }
            MaterialLayers {
                layers: std::array::from_fn(|slot| {
                    let list = if SRGB_SLOTS[slot] {
                        &plan.base_color
                    } else {
                        &plan.data
                    };
                    slots[slot]
                        .and_then(|t| list.iter().position(|&i| i == t.image))
                        .map_or(-1.0, |p| p as f32)
                }),
                wrap_modes,
                channels,
            }
        })
        .collect()
}

/// The texture arrays and their sampler, bound as group 2 of the G-buffer, ASG and shadow
/// passes.
pub struct SurfaceTextures {
    pub layout: wgpu::BindGroupLayout,
    pub bind_group: wgpu::BindGroup,
}

impl SurfaceTextures {
    /// Step 2 of the module doc: resamples and uploads the planned layers; the sampler
    /// filters with up to `anisotropy` samples (1..=[`MAX_ANISOTROPY`]).
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        scene: &Scene,
        plan: &LayerPlan,
        anisotropy: u16,
    ) -> Result<Self, TextureError> {
        let limit = device.limits().max_texture_array_layers;
        for list in [&plan.base_color, &plan.data] {
            if list.len() > limit as usize {
                return Err(TextureError::TooManyLayers {
                    layers: list.len(),
                    limit,
                });
            }
        }
        let start = std::time::Instant::now();
        let images = |list: &[u32], cutoffs: &[Option<f32>]| -> Vec<(&TextureImage, Option<f32>)> {
            list.iter()
                .enumerate()
                .filter_map(|(layer, &i)| {
                    let cutoff = cutoffs.get(layer).copied().flatten();
                    Some((scene.textures.get(i as usize)?, cutoff))
                })
                .collect()
        };
        let base_color = upload_array(
            device,
            queue,
            "colour textures",
            &images(&plan.base_color, &plan.cutoffs),
            plan.side,
            true,
        );
        let data = upload_array(
            device,
            queue,
            "data textures",
            &images(&plan.data, &[]),
            plan.side,
            false,
        );
        let layers = plan.base_color.len() + plan.data.len();
        if layers > 0 {
            let bytes = layers as f64 * f64::from(plan.side).powi(2) * 4.0 * 4.0 / 3.0;
            tracing::info!(
                "textures: {layers} layers of {side}² ({:.1} MiB with mips) made in {:.0} ms",
                bytes / f64::from(1 << 20),
                start.elapsed().as_secs_f64() * 1e3,
                side = plan.side
            );
        }
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("surface textures"),
            // Clamping and mirroring are done in the shader (surface.wgsl, `wrap_coordinate`).
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            // Up to 16 samples along a footprint stretched by a grazing view, where the
            // adapter filters anisotropically (wgpu sets 1 where it does not).
            anisotropy_clamp: anisotropy.clamp(1, MAX_ANISOTROPY),
            ..Default::default()
        });
        // The compute rasteriser reads them too (the cut-out casters' alpha).
        let visibility = wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE;
        let texture_entry = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: true },
                view_dimension: wgpu::TextureViewDimension::D2Array,
                multisampled: false,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("surface textures"),
            entries: &[
                texture_entry(0),
                texture_entry(1),
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("surface textures"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&base_color),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&data),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(&sampler),
                },
            ],
        });
        Ok(Self { layout, bind_group })
    }
}

/// One array of `images` (at least one placeholder layer), each resampled to `side`² with
/// its mip chain (keeping the coverage of its alpha cutoff, where it has one); `srgb`: the
/// bytes are sRGB-encoded (and the array's format says so).
fn upload_array(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    label: &str,
    images: &[(&TextureImage, Option<f32>)],
    side: u32,
    srgb: bool,
) -> wgpu::TextureView {
    let (side, layers) = if images.is_empty() {
        (1, 1)
    } else {
        (side, images.len() as u32)
    };
    let mip_level_count = side.ilog2() + 1;
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: side,
            height: side,
            depth_or_array_layers: layers,
        },
        mip_level_count,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: if srgb {
            wgpu::TextureFormat::Rgba8UnormSrgb
        } else {
            wgpu::TextureFormat::Rgba8Unorm
        },
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let placeholder = TextureImage {
        name: "placeholder".into(),
        width: 1,
        height: 1,
        rgba: vec![255; 4],
    };
    let images = if images.is_empty() {
        vec![(&placeholder, None)]
    } else {
        images.to_vec()
    };
    // The chains are made on rayon's threads, a few images at a time (at most one chain per
    // thread is held before its upload).
    use rayon::prelude::*;
    let batch = rayon::current_num_threads().max(1);
    let chains = images.chunks(batch).flat_map(|chunk| {
        chunk
            .par_iter()
            .map(|&(image, cutoff)| mip_chain(image, side, srgb, cutoff))
            .collect::<Vec<_>>()
    });
    for (layer, chain) in chains.enumerate() {
        for (level, mip) in chain.iter().enumerate() {
            let mip_side = side >> level;
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: level as u32,
                    origin: wgpu::Origin3d {
                        x: 0,
                        y: 0,
                        z: layer as u32,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                mip,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(4 * mip_side),
                    rows_per_image: Some(mip_side),
                },
                wgpu::Extent3d {
                    width: mip_side,
                    height: mip_side,
                    depth_or_array_layers: 1,
                },
            );
        }
    }
    texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    })
}

/// 8-bit sRGB by table: the 256 powers of the decoding, and 255 for the encoding instead of a
/// power per texel.
struct SrgbTables {
    /// Per code, its linear value.
    to_linear: [f32; 256],
    /// The linear values at which the code rounds up: eotf((k + ½)/255).
    rounds_up: [f32; 255],
}

impl SrgbTables {
    fn new() -> Self {
        Self {
            to_linear: std::array::from_fn(|c| srgb_eotf(c as f32 / 255.0)),
            rounds_up: std::array::from_fn(|k| srgb_eotf((k as f32 + 0.5) / 255.0)),
        }
    }

    /// round(oetf(v)·255), clamped to [0, 255] (NaN: 0): how many rounding points lie at or
    /// below v.
    fn code(&self, v: f32) -> u8 {
        self.rounds_up.partition_point(|&t| t <= v) as u8
    }
}

/// Step 2 of the module doc for one image: its levels from `side`² down to 1², each as RGBA8
/// bytes in the image's encoding (alpha is always linear).
///
/// With an alpha `cutoff` (the image is a cut-out's base colour), each smaller level's alpha is
/// scaled so that the fraction of its texels at or above the cutoff — the surface the cut-out
/// keeps — is the full-size level's (Castaño 2010, "Computing Alpha Mipmaps"): averaging alone
/// lowers the alpha of thin opaque parts (a 1-texel line in 4 averages to 0.25), and foliage
/// and fences thinned out and vanished with distance. The scale puts the level's alpha at the
/// kept fraction's quantile just above the cutoff (half an 8-bit step, so that the encoding
/// does not round it below).
pub fn mip_chain(image: &TextureImage, side: u32, srgb: bool, cutoff: Option<f32>) -> Vec<Vec<u8>> {
    let tables = SrgbTables::new();
    let decode = |channel: usize, byte: u8| {
        if srgb && channel < 3 {
            tables.to_linear[usize::from(byte)]
        } else {
            f32::from(byte) / 255.0
        }
    };
    let encode = |channel: usize, v: f32| {
        if srgb && channel < 3 {
            tables.code(v)
        } else {
            (v.clamp(0.0, 1.0) * 255.0).round() as u8
        }
    };
    let linear: Vec<f32> = image
        .rgba
        .iter()
        .enumerate()
        .map(|(i, &b)| decode(i % 4, b))
        .collect();
    let mut level = match image::Rgba32FImage::from_raw(image.width, image.height, linear) {
        Some(full) if image.width == side && image.height == side => full,
        Some(full) => {
            image::imageops::resize(&full, side, side, image::imageops::FilterType::Triangle)
        }
        // A malformed image (its bytes do not match its size): a flat mid-grey layer.
        None => image::Rgba32FImage::from_pixel(side, side, image::Rgba([0.5, 0.5, 0.5, 1.0])),
    };
    let kept = cutoff.map(|c| (c, alpha_coverage(&level, c)));
    let mut chain: Vec<Vec<u8>> = Vec::new();
    loop {
        let alpha_scale = match kept {
            Some((c, coverage)) if !chain.is_empty() => coverage_scale(&level, c, coverage),
            _ => 1.0,
        };
        chain.push(
            level
                .as_raw()
                .iter()
                .enumerate()
                .map(|(i, &v)| match i % 4 {
                    3 => encode(3, v * alpha_scale),
                    c => encode(c, v),
                })
                .collect(),
        );
        let s = level.width();
        if s <= 1 {
            return chain;
        }
        let half = s / 2;
        level = image::Rgba32FImage::from_fn(half, half, |x, y| {
            let mut sum = [0.0f32; 4];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let p = level.get_pixel(2 * x + dx, 2 * y + dy).0;
                for c in 0..4 {
                    sum[c] += p[c];
                }
            }
            image::Rgba(sum.map(|v| v * 0.25))
        });
    }
}

/// The fraction of `level`'s texels whose alpha is at or above `cutoff`.
fn alpha_coverage(level: &image::Rgba32FImage, cutoff: f32) -> f32 {
    let texels = level.pixels().len().max(1);
    let kept = level.pixels().filter(|p| p.0[3] >= cutoff).count();
    kept as f32 / texels as f32
}

/// The factor on `level`'s alpha that keeps `coverage` of its texels at or above `cutoff`
/// ([`mip_chain`]): the cutoff (plus half an 8-bit step) over the alpha of the texel at that
/// rank, brightest first. 1 where the coverage is all or nothing (averages keep it) or the
/// rank's alpha is 0.
fn coverage_scale(level: &image::Rgba32FImage, cutoff: f32, coverage: f32) -> f32 {
    if coverage <= 0.0 || coverage >= 1.0 {
        return 1.0;
    }
    let mut alphas: Vec<f32> = level.pixels().map(|p| p.0[3]).collect();
    let rank = ((coverage * alphas.len() as f32).round() as usize).clamp(1, alphas.len());
    // The rank-th largest.
    let (_, &mut at_rank, _) = alphas.select_nth_unstable_by(rank - 1, |a, b| b.total_cmp(a));
    if at_rank > 0.0 {
        (cutoff + 0.5 / 255.0) / at_rank
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::scene::{MaterialTextures, TextureRef};

    fn image(width: u32, height: u32, rgba: [u8; 4]) -> TextureImage {
        TextureImage {
            name: "test".into(),
            width,
            height,
            rgba: rgba.repeat((width * height) as usize),
        }
    }

    /// The table encoding gives every code back from its own linear value and is
    /// round(oetf(v)·255) across [0, 1] (off by one only where v sits on a rounding point to
    /// f32's precision), clamped outside it (NaN to 0).
    #[test]
    fn srgb_tables_round_as_the_transfer_function() {
        let t = SrgbTables::new();
        for c in 0..=255u8 {
            assert_eq!(t.code(t.to_linear[usize::from(c)]), c);
        }
        let mut off = 0;
        for i in 0..=100_000 {
            let v = i as f32 / 100_000.0;
            let want = (crate::render::output::srgb_oetf(v) * 255.0).round() as u8;
            let got = t.code(v);
            assert!(got.abs_diff(want) <= 1, "{v}: {got} against {want}");
            off += usize::from(got != want);
        }
        assert!(off <= 10, "{off} of 100001 values off by one");
        assert_eq!((t.code(-1.0), t.code(2.0), t.code(f32::NAN)), (0, 255, 0));
    }

    #[test]
    fn mip_chains_average_in_linear_light() {
        // Half black, half white columns: the 1×1 level is the linear mean, 0.5, which sRGB
        // encodes as 188, not the 128 an average of the codes would give.
        let mut half = image(2, 2, [0, 0, 0, 255]);
        for y in 0..2 {
            half.rgba[(y * 2 + 1) * 4..(y * 2 + 2) * 4].copy_from_slice(&[255; 4]);
        }
        let chain = mip_chain(&half, 2, true, None);
        assert_eq!(chain.len(), 2);
        assert_eq!(chain[0], half.rgba);
        assert_eq!(&chain[1][..3], &[188, 188, 188]);
        // Linear data averages its codes.
        let chain = mip_chain(&half, 2, false, None);
        assert_eq!(&chain[1][..3], &[128, 128, 128]);
        // A flat image stays flat at every level, resampled to a larger side.
        let flat = image(3, 5, [200, 100, 50, 255]);
        let chain = mip_chain(&flat, 8, true, None);
        assert_eq!(chain.len(), 4);
        for level in &chain {
            for px in level.chunks_exact(4) {
                assert_eq!(px, [200, 100, 50, 255]);
            }
        }
    }

    /// A cut-out's mips keep the fraction of texels its cutoff keeps (within 2%, or 1.5
    /// texels on levels of at least 16 texels), where plain averages drift towards the mean alpha and, with it
    /// below the cutoff, lose the surface (30% kept at full size, under 5% at 8²).
    #[test]
    fn cut_out_mips_keep_their_alpha_coverage() {
        // Alpha uniform in 0..=255 (a splitmix-style hash of the texel index), white.
        let side = 64;
        let rgba: Vec<u8> = (0..side * side)
            .flat_map(|i: u32| {
                let mut h = u64::from(i).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                h ^= h >> 31;
                h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
                h ^= h >> 29;
                [255, 255, 255, (h % 256) as u8]
            })
            .collect();
        let noise = TextureImage {
            name: "noise".into(),
            width: side,
            height: side,
            rgba,
        };
        let cutoff = 0.7;
        let coverage = |level: &[u8]| {
            let kept = level
                .chunks_exact(4)
                .filter(|p| f32::from(p[3]) / 255.0 >= cutoff)
                .count();
            kept as f32 / (level.len() / 4) as f32
        };
        let kept = mip_chain(&noise, side, true, Some(cutoff));
        let plain = mip_chain(&noise, side, true, None);
        let full = coverage(&kept[0]);
        assert!((full - 0.3).abs() < 0.03, "{full}");
        assert_eq!(kept[0], plain[0], "the full-size level is the image");
        for level in 1..kept.len() {
            let texels = kept[level].len() / 4;
            if texels < 16 {
                break;
            }
            let got = coverage(&kept[level]);
            // Within 2%, or a texel and a half of the level: the rank rounds to whole texels,
            // and one within the margin's half step of the cutoff may be kept too.
            let tolerance = 0.02f32.max(1.5 / texels as f32);
            assert!(
                (got - full).abs() <= tolerance,
                "level {level}: {got} of the texels kept against {full}"
            );
            // Only the alpha changes.
            for (a, b) in kept[level]
                .chunks_exact(4)
                .zip(plain[level].chunks_exact(4))
            {
                assert_eq!(a[..3], b[..3]);
            }
        }
        assert!(coverage(&plain[3]) < 0.05, "{}", coverage(&plain[3]));
    }

    #[test]
    fn layers_are_planned_per_array_within_the_limits() {
        let mut scene = Scene::default_scene();
        scene.textures = vec![image(300, 100, [0; 4]), image(40, 40, [0; 4])];
        let r = |image| TextureRef {
            image,
            wrap: [Wrap::ClampToEdge, Wrap::MirroredRepeat],
            transform: crate::render::scene::NO_UV_TRANSFORM,
            channel: 0,
        };
        let repeating = TextureRef::repeating;
        scene.materials[0].textures = MaterialTextures {
            base_color: Some(r(1)),
            metallic_roughness: Some(r(0)),
            normal: Some(repeating(0)),
            occlusion: Some(TextureRef {
                channel: 1,
                ..repeating(2)
            }),
            emissive: Some(r(1)),
            // An sRGB slot past the core five shares the base colour's layer; a data one
            // past the eighth slot has its wrap modes in the second word.
            specular_color: Some(repeating(1)),
            clearcoat_normal: Some(r(1)),
            ..Default::default()
        };
        scene.materials[1].textures.base_color = Some(r(0));
        scene.textures.push(image(8, 8, [0; 4]));
        let plan = plan_layers(&scene, 16384);
        assert_eq!(plan.base_color, vec![1, 0]);
        assert_eq!(plan.cutoffs, vec![None, None]);
        assert_eq!(plan.data, vec![0, 2, 1]);
        // A cut-out material's base colour carries its cutoff (its emissive texture does not).
        // A blended one's does not (its mips are plain averages, as the blending wants).
        scene.materials[1].alpha_mode = AlphaMode::Mask(0.25);
        assert_eq!(plan_layers(&scene, 16384).cutoffs, vec![None, Some(0.25)]);
        scene.materials[1].alpha_mode = AlphaMode::Blend;
        assert_eq!(plan_layers(&scene, 16384).cutoffs, vec![None, None]);
        scene.materials[1].alpha_mode = AlphaMode::Opaque;
        assert_eq!(plan.side, 512);
        assert_eq!(plan_layers(&scene, 256).side, 256);
        assert_eq!(plan_layers(&scene, 300).side, 256);
        let layers = material_layers(&scene, &plan);
        // Clamp-to-edge u, mirrored v: 1 + 4·2 = 9, in each slot's four bits.
        let clamp_mirror = 9;
        assert_eq!(
            layers[0],
            MaterialLayers {
                layers: [0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0, -1.0, -1.0, 2.0],
                wrap_modes: [
                    clamp_mirror | clamp_mirror << 4 | clamp_mirror << 16,
                    clamp_mirror << 4
                ],
                channels: 1 << 3,
            }
        );
        assert_eq!(
            layers[1],
            MaterialLayers {
                layers: [1.0, -1.0, -1.0, -1.0, -1.0, -1.0, -1.0, -1.0, -1.0, -1.0],
                wrap_modes: [clamp_mirror, 0],
                channels: 0,
            }
        );
        assert_eq!(
            layers[2],
            MaterialLayers {
                layers: [-1.0; TEXTURE_SLOTS],
                wrap_modes: [0; 2],
                channels: 0,
            }
        );
        // Many large images: the side shrinks until the arrays fit the memory bound.
        scene.textures = vec![image(4096, 4096, [0; 4])];
        for m in &mut scene.materials {
            m.textures.base_color = Some(r(0));
        }
        assert_eq!(plan_layers(&scene, 16384).side, MAX_LAYER_SIDE);
        let textures: Vec<_> = (0..100).map(|_| image(2048, 2048, [0; 4])).collect();
        scene.textures = textures;
        scene.materials = (0..100)
            .map(|i| crate::render::scene::Material {
                textures: MaterialTextures {
                    base_color: Some(r(i)),
                    ..Default::default()
                },
                ..Default::default()
            })
            .collect();
        let plan = plan_layers(&scene, 16384);
        assert_eq!(plan.base_color.len(), 100);
        assert!(100 * u64::from(plan.side).pow(2) * 4 * 4 / 3 <= MAX_TEXTURE_BYTES);
        assert_eq!(plan.side, 1024);
    }
}
