//! Cutting without recomputing `L`: removing tets subtracts their element stiffness, a change
//! of rank at most 6 a tet, and the Sherman–Morrison–Woodbury identity (James & Pai's
//! capacitance matrix) gives the new compliance exactly from `L`'s columns at the changed
//! DOFs `D`:
//!
//! `L′ = L + L_D (I − ΔK′ L_DD)⁻¹ ΔK′ L_Dᵀ`, with `ΔK′` the removed stiffness on `D`.
//!
//! `L_D` (every free DOF's row, `D`'s columns, interior ones included) comes from solves with
//! the stiffness's factor, kept for that: a tet's 12 DOFs cost 12 solves. Nothing is
//! recomputed. Two kinds of DOF would make `K′` singular, and are handled before any solve:
//! * a node left with no tet is **pinned**: its DOFs keep a stiffness of their own diagonal
//!   in `K` and nothing else (so `L′` is exactly the inverse of the remaining tets' stiffness
//!   with that node removed); it does not move.
//! * a piece that nothing holds rigidly (cut right through, a flap hanging by nothing, or
//!   by an edge or a vertex alone) is **removed**: its tets join the cut and its nodes are
//!   pinned; the cut reports it.
//!
//! The standard formulation only (a locking-free mixed system's cut is not this rank).

use glam::{DMat3, DVec3};
use nalgebra::DMatrix;

use crate::fem::{element_stiffness, Dofs, Factor, Stiffness};
use crate::mesh::Mesh;
use crate::Error;

/// What one [`Cut::remove`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CutReport {
    /// Tets removed by this call (those asked for and not yet removed, and those of the
    /// pieces it cut off).
    pub tets_removed: usize,
    /// Pieces that lost every clamp and were removed.
    pub pieces_removed: usize,
    /// Nodes pinned (left with no tet).
    pub nodes_pinned: usize,
    /// The correction's rank (the DOFs it touches) after the call.
    pub rank: usize,
}

/// A body being cut: its factor, the tets removed so far and the exact correction of `L`.
pub struct Cut {
    dofs: Dofs,
    factor: Factor,
    /// Per tet: removed.
    removed: Vec<bool>,
    /// Per node: tets left.
    tets_left: Vec<u32>,
    /// Per node: pinned (no tet left, or in a removed piece).
    pinned: Vec<bool>,
    /// The free DOFs the correction touches, in order; and each free DOF's place (or MAX).
    d: Vec<usize>,
    place: Vec<u32>,
    /// `ΔK′` on `D`.
    dk: DMatrix<f64>,
    /// `L_D`: every free DOF's row, `D`'s columns.
    ld: DMatrix<f64>,
    /// `C = (I − ΔK′ L_DD)⁻¹ ΔK′`.
    cap: DMatrix<f64>,
    /// The diagonal of K at each free DOF (a pinned DOF's own stiffness).
    kdiag: Vec<f64>,
}

impl Cut {
    /// Prepares `mesh` for cutting: assembles and factors its stiffness (as the precompute
    /// does). Errors on the locking-free formulation.
    pub fn new(mesh: &Mesh) -> Result<Cut, Error> {
        if mesh.formulation != crate::mesh::units::Formulation::Standard {
            return Err(Error::Input(
                "cutting needs the standard formulation (the locking-free mixed system is not a low-rank change)"
                    .into(),
            ));
        }
        let k = Stiffness::assemble(mesh)?;
        let factor = k.factorize()?;
        let n_free = k.dofs.n_free;
        let mut kdiag = vec![0.0; n_free];
        for (j, kd) in kdiag.iter_mut().enumerate() {
            let col = k.k.col_range(j);
            let rows = &k.k.symbolic().row_idx()[col.clone()];
            let vals = &k.k.val()[col];
            if let Some(p) = rows.iter().position(|&r| r == j) {
                *kd = vals[p];
            }
        }
        let nn = mesh.nodes.len();
        let mut tets_left = vec![0u32; nn];
        for t in &mesh.tets {
            for &v in t {
                tets_left[v as usize] += 1;
            }
        }
        Ok(Cut {
            place: vec![u32::MAX; n_free],
            dofs: k.dofs,
            factor,
            removed: vec![false; mesh.tets.len()],
            tets_left,
            pinned: vec![false; nn],
            d: Vec::new(),
            dk: DMatrix::zeros(0, 0),
            ld: DMatrix::zeros(n_free, 0),
            cap: DMatrix::zeros(0, 0),
            kdiag,
        })
    }

    /// Tets removed so far.
    pub fn removed(&self) -> &[bool] {
        &self.removed
    }

    /// Nodes pinned so far (no tet left, or cut off in a piece).
    pub fn pinned(&self) -> &[bool] {
        &self.pinned
    }

    /// The correction's rank: the free DOFs it touches.
    pub fn rank(&self) -> usize {
        self.d.len()
    }

    /// Removes `tets` (indices into `mesh.tets`; repeats and removed ones are ignored), and any
    /// piece that loses every clamp, and updates the correction exactly. Errors (and changes
    /// nothing) on an index out of range.
    pub fn remove(&mut self, mesh: &Mesh, tets: &[usize]) -> Result<CutReport, Error> {
        if let Some(&bad) = tets.iter().find(|&&t| t >= mesh.tets.len()) {
            return Err(Error::Input(format!(
                "tet {bad} does not exist (the mesh has {})",
                mesh.tets.len()
            )));
        }
        let mut report = CutReport::default();
        let mut new_tets: Vec<usize> = Vec::new();
        for &t in tets {
            if !self.removed[t] {
                self.removed[t] = true;
                new_tets.push(t);
            }
        }
        for &t in &new_tets {
            for &v in &mesh.tets[t] {
                self.tets_left[v as usize] -= 1;
            }
        }
        // Pieces no clamp holds.
        let cut_off = self.free_pieces(mesh);
        if !cut_off.is_empty() {
            report.pieces_removed = cut_off.len();
            for piece in cut_off {
                for t in piece {
                    if !self.removed[t] {
                        self.removed[t] = true;
                        new_tets.push(t);
                        for &v in &mesh.tets[t] {
                            self.tets_left[v as usize] -= 1;
                        }
                    }
                }
            }
        }
        report.tets_removed = new_tets.len();
        // Nodes left with no tet.
        let mut new_pins: Vec<u32> = Vec::new();
        for &t in &new_tets {
            for &v in &mesh.tets[t] {
                if self.tets_left[v as usize] == 0 && !self.pinned[v as usize] {
                    self.pinned[v as usize] = true;
                    new_pins.push(v);
                }
            }
        }
        report.nodes_pinned = new_pins.len();
        // The DOFs the correction now touches.
        let mut new_d: Vec<usize> = Vec::new();
        for &t in &new_tets {
            for &v in &mesh.tets[t] {
                for a in 0..3 {
                    if let Some(f) = self.dofs.free(v, a) {
                        if self.place[f] == u32::MAX {
                            self.place[f] = (self.d.len() + new_d.len()) as u32;
                            new_d.push(f);
                        }
                    }
                }
            }
        }
        if !new_d.is_empty() {
            self.grow(&new_d);
        }
        // ΔK′: the removed tets' stiffness, minus a pin on the pinned DOFs.
        for &t in &new_tets {
            let nodes = mesh.tets[t];
            let ke =
                element_stiffness(nodes.map(|i| mesh.nodes[i as usize]), &mesh.tet_material(t));
            for a in 0..4 {
                for i in 0..3 {
                    let Some(fa) = self.dofs.free(nodes[a], i) else {
                        continue;
                    };
                    let pa = self.place[fa] as usize;
                    for b in 0..4 {
                        for j in 0..3 {
                            let Some(fb) = self.dofs.free(nodes[b], j) else {
                                continue;
                            };
                            let pb = self.place[fb] as usize;
                            self.dk[(pa, pb)] += ke[3 * a + i][3 * b + j];
                        }
                    }
                }
            }
        }
        for &v in &new_pins {
            for a in 0..3 {
                if let Some(f) = self.dofs.free(v, a) {
                    let p = self.place[f] as usize;
                    self.dk[(p, p)] -= self.kdiag[f];
                }
            }
        }
        self.capacitance()?;
        report.rank = self.d.len();
        Ok(report)
    }

    /// Appends the uncut `L`'s columns at `new` (solves with the factor) to `L_D`; the cut
    /// lives in `C` alone.
    fn grow(&mut self, new: &[usize]) {
        let n = self.dofs.n_free;
        let mut b = faer::Mat::<f64>::zeros(n, new.len());
        for (j, &f) in new.iter().enumerate() {
            b[(f, j)] = 1.0;
        }
        self.factor.solve_in_place(&mut b);
        let old = self.d.len();
        let m = old + new.len();
        let mut ld = DMatrix::zeros(n, m);
        ld.view_mut((0, 0), (n, old)).copy_from(&self.ld);
        for j in 0..new.len() {
            for i in 0..n {
                ld[(i, old + j)] = b[(i, j)];
            }
        }
        self.ld = ld;
        let mut dk = DMatrix::zeros(m, m);
        dk.view_mut((0, 0), (old, old)).copy_from(&self.dk);
        self.dk = dk;
        self.d.extend_from_slice(new);
    }

    /// `C = (I − ΔK′ L_DD)⁻¹ ΔK′`.
    fn capacitance(&mut self) -> Result<(), Error> {
        let m = self.d.len();
        let mut ldd = DMatrix::zeros(m, m);
        for (a, &fa) in self.d.iter().enumerate() {
            for b in 0..m {
                ldd[(a, b)] = self.ld[(fa, b)];
            }
        }
        let mmat = DMatrix::identity(m, m) - &self.dk * ldd;
        let lu = mmat.lu();
        let cap = lu.solve(&self.dk).ok_or_else(|| {
            Error::Input(
                "the cut left a singular stiffness (a piece that no clamp holds was not found)"
                    .into(),
            )
        })?;
        if !cap.iter().all(|v| v.is_finite()) {
            return Err(Error::Input("the cut's correction is not finite".into()));
        }
        self.cap = cap;
        Ok(())
    }

    /// The pieces of the remaining tets that nothing holds rigidly: each a list of tets.
    ///
    /// Tets sharing a face form a rigid-enough block (a component). A component is held when
    /// it has three non-collinear clamped nodes, or shares three non-collinear nodes with a
    /// held one (repeated until nothing changes). One held by a single node or an edge alone
    /// (a hinge), or by nothing, could move rigidly: its stiffness is singular, so it goes.
    fn free_pieces(&self, mesh: &Mesh) -> Vec<Vec<usize>> {
        let nt = mesh.tets.len();
        let mut parent: Vec<u32> = (0..nt as u32).collect();
        use crate::fem::{collinear, join, root};
        // Tets sharing a face.
        let mut faces: std::collections::HashMap<[u32; 3], u32> = Default::default();
        for (ti, t) in mesh.tets.iter().enumerate() {
            if self.removed[ti] {
                continue;
            }
            for skip in 0..4 {
                let mut f = [0u32; 3];
                let mut k = 0;
                for (a, &v) in t.iter().enumerate() {
                    if a != skip {
                        f[k] = v;
                        k += 1;
                    }
                }
                f.sort_unstable();
                match faces.entry(f) {
                    std::collections::hash_map::Entry::Occupied(o) => {
                        join(&mut parent, *o.get(), ti as u32);
                    }
                    std::collections::hash_map::Entry::Vacant(v) => {
                        v.insert(ti as u32);
                    }
                }
            }
        }
        // Each component's nodes.
        let mut nodes_of: std::collections::BTreeMap<u32, Vec<u32>> = Default::default();
        let mut tets_of: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
        for (ti, t) in mesh.tets.iter().enumerate() {
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
        // Three non-collinear points among these nodes (the same test as the stiffness's).
        let (lo, hi) = mesh.bounds();
        let scale = (hi - lo).length().max(f64::MIN_POSITIVE);
        let spans_plane = |pts: &mut dyn Iterator<Item = u32>| -> bool {
            let pts: Vec<DVec3> = pts.map(|v| mesh.nodes[v as usize]).collect();
            pts.len() >= 3 && !collinear(&pts, scale)
        };
        let roots: Vec<u32> = nodes_of.keys().copied().collect();
        let mut held: std::collections::BTreeSet<u32> = roots
            .iter()
            .copied()
            .filter(|r| {
                spans_plane(
                    &mut nodes_of[r]
                        .iter()
                        .copied()
                        .filter(|&v| mesh.fixed[v as usize]),
                )
            })
            .collect();
        // Which components each node is in.
        let mut comps_at: std::collections::HashMap<u32, Vec<u32>> = Default::default();
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

    /// The displacement of every node (m) under nodal `forces` (mesh node, N) on the cut
    /// body: `L′ f` by a solve and the correction. Pinned and clamped nodes do not move; a
    /// force on them is ignored.
    pub fn displace(&self, forces: &[(u32, DVec3)]) -> Vec<DVec3> {
        let n = self.dofs.n_free;
        let mut f = faer::Mat::<f64>::zeros(n, 1);
        for &(v, fv) in forces {
            if self.pinned.get(v as usize).copied().unwrap_or(true) {
                continue;
            }
            for a in 0..3 {
                if let Some(d) = self.dofs.free(v, a) {
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
        self.factor.solve_in_place(&mut x);
        let corr = &self.ld * z;
        let mut u = vec![DVec3::ZERO; self.pinned.len()];
        for (d, &(v, a)) in self.dofs.owner.iter().enumerate() {
            if !self.pinned[v as usize] {
                u[v as usize][a as usize] = x[(d, 0)] + corr[d];
            }
        }
        u
    }

    /// The 3×3 block `L′(i, j)` between two nodes (m/N): what the haptic path's force solve
    /// reads after the cut. Zero for a clamped or pinned node.
    pub fn block(&self, i: u32, j: u32) -> DMat3 {
        let mut out = DMat3::ZERO;
        if self.pinned[i as usize] || self.pinned[j as usize] {
            return out;
        }
        let n = self.dofs.n_free;
        let mut b = faer::Mat::<f64>::zeros(n, 3);
        let mut any = false;
        for c in 0..3 {
            if let Some(d) = self.dofs.free(j, c) {
                b[(d, c)] = 1.0;
                any = true;
            }
        }
        if !any {
            return out;
        }
        self.factor.solve_in_place(&mut b);
        let m = self.d.len();
        for c in 0..3 {
            let Some(dj) = self.dofs.free(j, c) else {
                continue;
            };
            // L′ e_j = L e_j + L_D C L_Dᵀ e_j, and L_Dᵀ e_j is L_D's row at j.
            let y = nalgebra::DVector::from_fn(m, |b, _| self.ld[(dj, b)]);
            let z = &self.cap * y;
            for r in 0..3 {
                let Some(di) = self.dofs.free(i, r) else {
                    continue;
                };
                let mut v = b[(di, c)];
                for k in 0..m {
                    v += self.ld[(di, k)] * z[k];
                }
                out.col_mut(c)[r] = v;
            }
        }
        out
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

/// The tets a blade sweeps: the blade is the segment from the surface point `p1` down to
/// `depth` (m) below it along `inward` (the object's inward surface normal where it
/// entered), drawn along the surface to `p2`; its swept surface is the quad `p1, p2,
/// p2 + depth·inward, p1 + depth·inward`. A tet is removed when the quad's plane separates
/// its corners and the plane's section of the tet meets the quad. Empty for a degenerate or
/// non-finite blade (depth ≤ 0, `p1 = p2`).
pub fn blade_tets(mesh: &Mesh, p1: DVec3, p2: DVec3, inward: DVec3, depth: f64) -> Vec<usize> {
    let along = p2 - p1;
    let len = along.length();
    let inward = inward.normalize_or_zero();
    if !(depth.is_finite() && depth > 0.0 && len.is_finite() && len > 0.0 && p1.is_finite())
        || inward == DVec3::ZERO
    {
        return Vec::new();
    }
    let t = along / len;
    // The blade's down direction, made perpendicular to its path.
    let down = (inward - t * t.dot(inward)).normalize_or_zero();
    if down == DVec3::ZERO {
        return Vec::new();
    }
    let m = t.cross(down);
    let inside = |q: DVec3| {
        let r = q - p1;
        let (u, v) = (r.dot(t), r.dot(down));
        (-1e-12..=len + 1e-12).contains(&u) && (-1e-12..=depth + 1e-12).contains(&v)
    };
    let mut out = Vec::new();
    for (ti, tet) in mesh.tets.iter().enumerate() {
        let p = tet.map(|v| mesh.nodes[v as usize]);
        let s = p.map(|q| (q - p1).dot(m));
        let (lo, hi) = s
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        if !(lo < 0.0 && hi > 0.0) {
            continue;
        }
        // The section's corners: where the tet's edges cross the plane.
        let mut hit = false;
        let mut section = [DVec3::ZERO; 4];
        let mut k = 0;
        for a in 0..4 {
            for b in a + 1..4 {
                if (s[a] < 0.0) != (s[b] < 0.0) {
                    let w = s[a] / (s[a] - s[b]);
                    let q = p[a] + (p[b] - p[a]) * w;
                    if k < 4 {
                        section[k] = q;
                        k += 1;
                    }
                    hit |= inside(q);
                }
            }
        }
        // The quad may lie inside a large tet's section: test its corners against the
        // section (a triangle or a quadrilateral, convex).
        if !hit && k >= 3 {
            let c = section[..k].iter().copied().sum::<DVec3>() / k as f64;
            let corners = [p1, p2, p2 + down * depth, p1 + down * depth];
            hit = corners.iter().any(|&q| in_convex(&section[..k], c, q, m));
        }
        if hit {
            out.push(ti);
        }
    }
    out
}

/// Whether `q` (on the plane of normal `m`) lies in the convex hull of `pts` (unordered,
/// 3 or 4 points, centroid `c`).
fn in_convex(pts: &[DVec3], c: DVec3, q: DVec3, m: DVec3) -> bool {
    // Order the points by angle around the centroid, then test the edges.
    let e1 = (pts[0] - c).normalize_or_zero();
    let e2 = m.cross(e1);
    let mut order: Vec<(f64, DVec3)> = pts
        .iter()
        .map(|&p| ((p - c).dot(e2).atan2((p - c).dot(e1)), p))
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = order.len();
    (0..n).all(|i| {
        let a = order[i].1;
        let b = order[(i + 1) % n].1;
        (b - a).cross(q - a).dot(m) >= -1e-15
    })
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

    /// This cut started afresh from the body it has made: the remaining tets' stiffness
    /// factored (pinned nodes held as clamps), the correction empty, the tets removed and the
    /// nodes pinned kept. Its corrections are then relative to [`Cut::fold`]'s compliance,
    /// so that after a fold the carried rank starts from zero. `mesh` is the uncut mesh (the
    /// one [`Cut::remove`] takes). Costs one assembly and factorisation.
    pub fn rebase(&self, mesh: &Mesh) -> Result<Cut, Error> {
        let mut rest = mesh.without_tets(&self.removed);
        for (f, &p) in rest.fixed.iter_mut().zip(&self.pinned) {
            *f |= p;
        }
        let mut next = Cut::new(&rest)?;
        next.removed = self.removed.clone();
        next.tets_left = self.tets_left.clone();
        next.pinned = self.pinned.clone();
        Ok(next)
    }
}

impl Cut {
    /// The correction to carry beside `c` (the uncut body's compliance, `L` on the host) so
    /// that it reads `L′` exactly: `U` at its held rows and touchable columns, `V = U Cᵀ`, the
    /// pinned rows and columns, and `L′_cc⁻¹` of every column left. Costs
    /// `3·C·rank²` multiply-adds (`V`) and the copy of `U`'s rows; made off the haptic
    /// thread, then handed over with [`Compliance::with_correction`].
    ///
    /// [`Compliance::with_correction`]: crate::compliance::Compliance::with_correction
    pub fn correction(
        &self,
        c: &crate::compliance::Compliance,
    ) -> Result<crate::compliance::correction::Correction, Error> {
        use crate::compliance::correction::Correction;
        if !c.holds_l() {
            return Err(Error::Input(
                "carrying a cut needs L on the host (not a lean compliance)".into(),
            ));
        }
        let r = self.d.len();
        let nr = c.l_rows();
        let nc = c.cols().len();
        let dof = |node: u32, a: usize| -> Option<usize> {
            if self.pinned.get(node as usize).copied().unwrap_or(true) {
                None
            } else {
                self.dofs.free(node, a)
            }
        };
        let mut rows = vec![0.0; 3 * nr * r];
        let mut dead_rows = vec![false; nr];
        for (k, &node) in c.rows()[..nr].iter().enumerate() {
            dead_rows[k] = self.pinned.get(node as usize).copied().unwrap_or(true);
            for a in 0..3 {
                if let Some(d) = dof(node, a) {
                    for q in 0..r {
                        rows[q * 3 * nr + 3 * k + a] = self.ld[(d, q)];
                    }
                }
            }
        }
        let mut u_cols = vec![0.0; 3 * nc * r];
        let mut v_cols = vec![0.0; 3 * nc * r];
        let mut dead_cols = vec![false; nc];
        for (ci, &node) in c.cols().iter().enumerate() {
            dead_cols[ci] = self.pinned.get(node as usize).copied().unwrap_or(true);
            for a in 0..3 {
                let Some(d) = dof(node, a) else { continue };
                let u = &mut u_cols[(3 * ci + a) * r..][..r];
                for (q, uq) in u.iter_mut().enumerate() {
                    *uq = self.ld[(d, q)];
                }
            }
        }
        // V = U Cᵀ for every column at once (a matrix product; u_cols is U row by row, so
        // U's transpose column-major: Vᵀ = C Uᵀ).
        if r > 0 && nc > 0 {
            let ut = nalgebra::DMatrixView::from_slice(&u_cols, r, 3 * nc);
            let vt = &self.cap * ut;
            v_cols.copy_from_slice(vt.as_slice());
        }
        let mut k = Correction {
            rank: r,
            rows,
            u_cols,
            v_cols,
            dead_rows,
            dead_cols,
            diag_inv: Vec::new(),
        };
        let mut diag_inv = Vec::with_capacity(nc);
        for ci in 0..nc {
            if k.dead_cols[ci] {
                diag_inv.push(DMat3::ZERO);
                continue;
            }
            let b = c.block(c.col_row(ci), ci) + k.col_block(ci, ci);
            diag_inv.push(crate::compliance::invert3(b).ok_or_else(|| {
                Error::Input(format!(
                    "the cut left node {} with a singular compliance",
                    c.cols()[ci]
                ))
            })?);
        }
        k.diag_inv = diag_inv;
        Ok(k)
    }
}
