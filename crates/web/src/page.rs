//! The page's engine side, plain Rust: what the page loads, how it presses, how it ticks.
//! Nothing here knows the browser; `crate::js` wraps it for the page, and the native tests
//! call it directly.

use glam::DVec3;
use std::sync::Arc;
use touchfem_core::compliance::Compliance;
use touchfem_core::contact::force::ForceModel;
use touchfem_core::devices::KeyframePath;
use touchfem_core::haptic::cutter::{CutBody, Cutter, FoldMode, Stroke};
use touchfem_core::haptic::{HapticWorld, WorldSample};
use touchfem_core::limits::MAX_FINGERS;
use touchfem_core::scene::pointer::{blade_twin, pointer_fingers, BladeTwin};
use touchfem_core::scene::{DeviceSpec, SceneSource, World};
use touchfem_core::Error;

/// The scenes and meshes the page offers (its `scene=` values).
pub const PAGE_SCENES: &[&str] = &[
    "fig1", "fig2", "palpate", "incision", "pinch", "rub", "cube", "mouse", "phantom",
];

/// Haptic ticks a scripted press is split into: `touchfem poke`'s default `--steps`.
pub const POKE_STEPS: usize = 50;

/// Ticks the page steps at most per animation frame (a tab in the background, or a slow
/// frame, does not pile up seconds of haptic time to catch up).
pub const MAX_TICKS_PER_FRAME: usize = 100;

/// Haptic ticks between two cut passes of a scripted run ([`PageWorld::run_scripts`]): a
/// display frame at 60 Hz, as the live page cuts once a frame.
pub const RUN_TICKS_PER_PASS: usize = 16;

/// Blade strokes kept between two cut passes ([`PageWorld::cut`]); more are dropped and
/// counted (the page cuts once a frame, so a frame's strokes always fit).
pub const MAX_PENDING_STROKES: usize = 4 * MAX_TICKS_PER_FRAME * MAX_FINGERS;

/// Where a page's compliance came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ComplianceSource {
    /// Computed in the page, by the engine, on one thread.
    Computed,
    /// Read from a cache file's bytes.
    Cache,
}

impl ComplianceSource {
    /// `"computed"` or `"cache"`.
    pub fn as_str(self) -> &'static str {
        match self {
            ComplianceSource::Computed => "computed",
            ComplianceSource::Cache => "cache",
        }
    }
}

/// The scene source of `spec`: a bundled scene, or a bundled mesh as a one-object scene whose
/// one finger is the pointer. [`PageWorld::load`] adds the pointer and its blade twin.
pub fn scene_source(spec: &str) -> Result<SceneSource, Error> {
    if !PAGE_SCENES.contains(&spec) {
        return Err(Error::Input(format!(
            "unknown scene '{spec}': the page has {}",
            PAGE_SCENES.join(", ")
        )));
    }
    Ok(SceneSource::find(spec)?.unwrap_or_else(|| SceneSource::for_mesh(spec, "pointer")))
}

/// The compliance of `spec`'s one object, computed here and written as a cache file's bytes
/// ([`touchfem_core::cache::to_bytes`]): what the page's worker computes off the page's
/// thread and hands to [`PageWorld::load`]. `None` for a scene of several objects (the page
/// computes those itself) or a compressed one.
pub fn compute_cache(spec: &str) -> Result<Option<Vec<u8>>, Error> {
    let plans = World::plan(&scene_source(spec)?)?;
    let [plan] = &plans[..] else {
        return Ok(None);
    };
    if plan.compression.is_some() {
        return Ok(None);
    }
    let c = Compliance::compute(&plan.mesh, &plan.selection)?;
    Ok(Some(touchfem_core::cache::to_bytes(
        &c,
        plan.key,
        plan.mesh.nodes.len(),
    )?))
}

/// A scripted press, as `touchfem poke MESH --at X,Y,Z --push DX,DY,DZ [--sphere R] [--exact]`
/// on the scene's first object (its own frame, the scene's unit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PressSpec {
    /// Where the finger first goes (the surface point nearest it is touched), scene unit.
    pub at: DVec3,
    /// How far it then moves, scene unit.
    pub push: DVec3,
    /// A sphere of this radius (scene unit) instead of a point finger.
    pub sphere: Option<f64>,
    /// The exact force model instead of the paper's (a point finger).
    pub exact: bool,
}

impl PressSpec {
    /// Parses the page's `press=X,Y,Z:DX,DY,DZ` value.
    pub fn parse(press: &str) -> Result<PressSpec, Error> {
        let bad = || {
            Error::Input(format!(
                "press '{press}': expected X,Y,Z:DX,DY,DZ (six finite numbers)"
            ))
        };
        let (a, b) = press.split_once(':').ok_or_else(bad)?;
        let vec = |s: &str| -> Result<DVec3, Error> {
            let v: Vec<f64> = s
                .split(',')
                .map(|x| x.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|_| bad())?;
            match v[..] {
                [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(DVec3::new(x, y, z)),
                _ => Err(bad()),
            }
        };
        Ok(PressSpec {
            at: vec(a)?,
            push: vec(b)?,
            sphere: None,
            exact: false,
        })
    }
}

/// What a scripted press gave.
#[derive(Clone, Debug, PartialEq)]
pub struct PressOutcome {
    /// The force fed back to the finger, N (`poke --json`'s `force`).
    pub force: DVec3,
    /// The contact forces on the first object: (column of `L`, force), N.
    pub forces: Vec<(u32, DVec3)>,
    /// The finger's end position (the sphere's centre), scene frame, m.
    pub finger: DVec3,
    /// The god-object (a point finger in contact), scene frame, m.
    pub proxy: Option<DVec3>,
}

/// A page's scene: the world, its haptic state, and the fingers' inputs.
pub struct PageWorld {
    /// The scene (leaked: one per page load, alive as long as the page).
    pub world: &'static World,
    hw: HapticWorld<'static>,
    sample: WorldSample,
    positions: [DVec3; MAX_FINGERS],
    forces: [DVec3; MAX_FINGERS],
    scripts: Vec<Option<KeyframePath>>,
    pointer: Option<usize>,
    pointer_at: DVec3,
    t: f64,
    /// Where the compliance came from.
    pub source: ComplianceSource,
    /// The pointer's blade twin, when an object can be cut.
    twin: Option<BladeTwin>,
    /// Whether the pointer drives its blade twin (`B`).
    blade: bool,
    /// The cutter (one thread: [`PageWorld::cut`] runs it between frames), when the scene has
    /// a blade and a cuttable object.
    cutter: Option<Cutter>,
    /// Strokes since the last cut pass.
    strokes: Vec<Stroke>,
    /// Strokes that did not fit before a cut pass.
    pub strokes_dropped: u64,
    /// Cut bodies made since the renderer last took them.
    new_bodies: Vec<(usize, Arc<CutBody>)>,
    /// Tets removed so far, every object (slivers, with the default blade that separates).
    pub tets_removed: usize,
    /// Copies of nodes the blade has made so far, every object (the material parted).
    pub nodes_split: usize,
    /// Cut bodies made so far.
    pub cut_bodies: u64,
}

impl PageWorld {
    /// Loads `spec` ([`scene_source`]): each object's compliance read from `cache` (a cache
    /// file's bytes, for a one-object scene) when given and valid for it, else computed here.
    /// A cache that does not fit (another mesh, material or selection, or damaged) is an error,
    /// not a silent recompute: the page asked for it.
    pub fn load(spec: &str, cache: Option<&[u8]>) -> Result<PageWorld, Error> {
        let src = scene_source(spec)?;
        let mut source = ComplianceSource::Computed;
        let mut compute =
            |plan: &touchfem_core::scene::file::PlannedObject| -> Result<Compliance, Error> {
                if let Some(bytes) = cache {
                    source = ComplianceSource::Cache;
                    return Ok(touchfem_core::cache::load_bytes(
                        bytes,
                        plan.key,
                        plan.mesh.nodes.len(),
                    )?);
                }
                Ok(match &plan.compression {
                    Some(o) => {
                        Compliance::compute_hier(&plan.mesh, &plan.selection, o, &mut |_, _| {})?
                    }
                    None => Compliance::compute(&plan.mesh, &plan.selection)?,
                })
            };
        let mut src = src;
        let mut world = World::from_source_by(&src, &mut compute)?;
        // The pointer, and its blade twin where an object is cuttable, as `touchfem view` adds
        // them; the compliances do not depend on the fingers and are taken over.
        let extra = pointer_fingers(&world, None);
        if !extra.is_empty() {
            src.text.push_str(&extra);
            let mut done = world.objects.iter().map(|o| o.body.compliance.clone());
            world = World::from_source_by(&src, &mut |plan| {
                done.next().ok_or_else(|| {
                    Error::Input(format!("object '{}' appeared on reload", plan.name))
                })
            })?;
        }
        if cache.is_some() && world.objects.len() != 1 {
            return Err(Error::Input(format!(
                "a cache file holds one object's compliance; '{spec}' has {}",
                world.objects.len()
            )));
        }
        PageWorld::new(Box::leak(Box::new(world)), source)
    }

    /// The page's state around an already loaded world; a world with a blade finger and a
    /// cuttable object gets its cutter (the stiffness factorised here).
    pub fn new(world: &'static World, source: ComplianceSource) -> Result<PageWorld, Error> {
        let scripts = world
            .fingers
            .iter()
            .map(|f| match &f.device {
                DeviceSpec::Script(keys) => KeyframePath::new(keys.clone()),
                _ => None,
            })
            .collect();
        let pointer = world
            .fingers
            .iter()
            .position(|f| f.device == DeviceSpec::Pointer);
        let blades = world.fingers.iter().any(|f| f.tool.blade_depth().is_some());
        let cutter = if blades && world.objects.iter().any(|o| o.cuttable.is_some()) {
            // One thread here: each fold runs inline, before the object's next cut, and no
            // columns of `L₀` are solved up front (the page would load seconds later).
            let mut c = Cutter::from_plan(Cutter::plan(world)?.without_columns())?;
            c.set_fold_mode(FoldMode::Inline);
            Some(c)
        } else {
            None
        };
        Ok(PageWorld {
            world,
            hw: HapticWorld::new(world),
            sample: WorldSample::default(),
            positions: [DVec3::NAN; MAX_FINGERS],
            forces: [DVec3::ZERO; MAX_FINGERS],
            scripts,
            pointer,
            pointer_at: DVec3::NAN,
            t: 0.0,
            source,
            twin: blade_twin(world).ok(),
            blade: false,
            cutter,
            strokes: Vec::with_capacity(MAX_PENDING_STROKES),
            strokes_dropped: 0,
            new_bodies: Vec::new(),
            tets_removed: 0,
            nodes_split: 0,
            cut_bodies: 0,
        })
    }

    /// `B`: the pointer becomes its blade twin, or the scene's pointer finger again (both
    /// lifted). Returns whether blade mode is now on, or why the pointer cannot cut here.
    pub fn toggle_blade(&mut self) -> Result<bool, Error> {
        match blade_twin(self.world) {
            Ok(_) if self.cutter.is_some() => {
                self.pointer_at = DVec3::NAN;
                self.blade = !self.blade;
                Ok(self.blade)
            }
            Ok(_) => Err(Error::Input("blade: no cutter for this scene".into())),
            Err(why) => Err(Error::Input(why)),
        }
    }

    /// Whether the pointer drives its blade twin.
    pub fn blade_on(&self) -> bool {
        self.blade
    }

    /// The blade twin's depth while blade mode is on, m.
    pub fn blade_depth_m(&self) -> Option<f64> {
        self.twin.filter(|_| self.blade).map(|t| t.depth_m)
    }

    /// One cut pass (the page's cutter, between frames, as the cutter's thread runs it
    /// natively): the strokes since the last pass cut the cuttable objects, each new cut body
    /// is installed in the haptic world (from the next tick its force solve reads it) and
    /// kept for the renderer ([`PageWorld::take_cut_bodies`]); a correction due is folded into
    /// a new `L`. Returns how many bodies it made.
    pub fn cut(&mut self) -> Result<usize, Error> {
        let Some(cutter) = self.cutter.as_mut() else {
            self.strokes.clear();
            return Ok(0);
        };
        if self.strokes.is_empty() {
            return Ok(0);
        }
        let bodies = cutter.apply_all(&self.strokes)?;
        self.strokes.clear();
        let n = bodies.len();
        for (o, body) in bodies {
            self.cut_bodies += 1;
            self.hw.install_cut(o, body.clone());
            self.new_bodies.retain(|(k, _)| *k != o);
            self.new_bodies.push((o, body));
        }
        let bodies = || (0..self.world.objects.len()).filter_map(|o| self.hw.cut_body(o));
        self.tets_removed = bodies().map(|b| b.tets_removed).sum();
        self.nodes_split = bodies().map(|b| b.nodes_split).sum();
        cutter.fold_due()?;
        Ok(n)
    }

    /// A scripted run, the same on every machine: `seconds` of haptic time of the scene's own
    /// scripts (the pointer lifted), a cut pass every [`RUN_TICKS_PER_PASS`] ticks. The page's
    /// `run=SECONDS` and the native tests call it alike, so that cuts and forces compare.
    pub fn run_scripts(&mut self, seconds: f64) -> Result<(), Error> {
        if !(seconds.is_finite() && seconds >= 0.0) {
            return Err(Error::Input(format!(
                "run: {seconds} s is not a finite, non-negative duration"
            )));
        }
        self.pointer_at = DVec3::NAN;
        let mut left = (seconds * self.world.haptics.rate_hz).round() as usize;
        while left > 0 {
            let n = left.min(RUN_TICKS_PER_PASS);
            self.tick(n);
            self.cut()?;
            left -= n;
        }
        Ok(())
    }

    /// Object `o`'s cut body in the haptic world, if it was cut.
    pub fn cut_body(&self, o: usize) -> Option<&Arc<CutBody>> {
        self.hw.cut_body(o)
    }

    /// The force last sent to each finger, N.
    pub fn finger_forces(&self) -> &[DVec3] {
        &self.forces[..self.world.fingers.len().min(MAX_FINGERS)]
    }

    /// The cut bodies made since the last call, each object's newest: for the renderer
    /// ([`touchfem_gpu::install_cut`]).
    pub fn take_cut_bodies(&mut self) -> Vec<(usize, Arc<CutBody>)> {
        std::mem::take(&mut self.new_bodies)
    }

    /// The scripted press on the first object, as `touchfem poke` does it: the same engine
    /// calls ([`touchfem_core::scene::Body::poke`] with `steps` ticks, or
    /// [`touchfem_core::scene::Body::poke_sphere`]), scene units in, SI out.
    pub fn press(&self, p: &PressSpec, steps: usize) -> Result<PressOutcome, Error> {
        let o = self
            .world
            .objects
            .first()
            .ok_or_else(|| Error::Input("the scene has no object".into()))?;
        let s = self.world.unit.to_metres();
        let (at, push) = (p.at * s, p.push * s);
        let body = &o.body;
        match p.sphere {
            Some(r) => {
                let sp = body.poke_sphere(at, push, r * s, None, None)?;
                Ok(PressOutcome {
                    force: sp.feedback,
                    forces: sp.forces,
                    finger: sp.centre + o.offset,
                    proxy: None,
                })
            }
            None => {
                let model = if p.exact {
                    ForceModel::Exact
                } else {
                    ForceModel::Paper
                };
                let k = body.poke(at, push, model, steps)?;
                Ok(PressOutcome {
                    force: k.feedback,
                    forces: k.bc.entries().to_vec(),
                    finger: k.touch_point + push + o.offset,
                    proxy: k.contact.map(|c| c.proxy + o.offset),
                })
            }
        }
    }

    /// Puts the pointer's finger at `p` (scene frame, m; NaN lifts it). A scene without a
    /// pointer finger ignores it.
    pub fn set_pointer(&mut self, p: DVec3) {
        self.pointer_at = p;
    }

    /// Whether the scene has a pointer finger.
    pub fn has_pointer(&self) -> bool {
        self.pointer.is_some()
    }

    /// Steps `n` haptic ticks (at most [`MAX_TICKS_PER_FRAME`]) of the scene's period: the
    /// scripts at their time (looping), the pointer (or its blade twin) where it was put; the
    /// blades' strokes are kept for the next [`PageWorld::cut`]. Allocates nothing.
    pub fn tick(&mut self, n: usize) {
        let period = 1.0 / self.world.haptics.rate_hz;
        let n_f = self.world.fingers.len().min(MAX_FINGERS);
        // The finger the pointer drives: the pointer's, or its blade twin in blade mode.
        let driven = match self.twin {
            Some(t) if self.blade => Some(t.finger),
            _ => self.pointer,
        };
        for _ in 0..n.min(MAX_TICKS_PER_FRAME) {
            self.t += period;
            for i in 0..n_f {
                self.positions[i] = match &mut self.scripts[i] {
                    _ if driven == Some(i) => self.pointer_at,
                    Some(path) => {
                        let d = path.duration();
                        let t = if d > 0.0 { self.t % d } else { 0.0 };
                        path.at(t)
                    }
                    None => DVec3::NAN,
                };
            }
            self.hw.step_dt(
                period,
                &self.positions[..n_f],
                &mut self.forces[..n_f],
                &mut self.sample,
            );
            for s in self.hw.strokes() {
                if self.strokes.len() < MAX_PENDING_STROKES {
                    self.strokes.push(*s);
                } else {
                    self.strokes_dropped += 1;
                }
            }
        }
    }

    /// The latest tick's sample (boundary conditions, finger views).
    pub fn sample(&self) -> &WorldSample {
        &self.sample
    }

    /// The force last sent to the pointer's finger, N (zero without a pointer).
    pub fn pointer_force(&self) -> DVec3 {
        self.pointer.map_or(DVec3::ZERO, |i| self.forces[i])
    }

    /// The largest force any finger got at the latest tick, N.
    pub fn max_force(&self) -> f64 {
        let n = self.world.fingers.len().min(MAX_FINGERS);
        self.forces[..n]
            .iter()
            .map(|f| f.length())
            .fold(0.0, f64::max)
    }

    /// Haptic time so far, s.
    pub fn time(&self) -> f64 {
        self.t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn press_values_parse_and_bad_ones_are_refused() {
        let p = PressSpec::parse("15,15,30:0,0,-3").unwrap();
        assert_eq!(p.at, DVec3::new(15.0, 15.0, 30.0));
        assert_eq!(p.push, DVec3::new(0.0, 0.0, -3.0));
        for bad in [
            "",
            "1,2,3",
            "1,2:3,4,5",
            "1,2,3:4,5,nan",
            "a,b,c:1,2,3",
            "1,2,3:4,5,6,7",
        ] {
            assert!(PressSpec::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn unknown_scenes_are_refused_and_palpate_gets_a_pointer_without_a_twin() {
        assert!(scene_source("nope").is_err());
        assert!(PageWorld::load("nope", None).is_err());
        // palpate has scripted fingers only and nothing cuttable: the page adds its pointer,
        // and `B` says why it cannot cut.
        let mut p = PageWorld::load("palpate", None).unwrap();
        let fingers = &p.world.fingers;
        let pointers = fingers.iter().filter(|f| f.device == DeviceSpec::Pointer);
        assert_eq!(pointers.count(), 1);
        assert!(fingers.iter().all(|f| f.tool.blade_depth().is_none()));
        let why = p.toggle_blade().unwrap_err().to_string();
        assert!(why.contains("cuttable"), "{why}");
        assert!(!p.blade_on());
    }

    /// `B` on the incision page: the pointer gets the scene blade's depth (8 mm) for its twin;
    /// with blade mode on, a slide across the cuttable ball parts it at zero force (copies of
    /// the nodes on the blade's quad, each on it), and the pointer's press beside the cut is
    /// then softer than the same press before it.
    #[test]
    fn the_incision_pages_blade_cuts_and_softens_the_tissue_beside_it() {
        let mut p = PageWorld::load("incision", None).unwrap();
        let w = p.world;
        let twin = blade_twin(w).unwrap();
        assert_eq!(twin.depth_m, 8e-3);
        assert_eq!(w.fingers[twin.pointer].device, DeviceSpec::Pointer);
        // The incision's own scripts stay lifted here: pin the time before their blade enters.
        let press = |p: &mut PageWorld| {
            p.set_pointer(DVec3::new(-15.0, 5.5, 21.0) * 1e-3);
            p.tick(5);
            p.set_pointer(DVec3::new(-15.0, 5.5, 18.5) * 1e-3);
            for _ in 0..3 {
                p.tick(100);
            }
            let f = p.pointer_force();
            p.set_pointer(DVec3::NAN);
            p.tick(5);
            p.t = 0.0;
            f
        };
        let before = press(&mut p);
        assert!(before.z > 5e-3, "{before:?}");
        assert!(p.toggle_blade().unwrap());
        assert_eq!(p.blade_depth_m(), Some(8e-3));
        // The blade's top 0.5 mm under the top face (z = 20 mm), slid 20 mm along y = 0.
        let (a, b) = (DVec3::new(-25.0, 0.0, 19.5), DVec3::new(-5.0, 0.0, 19.5));
        for k in 0..=40 {
            p.set_pointer(a.lerp(b, k as f64 / 40.0) * 1e-3);
            p.tick(2);
            assert_eq!(p.pointer_force(), DVec3::ZERO, "a blade presses nothing");
            p.t = 0.0;
            if k % 10 == 0 {
                p.cut().unwrap();
            }
        }
        p.cut().unwrap();
        let bodies = p.take_cut_bodies();
        assert_eq!(bodies.len(), 1);
        // The default blade separates: copies of the nodes on its quad, each on the blade's
        // plane (y = 0) and within 1 mm of the quad (its edge and the surface above its top
        // snap to it), and no tets dropped but slivers.
        let body = &bodies[0].1;
        let n0 = w.objects[0].body.mesh.nodes.len();
        let copies = &body.rest[n0..];
        eprintln!(
            "the page's blade: {} copies, {} tets dropped; copies x {:?} mm, z {:?} mm",
            body.nodes_split,
            body.tets_removed,
            copies
                .iter()
                .map(|c| c.x * 1e3)
                .fold((f64::MAX, f64::MIN), |r, x| (r.0.min(x), r.1.max(x))),
            copies
                .iter()
                .map(|c| c.z * 1e3)
                .fold((f64::MAX, f64::MIN), |r, z| (r.0.min(z), r.1.max(z))),
        );
        assert!(body.nodes_split >= 10, "{}", body.nodes_split);
        assert_eq!(copies.len(), body.nodes_split);
        assert_eq!(p.nodes_split, body.nodes_split);
        assert!(p.tets_removed <= 3 * body.nodes_split, "{}", p.tets_removed);
        for c in copies {
            let inside = c.y.abs() < 1e-9
                && (a.x - 1.0..=b.x + 1.0).contains(&(c.x * 1e3))
                && (a.z - 8.0 - 1.0..=a.z + 1.0).contains(&(c.z * 1e3));
            assert!(inside, "a copy off the blade's quad: {:?} mm", *c * 1e3);
        }
        p.pointer_at = DVec3::NAN;
        assert!(!p.toggle_blade().unwrap());
        let after = press(&mut p);
        assert!(after.is_finite());
        // (A slit 5.5 mm away: about 2 % softer; a trench of removed tets made it 3 % and more.)
        assert!(
            after.z < 0.99 * before.z,
            "beside the cut the press should be softer: {:.4} N before, {:.4} N after",
            before.z,
            after.z
        );
    }

    #[test]
    fn the_cube_press_is_pokes_and_the_pointer_ticks_within_the_bound() {
        let mut p = PageWorld::load("cube", None).unwrap();
        assert_eq!(p.source, ComplianceSource::Computed);
        let spec = PressSpec::parse("15,15,30:0,0,-3").unwrap();
        let got = p.press(&spec, POKE_STEPS).unwrap();
        // The same press on the engine's Body directly (what `touchfem poke` calls).
        let o = &p.world.objects[0];
        let s = p.world.unit.to_metres();
        let want = o
            .body
            .poke(spec.at * s, spec.push * s, ForceModel::Paper, POKE_STEPS)
            .unwrap();
        assert_eq!(got.force, want.feedback);
        assert!(got.force.z > 0.01, "{:?}", got.force);
        // The pointer pressing 3 mm into the top face for 200 ticks: a finite upward force
        // within the scene's bound.
        p.set_pointer(DVec3::new(15.0, 15.0, 31.0) * s);
        p.tick(5);
        p.set_pointer(DVec3::new(15.0, 15.0, 27.0) * s);
        for _ in 0..4 {
            p.tick(50);
        }
        let f = p.pointer_force();
        assert!(f.is_finite() && f.z > 0.01, "{f:?}");
        assert!(f.length() <= p.world.haptics.max_force_n + 1e-12);
        p.set_pointer(DVec3::NAN);
        p.tick(10);
        assert_eq!(p.pointer_force(), DVec3::ZERO);
    }

    #[test]
    fn a_cache_files_bytes_give_the_computed_compliance() {
        let computed = PageWorld::load("cube", None).unwrap();
        let o = &computed.world.objects[0];
        let plan = &World::plan(&scene_source("cube").unwrap()).unwrap()[0];
        let dir = std::env::temp_dir().join(format!("touchfem-web-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("cube.tfc");
        touchfem_core::cache::save(&path, &o.body.compliance, plan.key, o.body.mesh.nodes.len())
            .unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let cached = PageWorld::load("cube", Some(&bytes)).unwrap();
        assert_eq!(cached.source, ComplianceSource::Cache);
        let spec = PressSpec::parse("10,12,30:0,0,-2").unwrap();
        assert_eq!(
            cached.press(&spec, 10).unwrap().force,
            computed.press(&spec, 10).unwrap().force
        );
        // A damaged file is an error, not a silent recompute.
        let mut bad = bytes.clone();
        let k = bad.len() / 2;
        bad[k] ^= 0x55;
        assert!(PageWorld::load("cube", Some(&bad)).is_err());
        // And another scene's file is refused.
        assert!(PageWorld::load("mouse", Some(&bytes)).is_err());
        // The worker's bytes are the file's.
        assert!(compute_cache("cube").unwrap().unwrap() == bytes);
        assert!(compute_cache("nope").is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
