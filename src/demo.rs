//! `touchfem demo`: the bundled scenes run headless with both loops, as in the paper's
//! prototype — the haptic loop on its own thread at 1 kHz, the visual loop asynchronously —
//! and the paper's Table 2 measured on this machine.

use glam::DVec3;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::compliance::Selection;
use crate::contact::Surface;
use crate::force::ForceModel;
use crate::haptics::{
    bc_channel, percentile, run_loop, Finger, HapticConfig, HapticStats, ScriptedDevice,
};
use crate::scene::{load_mesh, LoadOptions, Scene};
use crate::Error;

/// One object's row of the paper's Table 2.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ObjectReport {
    /// Bundled mesh name.
    pub name: String,
    /// All nodes.
    pub nodes: usize,
    /// Displayed rows × touchable columns of L.
    pub rows: usize,
    /// Touchable columns.
    pub cols: usize,
    /// Precompute time, s.
    pub precompute_s: f64,
    /// max |K·L − I|.
    pub residual: f64,
    /// Median haptic force step (god-object + paper force), µs.
    pub force_us_median: f64,
    /// Median visual displacement update u = L·F, µs (the backend in `displacement_backend`).
    pub displacement_us_median: f64,
    /// Where the displacement ran.
    pub displacement_backend: String,
    /// Visual loop rate while the haptic loop ran, frames per second.
    pub draw_hz: f64,
    /// Frames drawn.
    pub frames: u64,
    /// The haptic loop's timing for this object.
    pub haptic: HapticStats,
}

/// The demo report (`--report FILE.json`).
#[derive(Clone, Debug, serde::Serialize)]
pub struct DemoReport {
    /// One entry per object.
    pub objects: Vec<ObjectReport>,
    /// The haptic loop's timing over all objects (the worst object's numbers).
    pub haptic: HapticStats,
    /// Machine description.
    pub machine: String,
}

/// What the visual loop does each frame, given the latest boundary condition; returns the time
/// spent in the displacement update (µs).
pub type FrameFn<'a> =
    dyn FnMut(&Scene, &crate::haptics::HapticSample, u64) -> Result<f64, Error> + 'a;

/// Options of the demo.
#[derive(Clone, Debug)]
pub struct DemoOptions {
    /// Seconds of haptic + visual loop per object.
    pub seconds: f64,
    /// Where frames go.
    pub out: PathBuf,
    /// Which cores the visual and haptic loops run on.
    pub placement: crate::threads::VisualPlacement,
}

/// The scripted finger: comes down on the object's top at the centre of its bounds, presses
/// up to 5 mm into the surface under it (Fig. 1b), slides in a circle of `radius`, and lifts
/// off. The depth is measured from the rest surface straight below the finger (a ray cast on
/// the surface grid, allocation-free), so the finger follows a curved top. Metres, at time `t`
/// of a run lasting `secs`.
pub fn finger_path(
    surface: &Surface,
    lo: DVec3,
    hi: DVec3,
    radius: f64,
    t: f64,
    secs: f64,
) -> DVec3 {
    let c = (lo + hi) * 0.5;
    let s = (t / secs).clamp(0.0, 1.0);
    let press = 5e-3 * (std::f64::consts::PI * s).sin().powf(0.5) - 1e-3;
    let a = 2.0 * std::f64::consts::PI * s;
    let r = radius * (std::f64::consts::PI * s).sin();
    let (x, y) = (c.x + r * a.cos(), c.y + r * a.sin());
    let above = DVec3::new(x, y, hi.z + 0.01);
    let below = DVec3::new(x, y, lo.z - 0.01);
    let top = surface
        .first_entry(above, below)
        .map(|(_, p)| p.z)
        .unwrap_or(hi.z + 0.01);
    DVec3::new(x, y, top - press)
}

/// The demo's circle radius for an object: a fifth of its smaller horizontal extent.
fn path_radius(lo: DVec3, hi: DVec3) -> f64 {
    0.2 * (hi.x - lo.x).min(hi.y - lo.y)
}

/// Median force step (µs) over a scripted press-and-slide, measured outside the loop.
pub fn force_step_median(scene: &Scene, samples: usize) -> f64 {
    let (lo, hi) = scene.mesh.bounds();
    let rad = path_radius(lo, hi);
    let mut f = Finger::new(finger_path(&scene.surface, lo, hi, rad, 0.0, 1.0));
    let mut times = Vec::with_capacity(samples);
    for i in 0..samples {
        let t = 0.05 + 0.9 * i as f64 / samples as f64;
        let x = finger_path(&scene.surface, lo, hi, rad, t, 1.0);
        let t = Instant::now();
        std::hint::black_box(f.step(&scene.surface, &scene.compliance, x, ForceModel::Paper, 8.5));
        times.push(t.elapsed().as_secs_f64() * 1e6);
    }
    times.sort_by(|a, b| a.total_cmp(b));
    percentile(&times, 0.5)
}

/// Runs one object: the haptic loop on a thread at 1 kHz, the visual loop on this thread calling
/// `frame` with the latest boundary condition as fast as it can.
pub fn run_object(
    name: &str,
    opts: &DemoOptions,
    frame: &mut FrameFn<'_>,
    backend: &str,
) -> Result<(ObjectReport, Scene), Error> {
    let (mesh, _unit) = load_mesh(name, &LoadOptions::default())?;
    let scene = Scene::new(mesh, &Selection::default())?;
    let force_us = force_step_median(&scene, 20_000);
    let (lo, hi) = scene.mesh.bounds();
    let radius = path_radius(lo, hi);
    let secs = opts.seconds;
    let (mut writer, mut reader) = bc_channel();
    let done = AtomicBool::new(false);
    let mut disp_us = Vec::new();
    let mut frames = 0u64;
    let (haptic, draw_hz) = std::thread::scope(|sc| -> Result<(HapticStats, f64), Error> {
        let scene_ref = &scene;
        let done_ref = &done;
        let h = sc.spawn(move || {
            let surf = &scene_ref.surface;
            let mut dev = ScriptedDevice::new(move |t| finger_path(surf, lo, hi, radius, t, secs));
            opts.placement.enter_haptic();
            let realtime = crate::haptics::try_realtime_priority();
            let mut stats = run_loop(
                &scene_ref.surface,
                &scene_ref.compliance,
                &mut dev,
                &HapticConfig::default(),
                secs,
                &mut writer,
            );
            done_ref.store(true, Ordering::Release);
            stats.realtime = realtime;
            stats
        });
        // The visual loop shares a core with the GPU driver's threads (see `threads`).
        opts.placement.enter_visual();
        let t0 = Instant::now();
        let mut result = Ok(());
        while !done.load(Ordering::Acquire) {
            let sample = *reader.read();
            match frame(&scene, &sample, frames) {
                Ok(us) => disp_us.push(us),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
            frames += 1;
        }
        let elapsed = t0.elapsed().as_secs_f64();
        opts.placement.leave();
        let stats = h
            .join()
            .map_err(|_| Error::Input("the haptic thread panicked".into()))?;
        result?;
        Ok((stats, frames as f64 / elapsed.max(1e-9)))
    })?;
    disp_us.sort_by(|a, b| a.total_cmp(b));
    let report = ObjectReport {
        name: name.to_string(),
        nodes: scene.mesh.nodes.len(),
        rows: scene.compliance.rows().len(),
        cols: scene.compliance.cols().len(),
        precompute_s: scene.compliance.stats.seconds,
        residual: scene.compliance.stats.residual,
        force_us_median: force_us,
        displacement_us_median: percentile(&disp_us, 0.5),
        displacement_backend: backend.to_string(),
        draw_hz,
        frames,
        haptic,
    };
    Ok((report, scene))
}

/// A short description of this machine for reports.
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    format!("{cpu}, {cores} cores")
}

/// The worst haptic numbers over objects.
pub fn worst(stats: &[HapticStats]) -> HapticStats {
    let mut w = stats.first().cloned().unwrap_or_default();
    for s in stats {
        w.haptic_rate_hz = w.haptic_rate_hz.min(s.haptic_rate_hz);
        w.period_error_us_p999 = w.period_error_us_p999.max(s.period_error_us_p999);
        w.missed_deadlines = w.missed_deadlines.max(s.missed_deadlines);
        w.step_us_median = w.step_us_median.max(s.step_us_median);
        w.max_force_n = w.max_force_n.max(s.max_force_n);
    }
    w.seconds = stats.iter().map(|s| s.seconds).sum();
    w.ticks = stats.iter().map(|s| s.ticks).sum();
    w
}
