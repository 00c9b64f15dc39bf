//! The plan of a hierarchical `L`: its blocks, panels and the products that fill them.

use super::*;

impl HPlan {
    /// The plan for rows at `row_points` and columns at `col_points` (row `i` is output entry
    /// `i`; `out_rows ≥ row_points.len()` entries are written by [`HMatrix::displace`], the
    /// rest zero).
    pub fn new(
        row_points: &[DVec3],
        col_points: &[DVec3],
        out_rows: usize,
        opts: &HOptions,
    ) -> Result<HPlan, HError> {
        opts.check()?;
        if row_points.is_empty() || col_points.is_empty() {
            return Err(HError::Empty {
                rows: row_points.len(),
                cols: col_points.len(),
            });
        }
        if out_rows < row_points.len() {
            return Err(HError::OutRows {
                out_rows,
                rows: row_points.len(),
            });
        }
        for (which, pts) in [("row", row_points), ("column", col_points)] {
            if let Some(index) = pts.iter().position(|p| !p.is_finite()) {
                return Err(HError::Point { which, index });
            }
        }
        let ct = ClusterTree::new(col_points, opts.leaf_size);
        // The same points on both sides: one tree, so that the partition is symmetric and one
        // triangle of it is solved and stored.
        let same = same_points(row_points, col_points);
        let rt = match &same {
            Some(row_of_col) => ClusterTree {
                nodes: ct.nodes.clone(),
                perm: ct.perm.iter().map(|&c| row_of_col[c as usize]).collect(),
            },
            None => ClusterTree::new(row_points, opts.leaf_size),
        };
        let mut raw = Vec::new();
        tree::partition(&rt, &ct, 0, 0, opts.eta, opts.panel_size, &mut raw);
        let mut pairs: Vec<(Range<u32>, Range<u32>, bool)> = raw
            .into_iter()
            .map(|(t, s, far)| {
                let (t, s) = (&rt.nodes[t as usize], &ct.nodes[s as usize]);
                (t.range.clone(), s.range.clone(), far)
            })
            .collect();
        pairs.sort_by_key(|(t, s, _)| (s.start, s.end, t.start));
        let mut mirror = vec![None; pairs.len()];
        if same.is_some() {
            let at: std::collections::HashMap<(u32, u32, u32, u32), u32> = pairs
                .iter()
                .enumerate()
                .map(|(i, (t, s, _))| ((t.start, t.end, s.start, s.end), i as u32))
                .collect();
            for (i, (t, s, _)) in pairs.iter().enumerate() {
                if t.start < s.start {
                    mirror[i] = at.get(&(s.start, s.end, t.start, t.end)).copied();
                }
            }
        }
        let mut has_mirror = vec![false; pairs.len()];
        for &s in mirror.iter().flatten() {
            has_mirror[s as usize] = true;
        }
        let mut panels = Vec::new();
        tree::panels(&ct, 0, opts.panel_size, &mut panels);
        let mut panel_pairs = Vec::with_capacity(panels.len());
        let mut next = 0;
        for p in &panels {
            let start = next;
            while next < pairs.len() && pairs[next].1.start < p.end {
                next += 1;
            }
            panel_pairs.push(start..next);
        }
        Ok(HPlan {
            opts: *opts,
            out_rows,
            row_perm: rt.perm,
            col_perm: ct.perm.clone(),
            col_leaves: tree::leaves(&ct),
            pairs,
            panels,
            panel_pairs,
            has_mirror,
            mirror,
            row_points: row_points.to_vec(),
            col_points: col_points.to_vec(),
        })
    }

    /// Whether rows and columns are the same points, so that only the blocks on and below
    /// the diagonal are solved and stored (the others are their transposes).
    pub fn symmetric(&self) -> bool {
        self.mirror.iter().any(Option::is_some)
    }

    /// Blocks of panel `p` that are stored (not mirrors), in order.
    pub(super) fn stored(&self, p: usize) -> impl Iterator<Item = usize> + '_ {
        self.panel_pairs[p]
            .clone()
            .filter(|&i| self.mirror[i].is_none())
    }

    /// The rows (indices) panel `p`'s stored blocks need: all of them unless the plan is
    /// symmetric, then those on and below the panel (about half on average).
    pub fn panel_rows(&self, p: usize) -> Vec<bool> {
        self.rows_of(p, false)
    }

    /// As [`HPlan::panel_rows`] for the blocks compressed from the panel's columns when the
    /// far blocks that pay for it are sketched ([`HPlan::compress_panel_with`]).
    pub fn panel_rows_unsketched(&self, p: usize) -> Vec<bool> {
        self.rows_of(p, true)
    }

    /// Whether block `i` is compressed by sketching when products are at hand: a far block
    /// for which `(2k + p)` vectors through it cost less than its `3|cols|` columns.
    pub(super) fn sketched(&self, i: usize) -> bool {
        let (r, c, far) = &self.pairs[i];
        let (m, n) = (3 * r.len(), 3 * c.len());
        *far && m * n >= (m + n) * (2 * self.sketch_k() + compress::PROBES)
    }

    /// Stored blocks compressed by sketching when products are at hand (with the Gram
    /// method's `W`): the far blocks for which that costs less than their columns.
    pub fn sketched_blocks(&self) -> usize {
        (0..self.pairs.len())
            .filter(|&i| self.mirror[i].is_none() && self.sketched(i))
            .count()
    }

    /// The first number of test vectors of a sketch: 1.5× the mean rank at a fifth of the
    /// tolerance (the probes' margin asks for a better basis), and 4 more; a block that needs
    /// more is sketched again with twice as many.
    pub(super) fn sketch_k(&self) -> usize {
        (1.5 * mean_rank_estimate(self.opts.tolerance / 5.0)).ceil() as usize + 4
    }

    /// Panel `p`'s column leaves, as ranges of [`HPlan::panel_cols`], each with the rows (indices)
    /// its stored blocks need (without the sketched ones when `skip_sketched`): the groups a
    /// panel's columns are solved in, each for its own rows.
    pub fn panel_leaves(&self, p: usize, skip_sketched: bool) -> Vec<(Range<usize>, Vec<bool>)> {
        let Some(pr) = self.panels.get(p) else {
            return Vec::new();
        };
        let start = self.col_leaves.partition_point(|l| l.start < pr.start);
        let mut out = Vec::new();
        for leaf in self.col_leaves[start..]
            .iter()
            .take_while(|l| l.start < pr.end)
        {
            let mut need = vec![false; self.row_perm.len()];
            for i in self.stored(p) {
                let (rows, cols, _) = &self.pairs[i];
                if cols.end <= leaf.start || cols.start >= leaf.end {
                    continue;
                }
                if skip_sketched && self.sketched(i) {
                    continue;
                }
                for q in rows.clone() {
                    need[self.row_perm[q as usize] as usize] = true;
                }
            }
            out.push((
                (leaf.start - pr.start) as usize..(leaf.end - pr.start) as usize,
                need,
            ));
        }
        out
    }

    pub(super) fn rows_of(&self, p: usize, skip_sketched: bool) -> Vec<bool> {
        let mut need = vec![false; self.row_perm.len()];
        for i in self.stored(p) {
            if skip_sketched && self.sketched(i) {
                continue;
            }
            for q in self.pairs[i].0.clone() {
                need[self.row_perm[q as usize] as usize] = true;
            }
        }
        need
    }

    /// The row points it was planned from.
    pub fn row_points(&self) -> &[DVec3] {
        &self.row_points
    }
    /// The column points it was planned from.
    pub fn col_points(&self) -> &[DVec3] {
        &self.col_points
    }
    /// Blocks of panel `p` (`None` out of range).
    pub fn panel_blocks(&self, p: usize) -> Option<usize> {
        self.panel_pairs.get(p).map(|r| r.len())
    }

    /// The options.
    pub fn options(&self) -> &HOptions {
        &self.opts
    }
    /// Row nodes.
    pub fn rows(&self) -> usize {
        self.row_perm.len()
    }
    /// Column nodes.
    pub fn cols(&self) -> usize {
        self.col_perm.len()
    }
    /// Output rows of [`HMatrix::displace`].
    pub fn out_rows(&self) -> usize {
        self.out_rows
    }
    /// Number of panels.
    pub fn panels(&self) -> usize {
        self.panels.len()
    }
    /// Blocks in the partition.
    pub fn blocks(&self) -> usize {
        self.pairs.len()
    }
    /// The column indices of panel `p`, in the order [`HPlan::compress_panel`] wants them.
    pub fn panel_cols(&self, p: usize) -> &[u32] {
        let r = &self.panels[p];
        &self.col_perm[r.start as usize..r.end as usize]
    }
    /// Values of the dense `L` over the same rows and columns (`3·rows × 3·cols`).
    pub fn dense_values(&self) -> usize {
        9 * self.row_perm.len() * self.col_perm.len()
    }

    /// The blocks' shapes in nodes, in order: (rows, columns, far).
    pub fn block_shapes(&self) -> impl Iterator<Item = (usize, usize, bool)> + '_ {
        self.pairs
            .iter()
            .map(|(r, c, far)| (r.len(), c.len(), *far))
    }

    /// Values an [`HMatrix`] on this plan would keep in its file and on the GPU (one triangle
    /// of a symmetric plan: the mirrors are read as transposes) if each far block had rank
    /// `rank` (a mean, see [`mean_rank_estimate`]) or stayed dense where that is smaller:
    /// the estimate behind `touchfem info --tolerance`.
    pub fn estimate_values(&self, rank: f64) -> usize {
        self.block_shapes()
            .zip(&self.mirror)
            .filter(|(_, m)| m.is_none())
            .map(|((r, c, far), _)| {
                let (m, n) = (3 * r, 3 * c);
                let dense = m * n;
                if far {
                    dense.min((rank * (m + n) as f64).ceil() as usize)
                } else {
                    dense
                }
            })
            .sum()
    }

    /// Compresses panel `p` from its columns of `L`: `data` is `3·rows × 3·|panel_cols(p)|`,
    /// column-major, entry `(3r + a, 3j + b)` coupling row `r` (an index, not a position) axis
    /// `a` to column `panel_cols(p)[j]` axis `b`. The blocks are compressed on up to `threads`
    /// threads; the result does not depend on how many.
    pub fn compress_panel(&self, p: usize, data: &[f64], threads: usize) -> Result<Panel, HError> {
        self.compress_panel_with(p, data, None, threads)
    }

    /// As [`HPlan::compress_panel`], the far blocks that pay for it compressed from
    /// `products` by sketching (`data` then needs only [`HPlan::panel_rows_unsketched`]; the
    /// other rows are not read). A sketched block's error is estimated, not measured (the
    /// module's guarantee).
    pub fn compress_panel_with(
        &self,
        p: usize,
        data: &[f64],
        products: Option<&dyn BlockProducts>,
        threads: usize,
    ) -> Result<Panel, HError> {
        let Some(pr) = self.panels.get(p) else {
            return Err(HError::Panel(p, self.panels.len()));
        };
        let ld = 3 * self.rows();
        let width = 3 * pr.len();
        if data.len() != ld * width {
            return Err(HError::BlockShape {
                want: (ld, width),
                got: (ld, data.len() / ld.max(1)),
            });
        }
        if data.iter().any(|v| !v.is_finite()) {
            return Err(HError::NonFinite);
        }
        let stored: Vec<usize> = self.stored(p).collect();
        let tol = self.opts.tolerance;
        let seed_of = |i: usize| {
            let (rows, cols, _) = &self.pairs[i];
            (rows.start as u64) << 32 ^ (cols.start as u64) ^ (rows.end as u64) << 48
        };
        fn idx<'x>(r: &Range<u32>, perm: &'x [u32]) -> &'x [u32] {
            &perm[r.start as usize..r.end as usize]
        }
        // A block from the panel's columns.
        let from_columns = |i: usize| {
            let (rows, cols, far) = &self.pairs[i];
            let ri = idx(rows, &self.row_perm);
            let (m, n) = (3 * ri.len(), 3 * cols.len());
            let c0 = 3 * (cols.start - pr.start) as usize;
            let mut b = Vec::with_capacity(m * n);
            for j in 0..n {
                let col = &data[(c0 + j) * ld..][..ld];
                for &r in ri {
                    b.extend_from_slice(&col[3 * r as usize..3 * r as usize + 3]);
                }
            }
            compress::compress(&b, m, n, *far, tol, seed_of(i))
        };
        // A block alone through products: sketched from `k` vectors, else formed.
        let alone = |src: &dyn BlockProducts, i: usize, k: usize| {
            let (rows, cols, far) = &self.pairs[i];
            let (ri, ci) = (idx(rows, &self.row_perm), idx(cols, &self.col_perm));
            let (m, n) = (3 * ri.len(), 3 * ci.len());
            let mut through = |t: bool, x: faer::MatRef<'_, f64>, out: faer::MatMut<'_, f64>| {
                src.products(ri, ci, t, x, out)
            };
            if let Some(c) = compress::sketch(m, n, tol, seed_of(i) ^ 0x5EED, k, &mut through)? {
                return Ok(c);
            }
            // Not worth factors by sketching: the block itself, from its products.
            let mut b = faer::Mat::<f64>::zeros(m, n);
            src.products(
                ri,
                ci,
                false,
                faer::Mat::<f64>::identity(n, n).as_ref(),
                b.as_mut(),
            )?;
            let b: Vec<f64> = b.col_iter().flat_map(|c| c.iter().copied()).collect();
            if b.iter().any(|v| !v.is_finite()) {
                return Err(HError::NonFinite);
            }
            compress::compress(&b, m, n, *far, tol, seed_of(i))
        };
        // The sketched blocks of one column cluster together: one shared Ω for their `BΩ`
        // through the union of their rows, then their `BᵀQ` side by side.
        let k0 = self.sketch_k();
        let cluster = |src: &dyn BlockProducts,
                       blocks: &[usize]|
         -> Vec<(usize, Result<compress::Compressed, HError>)> {
            let cols = &self.pairs[blocks[0]].1;
            let ci = idx(cols, &self.col_perm);
            let n = 3 * ci.len();
            let go = || -> Result<Vec<(usize, compress::Compressed)>, HError> {
                let all_rows: Vec<u32> = blocks
                    .iter()
                    .flat_map(|&i| idx(&self.pairs[i].0, &self.row_perm).iter().copied())
                    .collect();
                let mut rng =
                    compress::SplitMix((cols.start as u64) << 32 ^ cols.end as u64 ^ 0xC1u64 << 56);
                let omega = compress::test_vectors(n, k0 + compress::PROBES, &mut rng);
                let mut y = faer::Mat::<f64>::zeros(3 * all_rows.len(), k0 + compress::PROBES);
                src.products(&all_rows, ci, false, omega.as_ref(), y.as_mut())?;
                let mut at = 0;
                let mut qs = Vec::with_capacity(blocks.len());
                for &i in blocks {
                    let m = 3 * self.pairs[i].0.len();
                    qs.push(compress::basis(y.as_ref().subrows(at, m), k0)?);
                    at += m;
                }
                let pieces: Vec<(&[u32], faer::MatRef<'_, f64>)> = blocks
                    .iter()
                    .zip(&qs)
                    .map(|(&i, (q, _))| (idx(&self.pairs[i].0, &self.row_perm), q.as_ref()))
                    .collect();
                let mut c = faer::Mat::<f64>::zeros(n, k0 * blocks.len());
                src.products_t_pieces(&pieces, ci, c.as_mut())?;
                let mut out = Vec::with_capacity(blocks.len());
                for (t, (&i, (q, est))) in blocks.iter().zip(&qs).enumerate() {
                    let m = 3 * self.pairs[i].0.len();
                    let ct = c.as_ref().subcols(t * k0, k0);
                    let got = match compress::finish(m, n, tol, q.as_ref(), *est, ct)? {
                        compress::Sketch::Done(c) => c,
                        // Short: alone, with twice the vectors; not worth it: formed.
                        compress::Sketch::Short => alone(src, i, 2 * k0)?,
                        compress::Sketch::NotWorth => alone(src, i, usize::MAX / 4)?,
                    };
                    out.push((i, got));
                }
                Ok(out)
            };
            match go() {
                Ok(v) => v.into_iter().map(|(i, c)| (i, Ok(c))).collect(),
                Err(e) => vec![(blocks[0], Err(e))],
            }
        };
        // Jobs: each sketched column cluster (its blocks are consecutive), each other block.
        let sk = |i: usize| {
            let (r, c, _) = &self.pairs[i];
            products.is_some()
                && self.sketched(i)
                && compress::sketch_pays(3 * r.len(), 3 * c.len(), k0)
        };
        let mut jobs: Vec<Vec<usize>> = Vec::new();
        for &i in &stored {
            match jobs.last_mut() {
                Some(last) if sk(i) && sk(last[0]) && self.pairs[last[0]].1 == self.pairs[i].1 => {
                    last.push(i)
                }
                _ => jobs.push(vec![i]),
            }
        }
        // Largest first, so that the threads finish together.
        let cost = |job: &Vec<usize>| -> usize {
            let (r, c, _) = &self.pairs[job[0]];
            if sk(job[0]) {
                c.len() + job.iter().map(|&i| self.pairs[i].0.len()).sum::<usize>()
            } else {
                r.len() * c.len() / 64
            }
        };
        jobs.sort_by_key(|j| std::cmp::Reverse(cost(j)));
        let done = par_map(jobs.len(), threads, |j| {
            let job = &jobs[j];
            match products {
                Some(src) if sk(job[0]) => cluster(src, job),
                _ => job.iter().map(|&i| (i, from_columns(i))).collect(),
            }
        });
        let mut slot: std::collections::HashMap<usize, Result<compress::Compressed, HError>> =
            done.into_iter().flatten().collect();
        let mut out = Vec::with_capacity(stored.len());
        for &i in &stored {
            out.push(slot.remove(&i).unwrap_or(Err(HError::NonFinite)));
        }
        // A stored block whose transpose is a mirror counts twice in the norms (its mirror has
        // the same norm and the same error).
        let twice: Vec<f64> = self
            .stored(p)
            .map(|i| if self.has_mirror[i] { 2.0 } else { 1.0 })
            .collect();
        let mut panel = Panel {
            index: p,
            ranks: Vec::with_capacity(stored.len()),
            data: Vec::new(),
            norm_sq: 0.0,
            discarded_sq: 0.0,
        };
        for (c, w) in out.into_iter().zip(twice) {
            let c = c?;
            panel.ranks.push(c.rank);
            panel.data.extend_from_slice(&c.data);
            panel.norm_sq += w * c.norm_sq;
            panel.discarded_sq += w * c.discarded_sq;
        }
        Ok(panel)
    }

    /// Values block `i` (rank `rank`) holds.
    pub(super) fn block_values(&self, i: usize, rank: Option<u32>) -> usize {
        let (r, c, _) = &self.pairs[i];
        let (m, n) = (3 * r.len(), 3 * c.len());
        match rank {
            None => m * n,
            Some(k) => k as usize * (m + n),
        }
    }
}
