//! The haptic loop on its thread: devices → [`HapticWorld`] → devices, the sample published
//! lock-free, the tick recorded lock-free, and the thread's end (normal or by a panic) made
//! visible to the visual loop.

use glam::DVec3;
use std::sync::atomic::Ordering;

use super::pacer::Pacer;
use super::session::{Recorder, TickRecord};
use crate::devices::{FingerDevices, ForceState};
use crate::haptic::HapticWorld;
use crate::haptic::{LiveStatus, SampleWriter, MAX_OBJECTS};
use crate::limits::MAX_FINGERS;
use crate::runtime::pacer::HapticStats;
use crate::scene::World;
use crate::Error;

/// The longest a clocked loop waits for its device's reading before it ticks anyway (the
/// device's own watchdog may be shorter) and looks at its stop flag.
const CLOCKED_WAIT: std::time::Duration = std::time::Duration::from_millis(20);

/// The longest a run that ended on time ticks on for the cutter to finish the strokes
/// already sent ([`super::cutting::CutLink::pending`]).
pub(crate) const CUT_DRAIN: std::time::Duration = std::time::Duration::from_secs(5);

/// What a haptic run measured.
#[derive(Clone, Debug, Default)]
pub struct HapticRun {
    /// Timing and largest force.
    pub stats: HapticStats,
    /// Per object, the most fingers touching it at once.
    pub max_contacts: [usize; MAX_OBJECTS],
    /// Ticks whose record did not fit the recorder's ring (0 unless the disk stalled).
    pub records_dropped: u64,
    /// What the cutter did (a scene with a blade and a cuttable object).
    pub cuts: super::cutting::CutStats,
}

/// Runs the haptic loop on the calling thread at the scene's rate — or, for a device that
/// clocks it ([`FingerDevices::clocked`]), at each of its readings — until `seconds` have
/// passed (`None`: until `status.stop`), and then while the cutter finishes the blade's
/// strokes already sent (at most `CUT_DRAIN`, 5 s). Each tick reads every finger's device, steps the god-objects
/// and forces, sends each device its force, publishes the [`WorldSample`](crate::runtime::WorldSample) and, if recording,
/// queues the tick's positions and forces. Allocates nothing per tick.
pub fn run_haptic(
    world: &World,
    devices: &mut (impl FingerDevices + ?Sized),
    seconds: Option<f64>,
    publish: &mut SampleWriter,
    status: &LiveStatus,
    mut recorder: Option<&mut Recorder>,
) -> HapticRun {
    let mut hw = HapticWorld::new(world);
    // A blade's cuts are made on their own thread; the loop only trades strokes and bodies.
    let mut cutting = match super::cutting::CutThread::spawn(world, status.cuts.clone()) {
        Ok(c) => c,
        Err(e) => {
            log::warn!("cutting is off: {e}");
            None
        }
    };
    let n = hw.fingers();
    let rate = world.haptics.rate_hz;
    let limit = seconds.map(|s| (s * rate).ceil().max(1.0) as u64);
    let mut pacer = Pacer::new(rate);
    let mut pos = [DVec3::ZERO; MAX_FINGERS];
    let mut force = [DVec3::ZERO; MAX_FINGERS];
    let mut state = [ForceState::default(); MAX_FINGERS];
    let mut out = HapticRun::default();
    let mut max_force: f64 = 0.0;
    let period = 1.0 / rate;
    let mut last_t: Option<f64> = None;
    // Ticks stepped so far (the index of a cut's tick in the recording).
    let mut recorded = 0u64;
    // A device that clocks the loop (the UDP bridge with `--clock device`) starts each tick
    // with its reading; the run then ends on wall time.
    let clocked = devices.clocked();
    // A span too long for a Duration (or infinite) runs until `status.stop`.
    let until = seconds.and_then(|s| std::time::Duration::try_from_secs_f64(s.max(0.0)).ok());
    let more = |p: &Pacer| match (clocked, limit, until) {
        (false, Some(l), _) => p.ticks() < l,
        (true, _, Some(u)) => p.elapsed() < u,
        _ => true,
    };
    // When the run's time is up, the cutter's strokes in flight are waited for (ticking on,
    // up to `CUT_DRAIN`), so that a cut the blade made is in the recording and the report.
    let mut drain_from: Option<std::time::Duration> = None;
    while !status.stop.load(Ordering::Relaxed) {
        if !more(&pacer) {
            let pending = cutting.as_ref().is_some_and(|(l, _)| l.pending());
            let from = *drain_from.get_or_insert(pacer.elapsed());
            if !pending || pacer.elapsed() >= from + CUT_DRAIN {
                break;
            }
        }
        let (start, t) = if clocked {
            let reading = devices.wait_reading(CLOCKED_WAIT);
            pacer.arrived(reading)
        } else {
            pacer.wait()
        };
        // Time-based quantities (the ramp, the coupling, the force bound's rate) take the
        // measured time between the device's readings; the host clock's ticks are its
        // deadlines, one period apart.
        let dt = match last_t {
            Some(l) if clocked => (t - l).max(0.0),
            _ => period,
        };
        last_t = Some(t);
        devices.read(t, &mut pos[..n]);
        // Written in place into the triple buffer's back buffer: only the cache lines this
        // tick uses move between the cores (copying the whole sample cost ~3 µs a tick).
        let sample = publish.input_buffer_mut();
        hw.step_dt(dt, &pos[..n], &mut force[..n], sample);
        if let Some((link, _)) = &mut cutting {
            let rec = &mut recorder;
            let after_tick = recorded;
            link.exchange(&mut hw, |object, body| {
                if let Some(r) = rec.as_deref_mut() {
                    r.push_cut(super::session::CutRecord {
                        after_tick,
                        object,
                        body: body.clone(),
                    });
                }
            });
        }
        for (i, (s, f)) in state.iter_mut().zip(sample.fingers()).enumerate() {
            *s = ForceState {
                touching: f.object.is_some(),
                limited: hw.limited(i),
            };
        }
        for (o, m) in out
            .max_contacts
            .iter_mut()
            .enumerate()
            .take(sample.n_objects)
        {
            *m = (*m).max(sample.contacts(o));
        }
        publish.publish();
        devices.write(&force[..n], &state[..n]);
        for f in &force[..n] {
            max_force = max_force.max(f.length());
        }
        if let Some(r) = recorder.as_deref_mut() {
            r.push(&TickRecord::new(dt, &pos[..n], &force[..n]));
        }
        recorded += 1;
        pacer.end(start);
        status.ticks.store(pacer.ticks(), Ordering::Relaxed);
        status
            .elapsed_ns
            .store(pacer.elapsed().as_nanos() as u64, Ordering::Relaxed);
        status.missed.store(pacer.missed(), Ordering::Relaxed);
    }
    // The end of service, however it came: every device is released (zero force).
    devices.release();
    out.stats = pacer.stats();
    out.stats.max_force_n = max_force;
    out.stats.contact_budget_exhausted = hw.budget_exhausted();
    out.records_dropped = recorder.map_or(0, |r| r.dropped());
    if let Some((link, thread)) = cutting {
        match thread.finish() {
            Ok(s) => out.cuts = s.with_delays(link.delays()),
            Err(e) => log::warn!("the cutter failed: {e}"),
        }
    }
    out
}

/// Marks `status` done when dropped — also when the haptic thread unwinds from a panic, which
/// it then records, so a visual loop waiting on `status.done` never spins forever.
pub struct DoneGuard<'a>(pub &'a LiveStatus);

impl Drop for DoneGuard<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.panicked.store(true, Ordering::Release);
        }
        self.0.done.store(true, Ordering::Release);
    }
}

/// Joins a haptic thread, turning a panic into [`Error::HapticThread`].
pub fn join_haptic<T>(h: std::thread::ScopedJoinHandle<'_, T>) -> Result<T, Error> {
    h.join().map_err(|p| {
        let msg = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        Error::HapticThread(msg)
    })
}
