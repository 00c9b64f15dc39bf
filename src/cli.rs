//! The `touchfem` command line (see `../shared/CONTRACTS.md` for the stable flags and keys).

use clap::{Args, Parser, Subcommand};
use glam::DVec3;
use std::path::PathBuf;

use crate::compliance::Selection;
use crate::force::ForceModel;
use crate::scene::{load_mesh, LoadOptions, Scene};

use crate::units::LengthUnit;
use crate::Error;

/// Touch and see soft objects in real time (Hirota & Kaneko's precomputed-compliance FEM).
#[derive(Parser, Debug)]
#[command(name = "touchfem", version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Print the paper's Table 1 row of a mesh.
    Info {
        /// Mesh file (.msh, .node/.ele) or bundled name (cube).
        mesh: String,
        /// How to load the mesh.
        #[command(flatten)]
        load: LoadArgs,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Touch the surface at the point nearest --at, push by --push, print the force fed back.
    Poke(PokeArgs),
    /// The main job: scenes headless (the bundled ones by default) with the 1 kHz haptic loop
    /// and the visual loop; frames, GIF, force traces, the session and the paper's Table 2.
    Demo(DemoArgs),
    /// Run the haptic loop for fingers driven over UDP (the protocol in CONTRACTS.md).
    Serve(ServeArgs),
    /// Run a recorded session's finger positions through the haptic path again and compare
    /// the forces with the recorded ones.
    Replay(ReplayArgs),
    /// Speed against error: every method on the same meshes in one run.
    Bench(BenchArgs),
    /// An interactive window: a left drag presses the pointer into the object, a right drag
    /// orbits, the wheel zooms, Esc quits.
    View(ViewArgs),
    /// Precompute the compliance a scene needs into a cache file; `--shard I/N` computes one
    /// part of the columns (for N machines), `--merge` joins the parts.
    Precompute(PrecomputeArgs),
}

/// `touchfem precompute` flags.
#[derive(Args, Debug)]
pub struct PrecomputeArgs {
    /// Scene file, bundled scene, mesh file or bundled mesh.
    #[arg(required_unless_present = "merge")]
    pub scene: Option<String>,
    /// How to load a mesh given as SCENE (a scene file says it itself).
    #[command(flatten)]
    pub load: LoadArgs,
    /// Output file (a directory for a scene of several objects). Default: the cache file the
    /// scene loader reads ($TOUCHFEM_CACHE_DIR), with `.part-I-of-N` appended for a shard.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Compute only the I-th of N parts of the columns (1-based), e.g. 3/8.
    #[arg(long, value_parser = parse_shard)]
    pub shard: Option<(usize, usize)>,
    /// Join these shard files into --out (equal to the unsharded file).
    #[arg(long, num_args = 1.., conflicts_with_all = ["scene", "shard"], requires = "out")]
    pub merge: Vec<PathBuf>,
    /// Print one JSON object (`seconds`, `rows`, `cols`, `bytes`, ...).
    #[arg(long)]
    pub json: bool,
}

/// Parses "I/N" (1 ≤ I ≤ N ≤ 65536) into a shard index and count.
pub fn parse_shard(s: &str) -> Result<(usize, usize), String> {
    let bad = || format!("expected I/N with 1 <= I <= N <= 65536 (e.g. 3/8), got '{s}'");
    let (i, n) = s.split_once('/').ok_or_else(bad)?;
    let i: usize = i.trim().parse().map_err(|_| bad())?;
    let n: usize = n.trim().parse().map_err(|_| bad())?;
    if i == 0 || i > n || n > 65536 {
        return Err(bad());
    }
    Ok((i, n))
}

/// `touchfem view` flags.
#[derive(Args, Debug)]
pub struct ViewArgs {
    /// Scene file, bundled scene, mesh file or bundled mesh (cube, mouse).
    pub scene: String,
    /// Window size, WxH pixels.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub size: [u32; 2],
    /// Record the session to this file.
    #[arg(long)]
    pub record: Option<PathBuf>,
}

/// `touchfem bench` flags.
#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Fewer repetitions and active-column counts (for CI smoke runs).
    #[arg(long)]
    pub quick: bool,
    /// Write the rows as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Add rows for this scene's objects (a scene file, bundled scene or mesh): its precompute
    /// (time, memory, peak RSS; the JSON's `scene` array) and the displacement methods.
    #[arg(long)]
    pub scene: Option<String>,
}

/// `touchfem serve` flags.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// Scene file, bundled scene, or mesh (then up to four UDP fingers).
    pub scene: String,
    /// Address to listen on, e.g. 127.0.0.1:47800.
    #[arg(long)]
    pub udp: std::net::SocketAddr,
    /// Seconds to run (default: until interrupted).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Write the report as JSON here (else to stdout).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Record the session here.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Allow a non-loopback address (forces reach a person's hand from the network).
    #[arg(long)]
    pub allow_remote: bool,
    /// Watchdog: silence longer than this (ms) gives zero force and the stale flag.
    #[arg(long, default_value_t = 20.0)]
    pub watchdog_ms: f64,
}

/// `touchfem replay` flags.
#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The session file (`--record` of `demo` or `view`).
    pub file: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// `touchfem demo` flags.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Scene files or bundled scene names (fig1, fig2, pinch); none: every bundled scene.
    pub scenes: Vec<String>,
    /// Seconds of haptic + visual loop per scene (scripted paths are stretched to fit).
    #[arg(long, default_value_t = 3.0)]
    pub seconds: f64,
    /// Record each scene's session here (several scenes: FILE.SCENE.EXT).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Write the report as JSON here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Directory for frames and the report.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
}

/// Flags that say how to load a mesh.
#[derive(Args, Debug, Clone)]
pub struct LoadArgs {
    /// Length unit of the mesh file: mm or m (default m; bundled meshes know their own).
    #[arg(long)]
    pub unit: Option<LengthUnit>,
    /// The Gmsh physical group (or TetGen marker) whose nodes are clamped.
    #[arg(long, default_value = "fixed")]
    pub fixed: String,
    /// Young's modulus in Pa (default: the bundled mesh's, else 1000).
    #[arg(long)]
    pub young: Option<f64>,
    /// Poisson's ratio (default: the bundled mesh's, else 0.3).
    #[arg(long)]
    pub poisson: Option<f64>,
}

impl LoadArgs {
    /// The mesh-loading options these flags name.
    pub fn options(&self) -> LoadOptions {
        LoadOptions {
            unit: self.unit,
            young_pa: self.young,
            poisson: self.poisson,
            fixed_group: self.fixed.clone(),
        }
    }
}

/// `touchfem poke` flags.
#[derive(Args, Debug)]
pub struct PokeArgs {
    /// Mesh file or bundled name.
    pub mesh: String,
    /// The point to touch, X,Y,Z in mesh units.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub at: DVec3,
    /// The finger's motion, DX,DY,DZ in mesh units.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub push: DVec3,
    /// How to load the mesh.
    #[command(flatten)]
    pub load: LoadArgs,
    /// Use the exact contact-point compliance instead of the paper's interpolation.
    #[arg(long)]
    pub exact: bool,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Write a VTK XML unstructured grid with displacement, force and fixed arrays.
    #[arg(long)]
    pub vtu: Option<PathBuf>,
    /// Render the poke (deformed surface, finger and god-object) to this PNG (GPU; lavapipe
    /// works).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Image size for --png, WxH pixels.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub size: [u32; 2],
    /// Keep the precomputed compliance in this cache file (recomputed if stale or corrupt).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Haptic ticks over which the finger moves.
    #[arg(long, default_value_t = 50)]
    pub steps: usize,
}

/// Parses "WxH" into an image size.
pub fn parse_size(s: &str) -> Result<[u32; 2], String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WxH, got '{s}'"))?;
    let p = |v: &str| {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|&n| (1..=16384).contains(&n))
            .ok_or_else(|| format!("'{v}' is not a size in 1..=16384"))
    };
    Ok([p(w)?, p(h)?])
}

/// Parses "x,y,z" into a finite vector.
pub fn parse_vec3(s: &str) -> Result<DVec3, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("expected X,Y,Z, got '{s}'"));
    }
    let mut v = [0.0; 3];
    for (o, p) in v.iter_mut().zip(&parts) {
        *o = p
            .parse::<f64>()
            .map_err(|e| format!("'{p}' is not a number: {e}"))?;
        if !o.is_finite() {
            return Err(format!("'{p}' is not finite"));
        }
    }
    Ok(DVec3::from_array(v))
}

/// Runs the command line; returns the process exit code.
pub fn run(cli: Cli) -> Result<(), Error> {
    match cli.command {
        Command::Info { mesh, load, json } => info(&mesh, &load, json),
        Command::Poke(args) => poke(&args),
        Command::Demo(args) => demo(&args),
        Command::Replay(args) => replay(&args),
        Command::Serve(args) => serve(&args),
        Command::Bench(args) => bench(&args),
        Command::View(args) => crate::window::view_command(&args),
        Command::Precompute(args) => crate::precompute::command(&args),
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

fn bench(a: &BenchArgs) -> Result<(), Error> {
    use crate::tradeoff::{bench_scenes, cpu_rows};
    let (reps, active): (usize, &[usize]) = if a.quick {
        (20, &[9])
    } else {
        (200, &[3, 9, 90, 900])
    };
    lavapipe_inline();
    let placement = crate::threads::VisualPlacement::split();
    let gpu = match crate::gpu::Gpu::new_headless_placed(&placement) {
        Ok(g) => Some(g),
        Err(e) => {
            eprintln!("warning: {e}; no gpu-f32-* rows");
            None
        }
    };
    let mut rows = Vec::new();
    let mut scene_table = Vec::new();
    let mut scenes = bench_scenes()?;
    if let Some(spec) = &a.scene {
        let (r, t, s) = crate::tradeoff::scene_objects(spec)?;
        rows.extend(r);
        scene_table = t;
        scenes.extend(s);
    }
    for (name, scene) in scenes {
        rows.extend(cpu_rows(&name, &scene, active, reps)?);
        if let Some(g) = &gpu {
            // Submit from the core the driver's threads started on (as the demo does).
            placement.enter_visual();
            let gpu_rows = crate::tradeoff::gpu_rows(&name, &scene, g, active, reps);
            placement.leave();
            rows.extend(gpu_rows?);
        }
    }
    println!(
        "{:<14} {:<6} {:>6} {:>7} {:>12} {:>11}",
        "method", "mesh", "nodes", "active", "time_us", "rel_error"
    );
    for r in &rows {
        println!(
            "{:<14} {:<6} {:>6} {:>7} {:>12.3} {:>11.2e}",
            r.method, r.mesh, r.nodes, r.active_columns, r.time_us, r.rel_error
        );
    }
    for t in &scene_table {
        println!(
            "{}: {} nodes, {} surface / {} free surface, {} rows × {} cols: precompute {:.2} s, L {:.0} MB (f64 + f32), peak RSS {:.2} GB",
            t["object"].as_str().unwrap_or("?"),
            t["nodes"],
            t["surface_nodes"],
            t["free_surface_nodes"],
            t["rows"],
            t["cols"],
            t["precompute_s"].as_f64().unwrap_or(0.0),
            t["bytes_l"].as_f64().unwrap_or(0.0) / 1e6,
            t["peak_rss_bytes"].as_f64().unwrap_or(0.0) / 1e9,
        );
    }
    if let Some(path) = &a.json {
        let v = serde_json::json!({
            "rows": rows,
            "scene": scene_table,
            "machine": crate::demo::machine(),
        });
        std::fs::write(
            path,
            serde_json::to_string_pretty(&v).expect("serialisable"),
        )
        .map_err(|source| Error::Write {
            path: path.clone(),
            source,
        })?;
    }
    Ok(())
}

fn serve(a: &ServeArgs) -> Result<(), Error> {
    use crate::runtime::serve::{serve, stop_on_interrupt, ServeOptions, INTERRUPTED};
    if let Some(s) = a.seconds {
        if !(s.is_finite() && s > 0.0) {
            return Err(Error::Input(format!("--seconds must be positive, got {s}")));
        }
    }
    if !(a.watchdog_ms.is_finite() && a.watchdog_ms > 0.0) {
        return Err(Error::Input(format!(
            "--watchdog-ms must be positive, got {}",
            a.watchdog_ms
        )));
    }
    if !a.udp.ip().is_loopback() && a.allow_remote {
        eprintln!(
            "warning: serving {} beyond this machine: anyone who can reach it drives forces into a person's hand",
            a.udp
        );
    }
    let is_scene = crate::scene::SceneSource::find(&a.scene)?.is_some();
    let mut world = crate::scene::World::load(&a.scene, "udp")?;
    if !is_scene {
        // A bare mesh: as many UDP fingers as a packet may carry.
        let f = world.fingers[0].clone();
        world.fingers = vec![f; crate::force::MAX_FINGERS];
    }
    if world
        .fingers
        .iter()
        .any(|f| f.device != crate::scene::DeviceSpec::Udp)
    {
        return Err(Error::Scene(format!(
            "scene '{}': `serve` drives udp fingers only",
            world.name
        )));
    }
    stop_on_interrupt();
    let opts = ServeOptions {
        addr: a.udp,
        allow_remote: a.allow_remote,
        seconds: a.seconds,
        record: a.record.clone(),
        watchdog: std::time::Duration::from_secs_f64(a.watchdog_ms * 1e-3),
        placement: crate::threads::VisualPlacement::split(),
    };
    let report = serve(&world, &opts, &INTERRUPTED, |addr| {
        eprintln!("listening on udp {addr}");
    })?;
    let json = serde_json::to_string_pretty(&report).expect("serialisable");
    match &a.report {
        Some(path) => std::fs::write(path, json).map_err(|source| Error::Write {
            path: path.clone(),
            source,
        })?,
        None => println!("{json}"),
    }
    Ok(())
}

fn replay(a: &ReplayArgs) -> Result<(), Error> {
    use crate::runtime::session;
    let sess = session::read(&a.file)?;
    let h = &sess.header;
    let src = crate::scene::SceneSource {
        name: h.scene_name.clone(),
        text: h.scene_toml.clone(),
        dir: h.scene_dir.clone(),
        label: format!("the scene recorded in {}", a.file.display()),
    };
    let world = crate::scene::World::from_source(&src)?;
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
    Ok(())
}

fn demo(a: &DemoArgs) -> Result<(), Error> {
    use crate::demo::{machine, record_path_for, run_scene, worst, DemoOptions, DemoReport};
    if !(a.seconds.is_finite() && a.seconds > 0.0 && a.seconds <= 3600.0) {
        return Err(Error::Input(format!(
            "--seconds must be in (0, 3600], got {}",
            a.seconds
        )));
    }
    let specs: Vec<String> = if a.scenes.is_empty() {
        crate::scene::BUNDLED_SCENES
            .iter()
            .map(|(n, _)| n.to_string())
            .collect()
    } else {
        a.scenes.clone()
    };
    // Load every scene first: a bad scene file fails before anything runs.
    let mut worlds = Vec::new();
    for spec in &specs {
        if crate::scene::SceneSource::find(spec)?.is_none() {
            return Err(Error::Scene(format!(
                "'{spec}' is neither a bundled scene ({}) nor a .toml scene file",
                crate::scene::BUNDLED_SCENES
                    .iter()
                    .map(|(n, _)| *n)
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        }
        worlds.push(crate::scene::World::load(spec, "script")?);
    }
    std::fs::create_dir_all(&a.out).map_err(|source| Error::Write {
        path: a.out.clone(),
        source,
    })?;
    let placement = crate::threads::VisualPlacement::split();
    lavapipe_inline();
    let gpu = match crate::gpu::Gpu::new_headless_placed(&placement) {
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
        Some(g) => Some(
            crate::render::Renderer::with_options(
                &g.device,
                size,
                crate::render::RenderOptions {
                    samples: crate::render::live_samples(&g.adapter.get_info()),
                    ..Default::default()
                },
            )
            .map_err(|e| Error::Input(e.to_string()))?,
        ),
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
        };
        let rows = run_scene(world, &opts, gpu.as_ref(), renderer.as_ref())?;
        if let Some(r) = rows.first() {
            floors.push(r.floor.clone());
            haptics.push(r.haptic.clone());
            eprintln!(
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
            eprintln!(
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
    eprintln!("report: {}", path.display());
    Ok(())
}

fn info(spec: &str, load: &LoadArgs, json: bool) -> Result<(), Error> {
    let (mesh, unit) = load_mesh(spec, &load.options())?;
    let t = mesh.table1();
    if json {
        let mut v = serde_json::to_value(&t).expect("serialisable");
        v["unit"] = serde_json::json!(unit.symbol());
        v["fixed_nodes"] = serde_json::json!(mesh.fixed_count());
        v["reoriented_tets"] = serde_json::json!(mesh.report.reoriented_tets.len());
        v["dropped_nodes"] = serde_json::json!(mesh.report.dropped_nodes.len());
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
        report_changes(&mesh);
    }
    Ok(())
}

fn report_changes(mesh: &crate::Mesh) {
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

fn poke(a: &PokeArgs) -> Result<(), Error> {
    let (mesh, unit) = load_mesh(&a.mesh, &a.load.options())?;
    if !a.json {
        report_changes(&mesh);
    }
    let s = unit.to_metres();
    let sel = Selection::default();
    let compliance = match &a.cache {
        Some(path) => {
            let (c, outcome) = crate::cache::load_or_compute(path, &mesh, &sel)?;
            if let Some(m) = outcome.message() {
                eprintln!("{m}");
            }
            c
        }
        None => precompute_with_bar(&mesh, &sel)?,
    };
    let scene = Scene::with_compliance(mesh, compliance);
    let st = &scene.compliance.stats;
    let model = if a.exact {
        ForceModel::Exact
    } else {
        ForceModel::Paper
    };
    let p = scene.poke(a.at * s, a.push * s, model, a.steps)?;
    let nodal = scene.nodal_forces(&p.bc);
    let u = crate::fem::solve_static(&scene.mesh, &nodal)?;
    let max_u = u.iter().map(|v| v.length()).fold(0.0, f64::max);
    if let Some(path) = &a.vtu {
        let mut f = vec![DVec3::ZERO; scene.mesh.nodes.len()];
        for &(n, v) in &nodal {
            f[n as usize] += v;
        }
        crate::vtu::write_vtu(path, &scene.mesh, &u, &f)?;
    }
    if let Some(path) = &a.png {
        let (f32s, n) = p.bc.to_f32();
        let scene_r = crate::render::Scene {
            mesh: &scene.mesh,
            compliance: &scene.compliance,
            forces: &f32s[..n],
            finger: Some(p.touch_point + a.push * s),
            proxy: p.contact.map(|c| c.proxy),
            wireframe: true,
        };
        crate::render::render_png(path, a.size, &scene_r)
            .map_err(|e| Error::Input(e.to_string()))?;
    }
    let diff = (p.feedback_paper - p.feedback_exact).length();
    if a.json {
        let contact = p.contact.map(|c| {
            serde_json::json!({
                "triangle": c.tri,
                "nodes": c.nodes,
                "alpha": c.alpha,
                "proxy": c.proxy.to_array(),
                "finger": c.finger.to_array(),
            })
        });
        let v = serde_json::json!({
            "force": p.feedback.to_array(),
            "max_displacement": max_u,
            "model": if a.exact { "exact" } else { "paper" },
            "force_paper": p.feedback_paper.to_array(),
            "force_exact": p.feedback_exact.to_array(),
            "paper_exact_difference": diff,
            "touch_point": p.touch_point.to_array(),
            "contact": contact,
            "active_columns": p.bc.len(),
            "precompute": {
                "seconds": st.seconds,
                "bytes": st.bytes,
                "residual": st.residual,
                "symmetry": st.symmetry,
                "rows": scene.compliance.rows().len(),
                "cols": scene.compliance.cols().len(),
            },
            "units": {"force": "N", "max_displacement": "m", "positions": "m"},
        });
        println!("{v}");
    } else {
        let f = p.feedback;
        println!(
            "force fed back: ({:.6}, {:.6}, {:.6}) N, |F| = {:.6} N ({} model)",
            f.x,
            f.y,
            f.z,
            f.length(),
            if a.exact { "exact" } else { "paper" }
        );
        println!("paper vs exact: |ΔF| = {diff:.3e} N");
        println!("max displacement: {:.6} mm", max_u * 1e3);
        println!(
            "precompute: {} rows × {} columns in {:.3} s, {:.1} MiB, max|K·L − I| = {:.1e}, symmetry {:.1e}",
            scene.compliance.rows().len(),
            scene.compliance.cols().len(),
            st.seconds,
            st.bytes as f64 / (1 << 20) as f64,
            st.residual,
            st.symmetry
        );
        if p.contact.is_none() {
            println!("(the finger is not in contact)");
        }
    }
    Ok(())
}

/// Precomputes the compliance with a progress bar on a terminal for large meshes.
fn precompute_with_bar(
    mesh: &crate::Mesh,
    sel: &Selection,
) -> Result<crate::compliance::Compliance, Error> {
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
    let c = crate::compliance::Compliance::compute_with_progress(mesh, sel, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    Ok(c)
}
