//! `touchfem view`: loads the scene, starts the haptic side and runs the window.

use glam::DVec3;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::WindowOptions;
use crate::compliance::Selection;
use crate::devices::pointer::{PointerDevice, PointerShared};
use crate::devices::HapticDevice;
use crate::force::ForceModel;
use crate::haptics::Finger;
use crate::runtime::{sample_channel, FingerView, LiveStatus, SampleWriter, WorldSample};
use crate::scene::{load_mesh, DeviceSpec, FingerSpec, HapticSettings, Object, Scene, World};
use crate::Error;

/// Runs `touchfem view SCENE|MESH`: the window on the main thread (the visual core), the
/// haptic loop on its own thread (the haptic core), lavapipe inline on its queue thread
/// (`LP_NUM_THREADS=0` unless set). Prints the window's summary.
pub fn view_command(args: &crate::cli::ViewArgs) -> Result<(), Error> {
    if std::env::var_os("LP_NUM_THREADS").is_none() {
        std::env::set_var("LP_NUM_THREADS", "0");
    }
    if args.record.is_some() {
        eprintln!("warning: touchfem view --record is not implemented yet; nothing is recorded");
    }
    // interim: replaced by runtime::spawn_haptic on main — from here ...
    let world = interim_world(&args.scene)?;
    let pointer = Arc::new(PointerShared::default());
    let (writer, reader) = sample_channel();
    let status = LiveStatus::default();
    let placement = crate::threads::VisualPlacement::split();
    let opts = WindowOptions {
        size: args.size,
        title: format!("touchfem view: {}", world.name),
    };
    let (result, haptic_panicked) = std::thread::scope(|s| {
        let haptic = s.spawn(|| {
            placement.enter_haptic();
            interim_haptic_loop(&world, PointerDevice(pointer.clone()), writer, &status);
        });
        placement.enter_visual();
        let r = super::run(&world, reader, &status, Some(pointer.clone()), &opts);
        status.stop.store(true, Ordering::SeqCst);
        let joined = haptic.join();
        placement.leave();
        (r, joined.is_err())
    });
    // ... to here.
    let summary = result?;
    if haptic_panicked {
        return Err(Error::Input("the haptic thread panicked".into()));
    }
    println!(
        "touchfem view: {} frames in {:.1} s, median frame {:.2} ms, haptic {:.0} Hz, max |F| {:.3} N",
        summary.frames,
        summary.seconds,
        summary.frame_ms_median,
        status.rate_hz(),
        summary.max_force_n
    );
    Ok(())
}

// interim: replaced by runtime::spawn_haptic on main (scene files, several fingers).
fn interim_world(spec: &str) -> Result<World, Error> {
    let (mesh, unit) = load_mesh(spec, &Default::default())?;
    let name = std::path::Path::new(spec)
        .file_stem()
        .map_or_else(|| spec.to_string(), |s| s.to_string_lossy().into_owned());
    let scene = Scene::new(mesh, &Selection::default())?;
    Ok(World {
        name: name.clone(),
        unit,
        objects: vec![Object {
            name,
            scene,
            offset: DVec3::ZERO,
        }],
        fingers: vec![FingerSpec {
            device: DeviceSpec::Pointer,
            model: ForceModel::Paper,
        }],
        haptics: HapticSettings::default(),
        source: String::new(),
        hash: 0,
    })
}

/// Sets [`LiveStatus::done`] (and `panicked` on a panic) when the haptic loop ends.
struct DoneGuard<'a>(&'a LiveStatus);

impl Drop for DoneGuard<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.panicked.store(true, Ordering::SeqCst);
        }
        self.0.done.store(true, Ordering::SeqCst);
    }
}

/// A finger for a device reading `x` (object frame) that follows a lifted one: free at `x` if
/// `x` is outside, else about to enter through the surface point nearest `x`.
fn entering(scene: &Scene, x: DVec3) -> Finger {
    let (tri, q) = scene.surface.closest_global(x);
    let n = scene.surface.normals[tri as usize];
    if (x - q).dot(n) < 0.0 {
        let (lo, hi) = scene.mesh.bounds();
        Finger::new(q + n * (1e-3 * (hi - lo).length()))
    } else {
        Finger::new(x)
    }
}

// interim: replaced by runtime::spawn_haptic on main.
/// One pointer finger on object 0 at the scene's haptic rate (sleep, then spin to each
/// deadline) until [`LiveStatus::stop`]: reads the pointer, steps the finger, sends the force,
/// publishes a [`WorldSample`] and the live counters.
fn interim_haptic_loop(
    world: &World,
    mut device: PointerDevice,
    mut writer: SampleWriter,
    status: &LiveStatus,
) {
    let _done = DoneGuard(status);
    let obj = &world.objects[0];
    let scene = &obj.scene;
    let model = world.fingers[0].model;
    let rate = world.haptics.rate_hz.clamp(1.0, 100_000.0);
    let max_force = world.haptics.max_force_n;
    let mut finger = Finger::new(DVec3::NAN);
    let mut valid = false;
    let start = Instant::now();
    let mut tick: u64 = 0;
    while !status.stop.load(Ordering::Relaxed) {
        let deadline = start + Duration::from_secs_f64(tick as f64 / rate);
        let now = Instant::now();
        if deadline > now + Duration::from_micros(300) {
            std::thread::sleep(deadline - now - Duration::from_micros(200));
        }
        while Instant::now() < deadline {
            std::hint::spin_loop();
        }
        if Instant::now() > deadline + Duration::from_secs_f64(1.0 / rate) {
            status.missed.fetch_add(1, Ordering::Relaxed);
        }
        let t = start.elapsed().as_secs_f64();
        let x_scene = device.position(t);
        let x = x_scene - obj.offset;
        if x.is_finite() != valid {
            valid = x.is_finite();
            finger = if valid {
                entering(scene, x)
            } else {
                Finger::new(DVec3::NAN)
            };
        }
        let f = finger.step(&scene.surface, &scene.compliance, x, model, max_force);
        device.set_force(f);
        let mut sample = WorldSample {
            tick: tick + 1,
            n_objects: 1,
            n_fingers: 1,
            ..Default::default()
        };
        sample.bcs[0] = finger.bc;
        sample.fingers[0] = FingerView {
            position: x_scene,
            proxy: finger.contact.map(|c| c.proxy + obj.offset),
            object: finger.contact.map(|_| 0),
            force: f,
        };
        writer.write(sample);
        tick += 1;
        status.ticks.store(tick, Ordering::Relaxed);
        status
            .elapsed_ns
            .store(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
    }
}
