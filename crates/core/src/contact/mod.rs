//! The god-object (Zilles & Salisbury): a proxy that stays on the object's rest surface while the
//! finger may sink into it.
//!
//! The proxy is a point of one surface triangle. Each haptic tick it moves to the point of the
//! surface nearest the finger that it can reach by sliding over the surface from where it was
//! (a descent across adjacent triangles), so it never jumps through a thin part to a nearer,
//! unconnected face. Where it stops, its active constraints are the faces through its feature:
//! one plane on a face, two on an edge (a valley), three or more at a vertex (a concave corner).
//! The finger is released when it is outside those constraints, tested with the feature's
//! angle-weighted pseudo-normal. All queries run on precomputed arrays and allocate nothing.

use glam::DVec3;

use crate::mesh::Mesh;

pub mod finger;
pub mod force;
mod friction;
mod sphere;
mod tool;
pub use friction::StickSlip;
pub use sphere::{Budget, Patch, PatchNode, PatchReport, Sphere, MAX_PATCH};
pub use tool::{check_length, show_length, ContactError, Friction, Tool, MIN_LENGTH_FRACTION};

/// Where on its triangle the proxy is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Feature {
    /// Inside the triangle: one active constraint plane.
    Face,
    /// On edge k = (v_k, v_{k+1}) of the triangle: two active planes.
    Edge(u8),
    /// At vertex k of the triangle: all faces around it are active.
    Vertex(u8),
}

impl Feature {
    /// Number of distinct active constraint planes through the feature (coplanar faces count
    /// once): 1 on a face or a flat edge, 2 in a valley, 3 or more at a corner.
    pub fn active_planes(self, surf: &Surface, tri: u32) -> usize {
        let distinct = |faces: &mut dyn Iterator<Item = u32>| {
            let mut seen: [glam::DVec3; 16] = [glam::DVec3::ZERO; 16];
            let mut n = 0usize;
            for f in faces {
                let nrm = surf.normals[f as usize];
                if !seen[..n.min(16)].iter().any(|s| s.dot(nrm) > 1.0 - 1e-9) {
                    if n < 16 {
                        seen[n] = nrm;
                    }
                    n += 1;
                }
            }
            n
        };
        match self {
            Feature::Face => 1,
            Feature::Edge(k) => {
                let o = surf.neighbors[tri as usize][k as usize];
                distinct(&mut [tri, o].into_iter())
            }
            Feature::Vertex(k) => {
                let v = surf.tris[tri as usize][k as usize];
                distinct(&mut surf.vertex_tris(v).iter().copied())
            }
        }
    }
}

/// The contact the god-object reports each tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactPoint {
    /// Index of the contact triangle in [`Surface::tris`].
    pub tri: u32,
    /// Its three mesh nodes.
    pub nodes: [u32; 3],
    /// Area coordinates of the proxy (eq. 11), summing to 1.
    pub alpha: [f64; 3],
    /// The god-object (proxy) position on the rest surface, metres.
    pub proxy: DVec3,
    /// The finger position, metres.
    pub finger: DVec3,
    /// The proxy's feature.
    pub feature: Feature,
}

impl Default for ContactPoint {
    fn default() -> Self {
        ContactPoint {
            tri: 0,
            nodes: [0; 3],
            alpha: [1.0, 0.0, 0.0],
            proxy: DVec3::ZERO,
            finger: DVec3::ZERO,
            feature: Feature::Face,
        }
    }
}

impl ContactPoint {
    /// The displacement boundary condition: finger minus god-object, metres.
    pub fn displacement(&self) -> DVec3 {
        self.finger - self.proxy
    }
}

/// The rest surface with the adjacency the god-object walks on and a grid for entry tests.
#[derive(Clone, Debug)]
pub struct Surface {
    /// Node positions (all mesh nodes, indexed by node), metres.
    pub nodes: Vec<DVec3>,
    /// Boundary triangles, outward.
    pub tris: Vec<[u32; 3]>,
    /// Unit outward normal of each triangle.
    pub normals: Vec<DVec3>,
    /// Triangle across edge k = (v_k, v_{k+1}) of each triangle.
    pub neighbors: Vec<[u32; 3]>,
    vt_start: Vec<u32>,
    vt: Vec<u32>,
    vertex_normal: Vec<DVec3>,
    grid: Grid,
    /// The surface's nodes bucketed on the same cells as `grid`.
    node_grid: Grid,
}

#[derive(Clone, Debug)]
struct Grid {
    lo: DVec3,
    inv_cell: f64,
    dims: [usize; 3],
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Grid {
    fn cell_range(&self, lo: DVec3, hi: DVec3) -> [std::ops::RangeInclusive<usize>; 3] {
        let c = |p: f64, o: f64, d: usize| {
            (((p - o) * self.inv_cell).floor().max(0.0) as usize).min(d - 1)
        };
        [
            c(lo.x, self.lo.x, self.dims[0])..=c(hi.x, self.lo.x, self.dims[0]),
            c(lo.y, self.lo.y, self.dims[1])..=c(hi.y, self.lo.y, self.dims[1]),
            c(lo.z, self.lo.z, self.dims[2])..=c(hi.z, self.lo.z, self.dims[2]),
        ]
    }
}

impl Surface {
    /// Builds the walking structure from a validated mesh.
    pub fn new(mesh: &Mesh) -> Surface {
        let nodes = mesh.nodes.clone();
        let tris = mesh.surface.clone();
        let normals: Vec<DVec3> = tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| nodes[i as usize]);
                (b - a).cross(c - a).normalize_or_zero()
            })
            .collect();
        let mut edge_owner = std::collections::HashMap::with_capacity(tris.len() * 3);
        for (ti, t) in tris.iter().enumerate() {
            for k in 0..3 {
                edge_owner.insert((t[k], t[(k + 1) % 3]), ti as u32);
            }
        }
        let neighbors = tris
            .iter()
            .map(|t| {
                [0, 1, 2].map(|k| {
                    *edge_owner
                        .get(&(t[(k + 1) % 3], t[k]))
                        .expect("validated meshes have a closed manifold boundary")
                })
            })
            .collect();
        let n = nodes.len();
        let (vt_start, vt) = crate::mesh::vertex_triangles(n, &tris);
        let mut vertex_normal = vec![DVec3::ZERO; n];
        for (ti, t) in tris.iter().enumerate() {
            for k in 0..3 {
                let v = t[k] as usize;
                let p = nodes[v];
                let e1 = (nodes[t[(k + 1) % 3] as usize] - p).normalize_or_zero();
                let e2 = (nodes[t[(k + 2) % 3] as usize] - p).normalize_or_zero();
                let angle = e1.dot(e2).clamp(-1.0, 1.0).acos();
                vertex_normal[v] += normals[ti] * angle;
            }
        }
        for nrm in &mut vertex_normal {
            *nrm = nrm.normalize_or_zero();
        }
        let grid = build_grid(&nodes, &tris);
        let node_grid = build_node_grid(&grid, &nodes, &tris);
        Surface {
            nodes,
            tris,
            normals,
            neighbors,
            vt_start,
            vt,
            vertex_normal,
            grid,
            node_grid,
        }
    }

    /// The outward angle-weighted normal of a surface node (zero for an interior node).
    #[inline]
    pub fn vertex_normal(&self, v: u32) -> DVec3 {
        self.vertex_normal
            .get(v as usize)
            .copied()
            .unwrap_or(DVec3::ZERO)
    }

    /// Calls `f` with every surface node within `r` of `c` (rest positions). Allocates
    /// nothing.
    pub fn for_nodes_near(&self, c: DVec3, r: f64, mut f: impl FnMut(u32)) {
        if !c.is_finite() || !r.is_finite() || r < 0.0 {
            return;
        }
        let g = &self.node_grid;
        let cells = g.cell_range(c - DVec3::splat(r), c + DVec3::splat(r));
        let r2 = r * r;
        // Cells wholly outside the ball are skipped (a large sphere's box holds far more of
        // the surface than the ball does); a border cell also holds the nodes past it.
        let size = 1.0 / g.inv_cell;
        let gap = |x: f64, lo: f64, i: usize, d: usize| {
            let a = lo + i as f64 * size;
            let b = a + size;
            if x < a && i > 0 {
                a - x
            } else if x > b && i + 1 < d {
                x - b
            } else {
                0.0
            }
        };
        for k in cells[2].clone() {
            let dz = gap(c.z, g.lo.z, k, g.dims[2]);
            for j in cells[1].clone() {
                let dy = gap(c.y, g.lo.y, j, g.dims[1]);
                if dz * dz + dy * dy > r2 {
                    continue;
                }
                for i in cells[0].clone() {
                    let dx = gap(c.x, g.lo.x, i, g.dims[0]);
                    if dz * dz + dy * dy + dx * dx > r2 {
                        continue;
                    }
                    let cell = (k * g.dims[1] + j) * g.dims[0] + i;
                    let s = g.start[cell] as usize;
                    let e = g.start[cell + 1] as usize;
                    for &v in &g.items[s..e] {
                        if self.nodes[v as usize].distance_squared(c) <= r2 {
                            f(v);
                        }
                    }
                }
            }
        }
    }

    /// Triangles around a node.
    #[inline]
    pub(crate) fn vertex_tris(&self, v: u32) -> &[u32] {
        &self.vt[self.vt_start[v as usize] as usize..self.vt_start[v as usize + 1] as usize]
    }

    #[inline]
    fn corners(&self, t: u32) -> [DVec3; 3] {
        self.tris[t as usize].map(|i| self.nodes[i as usize])
    }

    /// Closest point of triangle `t` to `x`, with its barycentric coordinates.
    #[inline]
    pub(crate) fn closest_on_tri(&self, t: u32, x: DVec3) -> (DVec3, [f64; 3]) {
        let [a, b, c] = self.corners(t);
        closest_point_triangle(x, a, b, c)
    }

    /// The point of the whole surface nearest `x` (brute force; for placing a finger, not for
    /// the haptic loop). Returns (triangle, point).
    pub fn closest_global(&self, x: DVec3) -> (u32, DVec3) {
        let mut best = (0u32, self.nodes[self.tris[0][0] as usize], f64::INFINITY);
        for t in 0..self.tris.len() as u32 {
            let (q, _) = self.closest_on_tri(t, x);
            let d = q.distance_squared(x);
            if d < best.2 {
                best = (t, q, d);
            }
        }
        (best.0, best.1)
    }

    /// True when `x` is strictly inside the closed surface: the generalised winding number
    /// (the sum of the triangles' solid angles over 4π, Jacobson et al. 2013) exceeds ½. Robust
    /// on edges and vertices; brute force over the triangles (tens of µs on the mouse), for a
    /// finger that appears, not for every tick. Allocates nothing.
    pub fn contains(&self, x: DVec3) -> bool {
        if !x.is_finite() {
            return false;
        }
        let mut omega = 0.0;
        for t in 0..self.tris.len() as u32 {
            let [a, b, c] = self.corners(t).map(|p| p - x);
            let (la, lb, lc) = (a.length(), b.length(), c.length());
            let num = a.dot(b.cross(c));
            let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
            omega += 2.0 * num.atan2(den);
        }
        omega / (4.0 * std::f64::consts::PI) > 0.5
    }

    /// The outward pseudo-normal of a feature of triangle `t`.
    pub(crate) fn pseudo_normal(&self, t: u32, f: Feature) -> DVec3 {
        match f {
            Feature::Face => self.normals[t as usize],
            Feature::Edge(k) => {
                let o = self.neighbors[t as usize][k as usize];
                (self.normals[t as usize] + self.normals[o as usize]).normalize_or_zero()
            }
            Feature::Vertex(k) => self.vertex_normal[self.tris[t as usize][k as usize] as usize],
        }
    }

    /// The first triangle the segment `p0 → p1` enters from outside, with the entry point.
    pub fn first_entry(&self, p0: DVec3, p1: DVec3) -> Option<(u32, DVec3)> {
        let d = p1 - p0;
        let eps = 1e-9 * self.grid_scale();
        let r = self.grid.cell_range(
            p0.min(p1) - DVec3::splat(eps),
            p0.max(p1) + DVec3::splat(eps),
        );
        let mut best: Option<(u32, f64)> = None;
        for k in r[2].clone() {
            for j in r[1].clone() {
                for i in r[0].clone() {
                    let cell = (k * self.grid.dims[1] + j) * self.grid.dims[0] + i;
                    let s = self.grid.start[cell] as usize;
                    let e = self.grid.start[cell + 1] as usize;
                    for &t in &self.grid.items[s..e] {
                        if d.dot(self.normals[t as usize]) >= 0.0 {
                            continue;
                        }
                        let [a, b, c] = self.corners(t);
                        if let Some(s) = segment_triangle(p0, d, a, b, c) {
                            if best.is_none_or(|(_, bs)| s < bs) {
                                best = Some((t, s));
                            }
                        }
                    }
                }
            }
        }
        best.map(|(t, s)| (t, p0 + d * s))
    }

    fn grid_scale(&self) -> f64 {
        1.0 / self.grid.inv_cell
    }

    /// Slides from a point on triangle `t` to the nearest point to `x` reachable by descent over
    /// adjacent triangles. Returns (triangle, barycentrics, point, feature). Allocates nothing.
    pub(crate) fn walk(&self, mut t: u32, x: DVec3) -> (u32, [f64; 3], DVec3, Feature) {
        let (mut q, mut bc) = self.closest_on_tri(t, x);
        let mut d = q.distance_squared(x);
        // Each step strictly decreases the distance, so this terminates; the cap is a guard.
        for _ in 0..4 * self.tris.len().max(64) {
            let f = feature_of(&bc);
            let better = |cand: u32, d: f64| {
                let (q2, bc2) = self.closest_on_tri(cand, x);
                let d2 = q2.distance_squared(x);
                (d2 < d * (1.0 - 1e-12)).then_some((cand, q2, bc2, d2))
            };
            let step = match f {
                Feature::Face => None,
                Feature::Edge(k) => better(self.neighbors[t as usize][k as usize], d),
                Feature::Vertex(k) => {
                    let v = self.tris[t as usize][k as usize];
                    let mut best = None;
                    let mut bd = d;
                    for &c in self.vertex_tris(v) {
                        if c != t {
                            if let Some(s) = better(c, bd) {
                                bd = s.3;
                                best = Some(s);
                            }
                        }
                    }
                    best
                }
            };
            match step {
                Some((t2, q2, bc2, d2)) => {
                    t = t2;
                    q = q2;
                    bc = bc2;
                    d = d2;
                }
                None => break,
            }
        }
        (t, bc, q, feature_of(&bc))
    }
}

fn build_grid(nodes: &[DVec3], tris: &[[u32; 3]]) -> Grid {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    let mut edge = 0.0;
    for t in tris {
        for k in 0..3 {
            let p = nodes[t[k] as usize];
            lo = lo.min(p);
            hi = hi.max(p);
            edge += p.distance(nodes[t[(k + 1) % 3] as usize]);
        }
    }
    let mean_edge = (edge / (3 * tris.len().max(1)) as f64).max(1e-12);
    let ext = (hi - lo).max(DVec3::splat(mean_edge));
    let mut cell = 2.0 * mean_edge;
    // Keep the grid to at most ~64³ cells.
    while (ext / cell).ceil().to_array().iter().product::<f64>() > 262_144.0 {
        cell *= 1.5;
    }
    let dims = (ext / cell).ceil().to_array().map(|v| (v as usize).max(1));
    let grid0 = Grid {
        lo,
        inv_cell: 1.0 / cell,
        dims,
        start: Vec::new(),
        items: Vec::new(),
    };
    let ncell = dims[0] * dims[1] * dims[2];
    let mut lists: Vec<Vec<u32>> = vec![Vec::new(); ncell];
    for (ti, t) in tris.iter().enumerate() {
        let p = t.map(|i| nodes[i as usize]);
        let r = grid0.cell_range(p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        for k in r[2].clone() {
            for j in r[1].clone() {
                for i in r[0].clone() {
                    lists[(k * dims[1] + j) * dims[0] + i].push(ti as u32);
                }
            }
        }
    }
    let mut start = Vec::with_capacity(ncell + 1);
    let mut items = Vec::new();
    for l in &lists {
        start.push(items.len() as u32);
        items.extend_from_slice(l);
    }
    start.push(items.len() as u32);
    Grid {
        start,
        items,
        ..grid0
    }
}

/// The surface's nodes on the cells of the triangle grid `g`, each node once.
fn build_node_grid(g: &Grid, nodes: &[DVec3], tris: &[[u32; 3]]) -> Grid {
    let mut on_surface = vec![false; nodes.len()];
    for t in tris {
        for &v in t {
            on_surface[v as usize] = true;
        }
    }
    let ncell = g.dims[0] * g.dims[1] * g.dims[2];
    let mut count = vec![0u32; ncell + 1];
    let cell_of = |p: DVec3| {
        let r = g.cell_range(p, p);
        (r[2].start() * g.dims[1] + r[1].start()) * g.dims[0] + r[0].start()
    };
    for (v, &s) in on_surface.iter().enumerate() {
        if s {
            count[cell_of(nodes[v]) + 1] += 1;
        }
    }
    for i in 0..ncell {
        count[i + 1] += count[i];
    }
    let mut fill = count.clone();
    let mut items = vec![0u32; count[ncell] as usize];
    for (v, &s) in on_surface.iter().enumerate() {
        if s {
            let c = cell_of(nodes[v]);
            items[fill[c] as usize] = v as u32;
            fill[c] += 1;
        }
    }
    Grid {
        lo: g.lo,
        inv_cell: g.inv_cell,
        dims: g.dims,
        start: count,
        items,
    }
}

/// The feature a barycentric triple lies on (exact zeros come from the region tests).
pub(crate) fn feature_of(bc: &[f64; 3]) -> Feature {
    let zeros = bc.iter().filter(|&&v| v == 0.0).count();
    match zeros {
        0 => Feature::Face,
        1 => {
            // Edge k = (v_k, v_{k+1}) has bc[k+2] == 0.
            let z = bc.iter().position(|&v| v == 0.0).unwrap_or(0);
            Feature::Edge(((z + 1) % 3) as u8)
        }
        _ => Feature::Vertex(bc.iter().position(|&v| v != 0.0).unwrap_or(0) as u8),
    }
}

/// Closest point of triangle abc to p, and its barycentric coordinates (Ericson, *Real-Time
/// Collision Detection*, 5.1.5). Coordinates on the boundary regions are exactly zero.
pub(crate) fn closest_point_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> (DVec3, [f64; 3]) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, [1.0, 0.0, 0.0]);
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, [0.0, 1.0, 0.0]);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (a + ab * v, [1.0 - v, v, 0.0]);
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, [0.0, 0.0, 1.0]);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (a + ac * w, [1.0 - w, 0.0, w]);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (b + (c - b) * w, [0.0, 1.0 - w, w]);
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    (a + ab * v + ac * w, [1.0 - v - w, v, w])
}

/// Segment p0 + s·d, s ∈ [0, 1], against triangle abc (Möller–Trumbore); returns s at the hit.
fn segment_triangle(p0: DVec3, d: DVec3, a: DVec3, b: DVec3, c: DVec3) -> Option<f64> {
    let e1 = b - a;
    let e2 = c - a;
    let h = d.cross(e2);
    let det = e1.dot(h);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s0 = p0 - a;
    let u = inv * s0.dot(h);
    const TOL: f64 = 1e-12;
    if !(-TOL..=1.0 + TOL).contains(&u) {
        return None;
    }
    let q = s0.cross(e1);
    let v = inv * d.dot(q);
    if v < -TOL || u + v > 1.0 + TOL {
        return None;
    }
    let s = inv * e2.dot(q);
    (-TOL..=1.0 + TOL).contains(&s).then_some(s.clamp(0.0, 1.0))
}

/// One finger's god-object.
#[derive(Clone, Copy, Debug)]
pub struct GodObject {
    state: State,
}

#[derive(Clone, Copy, Debug)]
enum State {
    Free { finger: DVec3 },
    Touching { tri: u32 },
}

impl GodObject {
    /// A god-object for a finger at `finger`, not touching anything (it must be outside).
    pub fn new(finger: DVec3) -> GodObject {
        GodObject {
            state: State::Free { finger },
        }
    }

    /// A god-object already in contact on triangle `tri` (e.g. placed by
    /// `Surface::closest_global`).
    pub fn touching(tri: u32) -> GodObject {
        GodObject {
            state: State::Touching { tri },
        }
    }

    /// True while the finger is in contact.
    pub fn in_contact(&self) -> bool {
        matches!(self.state, State::Touching { .. })
    }

    /// Moves the finger to `x`; returns the contact, or `None` when the finger is free.
    /// Allocates nothing.
    pub fn update(&mut self, surf: &Surface, x: DVec3) -> Option<ContactPoint> {
        let start = match self.state {
            State::Free { finger } => match surf.first_entry(finger, x) {
                Some((t, _)) => t,
                None => {
                    self.state = State::Free { finger: x };
                    return None;
                }
            },
            State::Touching { tri } => tri,
        };
        let (t, bc, q, f) = surf.walk(start, x);
        if (x - q).dot(surf.pseudo_normal(t, f)) > 0.0 {
            self.state = State::Free { finger: x };
            return None;
        }
        self.state = State::Touching { tri: t };
        Some(ContactPoint {
            tri: t,
            nodes: surf.tris[t as usize],
            alpha: bc,
            proxy: q,
            finger: x,
            feature: f,
        })
    }
}
