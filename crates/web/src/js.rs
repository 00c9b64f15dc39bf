//! The page's browser side: [`Page`], exported with wasm-bindgen. It owns the canvas's WebGPU
//! device, one [`Deformer`] per object (the same WGSL as native), the renderer, the orbit
//! camera and the pointer's press; `web/main.js` calls it from the page's events and
//! animation frames, and measures time (there is no clock in the engine).

use glam::DVec3;
use std::sync::Arc;
use wasm_bindgen::prelude::*;

use crate::page::{PageWorld, PressOutcome, PressSpec};
use touchfem_core::haptic::cutter::CutBody;
use touchfem_gpu::render::{
    frame_objects, frame_texture, legend_image, pick, rest_surfaces, Anchor, Coloring, Edges,
    Frame, LegendSpec, Orbit, Overlay, PointerPress, RenderOptions, Renderer, SampleMarks,
    ViewScales,
};
use touchfem_gpu::{install_cut, Deformer, DeformerOptions, VERTEX_STRIDE};

fn js_err(e: impl std::fmt::Display) -> JsError {
    JsError::new(&e.to_string())
}

/// The canvas's device and everything drawn on it.
struct Gfx {
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    renderer: Renderer,
    legend: Overlay,
    deformers: Vec<Deformer>,
    edges: Vec<Edges>,
    /// Each object's cut body on its deformer (`None`: uncut).
    bodies: Vec<Option<Arc<CutBody>>>,
    /// What a deformer is rebuilt with when a cut brings a new `L`.
    options: DeformerOptions,
    adapter: String,
    /// The frame drawn in the canvas's format's sRGB twin, then copied onto the canvas.
    offscreen: wgpu::Texture,
    /// A read-back in flight: the staging buffer and the slot its callback fills.
    readback: Option<(wgpu::Buffer, std::rc::Rc<std::cell::Cell<Option<bool>>>)>,
}

/// The compliance of a one-object scene or mesh, computed on this thread and returned as a
/// cache file's bytes: the page's worker calls it, off the page's thread, and hands the bytes
/// to [`Page::new`]. `undefined` for a scene the page computes itself (several objects).
#[wasm_bindgen]
pub fn compute_cache(scene: &str) -> Result<Option<Vec<u8>>, JsError> {
    crate::page::compute_cache(scene).map_err(js_err)
}

/// touchfem in the page: a scene, its haptic state and, once attached, its canvas.
#[wasm_bindgen]
pub struct Page {
    world: PageWorld,
    gfx: Option<Gfx>,
    size: [u32; 2],
    orbit: Orbit,
    scales: ViewScales,
    press: Option<PointerPress>,
    /// A scripted press's contact forces, drawn instead of the live sample's.
    scripted: Option<PressOutcome>,
}

#[wasm_bindgen]
impl Page {
    /// Loads a bundled scene or mesh (`fig1`, `fig2`, `palpate`, `incision`, `cube`, `mouse`,
    /// …), its compliance read from `cache` (a cache file's bytes) when given, else computed
    /// here on this thread.
    #[wasm_bindgen(constructor)]
    pub fn new(scene: &str, cache: Option<Vec<u8>>) -> Result<Page, JsError> {
        let world = PageWorld::load(scene, cache.as_deref()).map_err(js_err)?;
        let scales = ViewScales::of(world.world);
        let (lo, hi) = world.world.bounds();
        Ok(Page {
            world,
            gfx: None,
            size: [640, 480],
            orbit: Orbit::framing(lo, hi, 640.0 / 480.0),
            scales,
            press: None,
            scripted: None,
        })
    }

    /// `"computed"` or `"cache"`: where the compliance came from.
    pub fn compliance_source(&self) -> String {
        self.world.source.as_str().into()
    }

    /// Nodes and surface triangles of every object (for the page's status line).
    pub fn describe(&self) -> String {
        let w = self.world.world;
        let nodes: usize = w.objects.iter().map(|o| o.body.mesh.nodes.len()).sum();
        let tris: usize = w.objects.iter().map(|o| o.body.mesh.surface.len()).sum();
        let cols: usize = w
            .objects
            .iter()
            .map(|o| o.body.compliance.cols().len())
            .sum();
        format!(
            "{}: {} object(s), {nodes} nodes, {tris} surface triangles, {cols} touchable nodes",
            w.name,
            w.objects.len()
        )
    }

    /// Asks for a WebGPU adapter and device that can draw to `canvas`, uploads every object's
    /// compliance and builds the renderer. `software`: the browser's adapter is a software
    /// rasteriser (its `isFallbackAdapter`): frames are then drawn without MSAA, as the native
    /// window does on lavapipe ([`touchfem_gpu::render::live_samples`]). Errors (no WebGPU, no
    /// adapter) are for the page to show.
    pub async fn attach(
        mut self,
        canvas: web_sys::HtmlCanvasElement,
        software: bool,
    ) -> Result<Page, JsError> {
        let size = [canvas.width().max(1), canvas.height().max(1)];
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::BROWSER_WEBGPU,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let surface = instance
            .create_surface(wgpu::SurfaceTarget::Canvas(canvas))
            .map_err(js_err)?;
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: false,
                compatible_surface: Some(&surface),
                apply_limit_buckets: false,
            })
            .await
            .map_err(|e| JsError::new(&format!("no WebGPU adapter: {e}")))?;
        let info = adapter.get_info();
        let adapter_name = [
            info.name.as_str(),
            info.driver.as_str(),
            info.driver_info.as_str(),
        ]
        .iter()
        .filter(|s| !s.is_empty())
        .copied()
        .collect::<Vec<_>>()
        .join(" / ");
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("touchfem web"),
                required_features: wgpu::Features::empty(),
                required_limits: adapter.limits(),
                experimental_features: wgpu::ExperimentalFeatures::disabled(),
                memory_hints: wgpu::MemoryHints::Performance,
                trace: wgpu::Trace::Off,
            })
            .await
            .map_err(js_err)?;
        let caps = surface.get_capabilities(&adapter);
        // A canvas takes 8-bit unorm formats only: the renderer draws linear colour into an
        // sRGB texture, as into the native window's sRGB surface, whose bytes are then copied
        // onto the canvas (formats that differ only in sRGB-ness copy as they are).
        let format = caps
            .formats
            .first()
            .copied()
            .ok_or_else(|| JsError::new("the adapter cannot draw to this canvas"))?;
        let view_format = format.add_srgb_suffix();
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_DST,
            format,
            width: size[0],
            height: size[1],
            present_mode: wgpu::PresentMode::Fifo,
            desired_maximum_frame_latency: 2,
            alpha_mode: wgpu::CompositeAlphaMode::Opaque,
            view_formats: vec![],
            color_space: wgpu::SurfaceColorSpace::Auto,
        };
        surface.configure(&device, &config);
        let options = RenderOptions {
            samples: if software { 1 } else { 4 },
            format: view_format,
        };
        let offscreen = frame_texture(
            &device,
            "touchfem web frame",
            size,
            view_format,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        );
        let renderer = Renderer::with_options(&device, size, options).map_err(js_err)?;
        let mut legend = Overlay::new(&device, options);
        legend.set_anchor(Anchor::TopRight);
        let img = legend_image(&LegendSpec {
            bar_px: LegendSpec::bar_for(size[1]),
            displacement: Some(self.scales.color_scale),
            arrow_m_per_n: Some(self.scales.arrow_m_per_n),
            force_n: None,
        });
        legend.set_image(&device, &queue, img.as_ref());
        // Room for a separating cut's copies (touchfem-app's `CUT_VERTICES`).
        let cuttable = self
            .world
            .world
            .objects
            .iter()
            .any(|o| o.cuttable.is_some());
        let dopts = DeformerOptions {
            extra_vertices: if cuttable { 256 } else { 0 },
            ..Default::default()
        };
        let mut deformers = Vec::new();
        for o in &self.world.world.objects {
            let b = &o.body;
            deformers.push(
                Deformer::new(
                    &device,
                    &queue,
                    &b.compliance,
                    &b.mesh.nodes,
                    &b.mesh.surface,
                    &dopts,
                )
                .map_err(js_err)?,
            );
        }
        let edges = deformers.iter().map(|d| Edges::new(&device, d)).collect();
        let bodies = vec![None; deformers.len()];
        let (lo, hi) = self.world.world.bounds();
        self.size = size;
        self.orbit = Orbit::framing(lo, hi, f64::from(size[0]) / f64::from(size[1]));
        self.gfx = Some(Gfx {
            surface,
            device,
            queue,
            config,
            renderer,
            legend,
            deformers,
            edges,
            bodies,
            options: dopts,
            adapter: adapter_name,
            readback: None,
            offscreen,
        });
        Ok(self)
    }

    /// The adapter's description (empty before [`Page::attach`]).
    pub fn adapter(&self) -> String {
        self.gfx
            .as_ref()
            .map_or(String::new(), |g| g.adapter.clone())
    }

    /// The scripted press (`press=X,Y,Z:DX,DY,DZ`, scene units; `sphere` a radius or 0;
    /// `exact` the exact model), as `touchfem poke` presses: returns a JSON object with
    /// `force` (N) and `finger` (m). The next frames draw its deformation.
    pub fn scripted_press(
        &mut self,
        press: &str,
        sphere: f64,
        exact: bool,
    ) -> Result<String, JsError> {
        let mut spec = PressSpec::parse(press).map_err(js_err)?;
        spec.exact = exact;
        if sphere != 0.0 {
            spec.sphere = Some(sphere);
        }
        let out = self
            .world
            .press(&spec, crate::page::POKE_STEPS)
            .map_err(js_err)?;
        let json = serde_json::json!({
            "force": out.force.to_array(),
            "finger": out.finger.to_array(),
            "active_columns": out.forces.len(),
        });
        self.scripted = Some(out);
        Ok(json.to_string())
    }

    /// The scripted run (`run=SECONDS`): the scene's scripts for `seconds` of haptic time, a
    /// cut pass every 16 ticks ([`PageWorld::run_scripts`]). Returns a JSON object with each
    /// finger's `forces` (N), `tets_removed`, `nodes_split`, `cut_bodies` and the haptic `time`
    /// (s); the next frames draw the result.
    pub fn run_scripts(&mut self, seconds: f64) -> Result<String, JsError> {
        self.scripted = None;
        self.world.run_scripts(seconds).map_err(js_err)?;
        let forces: Vec<[f64; 3]> = self
            .world
            .finger_forces()
            .iter()
            .map(|f| f.to_array())
            .collect();
        Ok(serde_json::json!({
            "forces": forces,
            "tets_removed": self.world.tets_removed,
            "nodes_split": self.world.nodes_split,
            "cut_bodies": self.world.cut_bodies,
            "time": self.world.time(),
        })
        .to_string())
    }

    /// Steps `n` haptic ticks (the page passes the time elapsed, in ticks; capped).
    pub fn tick(&mut self, n: usize) {
        self.world.tick(n);
    }

    /// The force on the pointer's finger and on any finger, and whether one touches:
    /// `[|F_pointer|, max |F|, touching (0/1), haptic time s]`.
    pub fn readout(&self) -> Vec<f64> {
        let s = self.world.sample();
        let touching = s.fingers().iter().any(|f| f.object.is_some());
        vec![
            self.world.pointer_force().length(),
            self.world.max_force(),
            f64::from(u8::from(touching)),
            self.world.time(),
        ]
    }

    /// The press depth of the pointer's finger under the surface it was pressed on, m (0 when
    /// not pressing).
    pub fn depth(&self) -> f64 {
        self.press.map_or(0.0, |p| {
            let s = self.world.sample();
            s.fingers()
                .iter()
                .find_map(|f| f.object.map(|_| (p.point - f.position).dot(p.normal)))
                .unwrap_or(0.0)
                .max(0.0)
        })
    }

    /// A left press at pixel (x, y): the pointer's finger goes just outside the surface point
    /// under it (nothing under it: nothing happens). True when it touched.
    pub fn pointer_down(&mut self, x: f64, y: f64) -> bool {
        if !self.world.has_pointer() {
            return false;
        }
        let surfaces = rest_surfaces(self.world.world);
        let Some(h) = pick(&self.orbit.camera(), self.size, [x, y], &surfaces) else {
            return false;
        };
        self.scripted = None;
        let press = PointerPress {
            pixel: [x, y],
            point: h.point,
            normal: h.normal,
            object: h.object,
        };
        self.world
            .set_pointer(press.start(self.world.blade_on(), &self.scales));
        self.press = Some(press);
        true
    }

    /// The pointer dragged to (x, y) while pressing: the finger goes into the surface by the
    /// distance dragged, or the blade slides along it (as `touchfem view`).
    pub fn pointer_drag(&mut self, x: f64, y: f64) {
        let Some(p) = self.press else {
            return;
        };
        let camera = self.orbit.camera();
        let blade = self.world.blade_on();
        let surfaces = rest_surfaces(self.world.world);
        if let Some(at) = p.drag(&camera, self.size, [x, y], blade, &self.scales, &surfaces) {
            self.world.set_pointer(at);
        }
    }

    /// `B`: the pointer becomes a blade, or a finger again (the press ends). Returns whether
    /// blade mode is now on; on a scene that cannot be cut, the error says why.
    pub fn toggle_blade(&mut self) -> Result<bool, JsError> {
        self.press = None;
        self.world.toggle_blade().map_err(js_err)
    }

    /// The cutting so far: `[cut bodies made, tets removed, blade mode (0/1), blade depth m,
    /// copies of nodes made]`.
    pub fn cut_readout(&self) -> Vec<f64> {
        vec![
            self.world.cut_bodies as f64,
            self.world.tets_removed as f64,
            f64::from(u8::from(self.world.blade_on())),
            self.world.blade_depth_m().unwrap_or(0.0),
            self.world.nodes_split as f64,
        ]
    }

    /// One cut pass over the strokes since the last one (the cutter runs here, between
    /// frames; the haptic world reads each new body from the next tick). [`Page::frame`]
    /// draws the bodies it made. Returns how many it made.
    pub fn cut(&mut self) -> Result<usize, JsError> {
        self.world.cut().map_err(js_err)
    }

    /// Puts the pointer's finger at (x, y, z), scene frame, metres (NaN lifts it): for scripts
    /// and measurements.
    pub fn set_finger(&mut self, x: f64, y: f64, z: f64) {
        self.world.set_pointer(DVec3::new(x, y, z));
    }

    /// The scripted press's end position (the finger), scene frame, m; empty without one.
    pub fn scripted_finger(&self) -> Vec<f64> {
        self.scripted
            .as_ref()
            .map_or(Vec::new(), |s| s.finger.to_array().to_vec())
    }

    /// Drops the scripted press: the next frames draw the live sample.
    pub fn end_scripted(&mut self) {
        self.scripted = None;
    }

    /// The press ends: the finger lifts.
    pub fn pointer_up(&mut self) {
        self.press = None;
        self.world.set_pointer(DVec3::NAN);
    }

    /// A right drag by (dx, dy) pixels orbits the camera.
    pub fn orbit(&mut self, dx: f64, dy: f64) {
        self.orbit.rotate(dx, dy);
    }

    /// The wheel: `steps` notches (positive zooms in).
    pub fn zoom(&mut self, steps: f64) {
        self.orbit.zoom(steps);
    }

    /// Draws a frame: the cut bodies made since the last frame installed, each object's
    /// deformation pass for the latest forces (the scripted press's, or the haptic sample's),
    /// then the scene as `touchfem view` draws it.
    pub fn frame(&mut self) -> Result<(), JsError> {
        let Some(g) = self.gfx.as_mut() else {
            return Err(JsError::new("no canvas attached"));
        };
        // The cut bodies the cutter made: on the GPU (a new `L` after a fold, the correction,
        // the opened surface and its wireframe).
        for (o, body) in self.world.take_cut_bodies() {
            let (Some(d), Some(obj)) = (g.deformers.get_mut(o), self.world.world.objects.get(o))
            else {
                continue;
            };
            let uploaded = g.bodies[o]
                .as_ref()
                .map_or(&obj.body.compliance, |b| &b.compliance);
            install_cut(
                &g.device,
                &g.queue,
                d,
                uploaded,
                &body.compliance,
                &body.triangles,
                &body.rest,
                &g.options,
            )
            .map_err(|e| JsError::new(&format!("cannot draw the cut of '{}': {e}", obj.name)))?;
            g.edges[o] = Edges::new(&g.device, d);
            g.bodies[o] = Some(body);
        }
        let sample = *self.world.sample();
        let mut marks =
            SampleMarks::of(&sample, self.scales.arrow_m_per_n).with_tools(self.world.world);
        for (o, d) in g.deformers.iter_mut().enumerate() {
            let forces: Vec<(u32, [f32; 3])> = match &self.scripted {
                Some(out) if o == 0 => out
                    .forces
                    .iter()
                    .map(|&(c, f)| (c, f.as_vec3().to_array()))
                    .collect(),
                Some(_) => Vec::new(),
                None if o < sample.n_objects => {
                    let (f, n) = sample.bcs[o].to_f32();
                    f[..n].to_vec()
                }
                None => Vec::new(),
            };
            d.set_forces(&g.queue, &forces).map_err(js_err)?;
        }
        if let Some(out) = &self.scripted {
            marks.n = 1;
            marks.fingers[0] = out.finger;
            marks.proxies[0] = out.proxy.unwrap_or(DVec3::NAN);
            marks.arrows[0].at = out.proxy.unwrap_or(out.finger);
            marks.arrows[0].force_n = out.force;
        }
        let tex = match g.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            _ => {
                g.surface.configure(&g.device, &g.config);
                return Ok(());
            }
        };
        let view = g.offscreen.create_view(&Default::default());
        let objects = frame_objects(self.world.world, &g.deformers, &g.edges);
        let n = marks.n;
        let frame = Frame {
            objects: &objects,
            camera: self.orbit.camera(),
            fingers: &marks.fingers[..n],
            finger_radii: &marks.radii[..n],
            patch: &[],
            proxies: &marks.proxies[..n],
            scale: self.scales.diag,
            wireframe: false,
            overlay: None,
            coloring: Coloring::Displacement {
                full_scale_m: self.scales.color_scale.0,
                step_m: self.scales.color_scale.1,
            },
            arrows: &marks.arrows[..n],
            legend: Some(&g.legend),
        };
        let mut enc = g.device.create_command_encoder(&Default::default());
        g.renderer
            .draw(&g.device, &g.queue, &mut enc, &view, &frame)
            .map_err(js_err)?;
        enc.copy_texture_to_texture(
            g.offscreen.as_image_copy(),
            tex.texture.as_image_copy(),
            g.offscreen.size(),
        );
        g.queue.submit([enc.finish()]);
        g.queue.present(tex);
        Ok(())
    }

    /// Starts reading the first object's vertex buffer back (after the frames drawn so far);
    /// poll [`Page::readback_positions`] until it gives them.
    pub fn begin_readback(&mut self) -> Result<(), JsError> {
        let Some(g) = self.gfx.as_mut() else {
            return Err(JsError::new("no canvas attached"));
        };
        let d = g
            .deformers
            .first()
            .ok_or_else(|| JsError::new("no object"))?;
        // (The displayed rows; the vertices reserved for a separating cut's copies follow.)
        let size = VERTEX_STRIDE * u64::from(d.vertex_count());
        let staging = g.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem web readback"),
            size,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = g.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(d.vertex_buffer(), 0, &staging, 0, size);
        g.queue.submit([enc.finish()]);
        let slot = std::rc::Rc::new(std::cell::Cell::new(None));
        let s2 = slot.clone();
        staging.map_async(wgpu::MapMode::Read, .., move |r| s2.set(Some(r.is_ok())));
        g.readback = Some((staging, slot));
        Ok(())
    }

    /// The read-back's deformed positions, x y z per displayed row (f32, m, the object's
    /// frame), once the GPU has written them; `None` while pending. Errors if the map failed.
    pub fn readback_positions(&mut self) -> Result<Option<Vec<f32>>, JsError> {
        let Some(g) = self.gfx.as_mut() else {
            return Ok(None);
        };
        let Some((buf, slot)) = &g.readback else {
            return Ok(None);
        };
        match slot.get() {
            None => Ok(None),
            Some(false) => {
                g.readback = None;
                Err(JsError::new("reading the vertex buffer back failed"))
            }
            Some(true) => {
                let bytes = buf.get_mapped_range(..).map_err(js_err)?.to_vec();
                buf.unmap();
                g.readback = None;
                let stride = VERTEX_STRIDE as usize;
                let out = bytes
                    .chunks_exact(stride)
                    .flat_map(|v| {
                        (0..3).map(move |k| {
                            f32::from_le_bytes([v[4 * k], v[4 * k + 1], v[4 * k + 2], v[4 * k + 3]])
                        })
                    })
                    .collect();
                Ok(Some(out))
            }
        }
    }

    /// The first object's displayed rows: the node drawn at each vertex of the read-back.
    /// Once it is cut, those of the body its GPU holds (a fold's `L` has rows for the copies;
    /// copies made since are drawn after the rows and not read back).
    pub fn rows(&self) -> Vec<u32> {
        let Some(o) = self.world.world.objects.first() else {
            return Vec::new();
        };
        let uncut = || o.body.compliance.rows().to_vec();
        let Some(g) = self.gfx.as_ref() else {
            return uncut();
        };
        let (Some(d), Some(Some(body))) = (g.deformers.first(), g.bodies.first()) else {
            return uncut();
        };
        let mut rows = vec![u32::MAX; d.vertex_count() as usize];
        for node in 0..body.rest.len() as u32 {
            if let Some(v) = d.row_of(node).and_then(|v| rows.get_mut(v as usize)) {
                *v = node;
            }
        }
        rows
    }
}
