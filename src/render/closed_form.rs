//! What the closed-form lighting passes ([`super::asg`], [`super::sh`]) share: a scene pass
//! whose fragment shader sums the lighting per pixel, with its pipelines for opaque and blended
//! surfaces, encoded after the frame's shadow maps (the ASG lobes' maps; none for SH) and
//! before the post pass, timed and waited for as the light pass is.

use super::Renderer;

/// The pipelines of a closed-form pass: `fs_main` for the opaque surfaces and, where the scene
/// has blended ones, `fs_blended` drawn over them back to front (premultiplied alpha).
pub(super) struct SurfacePipelines {
    pub(super) opaque: wgpu::RenderPipeline,
    pub(super) blended: Option<wgpu::RenderPipeline>,
}

impl SurfacePipelines {
    /// The pipelines of `module` (entry points `vs_main`, `fs_main`, `fs_blended`) with
    /// `layout`, named after `label`.
    pub(super) fn new(
        renderer: &Renderer,
        label: &str,
        layout: &wgpu::PipelineLayout,
        module: &wgpu::ShaderModule,
    ) -> Self {
        let device = &renderer.gpu.device;
        let pipeline = |label: &str, entry: &str, blend: Option<wgpu::BlendState>| {
            super::depth_tested_pipeline(
                device,
                label,
                layout,
                module,
                ("vs_main", &super::SURFACE_ATTRIBUTES),
                wgpu::DepthBiasState::default(),
                Some((entry, &[super::COLOR_FORMAT])),
                blend,
            )
        };
        Self {
            opaque: pipeline(label, "fs_main", None),
            blended: renderer.blended_pipeline.is_some().then(|| {
                pipeline(
                    &format!("{label} blended"),
                    "fs_blended",
                    Some(wgpu::BlendState::PREMULTIPLIED_ALPHA_BLENDING),
                )
            }),
        }
    }
}

impl Renderer {
    /// A frame of a closed-form pass: the first `maps` shadow maps, the pass (`label`, its
    /// pipelines with their group 0; none before the pass is built), the post pass, the
    /// timestamps' resolve and, with `readback`, the image's copy. GPU timestamps as the light
    /// pass's: the shadow maps' start (0), the shading's (1), the frame's end (2) after the
    /// last pass.
    pub(super) fn encode_closed_form(
        &self,
        label: &str,
        pass: Option<(&SurfacePipelines, &wgpu::BindGroup)>,
        maps: usize,
        readback: bool,
    ) -> wgpu::CommandEncoder {
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        self.encode_shadow_maps(&mut enc, maps);
        let ts = self.timestamps.as_ref();
        let post = self.post_pass.is_some();
        if let Some((pipelines, bind_group)) = pass {
            self.encode_scene_pass(
                &mut enc,
                label,
                &[&self.color_view],
                &pipelines.opaque,
                bind_group,
                ts.map(|t| wgpu::RenderPassTimestampWrites {
                    query_set: &t.set,
                    beginning_of_pass_write_index: Some(1),
                    end_of_pass_write_index: (!post).then_some(2),
                }),
                pipelines.blended.as_ref(),
            );
        }
        self.encode_post_pass(&mut enc, ts.filter(|_| post).map(|t| (t, 2)));
        if let Some(t) = ts {
            enc.resolve_query_set(&t.set, 0..super::TIMESTAMPS, &t.resolve, 0);
            enc.copy_buffer_to_buffer(&t.resolve, 0, &t.read, 0, 8 * u64::from(super::TIMESTAMPS));
        }
        if readback {
            self.encode_readback(&mut enc);
        }
        enc
    }
}
