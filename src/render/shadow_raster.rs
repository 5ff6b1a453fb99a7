//! Shadow maps rasterised by compute shaders ([`ShadowRaster::Compute`]): the frame's maps as
//! one storage buffer of `u32` depths, written by `shaders/shadow_raster.wgsl` (a clear, then
//! one invocation per small shadow-casting triangle and map, one workgroup per large one
//! ([`split_by_size`]), atomicMin of the depth's bits; the shader's header gives the steps) and
//! read by the shading pass with a hand-made bilinear depth comparison (`shaders/shade.wgsl`,
//! `compare_tap`).
//!
//! The maps are the render pass's: the same orthographic light cameras, texel centres, depth
//! bias and two-sided casters, so the images of the two paths agree to the penumbra's last
//! texels (tests/render.rs bounds the difference). What differs is where the work runs: the
//! render pass goes through the raster pipeline's fill, which on a compute part such as the
//! H200 is a small part of the chip; the compute path runs on every multiprocessor
//! (docs/performance.md gives both).

use super::scene::Scene;
use super::setup::{compute_storage_entry, uniform_entry};
use glam::{Mat4, Vec3};

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

    /// The way used on an adapter of type `device_type` whose storage bindings hold
    /// `compute_maps` maps ([`ComputeShadows::max_maps`]): as [`Self::resolve`], except that
    /// with no room for even one map `Auto` falls back to render passes and an explicit
    /// `Compute` is an error that says why.
    pub fn resolve_for(
        self,
        device_type: wgpu::DeviceType,
        compute_maps: u32,
        resolution: u32,
    ) -> Result<Self, String> {
        match self.resolve(device_type) {
            Self::Compute if compute_maps == 0 => {
                if self == Self::Auto {
                    Ok(Self::Pipeline)
                } else {
                    Err(format!(
                        "a compute shadow map of {resolution}² texels ({} MiB) is larger than \
                         the adapter's largest storage buffer binding; use a smaller \
                         --shadow-res or --shadow-raster pipeline",
                        (4 * u64::from(resolution) * u64::from(resolution)) >> 20
                    ))
                }
            }
            way => Ok(way),
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
        // No room for one compute map: auto falls back, an explicit compute is refused.
        let gpu = wgpu::DeviceType::DiscreteGpu;
        assert_eq!(auto.resolve_for(gpu, 0, 8192), Ok(ShadowRaster::Pipeline));
        assert_eq!(auto.resolve_for(gpu, 3, 8192), Ok(ShadowRaster::Compute));
        let refused = compute.resolve_for(gpu, 0, 8192).unwrap_err();
        assert!(refused.contains("8192² texels (256 MiB)"), "{refused}");
        assert_eq!(pipeline.resolve_for(gpu, 0, 8192), Ok(pipeline));
    }
    #[test]
    fn casters_split_by_their_longest_edge_in_texels() {
        let scene = Scene::default_scene();
        let casters = scene.caster_indices / 3;
        for resolution in [16, 256, 2048] {
            let (ids, small) = split_by_size(&scene, resolution);
            let mut sorted = ids.clone();
            sorted.sort_unstable();
            assert_eq!(
                sorted,
                (0..casters).collect::<Vec<_>>(),
                "every caster once"
            );
            let texel = 2.0 * scene.bounds.radius / resolution as f32;
            for (k, &t) in ids.iter().enumerate() {
                let i = 3 * t as usize;
                let p = |j: usize| {
                    Vec3::from_array(scene.vertices[scene.indices[i + j] as usize].position)
                };
                let longest = p(0)
                    .distance(p(1))
                    .max(p(1).distance(p(2)))
                    .max(p(2).distance(p(0)));
                assert_eq!(
                    k < small as usize,
                    longest <= LARGE_TEXELS * texel,
                    "triangle {t}"
                );
            }
        }
        // The default scene's box faces are large at 256² maps, its sphere triangles small.
        let (ids, small) = split_by_size(&scene, 256);
        assert!(
            small > 0 && (small as usize) < ids.len(),
            "{small} of {}",
            ids.len()
        );
        assert_eq!(
            split_by_size(&scene, 16).1,
            casters,
            "nothing is large at 16²"
        );
    }
}

/// WGSL source of the compute rasteriser (`surface.wgsl` prepended, for the cut-out casters).
pub const SHADOW_RASTER_WGSL: &str = concat!(
    include_str!("../../shaders/surface.wgsl"),
    include_str!("../../shaders/shadow_raster.wgsl")
);

/// `cs_rasterize_small`'s workgroup (triangles per group).
const RASTER_WORKGROUP: u32 = 64;
/// A caster triangle is large (rasterised by a workgroup, not one invocation) if its bounding
/// box in a map may be wider than this many texels. An orthographic projection keeps lengths,
/// so its longest edge in texels bounds that for every light.
pub const LARGE_TEXELS: f32 = 16.0;
/// `cs_clear`'s workgroup (texels per group and step).
const CLEAR_WORKGROUP: u32 = 256;

/// Matches `Params` in shadow_raster.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct ParamsRaw {
    resolution: u32,
    maps: u32,
    small_triangles: u32,
    large_triangles: u32,
}

/// The shadow casters' triangle indices (into `scene.indices`, by threes), the small ones first,
/// and how many are small: large ones have an edge longer than [`LARGE_TEXELS`] texels of a
/// map of side `resolution` over the light window (2 × the scene's bounding radius).
pub fn split_by_size(scene: &Scene, resolution: u32) -> (Vec<u32>, u32) {
    let texel = 2.0 * scene.bounds.radius.max(1e-3) / resolution.max(1) as f32;
    let position = |i: u32| {
        scene
            .vertices
            .get(i as usize)
            .map_or(Vec3::ZERO, |v| Vec3::from_array(v.position))
    };
    let (small, large): (Vec<u32>, Vec<u32>) = (0..scene.caster_indices / 3).partition(|&t| {
        let k = 3 * t as usize;
        let [a, b, c] = [k, k + 1, k + 2].map(|i| position(scene.indices[i]));
        let longest = a.distance(b).max(b.distance(c)).max(c.distance(a));
        // Small unless surely long (a NaN coordinate leaves it to one invocation).
        let texels = longest / texel;
        texels.is_nan() || texels <= LARGE_TEXELS
    });
    let count = small.len() as u32;
    (small.into_iter().chain(large).collect(), count)
}

/// The compute rasteriser's pipelines and buffers.
pub struct ComputeShadows {
    clear: wgpu::ComputePipeline,
    rasterize_small: wgpu::ComputePipeline,
    rasterize_large: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    params: wgpu::Buffer,
    /// One view-projection (64 bytes) per map.
    cameras: wgpu::Buffer,
    /// The maps' depths, `capacity` maps of `resolution²` texels.
    depths: wgpu::Buffer,
    /// The casters' triangles, small first ([`split_by_size`]).
    triangle_ids: wgpu::Buffer,
    /// The scene's vertex, index and material buffers (bound again when the maps' buffers
    /// grow).
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    materials: wgpu::Buffer,
    /// The materials' textures (group 2), for the cut-out casters' alpha.
    textures: wgpu::BindGroup,
    capacity: u32,
    /// [`Self::max_maps`] of this device and resolution.
    max_maps: u32,
    resolution: u32,
    small_triangles: u32,
    large_triangles: u32,
    max_workgroups: u32,
}

impl ComputeShadows {
    /// Builds the pipelines over `scene` and its vertex, index and material buffers (which
    /// need `STORAGE` usage) and its textures, with room for one map.
    pub fn new(
        device: &wgpu::Device,
        scene: &Scene,
        (vertices, indices, materials): (&wgpu::Buffer, &wgpu::Buffer, &wgpu::Buffer),
        textures: &super::textures::SurfaceTextures,
        resolution: u32,
    ) -> Self {
        use wgpu::util::DeviceExt;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shadow_raster.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADOW_RASTER_WGSL.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shadow raster"),
            entries: &[
                uniform_entry(0, wgpu::ShaderStages::COMPUTE),
                compute_storage_entry(1, true),
                compute_storage_entry(2, true),
                compute_storage_entry(3, true),
                compute_storage_entry(4, false),
                compute_storage_entry(5, true),
                compute_storage_entry(6, true),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shadow raster"),
            bind_group_layouts: &[Some(&layout), None, Some(&textures.layout)],
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
        let rasterize_small = pipeline("cs_rasterize_small");
        let rasterize_large = pipeline("cs_rasterize_large");
        let (mut ids, small_triangles) = split_by_size(scene, resolution);
        let large_triangles = ids.len() as u32 - small_triangles;
        if ids.is_empty() {
            // A binding needs a byte; the counts say there is nothing.
            ids.push(0);
        }
        let triangle_ids = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("shadow caster triangles"),
            contents: bytemuck::cast_slice(&ids),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow raster params"),
            size: std::mem::size_of::<ParamsRaw>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let cameras = Self::make_cameras(device, 1);
        let depths = Self::make_depths(device, resolution, 1);
        let bind_group = Self::make_bind_group(
            device,
            &layout,
            [
                &params,
                vertices,
                indices,
                &cameras,
                &depths,
                &triangle_ids,
                materials,
            ],
        );
        Self {
            clear,
            rasterize_small,
            rasterize_large,
            layout,
            bind_group,
            params,
            cameras,
            depths,
            triangle_ids,
            vertices: vertices.clone(),
            indices: indices.clone(),
            materials: materials.clone(),
            textures: textures.bind_group.clone(),
            capacity: 1,
            max_maps: Self::max_maps(device, resolution),
            resolution,
            small_triangles,
            large_triangles,
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

    /// Bindings 0–6 in order: params, vertices, indices, cameras, depths, triangle ids,
    /// materials.
    fn make_bind_group(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        buffers: [&wgpu::Buffer; 7],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = buffers
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

    /// The most maps a frame can hold here ([`Self::max_maps`]).
    pub fn map_limit(&self) -> u32 {
        self.max_maps
    }

    /// Writes the frame's light cameras (map k's at k; at most [`Self::map_limit`]) and grows
    /// the buffers to hold them; returns whether the depth buffer was replaced (the shading pass
    /// must bind the new one).
    pub fn prepare(
        &mut self,
        gpu: &super::device::Gpu,
        cameras: impl ExactSizeIterator<Item = Mat4>,
    ) -> bool {
        let device = &gpu.device;
        let maps = cameras.len() as u32;
        let mut grown = false;
        if maps > self.capacity {
            self.capacity = maps.next_power_of_two().min(self.max_maps.max(1)).max(maps);
            self.cameras = Self::make_cameras(device, self.capacity);
            self.depths = Self::make_depths(device, self.resolution, self.capacity);
            self.bind_group = Self::make_bind_group(
                device,
                &self.layout,
                [
                    &self.params,
                    &self.vertices,
                    &self.indices,
                    &self.cameras,
                    &self.depths,
                    &self.triangle_ids,
                    &self.materials,
                ],
            );
            grown = true;
        }
        if maps > 0 {
            let flat: Vec<f32> = cameras.flat_map(|m| m.to_cols_array()).collect();
            gpu.queue
                .write_buffer(&self.cameras, 0, bytemuck::cast_slice(&flat));
        }
        let params = ParamsRaw {
            resolution: self.resolution,
            maps,
            small_triangles: self.small_triangles,
            large_triangles: self.large_triangles,
        };
        gpu.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        grown
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
        pass.set_bind_group(2, &self.textures, &[]);
        let texels = u64::from(maps) * u64::from(self.resolution) * u64::from(self.resolution);
        let clear_groups = texels
            .div_ceil(u64::from(CLEAR_WORKGROUP))
            .clamp(1, u64::from(self.max_workgroups)) as u32;
        pass.set_pipeline(&self.clear);
        pass.dispatch_workgroups(clear_groups, 1, 1);
        if self.small_triangles > 0 {
            pass.set_pipeline(&self.rasterize_small);
            let groups = self
                .small_triangles
                .div_ceil(RASTER_WORKGROUP)
                .min(self.max_workgroups);
            pass.dispatch_workgroups(groups, maps, 1);
        }
        if self.large_triangles > 0 {
            pass.set_pipeline(&self.rasterize_large);
            pass.dispatch_workgroups(self.large_triangles.min(self.max_workgroups), maps, 1);
        }
    }
}
