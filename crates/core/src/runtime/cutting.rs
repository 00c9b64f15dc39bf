//! The cutter's thread: it runs the [`Cutter`] off the haptic thread, joined to it by the
//! wait-free rings of a [`CutLink`] (the cutting itself is [`crate::haptic::cutter`]'s).

use std::sync::Arc;

pub use crate::haptic::cutter::{
    blade_quads, CutBody, CutFeed, CutMode, CutOp, CutPlan, Cutter, FoldJob, FoldMode, Folded,
    Stroke, FOLD_RANK,
};
#[cfg(feature = "native")]
use crate::scene::{DeviceSpec, World};
#[cfg(feature = "native")]
use crate::Error;

/// The haptic thread's ends of the cutter: strokes out, cut bodies in, replaced bodies back
/// out (dropped on the cutter's thread). Wait-free rings: the haptic tick neither locks nor
/// allocates through them.
pub struct CutLink {
    strokes: rtrb::Producer<Stroke>,
    bodies: rtrb::Consumer<(usize, Arc<CutBody>, u64)>,
    spent: rtrb::Producer<Arc<CutBody>>,
    /// Strokes that did not fit the ring (the cutter fell behind).
    pub strokes_dropped: u64,
    /// When each stroke was sent, by its number modulo the ring's size (native only).
    #[cfg(feature = "native")]
    sent_at: Box<[Option<std::time::Instant>]>,
    /// Strokes sent so far (the next one's number).
    sent: u64,
    /// Strokes the cutter's passes have finished with (their bodies handed over).
    done: Arc<std::sync::atomic::AtomicU64>,
    /// Each body's delay (s, in order, up to [`DELAYS_KEPT`]): from the sending of the first
    /// stroke of the pass that made it to its installation.
    delays: Vec<f64>,
}

/// The strokes the ring holds.
#[cfg(feature = "native")]
const STROKE_RING: usize = 1 << 14;

/// How many cut bodies' delays a [`CutLink`] keeps (allocated up front).
pub const DELAYS_KEPT: usize = 4096;

/// A body's number of the first stroke of its pass when no stroke made it (a fold adopted).
#[cfg(feature = "native")]
const NO_STROKE: u64 = u64::MAX;

impl CutLink {
    /// Sends the tick's strokes, and installs in `hw` every body the cutter has finished,
    /// telling `installed` of each (a recording keeps them).
    pub fn exchange(
        &mut self,
        hw: &mut crate::haptic::HapticWorld,
        mut installed: impl FnMut(usize, &Arc<CutBody>),
    ) {
        for s in hw.strokes() {
            if self.strokes.push(*s).is_err() {
                self.strokes_dropped += 1;
            } else {
                #[cfg(feature = "native")]
                {
                    self.sent_at[(self.sent % STROKE_RING as u64) as usize] =
                        Some(std::time::Instant::now());
                }
                self.sent += 1;
            }
        }
        while let Ok((o, body, first)) = self.bodies.pop() {
            #[cfg(feature = "native")]
            if first != NO_STROKE && self.delays.len() < self.delays.capacity() {
                if let Some(t) = self.sent_at[(first % STROKE_RING as u64) as usize] {
                    self.delays.push(t.elapsed().as_secs_f64());
                }
            }
            #[cfg(not(feature = "native"))]
            let _ = first;
            installed(o, &body);
            if let Some(old) = hw.install_cut(o, body) {
                // Back to the cutter's thread to be freed there; if the ring is full, it is
                // freed here (never the case at the ring's size).
                let _ = self.spent.push(old);
            }
        }
    }

    /// Whether a stroke sent is still being cut, or a body made of it waits in the ring: a
    /// run ending on time ticks on until it is not ([`super::run::run_haptic`]), so that no
    /// stroke's cut is lost to the recording or the report.
    pub fn pending(&self) -> bool {
        self.done.load(std::sync::atomic::Ordering::Acquire) < self.sent || !self.bodies.is_empty()
    }

    /// Each cut body's delay so far (s, in order; at most [`DELAYS_KEPT`]): from the sending
    /// of the first stroke of the cutter's pass that made it to its installation in the
    /// haptic world (a fold's adoption, made of no stroke, has none).
    pub fn delays(&self) -> &[f64] {
        &self.delays
    }
}

/// The cutter's thread: it applies the strokes as they come, a pass every millisecond at
/// most, and hands each new body to the haptic thread and the visual feed. Folds run on a
/// thread of their own (`touchfem-fold`, also off the haptic core) and are adopted between
/// two passes, so that a pass never waits for a fold ([`FoldMode::Deferred`]).
#[cfg(feature = "native")]
pub struct CutThread {
    stop: Arc<std::sync::atomic::AtomicBool>,
    handle: Option<std::thread::JoinHandle<Result<CutStats, Error>>>,
}

/// What the cutter's thread did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct CutStats {
    /// Cut bodies built.
    pub bodies: u64,
    /// Tets removed (a separating blade's: slivers, and pieces cut off).
    pub tets_removed: usize,
    /// Copies of nodes a separating blade made (its last body's).
    pub nodes_split: usize,
    /// Pieces cut off (every object).
    pub pieces_removed: usize,
    /// The longest pass (strokes to cut body), s.
    pub max_pass_s: f64,
    /// Folds of a correction into a new `L` (adopted).
    pub folds: u64,
    /// The longest fold (with the new factorisation), s; on the fold's thread when deferred.
    pub max_fold_s: f64,
    /// The longest time from a deferred fold's start to its handing back, s: the fold, then
    /// the cuts made meanwhile made again on it.
    pub max_fold_handed_s: f64,
    /// The longest adoption of a fold (the cuts since its snapshot made again, and the
    /// body), s; on the cutter's thread, between two passes.
    pub max_adopt_s: f64,
    /// Cut bodies whose delay was measured ([`CutLink::delays`]).
    pub delays: usize,
    /// Their median delay, s: from the blade's stroke to the body in the haptic loop.
    pub median_delay_s: f64,
    /// Their longest delay, s.
    pub max_delay_s: f64,
}

impl CutStats {
    /// Fills the delays' figures from a link's ([`CutLink::delays`]).
    pub fn with_delays(mut self, delays: &[f64]) -> CutStats {
        let mut d = delays.to_vec();
        d.sort_by(f64::total_cmp);
        self.delays = d.len();
        self.median_delay_s = d.get(d.len() / 2).copied().unwrap_or(0.0);
        self.max_delay_s = d.last().copied().unwrap_or(0.0);
        self
    }
}

/// How the cutter's thread folds: [`FoldMode::Deferred`], unless `TOUCHFEM_FOLD=inline` (an
/// expert switch, to compare with the folds of before 2026-12-06; its sessions are version 3).
pub fn fold_mode() -> FoldMode {
    match crate::options::var("TOUCHFEM_FOLD").as_deref() {
        Some("inline") => FoldMode::Inline,
        _ => FoldMode::Deferred,
    }
}

/// What a live cutter's blade does: [`CutMode::Separate`] (it parts the material along its
/// path; its sessions are version 5), unless `TOUCHFEM_CUT=remove` (it removes the tets it
/// sweeps; version 3 or 4). Any other value keeps the default, as the other switches do.
pub fn cut_mode() -> CutMode {
    match crate::options::var("TOUCHFEM_CUT").as_deref() {
        Some("remove") => CutMode::Remove,
        _ => CutMode::Separate,
    }
}

/// What the cutter's thread sends the fold's thread.
#[cfg(feature = "native")]
enum ToFold {
    /// A fold to run (its number).
    Job(u64, Box<FoldJob>),
    /// The next cuts made while fold number `.0` is out.
    Ops(u64, Vec<CutOp>),
}

/// A fold's result for the cutter's thread: its object, the fold (or why not), the seconds
/// the fold took and those until it was handed back (its catching up included).
#[cfg(feature = "native")]
type FoldDone = (usize, Result<Folded, Error>, f64, f64);

/// The fold's thread: runs each job in turn, then makes again on it the cuts made while it
/// ran (as they arrive), and hands it back once it has caught up; ends when the cutter's
/// thread hangs up.
#[cfg(feature = "native")]
fn fold_thread(rx: std::sync::mpsc::Receiver<ToFold>, tx: std::sync::mpsc::Sender<FoldDone>) {
    use std::collections::{HashMap, VecDeque};
    let mut jobs: VecDeque<(u64, Box<FoldJob>)> = VecDeque::new();
    let mut ops: HashMap<u64, Vec<CutOp>> = HashMap::new();
    let take = |m: ToFold,
                jobs: &mut VecDeque<(u64, Box<FoldJob>)>,
                ops: &mut HashMap<u64, Vec<CutOp>>| {
        match m {
            ToFold::Job(id, job) => {
                ops.entry(id).or_default();
                jobs.push_back((id, job));
            }
            // (Cuts of a fold already handed back are the cutter's to make again.)
            ToFold::Ops(id, more) => {
                if let Some(v) = ops.get_mut(&id) {
                    v.extend(more);
                }
            }
        }
    };
    while let Ok(m) = rx.recv() {
        take(m, &mut jobs, &mut ops);
        while let Some((id, job)) = jobs.pop_front() {
            let t = std::time::Instant::now();
            let (o, r) = job.run();
            let fold_s = t.elapsed().as_secs_f64();
            let mut gone = false;
            let r = r.and_then(|mut f| loop {
                loop {
                    match rx.try_recv() {
                        Ok(m) => take(m, &mut jobs, &mut ops),
                        Err(std::sync::mpsc::TryRecvError::Empty) => break,
                        Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                            gone = true;
                            break;
                        }
                    }
                }
                let have = ops.get(&id).map_or(&[][..], |v| &v[..]);
                if gone || f.applied() >= have.len() {
                    return Ok(f);
                }
                f.catch_up(have)?;
            });
            // The cutter has ended: nothing to hand back.
            if gone {
                return;
            }
            ops.remove(&id);
            if tx.send((o, r, fold_s, t.elapsed().as_secs_f64())).is_err() {
                return;
            }
        }
    }
}

#[cfg(feature = "native")]
impl CutThread {
    /// Starts the cutter for `world`'s cuttable objects, or returns `None` when nothing in it
    /// can be cut by a blade (no cuttable object or no blade finger). The factorisation runs
    /// on the new thread.
    pub fn spawn(world: &World, feed: Arc<CutFeed>) -> Result<Option<(CutLink, CutThread)>, Error> {
        let blades = world.fingers.iter().any(|f| f.tool.blade_depth().is_some());
        if !blades || world.objects.iter().all(|o| o.cuttable.is_none()) {
            return Ok(None);
        }
        let haptic_cpus = crate::threads::cpus_of_current_thread();
        // (The columns up front shared with a helper in the haptic core's idle time.)
        let plan = Cutter::plan(world)?.with_helper_on(haptic_cpus.clone());
        let mode = fold_mode();
        let cut = cut_mode();
        let (sp, mut sc) = rtrb::RingBuffer::<Stroke>::new(STROKE_RING);
        let (mut bp, bc) = rtrb::RingBuffer::<(usize, Arc<CutBody>, u64)>::new(256);
        let (pp, mut pc) = rtrb::RingBuffer::<Arc<CutBody>>::new(256);
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let stop2 = stop.clone();
        let done = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let done2 = done.clone();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel::<()>();
        let handle = std::thread::Builder::new()
            .name("touchfem-cutter".into())
            .spawn(move || -> Result<CutStats, Error> {
                // Spawned from the haptic loop: off its core and out of its real-time class.
                crate::threads::become_background_worker(&haptic_cpus);
                let t = std::time::Instant::now();
                let mut cutter = Cutter::from_plan(plan)?;
                log::info!(
                    "the cutter was ready in {:.2} s (its factor, and {} columns of L₀ solved up front)",
                    t.elapsed().as_secs_f64(),
                    cutter.columns_held()
                );
                cutter.set_fold_mode(mode);
                cutter.set_cut_mode(cut);
                let _ = ready_tx.send(());
                // Its passes now go before the visual loop on their core (the factorisation
                // above did not: it is long). The fold's thread stays a background worker.
                if mode == FoldMode::Deferred {
                    crate::threads::become_urgent_worker(&haptic_cpus);
                }
                let mut stats = CutStats::default();
                let mut pieces: Vec<usize> = Vec::new();
                let mut pending = Vec::with_capacity(1 << 14);
                // The fold's thread: jobs in, and the cuts made while each is out; folded
                // compliances (caught up with those cuts, with their time) out.
                let (job_tx, job_rx) = std::sync::mpsc::channel::<ToFold>();
                let (done_tx, done_rx) = std::sync::mpsc::channel();
                let cpus = haptic_cpus.clone();
                let folder = std::thread::Builder::new()
                    .name("touchfem-fold".into())
                    .spawn(move || {
                        // In the haptic loop's idle time (and out of the visual loop's).
                        crate::threads::become_idle_worker(&cpus);
                        fold_thread(job_rx, done_tx);
                    })
                    .map_err(|e| Error::Input(format!("cannot start the fold's thread: {e}")))?;
                // Per object: the job out (its number) and how many of its cuts were sent.
                let mut out: Vec<Option<(u64, usize)>> = Vec::new();
                let mut jobs_made = 0u64;
                // Strokes taken from the ring so far (the next one's number).
                let mut taken = 0u64;
                let mut publish =
                    |o: usize, body: Arc<CutBody>, first: u64, stats: &mut CutStats| {
                        stats.bodies += 1;
                        stats.tets_removed = body.tets_removed;
                        stats.nodes_split = body.nodes_split;
                        if pieces.len() <= o {
                            pieces.resize(o + 1, 0);
                        }
                        pieces[o] = body.pieces_removed;
                        stats.pieces_removed = pieces.iter().sum();
                        feed.publish(o, body.clone());
                        // The haptic thread takes what fits; it never waits.
                        let _ = bp.push((o, body, first));
                    };
                let result = loop {
                    let stopping = stop2.load(std::sync::atomic::Ordering::Acquire);
                    // Folds done since the last pass: adopted, each with a body of its own.
                    while let Ok((o, r, secs, until)) = done_rx.try_recv() {
                        let o: usize = o;
                        if let Some(slot) = out.get_mut(o) {
                            *slot = None;
                        }
                        stats.max_fold_s = stats.max_fold_s.max(secs);
                        stats.max_fold_handed_s = stats.max_fold_handed_s.max(until);
                        let t = std::time::Instant::now();
                        let adopted = r.and_then(|f| cutter.adopt(f));
                        match adopted.and_then(|()| cutter.body_now(o)) {
                            Ok(body) => {
                                stats.folds += 1;
                                publish(o, body, NO_STROKE, &mut stats);
                                stats.max_adopt_s =
                                    stats.max_adopt_s.max(t.elapsed().as_secs_f64());
                            }
                            Err(e) => {
                                log::warn!(
                                    "a fold of object {o} failed (its cut is carried on): {e}"
                                );
                                cutter.drop_fold(o);
                            }
                        }
                    }
                    pending.clear();
                    let first = taken;
                    while let Ok(s) = sc.pop() {
                        pending.push(s);
                        taken += 1;
                    }
                    while pc.pop().is_ok() {}
                    if !pending.is_empty() {
                        let t = std::time::Instant::now();
                        let bodies = match cutter.apply_all(&pending) {
                            Ok(b) => b,
                            Err(e) => break Err(e),
                        };
                        let any = !bodies.is_empty();
                        for (o, body) in bodies {
                            publish(o, body, first, &mut stats);
                        }
                        stats.max_pass_s = stats.max_pass_s.max(t.elapsed().as_secs_f64());
                        // After the bodies are in the ring (the haptic thread's `pending`).
                        done2.store(taken, std::sync::atomic::Ordering::Release);
                        // Folds due go to the fold's thread (deferred), or run here (inline).
                        if any {
                            // The cuts made while a fold is out, to its thread to catch up.
                            for (o, slot) in out.iter_mut().enumerate() {
                                if let Some((id, sent)) = slot {
                                    let ops = cutter.fold_ops(o);
                                    if ops.len() > *sent {
                                        let _ =
                                            job_tx.send(ToFold::Ops(*id, ops[*sent..].to_vec()));
                                        *sent = ops.len();
                                    }
                                }
                            }
                            match cutter.take_folds() {
                                Ok(jobs) => {
                                    for job in jobs {
                                        let o = job.object();
                                        if out.len() <= o {
                                            out.resize(o + 1, None);
                                        }
                                        out[o] = Some((jobs_made, 0));
                                        let _ = job_tx.send(ToFold::Job(jobs_made, Box::new(job)));
                                        jobs_made += 1;
                                    }
                                }
                                Err(e) => break Err(e),
                            }
                        }
                        let t = std::time::Instant::now();
                        match cutter.fold_due() {
                            Ok(0) => {}
                            Ok(n) => {
                                stats.folds += n as u64;
                                stats.max_fold_s = stats.max_fold_s.max(t.elapsed().as_secs_f64());
                            }
                            Err(e) => break Err(e),
                        }
                    } else if stopping {
                        break Ok(stats);
                    } else {
                        std::thread::sleep(std::time::Duration::from_millis(1));
                    }
                };
                // A fold still out is not waited for: its thread ends once the fold in hand
                // is made, in the normal class (in the haptic core's idle time, which a
                // loaded machine may not give for seconds, it held a window's exit for over
                // 30 s: joined, or as the process's last thread, freeing its memory).
                drop(job_tx);
                crate::threads::make_ordinary(&folder);
                drop(folder);
                result
            })
            .map_err(|e| Error::Input(format!("cannot start the cutter's thread: {e}")))?;
        // A scripted run's loop starts once the cutter is ready (its factor and its columns
        // of `L₀` solved up front: seconds), so that none of the script's strokes waits for
        // them; a hand's (the window's pointer, a device) starts at once, pressing while the
        // cutter prepares, its first strokes cut when it is ready. (A cutter that failed to
        // start drops its end and reports why when it is joined.)
        let scripted = (world.fingers.iter())
            .all(|f| matches!(f.device, DeviceSpec::Script(_) | DeviceSpec::Replay));
        if scripted {
            let _ = ready_rx.recv();
        }
        Ok(Some((
            CutLink {
                strokes: sp,
                bodies: bc,
                spent: pp,
                strokes_dropped: 0,
                sent_at: vec![None; STROKE_RING].into_boxed_slice(),
                sent: 0,
                done,
                delays: Vec::with_capacity(DELAYS_KEPT),
            },
            CutThread {
                stop,
                handle: Some(handle),
            },
        )))
    }

    /// Stops the cutter after the strokes already sent, and joins it.
    pub fn finish(mut self) -> Result<CutStats, Error> {
        self.stop.store(true, std::sync::atomic::Ordering::Release);
        match self.handle.take().map(|h| h.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(Error::HapticThread("the cutter's thread panicked".into())),
            None => Ok(CutStats::default()),
        }
    }
}

#[cfg(feature = "native")]
impl Drop for CutThread {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Release);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}
