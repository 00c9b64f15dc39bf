//! The `touchfem` command line: each subcommand (flags in [`crate::args`]; the stable ones are
//! in the reference, `docs/reference/cli.md`).

use crate::args::*;
use glam::DVec3;

use touchfem_core::compliance::Selection;
use touchfem_core::contact::force::ForceModel;
use touchfem_core::scene::Body;

use crate::error::Error;

/// Runs the command line; returns the process exit code.
pub fn run(cli: Cli) -> Result<(), Error> {
    let window = matches!(cli.command, Command::View(_));
    let no_wayland = ["XDG_RUNTIME_DIR", "WAYLAND_DISPLAY"]
        .iter()
        .all(|v| std::env::var_os(v).is_none_or(|s| s.is_empty()));
    if !window || no_wayland {
        headless_vulkan();
    }
    match cli.command {
        Command::Info {
            mesh,
            load,
            tool,
            json,
            tolerance,
        } => info(&mesh, &load, &tool, json, tolerance),
        Command::Poke(args) => poke(&args),
        Command::Demo(args) => demo(&args),
        Command::Replay(args) => replay(&args),
        Command::Serve(args) => serve(&args),
        Command::Bench(args) => bench(&args),
        Command::View(args) => crate::window::view_command(&args),
        Command::Precompute(args) => crate::precompute::command(&args),
    }
}

/// Every command but `view` draws offscreen: no window system is involved. Mesa's implicit
/// Vulkan layer `VK_LAYER_MESA_device_select` nevertheless probes the window systems while the
/// adapters are enumerated (wgpu enables the Wayland, Xlib and XCB surface extensions on every
/// instance), to put the GPU that drives the display first; without `XDG_RUNTIME_DIR`
/// libwayland prints `error: XDG_RUNTIME_DIR is invalid or not set in the environment.` twice,
/// on every run. Offscreen there is no display whose GPU to prefer, and wgpu chooses the
/// adapter itself (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`, `WGPU_POWER_PREF`), so the layer is
/// turned off with its own switch, `NODEVICE_SELECT=1` — unless the user set it, or asked the
/// layer for a device with `MESA_VK_DEVICE_SELECT`. The `view` window does the same when no
/// Wayland session can be reached (neither `XDG_RUNTIME_DIR` nor `WAYLAND_DISPLAY` set: the
/// probe could only complain); its adapter is then the one wgpu finds able to present to the
/// window's surface. Nothing is filtered: a real adapter error is still reported. Call before
/// any thread is spawned.
fn headless_vulkan() {
    if std::env::var_os("NODEVICE_SELECT").is_none()
        && std::env::var_os("MESA_VK_DEVICE_SELECT").is_none()
    {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
}

/// The visual loop and lavapipe (software Vulkan) share one core and the haptic loop has
/// another: with `LP_NUM_THREADS=0` lavapipe runs compute and rasterisation on its queue thread
/// (no worker pool to wake), and that thread starts on the visual core because the context is
/// made while this thread is pinned there (`Gpu::new_headless_placed`, `threads`). Measured on
/// the 2-core development VM: mouse displacement in the demo 0.50 → 0.20 ms. A value the user
/// set is kept. Call before any thread is spawned.
fn lavapipe_inline() {
    if std::env::var_os("LP_NUM_THREADS").is_none() {
        std::env::set_var("LP_NUM_THREADS", "0");
    }
}

/// The GPU the benchmarks time (lavapipe inline, on the visual thread's placement, returned
/// with it), or `None` with a warning saying which rows are left out.
fn bench_gpu(
    without: &str,
) -> (
    Option<touchfem_gpu::Gpu>,
    touchfem_core::threads::VisualPlacement,
) {
    lavapipe_inline();
    let placement = touchfem_core::threads::VisualPlacement::split();
    let gpu = match touchfem_gpu::Gpu::new_headless_placed(&placement) {
        Ok(g) => Some(g),
        Err(e) => {
            eprintln!("warning: {e}; {without}");
            None
        }
    };
    (gpu, placement)
}

fn bench(a: &BenchArgs) -> Result<(), Error> {
    use touchfem_lab::tradeoff::{bench_scenes, cpu_rows};
    if a.hard {
        print!("{}", touchfem_lab::hard::bench(a.json.as_deref())?);
        return Ok(());
    }
    if a.ladder {
        let cells: &[usize] = if a.quick {
            &[4, 8, 16]
        } else {
            &[4, 8, 16, 32]
        };
        print!(
            "{}",
            touchfem_lab::ladder::bench(cells, &a.ladder_dir, a.json.as_deref())?
        );
        return Ok(());
    }
    if a.cut {
        let (gpu, _) = bench_gpu("no GPU rows");
        print!(
            "{}",
            touchfem_lab::cutting::bench(
                gpu.as_ref(),
                a.quick,
                a.json.as_deref(),
                a.scene.as_deref()
            )?
        );
        return Ok(());
    }
    let (reps, active): (usize, &[usize]) = if a.quick {
        (20, &[9])
    } else {
        (200, &[3, 9, 40, 90, 900])
    };
    let (gpu, placement) = bench_gpu("no gpu-f32-* rows");
    let mut rows = Vec::new();
    let mut scene_table = Vec::new();
    let mut scenes = bench_scenes()?;
    if let Some(spec) = &a.scene {
        let (r, mut t, s) = touchfem_lab::tradeoff::scene_objects(spec)?;
        if let Some(g) = &gpu {
            // One live frame per object: a contact triangle's deformation and the draw.
            placement.enter_visual();
            for (row, (_, scene)) in t.iter_mut().zip(&s) {
                let ms = touchfem_lab::tradeoff::frame_ms(scene, g, reps);
                row["frame_ms"] = serde_json::json!(ms.as_ref().ok().copied().flatten());
                if let Err(e) = ms {
                    eprintln!("warning: frame: {e}");
                }
            }
            placement.leave();
        }
        rows.extend(r);
        scene_table = t;
        scenes.extend(s);
    }
    let tolerances: Vec<f64> = match (a.tolerance, a.quick) {
        (Some(eps), _) => vec![eps],
        (None, true) => vec![1e-3],
        (None, false) => vec![1e-2, 1e-3, 1e-4, 1e-6],
    };
    let mut hier_table = Vec::new();
    for (name, scene) in scenes {
        rows.extend(cpu_rows(&name, &scene, active, reps)?);
        // The hierarchical L where it has far blocks (more than two leaves of nodes).
        if scene.compliance.rows().len() > 500 {
            placement.enter_visual();
            let t = touchfem_lab::hmatrix_study::bench_rows(
                &name,
                &scene,
                &tolerances,
                reps.min(50),
                gpu.as_ref(),
            );
            placement.leave();
            let t = t?;
            rows.extend(touchfem_lab::hmatrix_study::tradeoff_of(
                &t,
                scene.mesh.nodes.len(),
            ));
            hier_table.extend(t);
        }
        if let Some(g) = &gpu {
            // Submit from the core the driver's threads started on (as the demo does).
            placement.enter_visual();
            let gpu_rows = touchfem_lab::tradeoff::gpu_rows(&name, &scene, g, active, reps);
            placement.leave();
            rows.extend(gpu_rows?);
        }
    }
    println!(
        "{:<18} {:<6} {:>6} {:>7} {:>12} {:>11}",
        "method", "mesh", "nodes", "active", "time_us", "rel_error"
    );
    for r in &rows {
        println!(
            "{:<18} {:<6} {:>6} {:>7} {:>12.3} {:>11.2e}",
            r.method, r.mesh, r.nodes, r.active_columns, r.time_us, r.rel_error
        );
    }
    for t in &scene_table {
        println!(
            "{}: {} nodes, {} surface / {} free surface, {} rows × {} cols: precompute {:.2} s, L {:.0} MB (f64, host), peak RSS {:.2} GB, frame {}",
            t["object"].as_str().unwrap_or("?"),
            t["nodes"],
            t["surface_nodes"],
            t["free_surface_nodes"],
            t["rows"],
            t["cols"],
            t["precompute_s"].as_f64().unwrap_or(0.0),
            t["bytes_l"].as_f64().unwrap_or(0.0) / 1e6,
            t["peak_rss_bytes"].as_f64().unwrap_or(0.0) / 1e9,
            match t["frame_ms"].as_f64() {
                Some(ms) => format!(
                    "{ms:.1} ms ({}×{}, one contact triangle: deform + draw)",
                    touchfem_lab::tradeoff::FRAME_SIZE[0],
                    touchfem_lab::tradeoff::FRAME_SIZE[1]
                ),
                None => "-".into(),
            },
        );
    }
    if !hier_table.is_empty() {
        println!(
            "{:<8} {:>7} {:>10} {:>10} {:>6} {:>10} {:>10} {:>10} {:>10} {:>10}",
            "mesh",
            "eps",
            "gpu_MB",
            "dense_MB",
            "ratio",
            "l2_median",
            "l2_worst",
            "near_clamp",
            "gpu_us",
            "dense_us"
        );
        for r in &hier_table {
            let us = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.0}"));
            println!(
                "{:<8} {:>7.0e} {:>10.2} {:>10.2} {:>6.3} {:>10.2e} {:>10.2e} {:>10} {:>10} {:>10}",
                r.h.mesh,
                r.h.tolerance,
                r.gpu_bytes as f64 / 1e6,
                r.dense_gpu_bytes as f64 / 1e6,
                r.gpu_ratio,
                r.h.l2_median,
                r.h.l2_worst,
                r.h.l2_worst_near_clamps
                    .map_or("-".into(), |v| format!("{v:.2e}")),
                us(r.gpu_pass_us),
                us(r.gpu_dense_pass_us),
            );
        }
    }
    // The answer a reader brings: the fastest method for one contact triangle (3 nodes) and
    // for about a hundred touched nodes, per mesh, from this run, among those within 1e-3 of
    // the exact displacement.
    let mut fastest = Vec::new();
    let mut seen: Vec<&str> = Vec::new();
    for r in &rows {
        if seen.contains(&r.mesh.as_str()) {
            continue;
        }
        seen.push(&r.mesh);
        let mut shown = Vec::new();
        for want in [3, 100] {
            if let Some(f) = touchfem_lab::tradeoff::fastest(&rows, &r.mesh, want, 1e-3) {
                if shown.contains(&f.active_columns) {
                    continue;
                }
                shown.push(f.active_columns);
                println!(
                    "fastest on {} for {} touched nodes (error <= 1e-3): {} ({:.1} µs, error {:.1e})",
                    f.mesh, f.active_columns, f.method, f.time_us, f.rel_error
                );
                fastest.push(serde_json::json!({
                    "mesh": f.mesh, "want": want, "active_columns": f.active_columns,
                    "method": f.method, "time_us": f.time_us, "rel_error": f.rel_error,
                }));
            }
        }
    }
    if let Some(path) = &a.plot {
        let mut meshes: Vec<&str> = Vec::new();
        for r in &rows {
            if r.mesh != "cube" && !meshes.contains(&r.mesh.as_str()) {
                meshes.push(&r.mesh);
            }
        }
        let memory: Vec<touchfem_lab::bench_plot::MemoryPoint> = hier_table
            .iter()
            .map(|r| touchfem_lab::bench_plot::MemoryPoint {
                mesh: r.h.mesh.clone(),
                tolerance: r.h.tolerance,
                error: r.h.l2_worst,
                gpu_bytes: r.gpu_bytes as f64,
                dense_gpu_bytes: r.dense_gpu_bytes as f64,
            })
            .collect();
        touchfem_lab::bench_plot::write_plot(path, &rows, &meshes, &memory)?;
    }
    if let Some(path) = &a.json {
        let v = serde_json::json!({
            "rows": rows,
            "scene": scene_table,
            "hierarchical": hier_table,
            "fastest": fastest,
            "machine": touchfem_lab::report::machine(),
        });
        touchfem_lab::tradeoff::write_json(path, &v)?;
    }
    Ok(())
}

fn serve(a: &ServeArgs) -> Result<(), Error> {
    use touchfem_core::runtime::serve::{serve, stop_on_interrupt, ServeOptions, INTERRUPTED};
    let Some(udp) = a.udp else {
        return crate::haply::cli::serve(a);
    };
    if let Some(s) = a.seconds {
        if !(s.is_finite() && s > 0.0) {
            return Err(Error::Input(format!("--seconds must be positive, got {s}")));
        }
    }
    if let Some(s) = a.floor_seconds {
        if !(s.is_finite() && (0.0..=3600.0).contains(&s)) {
            return Err(Error::Input(format!(
                "--floor-seconds must be between 0 and 3600, got {s}"
            )));
        }
    }
    if !(a.watchdog_ms.is_finite() && a.watchdog_ms > 0.0) {
        return Err(Error::Input(format!(
            "--watchdog-ms must be positive, got {}",
            a.watchdog_ms
        )));
    }
    let key = match &a.key {
        Some(p) => Some(
            touchfem_core::devices::udp::Key::from_file(p)
                .map_err(|e| Error::Input(format!("--key: {e}")))?,
        ),
        None => None,
    };
    let remote_ok = a.allow_remote && key.is_some();
    if !udp.ip().is_loopback() && !remote_ok {
        return Err(Error::Input(format!(
            "--udp {udp}: not a loopback address; serving beyond this machine needs --allow-remote and --key FILE"
        )));
    }
    if !udp.ip().is_loopback() {
        eprintln!(
            "warning: serving {udp} beyond this machine: anyone who can reach it drives forces into a person's hand"
        );
    }
    let limits = match &a.limits {
        Some(name) => Some(
            touchfem_core::devices::limits::DeviceLimits::named(name)
                .map_err(|e| Error::Input(format!("--limits: {e}")))?,
        ),
        None => None,
    };
    let world = touchfem_core::runtime::serve::udp_world(&a.scene, limits.as_ref())?;
    stop_on_interrupt();
    let opts = ServeOptions {
        addr: udp,
        allow_remote: a.allow_remote,
        key,
        seconds: a.seconds,
        record: a.record.clone(),
        watchdog: std::time::Duration::from_secs_f64(a.watchdog_ms * 1e-3),
        clock: a.clock,
        placement: touchfem_core::threads::VisualPlacement::split(),
        floor_seconds: a.floor_seconds,
    };
    let bound = |addr| eprintln!("listening on udp {addr}");
    let report = if a.view {
        crate::window::cli::serve_view(&world, &opts, &INTERRUPTED, a.size, bound)?
    } else {
        serve(&world, &opts, &INTERRUPTED, bound)?
    };
    crate::report::report_out(
        &report,
        a.report.as_deref(),
        report.run.recording_error.as_deref(),
    )
}

fn replay(a: &ReplayArgs) -> Result<(), Error> {
    use touchfem_core::runtime::session;
    let sess = session::read(&a.file)?;
    let h = &sess.header;
    if sess.ticks.is_empty() {
        return Err(Error::Session(format!(
            "{}: the session holds no tick ({} bytes after the header): nothing to replay",
            a.file.display(),
            sess.trailing_bytes
        )));
    }
    let world = session::world(
        &sess,
        &format!("the scene recorded in {}", a.file.display()),
    )?;
    let r = session::replay(&world, &sess)?;
    if a.json {
        let mut v = serde_json::to_value(&r).expect("serialisable");
        v["scene"] = serde_json::json!(h.scene_name);
        v["trailing_bytes"] = serde_json::json!(sess.trailing_bytes);
        println!("{v}");
    } else {
        println!(
            "replayed {} ticks of scene '{}': max |ΔF| = {:.3e} N (at tick {}), largest recorded force {:.4} N",
            r.ticks, h.scene_name, r.max_force_diff_n, r.worst_tick, r.max_force_n
        );
        if sess.trailing_bytes > 0 {
            eprintln!(
                "note: {} bytes at the end make no whole tick (the recording was cut off)",
                sess.trailing_bytes
            );
        }
    }
    // The contract: a non-finite difference (a NaN or infinite force, recorded or replayed)
    // fails the replay; the JSON above wrote it as f64::MAX, never null.
    if !r.max_force_diff_n.is_finite() {
        return Err(Error::Session(format!(
            "{}: {} tick(s) hold a non-finite force (recorded or replayed), the first at tick {}: the difference is infinite",
            a.file.display(),
            r.non_finite_ticks,
            r.worst_tick
        )));
    }
    Ok(())
}

fn demo(a: &DemoArgs) -> Result<(), Error> {
    use crate::demo::{record_path_for, run_scene, worst, DemoOptions, DemoReport};
    use touchfem_lab::report::machine;
    if !(a.seconds.is_finite() && a.seconds > 0.0 && a.seconds <= 3600.0) {
        return Err(Error::Input(format!(
            "--seconds must be in (0, 3600], got {}",
            a.seconds
        )));
    }
    let specs: Vec<String> = if a.scenes.is_empty() {
        touchfem_core::scene::BUNDLED_SCENES
            .iter()
            .map(|(n, _)| n.to_string())
            .collect()
    } else {
        a.scenes.clone()
    };
    // Load every scene first: a bad scene file fails before anything runs.
    let mut worlds = Vec::new();
    for spec in &specs {
        if touchfem_core::scene::SceneSource::find(spec)?.is_none() {
            return Err(Error::Body(format!(
                "'{spec}' is neither a bundled scene ({}) nor a .toml scene file",
                bundled_scene_names()
            )));
        }
        worlds.push(touchfem_core::scene::World::load(spec, "script")?);
    }
    std::fs::create_dir_all(&a.out).map_err(|source| Error::Write {
        path: a.out.clone(),
        source,
    })?;
    let placement = touchfem_core::threads::VisualPlacement::split();
    lavapipe_inline();
    let gpu = match touchfem_gpu::Gpu::new_headless_placed(&placement) {
        Ok(g) => Some(g),
        Err(e) => {
            eprintln!("warning: {e}; the visual loop falls back to the CPU and draws no frames");
            None
        }
    };
    let size = [480u32, 360u32];
    // A software adapter rasterises on the visual core: one sample, not 4× MSAA (the mouse:
    // ~5 ms against ~18 ms a frame on lavapipe).
    let renderer = match &gpu {
        Some(g) => Some(touchfem_gpu::render::Renderer::with_options(
            &g.device,
            size,
            touchfem_gpu::render::RenderOptions {
                samples: touchfem_gpu::render::live_samples(&g.adapter.get_info()),
                ..Default::default()
            },
        )?),
        None => None,
    };
    let mut objects: Vec<crate::demo::ObjectReport> = Vec::new();
    let mut floors = Vec::new();
    let mut haptics = Vec::new();
    for world in &worlds {
        let opts = DemoOptions {
            seconds: a.seconds,
            out: a.out.clone(),
            placement: placement.clone(),
            record: a
                .record
                .as_ref()
                .map(|r| record_path_for(r, &world.name, worlds.len() > 1)),
            size,
            displacement_colors: a.color == ColorArg::Displacement,
        };
        let rows = run_scene(world, &opts, gpu.as_ref(), renderer.as_ref())?;
        if let Some(r) = rows.first() {
            floors.push(r.floor.clone());
            haptics.push(r.haptic.clone());
            println!(
                "{:<6} haptic {:.1} Hz, p99.9 period error {:.1} µs, {} missed (floor: {:.1} µs, {} missed)",
                world.name,
                r.haptic.haptic_rate_hz,
                r.haptic.period_error_us_p999,
                r.haptic.missed_deadlines,
                r.floor.period_error_us_p999,
                r.floor.missed_deadlines
            );
        }
        for r in &rows {
            println!(
                "  {:<8} nodes {:>5}  rows {:>5} cols {:>5}  force {:>6.2} µs  displacement {:>8.1} µs ({})  draw {:>6.1} Hz  max contacts {}",
                r.name, r.nodes, r.rows, r.cols, r.force_us_median, r.displacement_us_median,
                r.displacement_backend, r.draw_hz, r.max_contacts
            );
        }
        objects.extend(rows);
    }
    let report = DemoReport {
        objects,
        haptic: worst(&haptics),
        floor: worst(&floors),
        machine: machine(),
    };
    let json = serde_json::to_string_pretty(&report).expect("serialisable");
    let path = a
        .report
        .clone()
        .unwrap_or_else(|| a.out.join("report.json"));
    std::fs::write(&path, json).map_err(|source| Error::Write {
        path: path.clone(),
        source,
    })?;
    println!("report: {}", path.display());
    Ok(())
}

fn info(
    spec: &str,
    load: &LoadArgs,
    tool: &ToolArgs,
    json: bool,
    tolerance: Option<f64>,
) -> Result<(), Error> {
    let (mesh, unit) = load.load(spec)?;
    let estimate = match tolerance {
        Some(eps) => Some(hier_estimate(&mesh, eps)?),
        None => None,
    };
    let sphere_m = match tool.sphere {
        Some(r) => Some(check_sphere_fits(r, &mesh, unit)?),
        None => None,
    };
    let t = mesh.table1();
    let cond = touchfem_core::compliance::conditioning::estimate(&mesh, 60)?;
    let (e32, e16) = touchfem_core::compliance::conditioning::predict_storage_error(&mesh)?;
    if let Some(w) = touchfem_core::compliance::conditioning::storage_warning(spec, e32, e16) {
        eprintln!("{w}");
    }
    if json {
        let mut v = serde_json::to_value(&t).expect("serialisable");
        v["condition_estimate"] = serde_json::json!(cond.condition_estimate);
        v["lambda_min"] = serde_json::json!(cond.lambda_min);
        v["lambda_max"] = serde_json::json!(cond.lambda_max);
        v["worst_quality"] = serde_json::json!(cond.worst_quality);
        v["f32_storage_error"] = serde_json::json!(e32);
        v["f16_storage_error"] = serde_json::json!(e16);
        v["unit"] = serde_json::json!(unit.symbol());
        v["formulation"] = serde_json::json!(mesh.formulation.name());
        v["fixed_nodes"] = serde_json::json!(mesh.fixed_count());
        v["reoriented_tets"] = serde_json::json!(mesh.report.reoriented_tets.len());
        v["dropped_nodes"] = serde_json::json!(mesh.report.dropped_nodes.len());
        v["regions"] = mesh
            .regions
            .iter()
            .map(|r| {
                serde_json::json!({
                    "group": r.group,
                    "tets": r.tets.len(),
                    "young": r.material.young_pa,
                    "poisson": r.material.poisson,
                })
            })
            .collect();
        if let Some(r) = sphere_m {
            v["sphere_m"] = serde_json::json!(r);
        }
        if let Some(fr) = tool.friction {
            v["friction"] = serde_json::json!([fr.static_mu, fr.dynamic_mu]);
        }
        if let Some(e) = &estimate {
            v["compression"] = serde_json::to_value(e).expect("serialisable");
        }
        println!("{v}");
    } else {
        println!("mesh                 {spec} (coordinates in {unit})");
        println!("all nodes            {}", t.nodes);
        println!("surface nodes        {}", t.surface_nodes);
        println!("free surface nodes   {}", t.free_surface_nodes);
        println!("surface patches      {}", t.surface_triangles);
        println!("tetrahedral elements {}", t.tets);
        println!("Young's modulus      {} Pa", t.young_pa);
        println!("Poisson's ratio      {}", t.poisson);
        for r in &mesh.regions {
            println!(
                "region {:<13} {} tets, E = {} Pa, nu = {}",
                r.group,
                r.tets.len(),
                r.material.young_pa,
                r.material.poisson
            );
        }
        println!("formulation          {}", mesh.formulation);
        println!(
            "condition of K       {:.2e} (eigenvalues {:.3e} … {:.3e} N/m, estimated)",
            cond.condition_estimate, cond.lambda_min, cond.lambda_max
        );
        println!(
            "worst element        quality {:.2e} (6V/l³; regular 0.707, refused at 1e-8)",
            cond.worst_quality
        );
        println!("storage error        f32 {e32:.1e}, f16 {e16:.1e} (of the largest displacement)");
        if let Some(r) = sphere_m {
            println!("sphere finger        R = {r} m (fits the object)");
        }
        if let Some(fr) = tool.friction {
            println!(
                "friction             static {}, dynamic {}",
                fr.static_mu, fr.dynamic_mu
            );
        }
        if let Some(e) = &estimate {
            println!(
                "hierarchical L       ~{:.1} MB on the GPU at tolerance {:e} (dense f32 {:.1} MB, \
                 {:.1}× smaller; estimated from {} blocks at mean rank {:.0})",
                e.gpu_bytes as f64 * 1e-6,
                e.tolerance,
                e.dense_gpu_bytes as f64 * 1e-6,
                e.dense_gpu_bytes as f64 / e.gpu_bytes.max(1) as f64,
                e.blocks,
                e.mean_rank
            );
        }
        report_changes(&mesh);
    }
    Ok(())
}

/// `info --tolerance`'s estimate of the hierarchical `L` (default selection: surface rows,
/// free-surface columns).
#[derive(serde::Serialize)]
struct HierEstimate {
    tolerance: f64,
    rows: usize,
    cols: usize,
    blocks: usize,
    mean_rank: f64,
    values: usize,
    gpu_bytes: usize,
    dense_gpu_bytes: usize,
    estimated: bool,
}

fn hier_estimate(mesh: &touchfem_core::Mesh, eps: f64) -> Result<HierEstimate, Error> {
    let opts = touchfem_core::compliance::hmatrix::HOptions::new(eps);
    let plan = touchfem_core::compliance::selection_plan(mesh, &Selection::default(), &opts)
        .map_err(touchfem_core::compliance::ComplianceError::from)?;
    let rank = touchfem_core::compliance::hmatrix::mean_rank_estimate(eps);
    let values = plan.estimate_values(rank);
    Ok(HierEstimate {
        tolerance: eps,
        rows: plan.rows(),
        cols: plan.cols(),
        blocks: plan.blocks(),
        mean_rank: rank,
        values,
        // f32 values and a 32-byte entry per block (the GPU's tables are about that).
        gpu_bytes: 4 * values + 32 * plan.blocks(),
        dense_gpu_bytes: 4 * plan.dense_values(),
        estimated: true,
    })
}

fn report_changes(mesh: &touchfem_core::Mesh) {
    if !mesh.report.reoriented_tets.is_empty() {
        eprintln!(
            "note: {} inverted tet(s) reoriented (first: {})",
            mesh.report.reoriented_tets.len(),
            mesh.report.reoriented_tets[0]
        );
    }
    if !mesh.report.dropped_nodes.is_empty() {
        eprintln!(
            "note: {} node(s) used by no tet dropped (first: {})",
            mesh.report.dropped_nodes.len(),
            mesh.report.dropped_nodes[0]
        );
    }
}

/// What a poke leaves behind for its outputs, whatever the finger.
struct PokeOutcome {
    /// The force fed back to the finger, N.
    feedback: DVec3,
    /// The force on the object: (column of `L`, N).
    forces: Vec<(u32, DVec3)>,
    /// Mesh nodes in contact at the end.
    contact_nodes: Vec<u32>,
    /// With `--slide`: per step, [s (m), fx, fy, fz (N)].
    trace: Option<Vec<[f64; 4]>>,
    /// For the picture: the finger's mark, the god-object (a point finger's), the arrow's
    /// start, and the contact's point and outward normal for `--view contact`.
    finger: DVec3,
    proxy: Option<DVec3>,
    arrow_at: DVec3,
    view: (DVec3, DVec3),
    /// A sphere's centre and radius (m), drawn at its size.
    sphere: Option<(DVec3, f64)>,
}

fn poke(a: &PokeArgs) -> Result<(), Error> {
    if let (Some(seg), Some(depth)) = (a.cut, a.depth) {
        return crate::cut_poke::poke_cut(a, seg, depth);
    }
    let (mesh, unit) = a.load.load(&a.mesh)?;
    if !a.json {
        report_changes(&mesh);
    }
    let s = unit.to_metres();
    let sphere_m = match a.sphere {
        Some(r) => Some(check_sphere_fits(r, &mesh, unit)?),
        None => None,
    };
    check_motion("--push", a.push, &mesh, unit)?;
    if let Some(d) = a.slide {
        check_motion("--slide", d, &mesh, unit)?;
    }
    let sel = Selection::default();
    let compliance = match &a.cache {
        Some(path) => {
            // `--tolerance`, else a compressed file's own options: a compressed cache is read
            // as a dense one is, kept compressed when recomputed, and never rewritten dense.
            let compression = a
                .tolerance
                .map(touchfem_core::compliance::hmatrix::HOptions::new);
            let (c, outcome) = touchfem_core::cache::load_or_compute_file(
                path,
                &mesh,
                &sel,
                compression.as_ref(),
            )?;
            if let Some(m) = outcome.message() {
                eprintln!("{m}");
            }
            c
        }
        None => precompute_with_bar(&mesh, &sel, a.tolerance)?,
    };
    let scene = Body::with_compliance(mesh, compliance);
    let st = &scene.compliance.stats;
    let model = if a.exact {
        ForceModel::Exact
    } else {
        ForceModel::Paper
    };
    let slide = a.slide.map(|d| (d * s, a.steps));
    let (at, push) = (a.at * s, a.push * s);
    let mut json = serde_json::Map::new();
    let mut text = Vec::new();
    let out = match sphere_m {
        Some(r) => {
            let sp = scene.poke_sphere(at, push, r, a.friction, slide)?;
            let normal = (sp.start_centre - sp.touch_point) / r;
            let bottom = sp.centre - normal * r;
            let rep = sp.report;
            if rep.exhausted || rep.overflow {
                eprintln!(
                    "warning: --sphere: the contact problem {} (max penetration {:.3e} m)",
                    if rep.overflow {
                        "touched more nodes than it holds; the nearest were kept"
                    } else {
                        "ran out of its budget"
                    },
                    rep.max_penetration
                );
            }
            json.insert("sphere_m".into(), r.into());
            json.insert("touch_point".into(), sp.touch_point.to_array().into());
            json.insert("start_centre".into(), sp.start_centre.to_array().into());
            json.insert("centre".into(), sp.centre.to_array().into());
            json.insert(
                "patch".into(),
                serde_json::json!({
                    "contacts": rep.contacts,
                    "slipping": rep.slipping,
                    "pivots": rep.pivots,
                    "exhausted": rep.exhausted,
                    "overflow": rep.overflow,
                    "max_penetration": rep.max_penetration,
                }),
            );
            text.push(format!(
                "sphere: R = {} mm, {} node(s) in contact ({} slipping)",
                touchfem_gpu::render::format_significant(r * 1e3, 6),
                sp.contact_nodes.len(),
                rep.slipping
            ));
            PokeOutcome {
                feedback: sp.feedback,
                forces: sp.forces,
                contact_nodes: sp.contact_nodes,
                trace: slide.map(|_| sp.trace),
                finger: bottom,
                proxy: None,
                arrow_at: bottom,
                view: (sp.touch_point, normal),
                sphere: Some((sp.centre, r)),
            }
        }
        None => {
            let (p, trace) = if a.friction.is_none() && a.slide.is_none() {
                (scene.poke(at, push, model, a.steps)?, None)
            } else {
                let (p, t) = scene.poke_slide(at, push, model, a.friction, slide, a.steps)?;
                (p, slide.map(|_| t))
            };
            let diff = (p.feedback_paper - p.feedback_exact).length();
            let finger = p.touch_point + push + slide.map_or(DVec3::ZERO, |(d, _)| d);
            json.insert(
                "model".into(),
                (if a.exact { "exact" } else { "paper" }).into(),
            );
            json.insert("force_paper".into(), p.feedback_paper.to_array().into());
            json.insert("force_exact".into(), p.feedback_exact.to_array().into());
            json.insert("paper_exact_difference".into(), diff.into());
            json.insert("touch_point".into(), p.touch_point.to_array().into());
            json.insert(
                "contact".into(),
                p.contact.map_or(serde_json::Value::Null, |c| {
                    serde_json::json!({
                        "triangle": c.tri,
                        "nodes": c.nodes,
                        "alpha": c.alpha,
                        "proxy": c.proxy.to_array(),
                        "finger": c.finger.to_array(),
                    })
                }),
            );
            text.push(format!("paper vs exact: |ΔF| = {diff:.3e} N"));
            let contact_nodes = p.contact.map_or(Vec::new(), |c| {
                (0..3)
                    .filter(|&k| c.alpha[k] != 0.0)
                    .map(|k| c.nodes[k])
                    .collect()
            });
            let view = match p.contact {
                Some(c) => {
                    let [a0, a1, a2] = c.nodes.map(|i| scene.mesh.nodes[i as usize]);
                    (c.proxy, (a1 - a0).cross(a2 - a0).normalize_or_zero())
                }
                None => (p.touch_point, -a.push.normalize_or_zero()),
            };
            PokeOutcome {
                feedback: p.feedback,
                forces: p.bc.entries().to_vec(),
                contact_nodes,
                trace,
                finger,
                proxy: p.contact.map(|c| c.proxy),
                arrow_at: p.contact.map_or(finger, |c| c.proxy),
                view,
                sphere: None,
            }
        }
    };
    let nodal: Vec<(u32, DVec3)> = out
        .forces
        .iter()
        .map(|&(c, f)| (scene.compliance.col_node(c as usize), f))
        .collect();
    let u = touchfem_core::fem::solve_static(&scene.mesh, &nodal)?;
    let max_u = u.iter().map(|v| v.length()).fold(0.0, f64::max);
    if let Some(path) = &a.vtu {
        let mut f = vec![DVec3::ZERO; scene.mesh.nodes.len()];
        for &(n, v) in &nodal {
            f[n as usize] += v;
        }
        // The nodal forces are the contact forces: the point finger's equivalent forces on
        // its triangle's nodes, or the sphere's contact problem's forces.
        crate::vtu::write_vtu(path, &scene.mesh, &u, &f, &f)?;
    }
    if let Some(path) = &a.png {
        poke_png(a, &scene, &out, s, path)?;
    }
    let f = out.feedback;
    if a.json {
        let mut v = serde_json::json!({
            "force": f.to_array(),
            "max_displacement": max_u,
            "tool": if sphere_m.is_some() { "sphere" } else { "point" },
            "contact_nodes": out.contact_nodes,
            "active_columns": out.forces.len(),
            "precompute": {
                "seconds": st.seconds,
                "bytes": st.bytes,
                "residual": st.residual,
                "symmetry": st.symmetry,
                "rows": scene.compliance.rows().len(),
                "cols": scene.compliance.cols().len(),
                "tolerance": scene.compliance.hier().map(|h| h.options().tolerance),
            },
            "units": {"force": "N", "max_displacement": "m", "positions": "m", "trace": ["m", "N", "N", "N"]},
        });
        for (k, x) in json {
            v[k] = x;
        }
        if let Some(fr) = a.friction {
            v["friction"] = serde_json::json!([fr.static_mu, fr.dynamic_mu]);
        }
        if let Some(t) = &out.trace {
            v["trace"] = serde_json::json!(t);
        }
        println!("{v}");
    } else {
        // Six significant digits at any scale (scientific when tiny), never `-0`.
        let g = |v: f64| touchfem_gpu::render::format_significant(v, 6);
        // A component below 1e-12 of |F| is rounding noise: shown as 0.
        let c = |v: f64| {
            g(if v.abs() <= 1e-12 * f.length() {
                0.0
            } else {
                v
            })
        };
        println!(
            "force fed back: ({}, {}, {}) N, |F| = {} N ({})",
            c(f.x),
            c(f.y),
            c(f.z),
            g(f.length()),
            match (sphere_m.is_some(), a.exact) {
                (true, _) => "sphere",
                (false, true) => "exact model",
                (false, false) => "paper model",
            }
        );
        for line in &text {
            println!("{line}");
        }
        if let Some(t) = &out.trace {
            let last = t.last().copied().unwrap_or([0.0; 4]);
            println!(
                "slide: {} mm in {} steps, last force ({}, {}, {}) N",
                g(last[0] * 1e3),
                t.len(),
                c(last[1]),
                c(last[2]),
                c(last[3])
            );
        }
        println!("max displacement: {} mm", g(max_u * 1e3));
        println!(
            "precompute: {} rows × {} columns in {:.3} s, {:.1} MiB, max|K·L − I| = {:.1e}, symmetry {:.1e}",
            scene.compliance.rows().len(),
            scene.compliance.cols().len(),
            st.seconds,
            st.bytes as f64 / (1 << 20) as f64,
            st.residual,
            st.symmetry
        );
        if out.contact_nodes.is_empty() {
            println!("(the finger is not in contact)");
        }
    }
    Ok(())
}

/// `poke --png`: the deformation under the poke's forces, the finger, its god-object and the
/// force on the finger as an arrow.
fn poke_png(
    a: &PokeArgs,
    scene: &Body,
    out: &PokeOutcome,
    s: f64,
    path: &std::path::Path,
) -> Result<(), Error> {
    let f32s: Vec<(u32, [f32; 3])> = out
        .forces
        .iter()
        .map(|&(c, f)| (c, f.as_vec3().to_array()))
        .collect();
    let (lo, hi) = scene.mesh.bounds();
    let diag = (hi - lo).length();
    // The largest displacement shown: u = L·F over the displayed rows (f64, as the GPU).
    let mut shown = vec![DVec3::ZERO; scene.compliance.rows().len()];
    scene.compliance.displace(&out.forces, &mut shown);
    let max_surface_u = shown.iter().map(|v| v.length()).fold(0.0, f64::max);
    let coloring = match a.color {
        ColorArg::Displacement => touchfem_gpu::render::Coloring::displacement(max_surface_u),
        ColorArg::Plain => touchfem_gpu::render::Coloring::Plain,
    };
    // The arrow: about a quarter of the object's size for this force, in nice mm/N.
    let arrow = touchfem_gpu::render::ForceArrow {
        at: out.arrow_at,
        force_n: out.feedback,
        m_per_n: touchfem_gpu::render::arrow_scale(out.feedback.length(), 0.25 * diag),
    };
    let view = match a.view {
        ViewArg::Auto => touchfem_gpu::render::View::Auto,
        ViewArg::Contact => touchfem_gpu::render::View::Contact {
            point: out.view.0,
            normal: out.view.1,
            radius_m: (3.0 * (a.push + a.slide.unwrap_or(DVec3::ZERO)).length() * s)
                .max(0.2 * diag),
        },
    };
    // A sphere is drawn at its size, and its contact patch as dots on the deformed surface.
    let patch: Vec<DVec3> = out
        .contact_nodes
        .iter()
        .filter_map(|&n| {
            let row = scene.compliance.row_of(n)?;
            Some(scene.mesh.nodes[n as usize] + shown[row])
        })
        .collect();
    let (finger, finger_radius) = match out.sphere {
        Some((c, r)) => (c, Some(r)),
        None => (out.finger, None),
    };
    let picture = touchfem_gpu::render::Picture {
        mesh: &scene.mesh,
        compliance: &scene.compliance,
        forces: &f32s,
        finger: Some(finger),
        finger_radius,
        patch: if out.sphere.is_some() { &patch } else { &[] },
        proxy: out.proxy,
        wireframe: true,
        coloring,
        arrow: Some(arrow),
        view,
        legend: true,
    };
    touchfem_gpu::render::render_png(path, a.size, &picture)?;
    Ok(())
}

/// Precomputes the compliance with a progress bar on a terminal for large meshes.
/// The compliance, dense or (with a tolerance) hierarchical, with a progress bar on a
/// terminal.
fn precompute_with_bar(
    mesh: &touchfem_core::Mesh,
    sel: &Selection,
    tolerance: Option<f64>,
) -> Result<touchfem_core::compliance::Compliance, Error> {
    use std::io::IsTerminal;
    let bar = if std::io::stderr().is_terminal() && mesh.nodes.len() > 5000 {
        indicatif::ProgressBar::new(0)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("precompute {bar:40} {pos}/{len} columns {eta}")
            .expect("valid template"),
    );
    let mut progress = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    use touchfem_core::compliance::Compliance;
    let c = match tolerance {
        Some(eps) => Compliance::compute_hier(
            mesh,
            sel,
            &touchfem_core::compliance::hmatrix::HOptions::new(eps),
            &mut progress,
        )?,
        None => Compliance::compute_with_progress(mesh, sel, &mut progress)?,
    };
    bar.finish_and_clear();
    Ok(c)
}
