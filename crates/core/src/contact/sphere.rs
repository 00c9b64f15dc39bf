//! A sphere pressing an area of the deformed surface: the contact problem on the contact
//! nodes' compliance `W` (3×3 blocks of `L`), solved exactly for the normal forces
//! (Signorini) and by projected Gauss–Seidel for Coulomb friction, within a bounded amount of
//! work per tick. Allocates nothing after [`Patch::new`].
//!
//! # The model (and the choices the issue left open)
//! * **Contact is node-to-sphere.** The candidates are the touchable surface nodes near a
//!   sphere; each node faces the sphere that gives it the smallest gap. A sphere meets a
//!   triangle at its vertices: a sphere much smaller than the triangles under it can sink
//!   between them, so refine the mesh under the contact to a fraction of `√(R·d)` (the
//!   contact radius at depth `d`).
//! * **Normals are fixed per node**: the rest surface's angle-weighted vertex normal `n_i`
//!   (outward). The gap `g_i` is the distance along `n_i` from the node to the sphere's near
//!   surface (the ray from the node along `n_i` meets the sphere at `t₁ = a − √(R² − ρ²)`,
//!   with `a` and `ρ` the axial and radial offsets of the centre); where the ray misses, the
//!   node's distance to the sphere. A contact force pushes along `−n_i` and the node's normal
//!   motion changes `g_i` one for one, so the problem is the classic rigid-indenter one of
//!   Hertz's theory: `g = q + A p`, `A = Nᵀ W N` (symmetric positive definite), `q_i` the
//!   gap under no contact force. The node's tangential displacement is not fed back into
//!   `ρ` (a second-order term under small strain).
//! * **Signorini**: `p ≥ 0`, `g ≥ −tol`, `p · g = 0`, solved as the convex problem
//!   `min ½ pᵀAp + qᵀp, p ≥ 0` by Lawson–Hanson's active-set method, warm-started from the
//!   last tick's active set, with a Cholesky factor of `A` on the active set grown one row at
//!   a time. Every iterate is feasible (`p ≥ 0`), so a solve cut short by the budget is still
//!   a finite, pulling-free force; it is counted in [`PatchReport::exhausted`].
//! * **Friction** (Coulomb, per node): a node in contact sticks to the sphere at its anchor
//!   (its tangential position relative to the centre when it stuck) while the tangential
//!   force that holds it there is inside its static cone `μ_s p_i`; past it, it slips with a
//!   tangential force `μ_d p_i` along the force that would have held it, and its anchor
//!   follows it. The tangential forces are updated by projected block Gauss–Seidel with
//!   each node's own stiffness `L_ii⁻¹`, alternated with exact normal solves
//!   ([`Budget::friction_sweeps`] rounds a tick, one by default: warm-started from the last
//!   tick, the sweeps converge over ticks; a poke solves to convergence). The sweep reads
//!   only the tangential rows of `W` in each node's tangent basis, in f32 (their error,
//!   1e-7 of the displacement, is far below the anchors' scale), and keeps each node's
//!   normal motion under the tangential forces as they change.
//! * The device receives the sum of the contact forces of its sphere.

use glam::{DMat3, DVec3};

use super::tool::Friction;
use super::Surface;
use crate::compliance::Compliance;

pub use crate::limits::MAX_PATCH;

/// A rigid sphere in the contact problem, in the object's frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Centre, m.
    pub centre: DVec3,
    /// Radius, m.
    pub radius: f64,
}

/// The work one solve may do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Budget {
    /// Active-set changes (a node added or dropped) per solve.
    pub pivots: usize,
    /// Rounds of friction (a tangential Gauss–Seidel sweep and a normal solve) per solve.
    pub friction_sweeps: usize,
}

impl Default for Budget {
    fn default() -> Self {
        Budget {
            pivots: 64,
            friction_sweeps: 1,
        }
    }
}

impl Budget {
    /// A budget large enough to converge (poking, tests, references).
    pub const UNLIMITED: Budget = Budget {
        pivots: 100_000,
        friction_sweeps: 400,
    };
}

/// What one solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PatchReport {
    /// Candidate nodes considered.
    pub candidates: usize,
    /// Nodes carrying a contact force.
    pub contacts: usize,
    /// Active-set changes made.
    pub pivots: usize,
    /// Whether the budget ran out before the conditions were met.
    pub exhausted: bool,
    /// Whether more nodes were near a sphere than the problem holds ([`MAX_PATCH`] on the haptic path) (the nearest were kept).
    pub overflow: bool,
    /// Nodes slipping (friction).
    pub slipping: usize,
    /// The largest penetration left, m (−min gap, 0 when none).
    pub max_penetration: f64,
}

/// One node of the contact problem, as a caller sees it after a solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PatchNode {
    /// Mesh node.
    pub node: u32,
    /// Its column of `L`.
    pub col: u32,
    /// The sphere it faces (index into the solve's spheres).
    pub sphere: usize,
    /// Its outward normal.
    pub normal: DVec3,
    /// The contact force on the object at this node, N (`−p n + τ`).
    pub force: DVec3,
    /// Its normal pressure force `p ≥ 0`, N.
    pub pressure: f64,
    /// Its gap to the sphere after the solve, m (linearised along the normal).
    pub gap: f64,
    /// Whether it slips (friction).
    pub slipping: bool,
}

/// The contact problem of one object touched by spheres, and its warm-start state.
#[derive(Clone, Debug)]
pub struct Patch {
    cap: usize,
    n: usize,
    node: Vec<u32>,
    col: Vec<u32>,
    normal: Vec<DVec3>,
    rest: Vec<DVec3>,
    owner: Vec<u8>,
    seen: Vec<bool>,
    p: Vec<f64>,
    tau: Vec<DVec3>,
    anchor: Vec<DVec3>,
    anchored: Vec<bool>,
    slipping: Vec<bool>,
    blocked: Vec<bool>,
    q: Vec<f64>,
    gap0: Vec<f64>,
    g: Vec<f64>,
    z: Vec<f64>,
    /// A = NᵀWN over the candidates, row-major with stride `cap`.
    a: Vec<f64>,
    /// The 3×3 blocks W_ij = L(node i, column j) of the candidates, stride `cap`: read from
    /// `L` once, when a node becomes a candidate.
    wblk: Vec<DMat3>,
    /// `Σ_j B_ij · τ_j`: how far the tangential forces move each candidate along its normal
    /// (kept as τ changes, so a tick needs no pass over every pair for it).
    btau: Vec<f64>,
    /// `B_ij = W_ijᵀ n_i` by component, stored by column (`bx[j·cap + i]`): a tangential
    /// force τ_j moves node i along its normal by `B_ij · τ_j`; a column is contiguous, so
    /// the normal effect of one τ_j on every candidate is three AXPYs.
    bx: Vec<f64>,
    by: Vec<f64>,
    bz: Vec<f64>,
    /// For each mesh node, its slot + 1 among the candidates (0: none); sized on first use.
    slot: Vec<u32>,
    /// The active set, in the order of the factor's rows.
    set: Vec<usize>,
    /// Lower Cholesky factor of A on the active set, stride `cap`.
    chol: Vec<f64>,
    rhs: Vec<f64>,
    /// Whether `chol` is the factor of A on `set` (in its order).
    factored: bool,
    report: PatchReport,
    stiffness: [f64; crate::limits::MAX_FINGERS],
    /// The (node, sphere) pairs, in the set's order, that `stiffness` was computed for.
    stiff_key: Vec<(u32, u8)>,
    /// Each node's tangential position relative to its sphere's centre after this tick's
    /// friction sweep (with its own force's change): its anchor when it slips.
    rt_end: Vec<DVec3>,
    /// Whether this tick's sweep visited the node.
    swept: Vec<bool>,
    /// The force on each node of the set during a sweep (`τ − n p`), f32 for the sweep's
    /// tangential products.
    fvec: [Vec<f32>; 3],
    /// Each candidate's tangent basis (`t₁`, `t₂`, with `n`: right-handed, orthonormal).
    tan: Vec<[DVec3; 2]>,
    /// `[t₁ᵢᵀ W_ij; t₂ᵢᵀ W_ij]` by entry (six arrays), f32, stride `cap`: the tangential motion of node i under a
    /// force at j, all a friction sweep reads (24 bytes a pair against `W_ij`'s 72: a sweep
    /// over 130 nodes stays in cache; its error, 1e-7 of the displacement, is far below the
    /// sticking anchors' scale).
    tblk: [Vec<f32>; 6],
}

impl Default for Patch {
    fn default() -> Self {
        Patch::new()
    }
}

impl Patch {
    /// An empty problem with room for [`MAX_PATCH`] nodes (about 7.5 MB): the haptic path's.
    pub fn new() -> Patch {
        Patch::with_capacity(MAX_PATCH)
    }

    /// An empty problem with room for `cap` nodes (`16·cap²` bytes and some): for studies
    /// and references larger than a haptic tick's.
    pub fn with_capacity(cap: usize) -> Patch {
        let m = cap.max(1);
        Patch {
            cap: m,
            n: 0,
            node: vec![0; m],
            col: vec![0; m],
            normal: vec![DVec3::ZERO; m],
            rest: vec![DVec3::ZERO; m],
            owner: vec![0; m],
            seen: vec![false; m],
            p: vec![0.0; m],
            tau: vec![DVec3::ZERO; m],
            anchor: vec![DVec3::ZERO; m],
            anchored: vec![false; m],
            slipping: vec![false; m],
            blocked: vec![false; m],
            q: vec![0.0; m],
            gap0: vec![0.0; m],
            g: vec![0.0; m],
            z: vec![0.0; m],
            a: vec![0.0; m * m],
            wblk: vec![DMat3::ZERO; m * m],
            btau: vec![0.0; m],
            bx: vec![0.0; m * m],
            by: vec![0.0; m * m],
            bz: vec![0.0; m * m],
            slot: Vec::new(),
            set: Vec::with_capacity(m),
            chol: vec![0.0; m * m],
            rhs: vec![0.0; m],
            factored: false,
            report: PatchReport::default(),
            stiffness: [0.0; crate::limits::MAX_FINGERS],
            stiff_key: Vec::with_capacity(m),
            rt_end: vec![DVec3::ZERO; m],
            swept: vec![false; m],
            fvec: std::array::from_fn(|_| vec![0.0; m]),
            tan: vec![[DVec3::X, DVec3::Y]; m],
            tblk: std::array::from_fn(|_| vec![0.0; m * m]),
        }
    }

    /// Forgets every contact (the spheres were lifted, or a device lost its position).
    pub fn reset(&mut self) {
        for i in 0..self.n {
            if let Some(s) = self.slot.get_mut(self.node[i] as usize) {
                *s = 0;
            }
        }
        self.n = 0;
        self.set.clear();
        self.factored = true;
        self.report = PatchReport::default();
        self.stiff_key.clear();
        self.stiffness = [0.0; crate::limits::MAX_FINGERS];
    }

    /// The last solve's report.
    pub fn report(&self) -> PatchReport {
        self.report
    }

    /// The nodes of the last solve (every candidate; those carrying force have
    /// `pressure > 0`).
    pub fn nodes(&self) -> impl Iterator<Item = PatchNode> + '_ {
        (0..self.n).map(move |i| PatchNode {
            node: self.node[i],
            col: self.col[i],
            sphere: self.owner[i] as usize,
            normal: self.normal[i],
            force: self.force_at(i),
            pressure: self.p[i],
            gap: self.g[i],
            slipping: self.slipping[i],
        })
    }

    /// The normal stiffness (N/m) of sphere `s`'s patch after the last solve: the force per
    /// metre of a rigid normal push of its active nodes, `Σ (A_SS⁻¹)` over them (what a
    /// device's virtual coupling is sized against). 0 when it touches nothing.
    pub fn normal_stiffness(&self, s: usize) -> f64 {
        self.stiffness.get(s).copied().unwrap_or(0.0)
    }

    /// The mean outward normal of sphere `s`'s contact nodes (zero when none).
    pub fn mean_normal(&self, s: usize) -> DVec3 {
        (0..self.n)
            .filter(|&i| self.p[i] > 0.0 && self.owner[i] as usize == s)
            .map(|i| self.normal[i] * self.p[i])
            .sum::<DVec3>()
            .normalize_or_zero()
    }

    /// The force-weighted mean rest position of sphere `s`'s contact nodes (`None` when it
    /// touches nothing), m.
    pub fn centroid(&self, s: usize) -> Option<DVec3> {
        let mut w = 0.0;
        let mut x = DVec3::ZERO;
        for i in 0..self.n {
            if self.p[i] > 0.0 && self.owner[i] as usize == s {
                w += self.p[i];
                x += self.rest[i] * self.p[i];
            }
        }
        (w > 0.0).then(|| x / w)
    }

    /// Per sphere, `Σ (A_SS⁻¹ 1_s)` over its own active nodes, from the last factor.
    fn update_stiffness(&mut self) {
        let k = self.set.len();
        // The same node pairs give the same factor, and so the same stiffness.
        if self.factored
            && self.stiff_key.len() == k
            && self
                .set
                .iter()
                .zip(&self.stiff_key)
                .all(|(&i, &key)| (self.node[i], self.owner[i]) == key)
        {
            return;
        }
        self.stiff_key.clear();
        self.stiff_key
            .extend(self.set.iter().map(|&i| (self.node[i], self.owner[i])));
        self.stiffness = [0.0; crate::limits::MAX_FINGERS];
        if k == 0 {
            return;
        }
        for sphere in 0..crate::limits::MAX_FINGERS {
            if !self.set.iter().any(|&i| self.owner[i] as usize == sphere) {
                continue;
            }
            for r in 0..k {
                self.rhs[r] = if self.owner[self.set[r]] as usize == sphere {
                    1.0
                } else {
                    0.0
                };
            }
            self.chol_solve();
            let total: f64 = (0..k)
                .filter(|&r| self.owner[self.set[r]] as usize == sphere)
                .map(|r| self.rhs[r])
                .sum();
            self.stiffness[sphere] = if total.is_finite() {
                total.max(0.0)
            } else {
                0.0
            };
        }
    }

    /// The total contact force on the object from sphere `s`, N (the finger feels its
    /// negative).
    pub fn sphere_force(&self, s: usize) -> DVec3 {
        (0..self.n)
            .filter(|&i| self.owner[i] as usize == s)
            .map(|i| self.force_at(i))
            .sum()
    }

    #[inline]
    fn force_at(&self, i: usize) -> DVec3 {
        if self.p[i] > 0.0 {
            -self.normal[i] * self.p[i] + self.tau[i]
        } else {
            DVec3::ZERO
        }
    }

    /// Sizes the node table for a mesh of `nodes` nodes (done by the first solve otherwise:
    /// call it up front to keep every tick allocation-free).
    pub fn reserve_nodes(&mut self, nodes: usize) {
        if self.slot.len() < nodes {
            self.slot.resize(nodes, 0);
        }
    }

    /// Solves the contact problem of `spheres` (object frame) on the object whose compliance
    /// is `c` and rest surface `surf`, with `friction` (none: frictionless), warm-started
    /// from the last solve. Non-finite spheres are ignored. Allocates nothing.
    pub fn solve(
        &mut self,
        c: &Compliance,
        surf: &Surface,
        spheres: &[Sphere],
        friction: Option<Friction>,
        budget: Budget,
    ) -> PatchReport {
        let mut report = PatchReport::default();
        let friction = friction.filter(|f| !f.is_none());
        self.reserve_nodes(surf.nodes.len());
        // 1. Candidates: touchable surface nodes near a sphere (rest positions).
        let mut max_u = 0.0f64;
        for i in 0..self.n {
            self.seen[i] = false;
            if self.p[i] > 0.0 {
                // How far it was pushed in along its normal.
                max_u = max_u.max(self.g[i] - self.gap0[i]);
            }
        }
        for (s, sp) in spheres.iter().enumerate() {
            if !(sp.centre.is_finite() && sp.radius.is_finite() && sp.radius > 0.0) {
                continue;
            }
            // A node becomes a candidate when its rest gap is within this (the surface
            // around a press sinks; a bulge towards the sphere is a fraction of the press).
            let margin = candidate_margin(max_u, sp.radius);
            // The ray gap is at least the distance to the sphere: nothing farther qualifies.
            let reach = sp.radius + margin + 1e-9;
            let overflow = &mut report.overflow;
            surf.for_nodes_near(sp.centre, reach, |v| {
                let Some(col) = c.col_of(v) else { return };
                let slot = self.slot[v as usize];
                if slot > 0 {
                    self.seen[slot as usize - 1] = true;
                    return;
                }
                let x = surf.nodes[v as usize];
                if ray_gap(x, surf.vertex_normal(v), sp.centre, sp.radius) > margin {
                    return;
                }
                if self.n == self.cap {
                    *overflow = true;
                    return;
                }
                let _ = s;
                self.add_candidate(c, surf, v, col as u32);
            });
        }
        // 2. Gaps with no contact force, and each node's sphere.
        let mut r_min = f64::INFINITY;
        for i in 0..self.n {
            let mut best = (f64::INFINITY, 0u8);
            for (s, sp) in spheres.iter().enumerate() {
                if !(sp.centre.is_finite() && sp.radius.is_finite() && sp.radius > 0.0) {
                    continue;
                }
                let held = self.p[i] > 0.0 && self.owner[i] as usize == s;
                let g = ray_gap_held(self.rest[i], self.normal[i], sp.centre, sp.radius, held);
                if g < best.0 {
                    best = (g, s as u8);
                }
                r_min = r_min.min(sp.radius);
            }
            self.gap0[i] = if best.0.is_finite() { best.0 } else { 1.0 };
            if best.0.is_finite() {
                self.owner[i] = best.1;
            }
        }
        // Drop the candidates that carry no force and that no sphere is near, or that have
        // moved well clear of their sphere (a slide leaves them behind).
        let mut i = 0;
        while i < self.n {
            let clear = spheres
                .get(self.owner[i] as usize)
                .is_some_and(|sp| self.gap0[i] > 2.0 * candidate_margin(max_u, sp.radius));
            if self.p[i] <= 0.0 && (!self.seen[i] || clear) {
                self.swap_remove(i);
            } else {
                i += 1;
            }
        }
        let m = self.n;
        report.candidates = m;
        if m == 0 {
            self.set.clear();
            self.factored = true;
            self.stiff_key.clear();
            self.stiffness = [0.0; crate::limits::MAX_FINGERS];
            self.report = report;
            return report;
        }
        let tol = 1e-9 * if r_min.is_finite() { r_min } else { 1e-3 };
        // 3. Normal solve; with friction, alternated with tangential sweeps.
        if friction.is_none() {
            self.tau[..m].fill(DVec3::ZERO);
            self.btau[..m].fill(0.0);
        }
        let rounds = if friction.is_some() {
            budget.friction_sweeps.max(1)
        } else {
            1
        };
        let mut pivots_left = budget.pivots;
        // q once: the sweeps keep it current as they change τ.
        self.normal_rhs(friction.is_some());
        for round in 0..rounds {
            let (used, done) = self.nnls(tol, pivots_left);
            report.pivots += used;
            pivots_left = pivots_left.saturating_sub(used);
            if !done {
                report.exhausted = true;
            }
            if let Some(fr) = friction {
                self.release_dropped();
                let change = self.friction_sweep(c, spheres, fr);
                let last = round + 1 == rounds;
                if last || change <= 1e-9 * self.p[..m].iter().sum::<f64>().max(1e-300) {
                    // The sweep changed τ: one more normal solve keeps Signorini exact.
                    let (used, done) = self.nnls(tol, pivots_left);
                    report.pivots += used;
                    if !done {
                        report.exhausted = true;
                    }
                    break;
                }
            }
        }
        // 4. Gaps (current unless the budget ran out mid-solve), anchors for the next tick.
        if report.exhausted {
            self.update_gaps();
        }
        for i in 0..m {
            if self.p[i] <= 0.0 {
                self.p[i] = 0.0;
                if self.tau[i] != DVec3::ZERO {
                    let t = self.tau[i];
                    self.shift_q(i, -t);
                }
                self.tau[i] = DVec3::ZERO;
                self.anchored[i] = false;
                self.slipping[i] = false;
            }
        }
        if friction.is_some() {
            for i in 0..m {
                if self.p[i] > 0.0 && self.slipping[i] && self.swept[i] {
                    // Where the sweep left it (the last normal solve's motion is second
                    // order: a slipping node's anchor is set again next tick).
                    self.anchor[i] = self.rt_end[i];
                    self.anchored[i] = true;
                } else if self.p[i] > 0.0 && (!self.anchored[i] || self.slipping[i]) {
                    let sp = spheres[self.owner[i] as usize];
                    let n = self.normal[i];
                    let r = self.rest[i] + self.u_at(i) - sp.centre;
                    self.anchor[i] = r - n * n.dot(r);
                    self.anchored[i] = true;
                }
            }
        }
        self.update_stiffness();
        report.contacts = (0..m).filter(|&i| self.p[i] > 0.0).count();
        report.slipping = (0..m)
            .filter(|&i| self.p[i] > 0.0 && self.slipping[i])
            .count();
        report.max_penetration = self.g[..m]
            .iter()
            .fold(0.0f64, |acc, &g| acc.max(-g))
            .max(0.0);
        self.report = report;
        report
    }

    fn add_candidate(&mut self, c: &Compliance, surf: &Surface, v: u32, col: u32) {
        let k = self.n;
        self.node[k] = v;
        self.col[k] = col;
        self.normal[k] = surf.vertex_normal(v);
        self.rest[k] = surf.nodes[v as usize];
        self.owner[k] = 0;
        self.seen[k] = true;
        self.p[k] = 0.0;
        self.tau[k] = DVec3::ZERO;
        self.anchored[k] = false;
        self.slipping[k] = false;
        let nk = self.normal[k];
        let (t1, t2) = nk.any_orthonormal_pair();
        self.tan[k] = [t1, t2];
        let s = self.cap;
        for j in 0..=k {
            let w = c.touch_block(col as usize, self.col[j] as usize);
            // W_kj's rows in k's tangent basis; W_jk = W_kjᵀ's in j's.
            let rows = |a: DVec3, b: DVec3, m: DMat3| {
                let (ra, rb) = (m.transpose() * a, m.transpose() * b);
                [ra.x, ra.y, ra.z, rb.x, rb.y, rb.z].map(|v| v as f32)
            };
            for (e, v) in rows(t1, t2, w).into_iter().enumerate() {
                self.tblk[e][k * s + j] = v;
            }
            let [tj1, tj2] = self.tan[j];
            for (e, v) in rows(tj1, tj2, w.transpose()).into_iter().enumerate() {
                self.tblk[e][j * s + k] = v;
            }
            self.wblk[k * s + j] = w;
            self.wblk[j * s + k] = w.transpose();
            // B_jk = W_jkᵀ n_j = W_kj n_j at column k, row j; then B_kj = W_kjᵀ n_k.
            let bjk = w * self.normal[j];
            self.bx[k * s + j] = bjk.x;
            self.by[k * s + j] = bjk.y;
            self.bz[k * s + j] = bjk.z;
            let bkj = w.transpose() * nk;
            self.bx[j * s + k] = bkj.x;
            self.by[j * s + k] = bkj.y;
            self.bz[j * s + k] = bkj.z;
            let a = nk.dot(w * self.normal[j]);
            self.a[k * s + j] = a;
            self.a[j * s + k] = a;
        }
        self.g[k] = 0.0;
        self.gap0[k] = 0.0;
        self.btau[k] = (0..k)
            .map(|j| {
                let t = self.tau[j];
                self.bx[j * s + k] * t.x + self.by[j * s + k] * t.y + self.bz[j * s + k] * t.z
            })
            .sum();
        if let Some(sl) = self.slot.get_mut(v as usize) {
            *sl = k as u32 + 1;
        }
        self.n += 1;
    }

    fn swap_remove(&mut self, i: usize) {
        let last = self.n - 1;
        let s = self.cap;
        // Its place in the active set (it carries no force, so normally none).
        if let Some(pos) = self.set.iter().position(|&x| x == i) {
            self.set.remove(pos);
            self.factored = false;
        }
        if let Some(sl) = self.slot.get_mut(self.node[i] as usize) {
            *sl = 0;
        }
        if i != last {
            if let Some(sl) = self.slot.get_mut(self.node[last] as usize) {
                *sl = i as u32 + 1;
            }
            macro_rules! mv {
                ($($f:ident),*) => {$( self.$f[i] = self.$f[last]; )*};
            }
            mv!(
                node, col, normal, rest, owner, seen, p, tau, anchor, anchored, slipping, g, gap0,
                rt_end, swept, tan, btau
            );
            for j in 0..self.n {
                self.a[i * s + j] = self.a[last * s + j];
                self.wblk[i * s + j] = self.wblk[last * s + j];
                self.bx[i * s + j] = self.bx[last * s + j];
                for t in &mut self.tblk {
                    t[i * s + j] = t[last * s + j];
                }
                self.by[i * s + j] = self.by[last * s + j];
                self.bz[i * s + j] = self.bz[last * s + j];
            }
            for j in 0..self.n {
                self.a[j * s + i] = self.a[j * s + last];
                self.wblk[j * s + i] = self.wblk[j * s + last];
                self.bx[j * s + i] = self.bx[j * s + last];
                for t in &mut self.tblk {
                    t[j * s + i] = t[j * s + last];
                }
                self.by[j * s + i] = self.by[j * s + last];
                self.bz[j * s + i] = self.bz[j * s + last];
            }
            self.a[i * s + i] = self.a[last * s + last];
            self.wblk[i * s + i] = self.wblk[last * s + last];
            self.bx[i * s + i] = self.bx[last * s + last];
            for t in &mut self.tblk {
                t[i * s + i] = t[last * s + last];
            }
            self.by[i * s + i] = self.by[last * s + last];
            self.bz[i * s + i] = self.bz[last * s + last];
            for x in &mut self.set {
                if *x == last {
                    *x = i;
                }
            }
        }
        self.n -= 1;
    }

    /// `q = gap0 − n·(W τ)`: the gaps under no normal force, with the tangential forces of
    /// the nodes carrying force (kept in `btau` as τ changes).
    fn normal_rhs(&mut self, with_tau: bool) {
        let m = self.n;
        if with_tau {
            for ((q, &g), &b) in self.q[..m]
                .iter_mut()
                .zip(&self.gap0[..m])
                .zip(&self.btau[..m])
            {
                *q = g - b;
            }
        } else {
            self.q[..m].copy_from_slice(&self.gap0[..m]);
        }
    }

    /// Zeroes the tangential force of every node that stopped carrying force, and takes its
    /// normal effect out of `q`.
    fn release_dropped(&mut self) {
        for i in 0..self.n {
            let t = self.tau[i];
            if self.p[i] <= 0.0 && t != DVec3::ZERO {
                self.shift_q(i, -t);
                self.tau[i] = DVec3::ZERO;
            }
        }
    }

    /// Node j's tangential force grew by `d`: `btau += B_·j · d` and `q −= B_·j · d` (column
    /// AXPYs, contiguous).
    #[inline]
    fn shift_q(&mut self, j: usize, d: DVec3) {
        let m = self.n;
        let s = self.cap;
        let (bx, by, bz) = (
            &self.bx[j * s..j * s + m],
            &self.by[j * s..j * s + m],
            &self.bz[j * s..j * s + m],
        );
        shift_columns(&mut self.q[..m], &mut self.btau[..m], [bx, by, bz], d);
    }

    /// Lawson–Hanson on `min ½pᵀAp + qᵀp, p ≥ 0`, from the current feasible `p`. Returns
    /// (pivots used, converged).
    fn nnls(&mut self, tol: f64, budget: usize) -> (usize, bool) {
        let m = self.n;
        let s = self.cap;
        self.blocked[..m].fill(false);
        // The warm start: the nodes carrying force. When they are the last solve's set, its
        // factor still holds (A depends only on the node pairs): keep it.
        let carrying = (0..m).filter(|&i| self.p[i] > 0.0).count();
        let same = carrying == self.set.len()
            && self.factored
            && self.set.iter().all(|&i| i < m && self.p[i] > 0.0);
        for i in 0..m {
            if self.p[i] <= 0.0 {
                self.p[i] = 0.0;
            }
        }
        if same {
            // Reuse.
        } else {
            self.set.clear();
            self.factored = true;
            for i in 0..m {
                if self.p[i] > 0.0 {
                    self.set.push(i);
                }
            }
        }
        if !same && !self.refactor() {
            // A (numerically) singular warm set: start cold.
            self.set.clear();
            self.factored = true;
            self.p[..m].fill(0.0);
        }
        let mut pivots = 0usize;
        loop {
            // Inner loop: the minimiser on the set, kept feasible.
            loop {
                if self.set.is_empty() {
                    break;
                }
                self.solve_set();
                let k = self.set.len();
                let mut alpha = 1.0f64;
                let mut all_pos = true;
                for r in 0..k {
                    let i = self.set[r];
                    let z = self.z[i];
                    if z <= 0.0 {
                        all_pos = false;
                        let pi = self.p[i];
                        let a = if pi - z > 0.0 { pi / (pi - z) } else { 0.0 };
                        alpha = alpha.min(a);
                    }
                }
                if all_pos {
                    for r in 0..k {
                        let i = self.set[r];
                        self.p[i] = self.z[i];
                    }
                    break;
                }
                for r in 0..k {
                    let i = self.set[r];
                    self.p[i] += alpha * (self.z[i] - self.p[i]);
                }
                // Drop the nodes that reached zero.
                let before = self.set.len();
                let (set, p, blocked, z) = (&mut self.set, &mut self.p, &mut self.blocked, &self.z);
                set.retain(|&i| {
                    let keep = p[i] > 1e-15 * (1.0 + z[i].abs()) && p[i] > 0.0;
                    if !keep {
                        p[i] = 0.0;
                        blocked[i] = true;
                    }
                    keep
                });
                pivots += before - self.set.len();
                if !self.refactor() {
                    self.set.clear();
                    self.factored = true;
                    self.p[..m].fill(0.0);
                }
                if pivots >= budget {
                    return (pivots, false);
                }
            }
            // Outer: the most violated gap outside the set.
            self.update_gaps();
            let mut worst = (-tol, usize::MAX);
            for i in 0..m {
                if self.p[i] <= 0.0 && !self.blocked[i] && self.g[i] < worst.0 {
                    worst = (self.g[i], i);
                }
            }
            if worst.1 == usize::MAX {
                // Nodes set aside this solve get one more look.
                if self.blocked[..m].iter().any(|&b| b)
                    && (0..m).any(|i| self.p[i] <= 0.0 && self.g[i] < -tol)
                {
                    self.blocked[..m].fill(false);
                    if pivots >= budget {
                        return (pivots, false);
                    }
                    pivots += 1;
                    continue;
                }
                return (pivots, true);
            }
            if pivots >= budget {
                return (pivots, false);
            }
            let j = worst.1;
            pivots += 1;
            if !self.append(j) {
                self.blocked[j] = true;
            }
            let _ = s;
        }
    }

    /// g = q + A p over the candidates (A is symmetric: its column j is row j, contiguous).
    fn update_gaps(&mut self) {
        let m = self.n;
        let s = self.cap;
        self.g[..m].copy_from_slice(&self.q[..m]);
        for &j in &self.set {
            let pj = self.p[j];
            if pj == 0.0 {
                continue;
            }
            for (g, &a) in self.g[..m].iter_mut().zip(&self.a[j * s..j * s + m]) {
                *g += a * pj;
            }
        }
    }

    /// Appends node `j` to the active set's factor. False (and unchanged) when `A` on the
    /// grown set is not numerically positive definite.
    fn append(&mut self, j: usize) -> bool {
        let s = self.cap;
        let k = self.set.len();
        // Solve L y = A[set, j].
        for r in 0..k {
            let mut v = self.a[self.set[r] * s + j];
            for t in 0..r {
                v -= self.chol[r * s + t] * self.chol[k * s + t];
            }
            self.chol[k * s + r] = v / self.chol[r * s + r];
        }
        let ajj = self.a[j * s + j];
        let d = ajj - (0..k).map(|t| self.chol[k * s + t].powi(2)).sum::<f64>();
        if !(d.is_finite() && d > 1e-12 * ajj.abs()) {
            return false;
        }
        self.chol[k * s + k] = d.sqrt();
        self.set.push(j);
        true
    }

    /// Factors `A` on the current set from scratch. False when not positive definite.
    fn refactor(&mut self) -> bool {
        let ok = self.refactor_inner();
        self.factored = ok;
        ok
    }

    fn refactor_inner(&mut self) -> bool {
        let s = self.cap;
        let k = self.set.len();
        for r in 0..k {
            for cidx in 0..=r {
                let mut v = self.a[self.set[r] * s + self.set[cidx]];
                for t in 0..cidx {
                    v -= self.chol[r * s + t] * self.chol[cidx * s + t];
                }
                if r == cidx {
                    if !(v.is_finite() && v > 1e-12 * self.a[self.set[r] * s + self.set[r]].abs()) {
                        return false;
                    }
                    self.chol[r * s + r] = v.sqrt();
                } else {
                    self.chol[r * s + cidx] = v / self.chol[cidx * s + cidx];
                }
            }
        }
        true
    }

    /// `rhs ← A_SS⁻¹ rhs` with the active set's factor (forward, then back substitution).
    fn chol_solve(&mut self) {
        let s = self.cap;
        let k = self.set.len();
        for r in 0..k {
            let mut v = self.rhs[r];
            for t in 0..r {
                v -= self.chol[r * s + t] * self.rhs[t];
            }
            self.rhs[r] = v / self.chol[r * s + r];
        }
        // Back substitution by columns of Lᵀ (rows of L: contiguous).
        for r in (0..k).rev() {
            let x = self.rhs[r] / self.chol[r * s + r];
            self.rhs[r] = x;
            let row = &self.chol[r * s..r * s + r];
            for (v, &l) in self.rhs[..r].iter_mut().zip(row) {
                *v -= l * x;
            }
        }
    }

    /// z[set] = −A_SS⁻¹ q_S.
    fn solve_set(&mut self) {
        let k = self.set.len();
        for r in 0..k {
            self.rhs[r] = -self.q[self.set[r]];
        }
        self.chol_solve();
        for r in 0..k {
            self.z[self.set[r]] = self.rhs[r];
        }
    }

    /// `u_i = Σ_j W_ij λ_j`: node i's displacement under the forces carried (the active
    /// set's).
    #[inline]
    fn u_at(&self, i: usize) -> DVec3 {
        let row = &self.wblk[i * self.cap..];
        let mut u = DVec3::ZERO;
        for &j in &self.set {
            u += row[j] * (self.tau[j] - self.normal[j] * self.p[j]);
        }
        u
    }

    #[inline]
    fn set_fvec(&mut self, j: usize, f: DVec3) {
        self.fvec[0][j] = f.x as f32;
        self.fvec[1][j] = f.y as f32;
        self.fvec[2][j] = f.z as f32;
    }

    /// One projected Gauss–Seidel sweep over the tangential forces. Returns Σ|Δτ|.
    fn friction_sweep(&mut self, c: &Compliance, spheres: &[Sphere], fr: Friction) -> f64 {
        let mut change = 0.0;
        self.swept[..self.n].fill(false);
        // Every candidate's force (zero off the set): the sweep's products then run over
        // rows in order, which the prefetcher streams (a gather in the set's order misses).
        let m = self.n;
        for f in &mut self.fvec {
            f[..m].fill(0.0);
        }
        for r in 0..self.set.len() {
            let j = self.set[r];
            let f = self.tau[j] - self.normal[j] * self.p[j];
            self.set_fvec(j, f);
        }
        for r in 0..self.set.len() {
            let i = self.set[r];
            let sp = spheres[self.owner[i] as usize];
            let n = self.normal[i];
            // Gauss–Seidel: the latest tangential forces of the nodes before it. Only the
            // tangential motion is needed: its two components in i's tangent basis.
            let (ua, ub) = {
                let o = i * self.cap;
                let t: [&[f32]; 6] = std::array::from_fn(|e| &self.tblk[e][o..o + m]);
                let f: [&[f32]; 3] = std::array::from_fn(|e| &self.fvec[e][..m]);
                let (ua, ub) = tangential_dot(t, f);
                (ua as f64, ub as f64)
            };
            let [t1, t2] = self.tan[i];
            let r = self.rest[i] - sp.centre + t1 * ua + t2 * ub;
            let rt = r - n * n.dot(r);
            if !self.anchored[i] {
                // A new contact sticks where it touched.
                self.anchor[i] = rt;
                self.anchored[i] = true;
            }
            let delta = self.anchor[i] - rt;
            let k = c.diag_inv(self.col[i] as usize);
            let step = k * delta;
            let trial = self.tau[i] + (step - n * n.dot(step));
            let mu = if self.slipping[i] {
                fr.dynamic_mu
            } else {
                fr.static_mu
            };
            let cap = mu * self.p[i];
            let t_new = if trial.length() <= cap {
                self.slipping[i] = false;
                trial
            } else {
                self.slipping[i] = true;
                trial * (fr.dynamic_mu * self.p[i] / trial.length().max(1e-300))
            };
            let d = t_new - self.tau[i];
            let own = self.wblk[i * self.cap + i] * d;
            self.rt_end[i] = rt + (own - n * n.dot(own));
            self.swept[i] = true;
            if d != DVec3::ZERO {
                change += d.length();
                self.tau[i] = t_new;
                let f = t_new - n * self.p[i];
                self.set_fvec(i, f);
                self.shift_q(i, d);
            }
        }
        change
    }
}

/// `(Σ_j t[0..3]_j · f_j, Σ_j t[3..6]_j · f_j)`: a row of tangential blocks against the
/// forces, in four fixed lanes (SSE on x86-64, the same sums in the same order elsewhere: the
/// result is bit for bit the same on every machine).
#[inline]
fn tangential_dot(t: [&[f32]; 6], f: [&[f32]; 3]) -> (f32, f32) {
    let n = t
        .iter()
        .map(|x| x.len())
        .chain(f.iter().map(|x| x.len()))
        .min()
        .unwrap_or(0);
    let full = n / 4 * 4;
    let (mut a, mut b) = lanes4(t, f, full);
    for j in full..n {
        a[0] += t[0][j] * f[0][j] + t[1][j] * f[1][j] + t[2][j] * f[2][j];
        b[0] += t[3][j] * f[0][j] + t[4][j] * f[1][j] + t[5][j] * f[2][j];
    }
    ((a[0] + a[1]) + (a[2] + a[3]), (b[0] + b[1]) + (b[2] + b[3]))
}

/// The lanes of [`tangential_dot`] over the first `full` entries (a multiple of 4, at most
/// every slice's length).
#[cfg(target_arch = "x86_64")]
#[inline]
fn lanes4(t: [&[f32]; 6], f: [&[f32]; 3], full: usize) -> ([f32; 4], [f32; 4]) {
    use std::arch::x86_64::*;
    assert!(t.iter().all(|x| x.len() >= full) && f.iter().all(|x| x.len() >= full));
    // SAFETY: SSE is part of x86-64; every load reads 4 floats at `o < full`, within every
    // slice (checked above).
    unsafe {
        let mut a = _mm_setzero_ps();
        let mut b = _mm_setzero_ps();
        let mut o = 0;
        while o < full {
            let ld = |x: &[f32]| _mm_loadu_ps(x.as_ptr().add(o));
            let (f0, f1, f2) = (ld(f[0]), ld(f[1]), ld(f[2]));
            let ra = _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(ld(t[0]), f0), _mm_mul_ps(ld(t[1]), f1)),
                _mm_mul_ps(ld(t[2]), f2),
            );
            let rb = _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(ld(t[3]), f0), _mm_mul_ps(ld(t[4]), f1)),
                _mm_mul_ps(ld(t[5]), f2),
            );
            a = _mm_add_ps(a, ra);
            b = _mm_add_ps(b, rb);
            o += 4;
        }
        let mut oa = [0.0f32; 4];
        let mut ob = [0.0f32; 4];
        _mm_storeu_ps(oa.as_mut_ptr(), a);
        _mm_storeu_ps(ob.as_mut_ptr(), b);
        (oa, ob)
    }
}

/// The lanes of [`tangential_dot`] over the first `full` entries: the same sums, in the same
/// order, as the SSE version.
#[cfg(not(target_arch = "x86_64"))]
#[inline]
fn lanes4(t: [&[f32]; 6], f: [&[f32]; 3], full: usize) -> ([f32; 4], [f32; 4]) {
    let mut a = [0.0f32; 4];
    let mut b = [0.0f32; 4];
    let mut o = 0;
    while o < full {
        for l in 0..4 {
            let j = o + l;
            a[l] += t[0][j] * f[0][j] + t[1][j] * f[1][j] + t[2][j] * f[2][j];
            b[l] += t[3][j] * f[0][j] + t[4][j] * f[1][j] + t[5][j] * f[2][j];
        }
        o += 4;
    }
    (a, b)
}

/// `b = bx·d.x + by·d.y + bz·d.z` by entry; `btau += b`, `q −= b`.
#[inline]
fn shift_columns(q: &mut [f64], btau: &mut [f64], b: [&[f64]; 3], d: DVec3) {
    for ((((q, bt), &x), &y), &z) in q.iter_mut().zip(btau).zip(b[0]).zip(b[1]).zip(b[2]) {
        let v = x * d.x + y * d.y + z * d.z;
        *bt += v;
        *q -= v;
    }
}

/// How near (m) a node's rest gap must come to a sphere of radius `r` for it to be a
/// candidate, after a press that pushed the surface in by up to `max_u`: the surface around a
/// press sinks, and a bulge towards the sphere is a fraction of the press.
#[inline]
fn candidate_margin(max_u: f64, r: f64) -> f64 {
    0.25 * max_u + 0.01 * r
}

/// The gap from a node at `x` with outward normal `n` to the sphere (centre `c`, radius
/// `r`) along `n`: where the ray `x + t n` enters the sphere, or the node's distance to the
/// sphere where the ray misses it or the sphere lies wholly behind the node.
#[inline]
pub(crate) fn ray_gap(x: DVec3, n: DVec3, c: DVec3, r: f64) -> f64 {
    ray_gap_held(x, n, c, r, false)
}

/// [`ray_gap`] for a node that may be pressed already (`held`: it carried a contact force
/// last tick). A held node whose normal line meets the sphere keeps the line's entry as its
/// gap even when the sphere lies wholly behind it: a sphere pressed deeper than its radius
/// has its centre under the rest surface, and the nodes it presses must stay under it (their
/// gap continuous as the press deepens; the distance would release them at once). A node not
/// held, with the sphere behind it (beside an edge the sphere passes), is not pressed there:
/// its gap is its distance.
#[inline]
pub(crate) fn ray_gap_held(x: DVec3, n: DVec3, c: DVec3, r: f64, held: bool) -> f64 {
    let d = c - x;
    let a = d.dot(n);
    let rho2 = (d.length_squared() - a * a).max(0.0);
    if rho2 >= r * r {
        return d.length() - r;
    }
    let h = (r * r - rho2).sqrt();
    if a + h < 0.0 && !held {
        return d.length() - r;
    }
    a - h
}
