//! Building the renderer: its pipelines, bind-group layouts, buffers and targets for one scene
//! and image size ([`Renderer::with_gpu`]), and the triangle order the passes draw
//! (`order_triangles`: opaque, cut-out, then blended casters back to front).

use super::*;

pub(super) struct ShadowArray {
    pub(super) _texture: wgpu::Texture,
    pub(super) layer_views: Vec<wgpu::TextureView>,
    pub(super) array_view: wgpu::TextureView,
    pub(super) layers: u32,
}

pub(super) struct Timestamps {
    pub(super) set: wgpu::QuerySet,
    pub(super) resolve: wgpu::Buffer,
    pub(super) read: wgpu::Buffer,
    pub(super) period_ns: f32,
}

/// The G-buffer's targets: position + material, normal + roughness, base colour + metallic,
/// emission + occlusion (`Rgba32Float`), and the layers over the base (`Rgba32Uint`, 16-bit
/// fields: the dielectric Fresnel terms, the clear coat's strength, roughness and normal;
/// `shaders/shade.wgsl`, `pack_layers`).
pub(super) const GBUFFER_TARGETS: usize = 5;

/// The formats of the G-buffer's targets, in order.
const GBUFFER_FORMATS: [wgpu::TextureFormat; GBUFFER_TARGETS] = [
    COLOR_FORMAT,
    COLOR_FORMAT,
    COLOR_FORMAT,
    COLOR_FORMAT,
    wgpu::TextureFormat::Rgba32Uint,
];

/// The vertex attributes the surface passes (G-buffer, ASG) read: position, normal, material,
/// the two texture coordinates, tangent, colour (`shaders/surface.wgsl`, `VertexIn`), in
/// [`scene::Vertex`]'s order.
pub(super) const SURFACE_ATTRIBUTES: [wgpu::VertexAttribute; 7] = wgpu::vertex_attr_array![
    0 => Float32x3, 1 => Float32x3, 2 => Uint32, 3 => Float32x2, 5 => Float32x2, 4 => Float32x4,
    6 => Unorm16x4
];

/// The vertex attributes the cut-out casters' shadow pass reads (`shaders/shadow.wgsl`,
/// `MaskedIn`): position, material, the two texture coordinates and the colour (its alpha), at
/// their offsets in [`scene::Vertex`].
const MASKED_SHADOW_ATTRIBUTES: [wgpu::VertexAttribute; 5] = {
    use std::mem::offset_of;
    use wgpu::VertexFormat::{Float32x2, Float32x3, Uint32, Unorm16x4};
    const fn at(
        format: wgpu::VertexFormat,
        offset: usize,
        shader_location: u32,
    ) -> wgpu::VertexAttribute {
        wgpu::VertexAttribute {
            format,
            offset: offset as u64,
            shader_location,
        }
    }
    [
        at(Float32x3, offset_of!(scene::Vertex, position), 0),
        at(Uint32, offset_of!(scene::Vertex, material), 2),
        at(Float32x2, offset_of!(scene::Vertex, uv), 3),
        at(Float32x2, offset_of!(scene::Vertex, uv1), 5),
        at(Unorm16x4, offset_of!(scene::Vertex, color), 6),
    ]
};

fn vertex_layout(attributes: &[wgpu::VertexAttribute]) -> wgpu::VertexBufferLayout<'_> {
    wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<scene::Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes,
    }
}

/// A uniform-buffer binding (no dynamic offset) seen by the `visibility` stages.
pub(super) fn uniform_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// The frame a compute pass writes: a write-only 2D storage texture of [`COLOR_FORMAT`].
pub(super) fn frame_storage_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::StorageTexture {
            access: wgpu::StorageTextureAccess::WriteOnly,
            format: COLOR_FORMAT,
            view_dimension: wgpu::TextureViewDimension::D2,
        },
        count: None,
    }
}

/// A storage-buffer binding read (or, without `read_only`, written) by compute shaders.
/// A single-level, single-sample 2D texture of `width` × `height` (the frame, the G-buffer, the
/// post passes' outputs).
pub(super) fn texture_2d(
    device: &wgpu::Device,
    label: &str,
    (width, height): (u32, u32),
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

/// A layout entry for a 2D float texture read with `textureLoad` (not filtered: the
/// `Rgba32Float` frame and G-buffer), visible to `visibility`.
pub(super) fn unfiltered_texture_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

pub(super) fn compute_storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Where a pass binds what `shaders/shadow_lookup.wgsl` reads: the light records, the
/// shadow-map array, its comparison sampler and the compute rasteriser's depths (the light
/// pass and the ASG pass, each at its own binding numbers).
#[derive(Clone, Copy, Debug)]
pub(super) struct ShadowLookupBindings {
    pub(super) lights: u32,
    pub(super) maps: u32,
    pub(super) sampler: u32,
    pub(super) depths: u32,
}

impl ShadowLookupBindings {
    /// The layout entries, visible to `visibility`.
    pub(super) fn layout_entries(
        self,
        visibility: wgpu::ShaderStages,
    ) -> [wgpu::BindGroupLayoutEntry; 4] {
        [
            wgpu::BindGroupLayoutEntry {
                visibility,
                ..compute_storage_entry(self.lights, true)
            },
            wgpu::BindGroupLayoutEntry {
                binding: self.maps,
                visibility,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Depth,
                    view_dimension: wgpu::TextureViewDimension::D2Array,
                    multisampled: false,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: self.sampler,
                visibility,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                visibility,
                ..compute_storage_entry(self.depths, true)
            },
        ]
    }

    /// The bind-group entries of those resources.
    pub(super) fn bind_entries<'a>(
        self,
        lights: &'a wgpu::Buffer,
        maps: &'a wgpu::TextureView,
        sampler: &'a wgpu::Sampler,
        depths: &'a wgpu::Buffer,
    ) -> [wgpu::BindGroupEntry<'a>; 4] {
        [
            wgpu::BindGroupEntry {
                binding: self.lights,
                resource: lights.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: self.maps,
                resource: wgpu::BindingResource::TextureView(maps),
            },
            wgpu::BindGroupEntry {
                binding: self.sampler,
                resource: wgpu::BindingResource::Sampler(sampler),
            },
            wgpu::BindGroupEntry {
                binding: self.depths,
                resource: depths.as_entire_binding(),
            },
        ]
    }
}

/// The light pass's [`ShadowLookupBindings`] (group 0 of `shaders/shade.wgsl`).
const SHADE_SHADOW_BINDINGS: ShadowLookupBindings = ShadowLookupBindings {
    lights: 1,
    maps: 3,
    sampler: 4,
    depths: 5,
};

/// A triangle pipeline over the scene's vertices (the vertex entry point reading the given
/// attributes), depth-tested with `Less`, no culling; with `fragment = Some((entry, formats))`,
/// that fragment entry point writes targets of those formats (none: it only discards), without it
/// the pass is depth-only (shadow maps). Unblended, it writes depth; with `blend` (the blended
/// surfaces' passes) its targets are blended so and depth is only tested.
#[allow(clippy::too_many_arguments)]
pub(super) fn depth_tested_pipeline(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
    (vertex_entry, attributes): (&str, &[wgpu::VertexAttribute]),
    bias: wgpu::DepthBiasState,
    fragment: Option<(&str, &[wgpu::TextureFormat])>,
    blend: Option<wgpu::BlendState>,
) -> wgpu::RenderPipeline {
    let targets: Vec<_> = fragment
        .map_or(&[][..], |(_, formats)| formats)
        .iter()
        .map(|&format| {
            Some(wgpu::ColorTargetState {
                format,
                blend,
                write_mask: wgpu::ColorWrites::ALL,
            })
        })
        .collect();
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(label),
        layout: Some(layout),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some(vertex_entry),
            compilation_options: Default::default(),
            buffers: &[Some(vertex_layout(attributes))],
        },
        primitive: wgpu::PrimitiveState {
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil: Some(wgpu::DepthStencilState {
            format: DEPTH_FORMAT,
            depth_write_enabled: Some(blend.is_none()),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias,
        }),
        multisample: Default::default(),
        fragment: fragment.map(|(entry, _)| wgpu::FragmentState {
            module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            targets: &targets,
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// Where the groups of shadow casters start in the scene's index list, as
/// [`order_triangles`] leaves it: opaque casters `0..cutout_start`, then those cut out by their
/// alpha in the shadow maps (masked or blended) up to `caster_indices`, of which the blended
/// ones are `blended_start..caster_indices`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct TriangleGroups {
    pub(super) cutout_start: u32,
    pub(super) blended_start: u32,
}

/// Orders the shadow casters' triangles of `scene` (the ground, after them, is left as it is):
/// opaque first, then masked (a cutoff above 0), each in its order, then blended (glTF's BLEND)
/// back to front from the camera, by the distance of their centroids. The shadow pass draws
/// the opaque group with the depth-only pipeline and the other two with the alpha-testing one;
/// the G-buffer pass draws all but the blended group, which the blended pass draws over the
/// frame in this order. (Sorting triangles rather than objects orders intersecting and nested
/// blended surfaces too, except where two triangles overlap in depth.)
pub(super) fn order_triangles(scene: &mut Scene) -> TriangleGroups {
    use scene::AlphaMode;
    let casters = (scene.caster_indices as usize).min(scene.indices.len());
    let mode = |triangle: &[u32]| {
        triangle
            .first()
            .and_then(|&i| scene.vertices.get(i as usize))
            .and_then(|v| scene.materials.get(v.material as usize))
            .map_or(AlphaMode::Opaque, |m| m.alpha_mode)
    };
    let (mut opaque, mut masked, mut blended) = (Vec::new(), Vec::new(), Vec::new());
    for triangle in scene.indices[..casters].chunks(3) {
        match mode(triangle) {
            AlphaMode::Mask(cutoff) if cutoff > 0.0 => masked.push(triangle),
            AlphaMode::Blend => blended.push(triangle),
            _ => opaque.push(triangle),
        }
    }
    let groups = TriangleGroups {
        cutout_start: (opaque.len() * 3) as u32,
        blended_start: ((opaque.len() + masked.len()) * 3) as u32,
    };
    let ordered: Vec<u32> = [opaque, masked, blended]
        .into_iter()
        .flatten()
        .flatten()
        .copied()
        .collect();
    scene.indices[..ordered.len()].copy_from_slice(&ordered);
    sort_blended(scene, groups);
    groups
}

/// Sorts the blended casters of `scene` (`groups.blended_start..caster_indices` of its
/// indices, as [`order_triangles`] leaves them) back to front from the camera, by the distance
/// of their centroids; again after the vertices or the camera move (an animated scene).
pub(super) fn sort_blended(scene: &mut Scene, groups: TriangleGroups) {
    let casters = (scene.caster_indices as usize).min(scene.indices.len());
    let start = (groups.blended_start as usize).min(casters);
    let depth = |triangle: &[u32]| {
        let sum: Vec3 = triangle
            .iter()
            .filter_map(|&i| scene.vertices.get(i as usize))
            .map(|v| Vec3::from(v.position))
            .sum();
        scene.camera.sort_depth(sum / 3.0)
    };
    // Farthest first; each depth computed once.
    let mut by_depth: Vec<(f32, [u32; 3])> = scene.indices[start..casters]
        .chunks_exact(3)
        .map(|t| (depth(t), [t[0], t[1], t[2]]))
        .collect();
    by_depth.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (slot, (_, triangle)) in scene.indices[start..casters]
        .chunks_exact_mut(3)
        .zip(by_depth)
    {
        slot.copy_from_slice(&triangle);
    }
}

/// Makes the blended materials of `scene` opaque (an adapter that cannot blend `Rgba32Float`
/// targets), with a warning that says how many.
pub(super) fn draw_blended_opaque(scene: &mut Scene) {
    let blended = scene
        .materials
        .iter_mut()
        .filter(|m| m.alpha_mode == scene::AlphaMode::Blend)
        .map(|m| m.alpha_mode = scene::AlphaMode::Opaque)
        .count();
    if blended > 0 {
        tracing::warn!(
            "{blended} blended material(s) drawn opaque: the adapter cannot blend Rgba32Float \
             targets (wgpu's FLOAT32_BLENDABLE)"
        );
    }
}

impl Renderer {
    /// Opens the preferred adapter ([`Gpu::new`]) and builds a renderer.
    pub fn new(scene: Scene, settings: RenderSettings) -> Result<Self, RenderError> {
        let gpu = Gpu::new()?;
        Self::with_gpu(gpu, scene, settings)
    }

    /// Builds a renderer on an open device.
    pub fn with_gpu(
        gpu: Gpu,
        mut scene: Scene,
        mut settings: RenderSettings,
    ) -> Result<Self, RenderError> {
        use wgpu::util::DeviceExt;
        let max_dim = gpu.device.limits().max_texture_dimension_2d;
        if settings.width == 0
            || settings.height == 0
            || settings.width > max_dim
            || settings.height > max_dim
        {
            return Err(RenderError::Settings(format!(
                "image size {}x{} outside 1..={max_dim}",
                settings.width, settings.height
            )));
        }
        let s = settings.supersample;
        if !(1..=supersample::MAX_SUPERSAMPLE).contains(&s) {
            return Err(RenderError::Settings(format!(
                "supersampling {s} outside 1..={}",
                supersample::MAX_SUPERSAMPLE
            )));
        }
        if settings.fxaa && s > 1 {
            return Err(RenderError::Settings(format!(
                "FXAA with supersampling {s}: FXAA blurs the resolved edges (further from their \
                 covered fraction than the supersampling alone, docs/rendering.md); choose one"
            )));
        }
        if u64::from(settings.width.max(settings.height)) * u64::from(s) > u64::from(max_dim) {
            return Err(RenderError::Settings(format!(
                "image size {}x{} supersampled {s}× is {}x{}, past the adapter's largest \
                 texture side {max_dim}; a smaller size or supersampling",
                settings.width,
                settings.height,
                u64::from(settings.width) * u64::from(s),
                u64::from(settings.height) * u64::from(s),
            )));
        }
        if !(16..=max_dim).contains(&settings.shadow_resolution) {
            return Err(RenderError::Settings(format!(
                "shadow map resolution {} outside 16..={max_dim}",
                settings.shadow_resolution
            )));
        }
        if scene.indices.is_empty() {
            return Err(RenderError::Settings("the scene has no triangles".into()));
        }
        if !(1..=textures::MAX_ANISOTROPY).contains(&settings.texture_anisotropy) {
            return Err(RenderError::Settings(format!(
                "texture anisotropy {} outside 1..={}",
                settings.texture_anisotropy,
                textures::MAX_ANISOTROPY
            )));
        }
        settings.shadow_raster = settings
            .shadow_raster
            .resolve_for(
                gpu.info.device_type,
                ComputeShadows::max_maps(&gpu.device, settings.shadow_resolution),
                settings.shadow_resolution,
            )
            .map_err(RenderError::Settings)?;
        // A buffer past the device's limit is a validation error, and wgpu's buffer
        // initialisation then panicked on the invalid buffer's mapping.
        let max_buffer = gpu.device.limits().max_buffer_size;
        for (what, count, bytes) in [
            (
                "vertices",
                scene.vertices.len(),
                std::mem::size_of_val(scene.vertices.as_slice()),
            ),
            (
                "triangle indices",
                scene.indices.len(),
                std::mem::size_of_val(scene.indices.as_slice()),
            ),
        ] {
            if bytes as u64 > max_buffer {
                return Err(RenderError::Settings(format!(
                    "the scene's {count} {what} take {bytes} bytes, more than the largest \
                     buffer the adapter allows ({max_buffer} bytes); simplify the model"
                )));
            }
        }
        if !gpu.float32_blendable {
            draw_blended_opaque(&mut scene);
        }
        let groups = order_triangles(&mut scene);
        let layered_gbuffer = scene
            .materials
            .iter()
            .any(scene::Material::needs_layered_gbuffer);
        let device = &gpu.device;
        let vertex_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: bytemuck::cast_slice(&scene.vertices),
            // Storage: the compute rasteriser reads the positions. Copied to: an animated
            // scene's poses (`Renderer::set_scene_time`).
            usage: wgpu::BufferUsages::VERTEX
                | wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST,
        });
        let index_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("indices"),
            contents: bytemuck::cast_slice(&scene.indices),
            // Copied to: an animated scene's blended triangles, sorted again.
            usage: wgpu::BufferUsages::INDEX
                | wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST,
        });
        let texture_plan = textures::plan_layers(&scene, max_dim);
        let surface_textures = textures::SurfaceTextures::new(
            &gpu.device,
            &gpu.queue,
            &scene,
            &texture_plan,
            settings.texture_anisotropy,
        )
        .map_err(|e| RenderError::Settings(e.to_string()))?;
        let materials: Vec<shading::MaterialRaw> = scene
            .materials
            .iter()
            .zip(textures::material_layers(&scene, &texture_plan))
            .enumerate()
            .map(|(i, (m, layers))| {
                let catcher = settings.shadow_catcher && scene.ground_material == Some(i as u32);
                m.to_raw(if catcher { shading::FLAG_CATCHER } else { 0 }, layers)
            })
            .collect();
        let material_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("materials"),
            contents: bytemuck::cast_slice(&materials),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let globals_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("globals"),
            size: std::mem::size_of::<shading::GlobalsRaw>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let light_capacity = 64;
        let light_buffer = Self::make_light_buffer(device, light_capacity);
        let align = u64::from(device.limits().min_uniform_buffer_offset_alignment);
        let light_cam_stride = 64u64.div_ceil(align) * align;
        let light_cam_capacity = 64;
        let light_cam_buffer =
            Self::make_light_cam_buffer(device, light_cam_stride, light_cam_capacity);
        let shadow = Self::make_shadow_array(device, settings.shadow_resolution, 1);
        let shadow_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow comparison"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });

        // The fragment stages: the G-buffer pass reads the materials' factors and texture
        // layers, the blended pass shades as the compute pass does.
        let shading_stages = wgpu::ShaderStages::COMPUTE | wgpu::ShaderStages::FRAGMENT;
        let [lights_entry, maps_entry, sampler_entry, depths_entry] =
            SHADE_SHADOW_BINDINGS.layout_entries(shading_stages);
        let shade_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shade"),
            entries: &[
                uniform_entry(0, wgpu::ShaderStages::VERTEX | shading_stages),
                lights_entry,
                wgpu::BindGroupLayoutEntry {
                    visibility: shading_stages,
                    ..compute_storage_entry(2, true)
                },
                maps_entry,
                sampler_entry,
                depths_entry,
            ],
        });
        let shadow_cam_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("light camera"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: true,
                        min_binding_size: wgpu::BufferSize::new(64),
                    },
                    count: None,
                },
                // The materials, for the cut-out casters' alpha.
                wgpu::BindGroupLayoutEntry {
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ..compute_storage_entry(1, true)
                },
            ],
        });

        let gbuffer_texture =
            |binding| unfiltered_texture_entry(binding, wgpu::ShaderStages::COMPUTE);
        let gbuffer_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("g-buffer and frame"),
            entries: &[
                gbuffer_texture(0),
                gbuffer_texture(1),
                gbuffer_texture(3),
                gbuffer_texture(4),
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                frame_storage_entry(2),
            ],
        });

        let shade_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shade.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADE_WGSL.into()),
        });
        let shadow_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shadow.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADOW_WGSL.into()),
        });
        let gbuffer_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("g-buffer"),
            bind_group_layouts: &[Some(&shade_layout), None, Some(&surface_textures.layout)],
            immediate_size: 0,
        });
        let shade_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shade"),
            bind_group_layouts: &[Some(&shade_layout), Some(&gbuffer_layout)],
            immediate_size: 0,
        });
        let shadow_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shadow"),
            bind_group_layouts: &[Some(&shadow_cam_layout)],
            immediate_size: 0,
        });
        let shadow_attrs = wgpu::vertex_attr_array![0 => Float32x3];
        let gbuffer_pipeline = depth_tested_pipeline(
            device,
            "g-buffer",
            &gbuffer_pl,
            &shade_module,
            ("vs_main", &SURFACE_ATTRIBUTES),
            wgpu::DepthBiasState::default(),
            Some(if layered_gbuffer {
                ("fs_gbuffer_layered", &GBUFFER_FORMATS[..])
            } else {
                ("fs_gbuffer", &GBUFFER_FORMATS[..GBUFFER_TARGETS - 1])
            }),
            None,
        );
        let blended_pipeline = (groups.blended_start < scene.caster_indices).then(|| {
            depth_tested_pipeline(
                device,
                "blended",
                &gbuffer_pl,
                &shade_module,
                ("vs_main", &SURFACE_ATTRIBUTES),
                wgpu::DepthBiasState::default(),
                Some(("fs_blended", &[COLOR_FORMAT])),
                Some(wgpu::BlendState::PREMULTIPLIED_ALPHA_BLENDING),
            )
        });
        let shade_pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("shade"),
            layout: Some(&shade_pl),
            module: &shade_module,
            entry_point: Some("cs_shade"),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants: &[("LAYERED_GBUFFER", f64::from(u8::from(layered_gbuffer)))],
                ..Default::default()
            },
            cache: None,
        });
        let shadow_bias = wgpu::DepthBiasState {
            constant: 2,
            slope_scale: 1.5,
            clamp: 0.0,
        };
        let shadow_pipeline = depth_tested_pipeline(
            device,
            "shadow",
            &shadow_pl,
            &shadow_module,
            ("vs_main", &shadow_attrs),
            shadow_bias,
            None,
            None,
        );
        // The cut-out casters: the same maps, with the materials and their textures, and a
        // fragment stage that discards where the alpha is below the cutoff (no colour target).
        let masked_shadow_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("masked shadow"),
            bind_group_layouts: &[
                Some(&shadow_cam_layout),
                None,
                Some(&surface_textures.layout),
            ],
            immediate_size: 0,
        });
        let masked_shadow_pipeline = depth_tested_pipeline(
            device,
            "masked shadow",
            &masked_shadow_pl,
            &shadow_module,
            ("vs_masked", &MASKED_SHADOW_ATTRIBUTES),
            shadow_bias,
            Some(("fs_masked", &[])),
            None,
        );

        let (width, height) = (settings.width * s, settings.height * s);
        let (color_texture, color_view, depth_view) = Self::make_targets(device, width, height);
        let gbuffer_views = Self::make_gbuffer(device, width, height, layered_gbuffer);
        let (out_width, out_height) = (settings.width, settings.height);
        let post_pass = if s > 1 {
            Some(supersample::resolve(
                device,
                &color_view,
                out_width,
                out_height,
            ))
        } else if settings.fxaa {
            Some(post::fxaa(device, &color_view, out_width, out_height))
        } else {
            None
        };
        let gbuffer_bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("g-buffer and frame"),
            layout: &gbuffer_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[0]),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[1]),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&color_view),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[2]),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[3]),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: wgpu::BindingResource::TextureView(&gbuffer_views[4]),
                },
            ],
        });
        let padded_row = (settings.width * 16).div_ceil(256) * 256;
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded_row) * u64::from(settings.height),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let timestamps = gpu.timestamps.then(|| Timestamps {
            set: device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("frame timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: TIMESTAMPS,
            }),
            resolve: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: 8 * u64::from(TIMESTAMPS),
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            read: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp read"),
                size: 8 * u64::from(TIMESTAMPS),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            period_ns: gpu.queue.get_timestamp_period(),
        });
        // The compute rasteriser and its depth buffer, or a placeholder for binding 5.
        let compute_shadows = (settings.shadow_raster == ShadowRaster::Compute).then(|| {
            ComputeShadows::new(
                device,
                &scene,
                (&vertex_buffer, &index_buffer, &material_buffer),
                &surface_textures,
                settings.shadow_resolution,
            )
        });
        let no_shadow_depths = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("no compute shadow maps"),
            size: 4,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let shade_bind_group = Self::make_shade_bind_group(
            device,
            &shade_layout,
            &globals_buffer,
            &light_buffer,
            &material_buffer,
            &shadow.array_view,
            &shadow_sampler,
            compute_shadows
                .as_ref()
                .map_or(&no_shadow_depths, ComputeShadows::depths),
        );
        let shadow_cam_bind_group = Self::make_cam_bind_group(
            device,
            &shadow_cam_layout,
            &light_cam_buffer,
            &material_buffer,
        );
        let facing = shadow::facing_normals(&scene);
        let still_facing = shadow::still_facing(&scene);
        if let Some(error) = gpu.take_error() {
            return Err(RenderError::Gpu(format!(
                "{error} (a smaller --size or --shadow-res needs less GPU memory)"
            )));
        }
        Ok(Self {
            gpu,
            scene,
            settings,
            facing,
            still_facing,
            vertex_buffer,
            index_buffer,
            material_buffer,
            globals_buffer,
            light_buffer,
            light_capacity,
            light_cam_buffer,
            light_cam_stride,
            light_cam_capacity,
            shadow,
            shadow_sampler,
            shade_layout,
            shadow_cam_layout,
            shade_bind_group,
            shadow_cam_bind_group,
            gbuffer_bind_group,
            gbuffer_pipeline,
            shade_pipeline,
            shadow_pipeline,
            masked_shadow_pipeline,
            groups,
            blended_pipeline,
            color_view,
            color_texture,
            post_pass,
            depth_view,
            gbuffer_views,
            layered_gbuffer,
            surface_textures,
            readback,
            padded_row,
            timestamps,
            warned_layers: false,
            asg_pass: None,
            sh_pass: None,
            compute_shadows,
            no_shadow_depths,
            shadow_bindings_generation: 0,
        })
    }

    pub(super) fn make_light_buffer(device: &wgpu::Device, capacity: usize) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("lights"),
            size: (capacity.max(1) * std::mem::size_of::<shading::LightRaw>()) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    pub(super) fn make_light_cam_buffer(
        device: &wgpu::Device,
        stride: u64,
        capacity: usize,
    ) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("light cameras"),
            size: stride * capacity.max(1) as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    pub(super) fn make_shadow_array(
        device: &wgpu::Device,
        resolution: u32,
        layers: u32,
    ) -> ShadowArray {
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow maps"),
            size: wgpu::Extent3d {
                width: resolution,
                height: resolution,
                depth_or_array_layers: layers,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let layer_views = (0..layers)
            .map(|i| {
                texture.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("shadow layer"),
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: i,
                    array_layer_count: Some(1),
                    ..Default::default()
                })
            })
            .collect();
        let array_view = texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some("shadow array"),
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        ShadowArray {
            _texture: texture,
            layer_views,
            array_view,
            layers,
        }
    }

    /// The G-buffer's targets ([`GBUFFER_FORMATS`]): world position + material, normal +
    /// roughness, base colour + metallic, emission + occlusion, the layers over the base (1 × 1
    /// unless `layered`).
    fn make_gbuffer(
        device: &wgpu::Device,
        width: u32,
        height: u32,
        layered: bool,
    ) -> [wgpu::TextureView; GBUFFER_TARGETS] {
        let labels = [
            "g-buffer position",
            "g-buffer normal",
            "g-buffer surface",
            "g-buffer emission",
            "g-buffer layers",
        ];
        std::array::from_fn(|i| {
            let (label, format) = (labels[i], GBUFFER_FORMATS[i]);
            let (width, height) = if i + 1 < GBUFFER_TARGETS || layered {
                (width, height)
            } else {
                (1, 1)
            };
            let usage =
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
            texture_2d(device, label, (width, height), format, usage)
                .create_view(&Default::default())
        })
    }

    fn make_targets(
        device: &wgpu::Device,
        width: u32,
        height: u32,
    ) -> (wgpu::Texture, wgpu::TextureView, wgpu::TextureView) {
        let color = texture_2d(
            device,
            "color",
            (width, height),
            COLOR_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::STORAGE_BINDING,
        );
        let depth = texture_2d(
            device,
            "depth",
            (width, height),
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let cv = color.create_view(&Default::default());
        let dv = depth.create_view(&Default::default());
        (color, cv, dv)
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn make_shade_bind_group(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        globals: &wgpu::Buffer,
        lights: &wgpu::Buffer,
        materials: &wgpu::Buffer,
        shadow_view: &wgpu::TextureView,
        sampler: &wgpu::Sampler,
        shadow_depths: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let [lights, maps, sampler, depths] =
            SHADE_SHADOW_BINDINGS.bind_entries(lights, shadow_view, sampler, shadow_depths);
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("shade"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: globals.as_entire_binding(),
                },
                lights,
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: materials.as_entire_binding(),
                },
                maps,
                sampler,
                depths,
            ],
        })
    }

    pub(super) fn make_cam_bind_group(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        buffer: &wgpu::Buffer,
        materials: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("light camera"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer,
                        offset: 0,
                        size: wgpu::BufferSize::new(64),
                    }),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: materials.as_entire_binding(),
                },
            ],
        })
    }
}
