//! Shadow maps rasterised by compute shaders ([`ShadowRaster::Compute`]): the frame's maps as
//! one storage buffer of `u32` depths, written by `shaders/shadow_raster.wgsl` (a clear, then
//! one invocation per shadow-casting triangle and map, atomicMin of the depth's bits; the
//! shader's header gives the steps) and read by the shading pass with a hand-made bilinear
//! depth comparison (`shaders/shade.wgsl`, `compare_tap`).
//!
//! The maps are the render pass's: the same orthographic light cameras, texel centres, depth
//! bias and two-sided casters, so the images of the two paths agree to the penumbra's last
//! texels (tests/render.rs bounds the difference). What differs is where the work runs: the
//! render pass goes through the raster pipeline's fill, which on a compute part such as the
//! H200 is a small part of the chip; the compute path runs on every multiprocessor
//! (docs/performance.md gives both).

use super::{compute_storage_entry, RenderError};

/// How the shadow maps are drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ShadowRaster {
    /// [`Self::Compute`] on a GPU, [`Self::Pipeline`] on a CPU rasteriser such as lavapipe:
    /// the faster of the two on each adapter measured (docs/performance.md, "Rendering").
    #[default]
    Auto,
    /// Depth-only render passes into a `Depth32Float` texture array, one per map.
    Pipeline,
    /// Compute shaders writing a storage buffer (this module).
    Compute,
}

impl ShadowRaster {
    /// The command-line and config spelling.
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Pipeline => "pipeline",
            Self::Compute => "compute",
        }
    }

    /// Parses [`Self::name`]'s spelling.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "auto" => Some(Self::Auto),
            "pipeline" => Some(Self::Pipeline),
            "compute" => Some(Self::Compute),
            _ => None,
        }
    }

    /// The way used on an adapter of type `device_type`: [`Self::Auto`] resolved, the others
    /// as they are.
    pub fn resolve(self, device_type: wgpu::DeviceType) -> Self {
        match (self, device_type) {
            (Self::Auto, wgpu::DeviceType::Cpu) => Self::Pipeline,
            (Self::Auto, _) => Self::Compute,
            (other, _) => other,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_auto_picks_by_adapter() {
        for r in [
            ShadowRaster::Auto,
            ShadowRaster::Pipeline,
            ShadowRaster::Compute,
        ] {
            assert_eq!(ShadowRaster::parse(r.name()), Some(r));
        }
        assert_eq!(ShadowRaster::parse("raster"), None);
        let auto = ShadowRaster::Auto;
        assert_eq!(auto.resolve(wgpu::DeviceType::Cpu), ShadowRaster::Pipeline);
        assert_eq!(
            auto.resolve(wgpu::DeviceType::DiscreteGpu),
            ShadowRaster::Compute
        );
        assert_eq!(
            auto.resolve(wgpu::DeviceType::IntegratedGpu),
            ShadowRaster::Compute
        );
        let pipeline = ShadowRaster::Pipeline;
        assert_eq!(pipeline.resolve(wgpu::DeviceType::DiscreteGpu), pipeline);
        let compute = ShadowRaster::Compute;
        assert_eq!(compute.resolve(wgpu::DeviceType::Cpu), compute);
    }
}

/// WGSL source of the compute rasteriser.
pub const SHADOW_RASTER_WGSL: &str = include_str!("../../shaders/shadow_raster.wgsl");

/// `cs_rasterize`'s workgroup (triangles per group).
const RASTER_WORKGROUP: u32 = 64;
/// `cs_clear`'s workgroup (texels per group and step).
const CLEAR_WORKGROUP: u32 = 256;

/// Matches `Params` in shadow_raster.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct ParamsRaw {
    resolution: u32,
    caster_triangles: u32,
    maps: u32,
    groups_x: u32,
}

/// The compute rasteriser's pipelines and buffers.
pub struct ComputeShadows {
    clear: wgpu::ComputePipeline,
    rasterize: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    params: wgpu::Buffer,
    /// One view-projection (64 bytes) per map.
    cameras: wgpu::Buffer,
    /// The maps' depths, `capacity` maps of `resolution²` texels.
    depths: wgpu::Buffer,
    capacity: u32,
    resolution: u32,
    caster_triangles: u32,
    max_workgroups: u32,
}

impl ComputeShadows {
    /// Builds the pipelines over the scene's vertex and index buffers (which need `STORAGE`
    /// usage), with room for one map.
    pub fn new(
        device: &wgpu::Device,
        vertices: &wgpu::Buffer,
        indices: &wgpu::Buffer,
        caster_indices: u32,
        resolution: u32,
    ) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shadow_raster.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADOW_RASTER_WGSL.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shadow raster"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                compute_storage_entry(1, true),
                compute_storage_entry(2, true),
                compute_storage_entry(3, true),
                compute_storage_entry(4, false),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shadow raster"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let clear = pipeline("cs_clear");
        let rasterize = pipeline("cs_rasterize");
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow raster params"),
            size: std::mem::size_of::<ParamsRaw>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let cameras = Self::make_cameras(device, 1);
        let depths = Self::make_depths(device, resolution, 1);
        let bind_group = Self::make_bind_group(
            device, &layout, &params, vertices, indices, &cameras, &depths,
        );
        Self {
            clear,
            rasterize,
            layout,
            bind_group,
            params,
            cameras,
            depths,
            capacity: 1,
            resolution,
            caster_triangles: caster_indices / 3,
            max_workgroups: device.limits().max_compute_workgroups_per_dimension,
        }
    }

    /// The most maps one frame can hold: the depth buffer within the adapter's largest storage
    /// binding and buffer, at most 2³¹ texels (so the shaders' `u32` texel indices and strided
    /// loops cannot wrap), and one dispatch row per map.
    pub fn max_maps(device: &wgpu::Device, resolution: u32) -> u32 {
        let limits = device.limits();
        let bytes = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            .min(4 << 31);
        let per_map = 4 * u64::from(resolution) * u64::from(resolution);
        (bytes / per_map.max(1))
            .min(u64::from(limits.max_compute_workgroups_per_dimension))
            .min(u64::from(u32::MAX)) as u32
    }

    fn make_cameras(device: &wgpu::Device, maps: u32) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow raster cameras"),
            size: 64 * u64::from(maps.max(1)),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    fn make_depths(device: &wgpu::Device, resolution: u32, maps: u32) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow raster depths"),
            size: 4 * u64::from(resolution) * u64::from(resolution) * u64::from(maps.max(1)),
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        })
    }

    fn make_bind_group(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        params: &wgpu::Buffer,
        vertices: &wgpu::Buffer,
        indices: &wgpu::Buffer,
        cameras: &wgpu::Buffer,
        depths: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = [params, vertices, indices, cameras, depths]
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("shadow raster"),
            layout,
            entries: &entries,
        })
    }

    /// The depth buffer the shading pass reads.
    pub fn depths(&self) -> &wgpu::Buffer {
        &self.depths
    }

    /// Writes the frame's light cameras (map k's at k) and grows the buffers to hold them;
    /// returns whether the depth buffer was replaced (the shading pass must bind the new one).
    pub fn prepare(
        &mut self,
        gpu: &super::device::Gpu,
        vertices: &wgpu::Buffer,
        indices: &wgpu::Buffer,
        cameras: &[glam::Mat4],
    ) -> Result<bool, RenderError> {
        let device = &gpu.device;
        let maps = u32::try_from(cameras.len())
            .map_err(|_| RenderError::Settings(format!("{} shadow maps", cameras.len())))?;
        let mut grown = false;
        if maps > self.capacity {
            let most = Self::max_maps(device, self.resolution).max(1);
            self.capacity = maps.next_power_of_two().min(most).max(maps);
            self.cameras = Self::make_cameras(device, self.capacity);
            self.depths = Self::make_depths(device, self.resolution, self.capacity);
            self.bind_group = Self::make_bind_group(
                device,
                &self.layout,
                &self.params,
                vertices,
                indices,
                &self.cameras,
                &self.depths,
            );
            grown = true;
        }
        if maps > 0 {
            let flat: Vec<f32> = cameras.iter().flat_map(|m| m.to_cols_array()).collect();
            gpu.queue
                .write_buffer(&self.cameras, 0, bytemuck::cast_slice(&flat));
        }
        let groups_x = self
            .caster_triangles
            .div_ceil(RASTER_WORKGROUP)
            .clamp(1, self.max_workgroups);
        let params = ParamsRaw {
            resolution: self.resolution,
            caster_triangles: self.caster_triangles,
            maps,
            groups_x,
        };
        gpu.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        Ok(grown)
    }

    /// Encodes the clear and the rasterisation of `maps` maps (as [`Self::prepare`] set them
    /// up) in one compute pass.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        maps: u32,
        timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("shadow maps (compute)"),
            timestamp_writes,
        });
        pass.set_bind_group(0, &self.bind_group, &[]);
        let texels = u64::from(maps) * u64::from(self.resolution) * u64::from(self.resolution);
        let clear_groups = texels
            .div_ceil(u64::from(CLEAR_WORKGROUP))
            .clamp(1, u64::from(self.max_workgroups)) as u32;
        pass.set_pipeline(&self.clear);
        pass.dispatch_workgroups(clear_groups, 1, 1);
        let groups_x = self
            .caster_triangles
            .div_ceil(RASTER_WORKGROUP)
            .clamp(1, self.max_workgroups);
        pass.set_pipeline(&self.rasterize);
        pass.dispatch_workgroups(groups_x, maps, 1);
    }
}
