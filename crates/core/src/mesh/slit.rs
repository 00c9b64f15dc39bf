//! Where a separating cut meets the surface: the line a closed slit shows.

use std::collections::HashMap;

use glam::DVec3;

/// The edges of a separated surface where a cut's faces meet the rest of it: each an edge
/// (mesh nodes, the smaller first) of one triangle that has a twin and one that has none. A
/// cut's face has a twin on the other lip (the same three rest positions: a copy rests where
/// its node does), the surface around the slit has none, so these edges trace the slit's
/// line on each lip, also while its lips are closed. Sorted; empty where nothing was split.
/// Triangles naming a node without a rest position are skipped.
pub fn slit_edges(triangles: &[[u32; 3]], rest: &[DVec3]) -> Vec<[u32; 2]> {
    let key = |t: &[u32; 3]| -> Option<[[u64; 3]; 3]> {
        let mut k = [[0u64; 3]; 3];
        for (slot, &v) in k.iter_mut().zip(t) {
            let p = rest.get(v as usize)?;
            *slot = [p.x, p.y, p.z].map(|c| (c + 0.0).to_bits());
        }
        k.sort_unstable();
        Some(k)
    };
    let keys: Vec<Option<[[u64; 3]; 3]>> = triangles.iter().map(key).collect();
    let mut count: HashMap<[[u64; 3]; 3], u32> = HashMap::new();
    for k in keys.iter().flatten() {
        *count.entry(*k).or_default() += 1;
    }
    // Per edge: whether a twinned triangle has it, whether an untwinned one does.
    let mut sides: HashMap<[u32; 2], (bool, bool)> = HashMap::new();
    for (t, k) in triangles.iter().zip(&keys) {
        let Some(k) = k else { continue };
        let twinned = count.get(k).is_some_and(|&n| n >= 2);
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            let s = sides.entry([a.min(b), a.max(b)]).or_default();
            if twinned {
                s.0 = true;
            } else {
                s.1 = true;
            }
        }
    }
    let mut edges: Vec<[u32; 2]> = (sides.into_iter())
        .filter(|(_, (twin, plain))| *twin && *plain)
        .map(|(e, _)| e)
        .collect();
    edges.sort_unstable();
    edges
}

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
        // Nothing split: no twin, no slit; a node without a rest position is skipped.
        assert!(slit_edges(&tris[..4], &rest).is_empty());
        assert!(slit_edges(&[[0, 1, 99], [0, 1, 99]], &rest).is_empty());
    }
}
