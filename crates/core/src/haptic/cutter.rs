//! Cutting live, the part without threads (the cutter's thread is `runtime::cutting`): the
//! blade's strokes go from the haptic thread to a cutter off it, which
//! removes the tets they sweep ([`crate::cut`]), builds the exact correction of `L` and the
//! opened surface, and hands the whole cut body back; the haptic path installs it between two
//! ticks ([`crate::haptic::HapticWorld::install_cut`]) and the visual path draws from it.
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
//! * Past [`FOLD_RANK`] the correction is folded into a new `L`. By default the fold is
//!   deferred ([`FoldMode::Deferred`]): it runs beside the cuts as a [`FoldJob`], and the cuts
//!   made meanwhile are made again on the folded `L` when it is adopted, so no cut waits for
//!   a fold.

use std::sync::Arc;

use glam::DVec3;

use crate::compliance::Compliance;
use crate::contact::Surface;
use crate::cut::{blade_tets, BladeQuad, Cut, CutReport};
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

/// What a blade does to the material it passes ([`Cutter::set_cut_mode`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CutMode {
    /// It removes the tets its quad sweeps (`TOUCHFEM_CUT=remove` for a live cutter): a
    /// trench about one element wide, at a lower rank.
    Remove,
    /// It separates the material along its quad ([`Cut::split_within`], snap and split):
    /// nothing is removed but slivers, and the body's compliance grows by the copies and the
    /// exposed nodes ([`Cut::grown_correction`]), which its surface then holds. In
    /// [`FoldMode::Inline`] a fold due runs before the object's next cut, as the deferred
    /// one does, then is adopted at once. The default, the live cutter's included.
    #[default]
    Separate,
}

/// A cut object as both paths read it: the compliance with the cut's correction carried
/// beside `L`, and the opened rest surface.
#[derive(Debug)]
pub struct CutBody {
    /// `L` (shared with the uncut body) and the correction.
    pub compliance: Compliance,
    /// The rest surface of the remaining tets (the cut's faces included).
    pub surface: Surface,
    /// The surface's triangles as mesh node triples (what a renderer draws; a separating
    /// cut's name its copies, past the mesh's nodes).
    pub triangles: Vec<[u32; 3]>,
    /// Every node's rest position now (m): the mesh's, snapped onto a separating blade's
    /// plane where it moved, then the copies ([`CutMode::Separate`]).
    pub rest: Arc<Vec<DVec3>>,
    /// What the whole cut so far did.
    pub report: CutReport,
    /// Tets removed so far (every pass), the pieces' included.
    pub tets_removed: usize,
    /// Pieces cut off so far (left with no clamp: removed, their nodes pinned still).
    pub pieces_removed: usize,
    /// Copies a separating blade made so far ([`CutMode::Separate`]).
    pub nodes_split: usize,
    /// 1 for the first cut body of the object, then one more a body.
    pub generation: u64,
    /// The strokes (chords) that made it from the object's previous body, in order: what a
    /// recorded session keeps to build it again.
    pub strokes: Vec<Stroke>,
    /// How many times the object's correction was folded into a new `L` before this body
    /// (its compliance then holds that `L`, not the uncut one).
    pub folds: u32,
    /// Whether a deferred fold was adopted just before this body's strokes
    /// ([`Cutter::adopt`]): a recorded session keeps it, so that a replay adopts where the
    /// live run did.
    pub fold_adopted: bool,
}

/// How a [`Cutter`] folds its correction into a new `L` once its rank reaches the fold rank.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FoldMode {
    /// On the cutter's own time, just before the object's next cut (which waits for it):
    /// [`Cutter::fold_due`]. Sessions of version 3 were recorded so.
    Inline,
    /// Off the cutter: [`Cutter::take_folds`] hands out a [`FoldJob`] (a snapshot), which
    /// runs anywhere while the cuts go on, carried against the old `L`; [`Cutter::adopt`]
    /// then takes the folded `L` and replays on it the cuts made since the snapshot. No cut
    /// waits for a fold.
    #[default]
    Deferred,
}

/// What a cut did to an object while a fold of it was out, kept to do it again on the folded
/// `L` ([`Folded::catch_up`], [`Cutter::adopt`]).
#[derive(Clone, Debug)]
pub struct CutOp(Op);

#[derive(Clone, Debug)]
enum Op {
    /// A blade's chord.
    Stroke(Stroke),
    /// A separating blade's segment so far after the segment before it
    /// ([`CutMode::Separate`], [`blade_quads`]), and the mesh's mean edge.
    Separate(Vec<Stroke>, Vec<Stroke>, f64),
    /// Tets removed by [`Cutter::remove_tets`].
    Tets(Vec<usize>),
}

/// Makes `op` again on `cut` (of `mesh`, cut within `region`): the same tets as when it was
/// first made, since `cut` has removed the same ones before it.
fn redo(cut: &mut Cut, mesh: &crate::Mesh, region: &CutRegion, op: &CutOp) -> Result<(), Error> {
    let tets = match &op.0 {
        Op::Stroke(st) => blade_tets(mesh, st.from, st.to, st.inward, st.depth),
        Op::Tets(t) => t.clone(),
        Op::Separate(before, segment, edge) => {
            return separate(cut, mesh, region, before, segment, *edge).map(|_| ())
        }
    };
    let tets = still_to_cut(cut, region, tets);
    if !tets.is_empty() {
        cut.remove(mesh, &tets)?;
    }
    Ok(())
}

/// How far behind a fold's rebased cut lets its `V` fall while it makes the cuts since the
/// snapshot again ([`Cut::v_behind`]): past it, [`redo_carried`] brings `V` up to date.
const CATCH_UP_BEHIND: f64 = 0.25;

/// [`redo`] on a fold's rebased cut, then, where its `V` has fallen [`CATCH_UP_BEHIND`]
/// behind (or it has none), its correction against the folded `base` (the result dropped;
/// its `U` and `V` stay carried in the cut). So `V` follows the cuts on the fold's thread,
/// and the adoption's body finds it at most a quarter of `V` afresh behind, instead of
/// making it afresh at the rank of every cut since the snapshot (120–190 ms on the incision,
/// which the next cut waited for). Adopting a fold, a replay makes the same cuts again the
/// same way (the rule depends on the cuts alone), so the same bits.
fn redo_carried(
    cut: &mut Cut,
    base: &Compliance,
    mesh: &crate::Mesh,
    region: &CutRegion,
    op: &CutOp,
) -> Result<(), Error> {
    redo(cut, mesh, region, op)?;
    if cut.v_behind().is_none_or(|b| b >= CATCH_UP_BEHIND) {
        cut.correction(base)?;
    }
    Ok(())
}

/// The quads a separating blade cuts along: the blade's path in segments of about an edge
/// (`edge`: the mesh's mean edge), each cut as one straight quad from its first point to its
/// last; `segment` the chords of the one it is drawing (the last quad, which snaps) and
/// `before` those of the one before it (whose faces it completes across their joint). A
/// hand's blade wanders across its path by a fraction of a millimetre, so that a chord of
/// one pass turns by tens of degrees from the next; over an edge it turns by a few, and the
/// nodes snapped along a segment lie on one plane, which makes faces to cut. Each quad
/// reaches back out of the body by the blade's depth (the blade's shank: a blade drawn under
/// the surface came in through it, where a convex body has no material) and down to the
/// nearest layer of nodes (the faces a cut opens are the mesh's, so a cut is as deep as the
/// blade to within half an edge). Empty when the segment makes no quad (too short, not
/// finite, a depth ≤ 0).
pub fn blade_quads(before: &[Stroke], segment: &[Stroke], edge: f64) -> Vec<BladeQuad> {
    let span = |chords: &[Stroke]| -> Option<BladeQuad> {
        let (first, last) = (chords.first()?, chords.last()?);
        let along = (last.to - first.from).normalize_or_zero();
        let up = -(last.inward - along * along.dot(last.inward)).normalize_or_zero();
        let (from, to) = (first.from + up * last.depth, last.to + up * last.depth);
        BladeQuad::new(from, to, last.inward, 2.0 * last.depth + 0.5 * edge).ok()
    };
    let Some(last) = span(segment) else {
        return Vec::new();
    };
    span(before).into_iter().chain([last]).collect()
}

/// The length a segment of a separating blade's path spans ([`blade_quads`]), m.
fn span_length(chords: &[Stroke]) -> f64 {
    match (chords.first(), chords.last()) {
        (Some(a), Some(b)) => a.from.distance(b.to),
        _ => 0.0,
    }
}

/// Separates `cut` (of `mesh`, within `region`) along a blade's segment after the segment
/// before it ([`blade_quads`], `edge` the mesh's mean edge); the report when it changed
/// anything. A segment that makes no quad (too short, not finite) changes nothing.
fn separate(
    cut: &mut Cut,
    mesh: &crate::Mesh,
    region: &CutRegion,
    before: &[Stroke],
    segment: &[Stroke],
    edge: f64,
) -> Result<Option<crate::cut::SplitReport>, Error> {
    let quads = blade_quads(before, segment, edge);
    if quads.is_empty() {
        return Ok(None);
    }
    // (The segment snaps; the one before only adds the faces now on its plane.)
    let (before, last) = quads.split_at(quads.len() - 1);
    let rep = cut.split_after(mesh, before, last, Some(region.mask()))?;
    let changed =
        rep.nodes_snapped > 0 || rep.nodes_split > 0 || rep.slivers > 0 || rep.cut.tets_removed > 0;
    Ok(changed.then_some(rep))
}

/// A cut of `mesh` with `L₀`'s columns solved up front at the DOFs it may reach: the
/// nodes of `region`'s tets (`cut::Columns`; none where they would not fit its budget; a
/// snap that reaches past the region solves for those few).
fn region_cut(
    mesh: &crate::Mesh,
    region: &CutRegion,
    helper: Option<&[usize]>,
) -> Result<Cut, Error> {
    let mut cut = Cut::new(mesh)?;
    let mut mark = vec![false; mesh.nodes.len()];
    for (t, nodes) in mesh.tets.iter().enumerate() {
        if region.contains(t) {
            for &v in nodes {
                mark[v as usize] = true;
            }
        }
    }
    cut.precompute_columns_on(&mark, helper);
    Ok(cut)
}

/// Those of `tets` that `cut` may still remove: in its `region`, and not removed yet.
fn still_to_cut(cut: &Cut, region: &CutRegion, tets: Vec<usize>) -> Vec<usize> {
    let removed = cut.removed();
    (tets.into_iter())
        .filter(|&t| region.contains(t) && !removed[t])
        .collect()
}

/// A fold taken off a [`Cutter`] ([`Cutter::take_folds`]): the object's compliance with its
/// correction at the snapshot, and its cut's rebase. Runs on any thread ([`FoldJob::run`]).
pub struct FoldJob {
    object: usize,
    compliance: Compliance,
    rebase: crate::cut::Rebase,
    mesh: crate::Mesh,
    region: CutRegion,
}

/// A finished [`FoldJob`]: the folded `L` and the cut rebased on it, for [`Cutter::adopt`],
/// with the first cuts made since the snapshot already made again on it
/// ([`Folded::catch_up`]).
pub struct Folded {
    object: usize,
    base: Compliance,
    cut: Cut,
    mesh: crate::Mesh,
    region: CutRegion,
    /// How many of the cuts since the snapshot it has made again.
    applied: usize,
}

impl FoldJob {
    /// The object it folds.
    pub fn object(&self) -> usize {
        self.object
    }

    /// Folds the correction into a new `L` and factors the cut body afresh (the heavy part:
    /// about 0.1–1 s on the mouse). Returns the object and the result.
    pub fn run(self) -> (usize, Result<Folded, Error>) {
        let o = self.object;
        let run = || -> Result<Folded, Error> {
            let base = self.compliance.folded().map_err(Error::from)?;
            let cut = self.rebase.run()?;
            Ok(Folded {
                object: o,
                base,
                cut,
                mesh: self.mesh,
                region: self.region,
                applied: 0,
            })
        };
        (o, run())
    }
}

impl Folded {
    /// The object it folds.
    pub fn object(&self) -> usize {
        self.object
    }

    /// Makes again the cuts made since the snapshot that it has not made yet, carrying `U`
    /// and `V` along as the adoption does (`redo_carried`): `ops` are
    /// [`Cutter::fold_ops`] as they stand (or any longer prefix of them), so that the fold's
    /// thread catches up with the cutter and the adoption is left little to do.
    pub fn catch_up(&mut self, ops: &[CutOp]) -> Result<(), Error> {
        for op in ops.iter().skip(self.applied) {
            redo_carried(&mut self.cut, &self.base, &self.mesh, &self.region, op)?;
            self.applied += 1;
        }
        Ok(())
    }

    /// How many cuts since the snapshot it has made again.
    pub fn applied(&self) -> usize {
        self.applied
    }
}

struct ObjectCut {
    cut: Cut,
    base: Compliance,
    mesh: crate::Mesh,
    region: CutRegion,
    generation: u64,
    tets_removed: usize,
    pieces_removed: usize,
    /// Copies made so far (a separating cut's).
    nodes_split: usize,
    last: CutReport,
    since: Vec<Stroke>,
    folds: u32,
    /// The compliance of the object's last body (the correction as cut so far).
    current: Option<Compliance>,
    /// While a deferred fold is out: what was cut since its snapshot.
    in_flight: Option<Vec<CutOp>>,
    /// A fold was adopted since the last body.
    adopted: bool,
    /// A separating blade's segment before the one it draws, and the chords of that one
    /// so far ([`blade_quads`]).
    before: Vec<Stroke>,
    segment: Vec<Stroke>,
    /// The mesh's mean edge, m.
    edge: f64,
}

impl ObjectCut {
    /// A fold of object `o`'s last body (a snapshot), now out (`None`: no body yet).
    fn fold_job(&mut self, o: usize) -> Result<Option<FoldJob>, Error> {
        let Some(compliance) = self.current.clone() else {
            return Ok(None);
        };
        let job = FoldJob {
            object: o,
            compliance,
            rebase: self.cut.rebase_plan(&self.mesh)?,
            mesh: self.mesh.clone(),
            region: self.region.clone(),
        };
        self.in_flight = Some(Vec::new());
        Ok(Some(job))
    }

    /// Removes `tets` from object `o` (and any piece left with no clamp) and counts them.
    fn remove(&mut self, o: usize, tets: &[usize]) -> Result<(), Error> {
        let report = self.cut.remove(&self.mesh, tets)?;
        self.tets_removed += report.tets_removed;
        self.pieces_removed += report.pieces_removed;
        if report.pieces_removed > 0 {
            log::info!(
                "a cut took {} piece(s) off object {o} (no clamp held them): removed",
                report.pieces_removed
            );
        }
        self.last = report;
        Ok(())
    }
}

/// What a [`Cutter`] is made from: each cuttable object's mesh, compliance and region.
pub struct CutPlan {
    objects: Vec<Option<(crate::Mesh, Compliance, CutRegion)>>,
    /// Whether [`Cutter::from_plan`] solves `L₀`'s columns at the regions' DOFs up front.
    columns: bool,
    /// Cores where a helper may solve half of them in their idle time (the haptic loop's).
    helper: Option<Vec<usize>>,
}

impl CutPlan {
    /// A plan whose cutter solves every column a cut needs as it goes, none up front: a
    /// quicker start and slower passes (the web page's single thread). The same bits.
    pub fn without_columns(mut self) -> CutPlan {
        self.columns = false;
        self
    }

    /// A plan whose cutter shares the columns it solves up front with a helper thread on
    /// `cpus` (the haptic loop's cores), in their idle time (`Cut::precompute_columns_on`).
    pub fn with_helper_on(mut self, cpus: Vec<usize>) -> CutPlan {
        self.helper = Some(cpus);
        self
    }
}

/// The rank at which a cutter folds its correction into `L` (see [`Cutter::fold_due`]): a
/// cut body's construction grows as the rank squared (`V = U Cᵀ`), and on the mouse it
/// passes a display frame (16 ms, with the removal) between ranks 120 (6 ms) and 360
/// (44 ms); a fold there costs about 0.15 s off the haptic thread (measured in
/// docs/measurements/2026-12-04-cutting.md).
pub const FOLD_RANK: usize = 160;

/// The off-thread side of cutting: each cuttable object's kept factor and correction.
pub struct Cutter {
    objects: Vec<Option<ObjectCut>>,
    fold_rank: usize,
    mode: FoldMode,
    cut_mode: CutMode,
    /// Cores where a helper makes part of each `V` (`Cut::share_v_with`).
    helper: Option<Arc<[usize]>>,
}

impl Cutter {
    /// Prepares every cuttable object of `world`: factors its stiffness and solves `L₀`'s
    /// columns at its cuttable region's DOFs up front (a solve per DOF, 1.8 s for the
    /// incision's 2,466 on a 2-core VM; none past `cut::columns::BUDGET`), so that a cut's
    /// pass reads them instead of solving. Errors on an object whose `L` is not
    /// held on the host or whose formulation cannot be cut.
    pub fn new(world: &World) -> Result<Cutter, Error> {
        Cutter::from_plan(Cutter::plan(world)?)
    }

    /// What [`Cutter::new`] needs of `world`, copied (cheap: `L` is shared), so that the
    /// factorisation can run on another thread ([`Cutter::from_plan`]).
    pub fn plan(world: &World) -> Result<CutPlan, Error> {
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
            objects.push(Some((
                obj.body.mesh.clone(),
                obj.body.compliance.clone(),
                region.clone(),
            )));
        }
        Ok(CutPlan {
            objects,
            columns: true,
            helper: None,
        })
    }

    /// Factors every planned object's stiffness.
    pub fn from_plan(plan: CutPlan) -> Result<Cutter, Error> {
        let mut objects = Vec::with_capacity(plan.objects.len());
        for p in plan.objects {
            objects.push(match p {
                None => None,
                Some((mesh, base, region)) => Some(ObjectCut {
                    cut: if plan.columns {
                        region_cut(&mesh, &region, plan.helper.as_deref())?
                    } else {
                        Cut::new(&mesh)?
                    },
                    before: Vec::new(),
                    segment: Vec::new(),
                    edge: mesh.mean_edge(),
                    base,
                    mesh,
                    region,
                    generation: 0,
                    tets_removed: 0,
                    pieces_removed: 0,
                    nodes_split: 0,
                    last: CutReport::default(),
                    since: Vec::new(),
                    folds: 0,
                    current: None,
                    in_flight: None,
                    adopted: false,
                }),
            });
        }
        Ok(Cutter {
            objects,
            fold_rank: FOLD_RANK,
            mode: FoldMode::default(),
            cut_mode: CutMode::default(),
            helper: plan.helper.map(Arc::from),
        })
    }

    /// How many columns of `L₀` its objects' cuts hold up front (`Cut::columns_held`).
    pub fn columns_held(&self) -> usize {
        (self.objects.iter().flatten())
            .map(|oc| oc.cut.columns_held())
            .sum()
    }

    /// Sets how the cutter folds (default [`FoldMode::Deferred`]).
    pub fn set_fold_mode(&mut self, mode: FoldMode) {
        self.mode = mode;
    }

    /// How the cutter folds.
    pub fn fold_mode(&self) -> FoldMode {
        self.mode
    }

    /// Sets what a blade does (default [`CutMode::Separate`]). Set it before the first cut.
    pub fn set_cut_mode(&mut self, mode: CutMode) {
        self.cut_mode = mode;
    }

    /// What a blade does.
    pub fn cut_mode(&self) -> CutMode {
        self.cut_mode
    }

    /// In [`FoldMode::Deferred`]: a [`FoldJob`] for every object whose rank has reached the
    /// fold rank and that has no fold out, each a snapshot of its last body (call it right
    /// after the bodies are built: [`Cutter::apply_all`], [`Cutter::apply_strokes`]). Empty
    /// in [`FoldMode::Inline`].
    pub fn take_folds(&mut self) -> Result<Vec<FoldJob>, Error> {
        let mut jobs = Vec::new();
        if self.mode != FoldMode::Deferred {
            return Ok(jobs);
        }
        let due = self.fold_rank.max(1);
        for (o, oc) in self.objects.iter_mut().enumerate() {
            let Some(oc) = oc else { continue };
            if oc.in_flight.is_some() || oc.cut.rank() < due {
                continue;
            }
            if let Some(job) = oc.fold_job(o)? {
                jobs.push(job);
            }
        }
        Ok(jobs)
    }

    /// Takes a finished fold: the object's `L` becomes the folded one and its cut the rebased
    /// one, on which the cuts made since the snapshot are made again (the same tets, so the
    /// same body, now carried against the folded `L`). The next body says so
    /// ([`CutBody::fold_adopted`]); [`Cutter::body_now`] builds it at once. Errors when no
    /// fold of that object is out, or when a cut cannot be made again (the object then keeps
    /// its unfolded state).
    pub fn adopt(&mut self, f: Folded) -> Result<(), Error> {
        let Some(Some(oc)) = self.objects.get_mut(f.object) else {
            return Err(Error::Input(format!("object {} is not cuttable", f.object)));
        };
        let Some(ops) = oc.in_flight.take() else {
            return Err(Error::Input(format!(
                "object {} has no fold out to adopt",
                f.object
            )));
        };
        if f.applied > ops.len() {
            oc.in_flight = Some(ops);
            return Err(Error::Input(format!(
                "a fold of object {} made more cuts again than were made",
                f.object
            )));
        }
        let mut cut = f.cut;
        for op in &ops[f.applied..] {
            if let Err(e) = redo_carried(&mut cut, &f.base, &oc.mesh, &oc.region, op) {
                oc.in_flight = Some(ops);
                return Err(e);
            }
        }
        oc.cut = cut;
        oc.base = f.base;
        oc.folds += 1;
        oc.adopted = true;
        Ok(())
    }

    /// The cuts made on object `o` since the snapshot of its fold out (empty when none is
    /// out), in order: what [`Folded::catch_up`] makes again.
    pub fn fold_ops(&self, o: usize) -> &[CutOp] {
        match self.objects.get(o) {
            Some(Some(ObjectCut {
                in_flight: Some(ops),
                ..
            })) => ops,
            _ => &[],
        }
    }

    /// Forgets object `o`'s fold out (it failed): the object carries its correction on, and
    /// [`Cutter::take_folds`] may hand it out again.
    pub fn drop_fold(&mut self, o: usize) {
        if let Some(Some(oc)) = self.objects.get_mut(o) {
            oc.in_flight = None;
        }
    }

    /// Object `o`'s body as it stands (after [`Cutter::adopt`]: the same cut, carried
    /// against the folded `L`, with no strokes of its own).
    pub fn body_now(&mut self, o: usize) -> Result<Arc<CutBody>, Error> {
        self.body(o)
    }

    /// Sets the rank past which [`Cutter::fold_due`] folds (default [`FOLD_RANK`]).
    pub fn set_fold_rank(&mut self, rank: usize) {
        self.fold_rank = rank;
    }

    /// In [`FoldMode::Inline`] (else it does nothing): folds the correction of every object
    /// whose rank has reached the fold rank into a new `L` ([`Cut::fold`]) and starts its cut
    /// afresh from it ([`Cut::rebase`]), so that the next body carries only what is cut after.
    /// Returns how many objects it folded. The bodies already handed out stay valid (they
    /// share the old `L`). An object is also folded, when due, just before its next cut, so a
    /// fold always happens at the same point of its cuts (a replay folds where the live run
    /// did).
    pub fn fold_due(&mut self) -> Result<usize, Error> {
        let mut n = 0;
        for o in 0..self.objects.len() {
            n += usize::from(self.fold_object(o)?);
        }
        Ok(n)
    }

    /// Folds object `o` when its rank has reached the fold rank; true when it did.
    fn fold_object(&mut self, o: usize) -> Result<bool, Error> {
        if self.mode != FoldMode::Inline {
            return Ok(false);
        }
        let Some(Some(oc)) = self.objects.get_mut(o) else {
            return Ok(false);
        };
        if oc.cut.rank() < self.fold_rank.max(1) {
            return Ok(false);
        }
        if self.cut_mode == CutMode::Separate {
            // The deferred fold (a grown correction's), run here and adopted at once: a
            // replay that defers it adopts it at the same body.
            let Some(job) = oc.fold_job(o)? else {
                return Ok(false);
            };
            return match job.run() {
                (_, Ok(f)) => self.adopt(f).map(|()| true),
                (_, Err(e)) => {
                    self.drop_fold(o);
                    Err(e)
                }
            };
        }
        let folded = oc.cut.fold(&oc.base)?;
        oc.cut = oc.cut.rebase(&oc.mesh)?;
        oc.base = folded;
        oc.folds += 1;
        Ok(true)
    }

    /// The tets removed from object `o` so far (`None`: it is not cuttable).
    pub fn removed(&self, o: usize) -> Option<&[bool]> {
        self.objects.get(o)?.as_ref().map(|oc| oc.cut.removed())
    }

    /// Object `o`'s cut as it stands (its nodes, tets and copies; `None`: not cuttable).
    pub fn cut(&self, o: usize) -> Option<&Cut> {
        self.objects.get(o)?.as_ref().map(|oc| &oc.cut)
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
        if !self.cut_only(stroke)? {
            return Ok(None);
        }
        self.body(stroke.object).map(Some)
    }

    /// Removes `tets` (indices into object `o`'s mesh; those outside its cuttable region or
    /// already removed are ignored) and any piece left with no clamp, as a blade would, and
    /// returns the object's new cut body, or `None` when nothing was removed. For scripted
    /// cuts and measurements; a live run cuts with a blade's strokes. Not recorded in sessions.
    pub fn remove_tets(&mut self, o: usize, tets: &[usize]) -> Result<Option<Arc<CutBody>>, Error> {
        let Some(Some(oc)) = self.objects.get(o) else {
            return Ok(None);
        };
        let removed = oc.cut.removed();
        let n = oc.mesh.tets.len();
        let tets: Vec<usize> = tets
            .iter()
            .copied()
            .filter(|&t| t < n && oc.region.contains(t) && !removed[t])
            .collect();
        if tets.is_empty() {
            return Ok(None);
        }
        self.fold_object(o)?;
        let Some(Some(oc)) = self.objects.get_mut(o) else {
            return Ok(None);
        };
        oc.remove(o, &tets)?;
        if let Some(ops) = &mut oc.in_flight {
            ops.push(CutOp(Op::Tets(tets)));
        }
        self.body(o).map(Some)
    }

    /// Object `o`'s strokes, in order (a recorded cut event): cuts along each, then builds
    /// one body. `None` when they removed nothing.
    pub fn apply_strokes(
        &mut self,
        o: usize,
        strokes: &[Stroke],
    ) -> Result<Option<Arc<CutBody>>, Error> {
        if !self.feed_strokes(o, strokes)? {
            return Ok(None);
        }
        self.body(o).map(Some)
    }

    /// Object `o`'s strokes that came before a fold's adoption (a session's adopting body's
    /// strokes: a separating blade's chords that changed nothing, kept for its segments and
    /// for the next body), fed to the cutter as when they were made, before
    /// [`Cutter::adopt`]. True when one of them changed something (then the session does not
    /// match its scene).
    pub fn feed_strokes(&mut self, o: usize, strokes: &[Stroke]) -> Result<bool, Error> {
        let mut any = false;
        for s in strokes.iter().filter(|s| s.object == o) {
            any |= self.cut_only(s)?;
        }
        Ok(any)
    }

    /// Removes what `stroke` sweeps; true when it removed something (and then records it
    /// among the strokes of the object's next body).
    fn cut_only(&mut self, stroke: &Stroke) -> Result<bool, Error> {
        let Some(Some(oc)) = self.objects.get_mut(stroke.object) else {
            return Ok(false);
        };
        // A blade of no depth (or a depth not finite) cuts nothing, whatever it does: the
        // separating quad's margin below would otherwise give it half an edge.
        if !(stroke.depth.is_finite() && stroke.depth > 0.0) {
            return Ok(false);
        }
        if self.cut_mode == CutMode::Separate {
            self.fold_object(stroke.object)?;
            let Some(Some(oc)) = self.objects.get_mut(stroke.object) else {
                return Ok(false);
            };
            if blade_quads(&[], std::slice::from_ref(stroke), oc.edge).is_empty() {
                return Ok(false);
            }
            // The blade's segments: a chord that goes on from the last one extends the
            // segment being drawn (another starts the path afresh).
            let joined = oc.segment.last().or(oc.before.last()).is_some_and(|p| {
                p.object == stroke.object && p.to == stroke.from && p.depth == stroke.depth
            });
            if !joined {
                oc.before.clear();
                oc.segment.clear();
            }
            oc.segment.push(*stroke);
            let (before, segment) = (oc.before.clone(), oc.segment.clone());
            // Once it spans an edge, the segment is done: the next chord starts the next.
            if span_length(&oc.segment) >= oc.edge {
                oc.before = std::mem::take(&mut oc.segment);
            }
            // (Every chord joins the next body's strokes, those that cut nothing too: a
            // replay makes the same segments.)
            oc.since.push(*stroke);
            let Some(rep) = separate(
                &mut oc.cut,
                &oc.mesh,
                &oc.region,
                &before,
                &segment,
                oc.edge,
            )?
            else {
                return Ok(false);
            };
            oc.tets_removed += rep.cut.tets_removed;
            oc.pieces_removed += rep.cut.pieces_removed;
            oc.nodes_split += rep.nodes_split;
            oc.last = rep.cut;
            if let Some(ops) = &mut oc.in_flight {
                ops.push(CutOp(Op::Separate(before, segment, oc.edge)));
            }
            return Ok(true);
        }
        let swept = blade_tets(
            &oc.mesh,
            stroke.from,
            stroke.to,
            stroke.inward,
            stroke.depth,
        );
        let tets = still_to_cut(&oc.cut, &oc.region, swept);
        if tets.is_empty() {
            return Ok(false);
        }
        // (Folded only before a stroke that cuts: a recorded session holds just those.)
        self.fold_object(stroke.object)?;
        let Some(Some(oc)) = self.objects.get_mut(stroke.object) else {
            return Ok(false);
        };
        oc.remove(stroke.object, &tets)?;
        oc.since.push(*stroke);
        if let Some(ops) = &mut oc.in_flight {
            ops.push(CutOp(Op::Stroke(*stroke)));
        }
        Ok(true)
    }

    /// Object `o`'s cut body as it stands: the correction, the opened surface.
    fn body(&mut self, o: usize) -> Result<Arc<CutBody>, Error> {
        let Some(Some(oc)) = self.objects.get_mut(o) else {
            return Err(Error::Input(format!("object {o} is not cuttable")));
        };
        oc.cut
            .share_v_with(self.helper.clone(), crate::cut::V_SHARE_ABOVE);
        let separating = oc.cut.copies() > 0 || self.cut_mode == CutMode::Separate;
        // (The opened mesh and its contact surface are made while a helper makes `V`.)
        let (correction, (open, surface)) = if separating {
            let (k, (open, surface)) = oc.cut.correction_meanwhile(&oc.base, || {
                let open = oc.cut.separated_mesh(&oc.mesh);
                let surface = Surface::new(&open);
                (open, surface)
            })?;
            (oc.cut.grown(&oc.base, k, &open.surface)?, (open, surface))
        } else {
            oc.cut.correction_meanwhile(&oc.base, || {
                let mut open = oc.mesh.clone();
                open.surface = oc.mesh.open_surface(oc.cut.removed());
                let surface = Surface::new(&open);
                (open, surface)
            })?
        };
        let compliance = oc
            .base
            .with_correction(Arc::new(correction))
            .map_err(Error::from)?;
        oc.generation += 1;
        oc.current = Some(compliance.clone());
        Ok(Arc::new(CutBody {
            compliance,
            surface,
            rest: Arc::new(open.nodes),
            triangles: open.surface,
            report: oc.last.clone(),
            tets_removed: oc.tets_removed,
            pieces_removed: oc.pieces_removed,
            nodes_split: oc.nodes_split,
            generation: oc.generation,
            strokes: std::mem::take(&mut oc.since),
            folds: oc.folds,
            fold_adopted: std::mem::take(&mut oc.adopted),
        }))
    }

    /// [`Cutter::apply`] on a run of strokes: consecutive strokes of one object with the same
    /// blade are joined into their chord first, and each object that lost tets gets one new
    /// body (whose `strokes` are the chords, in order).
    pub fn apply_all(&mut self, strokes: &[Stroke]) -> Result<Vec<(usize, Arc<CutBody>)>, Error> {
        let mut changed: Vec<usize> = Vec::new();
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
            if self.cut_only(&s)? && !changed.contains(&s.object) {
                changed.push(s.object);
            }
            k = j;
        }
        changed
            .into_iter()
            .map(|o| Ok((o, self.body(o)?)))
            .collect()
    }
}

/// The newest cut body of each object, for the visual path: written by the cutter's thread,
/// read by the visual loop (the haptic thread never touches it, so its lock is not shared
/// with the haptic path).
#[derive(Debug, Default)]
pub struct CutFeed {
    bodies: std::sync::Mutex<Vec<(usize, Arc<CutBody>)>>,
    /// Bumped at each new body.
    pub generation: std::sync::atomic::AtomicU64,
}

impl CutFeed {
    /// Publishes object `o`'s new body.
    pub fn publish(&self, o: usize, body: Arc<CutBody>) {
        let mut g = self.bodies.lock().unwrap_or_else(|e| e.into_inner());
        g.retain(|(k, _)| *k != o);
        g.push((o, body));
        self.generation
            .fetch_add(1, std::sync::atomic::Ordering::Release);
    }

    /// Each object's newest body.
    pub fn latest(&self) -> Vec<(usize, Arc<CutBody>)> {
        self.bodies
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }
}
