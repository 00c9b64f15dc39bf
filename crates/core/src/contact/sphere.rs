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
//!   tick, the sweeps converge over ticks; a poke solves to convergence).
//! * The device receives the sum of the contact forces of its sphere.

use glam::{DMat3, DVec3};

use super::tool::Friction;
use super::Surface;
use crate::compliance::Compliance;

/// Most candidate nodes of one object's contact problem (all its spheres together).
pub const MAX_PATCH: usize = 128;

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
    /// `W_ijᵀ n_i`, stride `cap`: a tangential force τ_j moves node i along its normal by
    /// `B_ij · τ_j`.
    bvec: Vec<DVec3>,
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
    stiffness: [f64; crate::force::MAX_FINGERS],
}

impl Default for Patch {
    fn default() -> Self {
        Patch::new()
    }
}

impl Patch {
    /// An empty problem with room for [`MAX_PATCH`] nodes (about 270 kB): the haptic path's.
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
            bvec: vec![DVec3::ZERO; m * m],
            slot: Vec::new(),
            set: Vec::with_capacity(m),
            chol: vec![0.0; m * m],
            rhs: vec![0.0; m],
            factored: false,
            report: PatchReport::default(),
            stiffness: [0.0; crate::force::MAX_FINGERS],
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
        self.stiffness = [0.0; crate::force::MAX_FINGERS];
        let k = self.set.len();
        if k == 0 {
            return;
        }
        for sphere in 0..crate::force::MAX_FINGERS {
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
            let reach = sp.radius * 1.02 + 0.5 * max_u + 1e-9;
            // A node becomes a candidate when its rest gap is within this (the surface
            // around a press sinks; a bulge towards the sphere is a fraction of the press).
            let margin = 0.5 * max_u + 0.02 * sp.radius;
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
        // Drop candidates no sphere is near and that carry no force.
        let mut i = 0;
        while i < self.n {
            if !self.seen[i] && self.p[i] <= 0.0 {
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
            self.report = report;
            return report;
        }
        // 2. Gaps with no contact force, and each node's sphere.
        let mut r_min = f64::INFINITY;
        for i in 0..m {
            let mut best = (f64::INFINITY, 0u8);
            for (s, sp) in spheres.iter().enumerate() {
                if !(sp.centre.is_finite() && sp.radius.is_finite() && sp.radius > 0.0) {
                    continue;
                }
                let g = ray_gap(self.rest[i], self.normal[i], sp.centre, sp.radius);
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
        let tol = 1e-9 * if r_min.is_finite() { r_min } else { 1e-3 };
        // 3. Normal solve; with friction, alternated with tangential sweeps.
        if friction.is_none() {
            for t in &mut self.tau[..m] {
                *t = DVec3::ZERO;
            }
        }
        let rounds = if friction.is_some() {
            budget.friction_sweeps.max(1)
        } else {
            1
        };
        let mut pivots_left = budget.pivots;
        for round in 0..rounds {
            self.normal_rhs(friction.is_some());
            let (used, done) = self.nnls(tol, pivots_left);
            report.pivots += used;
            pivots_left = pivots_left.saturating_sub(used);
            if !done {
                report.exhausted = true;
            }
            if let Some(fr) = friction {
                let change = self.friction_sweep(c, spheres, fr);
                if round + 1 == rounds {
                    // The last sweep changed τ: one more normal solve keeps Signorini exact.
                    self.normal_rhs(true);
                    let (used, done) = self.nnls(tol, pivots_left);
                    report.pivots += used;
                    if !done {
                        report.exhausted = true;
                    }
                } else if change <= 1e-9 * self.p[..m].iter().sum::<f64>().max(1e-300) {
                    self.normal_rhs(true);
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
                self.tau[i] = DVec3::ZERO;
                self.anchored[i] = false;
                self.slipping[i] = false;
            }
        }
        if friction.is_some() {
            for i in 0..m {
                if self.p[i] > 0.0 && (!self.anchored[i] || self.slipping[i]) {
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
        let s = self.cap;
        for j in 0..=k {
            let w = c.touch_block(col as usize, self.col[j] as usize);
            self.wblk[k * s + j] = w;
            self.wblk[j * s + k] = w.transpose();
            self.bvec[k * s + j] = w.transpose() * nk;
            self.bvec[j * s + k] = w * self.normal[j];
            let a = nk.dot(w * self.normal[j]);
            self.a[k * s + j] = a;
            self.a[j * s + k] = a;
        }
        self.g[k] = 0.0;
        self.gap0[k] = 0.0;
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
            mv!(node, col, normal, rest, owner, seen, p, tau, anchor, anchored, slipping, g, gap0);
            for j in 0..self.n {
                self.a[i * s + j] = self.a[last * s + j];
                self.wblk[i * s + j] = self.wblk[last * s + j];
                self.bvec[i * s + j] = self.bvec[last * s + j];
            }
            for j in 0..self.n {
                self.a[j * s + i] = self.a[j * s + last];
                self.wblk[j * s + i] = self.wblk[j * s + last];
                self.bvec[j * s + i] = self.bvec[j * s + last];
            }
            self.a[i * s + i] = self.a[last * s + last];
            self.wblk[i * s + i] = self.wblk[last * s + last];
            self.bvec[i * s + i] = self.bvec[last * s + last];
            for x in &mut self.set {
                if *x == last {
                    *x = i;
                }
            }
        }
        self.n -= 1;
    }

    /// `q = gap0 − n·(W τ)`.
    fn normal_rhs(&mut self, with_tau: bool) {
        let m = self.n;
        for i in 0..m {
            let mut q = self.gap0[i];
            if with_tau {
                // The nodes carrying force are the active set's.
                let row = &self.bvec[i * self.cap..];
                let mut un = 0.0;
                for &j in &self.set {
                    un += row[j].dot(self.tau[j]);
                }
                q -= un;
            }
            self.q[i] = q;
        }
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

    /// g = q + A p over the candidates.
    fn update_gaps(&mut self) {
        let m = self.n;
        let s = self.cap;
        for i in 0..m {
            let mut g = self.q[i];
            for &j in &self.set {
                g += self.a[i * s + j] * self.p[j];
            }
            self.g[i] = g;
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
        for r in (0..k).rev() {
            let mut v = self.rhs[r];
            for t in r + 1..k {
                v -= self.chol[t * s + r] * self.rhs[t];
            }
            self.rhs[r] = v / self.chol[r * s + r];
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

    /// One projected Gauss–Seidel sweep over the tangential forces. Returns Σ|Δτ|.
    fn friction_sweep(&mut self, c: &Compliance, spheres: &[Sphere], fr: Friction) -> f64 {
        let mut change = 0.0;
        for r in 0..self.set.len() {
            let i = self.set[r];
            let sp = spheres[self.owner[i] as usize];
            let n = self.normal[i];
            // Gauss–Seidel: the latest tangential forces of the nodes before it.
            let r = self.rest[i] + self.u_at(i) - sp.centre;
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
            if d != DVec3::ZERO {
                change += d.length();
                self.tau[i] = t_new;
            }
        }
        change
    }
}

/// The gap from a node at `x` with outward normal `n` to the sphere (centre `c`, radius
/// `r`) along `n`: where the ray `x + t n` enters the sphere, or the node's distance to the
/// sphere where the ray misses it or the sphere lies wholly behind the node.
#[inline]
pub(crate) fn ray_gap(x: DVec3, n: DVec3, c: DVec3, r: f64) -> f64 {
    let d = c - x;
    let a = d.dot(n);
    let rho2 = (d.length_squared() - a * a).max(0.0);
    if rho2 >= r * r {
        return d.length() - r;
    }
    let h = (r * r - rho2).sqrt();
    if a + h < 0.0 {
        return d.length() - r;
    }
    a - h
}
