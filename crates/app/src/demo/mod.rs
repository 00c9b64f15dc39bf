//! `touchfem demo`: scenes run headless with both loops, as in the paper's prototype — the
//! haptic loop on its own core at the scene's rate, the visual loop asynchronously — with the
//! paper's Table 2 measured on this machine, frames, an animated GIF of the press, each
//! object's force trace (CSV and plot) and the recorded session.
//!
//! Each scene first runs the *floor* (a bare paced loop on the haptic core, no work) for the
//! run's length while the visual loop draws, then the haptic loop for the same length: the
//! report holds both, so the haptic loop's timing is judged against what this machine gives a
//! loop that does nothing.

pub mod trace;

use glam::DVec3;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::Instant;

use crate::error::Error;
use crate::visual::Visual;
use touchfem_core::contact::force::MAX_FINGERS;
use touchfem_core::devices::{HapticDevice, KeyframePath};
use touchfem_core::runtime::pacer::run_floor;
use touchfem_core::runtime::pacer::{percentile, HapticStats};
use touchfem_core::runtime::{
    join_haptic, run_haptic, sample_channel, session, DoneGuard, HapticWorld, LiveStatus,
    WorldSample,
};
use touchfem_core::scene::{DeviceSpec, World};
use touchfem_gpu::Gpu;

/// One object's row of the paper's Table 2.
#[derive(Clone, Debug, serde::Serialize)]
pub(crate) struct ObjectReport {
    /// The scene it belongs to.
    pub scene: String,
    /// The object's name.
    pub name: String,
    /// All nodes.
    pub nodes: usize,
    /// Displayed nodes (rows of the precomputed compliance).
    pub rows: usize,
    /// Touchable nodes (columns).
    pub cols: usize,
    /// Precompute time, s (0 when loaded from the cache: see `precompute_cached`).
    pub precompute_s: f64,
    /// max |K·L − I| of the precompute.
    pub residual: f64,
    /// Median haptic step of the scene (every finger: god-objects and force solve), µs,
    /// measured outside the loop over the scene's own finger paths.
    pub force_us_median: f64,
    /// Median displacement update `u = L·F` of the scene's objects, µs (submit to completion).
    pub displacement_us_median: f64,
    /// Where the displacement ran.
    pub displacement_backend: String,
    /// Frames drawn per second while the haptic loop ran.
    pub draw_hz: f64,
    /// Frames drawn.
    pub frames: u64,
    /// Most fingers touching this object at once.
    pub max_contacts: usize,
    /// The haptic loop's timing in this scene.
    pub haptic: HapticStats,
    /// The bare loop's timing in this scene (same core, same length, visual loop running).
    pub floor: HapticStats,
    /// What the cutter's thread did to this scene (zero without a blade and a cuttable
    /// object): cut bodies built, tets removed, the longest pass in seconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cuts: Option<touchfem_core::runtime::cutting::CutStats>,
}

/// The demo report (`--report FILE.json`).
#[derive(Clone, Debug, serde::Serialize)]
pub(crate) struct DemoReport {
    /// One entry per object of every scene.
    pub objects: Vec<ObjectReport>,
    /// The haptic loop's timing over all scenes (the worst numbers).
    pub haptic: HapticStats,
    /// The bare loop's timing over all scenes (the worst numbers).
    pub floor: HapticStats,
    /// Machine description.
    pub machine: String,
}

/// Options of the demo.
#[derive(Clone, Debug)]
pub(crate) struct DemoOptions {
    /// Seconds of haptic + visual loop per scene (scripted paths are stretched to fit).
    pub seconds: f64,
    /// Where frames, traces, plots and GIFs go.
    pub out: PathBuf,
    /// Which cores the visual and haptic loops run on.
    pub placement: touchfem_core::threads::VisualPlacement,
    /// Record the session here (else `OUT/SCENE.tfsession`).
    pub record: Option<PathBuf>,
    /// Image size of frames.
    pub size: [u32; 2],
    /// Colour the frames by displacement (viridis, a legend in mm) rather than plain.
    pub displacement_colors: bool,
}

/// What a scene's frames share, so that they compare: the colour map's full scale, the force
/// arrow's scale and the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PictureScales {
    /// The largest |u| over the scene's objects during its scripted run (a preview), m.
    pub max_displacement_m: f64,
    /// The largest force on a finger during it, N.
    pub max_force_n: f64,
    /// The colour map's full scale ([`touchfem_gpu::render::displacement_scale`] of the largest
    /// |u|) and tick step, m.
    pub displacement: (f64, f64),
    /// The arrow's scale, m per N: the largest force about a quarter of the scene's size.
    pub arrow_m_per_n: f64,
}

/// Previews a scene's scripted run — `samples` instants of its paths through the haptic path,
/// `u = L·F` on the CPU (f64) for every object — for the scales its frames share.
pub(crate) fn picture_scales(world: &World, samples: usize) -> Result<PictureScales, Error> {
    let mut run = ScriptedRun::new(world)?;
    let mut u: Vec<Vec<DVec3>> = world
        .objects
        .iter()
        .map(|o| vec![DVec3::ZERO; o.body.compliance.rows().len()])
        .collect();
    let (mut max_u, mut max_f) = (0.0f64, 0.0f64);
    for i in 0..=samples {
        run.place(i as f64 / samples.max(1) as f64);
        run.step();
        for (k, o) in world.objects.iter().enumerate() {
            o.body.compliance.displace(run.s.bc(k).entries(), &mut u[k]);
            max_u = u[k].iter().map(|v| v.length()).fold(max_u, f64::max);
        }
        max_f = run.f[..run.n]
            .iter()
            .map(|v| v.length())
            .fold(max_f, f64::max);
    }
    let (lo, hi) = world.bounds();
    let diag = (hi - lo).length();
    Ok(PictureScales {
        max_displacement_m: max_u,
        max_force_n: max_f,
        displacement: touchfem_gpu::render::displacement_scale(max_u),
        arrow_m_per_n: touchfem_gpu::render::arrow_scale(max_f, 0.25 * diag),
    })
}

/// The camera a scene's frames share: its objects' rest surfaces, and its fingers' keyframes
/// within 15 % of the scene's size of them, fill the image left of a legend `legend_px` wide
/// (see [`touchfem_gpu::render::Camera::fit`]).
///
/// A scene that cuts (a blade finger and a cuttable object) is framed on its cuttable tets and
/// its fingers' keyframes instead, so that the cut is large enough to see.
pub fn scene_camera(
    world: &World,
    size: [u32; 2],
    legend_px: Option<[u32; 2]>,
) -> touchfem_gpu::render::Camera {
    let cuts = world.fingers.iter().any(|f| f.tool.blade_depth().is_some());
    let mut pts: Vec<DVec3> = Vec::new();
    for o in &world.objects {
        let mesh = &o.body.mesh;
        match (&o.cuttable, cuts) {
            (Some(region), true) => pts.extend(
                mesh.tets
                    .iter()
                    .enumerate()
                    .filter(|&(t, _)| region.contains(t))
                    .flat_map(|(_, tet)| tet.iter().map(|&i| mesh.nodes[i as usize] + o.offset)),
            ),
            _ => pts.extend(
                mesh.surface
                    .iter()
                    .flatten()
                    .map(|&i| mesh.nodes[i as usize] + o.offset),
            ),
        }
    }
    let (lo, hi) = world.bounds();
    let pad = DVec3::splat(0.15 * (hi - lo).length());
    for f in &world.fingers {
        if let DeviceSpec::Script(keys) = &f.device {
            pts.extend(keys.iter().map(|k| k.1.clamp(lo - pad, hi + pad)));
        }
    }
    touchfem_gpu::render::Camera::fit(
        &pts,
        touchfem_gpu::render::VIEW_DIR,
        f64::from(size[0]) / f64::from(size[1].max(1)),
        touchfem_gpu::render::region_beside_legend(size, legend_px),
    )
}

/// A scripted finger stretched in time to fit a run.
struct Stretched {
    path: KeyframePath,
    k: f64,
}

impl HapticDevice for Stretched {
    fn position(&mut self, t: f64) -> DVec3 {
        self.path.at(t * self.k)
    }
    fn set_force(&mut self, _f: DVec3) {}
}

/// The scene's scripted fingers as devices, stretched so the longest path lasts `seconds`.
/// Returns an error for a finger the demo cannot drive (pointer, udp, replay).
pub(crate) fn scripted_devices(
    world: &World,
    seconds: f64,
) -> Result<Vec<Box<dyn HapticDevice>>, Error> {
    let mut paths = Vec::new();
    for (i, f) in world.fingers.iter().enumerate() {
        match &f.device {
            DeviceSpec::Script(keys) => paths.push(
                KeyframePath::new(keys.clone())
                    .ok_or_else(|| Error::Body(format!("finger {}: bad path", i + 1)))?,
            ),
            other => {
                return Err(Error::Body(format!(
                    "scene '{}': finger {} uses device {other:?}; the demo drives scripted fingers only (use `view` or `serve`)",
                    world.name,
                    i + 1
                )))
            }
        }
    }
    let longest = paths.iter().map(KeyframePath::duration).fold(0.0, f64::max);
    let k = if longest > 0.0 {
        longest / seconds
    } else {
        1.0
    };
    Ok(paths
        .into_iter()
        .map(|path| Box::new(Stretched { path, k }) as Box<dyn HapticDevice>)
        .collect())
}

/// A scene's scripted fingers stepped through the haptic path outside the loop: what the
/// preview and the step timing share.
struct ScriptedRun<'w> {
    devs: Vec<Box<dyn HapticDevice>>,
    n: usize,
    hw: HapticWorld<'w>,
    s: WorldSample,
    pos: [DVec3; MAX_FINGERS],
    f: [DVec3; MAX_FINGERS],
}

impl<'w> ScriptedRun<'w> {
    fn new(world: &'w World) -> Result<ScriptedRun<'w>, Error> {
        let devs = scripted_devices(world, 1.0)?;
        Ok(ScriptedRun {
            n: devs.len().min(MAX_FINGERS),
            devs,
            hw: HapticWorld::new(world),
            s: WorldSample::default(),
            pos: [DVec3::ZERO; MAX_FINGERS],
            f: [DVec3::ZERO; MAX_FINGERS],
        })
    }

    /// Moves every finger to where its path is at `t` (0 to 1).
    fn place(&mut self, t: f64) {
        for (p, d) in self.pos.iter_mut().zip(self.devs.iter_mut()) {
            *p = d.position(t);
        }
    }

    /// One haptic step from where the fingers are.
    fn step(&mut self) {
        self.hw
            .step(&self.pos[..self.n], &mut self.f[..self.n], &mut self.s);
    }
}

/// Median haptic step (µs) of a scene over its scripted paths, outside the loop.
pub(crate) fn step_median(world: &World, samples: usize) -> Result<f64, Error> {
    let mut run = ScriptedRun::new(world)?;
    let mut times = Vec::with_capacity(samples);
    for i in 0..samples {
        run.place(i as f64 / samples as f64);
        let t0 = Instant::now();
        run.step();
        times.push(t0.elapsed().as_secs_f64() * 1e6);
        std::hint::black_box(&run.s);
    }
    times.sort_by(|a, b| a.total_cmp(b));
    Ok(percentile(&times, 0.5))
}

/// How a scene's frames are drawn: the shared camera, colouring, arrow scale and legend.
struct FrameStyle {
    camera: touchfem_gpu::render::Camera,
    coloring: touchfem_gpu::render::Coloring,
    arrow_m_per_n: f64,
    legend: Option<touchfem_gpu::render::Overlay>,
}

/// Draws one frame of every object with every finger and god-object, and an arrow for the
/// force on each touching finger.
fn draw(
    (gpu, renderer): (&Gpu, &touchfem_gpu::render::Renderer),
    edges: &[touchfem_gpu::render::Edges],
    world: &World,
    visual: &Visual<'_>,
    sample: &WorldSample,
    style: &FrameStyle,
    target: Option<&touchfem_gpu::wgpu::TextureView>,
) -> Result<Option<image::RgbaImage>, Error> {
    let Some(deformers) = visual.deformers() else {
        return Ok(None);
    };
    // `Visual::update` ran the deformation passes for this sample: not again here.
    let objects: Vec<_> = crate::visual::frame_objects(world, deformers, edges)
        .into_iter()
        .map(|o| touchfem_gpu::render::FrameObject {
            deformed: true,
            ..o
        })
        .collect();
    // A wireframe denser than one edge per 8 pixels is noise (and most of lavapipe's time
    // on a large organ): drawn only below that.
    let [w, h] = renderer.size();
    let n_edges: u64 = edges.iter().map(|e| u64::from(e.index_count() / 2)).sum();
    let wireframe = n_edges <= u64::from(w) * u64::from(h) / 8;
    let marks = crate::visual::SampleMarks::of(sample, style.arrow_m_per_n).with_tools(world);
    let n_f = marks.n;
    let (lo, hi) = world.bounds();
    let frame = touchfem_gpu::render::Frame {
        objects: &objects,
        camera: style.camera,
        fingers: &marks.fingers[..n_f],
        finger_radii: &marks.radii[..n_f],
        patch: &[],
        proxies: &marks.proxies[..n_f],
        scale: (hi - lo).length(),
        wireframe,
        overlay: None,
        coloring: style.coloring,
        arrows: &marks.arrows[..n_f],
        legend: style.legend.as_ref(),
    };
    let Some(target) = target else {
        return renderer
            .render_to_image(&gpu.device, &gpu.queue, &frame)
            .map(Some)
            .map_err(Error::from);
    };
    // No image wanted: drawn into the offscreen target, waited for, not read back.
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    renderer.draw(&gpu.device, &gpu.queue, &mut enc, target, &frame)?;
    let idx = gpu.queue.submit([enc.finish()]);
    gpu.device
        .poll(touchfem_gpu::wgpu::PollType::Wait {
            submission_index: Some(idx),
            timeout: None,
        })
        .map_err(|e| Error::Input(format!("waiting for a frame: {e}")))?;
    Ok(None)
}

/// Runs one scene: floor, then haptic loop, with the visual loop drawing throughout; writes
/// frames, GIF, traces, plots and the session under `opts.out`.
pub(crate) fn run_scene(
    world: &World,
    opts: &DemoOptions,
    gpu: Option<&Gpu>,
    renderer: Option<&touchfem_gpu::render::Renderer>,
) -> Result<Vec<ObjectReport>, Error> {
    let secs = opts.seconds;
    let mut devices = scripted_devices(world, secs)?;
    let force_us = step_median(world, 20_000)?;
    let session_path = opts
        .record
        .clone()
        .unwrap_or_else(|| opts.out.join(format!("{}.tfsession", world.name)));
    // The writer thread starts on the visual core (it inherits this thread's placement), away
    // from the haptic loop's.
    opts.placement.enter_visual();
    let (mut recorder, writer) = session::record(&session_path, world)?;
    let (mut publish, mut reader) = sample_channel();
    let status = LiveStatus::default();
    let phase = AtomicU8::new(0);
    let mut visual = Visual::new(world, gpu);
    // The frames show each cut as the cutter's thread makes it.
    visual.follow_cuts(status.cuts.clone());
    let edges_of = |visual: &Visual<'_>| -> Vec<touchfem_gpu::render::Edges> {
        match (gpu, visual.deformers()) {
            (Some(g), Some(ds)) => ds
                .iter()
                .map(|d| touchfem_gpu::render::Edges::new(&g.device, d))
                .collect(),
            _ => Vec::new(),
        }
    };
    let mut edges = edges_of(&visual);
    // Where frames that are not saved are drawn.
    let offscreen = match (gpu, renderer) {
        (Some(g), Some(r)) => {
            let [w, h] = r.size();
            let t = g
                .device
                .create_texture(&touchfem_gpu::wgpu::TextureDescriptor {
                    label: Some("demo frame"),
                    size: touchfem_gpu::wgpu::Extent3d {
                        width: w,
                        height: h,
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: touchfem_gpu::wgpu::TextureDimension::D2,
                    format: r.options().format,
                    usage: touchfem_gpu::wgpu::TextureUsages::RENDER_ATTACHMENT,
                    view_formats: &[],
                });
            Some(t.create_view(&Default::default()))
        }
        _ => None,
    };
    let mut edges_generation = visual.surface_generation();
    let scales = picture_scales(world, 400)?;
    let style = {
        let coloring = if opts.displacement_colors {
            touchfem_gpu::render::Coloring::Displacement {
                full_scale_m: scales.displacement.0,
                step_m: scales.displacement.1,
            }
        } else {
            touchfem_gpu::render::Coloring::Plain
        };
        let legend = match (gpu, renderer) {
            (Some(g), Some(r)) => {
                touchfem_gpu::render::legend_image(&touchfem_gpu::render::LegendSpec {
                    bar_px: touchfem_gpu::render::LegendSpec::bar_for(r.size()[1]),
                    displacement: opts.displacement_colors.then_some(scales.displacement),
                    arrow_m_per_n: Some(scales.arrow_m_per_n),
                    force_n: None,
                })
                .map(|img| {
                    let mut o = touchfem_gpu::render::Overlay::new(&g.device, r.options());
                    o.set_anchor(touchfem_gpu::render::Anchor::TopRight);
                    o.set_image(&g.device, &g.queue, Some(&img));
                    o
                })
            }
            _ => None,
        };
        let size = renderer.map_or(opts.size, |r| r.size());
        FrameStyle {
            camera: scene_camera(world, size, legend.as_ref().and_then(|o| o.image_size())),
            coloring,
            arrow_m_per_n: scales.arrow_m_per_n,
            legend,
        }
    };
    let mut disp_us = Vec::new();
    let mut frames = 0u64;
    let mut gif = Vec::new();
    let mut saved = 0usize;
    let mut next_save = Instant::now();
    let mut next_gif = Instant::now();
    let mut draw_t0 = None;
    let mut draw_t1 = Instant::now();
    let (floor, run, visual_result) = std::thread::scope(|sc| {
        let h = sc.spawn(|| {
            let _done = DoneGuard(&status);
            opts.placement.enter_haptic();
            let realtime = touchfem_core::threads::try_realtime_priority();
            let mut floor = run_floor(world.haptics.rate_hz, secs, &status.stop);
            floor.realtime = realtime;
            phase.store(1, Ordering::Release);
            let mut run = run_haptic(
                world,
                &mut devices,
                Some(secs),
                &mut publish,
                &status,
                Some(&mut recorder),
            );
            run.stats.realtime = realtime;
            drop(recorder);
            (floor, run)
        });
        opts.placement.enter_visual();
        let result = (|| -> Result<(), Error> {
            while !status.done.load(Ordering::Acquire) {
                let sample = *reader.read();
                let us = visual.update(&sample);
                if visual.surface_generation() != edges_generation {
                    // A cut opened the surface: its wireframe too.
                    edges = edges_of(&visual);
                    edges_generation = visual.surface_generation();
                }
                // The image is read back only when a frame or a GIF thumbnail is due.
                let due = {
                    let now = Instant::now();
                    (now >= next_save && saved < 12) || (now >= next_gif && gif.len() < 40)
                };
                let img = match (gpu, renderer) {
                    (Some(g), Some(r)) => {
                        let target = offscreen.as_ref().filter(|_| !due);
                        draw((g, r), &edges, world, &visual, &sample, &style, target)?
                    }
                    _ => None,
                };
                if phase.load(Ordering::Acquire) == 1 {
                    let now = Instant::now();
                    draw_t0.get_or_insert(now);
                    draw_t1 = now;
                    disp_us.push(us);
                    frames += 1;
                    if let Some(img) = img {
                        if now >= next_save && saved < 12 {
                            let path = opts.out.join(format!("{}_{saved:02}.png", world.name));
                            img.save(&path)
                                .map_err(|e| Error::Input(format!("{}: {e}", path.display())))?;
                            saved += 1;
                            next_save = later(now, secs / 12.0);
                        }
                        if now >= next_gif && gif.len() < 40 {
                            gif.push(image::imageops::thumbnail(
                                &img,
                                img.width() / 2,
                                img.height() / 2,
                            ));
                            next_gif = later(now, secs / 40.0);
                        }
                    }
                }
            }
            Ok(())
        })();
        if result.is_err() {
            status.stop.store(true, Ordering::Relaxed);
        }
        opts.placement.leave();
        let joined = join_haptic(h);
        match joined {
            Ok((floor, run)) => Ok((floor, run, result)),
            Err(e) => Err(e),
        }
    })?;
    visual_result?;
    let recorded = writer
        .join()
        .map_err(|_| Error::Input("the session writer panicked".into()))??;
    if !gif.is_empty() {
        trace::write_gif(&opts.out.join(format!("{}.gif", world.name)), &gif, 100)?;
    }
    let sess = session::read(&session_path)?;
    debug_assert_eq!(sess.ticks.len() as u64, recorded);
    let traces = trace::traces(world, &sess)?;
    for (o, tr) in world.objects.iter().zip(&traces) {
        let stem = format!("{}_{}_force", world.name, o.name);
        trace::write_csv(&opts.out.join(format!("{stem}.csv")), tr)?;
        trace::write_plot(
            &opts.out.join(format!("{stem}.png")),
            &format!("{} / {}: force on the finger(s)", world.name, o.name),
            tr,
        )?;
    }
    let span = draw_t0.map_or(0.0, |t0| (draw_t1 - t0).as_secs_f64());
    let draw_hz = if span > 0.0 && frames > 1 {
        (frames - 1) as f64 / span
    } else {
        0.0
    };
    disp_us.sort_by(|a, b| a.total_cmp(b));
    Ok(world
        .objects
        .iter()
        .enumerate()
        .map(|(i, o)| ObjectReport {
            scene: world.name.clone(),
            name: o.name.clone(),
            nodes: o.body.mesh.nodes.len(),
            rows: o.body.compliance.rows().len(),
            cols: o.body.compliance.cols().len(),
            precompute_s: o.body.compliance.stats.seconds,
            residual: o.body.compliance.stats.residual,
            force_us_median: force_us,
            displacement_us_median: percentile(&disp_us, 0.5),
            displacement_backend: visual.backend(),
            draw_hz,
            frames,
            max_contacts: run.max_contacts[i],
            haptic: run.stats.clone(),
            floor: floor.clone(),
            cuts: o.cuttable.as_ref().map(|_| run.cuts),
        })
        .collect())
}

/// The session path for scene `name` when several scenes share one `--record FILE`:
/// `FILE` with `.name` before its extension.
pub(crate) fn record_path_for(base: &Path, name: &str, several: bool) -> PathBuf {
    if !several {
        return base.to_path_buf();
    }
    let stem = base
        .file_stem()
        .map_or("session".into(), |s| s.to_string_lossy().into_owned());
    let ext = base
        .extension()
        .map_or("tfsession".into(), |s| s.to_string_lossy().into_owned());
    base.with_file_name(format!("{stem}.{name}.{ext}"))
}

/// The worst haptic numbers over runs; missed deadlines, ticks and seconds are totals.
pub fn worst(stats: &[HapticStats]) -> HapticStats {
    let mut w = stats.first().cloned().unwrap_or_default();
    for s in stats {
        w.haptic_rate_hz = w.haptic_rate_hz.min(s.haptic_rate_hz);
        w.period_error_us_p999 = w.period_error_us_p999.max(s.period_error_us_p999);
        w.step_us_median = w.step_us_median.max(s.step_us_median);
        w.max_force_n = w.max_force_n.max(s.max_force_n);
    }
    w.seconds = stats.iter().map(|s| s.seconds).sum();
    w.ticks = stats.iter().map(|s| s.ticks).sum();
    w.missed_deadlines = stats.iter().map(|s| s.missed_deadlines).sum();
    w.contact_budget_exhausted = stats.iter().map(|s| s.contact_budget_exhausted).sum();
    w
}

/// `now` plus `secs` seconds; an hour on when that is not a time (huge, NaN).
fn later(now: std::time::Instant, secs: f64) -> std::time::Instant {
    std::time::Duration::try_from_secs_f64(secs)
        .ok()
        .and_then(|d| now.checked_add(d))
        .unwrap_or(now + std::time::Duration::from_secs(3600))
}
