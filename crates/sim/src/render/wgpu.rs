//! Batched depth rendering on a GPU with wgpu (headless).
//!
//! The static scene (walls, floor, ceiling and every obstacle, already placed
//! in the world) is one vertex buffer uploaded once. A step draws all
//! cameras' 32×32 views as tiles of one atlas texture in one render pass: one
//! instanced draw per camera with that camera's viewport (the instance index
//! picks the camera), plus, in interactive mode, the other drones as
//! instanced spheres. One submission and one read-back per call.
//!
//! The fragment shader writes the planar depth (distance along the camera's
//! forward axis), which is exactly what the CPU ray caster computes, so both
//! renderers give the same images up to tessellation (cylinders have 24
//! facets) and edge pixels. Without a GPU, Mesa's lavapipe runs it on the CPU.

use std::sync::mpsc;

use rapier3d::math::Vector;
use wgpu::util::DeviceExt;

mod mesh;

use mesh::{SceneLayout, shape_triangles, sphere_triangles};

use crate::arena::Motion;
use crate::render::camera::frustum_floor_plan;
use crate::render::{CameraPose, CameraSpec, Drones, Scene};

/// wgpu's error as it came (boxed: wgpu has one type per operation).
pub type GpuCause = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Why the GPU renderer could not start or render. A cause is part of the
/// text and not also `source()`, so `{:#}` names it once.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No Vulkan adapter (install `mesa-vulkan-drivers` for the CPU one).
    #[error(
        "no GPU adapter found for the wgpu renderer ({0}); on a machine without a GPU install \
         Mesa's lavapipe (Debian: mesa-vulkan-drivers)"
    )]
    NoAdapter(GpuCause),
    /// The adapter refused the device.
    #[error("the wgpu device could not be created: {0}")]
    Device(GpuCause),
    /// Reading the rendered depth back failed.
    #[error("reading depth back from the GPU failed: {0}")]
    Readback(GpuCause),
    /// The cameras of a call do not fit the adapter's largest texture.
    #[error(
        "{cameras} cameras of {width} x {height} pixels need an atlas of {need} texels a side; \
         this adapter takes {limit} (fewer agents per simulator, or a smaller camera)"
    )]
    TooLarge { cameras: usize, width: usize, height: usize, need: u32, limit: u32 },
}

/// Tiles per atlas row (the row padded to [`ROW_TEXELS`]).
const COLS: u32 = 8;
/// Texels a read-back row is a multiple of: 64 × 4 bytes, the 256-byte row
/// alignment copies need (8 tiles of 32 pixels fill it exactly).
const ROW_TEXELS: u32 = 64;
const NEAR: f32 = 0.02;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuCamera {
    origin: [f32; 3],
    agent: u32,
    fwd: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    inv_tan: f32,
    inv_tan_v: f32,
    near: f32,
    far: f32,
    drones: u32,
    radius: f32,
    _pad: [f32; 2],
}

const SHADER: &str = r"
struct Camera { origin: vec3<f32>, agent: u32, fwd: vec4<f32>, right: vec4<f32>, up: vec4<f32> };
struct Params { inv_tan: f32, inv_tan_v: f32, near: f32, far: f32, drones: u32, radius: f32, p0: f32, p1: f32 };
@group(0) @binding(0) var<storage, read> cams: array<Camera>;
@group(0) @binding(1) var<uniform> params: Params;
@group(0) @binding(2) var<storage, read> drones: array<vec4<f32>>;

struct VOut { @builtin(position) pos: vec4<f32>, @location(0) depth: f32 };

fn project(cam: Camera, p: vec3<f32>) -> VOut {
    let d = p - cam.origin;
    let x = dot(d, cam.right.xyz);
    let y = dot(d, cam.up.xyz);
    let z = dot(d, cam.fwd.xyz);
    var o: VOut;
    o.pos = vec4<f32>(x * params.inv_tan, y * params.inv_tan_v, params.far * (z - params.near) / (params.far - params.near), z);
    o.depth = z;
    return o;
}

@vertex fn vs_scene(@location(0) p: vec3<f32>, @builtin(instance_index) i: u32) -> VOut {
    return project(cams[i], p);
}

@vertex fn vs_drone(@location(0) p: vec3<f32>, @builtin(instance_index) i: u32) -> VOut {
    let cam = cams[i / params.drones];
    let k = i % params.drones;
    var o = project(cam, drones[k].xyz + p * params.radius);
    if (k == cam.agent) {
        // A camera does not see its own drone: behind the near plane.
        o.pos = vec4<f32>(0.0, 0.0, -1.0, 1.0);
    }
    return o;
}

@fragment fn fs(v: VOut) -> @location(0) vec4<f32> {
    return vec4<f32>(clamp(v.depth / params.far, 0.0, 1.0), 0.0, 0.0, 1.0);
}
";

/// Sizes that grow with the number of cameras of a call.
struct Frame {
    cameras: u32,
    color: wgpu::Texture,
    depth: wgpu::Texture,
    readback: wgpu::Buffer,
    cams: wgpu::Buffer,
    drones: wgpu::Buffer,
    drone_capacity: u32,
    bind: wgpu::BindGroup,
}

/// The wgpu depth renderer for one scene.
pub struct GpuDepthRenderer {
    spec: CameraSpec,
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    scene_pipeline: wgpu::RenderPipeline,
    drone_pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    scene_vertices: wgpu::Buffer,
    scene_indices: wgpu::Buffer,
    layout_cull: SceneLayout,
    ranges: Vec<std::ops::Range<u32>>,
    sphere_vertices: wgpu::Buffer,
    sphere_count: u32,
    frame: Option<Frame>,
    staging: Vec<GpuCamera>,
    submissions: u64,
    /// The moving obstacles (none: every obstacle stands still).
    movers: Option<Movers>,
}

/// The moving obstacles' triangles, written into their vertex buffer where
/// the obstacles are at every [`GpuDepthRenderer::set_time`], and drawn
/// after the still scene by the cameras whose view reaches them.
struct Movers {
    /// Every mover's triangles at its centre, one mover after another.
    base: Vec<[f32; 3]>,
    /// Per mover: its vertices, its floor-plan bounds at its centre, its motion.
    parts: Vec<MoverPart>,
    /// Per mover: where it is now, from its centre.
    offsets: Vec<[f32; 2]>,
    moved: Vec<[f32; 3]>,
    buffer: wgpu::Buffer,
}

/// One moving obstacle's vertices, floor-plan bounds (at its centre) and motion.
type MoverPart = (std::ops::Range<u32>, [f32; 2], [f32; 2], Motion);

impl Movers {
    fn new(device: &wgpu::Device, scene: &Scene) -> Option<Self> {
        if scene.movers.is_empty() {
            return None;
        }
        let mut base = Vec::new();
        let mut parts = Vec::new();
        for &(_, shape, motion) in &scene.movers {
            let first = base.len() as u32;
            base.extend(shape_triangles(&shape, scene.height));
            let (lo, hi) = shape.aabb();
            parts.push((first..base.len() as u32, [lo.x, lo.y], [hi.x, hi.y], motion));
        }
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("moving obstacles"),
            size: (base.len() * std::mem::size_of::<[f32; 3]>()) as u64,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let offsets = vec![[0.0; 2]; parts.len()];
        Some(Self { moved: base.clone(), base, parts, offsets, buffer })
    }
}

impl std::fmt::Debug for GpuDepthRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuDepthRenderer")
            .field("adapter", &self.adapter)
            .field("submissions", &self.submissions)
            .finish()
    }
}

/// The first adapter wgpu finds (a GPU, or lavapipe on the CPU), its device
/// and queue, and its name.
fn open_device() -> Result<(wgpu::Device, wgpu::Queue, String), GpuError> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        force_fallback_adapter: false,
        compatible_surface: None,
        ..Default::default()
    }))
    .map_err(|e| GpuError::NoAdapter(e.into()))?;
    let info = adapter.get_info();
    let adapter_name = format!("{} ({:?}, {})", info.name, info.backend, info.driver);
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("rotorhive depth"),
        required_features: wgpu::Features::empty(),
        required_limits: adapter.limits(),
        ..Default::default()
    }))
    .map_err(|e| GpuError::Device(e.into()))?;
    Ok((device, queue, adapter_name))
}

/// The depth shader's bindings: cameras (0, storage), parameters (1,
/// uniform) and drones (2, storage).
fn bind_group_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    let buffer = |binding, ty, visibility| wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    };
    let storage = wgpu::BufferBindingType::Storage { read_only: true };
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("depth"),
        entries: &[
            buffer(0, storage, wgpu::ShaderStages::VERTEX),
            buffer(1, wgpu::BufferBindingType::Uniform, wgpu::ShaderStages::VERTEX_FRAGMENT),
            buffer(2, storage, wgpu::ShaderStages::VERTEX),
        ],
    })
}

/// The bind group layout and the two render pipelines (scene, with back
/// faces culled, and drones) of the depth shader.
fn pipelines(
    device: &wgpu::Device,
) -> (wgpu::BindGroupLayout, wgpu::RenderPipeline, wgpu::RenderPipeline) {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("depth"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let layout = bind_group_layout(device);
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("depth"),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = |entry: &str, cull_mode: Option<wgpu::Face>| {
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(entry),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: 12,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &wgpu::vertex_attr_array![0 => Float32x3],
                })],
            },
            primitive: wgpu::PrimitiveState { cull_mode, ..Default::default() },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: wgpu::TextureFormat::Depth32Float,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: wgpu::TextureFormat::R32Float,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        })
    };
    // Scene triangles face the cameras (see `orient`): the back faces of
    // obstacles are dropped before they are rasterised.
    let scene_pipeline = pipeline("vs_scene", Some(wgpu::Face::Back));
    let drone_pipeline = pipeline("vs_drone", None);
    (layout, scene_pipeline, drone_pipeline)
}

impl GpuDepthRenderer {
    /// Opens the first adapter wgpu finds (a GPU, or lavapipe on the CPU)
    /// and uploads the scene.
    pub fn new(spec: CameraSpec, scene: &Scene) -> Result<Self, GpuError> {
        let (device, queue, adapter_name) = open_device()?;
        let (layout, scene_pipeline, drone_pipeline) = pipelines(&device);
        let layout_cull = SceneLayout::new(scene, spec.range);
        let movers = Movers::new(&device, scene);
        let sphere = sphere_triangles();
        let vbuf = |label, v: &[[f32; 3]]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytemuck::cast_slice(v),
                usage: wgpu::BufferUsages::VERTEX,
            })
        };
        let scene_vertices = vbuf("scene", &layout_cull.vertices);
        let scene_indices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("scene indices"),
            contents: bytemuck::cast_slice(&layout_cull.indices),
            usage: wgpu::BufferUsages::INDEX,
        });
        let sphere_vertices = vbuf("sphere", &sphere);
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("params"),
            size: std::mem::size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut me = Self {
            spec,
            device,
            queue,
            adapter: adapter_name,
            scene_pipeline,
            drone_pipeline,
            layout,
            params,
            scene_vertices,
            scene_indices,
            layout_cull,
            ranges: Vec::new(),
            sphere_vertices,
            sphere_count: sphere.len() as u32,
            frame: None,
            staging: Vec::new(),
            submissions: 0,
            movers,
        };
        me.set_time(0.0);
        Ok(me)
    }

    /// Puts the moving obstacles where they are at time `t` of the world's
    /// clock (as [`Scene::set_time`] does for the CPU renderer).
    pub fn set_time(&mut self, t: f64) {
        let Some(m) = &mut self.movers else {
            return;
        };
        for (k, (range, _, _, motion)) in m.parts.iter().enumerate() {
            let [dx, dy] = motion.offset(t);
            m.offsets[k] = [dx, dy];
            let r = range.start as usize..range.end as usize;
            for (to, from) in m.moved[r.clone()].iter_mut().zip(&m.base[r]) {
                *to = [from[0] + dx, from[1] + dy, from[2]];
            }
        }
        self.queue.write_buffer(&m.buffer, 0, bytemuck::cast_slice(&m.moved));
    }

    /// The adapter in use, e.g. "llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, llvmpipe)".
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    /// Queue submissions so far (one per `render` call).
    pub fn submissions(&self) -> u64 {
        self.submissions
    }

    /// Texels of one atlas row: [`COLS`] tiles, padded to [`ROW_TEXELS`].
    fn atlas_width(&self) -> u32 {
        (COLS * self.spec.width as u32).next_multiple_of(ROW_TEXELS)
    }

    /// Makes sure the atlas and buffers hold `cameras` cameras and `drones` drones.
    fn ensure_frame(&mut self, cameras: u32, drones: u32) {
        let fits =
            self.frame.as_ref().is_some_and(|f| f.cameras >= cameras && f.drone_capacity >= drones);
        if !fits {
            let cameras = cameras.max(self.frame.as_ref().map_or(0, |f| f.cameras));
            let drone_capacity =
                drones.max(1).max(self.frame.as_ref().map_or(0, |f| f.drone_capacity));
            let rows = cameras.div_ceil(COLS);
            let size = wgpu::Extent3d {
                width: self.atlas_width(),
                height: rows * self.spec.height as u32,
                depth_or_array_layers: 1,
            };
            let texture = |format, usage, label| {
                self.device.create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
            };
            let color = texture(
                wgpu::TextureFormat::R32Float,
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
                "depth atlas",
            );
            let depth = texture(
                wgpu::TextureFormat::Depth32Float,
                wgpu::TextureUsages::RENDER_ATTACHMENT,
                "z buffer",
            );
            let buffer = |label, size: u64, usage| {
                self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size,
                    usage,
                    mapped_at_creation: false,
                })
            };
            let readback = buffer(
                "readback",
                u64::from(self.atlas_width() * 4 * rows * self.spec.height as u32),
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            );
            let cams = buffer(
                "cameras",
                u64::from(cameras) * std::mem::size_of::<GpuCamera>() as u64,
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            );
            let drone_buf = buffer(
                "drones",
                u64::from(drone_capacity) * 16,
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            );
            let bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("depth"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: cams.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: self.params.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: drone_buf.as_entire_binding() },
                ],
            });
            self.frame = Some(Frame {
                cameras,
                color,
                depth,
                readback,
                cams,
                drones: drone_buf,
                drone_capacity,
                bind,
            });
        }
    }

    /// Renders every camera's depth image into `out` (`cameras × width ×
    /// height`,
    /// row-major, top row first, normalised to [0, 1] by the range): one
    /// render pass, one submission, one read-back. `agents[i]` names the
    /// drone camera `i` sits on, so it does not see itself.
    pub fn render(
        &mut self,
        cameras: &[CameraPose],
        agents: &[u32],
        drones: Option<Drones<'_>>,
        out: &mut [f32],
    ) -> Result<(), GpuError> {
        let px = self.spec.pixels();
        assert_eq!(out.len(), cameras.len() * px, "depth buffer has the wrong size");
        assert_eq!(agents.len(), cameras.len(), "one agent index per camera");
        if cameras.is_empty() {
            return Ok(());
        }
        let n = cameras.len() as u32;
        let need = self.atlas_width().max(n.div_ceil(COLS) * self.spec.height as u32);
        let limit = self.device.limits().max_texture_dimension_2d;
        if need > limit {
            let (width, height) = (self.spec.width, self.spec.height);
            return Err(GpuError::TooLarge { cameras: cameras.len(), width, height, need, limit });
        }
        let nd = self.upload(cameras, agents, drones, n);
        let rows = n.div_ceil(COLS);
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("depth") });
        self.draw(&mut enc, cameras, nd);
        self.copy_out(&mut enc, rows);
        self.queue.submit([enc.finish()]);
        self.submissions += 1;
        self.read_back(rows, out)
    }

    /// Records the depth pass of every camera (camera `i` in tile `i` of the
    /// frame), with `nd` drones per camera.
    fn draw(&mut self, enc: &mut wgpu::CommandEncoder, cameras: &[CameraPose], nd: u32) {
        let f = self.frame.as_ref().expect("frame");
        let (w, h) = (self.spec.width as u32, self.spec.height as u32);
        let n = cameras.len() as u32;
        let color_view = f.color.create_view(&Default::default());
        let depth_view = f.depth.create_view(&Default::default());
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("depth"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color { r: 1.0, g: 0.0, b: 0.0, a: 1.0 }),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_bind_group(0, &f.bind, &[]);
        for (i, cam) in (0..n).zip(cameras) {
            let (x, y) = ((i % COLS) * w, (i / COLS) * h);
            pass.set_viewport(x as f32, y as f32, w as f32, h as f32, 0.0, 1.0);
            pass.set_scissor_rect(x, y, w, h);
            pass.set_pipeline(&self.scene_pipeline);
            pass.set_vertex_buffer(0, self.scene_vertices.slice(..));
            pass.set_index_buffer(self.scene_indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..self.layout_cull.always, 0, i..i + 1);
            // Only the obstacles the camera's view (to its range) can reach.
            let (lo, hi) = frustum_floor_plan(&self.spec, cam);
            self.layout_cull.visible(lo, hi, &mut self.ranges);
            for r in &self.ranges {
                pass.draw_indexed(r.clone(), 0, i..i + 1);
            }
            if let Some(m) = &self.movers {
                pass.set_vertex_buffer(0, m.buffer.slice(..));
                for ((range, a, b, _), [dx, dy]) in m.parts.iter().zip(&m.offsets) {
                    let seen = a[0] + dx <= hi[0]
                        && b[0] + dx >= lo[0]
                        && a[1] + dy <= hi[1]
                        && b[1] + dy >= lo[1];
                    if seen {
                        pass.draw(range.clone(), i..i + 1);
                    }
                }
            }
            if nd > 0 {
                pass.set_pipeline(&self.drone_pipeline);
                pass.set_vertex_buffer(0, self.sphere_vertices.slice(..));
                pass.draw(0..self.sphere_count, i * nd..(i + 1) * nd);
            }
        }
    }

    /// Records the copy of the frame's first `rows` rows of tiles into the
    /// read-back buffer.
    fn copy_out(&self, enc: &mut wgpu::CommandEncoder, rows: u32) {
        let f = self.frame.as_ref().expect("frame");
        let (width, h) = (self.atlas_width(), self.spec.height as u32);
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &f.color,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &f.readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(width * 4),
                    rows_per_image: None,
                },
            },
            wgpu::Extent3d { width, height: rows * h, depth_or_array_layers: 1 },
        );
    }

    /// Writes the cameras, the shader's parameters and the drones'
    /// positions into the frame's buffers (made or grown for `n` cameras
    /// first); returns the number of drones drawn.
    fn upload(
        &mut self,
        cameras: &[CameraPose],
        agents: &[u32],
        drones: Option<Drones<'_>>,
        n: u32,
    ) -> u32 {
        let nd = drones.map_or(0, |d| d.positions.len() as u32);
        self.staging.clear();
        self.staging.extend(cameras.iter().zip(agents).map(|(c, &agent)| {
            let v = |a: Vector| [a.x, a.y, a.z, 0.0];
            GpuCamera {
                origin: c.position.to_array(),
                agent,
                fwd: v(c.rotation * Vector::X),
                right: v(-(c.rotation * Vector::Y)),
                up: v(c.rotation * Vector::Z),
            }
        }));
        let params = Params {
            inv_tan: 1.0 / self.spec.tan_h(),
            inv_tan_v: 1.0 / self.spec.tan_v(),
            near: NEAR,
            far: self.spec.range,
            drones: nd.max(1),
            radius: drones.map_or(0.0, |d| d.radius),
            _pad: [0.0; 2],
        };
        self.ensure_frame(n, nd);
        let f = self.frame.as_ref().expect("frame");
        self.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        self.queue.write_buffer(&f.cams, 0, bytemuck::cast_slice(&self.staging));
        if let Some(d) = drones {
            let pos: Vec<[f32; 4]> = d.positions.iter().map(|p| [p.x, p.y, p.z, 0.0]).collect();
            self.queue.write_buffer(&f.drones, 0, bytemuck::cast_slice(&pos));
        }
        nd
    }

    /// Waits for the frame's depth tiles (`rows` rows of tiles) and copies
    /// each camera's image into `out`.
    fn read_back(&self, rows: u32, out: &mut [f32]) -> Result<(), GpuError> {
        let f = self.frame.as_ref().expect("frame");
        let (w, h, px) = (self.spec.width, self.spec.height, self.spec.pixels());
        let stride = self.atlas_width() as usize;
        let used = (stride * 4 * rows as usize * h) as u64;
        let slice = f.readback.slice(..used);
        let (tx, rx) = mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.into()))?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.into()))?
            .map_err(|e| GpuError::Readback(e.into()))?;
        {
            let data = slice.get_mapped_range().map_err(|e| GpuError::Readback(e.into()))?;
            let texels: &[f32] = bytemuck::cast_slice(&data);
            for (i, img) in out.chunks_mut(px).enumerate() {
                let (x0, y0) = ((i % COLS as usize) * w, (i / COLS as usize) * h);
                for r in 0..h {
                    let at = (y0 + r) * stride + x0;
                    img[r * w..(r + 1) * w].copy_from_slice(&texels[at..at + w]);
                }
            }
        }
        f.readback.unmap();
        Ok(())
    }
}
