//! The cutter's thread: it runs the [`Cutter`] off the haptic thread, joined to it by the
//! wait-free rings of a [`CutLink`] (the cutting itself is [`crate::haptic::cutter`]'s).

use std::sync::Arc;

pub use crate::haptic::cutter::{CutBody, CutFeed, CutPlan, Cutter, Stroke, FOLD_RANK};
#[cfg(feature = "native")]
use crate::scene::World;
#[cfg(feature = "native")]
use crate::Error;

/// The haptic thread's ends of the cutter: strokes out, cut bodies in, replaced bodies back
/// out (dropped on the cutter's thread). Wait-free rings: the haptic tick neither locks nor
/// allocates through them.
pub struct CutLink {
    strokes: rtrb::Producer<Stroke>,
    bodies: rtrb::Consumer<(usize, Arc<CutBody>)>,
    spent: rtrb::Producer<Arc<CutBody>>,
    /// Strokes that did not fit the ring (the cutter fell behind).
    pub strokes_dropped: u64,
}

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
            }
        }
        while let Ok((o, body)) = self.bodies.pop() {
            installed(o, &body);
            if let Some(old) = hw.install_cut(o, body) {
                // Back to the cutter's thread to be freed there; if the ring is full, it is
                // freed here (never the case at the ring's size).
                let _ = self.spent.push(old);
            }
        }
    }
}

/// The cutter's thread: it applies the strokes as they come, a pass every millisecond at
/// most, and hands each new body to the haptic thread and the visual feed.
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
    /// Tets removed.
    pub tets_removed: usize,
    /// Pieces cut off (every object).
    pub pieces_removed: usize,
    /// The longest pass (strokes to cut body), s.
    pub max_pass_s: f64,
    /// Folds of a correction into a new `L`.
    pub folds: u64,
    /// The longest fold (with the new factorisation), s.
    pub max_fold_s: f64,
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
        let plan = Cutter::plan(world)?;
        let (sp, mut sc) = rtrb::RingBuffer::<Stroke>::new(1 << 14);
        let (mut bp, bc) = rtrb::RingBuffer::<(usize, Arc<CutBody>)>::new(256);
        let (pp, mut pc) = rtrb::RingBuffer::<Arc<CutBody>>::new(256);
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let stop2 = stop.clone();
        let haptic_cpus = crate::threads::cpus_of_current_thread();
        let handle = std::thread::Builder::new()
            .name("touchfem-cutter".into())
            .spawn(move || -> Result<CutStats, Error> {
                // Spawned from the haptic loop: off its core and out of its real-time class.
                crate::threads::become_background_worker(&haptic_cpus);
                let mut cutter = Cutter::from_plan(plan)?;
                let mut stats = CutStats::default();
                let mut pieces: Vec<usize> = Vec::new();
                let mut pending = Vec::with_capacity(1 << 14);
                loop {
                    let stopping = stop2.load(std::sync::atomic::Ordering::Acquire);
                    pending.clear();
                    while let Ok(s) = sc.pop() {
                        pending.push(s);
                    }
                    while pc.pop().is_ok() {}
                    if !pending.is_empty() {
                        let t = std::time::Instant::now();
                        for (o, body) in cutter.apply_all(&pending)? {
                            stats.bodies += 1;
                            stats.tets_removed = body.tets_removed;
                            if pieces.len() <= o {
                                pieces.resize(o + 1, 0);
                            }
                            pieces[o] = body.pieces_removed;
                            stats.pieces_removed = pieces.iter().sum();
                            feed.publish(o, body.clone());
                            // The haptic thread takes what fits; it never waits.
                            let _ = bp.push((o, body));
                        }
                        stats.max_pass_s = stats.max_pass_s.max(t.elapsed().as_secs_f64());
                        // Fold now, while the blade is still, rather than before its next cut.
                        let t = std::time::Instant::now();
                        let n = cutter.fold_due()?;
                        if n > 0 {
                            stats.folds += n as u64;
                            stats.max_fold_s = stats.max_fold_s.max(t.elapsed().as_secs_f64());
                        }
                    } else if stopping {
                        return Ok(stats);
                    } else {
                        std::thread::sleep(std::time::Duration::from_millis(1));
                    }
                }
            })
            .map_err(|e| Error::Input(format!("cannot start the cutter's thread: {e}")))?;
        Ok(Some((
            CutLink {
                strokes: sp,
                bodies: bc,
                spent: pp,
                strokes_dropped: 0,
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
