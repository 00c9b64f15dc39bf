//! The cut body ([`Cut`]): the factor of the body it started from, the body as cut (nodes
//! and their copies, tets, removed tets, pinned nodes), and the exact correction of `L` that
//! removal and separation share.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use glam::{DMat3, DVec3};
use nalgebra::DMatrix;

use crate::fem::{element_stiffness, Dofs, Factor, Stiffness};
use crate::mesh::{face_neighbours, tet_face as face, tet_volume, Mesh};
use crate::Error;

/// Copies of nodes whose rows `L_D` holds beyond those made so far (zero rows).
const LD_ROOM: usize = 128;

/// What one [`Cut::remove`] (or the removal part of a [`Cut::split`]) did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CutReport {
    /// Tets removed by this call (those asked for and not yet removed, and those of the
    /// pieces it cut off; a split's slivers).
    pub tets_removed: usize,
    /// Pieces that lost every clamp and were removed.
    pub pieces_removed: usize,
    /// Nodes pinned (left with no tet).
    pub nodes_pinned: usize,
    /// The correction's rank (the DOFs it touches) after the call.
    pub rank: usize,
}

/// A tet as it was before a cut changed it: its nodes and their positions (so its stiffness).
#[derive(Clone, Copy, Debug)]
pub(super) struct Before {
    /// The tet.
    pub tet: usize,
    /// Its nodes then.
    pub nodes: [u32; 4],
    /// Their positions then (m).
    pub at: [DVec3; 4],
}

/// The tets one cut changes (moves, relabels or removes), each noted once, before its first
/// change, in the order they were first changed.
pub(super) struct Changes {
    /// The tets' states before the cut.
    pub list: Vec<Before>,
    seen: Vec<bool>,
}

impl Changes {
    /// Nothing changed yet on a body of `tets` tets.
    pub fn new(tets: usize) -> Changes {
        Changes {
            list: Vec::new(),
            seen: vec![false; tets],
        }
    }

    /// Notes tet `t` of `cut` as it stands now, unless it was noted already.
    pub fn note(&mut self, cut: &Cut, t: usize) {
        if !self.seen[t] {
            self.seen[t] = true;
            let nodes = cut.tets[t];
            self.list.push(Before {
                tet: t,
                nodes,
                at: nodes.map(|v| cut.nodes[v as usize]),
            });
        }
    }
}

/// A body being cut: the factor of the body it started from, the body as it is cut (its
/// nodes with their copies, tets, removed tets, pinned nodes) and the exact correction of `L`.
///
/// Its DOFs are the factored body's free DOFs (numbered as the stiffness numbers them), then
/// three for each unclamped copy a [`Cut::split`] made since (in the order they were made):
/// `K₀ = blockdiag(K, S)`, with `S` each copy's own diagonal (its node's in `K`).
pub struct Cut {
    /// The factored body's free DOFs, over its nodes (`base_nodes` of them).
    pub(super) dofs: Dofs,
    pub(super) base_nodes: usize,
    pub(super) factor: Factor,
    /// The diagonal of `K₀` at each DOF (a pinned DOF's own stiffness, a copy's `S`).
    pub(super) diag0: Vec<f64>,
    /// Per node past the factored body's: its first DOF, or `u32::MAX` when clamped.
    copy_dof: Vec<u32>,
    /// The uncut mesh's node count.
    uncut_nodes: usize,
    /// The uncut body's boundary faces (their nodes, sorted): a split's snap keeps its shape.
    pub(super) outer: std::sync::Arc<std::collections::HashSet<[u32; 3]>>,
    /// Every node's rest position (m), the copies' after the uncut mesh's.
    pub(super) nodes: Vec<DVec3>,
    /// Every tet's nodes (indices as the uncut mesh's; a moved tet names the copy).
    pub(super) tets: Vec<[u32; 4]>,
    /// Per node: clamped (a copy of a clamped node is clamped).
    pub(super) fixed: Vec<bool>,
    /// Per node: the uncut mesh's node it is (itself) or copies.
    pub(super) origin: Vec<u32>,
    /// Per node: the unit normal of the plane its clamped faces lie in (a clamped node may
    /// slide in it), or zero (it may not move: unclamped nodes ignore it).
    pub(super) clamp_normal: Vec<DVec3>,
    /// Per tet: its volume in the uncut mesh (m³).
    pub(super) vol0: Vec<f64>,
    /// Per tet: removed.
    pub(super) removed: Vec<bool>,
    /// Per node: tets left.
    tets_left: Vec<u32>,
    /// Per tet: the tet across each face (the face opposite each node), or `u32::MAX`. A cut
    /// only parts faces (a split moves one side's tets onto copies), never joins them.
    nbr: Vec<[u32; 4]>,
    /// Per node: pinned (no tet left, or in a removed piece).
    pub(super) pinned: Vec<bool>,
    /// The DOFs the correction touches, in order; and each DOF's place (or MAX).
    pub(super) d: Vec<usize>,
    pub(super) place: Vec<u32>,
    /// `ΔK′` on `D`.
    pub(super) dk: DMatrix<f64>,
    /// `L_D`: every DOF's row of `L₀`, `D`'s columns.
    pub(super) ld: DMatrix<f64>,
    /// `C = (I − ΔK′ L_DD)⁻¹ ΔK′`.
    pub(super) cap: DMatrix<f64>,
    /// What [`Cut::correction`]'s `V` is made from next (`cut/carry.rs`).
    pub(super) carried: std::sync::Mutex<super::carried::Carried>,
    /// `L₀`'s columns solved up front (`cut/columns.rs`).
    pub(super) columns: Option<std::sync::Arc<super::columns::Columns>>,
}

/// A cut's rebase, planned ([`Cut::rebase_plan`]) and not yet run: the separated body and
/// the state the rebased cut starts from.
pub struct Rebase {
    rest: Mesh,
    state: State,
    /// The nodes whose columns of `L₀` the rebased cut holds up front (`cut/columns.rs`),
    /// and what they are derived from (`cut/derive.rs`).
    columns: Option<(Vec<bool>, super::columns::Derive)>,
}

impl Rebase {
    /// Assembles and factors the separated body: the rebased cut ([`Cut::rebase`]), with
    /// its columns held up front where the cut it comes from had them (derived from it).
    pub fn run(self) -> Result<Cut, Error> {
        let mut cut = Cut::factored(&self.rest, self.state)?;
        if let Some((nodes, from)) = self.columns {
            cut.derive_columns(&nodes, &from);
        }
        Ok(cut)
    }
}

/// The body as cut, carried from a [`Cut`] to its rebased successor.
struct State {
    nodes: Vec<DVec3>,
    tets: Vec<[u32; 4]>,
    fixed: Vec<bool>,
    origin: Vec<u32>,
    clamp_normal: Vec<DVec3>,
    vol0: Vec<f64>,
    removed: Vec<bool>,
    pinned: Vec<bool>,
    uncut_nodes: usize,
    outer: std::sync::Arc<std::collections::HashSet<[u32; 3]>>,
}

/// What a cut changes of a [`Cut`], kept to put back when it fails.
pub(super) struct Saved {
    nodes: Vec<DVec3>,
    tets: Vec<[u32; 4]>,
    fixed: Vec<bool>,
    origin: Vec<u32>,
    clamp_normal: Vec<DVec3>,
    removed: Vec<bool>,
    tets_left: Vec<u32>,
    nbr: Vec<[u32; 4]>,
    pinned: Vec<bool>,
    diag0: Vec<f64>,
    copy_dof: Vec<u32>,
    d: Vec<usize>,
    place: Vec<u32>,
    dk: DMatrix<f64>,
    /// `L_D`'s shape: a cut only adds rows (zero in the old columns: a copy's DOFs are
    /// decoupled in `K₀`) and columns, so a failed one truncates it back.
    ld_shape: (usize, usize),
    cap: DMatrix<f64>,
}

/// Per node: the unit normal of the plane all its clamped boundary faces lie in, or zero
/// (none, or not one plane).
fn clamp_normals(mesh: &Mesh) -> Vec<DVec3> {
    let mut out = vec![DVec3::ZERO; mesh.nodes.len()];
    let mut bent = vec![false; mesh.nodes.len()];
    for f in &mesh.surface {
        if !f.iter().all(|&v| mesh.fixed[v as usize]) {
            continue;
        }
        let [a, b, c] = f.map(|v| mesh.nodes[v as usize]);
        let n = (b - a).cross(c - a).normalize_or_zero();
        if n == DVec3::ZERO {
            continue;
        }
        for &v in f {
            let o = &mut out[v as usize];
            if *o == DVec3::ZERO {
                *o = n;
            } else if o.dot(n).abs() < 1.0 - 1e-9 {
                bent[v as usize] = true;
            }
        }
    }
    for (o, b) in out.iter_mut().zip(bent) {
        if b {
            *o = DVec3::ZERO;
        }
    }
    out
}

impl Cut {
    /// Prepares `mesh` for cutting: assembles and factors its stiffness (as the precompute
    /// does). Errors on the locking-free formulation.
    pub fn new(mesh: &Mesh) -> Result<Cut, Error> {
        let n = mesh.nodes.len();
        let state = State {
            nodes: mesh.nodes.clone(),
            tets: mesh.tets.clone(),
            fixed: mesh.fixed.clone(),
            origin: (0..n as u32).collect(),
            clamp_normal: clamp_normals(mesh),
            vol0: (mesh.tets.iter())
                .map(|t| {
                    let p = t.map(|v| mesh.nodes[v as usize]);
                    tet_volume(p[0], p[1], p[2], p[3])
                })
                .collect(),
            removed: vec![false; mesh.tets.len()],
            pinned: vec![false; n],
            uncut_nodes: n,
            outer: std::sync::Arc::new(
                (mesh.surface.iter())
                    .map(|f| {
                        let mut k = *f;
                        k.sort_unstable();
                        k
                    })
                    .collect(),
            ),
        };
        Cut::factored(mesh, state)
    }

    /// A cut whose `K₀` is `factored`'s stiffness (every node of `state`, pinned ones
    /// clamped), with no correction yet.
    fn factored(factored: &Mesh, state: State) -> Result<Cut, Error> {
        if factored.formulation != crate::mesh::units::Formulation::Standard {
            return Err(Error::Input(
                "cutting needs the standard formulation (the locking-free mixed system is not a low-rank change)"
                    .into(),
            ));
        }
        let k = Stiffness::assemble(factored)?;
        let factor = k.factorize()?;
        let n_free = k.dofs.n_free;
        let mut diag0 = vec![0.0; n_free];
        for (j, kd) in diag0.iter_mut().enumerate() {
            let col = k.k.col_range(j);
            let rows = &k.k.symbolic().row_idx()[col.clone()];
            let vals = &k.k.val()[col];
            if let Some(p) = rows.iter().position(|&r| r == j) {
                *kd = vals[p];
            }
        }
        let nbr = face_neighbours(&state.tets);
        let mut tets_left = vec![0u32; state.nodes.len()];
        for (t, r) in state.tets.iter().zip(&state.removed) {
            if !r {
                for &v in t {
                    tets_left[v as usize] += 1;
                }
            }
        }
        Ok(Cut {
            place: vec![u32::MAX; n_free],
            dofs: k.dofs,
            base_nodes: state.nodes.len(),
            factor,
            diag0,
            copy_dof: Vec::new(),
            uncut_nodes: state.uncut_nodes,
            outer: state.outer,
            nodes: state.nodes,
            tets: state.tets,
            fixed: state.fixed,
            origin: state.origin,
            clamp_normal: state.clamp_normal,
            vol0: state.vol0,
            removed: state.removed,
            tets_left,
            nbr,
            pinned: state.pinned,
            d: Vec::new(),
            dk: DMatrix::zeros(0, 0),
            ld: DMatrix::zeros(n_free, 0),
            cap: DMatrix::zeros(0, 0),
            carried: Default::default(),
            columns: None,
        })
    }

    /// Tets removed so far.
    pub fn removed(&self) -> &[bool] {
        &self.removed
    }

    /// Nodes pinned so far (no tet left, or cut off in a piece); one entry per node, copies
    /// included.
    pub fn pinned(&self) -> &[bool] {
        &self.pinned
    }

    /// The correction's rank: the DOFs it touches.
    pub fn rank(&self) -> usize {
        self.d.len()
    }

    /// How many nodes the body has now: the uncut mesh's, then the copies [`Cut::split`] made.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Every node's rest position now (m): snapped nodes moved onto the blades' quads, the
    /// copies after the uncut mesh's nodes.
    pub fn nodes(&self) -> &[DVec3] {
        &self.nodes
    }

    /// Every tet's nodes now (the uncut mesh's tet order; a tet on a further side of a split
    /// names the copy).
    pub fn tets(&self) -> &[[u32; 4]] {
        &self.tets
    }

    /// The copy map: each node's node in the uncut mesh (itself for an uncut node).
    pub fn origin(&self) -> &[u32] {
        &self.origin
    }

    /// The copies made so far (nodes past the uncut mesh's).
    pub fn copies(&self) -> usize {
        self.nodes.len() - self.uncut_nodes
    }

    /// Whether node `v` cannot move: clamped, pinned, or no node of this body.
    pub fn holds_still(&self, v: u32) -> bool {
        let v = v as usize;
        v >= self.nodes.len() || self.fixed[v] || self.pinned[v]
    }

    /// The DOF of (node, axis) in `K₀`'s numbering, or `None` (clamped, or no such node).
    pub(super) fn dof(&self, node: u32, a: usize) -> Option<usize> {
        let v = node as usize;
        if v < self.base_nodes {
            self.dofs.free(node, a)
        } else {
            let f = *self.copy_dof.get(v - self.base_nodes)?;
            (f != u32::MAX).then_some(f as usize + a)
        }
    }

    /// The number of DOFs of `K₀` (the factored body's and the copies').
    pub(super) fn n_dofs(&self) -> usize {
        self.diag0.len()
    }

    /// Adds a copy of node `v` at its position (clamped if it is), with no tet yet; returns
    /// its index. Its DOFs (if unclamped) enter `K₀` with `v`'s diagonal as their `S`.
    pub(super) fn add_copy(&mut self, v: u32) -> u32 {
        let id = self.nodes.len() as u32;
        let vi = v as usize;
        self.nodes.push(self.nodes[vi]);
        self.fixed.push(self.fixed[vi]);
        self.origin.push(self.origin[vi]);
        self.clamp_normal.push(self.clamp_normal[vi]);
        self.pinned.push(false);
        self.tets_left.push(0);
        let first = match [0, 1, 2].map(|a| self.dof(v, a)) {
            [Some(a), Some(b), Some(c)] => {
                let f = self.n_dofs() as u32;
                for d in [a, b, c] {
                    self.diag0.push(self.diag0[d]);
                    self.place.push(u32::MAX);
                }
                f
            }
            _ => u32::MAX,
        };
        self.copy_dof.push(first);
        id
    }

    /// The state a cut changes, to put back with [`Cut::restore`] if it fails.
    pub(super) fn save(&self) -> Saved {
        Saved {
            nodes: self.nodes.clone(),
            tets: self.tets.clone(),
            fixed: self.fixed.clone(),
            origin: self.origin.clone(),
            clamp_normal: self.clamp_normal.clone(),
            removed: self.removed.clone(),
            tets_left: self.tets_left.clone(),
            nbr: self.nbr.clone(),
            pinned: self.pinned.clone(),
            diag0: self.diag0.clone(),
            copy_dof: self.copy_dof.clone(),
            d: self.d.clone(),
            place: self.place.clone(),
            dk: self.dk.clone(),
            ld_shape: self.ld.shape(),
            cap: self.cap.clone(),
        }
    }

    /// Puts back what [`Cut::save`] kept.
    pub(super) fn restore(&mut self, s: Saved) {
        self.nodes = s.nodes;
        self.tets = s.tets;
        self.fixed = s.fixed;
        self.origin = s.origin;
        self.clamp_normal = s.clamp_normal;
        self.removed = s.removed;
        self.tets_left = s.tets_left;
        self.nbr = s.nbr;
        self.pinned = s.pinned;
        self.diag0 = s.diag0;
        self.copy_dof = s.copy_dof;
        self.d = s.d;
        self.place = s.place;
        self.dk = s.dk;
        if self.ld.shape() != s.ld_shape {
            let ld = std::mem::replace(&mut self.ld, DMatrix::zeros(0, 0));
            self.ld = ld.resize(s.ld_shape.0, s.ld_shape.1, 0.0);
        }
        self.cap = s.cap;
        // (The updates since the last `V` went with the cut undone: `V` is made afresh.)
        *self.carried.get_mut().unwrap_or_else(|e| e.into_inner()) = Default::default();
    }

    /// Removes `tets` (indices into `mesh.tets`; repeats and removed ones are ignored), and any
    /// piece that loses every clamp, and updates the correction exactly. `mesh` is the uncut
    /// mesh (its tets' materials). Errors (and changes nothing) on an index out of range or a
    /// mesh that is not this cut's.
    pub fn remove(&mut self, mesh: &Mesh, tets: &[usize]) -> Result<CutReport, Error> {
        if let Some(&bad) = tets.iter().find(|&&t| t >= self.tets.len()) {
            return Err(Error::Input(format!(
                "tet {bad} does not exist (the mesh has {})",
                self.tets.len()
            )));
        }
        self.check_mesh(mesh)?;
        let mut changes = Changes::new(self.tets.len());
        for &t in tets {
            if !self.removed[t] {
                changes.note(self, t);
                self.removed[t] = true;
            }
        }
        let born = self.nodes.len();
        self.commit(mesh, changes, born)
    }

    /// Errors unless `mesh` has this body's tets (the uncut mesh, whose materials it reads).
    pub(super) fn check_mesh(&self, mesh: &Mesh) -> Result<(), Error> {
        if mesh.tets.len() != self.tets.len() || mesh.nodes.len() != self.uncut_nodes {
            return Err(Error::Input(format!(
                "this cut is of a mesh of {} nodes and {} tets, not {} and {}",
                self.uncut_nodes,
                self.tets.len(),
                mesh.nodes.len(),
                mesh.tets.len()
            )));
        }
        Ok(())
    }

    /// Finishes a cut whose geometry and tets have changed as `changes` notes (the copies
    /// from node `born` on made by it): removes the pieces no clamp holds, pins the nodes left
    /// with no tet, and updates `ΔK′` (each changed tet's stiffness before, less its stiffness
    /// now; `+S` for each new copy; `−` the diagonal for each new pin) and the capacitance.
    pub(super) fn commit(
        &mut self,
        mesh: &Mesh,
        mut changes: Changes,
        born: usize,
    ) -> Result<CutReport, Error> {
        let mut report = CutReport::default();
        // Pieces no clamp holds. Every piece was held before this cut (its stiffness was
        // not singular), so none is free where the cut removed no tet, gave none a copy and
        // moved no clamped node (a snap alone: most passes of a blade), and the search over
        // every tet (3–5 ms on the phantom) is not made.
        let same_pieces = born == self.nodes.len()
            && changes.list.iter().all(|b| {
                !self.removed[b.tet]
                    && b.nodes == self.tets[b.tet]
                    && (b.nodes.iter().zip(&b.at))
                        .all(|(&v, &p)| !self.fixed[v as usize] || self.nodes[v as usize] == p)
            });
        // Faces a split parted: a tet moved onto copies no longer shares them.
        for b in &changes.list {
            let t = self.tets[b.tet];
            if b.nodes == t {
                continue;
            }
            for k in 0..4 {
                let o = self.nbr[b.tet][k];
                if o == u32::MAX {
                    continue;
                }
                let f = face(t, k);
                let back = (0..4).find(|&j| face(self.tets[o as usize], j) == f);
                if back.is_none() {
                    self.nbr[b.tet][k] = u32::MAX;
                    if let Some(j) = (self.nbr[o as usize].iter()).position(|&x| x == b.tet as u32)
                    {
                        self.nbr[o as usize][j] = u32::MAX;
                    }
                }
            }
        }
        let cut_off = if same_pieces {
            Vec::new()
        } else {
            self.free_pieces()
        };
        report.pieces_removed = cut_off.len();
        if !cut_off.is_empty() {
            log::debug!(
                "a cut took {} piece(s) off (no clamp held them)",
                cut_off.len()
            );
        }
        for piece in cut_off {
            for t in piece {
                if !self.removed[t] {
                    changes.note(self, t);
                    self.removed[t] = true;
                }
            }
        }
        report.tets_removed = (changes.list.iter())
            .filter(|b| self.removed[b.tet])
            .count();
        // Tets left at each node, and the nodes left with none.
        for b in &changes.list {
            for &v in &b.nodes {
                self.tets_left[v as usize] -= 1;
            }
            if !self.removed[b.tet] {
                for &v in &self.tets[b.tet] {
                    self.tets_left[v as usize] += 1;
                }
            }
        }
        let mut new_pins: Vec<u32> = Vec::new();
        for b in &changes.list {
            for &v in b.nodes.iter().chain(&self.tets[b.tet]) {
                if self.tets_left[v as usize] == 0 && !self.pinned[v as usize] {
                    self.pinned[v as usize] = true;
                    new_pins.push(v);
                }
            }
        }
        report.nodes_pinned = new_pins.len();
        // The DOFs the correction now touches.
        let mut new_d: Vec<usize> = Vec::new();
        // (A removed tet's nodes now differ from its nodes before only if a split moved it
        // onto copies: theirs join too, so that every new copy's and pin's DOFs are in `D`.)
        for b in &changes.list {
            for &v in b.nodes.iter().chain(&self.tets[b.tet]) {
                for a in 0..3 {
                    if let Some(f) = self.dof(v, a) {
                        if self.place[f] == u32::MAX {
                            self.place[f] = (self.d.len() + new_d.len()) as u32;
                            new_d.push(f);
                        }
                    }
                }
            }
        }
        if self.ld.nrows() < self.n_dofs() {
            // Room for the copies of the next cuts too (their rows are zero in the old
            // columns): `L_D` is moved once per `LD_ROOM` copies, not at every cut.
            let ld = std::mem::replace(&mut self.ld, DMatrix::zeros(0, 0));
            self.ld = ld.resize_vertically(self.n_dofs() + 3 * LD_ROOM, 0.0);
        }
        if !new_d.is_empty() {
            self.grow(&new_d);
        }
        let before = self.dk.clone();
        // ΔK′ = K₀ − K′: each changed tet's stiffness before, less its stiffness now.
        for b in &changes.list {
            let mat = mesh.tet_material(b.tet);
            let ke = element_stiffness(b.at, &mat);
            self.add_element(b.nodes, &ke, 1.0);
            if !self.removed[b.tet] {
                let nodes = self.tets[b.tet];
                let ke = element_stiffness(nodes.map(|v| self.nodes[v as usize]), &mat);
                self.add_element(nodes, &ke, -1.0);
            }
        }
        // A new copy's DOFs leave their `S` (K₀ holds it, K′ does not).
        for v in born as u32..self.nodes.len() as u32 {
            self.add_diagonal(v, 1.0);
        }
        // A pinned node keeps its own diagonal in K′.
        for &v in &new_pins {
            self.add_diagonal(v, -1.0);
        }
        self.update_capacitance(&before)?;
        report.rank = self.d.len();
        Ok(report)
    }

    /// `ΔK′ += sign · ke` at the DOFs of `nodes` (all in `D`).
    fn add_element(&mut self, nodes: [u32; 4], ke: &[[f64; 12]; 12], sign: f64) {
        for a in 0..4 {
            for i in 0..3 {
                let Some(fa) = self.dof(nodes[a], i) else {
                    continue;
                };
                let pa = self.place[fa] as usize;
                for b in 0..4 {
                    for j in 0..3 {
                        let Some(fb) = self.dof(nodes[b], j) else {
                            continue;
                        };
                        let pb = self.place[fb] as usize;
                        self.dk[(pa, pb)] += sign * ke[3 * a + i][3 * b + j];
                    }
                }
            }
        }
    }

    /// `ΔK′ += sign · diag₀` at node `v`'s DOFs (in `D`).
    fn add_diagonal(&mut self, v: u32, sign: f64) {
        for a in 0..3 {
            if let Some(f) = self.dof(v, a) {
                let p = self.place[f] as usize;
                self.dk[(p, p)] += sign * self.diag0[f];
            }
        }
    }

    /// `L₀ X` for `X` over every DOF (`n_dofs × k`, column-major): solves with the factor on
    /// the factored body's DOFs, `S⁻¹` on the copies'.
    pub(super) fn solve0(&self, x: &mut DMatrix<f64>) {
        let nf = self.dofs.n_free;
        let k = x.ncols();
        let mut b = faer::Mat::<f64>::zeros(nf, k);
        for j in 0..k {
            for i in 0..nf {
                b[(i, j)] = x[(i, j)];
            }
        }
        self.factor.solve_in_place(&mut b);
        for j in 0..k {
            for i in 0..nf {
                x[(i, j)] = b[(i, j)];
            }
            for i in nf..x.nrows() {
                x[(i, j)] /= self.diag0[i];
            }
        }
    }

    /// The pieces of the remaining tets that nothing holds rigidly: each a list of tets.
    ///
    /// Tets sharing a face form a rigid-enough block (a component). A component is held when
    /// it has three non-collinear clamped nodes, or shares three non-collinear nodes with a
    /// held one (repeated until nothing changes). One held by a single node or an edge alone
    /// (a hinge), or by nothing, could move rigidly: its stiffness is singular, so it goes.
    fn free_pieces(&self) -> Vec<Vec<usize>> {
        let nt = self.tets.len();
        let mut parent: Vec<u32> = (0..nt as u32).collect();
        use crate::fem::{collinear, join, root};
        // Tets sharing a face.
        for (ti, nb) in self.nbr.iter().enumerate() {
            if self.removed[ti] {
                continue;
            }
            for &o in nb {
                if o != u32::MAX && !self.removed[o as usize] {
                    join(&mut parent, o, ti as u32);
                }
            }
        }
        // Three non-collinear points among these nodes (the same test as the stiffness's).
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for &p in &self.nodes {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let scale = (hi - lo).length().max(f64::MIN_POSITIVE);
        let spans_plane = |pts: &mut dyn Iterator<Item = u32>| -> bool {
            let pts: Vec<DVec3> = pts.map(|v| self.nodes[v as usize]).collect();
            pts.len() >= 3 && !collinear(&pts, scale)
        };
        // One component (what most cuts leave): held by its clamped nodes, or free whole.
        let kept = (0..nt).filter(|&t| !self.removed[t]);
        let first = kept.clone().next().map(|t| root(&mut parent, t as u32));
        if let Some(r0) = first {
            if kept.clone().all(|t| root(&mut parent, t as u32) == r0) {
                let mut on = vec![false; self.nodes.len()];
                for t in kept.clone() {
                    for &v in &self.tets[t] {
                        on[v as usize] = true;
                    }
                }
                let mut clamped = (0..self.nodes.len() as u32)
                    .filter(|&v| on[v as usize] && self.fixed[v as usize]);
                return if spans_plane(&mut clamped) {
                    Vec::new()
                } else {
                    vec![kept.collect()]
                };
            }
        }
        // Each component's nodes.
        let mut nodes_of: BTreeMap<u32, Vec<u32>> = Default::default();
        let mut tets_of: BTreeMap<u32, Vec<usize>> = Default::default();
        for (ti, t) in self.tets.iter().enumerate() {
            if self.removed[ti] {
                continue;
            }
            let r = root(&mut parent, ti as u32);
            nodes_of.entry(r).or_default().extend_from_slice(t);
            tets_of.entry(r).or_default().push(ti);
        }
        for v in nodes_of.values_mut() {
            v.sort_unstable();
            v.dedup();
        }
        let roots: Vec<u32> = nodes_of.keys().copied().collect();
        let mut held: BTreeSet<u32> = roots
            .iter()
            .copied()
            .filter(|r| {
                spans_plane(
                    &mut nodes_of[r]
                        .iter()
                        .copied()
                        .filter(|&v| self.fixed[v as usize]),
                )
            })
            .collect();
        // Which components each node is in.
        let mut comps_at: HashMap<u32, Vec<u32>> = Default::default();
        for (&r, ns) in &nodes_of {
            for &v in ns {
                comps_at.entry(v).or_default().push(r);
            }
        }
        loop {
            let mut grew = false;
            for &r in &roots {
                if held.contains(&r) {
                    continue;
                }
                let shared = nodes_of[&r]
                    .iter()
                    .copied()
                    .filter(|v| comps_at[v].iter().any(|o| *o != r && held.contains(o)));
                if spans_plane(&mut shared.into_iter()) {
                    held.insert(r);
                    grew = true;
                }
            }
            if !grew {
                break;
            }
        }
        tets_of
            .into_iter()
            .filter(|(r, _)| !held.contains(r))
            .map(|(_, t)| t)
            .collect()
    }

    /// The displacement of every node (m; copies included) under nodal `forces` (node, N) on
    /// the cut body: `L′ f` by a solve and the correction. Pinned and clamped nodes do not
    /// move; a force on them (or on no node) is ignored.
    pub fn displace(&self, forces: &[(u32, DVec3)]) -> Vec<DVec3> {
        let n = self.n_dofs();
        let mut f = DMatrix::<f64>::zeros(n, 1);
        for &(v, fv) in forces {
            if self.pinned.get(v as usize).copied().unwrap_or(true) {
                continue;
            }
            for a in 0..3 {
                if let Some(d) = self.dof(v, a) {
                    f[(d, 0)] += fv[a];
                }
            }
        }
        let m = self.d.len();
        // y = L_Dᵀ f, z = C y.
        let mut y = nalgebra::DVector::zeros(m);
        for b in 0..m {
            let mut s = 0.0;
            for i in 0..n {
                let fi = f[(i, 0)];
                if fi != 0.0 {
                    s += self.ld[(i, b)] * fi;
                }
            }
            y[b] = s;
        }
        let z = &self.cap * y;
        let mut x = f;
        self.solve0(&mut x);
        let corr = &self.ld * z;
        let mut u = vec![DVec3::ZERO; self.nodes.len()];
        for (v, uv) in u.iter_mut().enumerate() {
            if self.pinned[v] {
                continue;
            }
            for a in 0..3 {
                if let Some(d) = self.dof(v as u32, a) {
                    uv[a] = x[(d, 0)] + corr[d];
                }
            }
        }
        u
    }

    /// The 3×3 block `L′(i, j)` between two nodes (m/N; copies included): what the haptic
    /// path's force solve reads after the cut. Zero for a clamped or pinned node, or one the
    /// body does not have.
    pub fn block(&self, i: u32, j: u32) -> DMat3 {
        self.blocks(&[(i, j)])[0]
    }

    /// The diagonal blocks `L′(v, v)` of `nodes` (m/N), with one solve for every 32 nodes.
    pub fn diag_blocks(&self, nodes: &[u32]) -> Vec<DMat3> {
        let pairs: Vec<(u32, u32)> = nodes.iter().map(|&v| (v, v)).collect();
        pairs.chunks(32).flat_map(|c| self.blocks(c)).collect()
    }

    /// `L′(i, j)` for each pair, by one solve with three columns a pair.
    fn blocks(&self, pairs: &[(u32, u32)]) -> Vec<DMat3> {
        let mut out = vec![DMat3::ZERO; pairs.len()];
        let live = |v: u32| !self.pinned.get(v as usize).copied().unwrap_or(true);
        let n = self.n_dofs();
        let mut b = DMatrix::<f64>::zeros(n, 3 * pairs.len());
        let mut any = false;
        for (k, &(i, j)) in pairs.iter().enumerate() {
            if !(live(i) && live(j)) {
                continue;
            }
            for c in 0..3 {
                if let Some(d) = self.dof(j, c) {
                    b[(d, 3 * k + c)] = 1.0;
                    any = true;
                }
            }
        }
        if !any {
            return out;
        }
        self.solve0(&mut b);
        let m = self.d.len();
        for (k, &(i, j)) in pairs.iter().enumerate() {
            if !(live(i) && live(j)) {
                continue;
            }
            for c in 0..3 {
                let Some(dj) = self.dof(j, c) else {
                    continue;
                };
                // L′ e_j = L₀ e_j + L_D C L_Dᵀ e_j, and L_Dᵀ e_j is L_D's row at j.
                let y = nalgebra::DVector::from_fn(m, |q, _| self.ld[(dj, q)]);
                let z = &self.cap * y;
                for r in 0..3 {
                    let Some(di) = self.dof(i, r) else {
                        continue;
                    };
                    let mut v = b[(di, 3 * k + c)];
                    for q in 0..m {
                        v += self.ld[(di, q)] * z[q];
                    }
                    out[k].col_mut(c)[r] = v;
                }
            }
        }
        out
    }

    /// One tenth of the smallest mean diagonal compliance `tr L′(v, v) / 3` among `nodes`
    /// (those that can move): the compliance the paper's force gives a clamped or pinned
    /// contact node, as [`Compliance::clamp_compliance`] does. Zero when none can move.
    ///
    /// [`Compliance::clamp_compliance`]: crate::compliance::Compliance::clamp_compliance
    pub fn clamp_compliance(&self, nodes: &[u32]) -> f64 {
        let free: Vec<u32> = nodes
            .iter()
            .copied()
            .filter(|&v| !self.holds_still(v))
            .collect();
        let min = (self.diag_blocks(&free).iter())
            .map(|b| b.x_axis.x + b.y_axis.y + b.z_axis.z)
            .fold(f64::INFINITY, f64::min);
        if min.is_finite() {
            0.1 * min / 3.0
        } else {
            0.0
        }
    }

    /// The body as cut as a mesh of the uncut `mesh`'s materials: every node (copies
    /// included, at their rest positions now) and every tet, removed ones too (so tet
    /// indices, regions and groups stay), clamps as they are; its surface is stale.
    fn current_mesh(&self, mesh: &Mesh) -> Mesh {
        let mut m = mesh.clone();
        m.nodes = self.nodes.clone();
        m.tets = self.tets.clone();
        m.fixed = self.fixed.clone();
        m
    }

    /// The separated body as a mesh: every node (copies after the uncut mesh's, at their rest
    /// positions now), the tets not removed (renumbered, with their regions), its surface
    /// (the cut's faces included) and clamps; a node left with no tet stays, unclamped, as
    /// [`Mesh::without_tets`] leaves it. What `--vtu` writes and a recompute assembles.
    /// `mesh` is the uncut mesh.
    pub fn separated_mesh(&self, mesh: &Mesh) -> Mesh {
        let mut m = self.current_mesh(mesh);
        m.surface = crate::mesh::open_surface_from_neighbours(&m.tets, &self.nbr, &self.removed);
        let mut on = vec![false; m.nodes.len()];
        for f in &m.surface {
            for &v in f {
                on[v as usize] = true;
            }
        }
        m.surface_nodes = (0..m.nodes.len() as u32)
            .filter(|&v| on[v as usize])
            .collect();
        m.without_tets(&self.removed)
    }
}

/// The `n` tets whose centroids are nearest `p` (m), nearest first: a scripted cut.
pub fn tets_near(mesh: &Mesh, p: DVec3, n: usize) -> Vec<usize> {
    let centroid = |t: &[u32; 4]| t.iter().map(|&k| mesh.nodes[k as usize]).sum::<DVec3>() / 4.0;
    let mut v: Vec<(f64, usize)> = mesh
        .tets
        .iter()
        .enumerate()
        .map(|(i, t)| (centroid(t).distance(p), i))
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v.into_iter().take(n).map(|x| x.1).collect()
}

/// Up to `n` tets near `p` (m), nearest first, whose removal leaves every node some tet (so
/// no node is pinned and a full precompute of the rest is well posed: what a comparison with
/// a recompute needs).
pub fn tets_near_keeping_nodes(mesh: &Mesh, p: DVec3, n: usize) -> Vec<usize> {
    let mut left = vec![0u32; mesh.nodes.len()];
    for t in &mesh.tets {
        for &v in t {
            left[v as usize] += 1;
        }
    }
    let mut out = Vec::new();
    for t in tets_near(mesh, p, mesh.tets.len()) {
        if out.len() == n {
            break;
        }
        if mesh.tets[t].iter().all(|&v| left[v as usize] > 1) {
            for &v in &mesh.tets[t] {
                left[v as usize] -= 1;
            }
            out.push(t);
        }
    }
    out
}

/// What [`point_poke`] returns: the feedback (N, on the finger), the nodal forces (mesh
/// node, N) and every node's displacement (m).
pub type CutPoke = (DVec3, Vec<(u32, DVec3)>, Vec<DVec3>);

/// A point finger's poke on a cut body: the contact's nodes (`nodes`, area coordinates
/// `alpha`) move the contact point by `u` (m) under the exact point force `G = W′⁻¹ u`,
/// `W′ = Σ α_i α_j L′_ij` from the cut compliance. Returns the feedback (N, on the finger),
/// the nodal forces (mesh node, N) and every node's displacement. `None` when `W′` is
/// singular (every contact node pinned or clamped).
pub fn point_poke(cut: &Cut, nodes: [u32; 3], alpha: [f64; 3], u: DVec3) -> Option<CutPoke> {
    let mut w = DMat3::ZERO;
    for a in 0..3 {
        for b in 0..3 {
            let s = alpha[a] * alpha[b];
            if s != 0.0 {
                w += cut.block(nodes[a], nodes[b]) * s;
            }
        }
    }
    let g = crate::compliance::invert3(w)? * u;
    if !g.is_finite() {
        return None;
    }
    let forces: Vec<(u32, DVec3)> = (0..3)
        .filter(|&a| alpha[a] != 0.0 && !cut.pinned()[nodes[a] as usize])
        .map(|a| (nodes[a], g * alpha[a]))
        .collect();
    let disp = cut.displace(&forces);
    Some((-g, forces, disp))
}

/// The paper's force (eq. 9–12) on a cut body: each contact node `i` (area coordinate
/// `α_i`) pushes with `F_i = α_i L′_ii⁻¹ u`, and the finger feels `−Σ F_i`. A clamped or
/// pinned contact node has no column: it is given `clamp_compliance` (see
/// [`Cut::clamp_compliance`]) and adds `α_i u / clamp_compliance` to the feedback only.
/// Returns the feedback (N, on the finger), the nodal forces and every node's displacement;
/// `None` when a contact node's `L′_ii` is singular.
pub fn point_poke_paper(
    cut: &Cut,
    nodes: [u32; 3],
    alpha: [f64; 3],
    u: DVec3,
    clamp_compliance: f64,
) -> Option<CutPoke> {
    let mut total = DVec3::ZERO;
    let mut forces = Vec::with_capacity(3);
    for a in 0..3 {
        if alpha[a] == 0.0 {
            continue;
        }
        let v = nodes[a];
        if cut.holds_still(v) {
            if clamp_compliance > 0.0 {
                total += u * (alpha[a] / clamp_compliance);
            }
            continue;
        }
        let f = crate::compliance::invert3(cut.block(v, v))? * u * alpha[a];
        if !f.is_finite() {
            return None;
        }
        forces.push((v, f));
        total += f;
    }
    let disp = cut.displace(&forces);
    Some((-total, forces, disp))
}

impl Cut {
    /// Folds the correction into `c` (the compliance this cut's correction is relative to,
    /// `L` on the host): `L′ = L + U_R V_Cᵀ` over the same rows and columns, a pinned node's
    /// row and column zero and marked dead (see [`Compliance::folded`]). What the haptic and
    /// visual paths read once the correction has grown too large to carry; exact, like the
    /// correction. Costs `9·R·C·rank` multiply-adds (one matrix product).
    ///
    /// [`Compliance::folded`]: crate::compliance::Compliance::folded
    pub fn fold(
        &self,
        c: &crate::compliance::Compliance,
    ) -> Result<crate::compliance::Compliance, Error> {
        let k = self.correction(c)?;
        Ok(c.with_correction(std::sync::Arc::new(k))?.folded()?)
    }

    /// This cut started afresh from the body it has made: the separated body's stiffness
    /// factored (its nodes, copies included, at their rest positions now; pinned nodes held as
    /// clamps), the correction empty, the tets removed, the nodes pinned and the copies kept.
    /// Its corrections are then relative to [`Cut::fold`]'s compliance, so that after a fold
    /// the carried rank starts from zero. `mesh` is the uncut mesh (the one [`Cut::remove`]
    /// takes). Costs one assembly and factorisation.
    pub fn rebase(&self, mesh: &Mesh) -> Result<Cut, Error> {
        self.rebase_plan(mesh)?.run()
    }

    /// What [`Cut::rebase`] needs of this cut, copied (no factor: cheap), so that its
    /// assembly and factorisation can run on another thread ([`Rebase::run`]).
    pub fn rebase_plan(&self, mesh: &Mesh) -> Result<Rebase, Error> {
        self.check_mesh(mesh)?;
        let mut rest = self.current_mesh(mesh).without_tets(&self.removed);
        for (f, &p) in rest.fixed.iter_mut().zip(&self.pinned) {
            *f |= p;
        }
        let state = State {
            nodes: self.nodes.clone(),
            tets: self.tets.clone(),
            fixed: self.fixed.clone(),
            origin: self.origin.clone(),
            clamp_normal: self.clamp_normal.clone(),
            vol0: self.vol0.clone(),
            removed: self.removed.clone(),
            pinned: self.pinned.clone(),
            uncut_nodes: self.uncut_nodes,
            outer: self.outer.clone(),
        };
        // The rebased cut's columns: the same nodes and their copies made since.
        let columns = self
            .columns
            .as_ref()
            .zip(self.derive_from())
            .map(|(c, from)| {
                let held = c.nodes();
                let nodes = (self.origin.iter().enumerate())
                    .map(|(v, &o)| {
                        held.get(v).copied().unwrap_or(false)
                            || held.get(o as usize).copied().unwrap_or(false)
                    })
                    .collect();
                (nodes, from)
            });
        Ok(Rebase {
            rest,
            state,
            columns,
        })
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    /// The face neighbours a cut keeps through a split equal those found afresh (and give the
    /// opened surface matched afresh), the split parted some faces it cut and no others: a
    /// blade in the cube's grid plane x = 15 mm, 12 mm deep, a second across it, a removal.
    #[cfg_attr(test, test)]
    pub(crate) fn face_neighbours_kept_through_splits_equal_those_found_afresh() {
        use super::super::BladeQuad;
        let mesh = crate::mesh::cube();
        let mut cut = Cut::new(&mesh).expect("the cube factors");
        let links = |cut: &Cut| cut.nbr.iter().flatten().filter(|&&o| o != u32::MAX).count();
        // The opened surface from the neighbours kept is the faces matched afresh.
        let open_matches = |c: &Cut| {
            crate::mesh::open_surface_from_neighbours(&c.tets, &c.nbr, &c.removed)
                == crate::mesh::open_surface_of(&c.tets, &c.removed)
        };
        let mm = |x: f64, y: f64, z: f64| DVec3::new(x, y, z) * 1e-3;
        let blades = [
            (mm(15.0, 2.0, 30.0), mm(15.0, 28.0, 30.0)),
            (mm(4.0, 12.0, 30.0), mm(26.0, 18.0, 30.0)),
        ];
        for (k, (p1, p2)) in blades.into_iter().enumerate() {
            let before = links(&cut);
            let q = BladeQuad::new(p1, p2, DVec3::NEG_Z, 12e-3).expect("a quad");
            let rep = cut.split(&mesh, &[q]).expect("the cube splits");
            assert!(
                rep.nodes_split > 0 && rep.faces_cut > 0,
                "blade {k}: {rep:?}"
            );
            assert_eq!(rep.cut.pieces_removed, 0, "blade {k}: {rep:?}");
            assert!(cut.nbr == face_neighbours(&cut.tets), "blade {k}");
            assert!(open_matches(&cut), "blade {k}");
            // (A face cut where the blade ends inside the body stays joined where none of its
            // nodes got a copy: at most the faces cut are parted.)
            let parted = before - links(&cut);
            assert!(
                parted > 0 && parted <= 2 * rep.faces_cut,
                "blade {k}: {parted} links parted, {rep:?}"
            );
        }
        // So after tets beside the cuts are removed too.
        cut.remove(&mesh, &[0, 7, 49]).expect("three tets removed");
        assert!(open_matches(&cut));
    }
}
