//! The passes after the shading, each a compute pass from one `Rgba32Float` image to a new one:
//! supersampling's resolve ([`super::supersample`], `shaders/resolve.wgsl`) and fast
//! approximate anti-aliasing (`shaders/fxaa.wgsl`, [`FXAA_WGSL`]). `PostPass` holds one
//! such pass; the renderer runs the one its settings ask for (the two are not combined: FXAA
//! blurs resolved edges) and reads its image.

use super::{COLOR_FORMAT, SHADE_WORKGROUP};

/// WGSL source of the FXAA pass (Lottes's FXAA 3.11, quality variant; the file's header says
/// the steps).
pub const FXAA_WGSL: &str = include_str!("../../shaders/fxaa.wgsl");

/// The FXAA pass over `input` (`width` × `height`).
pub(super) fn fxaa(
    device: &wgpu::Device,
    input: &wgpu::TextureView,
    width: u32,
    height: u32,
) -> PostPass {
    PostPass::new(device, ("fxaa", FXAA_WGSL, "cs_fxaa"), input, width, height)
}

/// A compute pass from one image to a new one of the output's size: its output texture, its
/// pipeline and its bindings (the input at binding 0, the output at binding 1).
pub(super) struct PostPass {
    pub(super) texture: wgpu::Texture,
    pub(super) view: wgpu::TextureView,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    width: u32,
    height: u32,
    label: String,
}

impl PostPass {
    /// The pass of `entry` in WGSL source `wgsl` (named `label`), from `input` (an
    /// `Rgba32Float` image, read with `textureLoad`) into a new `Rgba32Float` image of
    /// `width` × `height`, one invocation a pixel in 8 × 8 workgroups.
    pub(super) fn new(
        device: &wgpu::Device,
        (label, wgsl, entry): (&str, &str, &str),
        input: &wgpu::TextureView,
        width: u32,
        height: u32,
    ) -> Self {
        let texture = super::texture_2d(
            device,
            label,
            (width, height),
            COLOR_FORMAT,
            wgpu::TextureUsages::STORAGE_BINDING
                | wgpu::TextureUsages::COPY_SRC
                | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let view = texture.create_view(&Default::default());
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries: &[
                super::unfiltered_texture_entry(0, wgpu::ShaderStages::COMPUTE),
                super::frame_storage_entry(1),
            ],
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(input),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
            ],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(wgsl.into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some(entry),
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
            label: label.to_string(),
        }
    }

    /// Encodes the pass; `timestamp_writes`: the frame's end, where this pass ends it.
    pub(super) fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(&self.label),
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
