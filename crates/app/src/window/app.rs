//! The winit application behind [`super::run`].

use glam::DVec3;
use std::io::Write as _;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

use super::blade::PointerRoute;
use super::{ViewError, WindowOptions, WindowSummary};
use crate::visual::{CutFollower, GpuTarget};
use touchfem_core::runtime::{LiveStatus, SampleReader};
use touchfem_core::scene::World;
use touchfem_gpu::render::{
    live_samples, pick, Edges, Frame, Orbit, Overlay, RenderOptions, Renderer,
};
use touchfem_gpu::{AdapterSelection, Deformer, DeformerOptions};

use touchfem_gpu::render::{median, rest_surfaces, PointerPress, ViewScales};

/// How long a notice (`B` on a scene that cannot cut) stays on the status line.
const NOTICE_FOR: Duration = Duration::from_secs(3);
/// How often the status line is refreshed.
const STATUS_EVERY: Duration = Duration::from_millis(250);

/// Everything that lives on the device.
struct Gfx {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    renderer: Renderer,
    overlay: Overlay,
    /// The legend (top right): the colour scale and the arrow's.
    legend: Overlay,
    deformers: Vec<Deformer>,
    edges: Vec<Edges>,
    deformer_options: DeformerOptions,
    /// Each object's cut body drawn, followed from the cutter's feed.
    cuts: CutFollower,
    /// The first error the device reported (validation, out of memory, lost).
    device_error: Arc<Mutex<Option<String>>>,
}

/// Per-second and whole-run frame statistics.
#[derive(Default)]
struct Stats {
    frames: u64,
    first: Option<Instant>,
    last_present: Option<Instant>,
    intervals_ms: Vec<f64>,
    second_intervals_ms: Vec<f64>,
    second_draw_ms: Vec<f64>,
    second_force: f64,
    second_frames: u64,
    max_force: f64,
    last_log: Option<Instant>,
    last_status: Option<Instant>,
    status_frame_ms: f64,
}

pub(super) struct App<'a> {
    world: &'a World,
    reader: SampleReader,
    status: &'a LiveStatus,
    pointer: Option<PointerRoute>,
    opts: WindowOptions,
    gfx: Option<Gfx>,
    error: Option<ViewError>,
    orbit: Orbit,
    size: [u32; 2],
    cursor: [f64; 2],
    press: Option<PointerPress>,
    orbiting: bool,
    wireframe: bool,
    /// Colour by displacement (`C` toggles).
    colors: bool,
    /// The colour map's full scale and tick step (m), fixed for the session.
    color_scale: (f64, f64),
    /// The force arrow's scale, m per N, fixed for the session.
    arrow_m_per_n: f64,
    /// The view's scales (press depth per pixel, the blade's sink).
    scales: ViewScales,
    /// A message for the status line, and when it was given.
    notice: Option<(String, Instant)>,
    scale: f64,
    stats: Stats,
    quit_after: Option<Duration>,
    started: Instant,
    log: Option<std::fs::File>,
    samples_override: Option<u32>,
}

/// The largest `TOUCHFEM_VIEW_SECONDS` accepted (about 11.6 days).
pub(super) const MAX_VIEW_SECONDS: f64 = 1e6;

/// The window's environment hooks (see the module documentation), checked.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct EnvHooks {
    /// `TOUCHFEM_VIEW_SECONDS`: quit after this long.
    pub quit_after: Option<Duration>,
    /// `TOUCHFEM_VIEW_SAMPLES`: the MSAA sample count, 1 or 4.
    pub samples: Option<u32>,
}

impl EnvHooks {
    /// Reads `TOUCHFEM_VIEW_SECONDS` (a number of seconds in [0, 1e6]) and
    /// `TOUCHFEM_VIEW_SAMPLES` (1 or 4); unset or empty means no hook. A value that is not one
    /// of those is an error naming the variable.
    pub(super) fn from_env() -> Result<EnvHooks, String> {
        let var = |name: &str| {
            std::env::var_os(name)
                .map(|v| v.to_string_lossy().trim().to_string())
                .filter(|v| !v.is_empty())
        };
        Ok(EnvHooks {
            quit_after: var("TOUCHFEM_VIEW_SECONDS")
                .map(|v| parse_view_seconds(&v))
                .transpose()?,
            samples: var("TOUCHFEM_VIEW_SAMPLES")
                .map(|v| parse_view_samples(&v))
                .transpose()?,
        })
    }
}

/// `TOUCHFEM_VIEW_SECONDS`: a finite number of seconds in [0, [`MAX_VIEW_SECONDS`]].
pub(super) fn parse_view_seconds(v: &str) -> Result<Duration, String> {
    v.parse::<f64>()
        .ok()
        .filter(|s| s.is_finite() && (0.0..=MAX_VIEW_SECONDS).contains(s))
        .and_then(|s| Duration::try_from_secs_f64(s).ok())
        .ok_or_else(|| {
            format!("TOUCHFEM_VIEW_SECONDS={v:?}: expected seconds in [0, {MAX_VIEW_SECONDS:e}]")
        })
}

/// `TOUCHFEM_VIEW_SAMPLES`: 1 or 4.
pub(super) fn parse_view_samples(v: &str) -> Result<u32, String> {
    match v.parse::<u32>() {
        Ok(n @ (1 | 4)) => Ok(n),
        _ => Err(format!("TOUCHFEM_VIEW_SAMPLES={v:?}: expected 1 or 4")),
    }
}

impl<'a> App<'a> {
    pub(super) fn new(
        world: &'a World,
        reader: SampleReader,
        status: &'a LiveStatus,
        pointer: Option<PointerRoute>,
        opts: &WindowOptions,
        hooks: &EnvHooks,
    ) -> App<'a> {
        let (lo, hi) = world.bounds();
        let (lo, hi) = if lo.is_finite() && hi.is_finite() {
            (lo, hi)
        } else {
            (DVec3::ZERO, DVec3::ONE)
        };
        let size = [opts.size[0].max(1), opts.size[1].max(1)];
        let scales = ViewScales::of(world);
        let diag = scales.diag;
        let EnvHooks {
            quit_after,
            samples: samples_override,
        } = *hooks;
        let log = std::env::var_os("TOUCHFEM_VIEW_LOG").and_then(|p| {
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(&p)
                .map_err(|e| {
                    eprintln!(
                        "warning: cannot open TOUCHFEM_VIEW_LOG={}: {e}",
                        p.to_string_lossy()
                    )
                })
                .ok()
        });
        App {
            world,
            reader,
            status,
            pointer,
            opts: opts.clone(),
            gfx: None,
            error: None,
            orbit: Orbit::framing(lo, hi, f64::from(size[0]) / f64::from(size[1])),
            size,
            cursor: [0.0; 2],
            press: None,
            orbiting: false,
            wireframe: touchfem_gpu::render::wireframe_by_default(
                world
                    .objects
                    .iter()
                    .map(|o| o.body.mesh.surface.len())
                    .sum(),
                size,
            ),
            colors: opts.colors,
            color_scale: scales.color_scale,
            arrow_m_per_n: scales.arrow_m_per_n,
            scales,
            notice: None,
            scale: diag,
            stats: Stats::default(),
            quit_after,
            started: Instant::now(),
            log,
            samples_override,
        }
    }

    /// The result once the event loop has returned.
    pub(super) fn finish(mut self) -> Result<WindowSummary, ViewError> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        let summary = self.summary();
        if let Some(f) = &mut self.log {
            let line = serde_json::json!({
                "summary": true,
                "frames": summary.frames,
                "seconds": summary.seconds,
                "frame_ms_median": summary.frame_ms_median,
                "max_force_n": summary.max_force_n,
                "haptic_hz": self.status.rate_hz(),
                "samples": self.gfx.as_ref().map(|g| g.renderer.options().samples),
            });
            let _ = writeln!(f, "{line}");
        }
        Ok(summary)
    }

    fn summary(&self) -> WindowSummary {
        let mut iv = self.stats.intervals_ms.clone();
        WindowSummary {
            frames: self.stats.frames,
            seconds: self.stats.first.map_or(0.0, |t| t.elapsed().as_secs_f64()),
            frame_ms_median: median(&mut iv),
            max_force_n: self.stats.max_force,
        }
    }

    fn fail(&mut self, el: &ActiveEventLoop, e: ViewError) {
        if self.error.is_none() {
            self.error = Some(e);
        }
        self.quit(el);
    }

    fn quit(&mut self, el: &ActiveEventLoop) {
        self.status.stop.store(true, Ordering::SeqCst);
        if let Some(p) = &self.pointer {
            p.lift();
        }
        el.exit();
    }

    fn aspect(&self) -> f64 {
        f64::from(self.size[0]) / f64::from(self.size[1])
    }

    /// Creates the window and everything on the device.
    fn init(&mut self, el: &ActiveEventLoop) -> Result<Gfx, ViewError> {
        let attrs = Window::default_attributes()
            .with_title(self.opts.title.clone())
            .with_inner_size(PhysicalSize::new(self.size[0], self.size[1]));
        let window = Arc::new(el.create_window(attrs)?);
        let sel = AdapterSelection::from_env();
        let instance = touchfem_gpu::Gpu::instance(&sel);
        let surface = instance.create_surface(window.clone())?;
        let touchfem_gpu::Gpu {
            instance: _,
            adapter,
            device,
            queue,
        } = touchfem_gpu::Gpu::with_instance(instance, &sel, Some(&surface)).map_err(|e| {
            ViewError::Present(format!(
                "no adapter can present to the window ({e}); set WGPU_BACKEND (e.g. \
                 WGPU_BACKEND=vulkan with Mesa's lavapipe installed)"
            ))
        })?;
        let device_error: Arc<Mutex<Option<String>>> = Arc::default();
        {
            let slot = device_error.clone();
            device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
                if let Ok(mut s) = slot.lock() {
                    s.get_or_insert_with(|| e.to_string());
                }
            }));
            let slot = device_error.clone();
            device.set_device_lost_callback(move |reason, msg| {
                if let Ok(mut s) = slot.lock() {
                    s.get_or_insert_with(|| format!("device lost ({reason:?}): {msg}"));
                }
            });
        }
        let caps = surface.get_capabilities(&adapter);
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| f.is_srgb())
            .or_else(|| caps.formats.first().copied())
            .ok_or_else(|| {
                ViewError::Present(format!(
                    "the adapter {} cannot present to this window",
                    adapter.get_info().name
                ))
            })?;
        let inner = window.inner_size();
        if inner.width > 0 && inner.height > 0 {
            self.size = [inner.width, inner.height];
        }
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            format,
            width: self.size[0],
            height: self.size[1],
            present_mode: wgpu::PresentMode::Fifo,
            desired_maximum_frame_latency: 2,
            alpha_mode: caps
                .alpha_modes
                .first()
                .copied()
                .unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: vec![],
            color_space: wgpu::SurfaceColorSpace::Auto,
        };
        surface.configure(&device, &config);
        let samples = self
            .samples_override
            .filter(|s| matches!(s, 1 | 4))
            .unwrap_or_else(|| live_samples(&adapter.get_info()));
        let options = RenderOptions { samples, format };
        let renderer = Renderer::with_options(&device, self.size, options)?;
        let overlay = Overlay::new(&device, options);
        let mut legend = Overlay::new(&device, options);
        legend.set_anchor(touchfem_gpu::render::Anchor::TopRight);
        let mut deformers = Vec::with_capacity(self.world.objects.len());
        let deformer_options =
            crate::visual::deformer_options(self.world, touchfem_gpu::LStorage::from_env()?);
        for o in &self.world.objects {
            deformers.push(Deformer::new(
                &device,
                &queue,
                &o.body.compliance,
                &o.body.mesh.nodes,
                &o.body.mesh.surface,
                &deformer_options,
            )?);
        }
        let edges = deformers.iter().map(|d| Edges::new(&device, d)).collect();
        let (lo, hi) = self.world.bounds();
        if lo.is_finite() && hi.is_finite() {
            self.orbit = Orbit::framing(lo, hi, self.aspect());
        }
        let legend_img = self.legend_image();
        legend.set_image(&device, &queue, legend_img.as_ref());
        Ok(Gfx {
            window,
            surface,
            device,
            queue,
            config,
            renderer,
            overlay,
            legend,
            cuts: CutFollower::new(deformers.len()),
            deformers,
            edges,
            deformer_options,
            device_error,
        })
    }

    /// The legend for the current colouring.
    fn legend_image(&self) -> Option<touchfem_gpu::render::RgbaPixels> {
        touchfem_gpu::render::legend_image(&touchfem_gpu::render::LegendSpec {
            bar_px: touchfem_gpu::render::LegendSpec::bar_for(self.size[1]),
            displacement: self.colors.then_some(self.color_scale),
            arrow_m_per_n: Some(self.arrow_m_per_n),
            force_n: None,
        })
    }

    /// The surface colouring now.
    fn coloring(&self) -> touchfem_gpu::render::Coloring {
        if self.colors {
            touchfem_gpu::render::Coloring::Displacement {
                full_scale_m: self.color_scale.0,
                step_m: self.color_scale.1,
            }
        } else {
            touchfem_gpu::render::Coloring::Plain
        }
    }

    fn redraw(&mut self, el: &ActiveEventLoop) -> Result<(), ViewError> {
        if self.status.done.load(Ordering::SeqCst) {
            if self.status.panicked.load(Ordering::SeqCst) {
                return Err(ViewError::HapticPanicked);
            }
            self.quit(el);
            return Ok(());
        }
        if self.quit_after.is_some_and(|d| self.started.elapsed() >= d) {
            self.quit(el);
            return Ok(());
        }
        let t0 = Instant::now();
        let sample = *self.reader.read();
        let force = super::force_readout(&sample);
        let marks =
            crate::visual::SampleMarks::of(&sample, self.arrow_m_per_n).with_tools(self.world);
        let touching = sample.fingers().iter().any(|f| f.object.is_some());
        let coloring = self.coloring();
        let status_due = self
            .stats
            .last_status
            .is_none_or(|t| t.elapsed() >= STATUS_EVERY);
        let status_text = status_due.then(|| {
            let fps = if self.stats.status_frame_ms > 0.0 {
                1000.0 / self.stats.status_frame_ms
            } else {
                0.0
            };
            let mut text = format!(
                "|F| {force:5.2} N  haptic {:4.0} Hz  frame {:5.1} ms ({fps:3.0} fps)",
                self.status.rate_hz(),
                self.stats.status_frame_ms,
            );
            if let Some(d) = self.pointer.as_ref().and_then(PointerRoute::blade_depth_m) {
                text.push_str(&format!("  blade {:.1} mm", d * 1e3));
            }
            let notice = self
                .notice
                .as_ref()
                .filter(|(_, t)| t.elapsed() < NOTICE_FOR)
                .map(|(msg, _)| msg.clone());
            (text, notice)
        });
        let camera = self.orbit.camera();
        let Some(g) = self.gfx.as_mut() else {
            return Ok(());
        };
        if let Some(e) = g.device_error.lock().ok().and_then(|mut s| s.take()) {
            return Err(ViewError::Device(e));
        }
        // The cutter's thread made new cut bodies: draw them.
        let (changed, failure) = g.cuts.take(
            &self.status.cuts,
            self.world,
            Some(GpuTarget {
                device: &g.device,
                queue: &g.queue,
                deformers: &mut g.deformers,
                options: &g.deformer_options,
            }),
        );
        if let Some(e) = failure {
            log::warn!("{e}");
        }
        for o in changed {
            if let (Some(e), Some(d)) = (g.edges.get_mut(o), g.deformers.get(o)) {
                *e = Edges::new(&g.device, d);
            }
        }
        for (o, d) in g.deformers.iter_mut().enumerate() {
            let (mut f, n) = if o < sample.n_objects {
                sample.bcs[o].to_f32()
            } else {
                touchfem_core::contact::force::ForceBc::default().to_f32()
            };
            // (A newer separating body's copies: left out for this frame.)
            let n = d.keep_known(&mut f[..n]);
            d.set_forces(&g.queue, &f[..n])?;
        }
        if let Some((text, notice)) = &status_text {
            let legend_w = g.legend.image_size().map_or(0, |s| s[0]);
            let shown = super::status_overlay(text, notice.as_deref(), self.size[0], legend_w);
            g.overlay.set_text(&g.device, &g.queue, &shown);
            let warning = notice
                .as_ref()
                .map_or(String::new(), |n| format!("  warning: {n}"));
            g.window
                .set_title(&format!("{} | {text}{warning}", self.opts.title));
            self.stats.last_status = Some(Instant::now());
        }
        let frame_tex = match g.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) => t,
            wgpu::CurrentSurfaceTexture::Suboptimal(t) => {
                // Present this one, then reconfigure.
                g.surface.configure(&g.device, &g.config);
                t
            }
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => {
                // Skip this frame; `about_to_wait` asks again shortly.
                return Ok(());
            }
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                g.surface.configure(&g.device, &g.config);
                g.window.request_redraw();
                return Ok(());
            }
            wgpu::CurrentSurfaceTexture::Validation => {
                let msg = g
                    .device_error
                    .lock()
                    .ok()
                    .and_then(|mut s| s.take())
                    .unwrap_or_else(|| "validation error acquiring the frame".into());
                return Err(ViewError::Present(msg));
            }
        };
        let view = frame_tex.texture.create_view(&Default::default());
        let objects = crate::visual::frame_objects(self.world, &g.deformers, &g.edges);
        let n_f = marks.n;
        let frame = Frame {
            objects: &objects,
            camera,
            fingers: &marks.fingers[..n_f],
            finger_radii: &marks.radii[..n_f],
            patch: &[],
            proxies: &marks.proxies[..n_f],
            scale: self.scale,
            wireframe: self.wireframe,
            overlay: Some(&g.overlay),
            coloring,
            arrows: &marks.arrows[..n_f],
            legend: Some(&g.legend),
        };
        let mut enc = g
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("touchfem view frame"),
            });
        g.renderer
            .draw(&g.device, &g.queue, &mut enc, &view, &frame)?;
        g.queue.submit([enc.finish()]);
        g.window.pre_present_notify();
        g.queue.present(frame_tex);
        g.window.request_redraw();

        // Statistics and the log.
        let now = Instant::now();
        let s = &mut self.stats;
        s.frames += 1;
        s.second_frames += 1;
        s.first.get_or_insert(now);
        if let Some(prev) = s.last_present {
            let ms = (now - prev).as_secs_f64() * 1e3;
            // The whole run's median is taken over the first million frames (8 MB).
            if s.intervals_ms.len() < 1_000_000 {
                s.intervals_ms.push(ms);
            }
            s.second_intervals_ms.push(ms);
        }
        s.last_present = Some(now);
        s.second_draw_ms.push((now - t0).as_secs_f64() * 1e3);
        s.second_force = s.second_force.max(force);
        s.max_force = s.max_force.max(force);
        let last_log = *s.last_log.get_or_insert(now);
        if now - last_log >= Duration::from_secs(1) {
            let frame_ms = median(&mut s.second_intervals_ms);
            s.status_frame_ms = frame_ms;
            let line = serde_json::json!({
                "t": self.started.elapsed().as_secs_f64(),
                "frames": s.frames,
                "fps": s.second_frames as f64 / (now - last_log).as_secs_f64(),
                "frame_ms_median": frame_ms,
                "draw_ms_median": median(&mut s.second_draw_ms),
                "force_n": s.second_force,
                "haptic_hz": self.status.rate_hz(),
                "haptic_missed": self.status.missed.load(Ordering::Relaxed),
                "touching": touching,
                "blade": self.pointer.as_ref().is_some_and(PointerRoute::blade_on),
                "tets_removed": self.status.cuts.latest().iter().map(|(_, b)| b.tets_removed).sum::<usize>(),
                "nodes_split": self.status.cuts.latest().iter().map(|(_, b)| b.nodes_split).sum::<usize>(),
            });
            if let Some(f) = &mut self.log {
                let _ = writeln!(f, "{line}");
            }
            s.second_intervals_ms.clear();
            s.second_draw_ms.clear();
            s.second_force = 0.0;
            s.second_frames = 0;
            s.last_log = Some(now);
        } else if s.status_frame_ms == 0.0 && s.intervals_ms.len() >= 5 {
            let mut iv = s.intervals_ms.clone();
            s.status_frame_ms = median(&mut iv);
        }
        Ok(())
    }

    fn resize(&mut self, size: PhysicalSize<u32>) -> Result<(), ViewError> {
        if size.width == 0 || size.height == 0 {
            return Ok(());
        }
        self.size = [size.width, size.height];
        if let Some(g) = self.gfx.as_mut() {
            g.config.width = size.width;
            g.config.height = size.height;
            g.surface.configure(&g.device, &g.config);
            g.renderer.resize(&g.device, self.size)?;
            g.window.request_redraw();
        }
        Ok(())
    }

    /// `B`: the pointer becomes a blade, or its scene tool again; on a scene that cannot cut,
    /// says why (status line and log) and changes nothing.
    fn toggle_blade(&mut self) {
        let Some(pointer) = &mut self.pointer else {
            self.notify("blade: this window has no pointer finger".into());
            return;
        };
        match pointer.toggle_blade() {
            Ok(on) => {
                // The finger that was driven was lifted: a drag starts again with a press.
                self.press = None;
                log::info!("blade mode {}", if on { "on" } else { "off" });
                self.notice = None;
            }
            Err(why) => self.notify(why),
        }
        self.stats.last_status = None;
    }

    fn notify(&mut self, msg: String) {
        log::warn!("warning: {msg}");
        self.notice = Some((msg, Instant::now()));
        self.stats.last_status = None;
    }

    fn left_press(&mut self) {
        let Some(pointer) = &self.pointer else {
            return;
        };
        let surfaces = rest_surfaces(self.world);
        let hit = pick(&self.orbit.camera(), self.size, self.cursor, &surfaces);
        if let Some(h) = hit {
            let press = PointerPress {
                pixel: self.cursor,
                point: h.point,
                normal: h.normal,
                object: h.object,
            };
            pointer.set_position(press.start(pointer.blade_on(), &self.scales));
            self.press = Some(press);
        }
    }

    fn drag(&mut self) {
        let (Some(p), Some(pointer)) = (self.press, &self.pointer) else {
            return;
        };
        let camera = self.orbit.camera();
        let surfaces = rest_surfaces(self.world);
        if let Some(x) = p.drag(
            &camera,
            self.size,
            self.cursor,
            pointer.blade_on(),
            &self.scales,
            &surfaces,
        ) {
            pointer.set_position(x);
        }
    }

    fn release(&mut self) {
        if self.press.take().is_some() {
            if let Some(p) = &self.pointer {
                p.lift();
            }
        }
    }
}

impl ApplicationHandler for App<'_> {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.gfx.is_some() {
            return;
        }
        match self.init(el) {
            Ok(g) => {
                g.window.request_redraw();
                self.gfx = Some(g);
                self.started = Instant::now();
                self.status.visual_ready.store(true, Ordering::SeqCst);
            }
            Err(e) => self.fail(el, e),
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested | WindowEvent::Destroyed => self.quit(el),
            // Not winit's synthetic presses of the keys held when the window gains focus (X11
            // sends one with a key that comes with the focus): a toggle would flip twice.
            WindowEvent::KeyboardInput {
                event,
                is_synthetic: false,
                ..
            } if event.state == ElementState::Pressed => match event.logical_key.as_ref() {
                Key::Named(NamedKey::Escape) => self.quit(el),
                Key::Character(c) if c.eq_ignore_ascii_case("b") => self.toggle_blade(),
                Key::Character(c) if c.eq_ignore_ascii_case("w") => {
                    self.wireframe = !self.wireframe
                }
                Key::Character(c) if c.eq_ignore_ascii_case("c") => {
                    self.colors = !self.colors;
                    let img = self.legend_image();
                    if let Some(g) = self.gfx.as_mut() {
                        g.legend.set_image(&g.device, &g.queue, img.as_ref());
                    }
                }
                _ => {}
            },
            WindowEvent::Resized(size) => {
                if let Err(e) = self.resize(size) {
                    self.fail(el, e);
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                let old = self.cursor;
                self.cursor = [position.x, position.y];
                if self.orbiting {
                    self.orbit
                        .rotate(self.cursor[0] - old[0], self.cursor[1] - old[1]);
                }
                self.drag();
            }
            WindowEvent::MouseInput { state, button, .. } => match (button, state) {
                (MouseButton::Left, ElementState::Pressed) => self.left_press(),
                (MouseButton::Left, ElementState::Released) => self.release(),
                (MouseButton::Right, s) => self.orbiting = s == ElementState::Pressed,
                _ => {}
            },
            WindowEvent::MouseWheel { delta, .. } => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => f64::from(y),
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                self.orbit.zoom(steps);
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw(el) {
                    self.fail(el, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, el: &ActiveEventLoop) {
        // Wake at least every 50 ms, so the timer and the haptic loop's end are noticed even
        // when no frame is drawn (a hidden window).
        if self.status.done.load(Ordering::SeqCst)
            || self.quit_after.is_some_and(|d| self.started.elapsed() >= d)
        {
            if self.status.panicked.load(Ordering::SeqCst) {
                self.fail(el, ViewError::HapticPanicked);
            } else {
                self.quit(el);
            }
            return;
        }
        // A skipped frame (timeout, occluded window) is retried here rather than at once.
        if let Some(g) = &self.gfx {
            let stale = self
                .stats
                .last_present
                .is_none_or(|t| t.elapsed() >= Duration::from_millis(50));
            if stale {
                g.window.request_redraw();
            }
        }
        el.set_control_flow(ControlFlow::WaitUntil(
            Instant::now() + Duration::from_millis(50),
        ));
    }
}
