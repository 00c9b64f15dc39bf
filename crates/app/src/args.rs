//! The command line's flags and subcommands (clap), and the parsers of their values: each
//! numeric flag has a range, and a value outside it is an error naming the flag.

use clap::{Args, Parser, Subcommand};
use glam::DVec3;
use std::path::PathBuf;

use touchfem_core::contact::{Friction, Tool};
use touchfem_core::mesh::units::{Formulation, LengthUnit, Material};
use touchfem_core::mesh::Mesh;
use touchfem_core::scene::{load_mesh, LoadOptions};

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
        /// The finger's tool, checked against the mesh.
        #[command(flatten)]
        tool: ToolArgs,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
        /// Estimate the size of `L` stored hierarchically to this tolerance (0 < EPS < 1)
        /// from its block layout, without computing it.
        #[arg(long, value_name = "EPS", value_parser = parse_tolerance)]
        tolerance: Option<f64>,
    },
    /// Touch the surface at the point nearest --at, push by --push, print the force fed back.
    Poke(Box<PokeArgs>),
    /// The main job: scenes headless (the bundled ones by default) with the 1 kHz haptic loop
    /// and the visual loop; frames, GIF, force traces, the session and the paper's Table 2.
    Demo(DemoArgs),
    /// Run the haptic loop for fingers driven over UDP (the protocol: docs/contracts.md and
    /// docs/reference/udp-protocol.md).
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
    /// Store L compressed (hierarchical) to this relative tolerance, 0 < EPS < 1, in the
    /// compressed cache format; shards are runs of panels. Without it L stays dense.
    #[arg(long, value_name = "EPS", value_parser = parse_tolerance, allow_hyphen_values = true, conflicts_with = "merge")]
    pub tolerance: Option<f64>,
    /// Print one JSON object (`seconds`, `rows`, `cols`, `bytes`, `tolerance`, ...).
    #[arg(long)]
    pub json: bool,
}

/// The bundled scenes' names, as `demo` runs them when none is named: `fig1, fig2, …`.
pub fn bundled_scene_names() -> String {
    touchfem_core::scene::BUNDLED_SCENES
        .iter()
        .map(|(n, _)| *n)
        .collect::<Vec<_>>()
        .join(", ")
}

/// `demo SCENE...`'s help, the bundled scenes listed from the code.
fn demo_scenes_help() -> String {
    format!(
        "Scene files or bundled scene names ({}); none: every bundled scene, in that order",
        bundled_scene_names()
    )
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
    /// Surface colour: by the displacement's magnitude with a legend in mm (the key C toggles
    /// it), or plain.
    #[arg(long, value_enum, default_value_t = ColorArg::Displacement)]
    pub color: ColorArg,
    /// The pointer is a sphere of this radius (the scene's unit; mm for a bundled mesh)
    /// instead of a point, drawn at its size.
    #[arg(long)]
    pub sphere: Option<f64>,
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
    /// Draw time against error (log–log, one panel per mesh but the cube) into this PNG.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Only the hard cases (nearly incompressible, slivers and needles, extreme scales,
    /// locking): their accuracy in f64 and f32.
    #[arg(long)]
    pub hard: bool,
    /// Only the mesh-resolution ladder: the paper's cube at 4³ … 32³ cells, Fig. 1b's press as
    /// a point and as a 5 mm punch, errors against the extrapolated limit.
    #[arg(long)]
    pub ladder: bool,
    /// Only cutting: cuts of 1 and 50 tets on the cube and the mouse against a full recompute
    /// (the cut pass, the fold, the haptic tick on the cut body and, with a GPU, the
    /// blade-to-vertex-buffer latency).
    #[arg(long)]
    pub cut: bool,
    /// Where the ladder's mouse meshes are (`mouse_hH.msh`, made by scripts/make_mouse.py).
    #[arg(long, default_value = "out/ladder")]
    pub ladder_dir: PathBuf,
    /// Add rows for this scene's objects (a scene file, bundled scene or mesh): its precompute
    /// (time, memory, peak RSS; the JSON's `scene` array) and the displacement methods. With
    /// `--cut`: a mesh file in mm (an organ from scripts/make_organ.py), only its separating
    /// blade step.
    #[arg(long)]
    pub scene: Option<String>,
    /// The hierarchical `L`'s rows at this tolerance only (0 < EPS < 1) instead of 10⁻²,
    /// 10⁻³, 10⁻⁴ and 10⁻⁶.
    #[arg(long, value_name = "EPS", value_parser = parse_tolerance)]
    pub tolerance: Option<f64>,
}

/// `touchfem serve` flags.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// Scene file, bundled scene, or mesh (then up to four UDP fingers, or one Haply finger
    /// with `--haply`).
    pub scene: String,
    /// Address to listen on for UDP fingers, e.g. 127.0.0.1:47800.
    #[arg(long, conflicts_with = "haply")]
    pub udp: Option<std::net::SocketAddr>,
    /// Drive the scene's Haply fingers through the Haply Inverse Service at URL (default
    /// ws://127.0.0.1:10001): sets every Haply finger's `url`; a scene with none gets its first
    /// finger made one, a bare mesh one Haply finger. Without `--udp` or `--haply`, a scene's
    /// own Haply fingers are served at their own URLs.
    #[arg(long, value_name = "URL", num_args = 0..=1, default_missing_value = touchfem_core::scene::HAPLY_DEFAULT_URL)]
    pub haply: Option<String>,
    /// Haply watchdog: no state from the service for longer than this (ms, in (0, 60000])
    /// gives zero force (counted in `haply_stale`).
    #[arg(long, value_name = "MS", default_value_t = crate::haply::DEFAULT_WATCHDOG_MS, value_parser = parse_watchdog_ms, allow_hyphen_values = true)]
    pub haply_watchdog_ms: f64,
    /// Seconds to run, in (0, 1e6] (default: until interrupted).
    #[arg(long, value_name = "S", value_parser = parse_serve_seconds, allow_hyphen_values = true)]
    pub seconds: Option<f64>,
    /// Write the report as JSON here (else to stdout).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Record the session here.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Allow a non-loopback address (forces reach a person's hand from the network); needs
    /// `--key`.
    #[arg(long)]
    pub allow_remote: bool,
    /// A file whose bytes (at least 16) are a shared secret: every packet, both ways, ends
    /// with its HMAC-SHA256 under it, and a position packet whose tag does not verify is
    /// dropped (`packets_rejected`).
    #[arg(long, value_name = "FILE")]
    pub key: Option<PathBuf>,
    /// Watchdog: silence longer than this (ms, in (0, 60000]) gives zero force and the stale
    /// flag.
    #[arg(long, value_name = "MS", default_value_t = 20.0, value_parser = parse_watchdog_ms, allow_hyphen_values = true)]
    pub watchdog_ms: f64,
    /// What paces the loop: `host` (touchfem's 1 kHz deadlines) or `device` (each position
    /// packet starts a tick, answered at once: the lowest round trip).
    #[arg(long, default_value = "host")]
    pub clock: touchfem_core::devices::udp::Clock,
    /// Device limits for UDP or Haply fingers whose scene gives none: a preset (falcon,
    /// phantom-omni, phantom-premium-1.5, delta.3, omega.3, sigma.7, inverse3; Haply fingers
    /// default to inverse3). The force is then rendered through a virtual coupling sized from
    /// them.
    #[arg(long)]
    pub limits: Option<String>,
    /// First measure this machine's bare-loop floor for this many seconds (in [0, 3600];
    /// reported as `floor`), then serve.
    #[arg(long, value_name = "S", value_parser = parse_floor_seconds, allow_hyphen_values = true)]
    pub floor_seconds: Option<f64>,
    /// Show the object in the `view` window (fingers, god-objects, deformation) instead of
    /// updating it headless; closing the window ends the run.
    #[arg(long)]
    pub view: bool,
    /// The window's size with `--view`, WxH pixels.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub size: [u32; 2],
}

/// `touchfem replay` flags. The command fails (status 2) on a session with no tick and when
/// a recorded or replayed force is not finite (`max_force_diff_n` is then written as
/// `f64::MAX`, never `null`).
#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The session file (`--record` of `demo`, `view` or `serve`).
    pub file: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// `touchfem demo` flags.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Scene files or bundled scene names; none: every bundled scene.
    #[arg(value_name = "SCENE", help = demo_scenes_help())]
    pub scenes: Vec<String>,
    /// Seconds of haptic + visual loop per scene, in (0, 3600] (scripted paths are stretched
    /// to fit).
    #[arg(long, value_name = "S", default_value_t = 3.0, value_parser = parse_demo_seconds, allow_hyphen_values = true)]
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
    /// Frame colour: by the displacement's magnitude with a legend in mm (one scale per scene),
    /// or plain.
    #[arg(long, value_enum, default_value_t = ColorArg::Displacement)]
    pub color: ColorArg,
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
    /// Young's modulus in Pa, in (0, 1e13] (default: the bundled mesh's, else 1000).
    #[arg(long, value_name = "PA", value_parser = parse_young, allow_hyphen_values = true)]
    pub young: Option<f64>,
    /// Poisson's ratio, in (-1, 0.5) (default: the bundled mesh's, else 0.3).
    #[arg(long, value_name = "NU", value_parser = parse_poisson, allow_hyphen_values = true)]
    pub poisson: Option<f64>,
    /// How the stiffness treats the volumetric strain: standard (linear tets as in the paper;
    /// locks as ν → 0.5) or locking-free (nodally averaged dilatation; for ν near 0.5).
    #[arg(long, value_name = "standard|locking-free", value_parser = parse_formulation)]
    pub formulation: Option<Formulation>,
    /// The tets of the Gmsh physical volume group GROUP have Young's modulus E (Pa, in
    /// (0, 1e13]) and Poisson's ratio NU (in (-1, 0.5)); repeatable, the groups disjoint.
    #[arg(long = "region", value_name = "GROUP=E,NU", value_parser = parse_region, allow_hyphen_values = true)]
    pub regions: Vec<RegionArg>,
}

/// One `--region GROUP=E,NU`.
#[derive(Clone, Debug, PartialEq)]
pub struct RegionArg {
    /// The physical volume group.
    pub group: String,
    /// Its material.
    pub material: Material,
}

impl LoadArgs {
    /// The mesh-loading options these flags name.
    pub fn options(&self) -> LoadOptions {
        LoadOptions {
            unit: self.unit,
            young_pa: self.young,
            poisson: self.poisson,
            formulation: self.formulation,
            fixed_group: self.fixed.clone(),
            regions: self
                .regions
                .iter()
                .map(|r| (r.group.clone(), r.material))
                .collect(),
        }
    }

    /// Loads the mesh `spec` with these flags ([`load_mesh`]); a region's error names the
    /// `--region` flag and its value.
    pub fn load(&self, spec: &str) -> Result<(Mesh, LengthUnit), crate::error::Error> {
        use touchfem_core::MeshError as M;
        load_mesh(spec, &self.options()).map_err(|e| {
            let group = match &e {
                touchfem_core::Error::Mesh(
                    M::NoVolumeGroup { name, .. }
                    | M::NotVolumeGroup { name, .. }
                    | M::EmptyVolumeGroup { name },
                ) => Some(name),
                touchfem_core::Error::Mesh(M::OverlappingRegions { second, .. }) => Some(second),
                touchfem_core::Error::Mesh(M::BadRegionMaterial { group, .. }) => Some(group),
                _ => None,
            };
            match group.and_then(|g| self.regions.iter().rev().find(|r| &r.group == g)) {
                Some(r) => crate::error::Error::Input(format!(
                    "--region {}={},{}: {e}",
                    r.group, r.material.young_pa, r.material.poisson
                )),
                None => e.into(),
            }
        })
    }
}

/// Parses `--region GROUP=E,NU`: a non-empty group name, E in (0, 1e13] Pa and NU in
/// (−1, 0.5).
pub fn parse_region(s: &str) -> Result<RegionArg, String> {
    let bad = |why: String| format!("expected GROUP=E,NU (e.g. nodule=30000,0.45): {why}");
    let (group, numbers) = s
        .rsplit_once('=')
        .ok_or_else(|| bad(format!("no '=' in '{s}'")))?;
    let group = group.trim();
    if group.is_empty() {
        return Err(bad("the group name is empty".into()));
    }
    let (e, nu) = numbers
        .split_once(',')
        .ok_or_else(|| bad(format!("'{numbers}' is not E,NU")))?;
    let young_pa = parse_young(e).map_err(|m| bad(format!("Young's modulus: {m}")))?;
    let poisson = parse_poisson(nu).map_err(|m| bad(format!("Poisson's ratio: {m}")))?;
    Ok(RegionArg {
        group: group.to_string(),
        material: Material { young_pa, poisson },
    })
}

/// `touchfem poke` flags.
#[derive(Args, Debug)]
pub struct PokeArgs {
    /// Mesh file or bundled name.
    pub mesh: String,
    /// The point to touch, X,Y,Z in mesh units (each at most 1e9 in magnitude).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub at: DVec3,
    /// The finger's motion, DX,DY,DZ in mesh units (each at most 1e9 in magnitude).
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
    /// Write a VTK XML unstructured grid with displacement, force and fixed point arrays and
    /// young, poisson and region cell arrays.
    #[arg(long)]
    pub vtu: Option<PathBuf>,
    /// Render the poke (deformed surface, finger and god-object) to this PNG (GPU; lavapipe
    /// works).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Image size for --png, WxH pixels.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub size: [u32; 2],
    /// Surface colour for --png: by the displacement's magnitude with a legend in mm, or plain.
    #[arg(long, value_enum, default_value_t = ColorArg::Displacement)]
    pub color: ColorArg,
    /// Camera for --png: the 3/4 view of the whole object, or the touched point from outside.
    #[arg(long, value_enum, default_value_t = ViewArg::Auto)]
    pub view: ViewArg,
    /// Keep the precomputed compliance in this cache file (recomputed if stale or corrupt).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Haptic ticks over which the finger moves, 1 to 1000000; with --slide also the slide's
    /// equal steps.
    #[arg(long, default_value_t = 50, value_parser = parse_steps, allow_hyphen_values = true)]
    pub steps: usize,
    /// The finger is a sphere of radius R (mesh units, finite, > 0, not larger than the
    /// object) whose surface first touches the surface point nearest --at.
    #[arg(long, value_name = "R", value_parser = parse_sphere, allow_hyphen_values = true, conflicts_with = "exact")]
    pub sphere: Option<f64>,
    /// Coulomb friction: static and dynamic coefficients MS,MD (finite, >= 0, MD <= MS).
    #[arg(long, value_name = "MS,MD", value_parser = parse_friction, allow_hyphen_values = true)]
    pub friction: Option<Friction>,
    /// After the push, move the finger by DX,DY,DZ (mesh units) in --steps equal steps, the
    /// contact state carried along.
    #[arg(long, value_name = "DX,DY,DZ", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub slide: Option<DVec3>,
    /// Before the push, a blade of `--depth` cuts along the surface from the surface point
    /// nearest the first point to the one nearest the second (mesh units), separating the
    /// material along the quad it sweeps (nodes snapped onto it and split); the poke then runs
    /// on the cut object (a point finger; the paper's force unless `--exact`).
    #[arg(long, value_name = "X1,Y1,Z1:X2,Y2,Z2", value_parser = parse_segment, allow_hyphen_values = true, requires = "depth")]
    pub cut: Option<(DVec3, DVec3)>,
    /// The blade's depth (mesh units, > 0) for `--cut`.
    #[arg(long, value_name = "D", value_parser = parse_depth, allow_hyphen_values = true, requires = "cut")]
    pub depth: Option<f64>,
    /// Store `L` hierarchically to this tolerance (0 < EPS < 1): far blocks low-rank, near
    /// blocks exact.
    #[arg(long, value_name = "EPS", value_parser = parse_tolerance, conflicts_with = "cut")]
    pub tolerance: Option<f64>,
}

/// The finger's tool flags of `info` (checked as `poke` checks them, echoed in `--json`).
#[derive(Args, Debug, Clone)]
pub struct ToolArgs {
    /// A sphere finger of radius R (mesh units, finite, > 0, not larger than the object).
    #[arg(long, value_name = "R", value_parser = parse_sphere, allow_hyphen_values = true)]
    pub sphere: Option<f64>,
    /// Coulomb friction: static and dynamic coefficients MS,MD (finite, >= 0, MD <= MS).
    #[arg(long, value_name = "MS,MD", value_parser = parse_friction, allow_hyphen_values = true)]
    pub friction: Option<Friction>,
}

/// A number a user gave, for a message: as written when it is short (`52`, `0.5`), else in
/// shortest scientific form (`1e9`, `5e-324`), never hundreds of digits.
pub fn show_value(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// `--sphere R`: a finite radius > 0, at most [`MAX_COORDINATE`] (mesh units; whether it fits
/// the object is checked once the mesh is loaded, [`check_tool`]).
pub fn parse_sphere(s: &str) -> Result<f64, String> {
    parse_length(s, "sphere radius")
}

/// A tool's size on the command line (`--sphere R`, `--depth D`): a finite number > 0 and at
/// most [`MAX_COORDINATE`] (mesh units). The floor relative to the object
/// ([`touchfem_core::contact::MIN_LENGTH_FRACTION`]) is checked once the mesh is loaded.
fn parse_length(s: &str, what: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|e| format!("'{s}' is not a number: {e}"))?;
    if !(v.is_finite() && v > 0.0 && v <= MAX_COORDINATE) {
        return Err(format!(
            "{what} {} must be a positive, finite length of at most {MAX_COORDINATE:e}",
            show_value(v)
        ));
    }
    Ok(v)
}

/// Checks a tool flag (`flag` and the value `given` in mesh units; the tool in metres) against
/// the objects it may touch (their bounding-box diagonals, m): the one rule for a user's
/// lengths, [`Tool::check_fits`], as a scene's `tool` is checked; it passes when it holds for
/// one object. A positive value that underflows to 0 m is too short, not a sign error.
pub fn check_tool(
    flag: &str,
    given: f64,
    tool: Tool,
    extents_m: &[f64],
) -> Result<(), crate::error::Error> {
    let mut first = None;
    for &x in extents_m {
        match tool.check_fits(x) {
            Ok(()) => return Ok(()),
            Err(e) => {
                first.get_or_insert(e);
            }
        }
    }
    match first {
        Some(e) => Err(crate::error::Error::Input(format!(
            "{flag} {}: {e}",
            show_value(given)
        ))),
        None => Ok(()),
    }
}

/// The bounding-box diagonal of a mesh, m.
pub fn extent_m(mesh: &Mesh) -> f64 {
    let (lo, hi) = mesh.bounds();
    lo.distance(hi)
}

/// Checks a `--sphere R` (mesh units) against the loaded mesh (metres, `unit` its file's
/// unit) by [`check_tool`]; returns the radius in metres.
pub fn check_sphere_fits(
    r: f64,
    mesh: &Mesh,
    unit: LengthUnit,
) -> Result<f64, crate::error::Error> {
    let r_m = r * unit.to_metres();
    check_tool(
        "--sphere",
        r,
        Tool::Sphere { radius_m: r_m },
        &[extent_m(mesh)],
    )?;
    Ok(r_m)
}

/// Checks a finger's motion flag (`--push`, `--slide`; `given` in mesh units) against the
/// loaded mesh: zero, or at least [`touchfem_core::contact::MIN_LENGTH_FRACTION`] of the
/// object's size (the rule of [`check_tool`]); a non-zero motion that underflows to 0 m is
/// too short.
pub fn check_motion(
    flag: &str,
    given: DVec3,
    mesh: &Mesh,
    unit: LengthUnit,
) -> Result<(), crate::error::Error> {
    let what = flag.trim_start_matches('-');
    let what: &'static str = if what == "slide" { "slide" } else { "push" };
    // |v| scaled by its largest component: a motion of 1e-300 mm does not square to 0.
    let v = given * unit.to_metres();
    let big = v.abs().max_element();
    let length_m = if big > 0.0 {
        big * (v / big).length()
    } else {
        0.0
    };
    touchfem_core::contact::check_length(what, length_m, extent_m(mesh), given == DVec3::ZERO)
        .map_err(|e| {
            crate::error::Error::Input(format!(
                "{flag} {},{},{}: {e}",
                show_value(given.x),
                show_value(given.y),
                show_value(given.z)
            ))
        })
}

/// `--friction MS,MD`: static and dynamic Coulomb coefficients, finite, >= 0, MD <= MS.
pub fn parse_friction(s: &str) -> Result<Friction, String> {
    let (ms, md) = s
        .split_once(',')
        .ok_or_else(|| format!("expected MS,MD (e.g. 0.6,0.4), got '{s}'"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<f64>()
            .map_err(|e| format!("'{v}' is not a number: {e}"))
    };
    Friction::new(num(ms)?, num(md)?).map_err(|e| e.to_string())
}

/// `--color`: how pictures colour the surface.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColorArg {
    /// By |u|, viridis, with a legend in mm.
    Displacement,
    /// One colour.
    Plain,
}

/// `--view`: where a picture's camera looks from.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewArg {
    /// The 3/4 view, the object filling the frame.
    Auto,
    /// The touched point from outside the surface.
    Contact,
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

/// The largest magnitude [`parse_vec3`] accepts for a coordinate (mesh units).
pub const MAX_COORDINATE: f64 = 1e9;

/// Parses a number for a flag: finite and within `lo..=hi`, or strictly above `lo` when
/// `lo_open` (clap's error then names the flag: `invalid value 'X' for '--flag <V>': ...`).
fn parse_bounded(s: &str, lo: f64, hi: f64, lo_open: bool) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|e| format!("'{s}' is not a number: {e}"))?;
    let above = if lo_open { v > lo } else { v >= lo };
    if !(v.is_finite() && above && v <= hi) {
        let open = if lo_open { '(' } else { '[' };
        return Err(format!("{} is outside {open}{lo}, {hi}]", show_value(v)));
    }
    Ok(v)
}

/// `serve --seconds`: a finite duration in (0, 1e6] seconds.
pub fn parse_serve_seconds(s: &str) -> Result<f64, String> {
    parse_bounded(s, 0.0, 1e6, true)
}

/// `demo --seconds`: a finite duration in (0, 3600] seconds.
pub fn parse_demo_seconds(s: &str) -> Result<f64, String> {
    parse_bounded(s, 0.0, 3600.0, true)
}

/// `serve --floor-seconds`: a finite duration in [0, 3600] seconds.
pub fn parse_floor_seconds(s: &str) -> Result<f64, String> {
    parse_bounded(s, 0.0, 3600.0, false)
}

/// `serve --watchdog-ms`: in (0, 60000] milliseconds.
pub fn parse_watchdog_ms(s: &str) -> Result<f64, String> {
    parse_bounded(s, 0.0, 60_000.0, true)
}

/// `--young`: Young's modulus in (0, 1e13] Pa.
pub fn parse_young(s: &str) -> Result<f64, String> {
    parse_bounded(s, 0.0, 1e13, true)
}

/// `--poisson`: Poisson's ratio in (-1, 0.5).
pub fn parse_poisson(s: &str) -> Result<f64, String> {
    match parse_bounded(s, -1.0, 0.5, true) {
        Ok(v) if v < 0.5 => Ok(v),
        Ok(v) => Err(format!(
            "{v} is outside (-1, 0.5): 0.5 exactly is incompressible, which no \
             displacement-only stiffness holds (use 0.4999 with --formulation locking-free)"
        )),
        Err(e) if e.ends_with(']') => Err(e.replace(", 0.5]", ", 0.5)")),
        Err(e) => Err(e),
    }
}

/// `--formulation`: `standard` or `locking-free`.
pub fn parse_formulation(s: &str) -> Result<Formulation, String> {
    s.trim().parse()
}

/// `poke --steps`: 1 to 1000000 haptic ticks.
pub fn parse_steps(s: &str) -> Result<usize, String> {
    s.trim()
        .parse::<usize>()
        .ok()
        .filter(|n| (1..=1_000_000).contains(n))
        .ok_or_else(|| format!("'{s}' is not a whole number in 1..=1000000"))
}

/// `X1,Y1,Z1:X2,Y2,Z2`: two points.
pub fn parse_segment(s: &str) -> Result<(DVec3, DVec3), String> {
    let Some((a, b)) = s.split_once(':') else {
        return Err(format!("expected X1,Y1,Z1:X2,Y2,Z2, got '{s}'"));
    };
    Ok((parse_vec3(a)?, parse_vec3(b)?))
}

/// A blade's depth: a positive, finite length of at most [`MAX_COORDINATE`] (mesh units; its
/// floor is checked against the mesh, [`check_tool`]).
pub fn parse_depth(s: &str) -> Result<f64, String> {
    parse_length(s, "blade depth")
}

/// Parses a compression tolerance: a number strictly between 0 and 1.
pub fn parse_tolerance(s: &str) -> Result<f64, String> {
    let e: f64 = s
        .trim()
        .parse()
        .map_err(|e| format!("'{s}' is not a number: {e}"))?;
    if !(e.is_finite() && e > 0.0 && e < 1.0) {
        return Err(format!(
            "'{s}' must be a tolerance between 0 and 1 (e.g. 1e-3)"
        ));
    }
    Ok(e)
}

/// Parses "x,y,z" into a finite vector, each component at most [`MAX_COORDINATE`] in
/// magnitude.
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
        if o.abs() > MAX_COORDINATE {
            return Err(format!(
                "'{p}' is larger than {MAX_COORDINATE:e} in magnitude"
            ));
        }
    }
    Ok(DVec3::from_array(v))
}
