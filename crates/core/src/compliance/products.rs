//! The Gram method's block products for the hierarchical compression.

use super::*;

/// [`crate::compliance::hmatrix::BlockProducts`] through the Gram method's `W`
/// ([`crate::fem::gram::GramPlan::apply`]).
pub(crate) struct GramProducts<'a> {
    pub(crate) gp: &'a crate::fem::gram::GramPlan,
    pub(crate) w: &'a [f64],
    /// Gram position of each row index (`usize::MAX`: clamped, no row of `L`).
    pub(crate) pos_of_row: Vec<usize>,
    /// Gram position of each column index.
    pub(crate) pos_of_col: Vec<usize>,
}

impl GramProducts<'_> {
    /// Gram positions of `idx` through `map`, ascending, each with its place in `idx`.
    fn sorted(map: &[usize], idx: &[u32]) -> Result<Vec<(usize, usize)>, HError> {
        let mut p = idx
            .iter()
            .enumerate()
            .map(|(t, &i)| match map.get(i as usize) {
                Some(&g) if g != usize::MAX => Ok((g, t)),
                _ => Err(HError::Node {
                    node: i,
                    nodes: map.len(),
                }),
            })
            .collect::<Result<Vec<_>, _>>()?;
        p.sort_unstable();
        Ok(p)
    }

    /// `x`'s rows (3 per node) in the order of `at`.
    fn permuted(x: faer::MatRef<'_, f64>, at: &[(usize, usize)]) -> Mat<f64> {
        let mut xs = Mat::<f64>::zeros(3 * at.len(), x.ncols());
        for j in 0..x.ncols() {
            for (t, &(_, from)) in at.iter().enumerate() {
                for a in 0..3 {
                    xs[(3 * t + a, j)] = x[(3 * from + a, j)];
                }
            }
        }
        xs
    }

    /// `(K⁻¹)[O, I₁]·x₁, …` side by side, `O` given by `o` (sorted), the pieces sorted too,
    /// written into `out` in the callers' row order.
    fn run(
        &self,
        o: &[(usize, usize)],
        pieces: &[(Vec<usize>, Mat<f64>)],
        mut out: faer::MatMut<'_, f64>,
    ) -> Result<(), HError> {
        let k: usize = pieces.iter().map(|p| p.1.ncols()).sum();
        if out.nrows() != 3 * o.len() || out.ncols() != k {
            return Err(HError::BlockShape {
                want: (3 * o.len(), k),
                got: (out.nrows(), out.ncols()),
            });
        }
        let op: Vec<usize> = o.iter().map(|p| p.0).collect();
        let refs: Vec<(&[usize], faer::MatRef<'_, f64>)> = pieces
            .iter()
            .map(|(p, x)| (p.as_slice(), x.as_ref()))
            .collect();
        let mut os = Mat::<f64>::zeros(3 * o.len(), k);
        thread_local! {
            static SCRATCH: std::cell::RefCell<crate::fem::gram::ApplyScratch> =
                std::cell::RefCell::new(crate::fem::gram::ApplyScratch::default());
        }
        SCRATCH.with_borrow_mut(|sc| self.gp.apply_pieces(self.w, &op, &refs, os.as_mut(), sc));
        for j in 0..k {
            for (t, &(_, back)) in o.iter().enumerate() {
                for a in 0..3 {
                    out[(3 * back + a, j)] = os[(3 * t + a, j)];
                }
            }
        }
        Ok(())
    }
}

impl crate::compliance::hmatrix::BlockProducts for GramProducts<'_> {
    fn products(
        &self,
        rows: &[u32],
        cols: &[u32],
        transpose: bool,
        x: faer::MatRef<'_, f64>,
        out: faer::MatMut<'_, f64>,
    ) -> Result<(), HError> {
        let r = Self::sorted(&self.pos_of_row, rows)?;
        let c = Self::sorted(&self.pos_of_col, cols)?;
        let (o, i) = if transpose { (c, r) } else { (r, c) };
        if x.nrows() != 3 * i.len() {
            return Err(HError::BlockShape {
                want: (3 * i.len(), x.ncols()),
                got: (x.nrows(), x.ncols()),
            });
        }
        let xs = Self::permuted(x, &i);
        self.run(&o, &[(i.iter().map(|p| p.0).collect(), xs)], out)
    }

    fn products_t_pieces(
        &self,
        pieces: &[(&[u32], faer::MatRef<'_, f64>)],
        cols: &[u32],
        out: faer::MatMut<'_, f64>,
    ) -> Result<(), HError> {
        let o = Self::sorted(&self.pos_of_col, cols)?;
        let mut sorted = Vec::with_capacity(pieces.len());
        for (rows, x) in pieces {
            let i = Self::sorted(&self.pos_of_row, rows)?;
            if x.nrows() != 3 * i.len() {
                return Err(HError::BlockShape {
                    want: (3 * i.len(), x.ncols()),
                    got: (x.nrows(), x.ncols()),
                });
            }
            let xs = Self::permuted(*x, &i);
            sorted.push((i.iter().map(|p| p.0).collect(), xs));
        }
        self.run(&o, &sorted, out)
    }
}
