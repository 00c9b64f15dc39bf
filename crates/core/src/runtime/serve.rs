//! `touchfem serve`: the haptic loop for fingers driven over UDP ([`crate::devices::udp`]) or
//! by a device thread of the program's ([`crate::devices::external`], the Haply Inverse3's
//! client in `touchfem-app`), with the visual path's displacement update running headless
//! beside it. [`serve_devices_with`] runs any [`FingerDevices`]; [`serve`] and [`serve_with`]
//! run the UDP bridge through it.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use super::HapticRun;
use super::{
    join_haptic, run_haptic, sample_channel, session, DoneGuard, LiveStatus, SampleReader,
};
use crate::devices::limits::DeviceLimits;
use crate::devices::udp::{BridgeConfig, Clock, Key, UdpBridge, UdpCounters};
use crate::devices::FingerDevices;
use crate::runtime::pacer::HapticStats;
use crate::scene::DeviceSpec;
use crate::scene::World;
use crate::Error;

/// Options of `serve`.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// Where to listen.
    pub addr: SocketAddr,
    /// Allow a non-loopback address (needs `key` too).
    pub allow_remote: bool,
    /// The shared secret every packet is signed with, both ways (`--key FILE`).
    pub key: Option<Key>,
    /// Seconds to run (`None`: until `stop`).
    pub seconds: Option<f64>,
    /// Record the session here.
    pub record: Option<PathBuf>,
    /// The watchdog.
    pub watchdog: Duration,
    /// What paces the loop.
    pub clock: Clock,
    /// Core placement.
    pub placement: crate::threads::VisualPlacement,
    /// Seconds of the bare-loop floor ([`crate::runtime::pacer::run_floor`]) to measure on
    /// the haptic core before serving, so the loop's timing can be judged against this
    /// machine's in the same run.
    pub floor_seconds: Option<f64>,
}

/// What every `serve` report says of the haptic loop, whatever its devices (flattened into the
/// report: its keys stand beside the devices' own).
#[derive(Clone, Debug, serde::Serialize)]
pub struct LoopReport {
    /// Haptic ticks run.
    pub ticks: u64,
    /// Missed haptic deadlines.
    pub missed_deadlines: u64,
    /// p99.9 of the period error, µs.
    pub period_error_us_p999: f64,
    /// Largest force sent, N.
    pub max_force_n: f64,
    /// Each finger's device limits (`null`: the paper's force, saturated).
    pub limits: Vec<Option<DeviceLimits>>,
    /// The haptic loop's timing.
    pub haptic: HapticStats,
    /// The bare-loop floor measured before serving (`--floor-seconds`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub floor: Option<HapticStats>,
    /// With `--record`: ticks whose record was not kept — the ring to the writer overflowed,
    /// or, when the recording failed, every tick (the file is then left as it was).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub records_dropped: Option<u64>,
    /// With `--record`, why the recording failed (the report is still written; the command
    /// then exits with this error).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recording_error: Option<String>,
}

impl LoopReport {
    /// The report of a loop that served `world`.
    pub fn of(world: &World, served: Served) -> LoopReport {
        let stats = served.run.stats;
        LoopReport {
            ticks: stats.ticks,
            missed_deadlines: stats.missed_deadlines,
            period_error_us_p999: stats.period_error_us_p999,
            max_force_n: stats.max_force_n,
            limits: world.fingers.iter().map(|f| f.limits.clone()).collect(),
            haptic: stats,
            floor: served.floor,
            records_dropped: served.records_dropped,
            recording_error: served.recording_error,
        }
    }
}

/// The report of `serve` (keys in CONTRACTS.md).
#[derive(Clone, Debug, serde::Serialize)]
pub struct ServeReport {
    /// The address served.
    pub address: String,
    /// Datagrams read.
    pub packets_received: u64,
    /// Datagrams dropped (malformed, rejected, old, duplicate, foreign).
    pub packets_dropped: u64,
    /// Of those, packets whose tag did not verify under `--key`.
    pub packets_rejected: u64,
    /// Times the watchdog expired with a client being served.
    pub stale_periods: u64,
    /// What paced the loop: "host" or "device".
    pub clock: String,
    /// Every counter of the bridge.
    pub udp: UdpCounters,
    /// The loop: ticks, deadlines, forces, limits, timing, recording.
    #[serde(flatten)]
    pub run: LoopReport,
}

/// The world `serve` runs: a scene whose fingers are all UDP fingers, or a bare mesh (then as
/// many UDP fingers as a packet may carry). `limits` go to every finger whose scene gives none.
pub fn udp_world(spec: &str, limits: Option<&DeviceLimits>) -> Result<World, Error> {
    use crate::scene::SceneSource;
    let mut world = match SceneSource::find(spec)? {
        // A scene with one finger holds only its near blocks of a large L (`Hold::Live`).
        Some(_) => World::load_live(spec, "udp")?,
        None => {
            // A bare mesh: its one-finger scene text with as many UDP fingers as a packet may
            // carry, so that a recorded session's scene has them all and replays.
            let mut src = SceneSource::for_mesh(spec, "udp");
            for _ in 1..crate::limits::MAX_FINGERS {
                src.text.push_str("\n[[finger]]\ndevice = \"udp\"\n");
            }
            World::from_source_with(&src, crate::scene::file::cache_dir().as_deref())?
        }
    };
    if world.fingers.iter().any(|f| f.device != DeviceSpec::Udp) {
        return Err(Error::Body(format!(
            "scene '{}': `serve` drives udp fingers only",
            world.name
        )));
    }
    if let Some(l) = limits {
        for f in &mut world.fingers {
            f.limits.get_or_insert_with(|| l.clone());
        }
    }
    Ok(world)
}

/// Binds the bridge, then runs the haptic loop on the haptic core and the headless visual
/// update on this thread until `seconds` or `stop`. `bound` is called with the bound address
/// before the loop starts.
pub fn serve(
    world: &World,
    opts: &ServeOptions,
    stop: &AtomicBool,
    bound: impl FnOnce(SocketAddr),
) -> Result<ServeReport, Error> {
    serve_with(world, opts, stop, bound, |reader, status| {
        headless(world, reader, status);
        Ok(())
    })
}

/// The headless visual loop: the displacement update `u = L·F` on the CPU (f64) at up to
/// 100 Hz until the haptic loop ends. (The GPU's is `touchfem-gpu`'s `Visual`.)
pub fn headless(world: &World, mut reader: SampleReader, status: &LiveStatus) {
    let mut u: Vec<Vec<glam::DVec3>> = world
        .objects
        .iter()
        .map(|o| vec![glam::DVec3::ZERO; o.body.compliance.rows().len()])
        .collect();
    while !status.done.load(Ordering::Acquire) {
        let sample = reader.read();
        for (o, (obj, u)) in world.objects.iter().zip(&mut u).enumerate() {
            obj.body.compliance.displace(sample.bc(o).entries(), u);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// [`serve`] with the visual loop given: `visual(reader, status)` runs on the calling thread
/// (the visual core) beside the haptic loop — headless ([`headless`]) or a window — and should
/// return once `status.done` is set; when it returns first, the haptic loop is stopped.
/// Setting `stop` stops the haptic loop.
pub fn serve_with<E: From<Error>>(
    world: &World,
    opts: &ServeOptions,
    stop: &AtomicBool,
    bound: impl FnOnce(SocketAddr),
    visual: impl FnOnce(SampleReader, &LiveStatus) -> Result<(), E>,
) -> Result<ServeReport, E> {
    let cfg = BridgeConfig {
        allow_remote: opts.allow_remote,
        watchdog: opts.watchdog,
        clock: opts.clock,
        key: opts.key.clone(),
    };
    let mut addr = opts.addr;
    let open = || -> Result<UdpBridge, E> {
        let bridge = UdpBridge::bind(opts.addr, &cfg).map_err(Error::from)?;
        addr = bridge
            .local_addr()
            .map_err(|e| Error::Input(format!("UDP socket: {e}")))?;
        bound(addr);
        Ok(bridge)
    };
    let (served, bridge) = serve_devices_with(world, &opts.loop_options(), stop, open, visual)?;
    let counters = bridge.counters();
    drop(bridge);
    Ok(ServeReport {
        address: addr.to_string(),
        packets_received: counters.packets_received,
        packets_dropped: counters.packets_dropped,
        packets_rejected: counters.packets_rejected,
        stale_periods: counters.stale_periods,
        clock: match opts.clock {
            Clock::Host => "host".into(),
            Clock::Device => "device".into(),
        },
        udp: counters,
        run: LoopReport::of(world, served),
    })
}

/// What serving does besides its devices: how long, recording, core placement, the floor.
#[derive(Clone, Debug, Default)]
pub struct LoopOptions {
    /// Seconds to run (`None`: until `stop`).
    pub seconds: Option<f64>,
    /// Record the session here.
    pub record: Option<PathBuf>,
    /// Core placement.
    pub placement: crate::threads::VisualPlacement,
    /// Seconds of the bare-loop floor to measure before serving (see
    /// [`ServeOptions::floor_seconds`]).
    pub floor_seconds: Option<f64>,
}

impl ServeOptions {
    /// The options that are not the bridge's.
    pub fn loop_options(&self) -> LoopOptions {
        LoopOptions {
            seconds: self.seconds,
            record: self.record.clone(),
            placement: self.placement.clone(),
            floor_seconds: self.floor_seconds,
        }
    }
}

/// What a served run gave, whatever its devices.
#[derive(Clone, Debug)]
pub struct Served {
    /// The haptic loop's run (timing, largest force, contacts).
    pub run: HapticRun,
    /// The bare-loop floor measured before serving.
    pub floor: Option<HapticStats>,
    /// With `--record`: ticks whose record was not kept (see [`LoopReport::records_dropped`]).
    pub records_dropped: Option<u64>,
    /// With `--record`: why the recording failed.
    pub recording_error: Option<String>,
}

/// Serves `world` with any devices: measures the floor if asked, opens the devices
/// (`open`, after the floor), then runs the haptic loop on the haptic core and `visual` on
/// this thread until `opts.seconds`, `stop`, or `visual` returning. The loop releases the
/// devices when it ends, however it ends ([`FingerDevices::release`]); the devices are handed
/// back for their counters.
pub fn serve_devices_with<D: FingerDevices, E: From<Error>>(
    world: &World,
    opts: &LoopOptions,
    stop: &AtomicBool,
    open: impl FnOnce() -> Result<D, E>,
    visual: impl FnOnce(SampleReader, &LiveStatus) -> Result<(), E>,
) -> Result<(Served, D), E> {
    let floor = match opts.floor_seconds {
        Some(secs) => Some(
            std::thread::scope(|sc| {
                sc.spawn(|| {
                    opts.placement.enter_haptic();
                    let realtime = crate::threads::try_realtime_priority();
                    let mut f = super::pacer::run_floor(world.haptics.rate_hz, secs, stop);
                    f.realtime = realtime;
                    opts.placement.leave();
                    f
                })
                .join()
                .map_err(|_| Error::HapticThread("the floor loop panicked".into()))
            })
            .map_err(E::from)?,
        ),
        None => None,
    };
    let mut devices = open()?;
    opts.placement.enter_visual();
    let mut recording = match &opts.record {
        Some(p) => Some(session::record(p, world).map_err(E::from)?),
        None => None,
    };
    let (mut writer, reader) = sample_channel();
    let status = LiveStatus::default();
    let (run, shown) = std::thread::scope(|sc| {
        let h = sc.spawn(|| {
            let _g = DoneGuard(&status);
            opts.placement.enter_haptic();
            let realtime = crate::threads::try_realtime_priority();
            let rec = recording.as_mut().map(|r| &mut r.0);
            let mut run = run_haptic(world, &mut devices, opts.seconds, &mut writer, &status, rec);
            run.stats.realtime = realtime;
            run
        });
        // `stop` (Ctrl-C) reaches the haptic loop whatever the visual loop does.
        sc.spawn(|| {
            while !status.done.load(Ordering::Acquire) {
                if stop.load(Ordering::Relaxed) {
                    status.stop.store(true, Ordering::Relaxed);
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        });
        let shown = visual(reader, &status);
        status.stop.store(true, Ordering::Relaxed);
        opts.placement.leave();
        join_haptic(h).map(|run| (run, shown))
    })
    .map_err(E::from)?;
    shown?;
    // A failed recording keeps the report: the error goes into it (and `serve` fails after
    // writing it).
    let (mut records_dropped, mut recording_error) = (None, None);
    if let Some((rec, w)) = recording {
        drop(rec);
        let written = w
            .join()
            .map_err(|_| Error::Input("the session writer panicked".into()))
            .and_then(|r| r);
        records_dropped = Some(match &written {
            Ok(_) => run.records_dropped,
            Err(_) => run.stats.ticks,
        });
        recording_error = written.err().map(|e| e.to_string());
    }
    Ok((
        Served {
            run,
            floor,
            records_dropped,
            recording_error,
        },
        devices,
    ))
}

/// The world `serve --haply` runs: a scene's Haply fingers (their `url` replaced by `url`
/// when given); a scene with none, its first finger made a Haply finger with the defaults
/// (model, tool and limits kept; the others dropped); a bare mesh, one Haply finger with the
/// defaults. Every Haply finger whose scene gives no limits gets `limits`, else the `inverse3`
/// preset: its force goes through the virtual coupling and is bounded by the smaller of
/// `[haptics] max_force_n` and the Inverse3's peak force.
pub fn haply_world(
    spec: &str,
    url: Option<&str>,
    limits: Option<&DeviceLimits>,
) -> Result<World, Error> {
    use crate::scene::{HaplySpec, SceneSource};
    let mut world = World::load_live(spec, "haply")?;
    let is_haply = |f: &crate::scene::FingerSpec| matches!(f.device, DeviceSpec::Haply(_));
    if !world.fingers.iter().any(is_haply) {
        let Some(first) = world.fingers.first().cloned() else {
            return Err(Error::Body(format!("scene '{}' has no finger", world.name)));
        };
        if SceneSource::find(spec)?.is_some() && url.is_none() {
            return Err(Error::Body(format!(
                "scene '{}' has no haply finger: serve it with --haply [URL] (or its udp fingers with --udp ADDR)",
                world.name
            )));
        }
        let default = haply_default(&world);
        world.fingers = vec![crate::scene::FingerSpec {
            device: DeviceSpec::Haply(default),
            ..first
        }];
    }
    if let Some(other) = world.fingers.iter().position(|f| !is_haply(f)) {
        return Err(Error::Body(format!(
            "scene '{}': finger {} is not a haply finger; `serve` drives haply fingers only, or udp fingers only (--udp ADDR)",
            world.name,
            other + 1
        )));
    }
    let preset = DeviceLimits::preset("inverse3").expect("a preset of the table");
    for f in &mut world.fingers {
        if let (DeviceSpec::Haply(HaplySpec { url: u, .. }), Some(url)) = (&mut f.device, url) {
            *u = url.to_string();
        }
        f.limits
            .get_or_insert_with(|| limits.cloned().unwrap_or_else(|| preset.clone()));
    }
    Ok(world)
}

/// A Haply finger with every default for `world`: the service on this machine, the first
/// Inverse3, its workspace centre at the middle of the top of the objects' bounds, scale 1.
fn haply_default(world: &World) -> crate::scene::HaplySpec {
    use crate::devices::workspace::{Workspace, DEFAULT_DEVICE_CENTRE};
    let (lo, hi) = world.bounds();
    let c = glam::DVec3::new(0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), hi.z);
    crate::scene::HaplySpec {
        url: crate::scene::HAPLY_DEFAULT_URL.into(),
        device_id: None,
        workspace: Workspace {
            device_centre: glam::DVec3::from_array(DEFAULT_DEVICE_CENTRE),
            scene_centre: if c.is_finite() { c } else { glam::DVec3::ZERO },
            scale: 1.0,
        },
    }
}

/// Set by SIGINT (Ctrl-C) or SIGTERM once [`stop_on_interrupt`] has been called.
pub static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// Makes SIGINT (Ctrl-C) and SIGTERM set [`INTERRUPTED`] instead of killing the process, so a
/// run without `--seconds` ends cleanly: its devices are released and its report written.
pub fn stop_on_interrupt() {
    extern "C" fn on_signal(_: libc::c_int) {
        INTERRUPTED.store(true, Ordering::Relaxed);
    }
    for sig in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: installs an async-signal-safe handler that only stores to an atomic.
        unsafe {
            libc::signal(
                sig,
                on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t,
            );
        }
    }
}
