//! The blade: the quad its path sweeps ([`BladeQuad`]), and the tets it sweeps
//! ([`blade_tets`], for the removal).

use glam::DVec3;

use crate::contact::Surface;
use crate::mesh::Mesh;
use crate::Error;

/// The surface a blade sweeps: its top edge drawn from `from` along `along` for `length`, the
/// blade hanging `depth` down `down` (the inward normal where it entered, made perpendicular
/// to its path). A point `q` has in-plane coordinates `u = (q − from)·along`,
/// `v = (q − from)·down` and signed distance `s = (q − from)·normal` from the quad's plane.
///
/// The quad a cut separates along is `0 ≤ u ≤ length`, `−depth ≤ v ≤ depth`: it reaches as far
/// above the blade's top as below it (the blade's spine: a top drawn as a chord under a
/// curved surface leaves no bridge of material above it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BladeQuad {
    /// The blade's top where its path starts (m).
    pub from: DVec3,
    /// Unit direction of its path.
    pub along: DVec3,
    /// Unit direction down the blade, perpendicular to `along`.
    pub down: DVec3,
    /// Unit normal of its plane, `along × down`.
    pub normal: DVec3,
    /// The path's length (m, > 0).
    pub length: f64,
    /// The blade's depth (m, > 0).
    pub depth: f64,
}

impl BladeQuad {
    /// The quad of a blade whose top goes from `p1` to `p2`, hanging `depth` (m) along
    /// `inward`. Errors on a non-finite input, a depth ≤ 0, a path of zero length, or an
    /// `inward` along the path.
    pub fn new(p1: DVec3, p2: DVec3, inward: DVec3, depth: f64) -> Result<BladeQuad, Error> {
        if !(p1.is_finite() && p2.is_finite() && inward.is_finite() && depth.is_finite()) {
            return Err(Error::Input("the blade is not finite".into()));
        }
        if depth <= 0.0 {
            return Err(Error::Input(format!(
                "the blade's depth {depth} m is not > 0"
            )));
        }
        let length = p1.distance(p2);
        let along = (p2 - p1) / length;
        if !(length > 0.0 && length.is_finite() && along.is_finite()) {
            return Err(Error::Input("the blade's path has zero length".into()));
        }
        let inward = inward.normalize_or_zero();
        let down = (inward - along * along.dot(inward)).normalize_or_zero();
        if inward == DVec3::ZERO || down == DVec3::ZERO || along.dot(inward).abs() > 1.0 - 1e-9 {
            return Err(Error::Input(
                "the blade hangs along its own path (no plane to cut)".into(),
            ));
        }
        Ok(BladeQuad {
            from: p1,
            along,
            down,
            normal: along.cross(down),
            length,
            depth,
        })
    }

    /// The quad of a blade drawn on `surface` from the surface point nearest `a` to the one
    /// nearest `b` (m), hanging `depth` (m) inward: along the mean inward normal of the
    /// surface's triangles at the first point (so a blade that enters along an edge hangs
    /// into the body, not along the edge's other face), less its part along the path; where
    /// that vanishes, the inward normal of the triangle there most across the path. Errors as
    /// [`BladeQuad::new`] does (the two points may meet on the surface).
    pub fn on_surface(
        surface: &Surface,
        a: DVec3,
        b: DVec3,
        depth: f64,
    ) -> Result<BladeQuad, Error> {
        if !(a.is_finite() && b.is_finite()) || surface.tris.is_empty() {
            return Err(Error::Input("the blade is not finite".into()));
        }
        let (t1, p1) = surface.closest_global(a);
        let (_, p2) = surface.closest_global(b);
        let along = (p2 - p1).normalize_or_zero();
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for &p in &surface.nodes {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let tol = 1e-9 * (hi - lo).length();
        let mut sum = DVec3::ZERO;
        let mut across = (-surface.normals[t1 as usize], f64::INFINITY);
        for t in 0..surface.tris.len() as u32 {
            let (q, _) = surface.closest_on_tri(t, p1);
            if q.distance(p1) <= tol {
                let n = -surface.normals[t as usize];
                sum += n;
                let c = n.dot(along).abs();
                if c < across.1 {
                    across = (n, c);
                }
            }
        }
        let mean = sum - along * along.dot(sum);
        let inward = if mean.length() > 1e-6 * sum.length().max(f64::MIN_POSITIVE) {
            mean
        } else {
            across.0
        };
        BladeQuad::new(p1, p2, inward, depth)
    }

    /// `(u, v, s)` of `q`: along the path, down the blade, and the signed distance from the
    /// plane (m).
    pub fn coords(&self, q: DVec3) -> (f64, f64, f64) {
        let r = q - self.from;
        (r.dot(self.along), r.dot(self.down), r.dot(self.normal))
    }

    /// Whether in-plane coordinates `(u, v)` lie in the quad the cut separates along, to `tol`
    /// (m).
    pub fn contains(&self, u: f64, v: f64, tol: f64) -> bool {
        (-tol..=self.length + tol).contains(&u)
            && (-self.depth - tol..=self.depth + tol).contains(&v)
    }

    /// The quad's corners (its spine above the top included).
    pub fn corners(&self) -> [DVec3; 4] {
        let (l, d) = (self.along * self.length, self.down * self.depth);
        [
            self.from - d,
            self.from + l - d,
            self.from + l + d,
            self.from + d,
        ]
    }
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
