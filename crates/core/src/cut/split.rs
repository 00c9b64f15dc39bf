//! Separating the material along a blade's quad, Nienhuys & van der Stappen's snap and split:
//!
//! 1. **Snap.** Every edge that crosses the quad's plane at a point inside the quad has its
//!    endpoint nearer the plane moved onto it, nearest first, until no edge crosses: an
//!    interior node along the plane's normal, a node on the body's surface sliding along the
//!    surface (so the body keeps its shape; the pocket a dropped sliver left along the plane
//!    is not the body's surface and holds no node), a clamped node only within the plane of its
//!    clamped faces; never more than half the edge. Where the nearer end may not move the
//!    other one does, within the same bound, else the crossing stays. A node's copies at its
//!    place move with it. A tet the snapping leaves with [`SLIVER_FRACTION`] of its uncut
//!    volume or less (or inverted) is a sliver: dropped, counted, its volume reported.
//! 2. **Cut faces** are the faces of the remaining tets whose three nodes lie on the plane and
//!    whose centroid lies in the quad.
//! 3. **Split.** Around each node of a cut face, the remaining tets are grouped into the
//!    components that share faces that are not cut; the first component (the one with the
//!    lowest tet) keeps the node, each further one gets a copy (clamped if the node is). Where
//!    the cut ends inside the body a node's tets stay one component: a crack's tip splits
//!    nothing. Tets that only touched at a node before the cut stay so.
//!
//! [`Cut::split`] then removes the pieces no clamp holds and updates the correction as
//! [`Cut::remove`] does.

use std::collections::{HashMap, HashSet};

use glam::DVec3;

use super::blade::BladeQuad;
use super::body::{Changes, Cut, CutReport};
use crate::mesh::{tet_volume, Mesh, TET_FACES};
use crate::Error;

/// A tet whose volume after snapping is at most this fraction of its uncut volume (or
/// inverted) is a sliver, and is dropped.
pub const SLIVER_FRACTION: f64 = 0.05;

/// What one [`Cut::split`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SplitReport {
    /// The removal part: the tets removed (slivers, and the pieces that lost every clamp),
    /// the nodes pinned, and the correction's rank after the call.
    pub cut: CutReport,
    /// Nodes moved onto a blade's plane (a node and its copies at its place count once).
    pub nodes_snapped: usize,
    /// Copies made: one for each further side of a split node.
    pub nodes_split: usize,
    /// Cut faces that two tets shared (the faces the cut opened).
    pub faces_cut: usize,
    /// Slivers dropped.
    pub slivers: usize,
    /// Their volume when dropped (m³, after snapping, inverted ones counted positive).
    pub sliver_volume: f64,
    /// Edges left crossing a quad (their nearer end clamped, the other too far to move).
    pub crossings_left: usize,
}

/// A face whose normal is within about 25° of a blade's plane normal (the cosine) lies along
/// that plane (a dropped sliver's pocket that does not hold a snap: `Cut::boundary_normals`).
const ALONG_THE_PLANE: f64 = 0.9;

/// What an edge needs from the snapping.
enum Crossing {
    /// Nothing: it does not cross the plane inside the quad.
    None,
    /// This node (at this distance from the plane) moves onto it.
    Snap(f64, u32),
    /// It crosses, and neither end may move.
    Stuck,
}

/// The alive tets of each node, as a CSR list.
struct NodeTets {
    start: Vec<u32>,
    list: Vec<u32>,
}

impl NodeTets {
    fn of(&self, v: u32) -> &[u32] {
        let v = v as usize;
        &self.list[self.start[v] as usize..self.start[v + 1] as usize]
    }
}

/// What one blade's snapping reads: its quad, the distance that counts as on its plane, the
/// normals of the boundary faces at each node, and each split node's copies (by origin).
struct Ctx<'a> {
    b: &'a BladeQuad,
    eps: f64,
    /// Per node: it has a tet outside the region the cut is confined to (it may not move).
    frozen: Vec<bool>,
    normals: HashMap<u32, Vec<DVec3>>,
    twins: HashMap<u32, Vec<u32>>,
}

/// Boundary faces whose normals all lie within this cosine of their mean make a smooth
/// surface, along which a node slides onto the plane; at a sharper edge or corner a node
/// moves only when the quad's normal lies along every face there.
const SMOOTH: f64 = 0.9;

/// A face across the joint of two quads is cut when its centroid lies within this fraction
/// of its longest edge of one of them ([`Cut::split_after`]).
const JOINT: f64 = 0.1;

impl Cut {
    /// Separates the body along each blade's quad in turn (a polyline's quads, or one), and
    /// updates the correction exactly: snaps, drops the slivers, cuts the faces and splits
    /// their nodes (see the module's page), then removes the pieces no clamp holds and pins
    /// the nodes left with no tet. `mesh` is the uncut mesh (its tets' materials). A blade
    /// that crosses no edge of the body changes nothing. Errors (and changes nothing) on a
    /// blade that is not finite or not a quad ([`BladeQuad::new`] makes only good ones), a
    /// mesh that is not this cut's, or a correction that cannot be made.
    pub fn split(&mut self, mesh: &Mesh, blades: &[BladeQuad]) -> Result<SplitReport, Error> {
        self.split_within(mesh, blades, None)
    }

    /// [`Cut::split`] confined to the tets `region` marks (per tet of `mesh`; `None`: all):
    /// only faces between two of them are cut, and only nodes whose every tet is one of them
    /// are snapped, so no other tet changes. Errors as [`Cut::split`] does, and on a region
    /// of another length.
    pub fn split_within(
        &mut self,
        mesh: &Mesh,
        blades: &[BladeQuad],
        region: Option<&[bool]>,
    ) -> Result<SplitReport, Error> {
        self.split_after(mesh, &[], blades, region)
    }

    /// [`Cut::split_within`] along `blades` after `before`: quads already cut (a continuous
    /// blade's chords just before), which snap nothing again but whose faces now on their
    /// plane (their nodes snapped by `blades`) are cut too, the nodes split once over every
    /// quad's faces. Errors as [`Cut::split_within`] does.
    pub fn split_after(
        &mut self,
        mesh: &Mesh,
        before: &[BladeQuad],
        blades: &[BladeQuad],
        region: Option<&[bool]>,
    ) -> Result<SplitReport, Error> {
        self.check_mesh(mesh)?;
        if region.is_some_and(|r| r.len() != self.tets.len()) {
            return Err(Error::Input(format!(
                "a cut region of {} tets for a mesh of {}",
                region.map_or(0, |r| r.len()),
                self.tets.len()
            )));
        }
        for b in before.iter().chain(blades) {
            let unit = |v: DVec3| v.is_finite() && (v.length() - 1.0).abs() < 1e-9;
            let good = b.from.is_finite()
                && unit(b.along)
                && unit(b.down)
                && unit(b.normal)
                && b.along.dot(b.down).abs() < 1e-9
                && b.length.is_finite()
                && b.length > 0.0
                && b.depth.is_finite()
                && b.depth > 0.0;
            if !good {
                return Err(Error::Input(format!("not a blade's quad: {b:?}")));
            }
        }
        let born = self.nodes.len();
        let saved = self.save();
        let mut changes = Changes::new(self.tets.len());
        let mut report = SplitReport::default();
        let (lo, hi) = (self.nodes.iter()).fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let eps = 1e-9 * (hi - lo).length();
        // Each blade snaps and finds its cut faces; the nodes are split once, over the faces
        // of every blade (a face cut by one quad and one cut by the next may part a node
        // between them: a continuous blade's chords, a polyline's quads).
        // (The faces a cut exposes, its lips and a dropped sliver's pocket, are not in the
        // uncut body's boundary, whose shape a snap keeps.)
        let outer = self.outer.clone();
        let mut faces: HashMap<[u32; 3], u32> = HashMap::new();
        for b in blades {
            for (k, n) in self.split_one(b, eps, region, &outer, &mut changes, &mut report) {
                let e = faces.entry(k).or_insert(0);
                *e = (*e).max(n);
            }
        }
        // The faces of the quads before, and those across the joint of two quads (a path's
        // segments, a polyline's bends): `joint_faces` finds every face `cut_faces` finds on
        // one of its quads, and those across their joints.
        if blades.len() + before.len() > 1 {
            let quads: Vec<&BladeQuad> = blades.iter().chain(before).collect();
            for (k, n) in self.joint_faces(&quads, eps, region) {
                let e = faces.entry(k).or_insert(0);
                *e = (*e).max(n);
            }
        }
        report.faces_cut = faces.values().filter(|&&n| n == 2).count();
        let cut: HashSet<[u32; 3]> = faces.into_keys().collect();
        self.split_nodes(&cut, region, &mut changes);
        report.nodes_split = self.nodes.len() - born;
        if changes.list.is_empty() {
            report.cut.rank = self.rank();
            return Ok(report);
        }
        report.cut = self
            .commit(mesh, changes, born)
            .inspect_err(|_| self.restore(saved))?;
        Ok(report)
    }

    /// One blade's snap, slivers and cut faces (`eps`: the distance that counts as on the
    /// plane, m): returns each cut face (sorted nodes) with the number of its tets near.
    fn split_one(
        &mut self,
        b: &BladeQuad,
        eps: f64,
        region: Option<&[bool]>,
        outer: &HashSet<[u32; 3]>,
        changes: &mut Changes,
        report: &mut SplitReport,
    ) -> HashMap<[u32; 3], u32> {
        let inside = |t: usize| region.is_none_or(|r| r[t]);
        let mut near = self.tets_near(b, eps);
        near.retain(|&t| inside(t));
        if near.is_empty() {
            return HashMap::new();
        }
        let adj = self.node_tets();
        // 1. Snap.
        let mut edges: Vec<(u32, u32)> = Vec::with_capacity(6 * near.len());
        for &t in &near {
            let tv = self.tets[t];
            for i in 0..4 {
                for j in i + 1..4 {
                    edges.push((tv[i].min(tv[j]), tv[i].max(tv[j])));
                }
            }
        }
        edges.sort_unstable();
        edges.dedup();
        let mut nbrs: HashMap<u32, Vec<u32>> = HashMap::new();
        for &(a, c) in &edges {
            nbrs.entry(a).or_default().push(c);
            nbrs.entry(c).or_default().push(a);
        }
        let mut twins: HashMap<u32, Vec<u32>> = HashMap::new();
        for c in self.nodes.len() - self.copies()..self.nodes.len() {
            let o = self.origin[c];
            twins.entry(o).or_insert_with(|| vec![o]).push(c as u32);
        }
        let mut frozen = vec![false; self.nodes.len()];
        if region.is_some() {
            for (t, tv) in self.tets.iter().enumerate() {
                if !self.removed[t] && !inside(t) {
                    for &v in tv {
                        frozen[v as usize] = true;
                    }
                }
            }
        }
        let cx = Ctx {
            b,
            eps,
            frozen,
            normals: self.boundary_normals(&near, &adj, &twins, (outer, b.normal)),
            twins,
        };
        loop {
            let mut picks: Vec<(f64, u32)> = Vec::new();
            let mut stuck = 0;
            for &(a, c) in &edges {
                match self.crossing(&cx, a, c) {
                    Crossing::None => {}
                    Crossing::Snap(s, v) => picks.push((s, v)),
                    Crossing::Stuck => stuck += 1,
                }
            }
            if picks.is_empty() {
                report.crossings_left += stuck;
                break;
            }
            picks.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            picks.dedup_by_key(|p| p.1);
            for &(_, v) in &picks {
                // Still needed after the nearer ones moved?
                // (Each edge is judged with its ends in one order, as above, so that a tie
                // picks the same end.)
                let needed = nbrs[&v].iter().any(|&w| {
                    let (a, c) = (v.min(w), v.max(w));
                    matches!(self.crossing(&cx, a, c), Crossing::Snap(_, x) if x == v)
                });
                if needed {
                    self.snap(v, &cx, &adj, changes);
                    report.nodes_snapped += 1;
                }
            }
        }
        // Slivers.
        for noted in &changes.list {
            let t = noted.tet;
            if self.removed[t] {
                continue;
            }
            let p = self.tets[t].map(|v| self.nodes[v as usize]);
            let vol = tet_volume(p[0], p[1], p[2], p[3]);
            if vol.is_nan() || vol <= SLIVER_FRACTION * self.vol0[t] {
                self.removed[t] = true;
                report.slivers += 1;
                report.sliver_volume += vol.abs();
            }
        }
        self.cut_faces(b, eps, region)
    }

    /// Step 2: the faces of the alive tets in `region` whose three nodes lie on `b`'s plane
    /// and whose centroid lies in the quad (sorted nodes), with the number of their tets near.
    fn cut_faces(
        &self,
        b: &BladeQuad,
        eps: f64,
        region: Option<&[bool]>,
    ) -> HashMap<[u32; 3], u32> {
        let inside = |t: usize| region.is_none_or(|r| r[t]);
        let mut near = self.tets_near(b, eps);
        near.retain(|&t| inside(t));
        let on = |v: u32| b.coords(self.nodes[v as usize]).2.abs() <= eps;
        let mut cut_faces: HashMap<[u32; 3], u32> = HashMap::new();
        for &t in &near {
            let tv = self.tets[t];
            for lf in TET_FACES {
                let f = lf.map(|k| tv[k]);
                if !f.iter().all(|&v| on(v)) {
                    continue;
                }
                let c = f.iter().map(|&v| self.nodes[v as usize]).sum::<DVec3>() / 3.0;
                let (u, v, _) = b.coords(c);
                if b.contains(u, v, eps) {
                    let mut key = f;
                    key.sort_unstable();
                    *cut_faces.entry(key).or_insert(0) += 1;
                }
            }
        }
        cut_faces
    }

    /// The faces of the alive tets in `region` near any of `quads` whose every node lies on
    /// one of them (on its plane to `eps`, within the face's longest edge of it: a snap moves
    /// the end of an edge that crosses the quad) and whose centroid lies within a tenth of
    /// that edge of one of them: every face [`Cut::cut_faces`] finds on one of them, and the
    /// faces across a joint, whose nodes were snapped onto two quads' planes (sorted nodes,
    /// with the number of their tets near). Where the planes
    /// turn by a few degrees, such a face lies on the blade's path to well within an edge;
    /// at a sharp bend its centroid is too far off both planes and it stays whole.
    fn joint_faces(
        &self,
        quads: &[&BladeQuad],
        eps: f64,
        region: Option<&[bool]>,
    ) -> HashMap<[u32; 3], u32> {
        let inside = |t: usize| region.is_none_or(|r| r[t]);
        let mut near: Vec<usize> = (quads.iter())
            .flat_map(|b| self.tets_near(b, eps))
            .filter(|&t| inside(t))
            .collect();
        near.sort_unstable();
        near.dedup();
        let on = |p: DVec3, within: f64, plane: f64| {
            quads.iter().any(|b| {
                let (u, v, s) = b.coords(p);
                s.abs() <= plane && b.contains(u, v, within)
            })
        };
        let mut out: HashMap<[u32; 3], u32> = HashMap::new();
        for &t in &near {
            let tv = self.tets[t];
            for lf in TET_FACES {
                let f = lf.map(|k| tv[k]);
                let p = f.map(|v| self.nodes[v as usize]);
                let longest = (p[0].distance(p[1]))
                    .max(p[1].distance(p[2]))
                    .max(p[2].distance(p[0]));
                let tol = (JOINT * longest).max(eps);
                if !p.iter().all(|&q| on(q, longest, eps)) {
                    continue;
                }
                if on((p[0] + p[1] + p[2]) / 3.0, tol, tol) {
                    let mut key = f;
                    key.sort_unstable();
                    *out.entry(key).or_insert(0) += 1;
                }
            }
        }
        out
    }

    /// Step 3: splits the nodes of the `cut` faces, from the tets as they stand (relabelled
    /// once every node is decided).
    fn split_nodes(
        &mut self,
        cut: &HashSet<[u32; 3]>,
        region: Option<&[bool]>,
        changes: &mut Changes,
    ) {
        let inside = |t: usize| region.is_none_or(|r| r[t]);
        let mut on_cut: Vec<u32> = cut.iter().flatten().copied().collect();
        on_cut.sort_unstable();
        on_cut.dedup();
        let adj = self.node_tets();
        let mut relabel: Vec<(usize, u32, u32)> = Vec::new();
        for &v in &on_cut {
            let star = adj.of(v);
            if star.len() < 2 {
                continue;
            }
            let mut all: Vec<usize> = (0..star.len()).collect();
            let mut open: Vec<usize> = (0..star.len()).collect();
            let mut seen: HashMap<[u32; 3], usize> = HashMap::new();
            for (i, &t) in star.iter().enumerate() {
                let tv = self.tets[t as usize];
                for lf in TET_FACES {
                    let mut key = lf.map(|k| tv[k]);
                    if !key.contains(&v) {
                        continue;
                    }
                    key.sort_unstable();
                    match seen.get(&key) {
                        Some(&j) => {
                            union(&mut all, i, j);
                            // (A face is cut only between two tets of the region.)
                            let both = inside(t as usize) && inside(star[j] as usize);
                            if !cut.contains(&key) || !both {
                                union(&mut open, i, j);
                            }
                        }
                        None => {
                            seen.insert(key, i);
                        }
                    }
                }
            }
            // Within each component of all the faces, the first side keeps the node.
            let mut keeper: HashMap<usize, usize> = HashMap::new();
            let mut copy: HashMap<usize, u32> = HashMap::new();
            for (i, &t) in star.iter().enumerate() {
                let (ra, ro) = (find(&mut all, i), find(&mut open, i));
                let keep = *keeper.entry(ra).or_insert(ro);
                if keep != ro {
                    let c = match copy.get(&ro) {
                        Some(&c) => c,
                        None => {
                            let c = self.add_copy(v);
                            copy.insert(ro, c);
                            c
                        }
                    };
                    relabel.push((t as usize, v, c));
                }
            }
        }
        for (t, v, c) in relabel {
            changes.note(self, t);
            for x in self.tets[t].iter_mut() {
                if *x == v {
                    *x = c;
                }
            }
        }
    }

    /// The alive tets with a node near the quad's plane on each side of it, or on it, whose
    /// box meets the quad's box (grown by `eps`).
    fn tets_near(&self, b: &BladeQuad, eps: f64) -> Vec<usize> {
        let corners = b.corners();
        let qlo = corners.iter().fold(DVec3::INFINITY, |m, &p| m.min(p)) - eps;
        let qhi = corners.iter().fold(DVec3::NEG_INFINITY, |m, &p| m.max(p)) + eps;
        let mut out = Vec::new();
        for (t, tv) in self.tets.iter().enumerate() {
            if self.removed[t] {
                continue;
            }
            let p = tv.map(|v| self.nodes[v as usize]);
            let lo = p.iter().fold(DVec3::INFINITY, |m, &q| m.min(q));
            let hi = p.iter().fold(DVec3::NEG_INFINITY, |m, &q| m.max(q));
            if lo.cmpgt(qhi).any() || hi.cmplt(qlo).any() {
                continue;
            }
            let s = p.map(|q| b.coords(q).2);
            if s.iter().any(|&x| x <= eps) && s.iter().any(|&x| x >= -eps) {
                out.push(t);
            }
        }
        out
    }

    /// Each node's alive tets, in tet order.
    fn node_tets(&self) -> NodeTets {
        let n = self.nodes.len();
        let mut start = vec![0u32; n + 1];
        for (t, tv) in self.tets.iter().enumerate() {
            if !self.removed[t] {
                for &v in tv {
                    start[v as usize + 1] += 1;
                }
            }
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut list = vec![0u32; start[n] as usize];
        for (t, tv) in self.tets.iter().enumerate() {
            if !self.removed[t] {
                for &v in tv {
                    list[fill[v as usize] as usize] = t as u32;
                    fill[v as usize] += 1;
                }
            }
        }
        NodeTets { start, list }
    }

    /// Whether edge `(a, c)` crosses the quad's plane inside the quad, and which end moves:
    /// the nearer one if it may, else the other; neither more than half the edge.
    fn crossing(&self, cx: &Ctx, a: u32, c: u32) -> Crossing {
        let (b, eps) = (cx.b, cx.eps);
        let (pa, pc) = (self.nodes[a as usize], self.nodes[c as usize]);
        let (sa, sc) = (b.coords(pa).2, b.coords(pc).2);
        if !((sa < -eps && sc > eps) || (sa > eps && sc < -eps)) {
            return Crossing::None;
        }
        let q = pa + (pc - pa) * (sa / (sa - sc));
        let (u, v, _) = b.coords(q);
        if !b.contains(u, v, eps) {
            return Crossing::None;
        }
        let ends = if sa.abs() <= sc.abs() {
            [(a, sa), (c, sc)]
        } else {
            [(c, sc), (a, sa)]
        };
        let half = 0.5 * pa.distance(pc);
        for (v, s) in ends {
            if let Some(t) = self.target(cx, v) {
                if t.distance(self.nodes[v as usize]) <= half {
                    return Crossing::Snap(s.abs(), v);
                }
            }
        }
        Crossing::Stuck
    }

    /// Node `v` and its copies at its place.
    fn group(&self, cx: &Ctx, v: u32) -> Vec<u32> {
        let p = self.nodes[v as usize];
        match cx.twins.get(&self.origin[v as usize]) {
            Some(g) => (g.iter().copied())
                .filter(|&w| self.nodes[w as usize] == p && !self.pinned[w as usize])
                .collect(),
            None => vec![v],
        }
    }

    /// Where node `v` lands on the quad's plane, or `None` when it may not move: an interior
    /// node along the plane's normal; a node on a smooth boundary slides along it (the normal
    /// less its part along the surface's mean normal; not where the surface is nearly
    /// parallel to the plane); at a sharp edge or corner, along the normal when that lies
    /// along every face there. A clamped node moves only within the plane of its clamped
    /// faces.
    fn target(&self, cx: &Ctx, v: u32) -> Option<DVec3> {
        let p = self.nodes[v as usize];
        let m = cx.b.normal;
        let s = cx.b.coords(p).2;
        if self.group(cx, v).iter().any(|&w| cx.frozen[w as usize]) {
            return None;
        }
        if self.fixed[v as usize] {
            let n = self.clamp_normal[v as usize];
            if n == DVec3::ZERO || n.dot(m).abs() > 1e-9 {
                return None;
            }
        }
        let ns: Vec<DVec3> = (self.group(cx, v).iter())
            .filter_map(|w| cx.normals.get(w))
            .flatten()
            .copied()
            .collect();
        let Some(&n0) = ns.first() else {
            return Some(p - m * s);
        };
        let mean = ns
            .iter()
            .map(|&n| if n.dot(n0) < 0.0 { -n } else { n })
            .sum::<DVec3>()
            .normalize_or_zero();
        if mean == DVec3::ZERO {
            return None;
        }
        if ns.iter().all(|n| n.dot(mean).abs() >= SMOOTH) {
            let t = m - mean * mean.dot(m);
            let tm = t.dot(m);
            (tm >= 0.25).then(|| p - t * (s / tm))
        } else {
            ns.iter().all(|n| n.dot(m).abs() <= 0.05).then(|| p - m * s)
        }
    }

    /// The outward normals of the boundary faces of the tets alive at the nodes of the `near`
    /// tets and their copies (sorted): from the faces of those nodes' tets alone (`adj`), since
    /// every tet of a face holds each of its nodes. The pocket a dropped sliver left (a face
    /// not on the uncut body's boundary `outer`, sorted uncut nodes, and with no twin, which
    /// a lip's face has) along the blade's `plane` (its normal) does not count: it is not
    /// the body's shape, and a node on it that had to slide along it could not reach the
    /// plane, which left the material joined across the incision's path next to a dropped
    /// flat sliver. (Lips keep their nodes on them, as the body's surface does.)
    fn boundary_normals(
        &self,
        near: &[usize],
        adj: &NodeTets,
        twins: &HashMap<u32, Vec<u32>>,
        (outer, plane): (&HashSet<[u32; 3]>, DVec3),
    ) -> HashMap<u32, Vec<DVec3>> {
        let mut nodes: Vec<u32> = near.iter().flat_map(|&t| self.tets[t]).collect();
        for k in 0..nodes.len() {
            if let Some(g) = twins.get(&self.origin[nodes[k] as usize]) {
                nodes.extend_from_slice(g);
            }
        }
        nodes.sort_unstable();
        nodes.dedup();
        let mut ring: Vec<u32> = nodes.iter().flat_map(|&v| adj.of(v)).copied().collect();
        ring.sort_unstable();
        ring.dedup();
        let mut faces: HashMap<[u32; 3], ([u32; 3], u32)> = HashMap::new();
        for &t in &ring {
            let tv = self.tets[t as usize];
            for lf in TET_FACES {
                let f = lf.map(|k| tv[k]);
                let mut key = f;
                key.sort_unstable();
                faces.entry(key).or_insert((f, 0)).1 += 1;
            }
        }
        let mut out: HashMap<u32, Vec<DVec3>> = HashMap::new();
        let bounding: Vec<[u32; 3]> = (faces.into_values())
            .filter(|&(_, count)| count == 1)
            .map(|(f, _)| f)
            .collect();
        // A lip's face has a twin (the other lip's, at the same rest positions).
        let place = |f: &[u32; 3]| {
            let mut k = f.map(|v| crate::mesh::slit::bits(self.nodes[v as usize]));
            k.sort_unstable();
            k
        };
        let mut at_place: HashMap<[[u64; 3]; 3], u32> = HashMap::new();
        for f in &bounding {
            *at_place.entry(place(f)).or_default() += 1;
        }
        for f in bounding {
            let [a, b, c] = f.map(|v| self.nodes[v as usize]);
            let n = (b - a).cross(c - a).normalize_or_zero();
            let mut uncut = f.map(|v| self.origin[v as usize]);
            uncut.sort_unstable();
            let pocket = !outer.contains(&uncut) && at_place[&place(&f)] == 1;
            if pocket && n.dot(plane).abs() >= ALONG_THE_PLANE {
                continue;
            }
            if n != DVec3::ZERO {
                for v in f {
                    if nodes.binary_search(&v).is_ok() {
                        out.entry(v).or_default().push(n);
                    }
                }
            }
        }
        // In an order that does not depend on the map's (a snap sums them: a replay must
        // snap to the same bits as the live run).
        for ns in out.values_mut() {
            ns.sort_by(|a, b| {
                (a.x.total_cmp(&b.x))
                    .then(a.y.total_cmp(&b.y))
                    .then(a.z.total_cmp(&b.z))
            });
        }
        out
    }

    /// Moves node `v` (and its copies at its place) onto the quad's plane, noting their tets.
    fn snap(&mut self, v: u32, cx: &Ctx, adj: &NodeTets, changes: &mut Changes) {
        let Some(target) = self.target(cx, v) else {
            return;
        };
        let group = self.group(cx, v);
        for &w in &group {
            for &t in adj.of(w) {
                if !self.removed[t as usize] {
                    changes.note(self, t as usize);
                }
            }
        }
        for &w in &group {
            self.nodes[w as usize] = target;
        }
    }
}

/// The root of `x` in the union–find forest `p` (path halving).
fn find(p: &mut [usize], mut x: usize) -> usize {
    while p[x] != x {
        p[x] = p[p[x]];
        x = p[x];
    }
    x
}

/// Joins the sets of `a` and `b`.
fn union(p: &mut [usize], a: usize, b: usize) {
    let (ra, rb) = (find(p, a), find(p, b));
    if ra != rb {
        p[ra.max(rb)] = ra.min(rb);
    }
}
