//! The compliance block `(K⁻¹)[S, T]` as a Gram product of sparse forward solves: the
//! precompute's method when many nodes are touchable (a whole surface).
//!
//! With the supernodal Cholesky factor `P K Pᵀ = G Gᵀ`, `(K⁻¹)[S,T] = W_Sᵀ W_T` where
//! `W = G⁻¹ P E` holds one forward solve per displayed DOF (`T ⊆ S`); for a mixed system's
//! signed factor `G Σ Gᵀ` ([`Factor`]), `(K⁻¹)[S,T] = W_Sᵀ Σ W_T`, the sign applied as a tile
//! gathers its columns. A DOF's column of `W`
//! is non-zero only on its own supernode and that supernode's ancestors. Ordering the
//! displayed nodes by the post-order of their supernodes makes the columns that reach a
//! supernode `s` one contiguous range `D(s)`, so `W` is held as one dense block `W_s`
//! (`|D(s)| × |s|`) per supernode, computed bottom-up with dense triangular solves and
//! products. Then `(K⁻¹)[S,T] = Σ_s W_s[D(s)] W_s[D_T(s)]ᵀ`, tile by tile of columns.
//!
//! Against one forward and one back substitution over all DOFs per column (the column
//! method), this skips the back substitution and every supernode that a column never reaches;
//! what remains is dense level-3 work. [`GramPlan::forward_flops`] and
//! [`GramPlan::gram_flops`] estimate it so that the precompute can pick the cheaper method.

use faer::reborrow::{Reborrow, ReborrowMut};
use faer::{Accum, Mat, MatMut, MatRef, Par};

use crate::fem::{Dofs, Factor};

/// The structure of the Gram product for one factor and one selection.
pub struct GramPlan {
    /// First factor column of each supernode, and one past the last (`n_sn + 1` entries).
    begin: Vec<usize>,
    /// Supernode of each factor column.
    sn_of: Vec<u32>,
    /// Displayed free nodes in Gram order.
    nodes: Vec<u32>,
    /// Factor column of (node in Gram order, axis).
    col_of: Vec<usize>,
    /// Per supernode, the node range `D(s)` (Gram order).
    range: Vec<(usize, usize)>,
    /// Touchable nodes in Gram order, as positions in `nodes`.
    t_pos: Vec<usize>,
    /// Per supernode, the range of `t_pos` inside `D(s)`.
    t_range: Vec<(usize, usize)>,
    /// Offset of each supernode's block in `W` (`n_sn + 1` entries), f64 entries.
    off: Vec<usize>,
    /// Per factor column, whether the factor's `Σ` is −1 there (empty: `Σ = I`).
    negative: Vec<bool>,
    /// Each supernode's parent (`usize::MAX` at a root).
    parent: Vec<usize>,
    /// Floating-point operations of [`GramPlan::forward`] (estimate).
    pub forward_flops: f64,
    /// Floating-point operations of all the [`GramPlan::tile`]s (estimate).
    pub gram_flops: f64,
}

/// A pointer to `W` shared by the forward sweep's threads, which write disjoint rows.
#[derive(Clone, Copy)]
struct Shared(*mut f64);
// SAFETY: the threads given a `Shared` write disjoint rows of disjoint-or-identical blocks,
// and the scope joins them before `W` is used again.
unsafe impl Send for Shared {}
unsafe impl Sync for Shared {}

impl GramPlan {
    /// The plan for rows `s_nodes` (the displayed free nodes) and columns `t_nodes` (each also
    /// in `s_nodes`); `None` if the factor is not supernodal or a node's DOFs do not share one
    /// path to the root (the column method then applies).
    pub fn new(f: &Factor, dofs: &Dofs, s_nodes: &[u32], t_nodes: &[u32]) -> Option<GramPlan> {
        let (sym, _) = f.supernodal()?;
        let pos = f.position_of_dof();
        let nsn = sym.n_supernodes();
        let mut begin: Vec<usize> = sym.supernode_begin().to_vec();
        begin.push(sym.nrows());
        let (sn_of, parent) = supernode_tree(f)?;
        if parent
            .iter()
            .enumerate()
            .any(|(s, &p)| p != usize::MAX && p <= s)
        {
            return None;
        }
        // Post-order: `post[s]`, and the first post-order index of s's subtree.
        let mut size = vec![1usize; nsn];
        for s in 0..nsn {
            if parent[s] != usize::MAX {
                size[parent[s]] += size[s];
            }
        }
        let mut child_ptr = vec![0usize; nsn + 1];
        for &p in &parent {
            if p != usize::MAX {
                child_ptr[p + 1] += 1;
            }
        }
        for s in 0..nsn {
            child_ptr[s + 1] += child_ptr[s];
        }
        let mut children = vec![0usize; child_ptr[nsn]];
        let mut fill = child_ptr.clone();
        for (s, &p) in parent.iter().enumerate() {
            if p != usize::MAX {
                children[fill[p]] = s;
                fill[p] += 1;
            }
        }
        // Subtrees in post-order are contiguous: give each subtree its block of indices.
        let mut first = vec![0usize; nsn];
        let mut next_root = 0usize;
        for s in (0..nsn).rev() {
            if parent[s] == usize::MAX {
                first[s] = next_root;
                next_root += size[s];
            }
        }
        for s in (0..nsn).rev() {
            let mut at = first[s];
            for &c in &children[child_ptr[s]..child_ptr[s + 1]] {
                first[c] = at;
                at += size[c];
            }
        }
        let post: Vec<usize> = (0..nsn).map(|s| first[s] + size[s] - 1).collect();
        // Each displayed node's home: the supernode of its first factor column.
        let mut keyed = Vec::with_capacity(s_nodes.len());
        for &n in s_nodes {
            let mut cols = [0usize; 3];
            for (a, c) in cols.iter_mut().enumerate() {
                *c = pos[dofs.free(n, a)?];
            }
            let low = *cols.iter().min()?;
            let home = sn_of[low] as usize;
            for &c in &cols {
                let s = sn_of[c] as usize;
                if !(first[s] <= post[home] && post[home] <= post[s]) {
                    return None;
                }
            }
            keyed.push((post[home], low, n, cols));
        }
        keyed.sort_unstable();
        let keys: Vec<usize> = keyed.iter().map(|k| k.0).collect();
        let nodes: Vec<u32> = keyed.iter().map(|k| k.2).collect();
        let col_of: Vec<usize> = keyed.iter().flat_map(|k| k.3).collect();
        let range: Vec<(usize, usize)> = (0..nsn)
            .map(|s| {
                (
                    keys.partition_point(|&k| k < first[s]),
                    keys.partition_point(|&k| k <= post[s]),
                )
            })
            .collect();
        let mut at_node = std::collections::HashMap::with_capacity(nodes.len());
        for (g, &n) in nodes.iter().enumerate() {
            at_node.insert(n, g);
        }
        let mut t_pos: Vec<usize> = t_nodes
            .iter()
            .map(|n| at_node.get(n).copied())
            .collect::<Option<_>>()?;
        t_pos.sort_unstable();
        let t_range: Vec<(usize, usize)> = range
            .iter()
            .map(|&(lo, hi)| {
                (
                    t_pos.partition_point(|&g| g < lo),
                    t_pos.partition_point(|&g| g < hi),
                )
            })
            .collect();
        let mut off = Vec::with_capacity(nsn + 1);
        off.push(0usize);
        let (mut fwd, mut gram) = (0.0f64, 0.0f64);
        for s in 0..nsn {
            let ns = (begin[s + 1] - begin[s]) as f64;
            let md = 3.0 * (range[s].1 - range[s].0) as f64;
            let mt = 3.0 * (t_range[s].1 - t_range[s].0) as f64;
            let npat = sym.supernode(s).pattern().len() as f64;
            fwd += md * ns * (ns + 2.0 * npat);
            gram += 2.0 * md * ns * mt;
            off.push(off[s] + 3 * (range[s].1 - range[s].0) * (begin[s + 1] - begin[s]));
        }
        if t_pos.len() == nodes.len() {
            gram /= 2.0; // symmetric: each tile's upper rows are mirrored
        }
        Some(GramPlan {
            begin,
            sn_of,
            nodes,
            col_of,
            range,
            t_pos,
            t_range,
            off,
            negative: f.negative().to_vec(),
            parent,
            forward_flops: fwd,
            gram_flops: gram,
        })
    }

    /// The displayed free nodes in Gram order (the rows of a [`GramPlan::tile`], 3 per node).
    pub fn nodes(&self) -> &[u32] {
        &self.nodes
    }

    /// The touchable nodes in Gram order: column `k` of the tiles is `touchable()[k]`.
    pub fn touchable(&self) -> Vec<u32> {
        self.t_pos.iter().map(|&g| self.nodes[g]).collect()
    }

    /// Bytes of `W`.
    pub fn w_bytes(&self) -> usize {
        8 * self.off.last().copied().unwrap_or(0)
    }

    /// Computes `W` (bottom-up over the supernodes; its rows split over `threads`).
    /// `None` if `W` does not fit in memory.
    pub fn forward(&self, f: &Factor, threads: usize) -> Option<Vec<f64>> {
        let (sym, val) = f.supernodal()?;
        let total = *self.off.last()?;
        let mut w = Vec::new();
        w.try_reserve_exact(total).ok()?;
        w.resize(total, 0.0f64);
        for (g, cols) in self.col_of.chunks_exact(3).enumerate() {
            for (a, &c) in cols.iter().enumerate() {
                let s = self.sn_of[c] as usize;
                let (lo, hi) = self.range[s];
                let md = 3 * (hi - lo);
                let i = c - self.begin[s];
                w[self.off[s] + i * md + 3 * (g - lo) + a] = 1.0;
            }
        }
        // Each row of `W` (one displayed DOF's forward solve) depends on no other row: the
        // threads take contiguous ranges of rows of about equal work and sweep every
        // supernode bottom-up over their own rows, with no synchronisation.
        let n_rows = 3 * self.nodes.len();
        let mut per_row = vec![0.0f64; n_rows + 1];
        for s in 0..self.begin.len() - 1 {
            let (lo, hi) = self.range[s];
            let ns = (self.begin[s + 1] - self.begin[s]) as f64;
            let npat = sym.supernode(s).pattern().len() as f64;
            // The work per row, plus a fixed cost per supernode visited.
            let cost = ns * (ns + 2.0 * npat) + 64.0;
            per_row[3 * lo] += cost;
            per_row[3 * hi] -= cost;
        }
        // `per_row` is a difference array: its running sum is each row's work, and the
        // running sum of that the work up to a row.
        let (mut row_work, mut total) = (0.0f64, 0.0f64);
        let prefix: Vec<f64> = std::iter::once(0.0)
            .chain(per_row[..n_rows].iter().map(|d| {
                row_work += d;
                total += row_work;
                total
            }))
            .collect();
        let parts = threads.clamp(1, n_rows.max(1));
        let total_work = prefix[n_rows];
        // Non-decreasing, from 0 to every row (whatever the rounding of the targets).
        let bounds: Vec<usize> = (0..=parts)
            .map(|t| match t {
                0 => 0,
                t if t == parts => n_rows,
                t => {
                    let target = total_work * t as f64 / parts as f64;
                    prefix.partition_point(|&v| v < target).min(n_rows)
                }
            })
            .collect();
        let ptr = Shared(w.as_mut_ptr());
        let vp = sym.col_ptr_for_val();
        let sweep = |rows: std::ops::Range<usize>| {
            // A factor in a file: drop the pages passed now and then.
            let mut passed = crate::fem::frontal::Passed::default();
            for s in 0..self.begin.len() - 1 {
                if let Some(r) = passed.add(vp[s]..vp[s + 1]) {
                    f.release(r);
                }
                let (lo, hi) = self.range[s];
                let (a, b) = ((3 * lo).max(rows.start), (3 * hi).min(rows.end));
                if a >= b {
                    continue;
                }
                let ns = self.begin[s + 1] - self.begin[s];
                let pattern = sym.supernode(s).pattern();
                let ls =
                    MatRef::from_column_major_slice(&val[vp[s]..vp[s + 1]], ns + pattern.len(), ns);
                let (l11, l21) = ls.split_at_row(ns);
                // SAFETY: rows a..b of W (global) are this thread's alone, in W_s and in
                // every ancestor's block.
                unsafe { self.update(ptr, s, a - 3 * lo..b - 3 * lo, l11, l21, pattern) }
            }
            if let Some(r) = passed.rest() {
                f.release(r);
            }
        };
        if parts == 1 {
            sweep(0..n_rows);
        } else {
            let done = crate::threads::fan_out(
                parts,
                || sweep(bounds[0]..bounds[1]),
                |t| sweep(bounds[t]..bounds[t + 1]),
            );
            for d in done {
                if let Err(e) = d {
                    std::panic::resume_unwind(e);
                }
            }
        }
        Some(w)
    }

    /// Rows `r` of supernode `s`'s step: `W_s ← W_s L₁₁⁻ᵀ` (the forward solve through the
    /// diagonal block) and the update `W_a −= W_s L₂₁ᵀ` of the ancestors' blocks.
    ///
    /// # Safety
    /// `w` points to `W`; no other thread touches rows `r` of `W_s` or the matching rows of
    /// the ancestors' blocks during the call.
    unsafe fn update(
        &self,
        w: Shared,
        s: usize,
        r: std::ops::Range<usize>,
        l11: MatRef<'_, f64>,
        l21: MatRef<'_, f64>,
        pattern: &[usize],
    ) {
        let (lo, hi) = self.range[s];
        let md = 3 * (hi - lo);
        let ns = l11.nrows();
        let nr = r.end - r.start;
        if nr == 0 {
            return;
        }
        // SAFETY: W_s occupies off[s]..off[s+1]; rows r of its md × ns column-major block.
        let mut ws: MatMut<'_, f64> = unsafe {
            MatMut::from_raw_parts_mut(w.0.add(self.off[s] + r.start), nr, ns, 1, md as isize)
        };
        faer::linalg::triangular_solve::solve_lower_triangular_in_place(
            l11,
            ws.rb_mut().transpose_mut(),
            Par::Seq,
        );
        let npat = pattern.len();
        let chunk = (4_000_000 / nr).clamp(1, npat.max(1));
        let mut u = Mat::<f64>::zeros(nr, chunk);
        for c0 in (0..npat).step_by(chunk) {
            let c1 = (c0 + chunk).min(npat);
            let mut uc = u.as_mut().subcols_mut(0, c1 - c0);
            faer::linalg::matmul::matmul(
                uc.rb_mut(),
                Accum::Replace,
                ws.rb(),
                l21.subrows(c0, c1 - c0).transpose(),
                1.0,
                Par::Seq,
            );
            for (k, &row) in pattern[c0..c1].iter().enumerate() {
                let a = self.sn_of[row] as usize;
                let (alo, ahi) = self.range[a];
                let mda = 3 * (ahi - alo);
                let i = row - self.begin[a];
                let base = self.off[a] + i * mda + 3 * (lo - alo) + r.start;
                // SAFETY: inside W_a (D(s) ⊆ D(a)); these rows belong to this job.
                let dst = unsafe { std::slice::from_raw_parts_mut(w.0.add(base), nr) };
                for (d, v) in dst.iter_mut().zip(uc.rb().col(k).iter()) {
                    *d -= *v;
                }
            }
        }
    }

    /// Whether every displayed free node is touchable (`T = S`): then `(K⁻¹)[S,T]` is
    /// symmetric and a tile's rows above it can be mirrored from earlier tiles.
    pub fn symmetric(&self) -> bool {
        self.t_pos.len() == self.nodes.len()
    }

    /// Supernode `s`'s block of `W` (`3·|D(s)| × n_s`) and, gathered into `buf`, its rows of
    /// the touchable nodes at positions `gs` (`k = 3·|gs|` rows), the factor's `Σ` applied
    /// (an auxiliary unknown's column counts negatively): the two operands of a tile's
    /// product `W_s · gatheredᵀ`.
    fn gather<'w>(
        &self,
        w: &'w [f64],
        s: usize,
        gs: impl Iterator<Item = usize> + Clone,
        k: usize,
        buf: &'w mut Vec<f64>,
    ) -> (MatRef<'w, f64>, MatRef<'w, f64>) {
        let (lo, hi) = self.range[s];
        let md = 3 * (hi - lo);
        let ns = self.begin[s + 1] - self.begin[s];
        buf.clear();
        buf.resize(k * ns, 0.0f64);
        let negative = self.negative.get(self.begin[s]..self.begin[s + 1]);
        for i in 0..ns {
            let col = &w[self.off[s] + i * md..][..md];
            let sign = match negative {
                Some(n) if n[i] => -1.0,
                _ => 1.0,
            };
            for (t, g) in gs.clone().enumerate() {
                for ax in 0..3 {
                    buf[i * k + 3 * t + ax] = sign * col[3 * (g - lo) + ax];
                }
            }
        }
        (
            MatRef::from_column_major_slice(&w[self.off[s]..self.off[s + 1]], md, ns),
            MatRef::from_column_major_slice(buf, k, ns),
        )
    }

    /// As [`GramPlan::tile`] for the touchable columns `js` (ascending, any gaps): `out`
    /// (`3·nodes × 3·js.len()`, column stride `ld`, zero on entry) receives `(K⁻¹)[S, T_js]`,
    /// column `3q + axis` for `js[q]`, on the node rows (Gram order) `rows` marks (all
    /// without); the others stay zero.
    pub fn tile_cols(
        &self,
        w: &[f64],
        js: &[usize],
        rows: Option<&[bool]>,
        out: &mut [f64],
        ld: usize,
    ) {
        let m = 3 * self.nodes.len();
        let nt = 3 * js.len();
        assert!(ld >= m && out.len() >= ld * nt.saturating_sub(1) + m);
        assert!(js.windows(2).all(|p| p[0] < p[1]));
        let mut out = MatMut::from_column_major_slice_with_stride_mut(out, m, nt, ld);
        let mut gather = Vec::new();
        let mut sel = Vec::new();
        for s in 0..self.begin.len() - 1 {
            let (tlo, thi) = self.t_range[s];
            // The wanted columns this supernode's block reaches: one run of `js`.
            let (q0, q1) = (
                js.partition_point(|&j| j < tlo),
                js.partition_point(|&j| j < thi),
            );
            if q0 >= q1 {
                continue;
            }
            let (lo, hi) = self.range[s];
            let md = 3 * (hi - lo);
            let k = 3 * (q1 - q0);
            let (ws, bm) = self.gather(
                w,
                s,
                js[q0..q1].iter().map(|&j| self.t_pos[j]),
                k,
                &mut gather,
            );
            sel.clear();
            if let Some(mask) = rows {
                sel.extend((lo..hi).filter(|&g| mask[g]));
                if sel.is_empty() {
                    continue;
                }
            }
            if sel.is_empty() || sel.len() == hi - lo {
                faer::linalg::matmul::matmul(
                    out.rb_mut().submatrix_mut(3 * lo, 3 * q0, md, k),
                    Accum::Add,
                    ws,
                    bm.transpose(),
                    1.0,
                    Par::Seq,
                );
                continue;
            }
            // Only some rows: those of W_s gathered, multiplied, put back.
            let r = 3 * sel.len();
            let wsub =
                Mat::<f64>::from_fn(r, ws.ncols(), |i, c| ws[(3 * (sel[i / 3] - lo) + i % 3, c)]);
            let mut prod = Mat::<f64>::zeros(r, k);
            faer::linalg::matmul::matmul(
                prod.as_mut(),
                Accum::Replace,
                wsub.as_ref(),
                bm.transpose(),
                1.0,
                Par::Seq,
            );
            for c in 0..k {
                for (t, &g) in sel.iter().enumerate() {
                    for a in 0..3 {
                        out[(3 * g + a, 3 * q0 + c)] += prod[(3 * t + a, c)];
                    }
                }
            }
        }
    }

    /// `out += (K⁻¹)[R, C] · c` for any two sets of displayed nodes, given as ascending Gram
    /// positions (indices into [`GramPlan::nodes`]): `c` is `3|C| × k`, `out` `3|R| × k`,
    /// DOFs in the sets' order. Only the supernodes both sets reach are visited, each as two
    /// products through its block of `W` (`W_s[C]ᵀ·c`, then `W_s[R]·` that), so a product of
    /// `k` vectors costs about `k·(|R| + |C|)` per shared supernode column, not `|R|·|C|`:
    /// the sketches that compress a far block. The result does not depend on threads.
    pub fn apply(
        &self,
        w: &[f64],
        rows: &[usize],
        cols: &[usize],
        c: MatRef<'_, f64>,
        out: MatMut<'_, f64>,
        sc: &mut ApplyScratch,
    ) {
        self.apply_pieces(w, rows, &[(cols, c)], out, sc);
    }

    /// As [`GramPlan::apply`] for several column sets at once, each with its own vectors:
    /// `out = [(K⁻¹)[R, C₁]·c₁, (K⁻¹)[R, C₂]·c₂, …]` (`out` is `3|R| × Σ kᵢ`). Each supernode's
    /// rows of `R` are gathered once for all the sets: the products `Bᵢᵀ Qᵢ` of the far blocks
    /// of one column cluster.
    pub fn apply_pieces(
        &self,
        w: &[f64],
        rows: &[usize],
        pieces: &[(&[usize], MatRef<'_, f64>)],
        mut out: MatMut<'_, f64>,
        sc: &mut ApplyScratch,
    ) {
        let k: usize = pieces.iter().map(|p| p.1.ncols()).sum();
        assert!(out.nrows() == 3 * rows.len() && out.ncols() == k);
        assert!(rows.windows(2).all(|p| p[0] < p[1]));
        for (cols, c) in pieces {
            assert!(c.nrows() == 3 * cols.len() && cols.windows(2).all(|p| p[0] < p[1]));
        }
        let nsn = self.begin.len() - 1;
        if sc.mark.len() != nsn {
            sc.mark = vec![0; nsn];
            sc.stamp = 0;
        }
        // The supernodes both sides reach: the common ancestors of their home supernodes.
        sc.stamp = sc.stamp.wrapping_add(2);
        if sc.stamp < 2 {
            sc.mark.fill(0);
            sc.stamp = 2;
        }
        let (a, b) = (sc.stamp, sc.stamp + 1);
        let home = |g: usize| {
            self.sn_of[self.col_of[3 * g..3 * g + 3]
                .iter()
                .copied()
                .min()
                .unwrap_or(0)] as usize
        };
        for &g in pieces.iter().flat_map(|p| p.0.iter()) {
            let mut s = home(g);
            while s != usize::MAX && sc.mark[s] != a {
                sc.mark[s] = a;
                s = self.parent[s];
            }
        }
        sc.list.clear();
        for &g in rows {
            let mut s = home(g);
            while s != usize::MAX && sc.mark[s] != b {
                if sc.mark[s] == a {
                    sc.list.push(s);
                }
                sc.mark[s] = b;
                s = self.parent[s];
            }
        }
        sc.list.sort_unstable();
        let list = std::mem::take(&mut sc.list);
        for &s in &list {
            let (lo, hi) = self.range[s];
            let md = 3 * (hi - lo);
            let ns = self.begin[s + 1] - self.begin[s];
            let ws = MatRef::from_column_major_slice(&w[self.off[s]..self.off[s + 1]], md, ns);
            let run = |set: &[usize]| {
                (
                    set.partition_point(|&g| g < lo),
                    set.partition_point(|&g| g < hi),
                )
            };
            let (r0, r1) = run(rows);
            if r0 >= r1 {
                continue;
            }
            // z = W_s[Cᵢ]ᵀ cᵢ side by side (the factor's signs applied to its rows).
            sc.z.clear();
            sc.z.resize(ns * k, 0.0);
            let mut z = MatMut::from_column_major_slice_mut(&mut sc.z, ns, k);
            let (mut at, mut any) = (0, false);
            for (cols, c) in pieces {
                let kc = c.ncols();
                let (c0, c1) = run(cols);
                if c0 < c1 {
                    let wc = rows_of(ws, lo, &cols[c0..c1], &mut sc.wc);
                    faer::linalg::matmul::matmul(
                        z.rb_mut().subcols_mut(at, kc),
                        Accum::Replace,
                        wc.transpose(),
                        c.subrows(3 * c0, 3 * (c1 - c0)),
                        1.0,
                        Par::Seq,
                    );
                    any = true;
                }
                at += kc;
            }
            if !any {
                continue;
            }
            if let Some(neg) = self.negative.get(self.begin[s]..self.begin[s + 1]) {
                for (i, _) in neg.iter().enumerate().filter(|x| *x.1) {
                    for j in 0..k {
                        z[(i, j)] = -z[(i, j)];
                    }
                }
            }
            // The rows in chunks, so that a gathered chunk of `W_s` stays small.
            let mut q0 = r0;
            while q0 < r1 {
                let q1 = (q0 + ROW_CHUNK).min(r1);
                let wr = rows_of(ws, lo, &rows[q0..q1], &mut sc.wr);
                faer::linalg::matmul::matmul(
                    out.rb_mut().subrows_mut(3 * q0, 3 * (q1 - q0)),
                    Accum::Add,
                    wr,
                    z.rb(),
                    1.0,
                    Par::Seq,
                );
                q0 = q1;
            }
        }
        sc.list = list;
    }

    /// Columns `j0..j1` of the touchable list: `out` (`3·nodes × 3·(j1 − j0)`, column-major
    /// with column stride `ld` ≥ 3·nodes, rows in Gram order) receives `(K⁻¹)[S, T_j0..j1]`
    /// except on the node rows `skip` (left as they are); it must be zero on entry.
    pub fn tile(
        &self,
        w: &[f64],
        j0: usize,
        j1: usize,
        skip: std::ops::Range<usize>,
        out: &mut [f64],
        ld: usize,
    ) {
        let m = 3 * self.nodes.len();
        let nt = 3 * (j1 - j0);
        assert!(ld >= m && out.len() >= ld * nt.saturating_sub(1) + m);
        let mut out = MatMut::from_column_major_slice_with_stride_mut(out, m, nt, ld);
        let mut gather = Vec::new();
        for s in 0..self.begin.len() - 1 {
            let (tlo, thi) = self.t_range[s];
            let (a, b) = (tlo.max(j0), thi.min(j1));
            if a >= b {
                continue;
            }
            let (lo, hi) = self.range[s];
            let k = 3 * (b - a);
            let (ws, bm) = self.gather(w, s, self.t_pos[a..b].iter().copied(), k, &mut gather);
            for (r0, r1) in [(lo, hi.min(skip.start)), (lo.max(skip.end), hi)] {
                if r0 >= r1 {
                    continue;
                }
                faer::linalg::matmul::matmul(
                    out.rb_mut()
                        .submatrix_mut(3 * r0, 3 * (a - j0), 3 * (r1 - r0), k),
                    Accum::Add,
                    ws.subrows(3 * (r0 - lo), 3 * (r1 - r0)),
                    bm.transpose(),
                    1.0,
                    Par::Seq,
                );
            }
        }
    }
}

/// Row nodes gathered at a time by [`GramPlan::apply_pieces`].
const ROW_CHUNK: usize = 512;

/// Reusable buffers of [`GramPlan::apply`] (one per thread).
#[derive(Default)]
pub struct ApplyScratch {
    mark: Vec<u32>,
    stamp: u32,
    list: Vec<usize>,
    wc: Vec<f64>,
    wr: Vec<f64>,
    z: Vec<f64>,
}

/// The rows of the nodes at Gram positions `pos` (ascending, within `lo..`) of a supernode's
/// block `ws`: a view when they are consecutive, else gathered into `buf`.
fn rows_of<'a>(
    ws: MatRef<'a, f64>,
    lo: usize,
    pos: &[usize],
    buf: &'a mut Vec<f64>,
) -> MatRef<'a, f64> {
    let (first, n) = (pos[0] - lo, pos.len());
    if pos[n - 1] - pos[0] + 1 == n {
        return ws.subrows(3 * first, 3 * n);
    }
    let (r, ns) = (3 * n, ws.ncols());
    buf.clear();
    buf.resize(r * ns, 0.0);
    for i in 0..ns {
        let col = ws.col(i).try_as_col_major().map(|c| c.as_slice());
        let dst = &mut buf[i * r..][..r];
        match col {
            Some(col) => {
                for (t, &g) in pos.iter().enumerate() {
                    dst[3 * t..3 * t + 3].copy_from_slice(&col[3 * (g - lo)..3 * (g - lo) + 3]);
                }
            }
            None => {
                for (t, &g) in pos.iter().enumerate() {
                    for a in 0..3 {
                        dst[3 * t + a] = ws[(3 * (g - lo) + a, i)];
                    }
                }
            }
        }
    }
    MatRef::from_column_major_slice(buf, r, ns)
}

/// Solves `K x = e_d` for unit right-hand sides on the supernodal factor, skipping what the
/// answer does not need: the forward sweep visits only the supernodes the columns reach (their
/// supernodes' ancestors), the back sweep only those that hold or precede a wanted row.
pub struct UnitSolver {
    parent: Vec<usize>,
    sn_of: Vec<u32>,
    pos: Vec<usize>,
    keep: Vec<bool>,
}

impl UnitSolver {
    /// A solver whose answers are exact on the free DOFs `wanted`; `None` if the factor is not
    /// supernodal.
    pub fn new(f: &Factor, wanted: impl IntoIterator<Item = usize>) -> Option<UnitSolver> {
        let (sn_of, parent) = supernode_tree(f)?;
        let pos = f.position_of_dof();
        let mut keep = vec![false; parent.len()];
        for d in wanted {
            mark_path(&mut keep, &parent, sn_of[*pos.get(d)?] as usize);
        }
        Some(UnitSolver {
            parent,
            sn_of,
            pos,
            keep,
        })
    }

    /// The row of the solution holding free DOF `d`.
    pub fn row(&self, d: usize) -> usize {
        self.pos[d]
    }

    /// Fraction of the factor's values in the supernodes the back sweep visits.
    pub fn kept_values(&self, f: &Factor) -> f64 {
        let Some((sym, _)) = f.supernodal() else {
            return 1.0;
        };
        let vp = sym.col_ptr_for_val();
        let kept: usize = (0..self.keep.len())
            .filter(|&s| self.keep[s])
            .map(|s| vp[s + 1] - vp[s])
            .sum();
        kept as f64 / vp[self.keep.len()].max(1) as f64
    }

    /// Fraction of the supernodes the back sweep visits.
    pub fn kept(&self) -> f64 {
        self.keep.iter().filter(|&&k| k).count() as f64 / self.keep.len().max(1) as f64
    }

    /// Column `j` of `x` (zero on entry, one row per free DOF, in the factor's order: see
    /// [`UnitSolver::row`]) becomes `K⁻¹ e_{dofs[j]}`, exact on the wanted DOFs.
    pub fn solve(&self, f: &Factor, dofs: &[usize], x: MatMut<'_, f64>) {
        self.sweep(f, dofs, x, &self.keep);
    }

    /// As [`UnitSolver::solve`], exact on every DOF.
    pub fn solve_full(&self, f: &Factor, dofs: &[usize], x: MatMut<'_, f64>) {
        self.sweep(f, dofs, x, &vec![true; self.keep.len()]);
    }

    /// The forward sweep over the supernodes the columns reach, the back sweep over `keep`.
    /// On a factor in a file, the pages passed are dropped now and then
    /// ([`crate::fem::frontal::Passed`]).
    fn sweep(&self, f: &Factor, dofs: &[usize], mut x: MatMut<'_, f64>, keep: &[bool]) {
        let Some((sym, _)) = f.supernodal() else {
            return;
        };
        let mut reach = vec![false; sym.n_supernodes()];
        for (j, &d) in dofs.iter().enumerate() {
            x[(self.pos[d], j)] = 1.0;
            mark_path(&mut reach, &self.parent, self.sn_of[self.pos[d]] as usize);
        }
        f.sweeps(x, &reach, keep);
    }
}

/// The supernode of each factor column, and the parent of each supernode in the supernodal
/// elimination tree (the supernode holding its first off-diagonal row; `usize::MAX` for a
/// root). `None` if the factor is not supernodal.
fn supernode_tree(f: &Factor) -> Option<(Vec<u32>, Vec<usize>)> {
    let (sym, _) = f.supernodal()?;
    let nsn = sym.n_supernodes();
    let mut sn_of = vec![0u32; sym.nrows()];
    let (begin, end) = (sym.supernode_begin(), sym.supernode_end());
    for s in 0..nsn {
        sn_of[begin[s]..end[s]].fill(s as u32);
    }
    let parent = (0..nsn)
        .map(|s| {
            sym.supernode(s)
                .pattern()
                .iter()
                .min()
                .map_or(usize::MAX, |&r| sn_of[r] as usize)
        })
        .collect();
    Some((sn_of, parent))
}

/// Marks `s` and its ancestors, stopping at the first already marked.
fn mark_path(marked: &mut [bool], parent: &[usize], mut s: usize) {
    while s != usize::MAX && !marked[s] {
        marked[s] = true;
        s = parent[s];
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    /// A clamped cube of `n`³ cells, its factor and the Gram plan of its free surface (rows and
    /// columns).
    fn cube_surface(n: usize) -> (Factor, GramPlan) {
        let m = crate::mesh::cube_with(
            [n, n, n],
            [30.0, 30.0, 30.0],
            crate::mesh::units::Material::DEFAULT,
        )
        .expect("cube");
        let k = crate::fem::Stiffness::assemble(&m).expect("K");
        let f = k.factorize().expect("factor");
        let shown = m.free_surface_nodes();
        let g = GramPlan::new(&f, &k.dofs, &shown, &shown).expect("supernodal");
        (f, g)
    }

    /// Shards made on machines with different core counts must merge into the unsharded
    /// file: `W` may not depend on how its rows are split over threads.
    #[cfg_attr(test, test)]
    pub(crate) fn w_is_the_same_bit_for_bit_on_any_number_of_threads() {
        let (f, g) = cube_surface(14);
        let one = g.forward(&f, 1).expect("W");
        assert!(one.iter().any(|&v| v != 0.0) && one.iter().all(|v| v.is_finite()));
        for t in [2, 3, 7] {
            let w = g.forward(&f, t).expect("W");
            assert!(
                one.iter().zip(&w).all(|(a, b)| a.to_bits() == b.to_bits()),
                "{t} threads"
            );
        }
    }

    /// `apply` of a set of vectors equals the Gram tiles' entries (all rows) times them, for
    /// scattered, consecutive and disjoint node sets.
    #[cfg_attr(test, test)]
    pub(crate) fn apply_equals_the_tiles_times_the_vectors() {
        let (f, g) = cube_surface(8);
        let w = g.forward(&f, 1).expect("W");
        let n = g.nodes().len();
        let nt = g.t_pos.len();
        let mm = 3 * n;
        let mut full = vec![0.0; mm * 3 * nt];
        g.tile_cols(&w, &(0..nt).collect::<Vec<_>>(), None, &mut full, mm);
        // Column j of the tiles is touchable j, at Gram position t_pos[j].
        let mut col_at = vec![usize::MAX; n];
        for (j, &p) in g.t_pos.iter().enumerate() {
            col_at[p] = j;
        }
        let mut sc = ApplyScratch::default();
        let sets: [(Vec<usize>, Vec<usize>); 3] = [
            ((0..n).step_by(3).collect(), (1..n).step_by(5).collect()),
            ((n / 2..n).collect(), (0..n / 3).collect()),
            ((0..n).collect(), (0..n).collect()),
        ];
        for (rows, cols) in sets {
            let kk = 4;
            let c = Mat::<f64>::from_fn(3 * cols.len(), kk, |i, j| {
                ((i * 7 + j * 3) % 11) as f64 - 5.0
            });
            let mut out = Mat::<f64>::zeros(3 * rows.len(), kk);
            g.apply(&w, &rows, &cols, c.as_ref(), out.as_mut(), &mut sc);
            let mut worst = 0.0f64;
            let mut scale = 0.0f64;
            for (ri, &r) in rows.iter().enumerate() {
                for a in 0..3 {
                    for j in 0..kk {
                        let mut want = 0.0;
                        for (ci, &cp) in cols.iter().enumerate() {
                            for b in 0..3 {
                                want += full[(3 * col_at[cp] + b) * mm + 3 * r + a]
                                    * c[(3 * ci + b, j)];
                            }
                        }
                        worst = worst.max((out[(3 * ri + a, j)] - want).abs());
                        scale = scale.max(want.abs());
                    }
                }
            }
            assert!(scale > 0.0 && worst <= 1e-10 * scale, "{worst} of {scale}");
        }
        // Several column sets at once equal one `apply` each, side by side.
        let rows: Vec<usize> = (0..n).step_by(2).collect();
        let (c1, c2): (Vec<usize>, Vec<usize>) =
            ((1..n).step_by(4).collect(), (3..n / 2).collect());
        let x1 = Mat::<f64>::from_fn(3 * c1.len(), 3, |i, j| ((i + 5 * j) % 7) as f64 - 3.0);
        let x2 = Mat::<f64>::from_fn(3 * c2.len(), 5, |i, j| ((2 * i + j) % 9) as f64 - 4.0);
        let mut both = Mat::<f64>::zeros(3 * rows.len(), 8);
        g.apply_pieces(
            &w,
            &rows,
            &[(&c1, x1.as_ref()), (&c2, x2.as_ref())],
            both.as_mut(),
            &mut sc,
        );
        let mut one = Mat::<f64>::zeros(3 * rows.len(), 3);
        let mut two = Mat::<f64>::zeros(3 * rows.len(), 5);
        g.apply(&w, &rows, &c1, x1.as_ref(), one.as_mut(), &mut sc);
        g.apply(&w, &rows, &c2, x2.as_ref(), two.as_mut(), &mut sc);
        let scale = one.norm_max().max(two.norm_max());
        for i in 0..3 * rows.len() {
            for j in 0..8 {
                let want = if j < 3 { one[(i, j)] } else { two[(i, j - 3)] };
                assert!((both[(i, j)] - want).abs() <= 1e-12 * scale, "({i}, {j})");
            }
        }
    }
}
