//! The page's engine side, plain Rust: what the page loads, how it presses, how it ticks.
//! Nothing here knows the browser; `crate::js` wraps it for the page, and the native tests
//! call it directly.

use glam::DVec3;
use touchfem_core::compliance::Compliance;
use touchfem_core::contact::force::ForceModel;
use touchfem_core::devices::KeyframePath;
use touchfem_core::haptic::{HapticWorld, WorldSample};
use touchfem_core::limits::MAX_FINGERS;
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

/// The scene source of `spec` (a bundled scene or mesh name) with the page's pointer: a scene
/// without a pointer finger gets one (`[[finger]] device = "pointer"` appended) when it has
/// room for it, as `touchfem view` does; a mesh's one finger is the pointer.
pub fn scene_source(spec: &str) -> Result<SceneSource, Error> {
    if !PAGE_SCENES.contains(&spec) {
        return Err(Error::Input(format!(
            "unknown scene '{spec}': the page has {}",
            PAGE_SCENES.join(", ")
        )));
    }
    let Some(mut src) = SceneSource::find(spec)? else {
        return Ok(SceneSource::for_mesh(spec, "pointer"));
    };
    let fingers = World::fingers_of(&src)?;
    if !fingers.iter().any(|f| f.device == DeviceSpec::Pointer) && fingers.len() < MAX_FINGERS {
        src.text.push_str("\n[[finger]]\ndevice = \"pointer\"\n");
    }
    Ok(src)
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
        let world = World::from_source_by(&src, &mut compute)?;
        if cache.is_some() && world.objects.len() != 1 {
            return Err(Error::Input(format!(
                "a cache file holds one object's compliance; '{spec}' has {}",
                world.objects.len()
            )));
        }
        Ok(PageWorld::new(Box::leak(Box::new(world)), source))
    }

    /// The page's state around an already loaded world.
    pub fn new(world: &'static World, source: ComplianceSource) -> PageWorld {
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
        PageWorld {
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
        }
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
    /// scripts at their time (looping), the pointer where it was put. Allocates nothing.
    pub fn tick(&mut self, n: usize) {
        let period = 1.0 / self.world.haptics.rate_hz;
        let n_f = self.world.fingers.len().min(MAX_FINGERS);
        for _ in 0..n.min(MAX_TICKS_PER_FRAME) {
            self.t += period;
            for i in 0..n_f {
                self.positions[i] = match (&mut self.scripts[i], self.pointer == Some(i)) {
                    (_, true) => self.pointer_at,
                    (Some(path), _) => {
                        let d = path.duration();
                        let t = if d > 0.0 { self.t % d } else { 0.0 };
                        path.at(t)
                    }
                    (None, false) => DVec3::NAN,
                };
            }
            self.hw.step_dt(
                period,
                &self.positions[..n_f],
                &mut self.forces[..n_f],
                &mut self.sample,
            );
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
    fn unknown_scenes_are_refused_and_scenes_get_a_pointer() {
        assert!(scene_source("nope").is_err());
        // palpate has scripted fingers only: the page adds its pointer.
        let src = scene_source("palpate").unwrap();
        let f = World::fingers_of(&src).unwrap();
        assert_eq!(
            f.iter().filter(|f| f.device == DeviceSpec::Pointer).count(),
            1
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
        let _ = std::fs::remove_dir_all(&dir);
    }
}
