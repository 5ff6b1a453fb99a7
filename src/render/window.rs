//! Windowed mode (cargo feature `window`): shows the frames in a winit window on the rig's
//! display, one new light frame per redraw, with the frame budget when one is set.
//!
//! The renderer draws into its HDR target as in headless mode; a present pass
//! (`shaders/present.wgsl`) tone-maps it into the window's sRGB swap chain in the same
//! submission. Escape or closing the window ends the loop. The window has the render size; a
//! resized window shows the frame scaled (nearest texel).

use super::budget::{BudgetController, BudgetSettings};
use super::device::Gpu;
use super::scene::Scene;
use super::{light_prefix, RenderError, RenderSettings, Renderer, PRESENT_WGSL};
use crate::light::{Light, LightFrame};
use std::sync::Arc;
use thiserror::Error;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, KeyEvent, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

/// Windowed-mode errors.
#[derive(Debug, Error)]
pub enum WindowError {
    #[error("cannot open a window (is there a display? DISPLAY or WAYLAND_DISPLAY): {0}")]
    Window(String),
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error("cannot read the next light frame: {0}")]
    Source(String),
}

/// Where the windowed loop gets each frame's lights: `Ok(None)` when the source has ended
/// (the last frame stays on screen). Each frame's `time` poses an animated scene
/// ([`Renderer::set_scene_time`]): the caller makes it the scene's clock.
pub type LightSource<'a> = Box<dyn FnMut() -> Result<Option<LightFrame>, String> + 'a>;

struct Present {
    pipeline: wgpu::RenderPipeline,
    bind_group: wgpu::BindGroup,
    params: wgpu::Buffer,
}

struct State {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    renderer: Renderer,
    present: Present,
}

struct App<'a> {
    scene: Option<Scene>,
    settings: RenderSettings,
    exposure: f32,
    budget_ms: Option<f64>,
    source: LightSource<'a>,
    lights: Vec<Light>,
    /// The latest frame's time, in seconds.
    time: f64,
    ended: bool,
    controller: Option<BudgetController>,
    state: Option<State>,
    error: Option<WindowError>,
    frames: u64,
}

/// Opens a window and renders until it is closed.
pub fn run(
    scene: Scene,
    settings: RenderSettings,
    exposure: f32,
    budget_ms: Option<f64>,
    source: LightSource<'_>,
) -> Result<(), WindowError> {
    let event_loop = EventLoop::new().map_err(|e| WindowError::Window(e.to_string()))?;
    let mut app = App {
        scene: Some(scene),
        settings,
        exposure,
        budget_ms,
        source,
        lights: Vec::new(),
        time: 0.0,
        ended: false,
        controller: None,
        state: None,
        error: None,
        frames: 0,
    };
    event_loop
        .run_app(&mut app)
        .map_err(|e| WindowError::Window(e.to_string()))?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

fn make_present(gpu: &Gpu, renderer: &Renderer, format: wgpu::TextureFormat) -> Present {
    let device = &gpu.device;
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("present"),
        entries: &[
            super::unfiltered_texture_entry(0, wgpu::ShaderStages::FRAGMENT),
            super::setup::uniform_entry(1, wgpu::ShaderStages::FRAGMENT),
        ],
    });
    let params = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("present params"),
        size: 16,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("present"),
        layout: &layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::TextureView(renderer.color_view()),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: params.as_entire_binding(),
            },
        ],
    });
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("present.wgsl"),
        source: wgpu::ShaderSource::Wgsl(PRESENT_WGSL.into()),
    });
    let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("present"),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("present"),
        layout: Some(&pl),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs_main"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: Default::default(),
        depth_stencil: None,
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs_main"),
            compilation_options: Default::default(),
            targets: &[Some(format.into())],
        }),
        multiview_mask: None,
        cache: None,
    });
    Present {
        pipeline,
        bind_group,
        params,
    }
}

impl App<'_> {
    fn open(&mut self, event_loop: &ActiveEventLoop) -> Result<State, WindowError> {
        let attrs = Window::default_attributes()
            .with_title("envlight")
            .with_inner_size(winit::dpi::PhysicalSize::new(
                self.settings.width,
                self.settings.height,
            ));
        let window = Arc::new(
            event_loop
                .create_window(attrs)
                .map_err(|e| WindowError::Window(e.to_string()))?,
        );
        let instance = Gpu::new_instance();
        let surface = instance
            .create_surface(window.clone())
            .map_err(|e| WindowError::Window(e.to_string()))?;
        let gpu = Gpu::with_instance(instance, Some(&surface)).map_err(RenderError::from)?;
        tracing::info!("adapter: {}", gpu.describe());
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&gpu.adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| WindowError::Window("the adapter cannot present to it".into()))?;
        let caps = surface.get_capabilities(&gpu.adapter);
        if let Some(f) = caps.formats.iter().find(|f| f.is_srgb()) {
            config.format = *f;
        }
        surface.configure(&gpu.device, &config);
        let scene = self
            .scene
            .take()
            .ok_or_else(|| WindowError::Window("the window was opened twice".into()))?;
        let renderer = Renderer::with_gpu(gpu, scene, self.settings)?;
        let present = make_present(renderer.gpu(), &renderer, config.format);
        Ok(State {
            window,
            surface,
            config,
            renderer,
            present,
        })
    }

    fn redraw(&mut self) -> Result<(), WindowError> {
        if !self.ended {
            match (self.source)().map_err(WindowError::Source)? {
                Some(frame) => {
                    self.lights = light_prefix(&frame.lights, usize::MAX);
                    self.time = frame.time;
                }
                None => self.ended = true,
            }
        }
        let Some(state) = &mut self.state else {
            return Ok(());
        };
        if self.controller.is_none() {
            if let Some(ms) = self.budget_ms {
                let n = self.lights.len().max(1);
                self.controller = Some(BudgetController::new(BudgetSettings::new(ms, n), n));
            }
        }
        let count = self
            .controller
            .as_ref()
            .map_or(self.lights.len(), |c| c.count())
            .min(self.lights.len());
        let frame = match state.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                let device = &state.renderer.gpu().device;
                state.surface.configure(device, &state.config);
                return Ok(());
            }
            _ => return Ok(()),
        };
        let target = frame.texture.create_view(&Default::default());
        let s = state.renderer.settings();
        let params = [self.exposure, s.width as f32, s.height as f32, 0.0];
        state.renderer.gpu().queue.write_buffer(
            &state.present.params,
            0,
            bytemuck::cast_slice(&params),
        );
        state.renderer.set_scene_time(self.time);
        let present = &state.present;
        let stats =
            state
                .renderer
                .render_then(&light_prefix(&self.lights, count), |_, enc, _| {
                    let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                        label: Some("present"),
                        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                            view: &target,
                            depth_slice: None,
                            resolve_target: None,
                            ops: wgpu::Operations {
                                load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                                store: wgpu::StoreOp::Store,
                            },
                        })],
                        depth_stencil_attachment: None,
                        timestamp_writes: None,
                        occlusion_query_set: None,
                        multiview_mask: None,
                    });
                    pass.set_pipeline(&present.pipeline);
                    pass.set_bind_group(0, &present.bind_group, &[]);
                    pass.draw(0..3, 0..1);
                })?;
        state.renderer.gpu().queue.present(frame);
        if let Some(c) = &mut self.controller {
            c.update(stats.frame_ms());
        }
        self.frames += 1;
        tracing::info!(
            "frame {}: {} lights, {} shadow maps, {:.2} ms",
            self.frames,
            stats.lights,
            stats.shadow_maps,
            stats.frame_ms()
        );
        state.window.request_redraw();
        Ok(())
    }
}

impl ApplicationHandler for App<'_> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.state.is_some() {
            return;
        }
        match self.open(event_loop) {
            Ok(state) => {
                state.window.request_redraw();
                self.state = Some(state);
            }
            Err(e) => {
                self.error = Some(e);
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested
            | WindowEvent::KeyboardInput {
                event:
                    KeyEvent {
                        logical_key: Key::Named(NamedKey::Escape),
                        state: ElementState::Pressed,
                        ..
                    },
                ..
            } => event_loop.exit(),
            WindowEvent::Resized(size) => {
                if let Some(state) = &mut self.state {
                    state.config.width = size.width.max(1);
                    state.config.height = size.height.max(1);
                    let device = &state.renderer.gpu().device;
                    state.surface.configure(device, &state.config);
                }
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
                    self.error = Some(e);
                    event_loop.exit();
                }
            }
            _ => {}
        }
    }
}
