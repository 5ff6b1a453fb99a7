//! One frame: the lights and shadow cameras written ([`Renderer::prepare`]), the passes
//! encoded in order (shadow maps, G-buffer, shading, blended surfaces, resolve or FXAA,
//! read-back), the wait for the GPU and its timestamps.

use super::*;

impl Renderer {
    /// The texture behind [`Self::color_view`].
    fn output_texture(&self) -> &wgpu::Texture {
        self.post_pass
            .as_ref()
            .map_or(&self.color_texture, |p| &p.texture)
    }

    /// Encodes the pass after the shading (resolve or FXAA), where there is one, writing
    /// `frame_end`.
    pub(super) fn encode_post_pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        frame_end: Option<(&Timestamps, u32)>,
    ) {
        if let Some(pass) = &self.post_pass {
            pass.encode(
                enc,
                frame_end.map(|(t, end)| wgpu::ComputePassTimestampWrites {
                    query_set: &t.set,
                    beginning_of_pass_write_index: None,
                    end_of_pass_write_index: Some(end),
                }),
            );
        }
    }

    pub(super) fn clip_planes(&self) -> (f32, f32) {
        let b = self.scene.bounds;
        let d = self.scene.camera.eye.distance(b.center);
        let far = (d + b.radius) * 8.0 + 10.0;
        let near = (far * 1e-4).max(1e-3);
        (near, far)
    }

    /// Writes the frame's lights and shadow cameras; returns the GPU lights and the number of
    /// shadow maps.
    pub(super) fn prepare(
        &mut self,
        lights: &[Light],
    ) -> Result<(Vec<GpuLight>, usize), RenderError> {
        let device = &self.gpu.device;
        let mut gpu_lights: Vec<GpuLight> =
            lights.iter().filter_map(GpuLight::from_light).collect();
        let res = self.settings.shadow_resolution;
        let bounds = self.scene.bounds;
        // Shadow maps: one layer each, at most as many as the adapter's texture arrays allow
        // (render passes) or its largest storage buffer holds (compute).
        let (max_maps, limit) = match &self.compute_shadows {
            Some(compute) => (
                compute.map_limit(),
                "what the adapter's largest storage buffer holds",
            ),
            None => (
                self.gpu.max_array_layers,
                "the adapter's texture-array layer limit",
            ),
        };
        let mut mapped: Vec<usize> = Vec::new();
        let mut skipped = 0usize;
        if self.settings.shadows {
            for (i, l) in gpu_lights.iter().enumerate() {
                if !shadow::reaches_visible(&self.facing, l.dir) {
                    continue;
                }
                if mapped.len() as u32 >= max_maps {
                    skipped += 1;
                    continue;
                }
                mapped.push(i);
            }
        }
        let maps = mapped.len() as u32;
        if skipped > 0 && !self.warned_layers {
            tracing::warn!(
                "{skipped} lights drawn without shadows: at most {max_maps} shadow maps \
                 ({limit})"
            );
            self.warned_layers = true;
        }
        let mut rebind = false;
        if gpu_lights.len() > self.light_capacity {
            // The adapter binds a storage buffer of at most so many bytes: a frame of more
            // lights is an error that says so (it was a validation error about "buffer binding
            // 1", after the frame had been drawn; found by an audit).
            let light_bytes = std::mem::size_of::<shading::LightRaw>() as u64;
            let most = device.limits().max_storage_buffer_binding_size / light_bytes;
            if gpu_lights.len() as u64 > most {
                return Err(RenderError::Settings(format!(
                    "a frame of {} lights is more than this adapter can shade in one pass \
                     (its storage buffers hold at most {most} lights); give fewer lights",
                    gpu_lights.len()
                )));
            }
            self.light_capacity = gpu_lights.len().next_power_of_two().min(most as usize);
            self.light_buffer = Self::make_light_buffer(device, self.light_capacity);
            rebind = true;
        }
        for (k, &i) in mapped.iter().enumerate() {
            let l = &mut gpu_lights[i];
            l.layer = Some(k as u32);
            l.view_proj = shadow::light_view_proj(l.dir, bounds);
            l.pcf_radius = shadow::pcf_radius_uv(l.solid_angle, res);
        }
        let cameras = mapped.iter().map(|&i| gpu_lights[i].view_proj);
        rebind |= match self.compute_shadows.as_mut() {
            Some(compute) => compute.prepare(&self.gpu, cameras),
            None => self.prepare_shadow_passes(cameras),
        };
        let device = &self.gpu.device;
        if rebind {
            self.shade_bind_group = Self::make_shade_bind_group(
                device,
                &self.shade_layout,
                &self.globals_buffer,
                &self.light_buffer,
                &self.material_buffer,
                &self.shadow.array_view,
                &self.shadow_sampler,
                self.shadow_depths(),
            );
            self.shadow_bindings_generation += 1;
        }
        let raw: Vec<shading::LightRaw> = gpu_lights.iter().map(GpuLight::to_raw).collect();
        if !raw.is_empty() {
            self.gpu
                .queue
                .write_buffer(&self.light_buffer, 0, bytemuck::cast_slice(&raw));
        }
        let globals = self.frame_globals(gpu_lights.len() as u32);
        self.gpu.queue.write_buffer(
            &self.globals_buffer,
            0,
            bytemuck::bytes_of(&globals.to_raw()),
        );
        self.check_gpu()?;
        Ok((gpu_lights, maps as usize))
    }

    /// The compute rasteriser's depth buffer, or the placeholder bound in its place.
    pub(super) fn shadow_depths(&self) -> &wgpu::Buffer {
        self.compute_shadows
            .as_ref()
            .map_or(&self.no_shadow_depths, ComputeShadows::depths)
    }

    /// The light pass's constants for a frame of `light_count` lights (the shadow lookup's
    /// offsets follow the map side and the casters' bounds).
    pub(super) fn frame_globals(&self, light_count: u32) -> Globals {
        let res = self.settings.shadow_resolution;
        let texel_world = 2.0 * self.scene.bounds.radius / res as f32;
        Globals {
            view_proj: self.view_proj(),
            viewer: self.scene.camera.viewer(),
            light_count,
            culling: self.settings.culling,
            shadows: self.settings.shadows,
            shadow_raster: self.settings.shadow_raster,
            shadow_resolution: res,
            normal_offset: 2.0 * texel_world,
            depth_bias: 1.0 / res as f32,
        }
    }

    /// The render passes' part of [`Self::prepare`]: grows the depth array and the light-camera
    /// buffer to hold the frame's maps and writes their cameras (map k's at the k-th dynamic
    /// offset); returns whether the array was replaced (the shading pass must bind the new one).
    fn prepare_shadow_passes(&mut self, cameras: impl ExactSizeIterator<Item = Mat4>) -> bool {
        let device = &self.gpu.device;
        let maps = cameras.len();
        let mut grown = false;
        if maps as u32 > self.shadow.layers {
            let layers = (maps as u32)
                .next_power_of_two()
                .min(self.gpu.max_array_layers);
            self.shadow = Self::make_shadow_array(device, self.settings.shadow_resolution, layers);
            grown = true;
        }
        if maps > self.light_cam_capacity {
            self.light_cam_capacity = maps.next_power_of_two();
            self.light_cam_buffer =
                Self::make_light_cam_buffer(device, self.light_cam_stride, self.light_cam_capacity);
            self.shadow_cam_bind_group = Self::make_cam_bind_group(
                device,
                &self.shadow_cam_layout,
                &self.light_cam_buffer,
                &self.material_buffer,
            );
        }
        if maps > 0 {
            let stride = self.light_cam_stride as usize;
            let mut cams = vec![0u8; stride * maps];
            for (k, m) in cameras.enumerate() {
                let at = stride * k;
                cams[at..at + 64].copy_from_slice(bytemuck::cast_slice(&m.to_cols_array()));
            }
            self.gpu
                .queue
                .write_buffer(&self.light_cam_buffer, 0, &cams);
        }
        grown
    }

    /// Fails with the first error the device reported (an allocation it could not make, such
    /// as shadow maps of a huge --shadow-res or targets of a huge --size) instead of rendering
    /// with the resource missing.
    fn check_gpu(&self) -> Result<(), RenderError> {
        match self.gpu.take_error() {
            Some(error) => Err(RenderError::Gpu(format!(
                "{error} (a smaller --size or --shadow-res needs less GPU memory)"
            ))),
            None => Ok(()),
        }
    }

    pub(super) fn encode(&self, maps: usize, readback: bool) -> wgpu::CommandEncoder {
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        let ts = self.timestamps.as_ref();
        self.encode_shadow_maps(&mut enc, maps);
        self.encode_gbuffer_pass(&mut enc);
        // The frame's end, written by its last pass: the resolve or FXAA where there is one,
        // else the blended surfaces' where there are any, else the shading.
        let frame_end = ts.map(|t| (t, 2));
        let (shade_end, blended_end, post_end) = match (&self.blended_pipeline, &self.post_pass) {
            (_, Some(_)) => (None, None, frame_end),
            (Some(_), None) => (None, frame_end, None),
            (None, None) => (frame_end, None, None),
        };
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("shade"),
                timestamp_writes: shade_end.map(|(t, end)| wgpu::ComputePassTimestampWrites {
                    query_set: &t.set,
                    beginning_of_pass_write_index: None,
                    end_of_pass_write_index: Some(end),
                }),
            });
            pass.set_pipeline(&self.shade_pipeline);
            pass.set_bind_group(0, &self.shade_bind_group, &[]);
            pass.set_bind_group(1, &self.gbuffer_bind_group, &[]);
            let s = self.settings.supersample;
            pass.dispatch_workgroups(
                (self.settings.width * s).div_ceil(SHADE_WORKGROUP),
                (self.settings.height * s).div_ceil(SHADE_WORKGROUP),
                1,
            );
        }
        if let Some(pipeline) = &self.blended_pipeline {
            self.encode_blended_pass(&mut enc, pipeline, blended_end);
        }
        self.encode_post_pass(&mut enc, post_end);
        if let Some(t) = ts {
            enc.resolve_query_set(&t.set, 0..TIMESTAMPS, &t.resolve, 0);
            enc.copy_buffer_to_buffer(&t.resolve, 0, &t.read, 0, 8 * u64::from(TIMESTAMPS));
        }
        if readback {
            self.encode_readback(&mut enc);
        }
        enc
    }

    /// One depth-only render pass per map into its layer of the depth array (the GPU timestamp
    /// of the frame's start at the first).
    /// The frame's `maps` shadow maps, by the compute rasteriser or by render passes (the
    /// frame's start timestamp at the first).
    pub(super) fn encode_shadow_maps(&self, enc: &mut wgpu::CommandEncoder, maps: usize) {
        match &self.compute_shadows {
            Some(compute) if maps > 0 => compute.encode(
                enc,
                maps as u32,
                self.timestamps
                    .as_ref()
                    .map(|t| wgpu::ComputePassTimestampWrites {
                        query_set: &t.set,
                        beginning_of_pass_write_index: Some(0),
                        end_of_pass_write_index: None,
                    }),
            ),
            Some(_) => {}
            None => self.encode_shadow_passes(enc, maps),
        }
    }

    fn encode_shadow_passes(&self, enc: &mut wgpu::CommandEncoder, maps: usize) {
        let ts = self.timestamps.as_ref();
        for layer in 0..maps {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.shadow.layer_views[layer],
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: ts.filter(|_| layer == 0).map(|t| {
                    wgpu::RenderPassTimestampWrites {
                        query_set: &t.set,
                        beginning_of_pass_write_index: Some(0),
                        end_of_pass_write_index: None,
                    }
                }),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.shadow_pipeline);
            pass.set_bind_group(
                0,
                &self.shadow_cam_bind_group,
                &[(layer as u64 * self.light_cam_stride) as u32],
            );
            pass.set_vertex_buffer(0, self.vertex_buffer.slice(..));
            pass.set_index_buffer(self.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..self.groups.cutout_start, 0, 0..1);
            if self.groups.cutout_start < self.scene.caster_indices {
                pass.set_pipeline(&self.masked_shadow_pipeline);
                pass.set_bind_group(2, &self.surface_textures.bind_group, &[]);
                pass.draw_indexed(self.groups.cutout_start..self.scene.caster_indices, 0, 0..1);
            }
        }
    }

    /// Draws the blended surfaces over the shaded frame (`fs_blended`, back to front as
    /// [`super::setup::order_triangles`] sorted them), depth-tested against the G-buffer pass's depth;
    /// `frame_end`: the timestamp to write at its end.
    fn encode_blended_pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::RenderPipeline,
        frame_end: Option<(&Timestamps, u32)>,
    ) {
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("blended"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &self.color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: frame_end.map(|(t, end)| wgpu::RenderPassTimestampWrites {
                query_set: &t.set,
                beginning_of_pass_write_index: None,
                end_of_pass_write_index: Some(end),
            }),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &self.shade_bind_group, &[]);
        pass.set_bind_group(2, &self.surface_textures.bind_group, &[]);
        pass.set_vertex_buffer(0, self.vertex_buffer.slice(..));
        pass.set_index_buffer(self.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
        pass.draw_indexed(
            self.groups.blended_start..self.scene.caster_indices,
            0,
            0..1,
        );
    }

    /// Rasterises the scene into the G-buffer (cleared to zero: no surface), all but the
    /// blended surfaces; their pass reads its depth afterwards.
    fn encode_gbuffer_pass(&self, enc: &mut wgpu::CommandEncoder) {
        let timestamps = self
            .timestamps
            .as_ref()
            .map(|t| wgpu::RenderPassTimestampWrites {
                query_set: &t.set,
                beginning_of_pass_write_index: Some(1),
                end_of_pass_write_index: None,
            });
        self.encode_scene_pass(
            enc,
            "g-buffer",
            &self.gbuffer_views.each_ref()[..if self.layered_gbuffer {
                GBUFFER_TARGETS
            } else {
                GBUFFER_TARGETS - 1
            }],
            &self.gbuffer_pipeline,
            &self.shade_bind_group,
            timestamps,
            None,
        );
    }

    /// Draws the scene but its blended surfaces with `pipeline` and `bind_group` into
    /// `targets` (cleared to transparent) over a fresh depth buffer, then the blended ones with
    /// `blended` where given: the G-buffer pass (whose depth is kept for the blended pass where
    /// the scene has blended surfaces), and the ASG pass into the colour target.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn encode_scene_pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        label: &str,
        targets: &[&wgpu::TextureView],
        pipeline: &wgpu::RenderPipeline,
        bind_group: &wgpu::BindGroup,
        timestamp_writes: Option<wgpu::RenderPassTimestampWrites<'_>>,
        blended: Option<&wgpu::RenderPipeline>,
    ) {
        let color_attachments: Vec<_> = targets
            .iter()
            .map(|view| {
                Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })
            })
            .collect();
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some(label),
            color_attachments: &color_attachments,
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: if self.blended_pipeline.is_some() {
                        wgpu::StoreOp::Store
                    } else {
                        wgpu::StoreOp::Discard
                    },
                }),
                stencil_ops: None,
            }),
            timestamp_writes,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        pass.set_bind_group(2, &self.surface_textures.bind_group, &[]);
        pass.set_vertex_buffer(0, self.vertex_buffer.slice(..));
        pass.set_index_buffer(self.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
        let blended_range = self.groups.blended_start..self.scene.caster_indices;
        pass.draw_indexed(0..blended_range.start, 0, 0..1);
        pass.draw_indexed(blended_range.end..self.scene.indices.len() as u32, 0, 0..1);
        if let Some(pipeline) = blended.filter(|_| !blended_range.is_empty()) {
            pass.set_pipeline(pipeline);
            pass.draw_indexed(blended_range, 0, 0..1);
        }
    }

    /// Copies the output image into the read-back buffer.
    pub(super) fn encode_readback(&self, enc: &mut wgpu::CommandEncoder) {
        {
            enc.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: self.output_texture(),
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &self.readback,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(self.padded_row),
                        rows_per_image: Some(self.settings.height),
                    },
                },
                wgpu::Extent3d {
                    width: self.settings.width,
                    height: self.settings.height,
                    depth_or_array_layers: 1,
                },
            );
        }
    }

    pub(super) fn wait(&self) -> Result<(), RenderError> {
        self.gpu
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| RenderError::Gpu(e.to_string()))
    }

    /// Maps `buffer`, waits, and hands its bytes to `f`.
    fn read_buffer<T>(
        &self,
        buffer: &wgpu::Buffer,
        f: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, RenderError> {
        let slice = buffer.slice(..);
        let (tx, rx) = crossbeam_channel::bounded(1);
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|e| RenderError::Gpu(format!("buffer map callback lost: {e}")))?
            .map_err(|e| RenderError::Gpu(format!("cannot map a buffer: {e}")))?;
        let out = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| RenderError::Gpu(format!("cannot read a mapped buffer: {e:?}")))?;
            f(&view)
        };
        buffer.unmap();
        Ok(out)
    }

    /// GPU time of the last frame and of its shadow passes (`None` without timestamps, or
    /// for the shadows without `shadow_passes`), in ms.
    pub(super) fn gpu_time(
        &self,
        shadow_passes: bool,
    ) -> Result<(Option<f64>, Option<f64>), RenderError> {
        let Some(t) = &self.timestamps else {
            return Ok((None, None));
        };
        let [shadows, shading, end] = self.read_buffer(&t.read, |b| {
            let v: &[u64] = bytemuck::cast_slice(b);
            [v[0], v[1], v[2]]
        })?;
        let ms = |from: u64, to: u64| {
            (to >= from).then(|| (to - from) as f64 * f64::from(t.period_ns) * 1e-6)
        };
        Ok(if shadow_passes {
            (ms(shadows, end), ms(shadows, shading))
        } else {
            (ms(shading, end), None)
        })
    }

    /// Reads the rendered image from the read-back buffer (after a frame encoded with it).
    pub(super) fn read_image(&self) -> Result<Image, RenderError> {
        let (w, h) = (self.settings.width as usize, self.settings.height as usize);
        let row = self.padded_row as usize;
        let rgba = self.read_buffer(&self.readback, |bytes| {
            let mut out = Vec::with_capacity(w * h * 4);
            for y in 0..h {
                let line = &bytes[y * row..y * row + w * 16];
                out.extend(
                    line.chunks_exact(4)
                        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                );
            }
            out
        })?;
        Ok(Image {
            width: self.settings.width,
            height: self.settings.height,
            rgba,
        })
    }
}
