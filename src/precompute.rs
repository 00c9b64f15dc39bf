//! `touchfem precompute`: the compliance a scene needs, streamed batch by batch into a cache
//! file (never the whole L in memory), optionally one shard of the columns at a time so that
//! several machines share the work, and the merge of the shards.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::cache::{self, CacheError, Header, Writer};
use crate::cli::PrecomputeArgs;
use crate::compliance::{ColumnPlan, PhaseTimes, Selection, BATCH_COLS};
use crate::scene::file::{cache_dir, cache_file, PlannedObject};
use crate::scene::{load_mesh, SceneSource, World};
use crate::{Error, Mesh};

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
    /// First column held.
    pub col_begin: usize,
    /// One past the last column held.
    pub col_end: usize,
    /// Bytes of the file.
    pub bytes: u64,
    /// max |K·x − e| over the checked columns.
    pub residual: f64,
    /// Where the time went.
    pub phases: PhaseTimes,
}

/// Set by SIGINT/SIGTERM during `touchfem precompute`: the batches in flight finish, the rest
/// wait for a resume.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::Relaxed);
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
pub fn precompute_to_file(
    mesh: &Mesh,
    sel: &Selection,
    out: &Path,
    shard: (usize, usize),
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Report, Error> {
    precompute_until(mesh, sel, out, shard, progress, &|_| {
        INTERRUPTED.load(Ordering::Relaxed)
    })
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
    let t0 = Instant::now();
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
                let tm = Instant::now();
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
    let ts = Instant::now();
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
        bytes,
        residual,
        phases,
    })
}

/// The objects `spec` names: a scene's objects, or one mesh (loaded with `args.load`).
fn objects(args: &PrecomputeArgs, spec: &str) -> Result<Vec<PlannedObject>, Error> {
    if let Some(src) = SceneSource::find(spec)? {
        return World::plan(&src);
    }
    let (mesh, _) = load_mesh(spec, &args.load.options())?;
    let selection = Selection::default();
    let key = cache::key(&mesh, &selection);
    let name = Path::new(spec)
        .file_stem()
        .map_or(spec.into(), |s| s.to_string_lossy().into_owned());
    Ok(vec![PlannedObject {
        name,
        mesh,
        selection,
        key,
    }])
}

/// `touchfem precompute`. Ctrl-C (or SIGTERM) keeps the finished batches in `OUT.partial`;
/// the same command again resumes from them.
pub fn command(args: &PrecomputeArgs) -> Result<(), Error> {
    let t0 = Instant::now();
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        let h = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::signal(libc::SIGINT, h);
        libc::signal(libc::SIGTERM, h);
    }
    if !args.merge.is_empty() {
        let out = args
            .out
            .as_ref()
            .ok_or_else(|| Error::Input("--merge needs --out FILE".into()))?;
        let m = cache::merge(&args.merge, out)?;
        let seconds = t0.elapsed().as_secs_f64();
        if args.json {
            println!(
                "{}",
                serde_json::json!({
                    "seconds": seconds, "rows": m.rows, "cols": m.cols, "bytes": m.bytes,
                    "parts": args.merge.len(), "file": out,
                })
            );
        } else {
            println!(
                "merged {} parts into {} ({} rows × {} columns, {} bytes) in {seconds:.2} s",
                args.merge.len(),
                out.display(),
                m.rows,
                m.cols,
                m.bytes
            );
        }
        return Ok(());
    }
    let spec = args
        .scene
        .as_deref()
        .ok_or_else(|| Error::Input("name a scene or mesh (or --merge PART...)".into()))?;
    let objs = objects(args, spec)?;
    let shard = args.shard.unwrap_or((1, 1));
    let suffix = |p: PathBuf| -> PathBuf {
        if shard.1 == 1 {
            return p;
        }
        let mut s = p.into_os_string();
        s.push(format!(".part-{}-of-{}", shard.0, shard.1));
        PathBuf::from(s)
    };
    let mut reports = Vec::new();
    for o in &objs {
        let out = match (&args.out, objs.len()) {
            (Some(f), 1) => f.clone(),
            (Some(dir), _) => suffix(cache_file(dir, &o.name, o.key)),
            (None, _) => {
                let dir = cache_dir().ok_or_else(|| {
                    Error::Input(
                        "caching is off (TOUCHFEM_CACHE_DIR is empty): give --out FILE".into(),
                    )
                })?;
                suffix(cache_file(&dir, &o.name, o.key))
            }
        };
        let bar = progress_bar(o.mesh.nodes.len());
        let r = precompute_to_file(&o.mesh, &o.selection, &out, shard, &mut |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        })?;
        bar.finish_and_clear();
        if !args.json {
            println!(
                "{}: {} rows × columns {}..{} of {} in {:.2} s ({:.0} MB) -> {}",
                o.name,
                r.rows,
                r.col_begin,
                r.col_end,
                r.cols,
                r.seconds,
                r.bytes as f64 / 1e6,
                r.file.display()
            );
        }
        reports.push(r);
    }
    if args.json {
        let v = serde_json::json!({
            "seconds": t0.elapsed().as_secs_f64(),
            "rows": reports.iter().map(|r| r.rows).sum::<usize>(),
            "cols": reports.iter().map(|r| r.cols).sum::<usize>(),
            "bytes": reports.iter().map(|r| r.bytes).sum::<u64>(),
            "shard": [shard.0, shard.1],
            "objects": reports,
            "units": {"seconds": "s", "bytes": "B"},
        });
        println!("{v}");
    }
    Ok(())
}

/// A progress bar with an ETA on a terminal for large meshes; hidden otherwise.
fn progress_bar(nodes: usize) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    let bar = if std::io::stderr().is_terminal() && nodes > 5000 {
        indicatif::ProgressBar::new(0)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "precompute {bar:40} {pos}/{len} columns, {elapsed} elapsed, ETA {eta}",
        )
        .expect("valid template"),
    );
    bar
}
