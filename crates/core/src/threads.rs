//! Thread placement: which cores the haptic loop, the visual loop and a software GPU driver's
//! threads run on.
//!
//! On a software Vulkan driver (Mesa's lavapipe) every submit hands work from the submitting
//! thread to the driver's queue thread and back. When the two run on different cores each
//! hand-off is a cross-core wake-up, which on a virtual machine costs tens of microseconds and
//! varies wildly; on one core it is a plain context switch. Measured on the development VM
//! (`cargo bench -p touchfem-benches --bench deform`): an empty submit-and-wait took 30–80 µs unpinned and a
//! steady 17 µs with both threads on one core. Threads inherit the affinity of the thread that
//! creates them, so [`VisualPlacement`] pins the visual thread *before* the GPU context is
//! created (the driver's threads start on that core too) and gives the haptic loop another.
//!
//! Without the `native` feature (the engine built for `wasm32-unknown-unknown`) there are no
//! threads and no clock: [`available`] is 1, [`fan_out`] runs every part on the calling thread,
//! one after another, and a [`Stopwatch`] reads zero. The solves' bits never depend on how many
//! threads share the work (the columns sit on a fixed grid), so the results are the same.

/// How many threads the parallel solves may use: the machine's cores (1 where unknown) with
/// the `native` feature, 1 without.
pub fn available() -> usize {
    #[cfg(feature = "native")]
    {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    }
    #[cfg(not(feature = "native"))]
    {
        1
    }
}

/// faer's parallelism for the factorisation's big dense fronts: every core (rayon) with the
/// `native` feature, sequential without.
pub fn faer_par() -> faer::Par {
    #[cfg(feature = "native")]
    {
        faer::Par::rayon(0)
    }
    #[cfg(not(feature = "native"))]
    {
        faer::Par::Seq
    }
}

/// Runs `rest(i)` for each `i` in `1..parts` on its own scoped thread, then `first` on the
/// calling thread, and returns their results in the order `first`, `rest(1)`, `rest(2)`, …
/// (`Err` with the payload for a part that panicked). Without the `native` feature every part
/// runs on the calling thread, in that order.
pub fn fan_out<T: Send>(
    parts: usize,
    first: impl FnOnce() -> T,
    rest: impl Fn(usize) -> T + Sync,
) -> Vec<std::thread::Result<T>> {
    #[cfg(feature = "native")]
    {
        std::thread::scope(|sc| {
            let rest = &rest;
            let handles: Vec<_> = (1..parts).map(|i| sc.spawn(move || rest(i))).collect();
            let mut out = Vec::with_capacity(parts.max(1));
            out.push(Ok(first()));
            out.extend(handles.into_iter().map(|h| h.join()));
            out
        })
    }
    #[cfg(not(feature = "native"))]
    {
        let mut out = Vec::with_capacity(parts.max(1));
        out.push(Ok(first()));
        out.extend((1..parts).map(|i| Ok(rest(i))));
        out
    }
}

/// A phase timer for the precompute's figures. With the `native` feature it reads the
/// monotonic clock; without, it reads zero: `std::time::Instant::now` panics on
/// `wasm32-unknown-unknown`, and the timings are only reported, never used to decide anything,
/// so an embedder that wants them times the call itself (e.g. `performance.now()`).
#[derive(Clone, Copy, Debug)]
pub struct Stopwatch {
    #[cfg(feature = "native")]
    start: std::time::Instant,
}

impl Stopwatch {
    /// A stopwatch started now.
    pub fn start() -> Stopwatch {
        Stopwatch {
            #[cfg(feature = "native")]
            start: std::time::Instant::now(),
        }
    }

    /// The time since [`Stopwatch::start`] (zero without the `native` feature).
    pub fn elapsed(&self) -> std::time::Duration {
        #[cfg(feature = "native")]
        {
            self.start.elapsed()
        }
        #[cfg(not(feature = "native"))]
        {
            std::time::Duration::ZERO
        }
    }
}

/// The cores the calling thread may run on (empty where unknown or unsupported).
pub(crate) fn current_cpus() -> Vec<usize> {
    #[cfg(all(feature = "native", target_os = "linux"))]
    {
        // SAFETY: `set` is a plain bit set, fully initialised by CPU_ZERO; the call writes at
        // most `size_of::<cpu_set_t>()` bytes into it.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_ZERO(&mut set);
            if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
                return Vec::new();
            }
            (0..libc::CPU_SETSIZE as usize)
                .filter(|&c| libc::CPU_ISSET(c, &set))
                .collect()
        }
    }
    #[cfg(not(all(feature = "native", target_os = "linux")))]
    {
        Vec::new()
    }
}

/// Restricts the calling thread to `cpus`. Returns false (and changes nothing) where that is
/// not permitted, not supported, or `cpus` is empty or out of range.
pub(crate) fn pin_current_thread(cpus: &[usize]) -> bool {
    #[cfg(all(feature = "native", target_os = "linux"))]
    {
        if cpus.is_empty() || cpus.iter().any(|&c| c >= libc::CPU_SETSIZE as usize) {
            return false;
        }
        // SAFETY: as in `current_cpus`; every index is below CPU_SETSIZE.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_ZERO(&mut set);
            for &c in cpus {
                libc::CPU_SET(c, &mut set);
            }
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
        }
    }
    #[cfg(not(all(feature = "native", target_os = "linux")))]
    {
        let _ = cpus;
        false
    }
}

/// Where the demo's threads go: the visual loop (and the GPU driver's threads, created while it
/// is pinned) on one core, the haptic loop on another. On a machine with fewer than two usable
/// cores nothing is pinned.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct VisualPlacement {
    /// Every core the process may use (restored around work that wants them all).
    pub all: Vec<usize>,
    /// The visual loop's core.
    pub visual: Option<usize>,
    /// The haptic loop's core.
    pub haptic: Option<usize>,
}

impl VisualPlacement {
    /// The first usable core for the visual loop, the last for the haptic loop.
    pub fn split() -> VisualPlacement {
        let all = current_cpus();
        match (all.first(), all.last()) {
            (Some(&v), Some(&h)) if all.len() >= 2 => VisualPlacement {
                visual: Some(v),
                haptic: Some(h),
                all,
            },
            _ => VisualPlacement {
                all,
                ..Default::default()
            },
        }
    }

    /// Pins the calling thread to the visual core; returns whether it did.
    pub fn enter_visual(&self) -> bool {
        self.visual.is_some_and(|c| pin_current_thread(&[c]))
    }

    /// Pins the calling thread to the haptic core; returns whether it did.
    pub fn enter_haptic(&self) -> bool {
        self.haptic.is_some_and(|c| pin_current_thread(&[c]))
    }

    /// Lets the calling thread run on every core again.
    pub fn leave(&self) -> bool {
        pin_current_thread(&self.all)
    }
}

#[cfg(all(
    any(test, feature = "self-check"),
    feature = "native",
    target_os = "linux"
))]
pub(crate) mod tests {
    use super::*;

    /// Pinning restricts the thread to the named core, and restoring gives every core back;
    /// bad requests change nothing. (Runs on a spawned thread so the test harness's thread
    /// keeps its affinity.)
    #[cfg_attr(test, test)]
    pub(crate) fn pin_and_restore() {
        std::thread::spawn(|| {
            let all = current_cpus();
            assert!(!all.is_empty(), "sched_getaffinity works on Linux");
            assert!(!pin_current_thread(&[]));
            assert!(!pin_current_thread(&[usize::MAX]));
            assert_eq!(current_cpus(), all);
            let last = *all.last().unwrap();
            assert!(pin_current_thread(&[last]));
            assert_eq!(current_cpus(), vec![last]);
            let p = VisualPlacement::split();
            assert_eq!(p.all, vec![last], "split sees the current mask");
            assert_eq!(p.visual, None, "one core: nothing to split");
            assert!(!p.enter_visual());
            assert!(pin_current_thread(&all));
            assert_eq!(current_cpus(), all);
            let p = VisualPlacement::split();
            if all.len() >= 2 {
                assert_ne!(p.visual, p.haptic);
                assert!(p.enter_haptic());
                assert_eq!(current_cpus(), vec![p.haptic.unwrap()]);
                assert!(p.enter_visual());
                assert_eq!(current_cpus(), vec![p.visual.unwrap()]);
                assert!(p.leave());
                assert_eq!(current_cpus(), all);
            }
        })
        .join()
        .unwrap();
    }

    /// The calling thread's scheduling class (Linux `SCHED_*`).
    fn policy() -> i32 {
        // SAFETY: a plain query on the current thread.
        unsafe { libc::sched_getscheduler(0) }
    }

    /// A worker spawned by a thread pinned off the haptic core (as the cutter spawns its fold
    /// and its helpers) becomes an idle worker on the haptic core, and a background worker
    /// spawned from the haptic core goes to the others. (On one core: a background worker.)
    #[cfg_attr(test, test)]
    pub(crate) fn workers_find_their_cores_from_a_pinned_thread() {
        std::thread::spawn(|| {
            let all = current_cpus();
            let (first, last) = (all[0], *all.last().unwrap());
            assert!(pin_current_thread(&[first]));
            let idle =
                std::thread::spawn(move || (become_idle_worker(&[last]), current_cpus(), policy()));
            let idle = idle.join().unwrap();
            assert!(pin_current_thread(&[last]));
            let back = std::thread::spawn(move || {
                become_background_worker(&[last]);
                (current_cpus(), policy())
            });
            let back = back.join().unwrap();
            let others: Vec<usize> = all.iter().copied().filter(|&c| c != last).collect();
            if all.len() >= 2 {
                assert_eq!(idle, (true, vec![last], libc::SCHED_IDLE));
                assert_eq!(back, (others, libc::SCHED_OTHER));
            } else {
                assert_eq!(idle, (false, vec![last], libc::SCHED_OTHER));
            }
        })
        .join()
        .unwrap();
    }
}

/// Asks the OS to run the calling thread at real-time priority (Linux `SCHED_FIFO`, priority
/// 80), so the 1 kHz loop keeps its rate whatever the visual path does. Returns false (and
/// changes nothing) where that is not permitted or not supported.
pub fn try_realtime_priority() -> bool {
    try_realtime_priority_at(80)
}

/// The cores off `haptic_cpus` that the calling thread may use: those of its own mask, or,
/// where its mask holds only haptic cores (a thread the haptic loop spawned), the machine's
/// other online cores. Not [`available`]: a thread inherits its spawner's mask, so a worker
/// that a pinned thread spawned would count one core where the machine has two (the cutter's
/// fold and columns helper did, and so ran beside the visual loop, never in the haptic
/// core's idle time).
fn off_haptic(haptic_cpus: &[usize]) -> Vec<usize> {
    let own: Vec<usize> = (current_cpus().into_iter())
        .filter(|c| !haptic_cpus.contains(c))
        .collect();
    if !own.is_empty() {
        return own;
    }
    #[cfg(all(feature = "native", target_os = "linux"))]
    let n = {
        // SAFETY: a plain query, no pointers.
        let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
        usize::try_from(n).unwrap_or(1)
    };
    #[cfg(not(all(feature = "native", target_os = "linux")))]
    let n = available();
    (0..n).filter(|c| !haptic_cpus.contains(c)).collect()
}

/// Makes the calling thread a background worker when the haptic loop spawned it: it leaves
/// the haptic loop's real-time class (threads inherit it, and a busy real-time thread gets
/// the whole class throttled) for the normal one, and the haptic loop's cores for the others
/// (where there are others). What the cutter's thread does first. Returns whether the
/// scheduling class was changed.
pub fn become_background_worker(haptic_cpus: &[usize]) -> bool {
    let others = off_haptic(haptic_cpus);
    if !others.is_empty() && !haptic_cpus.is_empty() {
        pin_current_thread(&others);
    }
    #[cfg(all(feature = "native", target_os = "linux"))]
    {
        // SAFETY: plain FFI call on the current thread with a fully initialised parameter
        // (priority 0 is the only one SCHED_OTHER takes).
        unsafe {
            let param = libc::sched_param { sched_priority: 0 };
            libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_OTHER, &param) == 0
        }
    }
    #[cfg(not(all(feature = "native", target_os = "linux")))]
    {
        false
    }
}

/// [`become_background_worker`], then a real-time priority below the haptic loop's (Linux
/// `SCHED_FIFO` 10) where permitted: for the cutter's passes, short bursts that the visual
/// loop and its GPU driver's threads on the same core would otherwise starve (a pass took
/// 0.15–0.25 s in the incision demo on 2 cores, against 10–40 ms alone). Returns whether it
/// got the priority; without it the thread is a background worker.
pub fn become_urgent_worker(haptic_cpus: &[usize]) -> bool {
    become_background_worker(haptic_cpus);
    try_realtime_priority_at(10)
}

/// Makes the calling thread run only when `cpus` (the haptic loop's cores) have nothing else
/// to run (Linux `SCHED_IDLE`, pinned there): for long work such as a fold, which then takes
/// the time the haptic loop sleeps between its ticks instead of the visual loop's, and yields
/// its core the moment the loop wakes (a real-time thread preempts it). Where that is not
/// possible (one core, no `SCHED_IDLE`), a background worker ([`become_background_worker`]).
/// Returns whether it became an idle worker.
pub fn become_idle_worker(haptic_cpus: &[usize]) -> bool {
    #[cfg(all(feature = "native", target_os = "linux"))]
    {
        if !off_haptic(haptic_cpus).is_empty() && pin_current_thread(haptic_cpus) {
            // SAFETY: plain FFI call on the current thread with a fully initialised parameter
            // (priority 0 is the only one SCHED_IDLE takes).
            let ok = unsafe {
                let param = libc::sched_param { sched_priority: 0 };
                libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_IDLE, &param) == 0
            };
            if ok {
                return true;
            }
        }
    }
    become_background_worker(haptic_cpus);
    false
}

/// The cores the calling thread may run on (empty where unknown).
pub fn cpus_of_current_thread() -> Vec<usize> {
    current_cpus()
}

/// [`try_realtime_priority`] at `SCHED_FIFO` priority `priority` (1–99).
pub(crate) fn try_realtime_priority_at(priority: i32) -> bool {
    #[cfg(all(feature = "native", target_os = "linux"))]
    {
        // SAFETY: plain FFI calls on the current thread with a fully initialised parameter.
        unsafe {
            let param = libc::sched_param {
                sched_priority: priority,
            };
            libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) == 0
        }
    }
    #[cfg(not(all(feature = "native", target_os = "linux")))]
    {
        let _ = priority;
        false
    }
}
