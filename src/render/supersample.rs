//! Supersampling anti-aliasing ([`super::RenderSettings::supersample`]): every pass renders at
//! s times the output's width and height (s² samples a pixel on a regular grid), and a compute
//! pass (`shaders/resolve.wgsl`) averages each pixel's s × s samples into the output image — a
//! box filter, in linear HDR with premultiplied alpha. Edges, shadow-catcher boundaries and
//! texture detail are resolved exactly to 1/s² of a pixel's coverage, at s² times the shading
//! and G-buffer memory; the shadow maps do not change.
//!
//! Supersampling rather than MSAA: the shading is deferred (a compute pass over a G-buffer), and
//! MSAA would need the G-buffer per sample and the shading per distinct sample along edges;
//! supersampling shades every sample and so also anti-aliases what MSAA does not (specular
//! highlights smaller than a pixel, texture and shadow edges).

use super::{COLOR_FORMAT, SHADE_WORKGROUP};

/// The largest supersampling factor (16 samples a pixel).
pub const MAX_SUPERSAMPLE: u32 = 4;

/// WGSL source of the resolve pass.
pub const RESOLVE_WGSL: &str = include_str!("../../shaders/resolve.wgsl");

/// The output image and the pass that resolves the samples into it.
pub(super) struct Resolve {
    pub(super) texture: wgpu::Texture,
    pub(super) view: wgpu::TextureView,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    width: u32,
    height: u32,
}

impl Resolve {
    /// An output image of `width` × `height` resolved from `samples` (the frame at s times
    /// that size, `Rgba32Float`).
    pub(super) fn new(
        device: &wgpu::Device,
        samples: &wgpu::TextureView,
        width: u32,
        height: u32,
    ) -> Self {
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("resolved frame"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: COLOR_FORMAT,
            usage: wgpu::TextureUsages::STORAGE_BINDING
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let view = texture.create_view(&Default::default());
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("resolve"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: COLOR_FORMAT,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                    count: None,
                },
            ],
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("resolve"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(samples),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
            ],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("resolve.wgsl"),
            source: wgpu::ShaderSource::Wgsl(RESOLVE_WGSL.into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("resolve"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("resolve"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("cs_resolve"),
            compilation_options: Default::default(),
            cache: None,
        });
        Self {
            texture,
            view,
            pipeline,
            bind_group,
            width,
            height,
        }
    }

    /// Encodes the resolve; `timestamp_writes`: the frame's end, where this pass ends it.
    pub(super) fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("resolve"),
            timestamp_writes,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.dispatch_workgroups(
            self.width.div_ceil(SHADE_WORKGROUP),
            self.height.div_ceil(SHADE_WORKGROUP),
            1,
        );
    }
}
