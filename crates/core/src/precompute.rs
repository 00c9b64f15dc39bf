//! `touchfem precompute`: the compliance a scene needs, streamed batch by batch into a cache
//! file (never the whole L in memory), optionally one shard of the columns at a time so that
//! several machines share the work, and the merge of the shards. With a compression tolerance
//! `L` is built hierarchically panel by panel and written in the compressed format (version 4,
//! [`cache::hier`]); a shard is a run of panels.
//!
//! [`precompute`] is the one call: a [`Job`] (an object's mesh, selection, compression, shard
//! and destination) in, an [`Outcome`] (the file, its key, the figures, and the hierarchical
//! `L` written) out.

use crate::threads::Stopwatch;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use crate::cache::{self, CacheError, Header, Writer};
use crate::compliance::hmatrix::{HMatrix, HOptions};
use crate::compliance::{ColumnPlan, Compliance, HierParts, PhaseTimes, Selection, BATCH_COLS};
use crate::{Error, Mesh};

/// Where a precompute writes.
#[derive(Clone, Copy, Debug)]
pub enum Destination<'a> {
    /// This file, as named (also for a shard).
    File(&'a Path),
    /// The object's cache file in this directory, named by the object's name and the key
    /// ([`cache::file_in`]), with `.part-I-of-N` appended for a shard ([`cache::shard_file`]).
    Dir(&'a Path),
}

/// One precompute: an object's compliance (or one shard of it) into one cache file.
#[derive(Clone, Debug)]
pub struct Job<'a> {
    /// The object's name (names the file in a [`Destination::Dir`]).
    pub name: &'a str,
    /// The mesh, with its material and clamps.
    pub mesh: &'a Mesh,
    /// Which rows and columns of `L`.
    pub selection: &'a Selection,
    /// `L` compressed hierarchically with these options; `None`: dense.
    pub compression: Option<HOptions>,
    /// Shard `(I, N)`, 1-based; `(1, 1)`: the whole.
    pub shard: (usize, usize),
    /// Where the file goes.
    pub out: Destination<'a>,
}

impl Job<'_> {
    /// The key the file is written under ([`cache::key_for`]).
    pub fn key(&self) -> u64 {
        cache::key_for(self.mesh, self.selection, self.compression.as_ref())
    }

    /// The file the job writes (for a key from [`Job::key`]).
    pub fn file(&self, key: u64) -> PathBuf {
        match self.out {
            Destination::File(f) => f.to_path_buf(),
            Destination::Dir(d) => cache::shard_file(cache::file_in(d, self.name, key), self.shard),
        }
    }
}

/// What one [`precompute`] made.
#[derive(Debug)]
pub struct Outcome {
    /// The file written, the sizes, times and residual.
    pub report: Report,
    /// The key the file was written under.
    pub key: u64,
    /// The hierarchical `L` written, for a complete (unsharded) compressed precompute.
    hier: Option<HMatrix>,
}

impl Outcome {
    /// The hierarchical `L` the file holds, for a complete compressed precompute (`None` for a
    /// dense file or a shard): what the GPU's byte count is computed from, without reading the
    /// file again.
    pub fn hier(&self) -> Option<&HMatrix> {
        self.hier.as_ref()
    }
}

/// Runs `job`: picks the key ([`Job::key`]), names the file ([`Job::file`]), computes the
/// compliance (or the shard's part of it) into it and reports what it wrote.
/// `progress(columns done, columns in this shard)`. A dense precompute keeps its finished
/// batches in `OUT.partial` when `stop` is set, and continues from them when run again
/// ([`precompute_to_file`]); a compressed one is not resumable.
pub fn precompute(
    job: &Job<'_>,
    progress: &mut dyn FnMut(usize, usize),
    stop: &AtomicBool,
) -> Result<Outcome, Error> {
    let key = job.key();
    let out = job.file(key);
    let (mesh, sel, shard) = (job.mesh, job.selection, job.shard);
    let Some(opts) = &job.compression else {
        let report = precompute_until(mesh, sel, &out, shard, progress, &|_| {
            stop.load(Ordering::Relaxed)
        })?;
        return Ok(Outcome {
            report,
            key,
            hier: None,
        });
    };
    let (report, parts) = hier_to_file(mesh, sel, opts, key, &out, shard, progress)?;
    let hier = if shard.1 == 1 {
        Some(HMatrix::from_panels(parts.plan, parts.panels)?)
    } else {
        None
    };
    Ok(Outcome { report, key, hier })
}

/// What one precompute wrote.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Report {
    /// The file written.
    pub file: PathBuf,
    /// Wall time, s.
    pub seconds: f64,
    /// Displayed nodes R.
    pub rows: usize,
    /// Touchable nodes C (all of them; a shard holds `col_end − col_begin`).
    pub cols: usize,
    /// First column held (compressed: 0).
    pub col_begin: usize,
    /// One past the last column held (compressed: the number of columns its panels hold,
    /// which are not a contiguous run of column indices).
    pub col_end: usize,
    /// The compression tolerance ε; `None` (JSON `null`) for a dense file.
    pub tolerance: Option<f64>,
    /// Compressed: the panels held, `[begin, end, total]`; `None` for a dense file.
    pub panels: Option<[usize; 3]>,
    /// Bytes of the file.
    pub bytes: u64,
    /// max |K·x − e| over the checked columns.
    pub residual: f64,
    /// Where the time went.
    pub phases: PhaseTimes,
}

/// Where an interrupted precompute of `out` keeps its finished batches.
pub fn partial_path(out: &Path) -> PathBuf {
    let mut s = out.as_os_str().to_os_string();
    s.push(".partial");
    PathBuf::from(s)
}

/// Precomputes the columns of shard `shard` = (I, N) (1-based; `(1, 1)`: all) of `mesh`'s
/// compliance for `sel` into `out`, streaming each solved batch into the file.
/// `progress(columns done, columns in this shard)`. If `OUT.partial` holds an interrupted run
/// of the same work, its finished batches are kept and only the rest is solved.
/// Setting `stop` (from a signal handler, say) stops the run after the batches in flight.
pub fn precompute_to_file(
    mesh: &Mesh,
    sel: &Selection,
    out: &Path,
    shard: (usize, usize),
    progress: &mut dyn FnMut(usize, usize),
    stop: &AtomicBool,
) -> Result<Report, Error> {
    precompute_to_file_with(mesh, sel, None, out, shard, progress, stop)
}

/// As [`precompute_to_file`]; with `compression`, `L` is built hierarchically to its tolerance
/// ([`Compliance::compute_hier_parts`]) and written as a compressed (version 4) file whose key
/// is [`cache::key_hier`]: shard `(I, N)` holds the panels [`crate::compliance::shard_panels`]
/// gives it, and [`cache::merge`] joins the shards into a file equal byte for byte to the
/// unsharded one. A compressed precompute is not resumable: `stop` is not consulted (the
/// caller may simply end the process; the file is written atomically, so nothing half-written
/// is left under its name).
pub fn precompute_to_file_with(
    mesh: &Mesh,
    sel: &Selection,
    compression: Option<&HOptions>,
    out: &Path,
    shard: (usize, usize),
    progress: &mut dyn FnMut(usize, usize),
    stop: &AtomicBool,
) -> Result<Report, Error> {
    let job = Job {
        name: "",
        mesh,
        selection: sel,
        compression: compression.copied(),
        shard,
        out: Destination::File(out),
    };
    Ok(precompute(&job, progress, stop)?.report)
}

/// The compressed precompute of shard `shard` into `out` under `key`: the report and the
/// parts written.
fn hier_to_file(
    mesh: &Mesh,
    sel: &Selection,
    opts: &HOptions,
    key: u64,
    out: &Path,
    shard: (usize, usize),
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(Report, HierParts), Error> {
    let t0 = Stopwatch::start();
    if shard.0 == 0 || shard.0 > shard.1 {
        return Err(Error::Input(format!(
            "shard {} of {}: expected 1 <= I <= N",
            shard.0, shard.1
        )));
    }
    let parts = Compliance::compute_hier_parts(
        mesh,
        sel,
        crate::compliance::method(),
        &crate::compliance::factor_store(),
        opts,
        shard,
        progress,
    )?;
    let ts = Stopwatch::start();
    let bytes = cache::hier::write_parts(out, &parts, key, mesh.nodes.len(), shard)?;
    let mut phases = parts.stats.phases.clone();
    phases.sync_s = ts.elapsed().as_secs_f64();
    let range = crate::compliance::shard_panels(parts.plan.panels(), shard.0, shard.1);
    let held: usize = range.clone().map(|p| parts.plan.panel_cols(p).len()).sum();
    let report = Report {
        file: out.to_path_buf(),
        seconds: t0.elapsed().as_secs_f64(),
        rows: parts.rows.len(),
        cols: parts.cols.len(),
        col_begin: 0,
        col_end: held,
        tolerance: Some(opts.tolerance),
        panels: Some([range.start, range.end, parts.plan.panels()]),
        bytes,
        residual: parts.stats.residual,
        phases,
    };
    Ok((report, parts))
}

/// As [`precompute_to_file`]; `stop(batches written)` is asked after each batch, and `true`
/// stops the run: the finished batches are kept in `OUT.partial` and
/// [`Error::Interrupted`] is returned.
pub fn precompute_until(
    mesh: &Mesh,
    sel: &Selection,
    out: &Path,
    shard: (usize, usize),
    progress: &mut dyn FnMut(usize, usize),
    stop: &(dyn Fn(usize) -> bool + Sync),
) -> Result<Report, Error> {
    let t0 = Stopwatch::start();
    let key = cache::key(mesh, sel);
    let mut plan = ColumnPlan::new(mesh, sel)?;
    let nc = plan.cols.len();
    let nr = plan.rows.len();
    let range = cache::shard_batches(plan.batches(), shard.0, shard.1);
    let col_begin = (range.start * BATCH_COLS).min(nc);
    let col_end = (range.end * BATCH_COLS).min(nc);
    // A symmetric plan computes each batch's rows below its first column (and above the
    // shard) and mirrors the rest from the shard's earlier batches (see below).
    let mirrored = plan.mirror_from(col_begin);
    let head = Header {
        n_nodes: mesh.nodes.len() as u32,
        rows: nr as u32,
        cols: nc as u32,
        batch: BATCH_COLS as u32,
        key,
        shard_index: shard.0 as u32,
        shard_count: shard.1 as u32,
        col_begin: col_begin as u32,
        col_end: col_end as u32,
        free_dofs: plan.free_dofs() as u32,
        l_rows: plan.l_rows as u32,
        residual_bits: 0,
    };
    let partial = partial_path(out);
    let (mut writer, done, old_residual) = match Writer::resume(out, &partial, &head)? {
        Some(w) => w,
        None => (
            Writer::create(out, head, &plan.rows, &plan.cols)?,
            vec![false; range.len()],
            0.0,
        ),
    };
    let todo: Vec<usize> = range.clone().filter(|&b| !done[b - range.start]).collect();
    let failed: std::sync::Mutex<Option<CacheError>> = std::sync::Mutex::new(None);
    let written = std::sync::atomic::AtomicUsize::new(done.iter().filter(|&&d| d).count());
    let stopped = AtomicBool::new(false);
    let total = col_end - col_begin;
    let already: usize = range
        .clone()
        .filter(|&b| done[b - range.start])
        .map(|b| plan.batch_cols(b).len())
        .sum();
    // A symmetric plan's batch waits for the shard's earlier batches, fills its upper rows
    // from their lower rows in the file and is written whole, once. Workers take the batches
    // in order, so the batches waited for are written or being solved.
    let complete = std::sync::Mutex::new(done.clone());
    let written_cv = std::sync::Condvar::new();
    let halt = AtomicBool::new(false);
    let mirror_ns = std::sync::atomic::AtomicU64::new(0);
    let fail = |e: CacheError| {
        *failed.lock().unwrap_or_else(|e| e.into_inner()) = Some(e);
        false
    };
    let base = 3 * range.start * BATCH_COLS;
    let (residual, t) = plan.solve_until(
        &todo,
        &|b, data| {
            let i = b - range.start;
            let result = if mirrored {
                let mut g = complete.lock().unwrap_or_else(|e| e.into_inner());
                while !g[..i].iter().all(|&d| d) {
                    if halt.load(Ordering::Relaxed) {
                        return false;
                    }
                    g = written_cv
                        .wait_timeout(g, std::time::Duration::from_millis(20))
                        .unwrap_or_else(|e| e.into_inner())
                        .0;
                }
                drop(g);
                let tm = Stopwatch::start();
                let r = plan
                    .mirror(b, data, &mut |q, r0, out| {
                        writer.read_column(q - base, r0, out)
                    })
                    .and_then(|_| writer.write_batch(i, data));
                mirror_ns.fetch_add(tm.elapsed().as_nanos() as u64, Ordering::Relaxed);
                r
            } else {
                writer.write_batch(i, data)
            };
            if let Err(e) = result {
                return fail(e);
            }
            complete.lock().unwrap_or_else(|e| e.into_inner())[i] = true;
            written_cv.notify_all();
            let w = written.fetch_add(1, Ordering::Relaxed) + 1;
            if stop(w) {
                stopped.store(true, Ordering::Relaxed);
                return false;
            }
            true
        },
        &mut |d| progress(already + d, total),
        &halt,
    )?;
    let mirror_s = mirror_ns.load(Ordering::Relaxed) as f64 * 1e-9;
    if let Some(e) = failed.into_inner().unwrap_or_else(|e| e.into_inner()) {
        return Err(e.into());
    }
    let residual = residual.max(old_residual);
    writer.set_residual(residual);
    if stopped.load(Ordering::Relaxed) {
        writer.keep_partial(&partial)?;
        return Err(Error::Interrupted {
            partial,
            done: written.load(Ordering::Relaxed),
            total: range.len(),
        });
    }
    progress(total, total);
    let ts = Stopwatch::start();
    let bytes = writer.finish()?;
    let sync_s = ts.elapsed().as_secs_f64();
    let mut phases = plan.phases.clone();
    phases.solve_s = t[0];
    phases.check_s = t[1];
    phases.scatter_s = t[2];
    phases.mirror_s = mirror_s;
    phases.sync_s = sync_s;
    Ok(Report {
        file: out.to_path_buf(),
        seconds: t0.elapsed().as_secs_f64(),
        rows: nr,
        cols: nc,
        col_begin,
        col_end,
        tolerance: None,
        panels: None,
        bytes,
        residual,
        phases,
    })
}
