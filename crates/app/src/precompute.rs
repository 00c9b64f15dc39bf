//! `touchfem precompute`: a scene's or mesh's compliance into cache files, with a progress bar,
//! shards and merging; Ctrl-C keeps the finished batches for a resume (dense only: a compressed
//! precompute, `--tolerance`, is not resumable and Ctrl-C ends it).

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::error::Error;
use touchfem_core::cache;
use touchfem_core::compliance::hmatrix::HOptions;
use touchfem_core::compliance::Selection;
use touchfem_core::precompute::{precompute, Destination, Job};
use touchfem_core::scene::file::{cache_dir, PlannedObject};
use touchfem_core::scene::{SceneSource, World};

use crate::args::PrecomputeArgs;

/// Set by SIGINT/SIGTERM during `touchfem precompute`: the batches in flight finish, the rest
/// wait for a resume.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::Relaxed);
}

/// The objects `spec` names: a scene's objects, or one mesh (loaded with `args.load`).
fn objects(args: &PrecomputeArgs, spec: &str) -> Result<Vec<PlannedObject>, Error> {
    if let Some(src) = SceneSource::find(spec)? {
        return Ok(World::plan(&src)?);
    }
    let (mesh, _) = args.load.load(spec)?;
    let selection = Selection::default();
    let key = cache::key(&mesh, &selection);
    let name = Path::new(spec)
        .file_stem()
        .map_or(spec.into(), |s| s.to_string_lossy().into_owned());
    Ok(vec![PlannedObject {
        name,
        mesh,
        selection,
        compression: None,
        key,
    }])
}

/// `touchfem precompute`. Ctrl-C (or SIGTERM) keeps the finished batches in `OUT.partial`;
/// the same command again resumes from them.
pub fn command(args: &PrecomputeArgs) -> Result<(), Error> {
    let t0 = Instant::now();
    let compression = args.tolerance.map(HOptions::new);
    // A compressed precompute is not resumable: Ctrl-C ends it as usual (its file is written
    // atomically, so nothing half-written is left under the name).
    if compression.is_none() {
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
        unsafe {
            let h = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            libc::signal(libc::SIGINT, h);
            libc::signal(libc::SIGTERM, h);
        }
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
                    "tolerance": m.tolerance, "parts": args.merge.len(), "file": out,
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
    // `--out`: the file of a single object, else the directory of several; no `--out`: the
    // cache directory.
    let out = match &args.out {
        Some(f) => f.clone(),
        None => cache_dir().ok_or_else(|| {
            Error::Input("caching is off (TOUCHFEM_CACHE_DIR is empty): give --out FILE".into())
        })?,
    };
    let mut reports = Vec::new();
    let mut gpu: Vec<(u64, u64)> = Vec::new();
    for o in &objs {
        let out = match (&args.out, objs.len()) {
            (Some(_), 1) => Destination::File(&out),
            _ => Destination::Dir(&out),
        };
        let job = Job {
            name: &o.name,
            mesh: &o.mesh,
            selection: &o.selection,
            // `--tolerance`, else the scene's `compression`.
            compression: compression.or(o.compression),
            shard,
            out,
        };
        let bar = progress_bar(o.mesh.nodes.len());
        let done = precompute(
            &job,
            &mut |done, total| {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            },
            &INTERRUPTED,
        )?;
        bar.finish_and_clear();
        // What the GPU will hold for L (a whole file only): the compressed layout against
        // dense f32.
        if let Some(h) = done.hier() {
            gpu.push((
                touchfem_gpu::hier_gpu_bytes(h, false),
                4 * h.dense_values() as u64,
            ));
        }
        let r = done.report;
        if let (false, Some([p0, p1, np]), Some(eps)) = (args.json, r.panels, r.tolerance) {
            println!(
                "{}: {} rows × {} columns compressed to {eps:e}, panels {p0}..{p1} of {np}, in {:.2} s ({:.1} MB) -> {}",
                o.name,
                r.rows,
                r.cols,
                r.seconds,
                r.bytes as f64 / 1e6,
                r.file.display()
            );
        } else if !args.json {
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
            "tolerance": reports.iter().find_map(|r| r.tolerance),
            "gpu_bytes": (!gpu.is_empty()).then(|| gpu.iter().map(|g| g.0).sum::<u64>()),
            "dense_gpu_bytes": (!gpu.is_empty()).then(|| gpu.iter().map(|g| g.1).sum::<u64>()),
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
