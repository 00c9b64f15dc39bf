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

    /// [`share_jobs`]: every job done once, and a helper still on a job when the calling
    /// thread runs out of them is lent the caller's class (its job here waits for that, at
    /// most 10 s: an idle-class helper would otherwise starve beside busy work). A job the
    /// helper panics in is returned, and the rest are done. [`make_ordinary`] moves an idle
    /// worker to the normal class.
    #[cfg_attr(test, test)]
    pub(crate) fn a_helper_left_working_is_lent_the_waiting_threads_class() {
        use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering::SeqCst};
        std::thread::spawn(|| {
            let all = current_cpus();
            let (first, last) = (all[0], *all.last().unwrap());
            assert!(pin_current_thread(&[first]));
            let helper_took = AtomicBool::new(false);
            let done = AtomicUsize::new(0);
            let lent_to = std::sync::Mutex::new(None);
            let is_helper = || std::thread::current().name() == Some("touchfem-helper");
            let lost = share_jobs(
                0..2,
                Some(&[last]),
                || {
                    // Until the helper is on a job (at most 10 s).
                    let t0 = std::time::Instant::now();
                    while !helper_took.load(SeqCst) && t0.elapsed().as_secs() < 10 {
                        std::thread::sleep(std::time::Duration::from_millis(1));
                    }
                },
                |_| {
                    if is_helper() {
                        helper_took.store(true, SeqCst);
                        let t0 = std::time::Instant::now();
                        while policy() == libc::SCHED_IDLE && t0.elapsed().as_secs() < 10 {
                            std::thread::sleep(std::time::Duration::from_millis(1));
                        }
                        *lent_to.lock().unwrap() = Some((policy(), current_cpus()));
                    }
                    done.fetch_add(1, SeqCst);
                },
            );
            assert!(lost.is_empty());
            assert_eq!(done.load(SeqCst), 2);
            if all.len() >= 2 {
                assert_eq!(
                    *lent_to.lock().unwrap(),
                    Some((libc::SCHED_OTHER, vec![last]))
                );
            }
            // A helper that panics on its job: that job is returned, the others done.
            let done = AtomicUsize::new(0);
            let lost = share_jobs(
                0..6,
                Some(&[last]),
                || {},
                |k| {
                    if is_helper() {
                        panic!("a helper's job {k} fails (expected by this check)");
                    }
                    done.fetch_add(1, SeqCst);
                },
            );
            if all.len() >= 2 {
                assert_eq!(lost.len(), 1, "{lost:?}");
                assert_eq!(done.load(SeqCst), 5);
            }
            // An idle worker left to end on its own is moved to the normal class.
            let (idle_tx, idle_rx) = std::sync::mpsc::channel();
            let (go_tx, go_rx) = std::sync::mpsc::channel::<()>();
            let h = std::thread::spawn(move || {
                become_idle_worker(&[last]);
                idle_tx.send(policy()).unwrap();
                let _ = go_rx.recv();
                policy()
            });
            let before = idle_rx.recv().unwrap();
            assert!(make_ordinary(&h));
            go_tx.send(()).unwrap();
            assert_eq!(h.join().unwrap(), libc::SCHED_OTHER);
            if all.len() >= 2 {
                assert_eq!(before, libc::SCHED_IDLE);
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
        set_own_scheduling(libc::SCHED_OTHER, 0)
    }
    #[cfg(not(all(feature = "native", target_os = "linux")))]
    {
        false
    }
}

/// Sets the scheduling class and priority of `thread` (Linux); returns whether it did.
///
/// # Safety
/// `thread` must name a live thread that is neither joined nor detached (its id valid).
#[cfg(all(feature = "native", target_os = "linux"))]
unsafe fn set_scheduling_of(thread: libc::pthread_t, policy: i32, priority: i32) -> bool {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: `thread` is valid (the caller's promise); the parameter is fully initialised.
    unsafe { libc::pthread_setschedparam(thread, policy, &param) == 0 }
}

/// [`set_scheduling_of`] the calling thread.
#[cfg(all(feature = "native", target_os = "linux"))]
fn set_own_scheduling(policy: i32, priority: i32) -> bool {
    // SAFETY: the calling thread is live.
    unsafe { set_scheduling_of(libc::pthread_self(), policy, priority) }
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
        if !off_haptic(haptic_cpus).is_empty()
            && pin_current_thread(haptic_cpus)
            && set_own_scheduling(libc::SCHED_IDLE, 0)
        {
            return true;
        }
    }
    become_background_worker(haptic_cpus);
    false
}

/// Runs `work` on every job of `jobs`: on the calling thread and on one helper thread on
/// `cpus` (the haptic loop's cores) in their idle time ([`become_idle_worker`]), each taking
/// the next job left. `first` runs on the calling thread once the helper has moved to its
/// cores (or after 5 ms), so the helper starts meanwhile: spawned from a real-time thread it
/// would otherwise wait on that thread's core for it to sleep. When the calling thread finds
/// no job left it lends the helper its own scheduling class before waiting for it: an idle
/// class thread gets almost no time while other work fills its cores (a loaded machine held
/// a cut's pass for seconds), and the caller must never wait on it (priority inversion).
/// Returns the numbers of the jobs the helper took and did not finish (it panicked), for the
/// caller to redo or give up on; empty normally. Without `cpus` (or the `native` feature),
/// `first` then every job on the calling thread.
pub fn share_jobs<J: Send>(
    jobs: impl Iterator<Item = J> + Send,
    cpus: Option<&[usize]>,
    first: impl FnOnce(),
    work: impl Fn(J) + Sync,
) -> Vec<usize> {
    #[cfg(feature = "native")]
    if let Some(cpus) = cpus.filter(|c| !c.is_empty()) {
        let jobs = std::sync::Mutex::new(jobs.enumerate());
        let next = || jobs.lock().unwrap_or_else(|e| e.into_inner()).next();
        // The job the helper is on (usize::MAX: none).
        let on = std::sync::atomic::AtomicUsize::new(usize::MAX);
        return std::thread::scope(|s| {
            let (me, its_id) = std::sync::mpsc::sync_channel::<Lendee>(1);
            let (moved, on_its_core) = std::sync::mpsc::sync_channel::<()>(1);
            let (next, work, on) = (&next, &work, &on);
            let helper = std::thread::Builder::new()
                .name("touchfem-helper".into())
                .spawn_scoped(s, move || {
                    let _ = me.send(Lendee::current());
                    become_idle_worker(cpus);
                    let _ = moved.send(());
                    while let Some((k, j)) = next() {
                        on.store(k, std::sync::atomic::Ordering::Relaxed);
                        work(j);
                        on.store(usize::MAX, std::sync::atomic::Ordering::Relaxed);
                    }
                });
            // (Its id comes first, before it leaves this thread's class and core.)
            let lendee = helper.as_ref().ok().and_then(|_| its_id.recv().ok());
            if lendee.is_some() {
                let _ = on_its_core.recv_timeout(std::time::Duration::from_millis(5));
            }
            first();
            while let Some((_, j)) = next() {
                work(j);
            }
            let Ok(helper) = helper else {
                return Vec::new();
            };
            if let Some(l) = lendee {
                // The helper is joinable until `join` below: its thread is live.
                l.lend_mine();
            }
            match helper.join() {
                Ok(()) => Vec::new(),
                Err(_) => match on.load(std::sync::atomic::Ordering::Relaxed) {
                    usize::MAX => Vec::new(),
                    k => vec![k],
                },
            }
        });
    }
    let _ = cpus;
    first();
    jobs.for_each(work);
    Vec::new()
}

/// Moves the thread of `h` (a worker, such as an idle one) into the normal scheduling class
/// (Linux `SCHED_OTHER`; its cores stay), for a worker left to end on its own: the last
/// thread of a process frees the process's memory as it exits, and in an idle worker that
/// took over 30 s on a loaded machine (a window's exit waited for it). Returns whether it
/// did.
pub fn make_ordinary<T>(h: &std::thread::JoinHandle<T>) -> bool {
    #[cfg(all(feature = "native", target_os = "linux"))]
    {
        use std::os::unix::thread::JoinHandleExt;
        // SAFETY: `h` is held, so its thread is neither joined nor detached.
        unsafe { set_scheduling_of(h.as_pthread_t(), libc::SCHED_OTHER, 0) }
    }
    #[cfg(not(all(feature = "native", target_os = "linux")))]
    {
        let _ = h;
        false
    }
}

/// A thread that may be lent another's scheduling ([`Lendee::lend_mine`]).
#[cfg(feature = "native")]
struct Lendee {
    #[cfg(target_os = "linux")]
    thread: libc::pthread_t,
}

#[cfg(feature = "native")]
impl Lendee {
    /// The calling thread.
    fn current() -> Lendee {
        Lendee {
            // SAFETY: a plain query of the calling thread's id.
            #[cfg(target_os = "linux")]
            thread: unsafe { libc::pthread_self() },
        }
    }

    /// Gives this thread the calling thread's scheduling class and priority (its cores
    /// stay). It must not have been joined or detached yet. Returns whether it did.
    fn lend_mine(&self) -> bool {
        #[cfg(target_os = "linux")]
        {
            let (mut policy, mut param) = (0, libc::sched_param { sched_priority: 0 });
            // SAFETY: a query of the calling thread into initialised places; `self.thread`
            // names a thread that is still joinable (the caller's promise).
            unsafe {
                libc::pthread_getschedparam(libc::pthread_self(), &mut policy, &mut param) == 0
                    && set_scheduling_of(self.thread, policy, param.sched_priority)
            }
        }
        #[cfg(not(target_os = "linux"))]
        {
            false
        }
    }
}

/// The cores the calling thread may run on (empty where unknown).
pub fn cpus_of_current_thread() -> Vec<usize> {
    current_cpus()
}

/// [`try_realtime_priority`] at `SCHED_FIFO` priority `priority` (1–99).
pub(crate) fn try_realtime_priority_at(priority: i32) -> bool {
    #[cfg(all(feature = "native", target_os = "linux"))]
    {
        set_own_scheduling(libc::SCHED_FIFO, priority)
    }
    #[cfg(not(all(feature = "native", target_os = "linux")))]
    {
        let _ = priority;
        false
    }
}
