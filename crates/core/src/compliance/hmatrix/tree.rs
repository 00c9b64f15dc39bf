//! Cluster trees over node positions, the block partition between two of them, and the
//! panels (column clusters solved together).

use std::ops::Range;

use glam::DVec3;

/// One cluster: a range of its tree's permutation and the bounding box of its nodes.
#[derive(Clone, Debug)]
pub(super) struct Cluster {
    pub range: Range<u32>,
    pub lo: DVec3,
    pub hi: DVec3,
    pub children: Option<[u32; 2]>,
}

impl Cluster {
    fn diam(&self) -> f64 {
        (self.hi - self.lo).length()
    }
    fn dist(&self, o: &Cluster) -> f64 {
        let gap = (o.lo - self.hi).max(self.lo - o.hi).max(DVec3::ZERO);
        gap.length()
    }
}

/// A cluster tree: node 0 is the root; `perm[position]` is the point at that position.
#[derive(Clone, Debug)]
pub(super) struct ClusterTree {
    pub nodes: Vec<Cluster>,
    pub perm: Vec<u32>,
}

impl ClusterTree {
    pub fn new(points: &[DVec3], leaf: usize) -> ClusterTree {
        let mut t = ClusterTree {
            nodes: Vec::new(),
            perm: (0..points.len() as u32).collect(),
        };
        t.split(points, 0..points.len(), leaf);
        t
    }

    /// Adds the cluster of positions `r` (and its subtree); returns its index.
    fn split(&mut self, points: &[DVec3], r: Range<usize>, leaf: usize) -> u32 {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for &i in &self.perm[r.clone()] {
            lo = lo.min(points[i as usize]);
            hi = hi.max(points[i as usize]);
        }
        let me = self.nodes.len() as u32;
        self.nodes.push(Cluster {
            range: r.start as u32..r.end as u32,
            lo,
            hi,
            children: None,
        });
        if r.len() <= leaf {
            return me;
        }
        let ext = hi - lo;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        let mid = 0.5 * (lo[axis] + hi[axis]);
        // Partition in place: points below the midpoint first.
        let s = &mut self.perm[r.clone()];
        let mut k = 0;
        for i in 0..s.len() {
            if points[s[i] as usize][axis] < mid {
                s.swap(i, k);
                k += 1;
            }
        }
        if k == 0 || k == s.len() {
            // All points coincide along the longest axis, hence everywhere: a leaf.
            return me;
        }
        let a = self.split(points, r.start..r.start + k, leaf);
        let b = self.split(points, r.start + k..r.end, leaf);
        self.nodes[me as usize].children = Some([a, b]);
        me
    }
}

/// The block partition below the pair (t, s): (row cluster, column cluster, admissible). A far
/// pair with a cluster of more than `cap` nodes is split on that side, so that every block lies
/// within one panel (see [`super::HPlan`]).
pub(super) fn partition(
    rt: &ClusterTree,
    ct: &ClusterTree,
    t: u32,
    s: u32,
    eta: f64,
    cap: usize,
    out: &mut Vec<(u32, u32, bool)>,
) {
    let (tc, sc) = (&rt.nodes[t as usize], &ct.nodes[s as usize]);
    let dist = tc.dist(sc);
    let far = dist > 0.0 && tc.diam().min(sc.diam()) <= eta * dist;
    // A far pair is one block unless a side is wider than a panel (then that side is split:
    // both sides alike, so that the partition of a tree with itself stays symmetric); a near
    // pair is split until both sides are leaves.
    let (tk, sk) = if far {
        let big = |c: &Cluster| c.children.filter(|_| c.range.len() > cap);
        (big(tc), big(sc))
    } else {
        (tc.children, sc.children)
    };
    if tk.is_none() && sk.is_none() {
        out.push((t, s, far));
        return;
    }
    let ts = tk.map_or(vec![t], |k| k.to_vec());
    let ss = sk.map_or(vec![s], |k| k.to_vec());
    for &a in &ts {
        for &b in &ss {
            partition(rt, ct, a, b, eta, cap, out);
        }
    }
}

/// The panels: the largest clusters of at most `cap` nodes (a leaf may hold more only when
/// its points coincide), as position ranges in order.
pub(super) fn panels(ct: &ClusterTree, s: u32, cap: usize, out: &mut Vec<Range<u32>>) {
    let c = &ct.nodes[s as usize];
    match c.children {
        Some(k) if c.range.len() > cap => k.iter().for_each(|&b| panels(ct, b, cap, out)),
        _ => out.push(c.range.clone()),
    }
}

/// The leaves' position ranges, in order.
pub(super) fn leaves(ct: &ClusterTree) -> Vec<Range<u32>> {
    let mut l: Vec<Range<u32>> = ct
        .nodes
        .iter()
        .filter(|c| c.children.is_none())
        .map(|c| c.range.clone())
        .collect();
    l.sort_by_key(|r| r.start);
    l
}
