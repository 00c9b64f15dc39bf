//! Where a separating cut meets the surface: the line a closed slit shows.

use std::collections::HashMap;

use glam::DVec3;

/// The edges of a separated surface where a cut's faces meet the rest of it: each an edge
/// (mesh nodes, the smaller first) of one triangle that has a twin and one that has none. A
/// cut's face has a twin on the other lip (the same three rest positions: a copy rests where
/// its node does), the surface around the slit has none, so these edges trace the slit's
/// line on each lip, also while its lips are closed. Where the faces below have no twin (the
/// pocket a dropped sliver left, triangulated differently on each lip), an edge where the
/// surface folds into the slit and whose twin edge is on the surface too is the slit's.
/// Sorted; empty where nothing was split.
/// Triangles naming a node without a rest position are skipped.
pub fn slit_edges(triangles: &[[u32; 3]], rest: &[DVec3]) -> Vec<[u32; 2]> {
    let valid = |t: &[u32; 3]| t.iter().all(|&v| (v as usize) < rest.len());
    // Twins differ in a node at least (the same three nodes twice would be one face of two
    // tets, inside), so only a triangle with a node that shares its rest position with
    // another can have a twin: those nodes first (a sort of the surface's nodes), then only
    // their triangles hashed (a surface of thousands has tens near a cut).
    let mut on = vec![false; rest.len()];
    for &v in triangles.iter().filter(|t| valid(t)).flatten() {
        on[v as usize] = true;
    }
    let mut by_place: Vec<([u64; 3], u32)> = (0..rest.len() as u32)
        .filter(|&v| on[v as usize])
        .map(|v| (bits(rest[v as usize]), v))
        .collect();
    by_place.sort_unstable();
    let mut shared = vec![false; rest.len()];
    for w in by_place.windows(2) {
        if w[0].0 == w[1].0 {
            shared[w[0].1 as usize] = true;
            shared[w[1].1 as usize] = true;
        }
    }
    let key = |t: &[u32; 3]| -> [[u64; 3]; 3] {
        let mut k = t.map(|v| bits(rest[v as usize]));
        k.sort_unstable();
        k
    };
    let maybe = |t: &[u32; 3]| valid(t) && t.iter().any(|&v| shared[v as usize]);
    let mut count: HashMap<[[u64; 3]; 3], u32> = HashMap::new();
    for t in triangles.iter().filter(|t| maybe(t)) {
        *count.entry(key(t)).or_default() += 1;
    }
    let twinned = |t: &[u32; 3]| maybe(t) && count.get(&key(t)).is_some_and(|&n| n >= 2);
    let edges_of = |t: &[u32; 3]| {
        [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])].map(|(a, b)| [a.min(b), a.max(b)])
    };
    // Per edge of a twinned triangle: whether an untwinned one has it too.
    let mut sides: HashMap<[u32; 2], bool> = HashMap::new();
    for t in triangles.iter().filter(|t| twinned(t)) {
        for e in edges_of(t) {
            sides.entry(e).or_insert(false);
        }
    }
    for t in triangles.iter().filter(|t| valid(t) && !twinned(t)) {
        for e in edges_of(t) {
            if let Some(plain) = sides.get_mut(&e) {
                *plain = true;
            }
        }
    }
    let mut edges: Vec<[u32; 2]> = (sides.into_iter())
        .filter(|(_, plain)| *plain)
        .map(|(e, _)| e)
        .collect();
    edges.extend(folds_into_the_slit(triangles, rest, &shared));
    edges.sort_unstable();
    edges.dedup();
    edges
}

/// A rest position's bits, −0 read as +0: the key of where two nodes (a node and its copy)
/// rest at one place.
pub(crate) fn bits(p: DVec3) -> [u64; 3] {
    p.to_array().map(|c| (c + 0.0).to_bits())
}

/// The edges (between nodes that share their rest positions with others, `shared`) where the
/// surface folds by more than [`FOLD`] and whose twin (other nodes, the same rest positions)
/// is an edge of the surface too: where the surface turns into a slit whose faces have no
/// twin, as where a dropped sliver left a pocket between two lips triangulated differently.
fn folds_into_the_slit(triangles: &[[u32; 3]], rest: &[DVec3], shared: &[bool]) -> Vec<[u32; 2]> {
    let mut normals: HashMap<[u32; 2], Vec<DVec3>> = HashMap::new();
    for t in triangles {
        if !t.iter().all(|&v| (v as usize) < rest.len()) {
            continue;
        }
        let [a, b, c] = t.map(|v| rest[v as usize]);
        let n = (b - a).cross(c - a).normalize_or_zero();
        for (x, y) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            if shared[x as usize] && shared[y as usize] {
                normals.entry([x.min(y), x.max(y)]).or_default().push(n);
            }
        }
    }
    let place = |e: &[u32; 2]| {
        let mut k = e.map(|v| bits(rest[v as usize]));
        k.sort_unstable();
        k
    };
    let mut at_place: HashMap<[[u64; 3]; 2], u32> = HashMap::new();
    for e in normals.keys() {
        *at_place.entry(place(e)).or_default() += 1;
    }
    (normals.iter())
        .filter(|(e, ns)| {
            ns.len() == 2
                && ns[0] != DVec3::ZERO
                && ns[1] != DVec3::ZERO
                && ns[0].dot(ns[1]) < FOLD.cos()
                && at_place[&place(e)] >= 2
        })
        .map(|(e, _)| *e)
        .collect()
}

/// The least angle between the normals of an edge's two triangles at which the surface
/// turns into a slit there (rad): 45°, well above the bends between a blade's segments.
const FOLD: f64 = std::f64::consts::FRAC_PI_4;

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    /// Two unit squares side by side on z = 0 (nodes 0–5), and a slit along x = 1 from the
    /// top: the vertical faces of each lip (nodes 1, 4 and their copies 6, 7 one unit down)
    /// twin each other; the slit's edges are the lips' top edges on x = 1.
    #[cfg_attr(test, test)]
    pub(crate) fn the_slit_is_where_twinned_faces_meet_the_rest() {
        let rest = vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(2.0, 1.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0), // 6: copy of 1
            DVec3::new(1.0, 1.0, 0.0), // 7: copy of 4
            DVec3::new(1.0, 0.0, -1.0),
            DVec3::new(1.0, 1.0, -1.0),
        ];
        let tris = [
            [0, 1, 4],
            [0, 4, 3],
            [6, 2, 5],
            [6, 5, 7],
            // The lips' faces on x = 1 (the cut), one per lip, twins.
            [1, 8, 9],
            [1, 9, 4],
            [6, 9, 8],
            [6, 7, 9],
        ];
        assert_eq!(slit_edges(&tris, &rest), vec![[1, 4], [6, 7]]);
        // The second lip triangulated the other way (no face has a twin, as beside a dropped
        // sliver's pocket): the same line, where the surface folds into the slit.
        let mut pocket = tris;
        pocket[6] = [6, 7, 8];
        pocket[7] = [7, 9, 8];
        assert_eq!(slit_edges(&pocket, &rest), vec![[1, 4], [6, 7]]);

        // Nothing split: no twin, no slit; a node without a rest position is skipped.
        assert!(slit_edges(&tris[..4], &rest).is_empty());
        assert!(slit_edges(&[[0, 1, 99], [0, 1, 99]], &rest).is_empty());
    }
}
