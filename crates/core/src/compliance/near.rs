//! The blocks of `L` the haptic path reads when `L` itself is not held on the host: for every
//! touchable column node, `L(node i, column j)` for the touchable nodes `j` that share a
//! surface triangle with it (and itself). One finger touches one triangle at a time, and its
//! force solve (eq. 7, 9–12, or the exact model) reads only those pairs.

use glam::DMat3;

/// `L(node of column i, column j)` for the near pairs `(i, j)`, in CSR form over `i`.
#[derive(Clone, Debug, Default)]
pub struct NearBlocks {
    /// Where column `i`'s neighbours start in `nbr` (`cols + 1` entries).
    start: Vec<u32>,
    /// Neighbour columns of each column, sorted, itself included.
    nbr: Vec<u32>,
    /// The block of each `(i, nbr)` entry, m/N.
    blocks: Vec<DMat3>,
}

impl NearBlocks {
    /// The near pairs of `cols` touchable columns: `(i, i)` for every column, and `(i, j)`
    /// for columns whose nodes share one of `triangles` (mesh node indices; `col_of_node` maps
    /// a node to its column or `u32::MAX`). Blocks start at zero.
    pub fn pairs(cols: usize, triangles: &[[u32; 3]], col_of_node: &[u32]) -> NearBlocks {
        let mut lists: Vec<Vec<u32>> = (0..cols as u32).map(|i| vec![i]).collect();
        let col = |n: u32| {
            col_of_node
                .get(n as usize)
                .copied()
                .filter(|&c| c != u32::MAX)
        };
        for t in triangles {
            for &a in t {
                let Some(ca) = col(a) else { continue };
                for &b in t {
                    if let Some(cb) = col(b) {
                        lists[ca as usize].push(cb);
                    }
                }
            }
        }
        let mut start = Vec::with_capacity(cols + 1);
        let mut nbr = Vec::new();
        start.push(0);
        for mut l in lists {
            l.sort_unstable();
            l.dedup();
            nbr.extend_from_slice(&l);
            start.push(nbr.len() as u32);
        }
        let blocks = vec![DMat3::ZERO; nbr.len()];
        NearBlocks { start, nbr, blocks }
    }

    /// Number of touchable columns.
    pub fn cols(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    /// The neighbour columns of column `i` (sorted, `i` included).
    pub fn neighbours(&self, i: usize) -> &[u32] {
        &self.nbr[self.start[i] as usize..self.start[i + 1] as usize]
    }

    fn index(&self, i: usize, j: usize) -> Option<usize> {
        let s = *self.start.get(i)? as usize;
        let e = *self.start.get(i + 1)? as usize;
        self.nbr[s..e]
            .binary_search(&(j as u32))
            .ok()
            .map(|k| s + k)
    }

    /// `L(node of column i, column j)` if `(i, j)` is a near pair.
    #[inline]
    pub fn get(&self, i: usize, j: usize) -> Option<DMat3> {
        self.index(i, j).map(|k| self.blocks[k])
    }

    /// Sets the block of the near pair `(i, j)`; `false` if it is not one.
    pub fn set(&mut self, i: usize, j: usize, block: DMat3) -> bool {
        match self.index(i, j) {
            Some(k) => {
                self.blocks[k] = block;
                true
            }
            None => false,
        }
    }

    /// Number of stored blocks.
    pub fn len(&self) -> usize {
        self.blocks.len()
    }

    /// Whether no block is stored.
    pub fn is_empty(&self) -> bool {
        self.blocks.is_empty()
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.start.len() * 4 + self.nbr.len() * 4 + self.blocks.len() * 72
    }

    /// `max |B_ij − B_jiᵀ|` over the stored pairs (the symmetry of `K⁻¹`, absolute).
    pub(crate) fn asymmetry(&self) -> f64 {
        let mut err = 0.0f64;
        for i in 0..self.cols() {
            for &j in self.neighbours(i) {
                let (Some(a), Some(b)) = (self.get(i, j as usize), self.get(j as usize, i)) else {
                    continue;
                };
                let d = (a - b.transpose()).abs().to_cols_array();
                err = d.iter().fold(err, |m, v| m.max(*v));
            }
        }
        err
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn pairs_are_the_triangles_edges_and_the_diagonal() {
        // Nodes 0..5; node 4 is clamped (no column); columns: node n -> n for n < 4, 5 -> 4.
        let col_of_node = [0, 1, 2, 3, u32::MAX, 4];
        let tris = [[0, 1, 2], [2, 1, 3], [3, 4, 5]];
        let mut nb = NearBlocks::pairs(5, &tris, &col_of_node);
        assert_eq!(nb.neighbours(0), &[0, 1, 2]);
        assert_eq!(nb.neighbours(1), &[0, 1, 2, 3]);
        assert_eq!(nb.neighbours(3), &[1, 2, 3, 4]);
        assert_eq!(nb.neighbours(4), &[3, 4]);
        assert_eq!(nb.len(), 3 + 4 + 4 + 4 + 2);
        assert!(nb.get(0, 3).is_none());
        assert!(nb.get(7, 0).is_none());
        assert!(!nb.set(0, 3, DMat3::IDENTITY));
        let m = DMat3::from_cols_array(&[1., 2., 3., 4., 5., 6., 7., 8., 9.]);
        assert!(nb.set(1, 3, m));
        assert!(nb.set(3, 1, m.transpose()));
        assert_eq!(nb.get(1, 3), Some(m));
        assert_eq!(nb.asymmetry(), 0.0);
        assert!(nb.set(3, 1, m));
        assert_eq!(nb.asymmetry(), 4.0);
    }
}
