//! `touchfem view`: loads the scene, starts the haptic loop and runs the window.

use std::path::Path;
use std::sync::atomic::Ordering;

use super::blade::PointerRoute;
use super::WindowOptions;
use crate::error::Error;
use touchfem_core::devices::pointer::PointerDevice;
use touchfem_core::devices::{HapticDevice, KeyframePath};
use touchfem_core::runtime::{
    join_haptic, run_haptic, sample_channel, session, DoneGuard, LiveStatus,
};
use touchfem_core::scene::file::{cache_dir, Hold};
use touchfem_core::scene::{DeviceSpec, SceneSource, World};

/// The devices of a scene's fingers in `view`: the first `pointer` finger is the window's
/// pointer, the pointer's blade twin ([`touchfem_core::scene::pointer::blade_twin`]) is the pointer in blade
/// mode, scripted fingers follow their paths; other devices are refused.
pub fn view_devices(
    world: &World,
    route: &PointerRoute,
) -> Result<Vec<Box<dyn HapticDevice>>, Error> {
    let twin = route.twin();
    let mut out: Vec<Box<dyn HapticDevice>> = Vec::new();
    let mut pointers = 0;
    for (i, f) in world.fingers.iter().enumerate() {
        match &f.device {
            DeviceSpec::Pointer if twin.is_some_and(|(_, t)| t.finger == i) => {
                let (shared, _) = twin.expect("checked");
                out.push(Box::new(PointerDevice(shared.clone())));
            }
            DeviceSpec::Pointer if pointers == 0 => {
                pointers += 1;
                out.push(Box::new(PointerDevice(route.finger().clone())));
            }
            DeviceSpec::Script(keys) => out.push(Box::new(
                KeyframePath::new(keys.clone())
                    .ok_or_else(|| Error::Body(format!("finger {}: bad path", i + 1)))?,
            )),
            other => {
                return Err(Error::Body(format!(
                    "scene '{}': finger {} uses device {other:?}, which `view` cannot drive (one pointer finger, its blade twin, and scripted ones)",
                    world.name,
                    i + 1
                )))
            }
        }
    }
    Ok(out)
}

/// Loads `spec` for `view`, keeping on the host only the near blocks of `L` (`Hold::Live`).
/// The window's pointer is always a finger: a scene without a `pointer` finger (one of
/// scripted fingers only, such as `palpate`) gets one more, `[[finger]] device = "pointer"`
/// appended to its text, so that a recorded session replays it; when the scene already has
/// [`touchfem_core::limits::MAX_FINGERS`] fingers it is shown as it is. Compliances are cached in `cache` (`None`: no
/// cache).
pub fn load_with_pointer(spec: &str, cache: Option<&Path>) -> Result<World, Error> {
    load_with_pointer_as(spec, cache, None)
}

/// [`load_with_pointer`], the added pointer finger a sphere of radius `sphere` (the scene's
/// unit; millimetres for a bundled mesh) when given: `view --sphere R`. A scene that already
/// has a pointer keeps its own tool.
///
/// A scene with a cuttable object whose pointer is not a blade also gets the pointer's blade
/// twin (`B` in the window; [`super::blade`]): one more finger, `[[finger]] device = "pointer"`
/// with `tool = { blade = DEPTH }` ([`touchfem_core::scene::pointer::pointer_fingers`]),
/// appended to the text when there is room for it (at most [`touchfem_core::limits::MAX_FINGERS`] fingers).
pub fn load_with_pointer_as(
    spec: &str,
    cache: Option<&Path>,
    sphere: Option<f64>,
) -> Result<World, Error> {
    let scene = SceneSource::find(spec)?;
    let mesh = scene.is_none();
    let mut src = scene.unwrap_or_else(|| SceneSource::for_mesh(spec, "pointer"));
    let world = World::from_source_holding(&src, cache, Hold::Live)?;
    if let Some(r) = sphere {
        // The one check of `poke`, `info` and a scene's `tool`, against this scene's objects.
        let radius_m = r * world.unit.to_metres();
        let extents: Vec<f64> = world
            .objects
            .iter()
            .map(|o| crate::args::extent_m(&o.body.mesh))
            .collect();
        let tool = touchfem_core::contact::Tool::Sphere { radius_m };
        crate::args::check_tool("--sphere", r, tool, &extents)?;
        if mesh {
            // A mesh's one finger is the pointer: it becomes the sphere.
            src.text.push_str(&format!("tool = {{ sphere = {r:?} }}\n"));
            return Ok(World::from_source_holding(&src, cache, Hold::Live)?);
        }
    }
    let extra = touchfem_core::scene::pointer::pointer_fingers(&world, sphere);
    if extra.is_empty() {
        return Ok(world);
    }
    // The compliance does not depend on the fingers: the second load reads the cache the first
    // wrote (or, with the cache off, computes it again). A text that cannot take one more
    // `[[finger]]` table (an inline `finger = [...]` array) is shown as it is.
    src.text.push_str(&extra);
    Ok(World::from_source_holding(&src, cache, Hold::Live).unwrap_or(world))
}

/// Runs `touchfem view SCENE|MESH`: the window on the main thread (the visual core), the
/// haptic loop ([`run_haptic`], the same as the demo's) on its own thread (the haptic core),
/// lavapipe inline on its queue thread (`LP_NUM_THREADS=0` unless set). A mesh is shown as a
/// one-object scene touched by the pointer. `--record FILE` records the session. Prints the
/// window's summary.
pub(crate) fn view_command(args: &crate::args::ViewArgs) -> Result<(), Error> {
    super::check_env()?;
    if std::env::var_os("LP_NUM_THREADS").is_none() {
        std::env::set_var("LP_NUM_THREADS", "0");
    }
    let world = load_with_pointer_as(&args.scene, cache_dir().as_deref(), args.sphere)?;
    let route = PointerRoute::new(&world);
    let mut devs = view_devices(&world, &route)?;
    let has_pointer = world
        .fingers
        .iter()
        .any(|f| matches!(f.device, DeviceSpec::Pointer));
    let placement = touchfem_core::threads::VisualPlacement::split();
    // The recorder's writer thread starts on the visual core, away from the haptic loop's.
    placement.enter_visual();
    let mut recording = match &args.record {
        Some(path) => Some(session::record(path, &world)?),
        None => None,
    };
    let (mut writer, reader) = sample_channel();
    let status = LiveStatus::default();
    let opts = WindowOptions {
        size: args.size,
        title: format!("touchfem view: {}", world.name),
        colors: args.color == crate::args::ColorArg::Displacement,
    };
    let (result, haptic) = std::thread::scope(|s| {
        let haptic = s.spawn(|| {
            let _done = DoneGuard(&status);
            placement.enter_haptic();
            // After the window's upload of `L` (or its failure, which sets `stop`).
            status.wait_visual_ready();
            let realtime = touchfem_core::threads::try_realtime_priority();
            let rec = recording.as_mut().map(|r| &mut r.0);
            let mut run = run_haptic(&world, &mut devs, None, &mut writer, &status, rec);
            run.stats.realtime = realtime;
            run
        });
        placement.enter_visual();
        let r = super::run(&world, reader, &status, has_pointer.then_some(route), &opts);
        status.stop.store(true, Ordering::SeqCst);
        let joined = join_haptic(haptic);
        placement.leave();
        (r, joined)
    });
    let run = haptic?;
    let summary = result?;
    if let Some((rec, writer)) = recording {
        drop(rec);
        let ticks = writer
            .join()
            .map_err(|_| Error::Input("the session writer panicked".into()))??;
        eprintln!(
            "recorded {ticks} ticks to {}",
            args.record.as_ref().expect("recording").display()
        );
    }
    let cuts = if run.cuts.bodies > 0 {
        match run.cuts.nodes_split {
            0 => format!(", cut {} tets", run.cuts.tets_removed),
            n => format!(", cut {} tets, {n} copies", run.cuts.tets_removed),
        }
    } else {
        String::new()
    };
    println!(
        "touchfem view: {} frames in {:.1} s, median frame {:.2} ms, haptic {:.0} Hz ({} missed), max |F| {:.3} N{cuts}",
        summary.frames,
        summary.seconds,
        summary.frame_ms_median,
        run.stats.haptic_rate_hz,
        run.stats.missed_deadlines,
        summary.max_force_n
    );
    Ok(())
}

/// `touchfem serve … --view`: the UDP fingers' haptic loop ([`touchfem_core::runtime::serve`]) with
/// the window as its visual loop (on this thread; it closes when the loop ends, and closing it
/// ends the loop).
pub(crate) fn serve_view(
    world: &World,
    opts: &touchfem_core::runtime::serve::ServeOptions,
    stop: &std::sync::atomic::AtomicBool,
    size: [u32; 2],
    bound: impl FnOnce(std::net::SocketAddr),
) -> Result<touchfem_core::runtime::serve::ServeReport, Error> {
    super::check_env()?;
    if std::env::var_os("LP_NUM_THREADS").is_none() {
        std::env::set_var("LP_NUM_THREADS", "0");
    }
    let wopts = WindowOptions {
        size,
        title: format!("touchfem serve: {}", world.name),
        colors: true,
    };
    touchfem_core::runtime::serve::serve_with(world, opts, stop, bound, |reader, status| {
        super::run(world, reader, status, None, &wopts)?;
        Ok(())
    })
}
