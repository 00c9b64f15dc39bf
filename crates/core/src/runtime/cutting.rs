//! Cutting live: the blade's strokes go from the haptic thread to a cutter off it, which
//! removes the tets they sweep ([`crate::cut`]), builds the exact correction of `L` and the
//! opened surface, and hands the whole cut body back; the haptic path installs it between two
//! ticks ([`crate::runtime::HapticWorld::install_cut`]) and the visual path draws from it.
//! The haptic tick never waits for a cut: until the new body arrives it reads the last one.
//!
//! * A blade finger ([`crate::contact::Tool::Blade`]) engages when its god-object touches (the
//!   device at or below the surface): the blade then hangs `depth` below the device position
//!   along the inward normal of the triangle it entered by, and each tick's motion is a
//!   [`Stroke`]. It disengages when the god-object is free again.
//! * Only an object with a `cuttable` region is cut, and only the region's tets.
//! * The cutter coalesces the strokes that arrived since its last pass into one quad (the
//!   chord of the blade's path), so one pass costs one sweep of the mesh's tets whatever the
//!   haptic rate.

use std::sync::Arc;

use glam::DVec3;

use crate::compliance::Compliance;
use crate::contact::Surface;
use crate::cut::{blade_tets, Cut, CutReport};
use crate::scene::{CutRegion, World};
use crate::Error;

/// The blade's motion during one tick, in its object's frame (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stroke {
    /// The object it cuts.
    pub object: usize,
    /// The blade's top (the device position) at the start and the end of the tick.
    pub from: DVec3,
    /// See `from`.
    pub to: DVec3,
    /// The inward normal the blade hangs along (unit).
    pub inward: DVec3,
    /// The blade's depth, m.
    pub depth: f64,
}

/// A cut object as both paths read it: the compliance with the cut's correction carried
/// beside `L`, and the opened rest surface.
#[derive(Debug)]
pub struct CutBody {
    /// `L` (shared with the uncut body) and the correction.
    pub compliance: Compliance,
    /// The rest surface of the remaining tets (the cut's faces included).
    pub surface: Surface,
    /// The surface's triangles as mesh node triples (what a renderer draws).
    pub triangles: Vec<[u32; 3]>,
    /// What the whole cut so far did.
    pub report: CutReport,
    /// Tets removed so far (every pass).
    pub tets_removed: usize,
    /// 1 for the first cut body of the object, then one more a body.
    pub generation: u64,
}

struct ObjectCut {
    cut: Cut,
    base: Compliance,
    mesh: crate::Mesh,
    region: CutRegion,
    generation: u64,
    tets_removed: usize,
}

/// The off-thread side of cutting: each cuttable object's kept factor and correction.
pub struct Cutter {
    objects: Vec<Option<ObjectCut>>,
}

impl Cutter {
    /// Prepares every cuttable object of `world` (factors its stiffness: the part of the
    /// precompute a cut needs, kept rather than `L`'s columns at every cuttable DOF, which
    /// would cost a full column solve per DOF up front). Errors on an object whose `L` is not
    /// held on the host or whose formulation cannot be cut.
    pub fn new(world: &World) -> Result<Cutter, Error> {
        let mut objects = Vec::with_capacity(world.objects.len());
        for obj in &world.objects {
            let Some(region) = &obj.cuttable else {
                objects.push(None);
                continue;
            };
            if !obj.body.compliance.holds_l() {
                return Err(Error::Input(format!(
                    "object '{}' is cuttable but its L is not held in memory",
                    obj.name
                )));
            }
            objects.push(Some(ObjectCut {
                cut: Cut::new(&obj.body.mesh)?,
                base: obj.body.compliance.clone(),
                mesh: obj.body.mesh.clone(),
                region: region.clone(),
                generation: 0,
                tets_removed: 0,
            }));
        }
        Ok(Cutter { objects })
    }

    /// The tets removed from object `o` so far (`None`: it is not cuttable).
    pub fn removed(&self, o: usize) -> Option<&[bool]> {
        self.objects.get(o)?.as_ref().map(|oc| oc.cut.removed())
    }

    /// Whether any object can be cut.
    pub fn any(&self) -> bool {
        self.objects.iter().any(|o| o.is_some())
    }

    /// Cuts along `stroke`: removes the region's tets its quad sweeps (and any piece that
    /// loses every clamp), and returns the object's new cut body, or `None` when it removed
    /// nothing (or the object is not cuttable). A degenerate or non-finite stroke removes
    /// nothing.
    pub fn apply(&mut self, stroke: &Stroke) -> Result<Option<Arc<CutBody>>, Error> {
        let Some(Some(oc)) = self.objects.get_mut(stroke.object) else {
            return Ok(None);
        };
        let removed = oc.cut.removed();
        let tets: Vec<usize> = blade_tets(
            &oc.mesh,
            stroke.from,
            stroke.to,
            stroke.inward,
            stroke.depth,
        )
        .into_iter()
        .filter(|&t| oc.region.contains(t) && !removed[t])
        .collect();
        if tets.is_empty() {
            return Ok(None);
        }
        let report = oc.cut.remove(&oc.mesh, &tets)?;
        oc.tets_removed += report.tets_removed;
        let correction = oc.cut.correction(&oc.base)?;
        let compliance = oc
            .base
            .with_correction(Arc::new(correction))
            .map_err(Error::from)?;
        let mut open = oc.mesh.clone();
        open.surface = oc.mesh.open_surface(oc.cut.removed());
        let surface = Surface::new(&open);
        oc.generation += 1;
        Ok(Some(Arc::new(CutBody {
            compliance,
            surface,
            triangles: open.surface,
            report,
            tets_removed: oc.tets_removed,
            generation: oc.generation,
        })))
    }

    /// [`Cutter::apply`] on a run of strokes: consecutive strokes of one object with the same
    /// blade are joined into their chord first. Returns each object's newest body.
    pub fn apply_all(&mut self, strokes: &[Stroke]) -> Result<Vec<(usize, Arc<CutBody>)>, Error> {
        let mut out: Vec<(usize, Arc<CutBody>)> = Vec::new();
        let mut k = 0;
        while k < strokes.len() {
            let mut s = strokes[k];
            let mut j = k + 1;
            while j < strokes.len()
                && strokes[j].object == s.object
                && strokes[j].inward == s.inward
                && strokes[j].depth == s.depth
            {
                s.to = strokes[j].to;
                j += 1;
            }
            if let Some(body) = self.apply(&s)? {
                out.retain(|(o, _)| *o != s.object);
                out.push((s.object, body));
            }
            k = j;
        }
        Ok(out)
    }
}
