//! Multifrontal Cholesky of K that streams each finished supernode to a file.
//!
//! faer's supernodal factorisation is left-looking: it holds every column of the factor in
//! memory until the end (1.05 GB for a 45k-node mesh). A multifrontal sweep over the same
//! supernodes ([`faer`]'s symbolic analysis, so the layout and the values' order are
//! faer's) only needs, at any moment, the front being factorised and the update matrices
//! that wait for their parents; each supernode's columns are final when its front is
//! factorised and go straight to the file. The solves then read the factor through a
//! read-only map of that file ([`Values::Mapped`]), and drop the pages they have passed
//! ([`Values::release`]), so the process holds neither the whole factor nor its pages.
//!
//! The dense work is faer's (Cholesky, triangular solve, lower-triangular product).
//! Supernodes are visited in a post-order of the supernodal tree whose children come
//! largest-stack first (Liu's order), which keeps the stack of waiting update matrices
//! small. Subtrees of about equal flops go to one thread each; the few supernodes above them
//! follow with the dense work on all cores. A supernode's arithmetic does not depend on
//! where it runs, so neither do the factor's bits.

use crate::fem::error::FemError;
use crate::fem::numeric::llt_else_ldlt;
use faer::reborrow::*;
use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;
use faer::{Accum, MatMut, Par};
use std::fs::File;

/// Where the values of a factor live.
pub enum Values {
    /// On the heap (faer's factorisation).
    Heap(Vec<f64>),
    /// In a read-only map of an unlinked temporary file (`factorize_to_file`).
    Mapped(memmap2::Mmap),
}

impl Values {
    /// The values, in faer's supernodal layout.
    pub fn as_slice(&self) -> &[f64] {
        match self {
            Values::Heap(v) => v,
            Values::Mapped(m) => bytemuck::cast_slice(&m[..]),
        }
    }

    /// Whether the values stream from a file.
    pub fn is_mapped(&self) -> bool {
        matches!(self, Values::Mapped(_))
    }

    /// Drops this process's pages of values `range` (a no-op on the heap): the next read
    /// maps them again from the page cache (or the disk, if the kernel has needed the
    /// memory). Used by the solves on the ranges they have passed.
    pub fn release(&self, range: std::ops::Range<usize>) {
        if let Values::Mapped(m) = self {
            // SAFETY: the map is a read-only shared map of a file that nothing writes any
            // more: dropping its pages loses nothing, and a later read maps the same bytes.
            unsafe { drop_pages(m.as_ptr(), range) }
        }
    }
}

/// Drops this process's pages wholly inside values (f64) `range` of the map at `base`.
///
/// # Safety
/// `range` must lie in a shared file map starting at `base`, whose pages may be dropped: a
/// later access maps the same bytes again (dirty pages stay in the page cache).
unsafe fn drop_pages(base: *const u8, range: std::ops::Range<usize>) {
    const PAGE: usize = 4096;
    let base = base as usize;
    let lo = (base + range.start * 8).div_ceil(PAGE) * PAGE;
    let hi = ((base + range.end * 8) / PAGE) * PAGE;
    if hi > lo {
        // SAFETY: whole pages inside the map (the caller's promise).
        #[cfg(all(feature = "native", unix))]
        unsafe {
            libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_DONTNEED)
        };
    }
}

/// The span of factor values a sweep has passed since it last dropped their pages: the
/// solves, the Gram forward and the factorisation's workers each drop theirs every
/// [`Passed::EVERY`] values (32 MB), so a factor in a file never sits whole in the process.
#[derive(Default)]
pub(crate) struct Passed(Option<std::ops::Range<usize>>);

impl Passed {
    /// Values passed between two drops.
    pub(crate) const EVERY: usize = 4 << 20;

    /// Adds `range` to the span; returns the span to drop once it reaches [`Passed::EVERY`].
    pub fn add(&mut self, range: std::ops::Range<usize>) -> Option<std::ops::Range<usize>> {
        let r = self.0.get_or_insert(range.clone());
        *r = r.start.min(range.start)..r.end.max(range.end);
        if r.len() >= Self::EVERY {
            self.0.take()
        } else {
            None
        }
    }

    /// The span not dropped yet.
    pub fn rest(&mut self) -> Option<std::ops::Range<usize>> {
        self.0.take()
    }
}

/// A new empty file in `dir`, already unlinked: it lives as long as the handle, and a
/// crash leaves nothing behind.
#[cfg(feature = "native")]
pub(crate) fn temp_file(dir: &std::path::Path) -> std::io::Result<File> {
    use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let path = dir.join(format!(
        ".touchfem-factor-{}-{nanos}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Relaxed)
    ));
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create_new(true)
        .open(&path)?;
    std::fs::remove_file(&path)?;
    Ok(file)
}

/// A new unlinked file in `dir` with `bytes` of disk reserved (`posix_fallocate`): a full
/// disk is this error now, not a fault (SIGBUS) while the map is written.
///
/// Without the `native` feature there are no files to map: an error, and the factor stays on
/// the heap where the store allows it.
#[cfg(not(feature = "native"))]
pub(crate) fn factor_file(dir: &std::path::Path, bytes: usize) -> Result<File, FemError> {
    Err(FemError::Factorisation(format!(
        "factor file of {bytes} bytes in {}: files need the `native` feature",
        dir.display()
    )))
}

/// A new unlinked file in `dir` with `bytes` of disk reserved (`posix_fallocate`): a full
/// disk is this error now, not a fault (SIGBUS) while the map is written.
#[cfg(feature = "native")]
pub(crate) fn factor_file(dir: &std::path::Path, bytes: usize) -> Result<File, FemError> {
    use std::os::fd::AsRawFd;
    let err = |e: std::io::Error| {
        FemError::Factorisation(format!(
            "factor file of {bytes} bytes in {}: {e}",
            dir.display()
        ))
    };
    let file = temp_file(dir).map_err(err)?;
    let len =
        libc::off_t::try_from(bytes.max(1)).map_err(|_| err(std::io::Error::other("too large")))?;
    // SAFETY: a valid open descriptor and a non-negative range.
    let rc = unsafe { libc::posix_fallocate(file.as_raw_fd(), 0, len) };
    if rc != 0 {
        return Err(err(std::io::Error::from_raw_os_error(rc)));
    }
    Ok(file)
}

/// Entries of a packed lower triangle of order `n`.
fn packed(n: usize) -> usize {
    n * (n + 1) / 2
}

/// The visiting order of the multifrontal sweep and the memory it needs.
pub(crate) struct FrontPlan {
    /// Supernodes in visiting order (a post-order: children right before their parent).
    pub order: Vec<usize>,
    /// The parent of each supernode (`usize::MAX` for a root).
    pub parent: Vec<usize>,
    /// The children of each supernode, in visiting order.
    pub children: Vec<Vec<usize>>,
}

impl FrontPlan {
    /// The visiting order of `sym`'s supernodes and its memory.
    pub fn new(sym: &SymbolicSupernodalCholesky<usize>) -> FrontPlan {
        let nsn = sym.n_supernodes();
        let (begin, end) = (sym.supernode_begin(), sym.supernode_end());
        let mut sn_of = vec![0usize; sym.nrows()];
        for s in 0..nsn {
            sn_of[begin[s]..end[s]].fill(s);
        }
        let nb = |s: usize| sym.supernode(s).pattern().len();
        let parent: Vec<usize> = (0..nsn)
            .map(|s| {
                sym.supernode(s)
                    .pattern()
                    .first()
                    .map_or(usize::MAX, |&r| sn_of[r])
            })
            .collect();
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); nsn];
        for s in 0..nsn {
            if parent[s] != usize::MAX {
                children[parent[s]].push(s);
            }
        }
        let upd = |s: usize| packed(nb(s));
        // The stack's height inside each subtree, above what was there before it. Children
        // are numbered before their parent, so one pass sees them done; they are visited in
        // decreasing order of (their height − their update), which minimises the parent's.
        let mut height = vec![0usize; nsn];
        for s in 0..nsn {
            let ch = &mut children[s];
            ch.sort_by_key(|&c| std::cmp::Reverse(height[c].saturating_sub(upd(c))));
            let mut held = 0usize;
            let mut h = 0usize;
            for &c in ch.iter() {
                h = h.max(held + height[c]);
                held += upd(c);
            }
            height[s] = h.max(held).max(upd(s));
        }
        let mut order = Vec::with_capacity(nsn);
        let mut stack: Vec<(usize, usize)> = Vec::new();
        for root in (0..nsn).filter(|&s| parent[s] == usize::MAX) {
            stack.push((root, 0));
            while let Some(top) = stack.last_mut() {
                let (s, next) = *top;
                if let Some(&c) = children[s].get(next) {
                    top.1 += 1;
                    stack.push((c, 0));
                } else {
                    order.push(s);
                    stack.pop();
                }
            }
        }
        FrontPlan {
            order,
            parent,
            children,
        }
    }
}

/// What every worker of one factorisation reads.
struct Shared<'a> {
    sym: &'a SymbolicSupernodalCholesky<usize>,
    k: faer::sparse::SparseColMatRef<'a, usize, f64>,
    fwd: &'a [usize],
    inv: &'a [usize],
    plan: &'a FrontPlan,
    dof_owner: &'a (dyn Fn(usize) -> u32 + Sync),
    /// Per factor column, whether its pivot is negative (a mixed system; empty: none).
    negative: &'a [bool],
}

impl Shared<'_> {
    fn ns(&self, s: usize) -> usize {
        self.sym.supernode_end()[s] - self.sym.supernode_begin()[s]
    }

    fn nb(&self, s: usize) -> usize {
        self.sym.supernode(s).pattern().len()
    }

    /// The largest front and the highest update stack of visiting `nodes` in order, where
    /// the updates of the supernodes `external` says come from elsewhere.
    fn needs(&self, nodes: &[usize], external: &dyn Fn(usize) -> bool) -> (usize, usize) {
        let mut held: Vec<usize> = Vec::new();
        let (mut front, mut height, mut top) = (0usize, 0usize, 0usize);
        for &s in nodes {
            let m = self.ns(s) + self.nb(s);
            front = front.max(m * m);
            for &c in &self.plan.children[s] {
                if !external(c) {
                    top -= held.pop().unwrap_or(0);
                }
            }
            if self.plan.parent[s] != usize::MAX {
                held.push(packed(self.nb(s)));
                top += packed(self.nb(s));
                height = height.max(top);
            }
        }
        (front, height)
    }
}

/// A worker's memory: its front, its stack of packed update matrices, and the maps from
/// factor rows to front rows.
struct Worker {
    local: Vec<usize>,
    stamp: Vec<usize>,
    /// Zero-filled anonymous memory for the largest front: the pages of the upper
    /// triangles, never written, are never touched.
    front: memmap2::MmapMut,
    stack: Vec<f64>,
    on_stack: Vec<(usize, usize)>,
    scratch: faer::dyn_stack::MemBuffer,
    /// Values written and not yet released (see [`Out::write`]).
    written: Passed,
}

/// The factor file, mapped shared and writable: workers copy their finished columns into
/// disjoint ranges of it. Page-cache writes through `pwrite` hold the file's lock, so two
/// workers' writes would take turns; faults on a map do not.
struct Out {
    ptr: *mut f64,
    len: usize,
}

// SAFETY: workers write disjoint ranges (each supernode's own values) through the pointer.
unsafe impl Send for Out {}
unsafe impl Sync for Out {}

impl Out {
    /// Copies `data` to values `offset..` and, every [`Passed::EVERY`] values, drops the pages the
    /// worker wrote since the last time (`written`, a range of values), so the process does not
    /// keep them: they stay in the page cache, dirty, for the kernel to write back.
    fn write(&self, offset: usize, data: &[f64], written: &mut Passed) -> Result<(), FemError> {
        let end = offset
            .checked_add(data.len())
            .filter(|&e| e <= self.len)
            .ok_or_else(|| {
                FemError::Factorisation(format!("values {offset}.. are outside the factor"))
            })?;
        // A large block (the top supernodes, written while nothing else runs) is copied by
        // all cores: the first touch of page-cache pages is what costs.
        let parts = if data.len() >= 1 << 22 {
            crate::threads::available().min(8)
        } else {
            1
        };
        let chunk = data.len().div_ceil(parts).max(1);
        let copy = |i: usize, part: &[f64]| {
            // SAFETY: in bounds (checked), and no other worker writes these values: each
            // supernode is factorised once, and the parts are disjoint.
            unsafe {
                std::ptr::copy_nonoverlapping(
                    part.as_ptr(),
                    self.ptr.add(offset + i * chunk),
                    part.len(),
                );
            }
        };
        if parts > 1 {
            std::thread::scope(|sc| {
                for (i, part) in data.chunks(chunk).enumerate() {
                    sc.spawn(move || copy(i, part));
                }
            });
        } else {
            copy(0, data);
        }
        if let Some(r) = written.add(offset..end) {
            self.release(r);
        }
        Ok(())
    }

    /// Drops this process's pages wholly inside values `range`.
    fn release(&self, range: std::ops::Range<usize>) {
        // SAFETY: the range lies in the shared map of the factor file (`ptr` is its start).
        unsafe { drop_pages(self.ptr.cast_const().cast(), range) }
    }
}

impl Worker {
    /// A worker whose front and stack hold `front` and `stack` entries without growing.
    fn new(n: usize, front: usize, stack: usize) -> Result<Worker, FemError> {
        let bad = |what: &str, e: std::collections::TryReserveError| {
            FemError::Factorisation(format!("{what}: {e}"))
        };
        let mut w = Worker {
            local: vec![0; n],
            stamp: vec![usize::MAX; n],
            front: memmap2::MmapMut::map_anon(8 * front.max(1))
                .map_err(|e| FemError::Factorisation(format!("front of {front} values: {e}")))?,
            stack: Vec::new(),
            on_stack: Vec::new(),
            scratch: faer::dyn_stack::MemBuffer::new(faer::dyn_stack::StackReq::empty()),
            written: Passed::default(),
        };
        w.stack
            .try_reserve_exact(stack)
            .map_err(|e| bad("update stack", e))?;
        Ok(w)
    }

    /// Factorises supernode `s`: assembles its front from K and its children's updates
    /// (on this worker's stack, or in `external`), factorises it, writes its columns and
    /// pushes its update.
    fn visit(
        &mut self,
        sh: &Shared<'_>,
        s: usize,
        external: &mut [Option<Vec<f64>>],
        out: &Out,
    ) -> Result<(), FemError> {
        let bad = FemError::Factorisation;
        let sym = sh.sym;
        let pattern = sym.supernode(s).pattern();
        let b0 = sym.supernode_begin()[s];
        let (ns, nb) = (sh.ns(s), sh.nb(s));
        let m = ns + nb;
        for i in 0..ns {
            self.local[b0 + i] = i;
            self.stamp[b0 + i] = s;
        }
        for (i, &r) in pattern.iter().enumerate() {
            self.local[r] = ns + i;
            self.stamp[r] = s;
        }
        let (local, stamp) = (&self.local, &self.stamp);
        // Only the lower triangle is read or written (the diagonal block's upper triangle
        // goes to the file: zeros, as faer leaves it).
        let front: &mut [f64] = bytemuck::cast_slice_mut(&mut self.front[..]);
        let front = front
            .get_mut(..m * m)
            .ok_or_else(|| bad(format!("supernode {s}'s front is larger than the plan's")))?;
        for j in 0..m {
            let from = if j < ns { j * m } else { j * m + j };
            front[from..(j + 1) * m].fill(0.0);
        }
        // K's entries of the supernode's columns (lower triangle, permuted).
        for j in 0..ns {
            let c = sh.fwd[b0 + j];
            for (&r_old, &v) in sh.k.row_idx_of_col_raw(c).iter().zip(sh.k.val_of_col(c)) {
                let r = sh.inv[r_old];
                if r < b0 + j {
                    continue;
                }
                if stamp[r] != s {
                    return Err(bad(format!(
                        "row {r} of K is outside the front of supernode {s}"
                    )));
                }
                front[j * m + local[r]] += v;
            }
        }
        // The children's updates, in the plan's order: the ones made here are on top of
        // the stack in that order.
        let ch = &sh.plan.children[s];
        let here = ch.iter().filter(|&&c| external[c].is_none()).count();
        let first = self.on_stack.len().checked_sub(here).ok_or_else(|| {
            bad(format!(
                "supernode {s}'s children were not factorised before it"
            ))
        })?;
        let mut next = first;
        for &c in ch {
            let cp = sym.supernode(c).pattern();
            let nc = cp.len();
            if cp.iter().any(|&r| stamp[r] != s) {
                return Err(bad(format!(
                    "supernode {c}'s rows are outside its parent {s}'s front"
                )));
            }
            let ext = external[c].take();
            let mut src: &[f64] = match &ext {
                Some(u) => u,
                None => {
                    let (sc, off) = self.on_stack[next];
                    next += 1;
                    if sc != c {
                        return Err(bad(format!(
                            "the update on the stack is supernode {sc}'s, not {c}'s"
                        )));
                    }
                    &self.stack[off..off + packed(nc)]
                }
            };
            for jj in 0..nc {
                let col = &mut front[local[cp[jj]] * m..][..m];
                let (seg, rest) = src.split_at(nc - jj);
                for (&r, &v) in cp[jj..].iter().zip(seg) {
                    col[local[r]] += v;
                }
                src = rest;
            }
        }
        if let Some(&(_, off)) = self.on_stack.get(first) {
            self.stack.truncate(off);
        }
        self.on_stack.truncate(first);
        let par = if (ns * m) as f64 * m as f64 > 1e7 {
            crate::threads::faer_par()
        } else {
            Par::Seq
        };
        let f = MatMut::from_column_major_slice_mut(front, m, m);
        let (f1, f2) = f.split_at_col_mut(ns);
        let (mut l11, mut l21) = f1.split_at_row_mut(ns);
        let singular = |index: usize| {
            let dof = sh.fwd[b0 + index];
            FemError::Singular {
                node: (sh.dof_owner)(dof),
                dof,
            }
        };
        let negative = sh.negative.get(b0..b0 + ns).filter(|n| n.contains(&true));
        // The diagonal block: G₁₁ G₁₁ᵀ, or for a mixed system's front L₁₁ D L₁₁ᵀ in the
        // signed form G₁₁ Σ G₁₁ᵀ.
        // The one numeric step, written once for both of faer's dense factorisations.
        macro_rules! numeric {
            ($kind:ident) => {
                |(scratch, l11)| {
                    use faer::linalg::cholesky::$kind::factor;
                    reserve(
                        scratch,
                        factor::cholesky_in_place_scratch::<f64>(ns, par, Default::default()),
                    );
                    factor::cholesky_in_place(
                        l11.rb_mut(),
                        Default::default(),
                        par,
                        faer::dyn_stack::MemStack::new(scratch),
                        Default::default(),
                    )?;
                    Ok(())
                }
            };
        }
        llt_else_ldlt(
            negative.is_some(),
            &mut (&mut self.scratch, l11.rb_mut()),
            numeric!(llt),
            numeric!(ldlt),
            singular,
        )?;
        if let Some(negative) = negative {
            for (j, &neg) in negative.iter().enumerate() {
                let col = l11.rb_mut().col_mut(j).try_as_col_major_mut();
                let col = col.ok_or_else(|| bad("a front column is not contiguous".into()))?;
                signed_column(col.as_slice_mut(), j, neg).map_err(|()| singular(j))?;
            }
        }
        // X = F₂₁ G₁₁⁻ᵀ; signed: G₂₁ = X Σ, and the update F₂₂ −= X Σ Xᵀ = G₂₁ Xᵀ.
        faer::linalg::triangular_solve::solve_lower_triangular_in_place(
            l11.rb(),
            l21.rb_mut().transpose_mut(),
            par,
        );
        if nb > 0 {
            let x = negative.map(|negative| {
                let x = l21.to_owned();
                for (j, _) in negative.iter().enumerate().filter(|(_, &n)| n) {
                    l21.rb_mut().col_mut(j).iter_mut().for_each(|v| *v = -*v);
                }
                x
            });
            let l21 = l21.rb();
            let rhs = x.as_ref().map_or(l21, |x| x.as_ref());
            faer::linalg::matmul::triangular::matmul(
                f2.subrows_mut(ns, nb),
                faer::linalg::matmul::triangular::BlockStructure::TriangularLower,
                Accum::Add,
                l21,
                faer::linalg::matmul::triangular::BlockStructure::Rectangular,
                rhs.transpose(),
                faer::linalg::matmul::triangular::BlockStructure::Rectangular,
                -1.0,
                par,
            );
        }
        let front: &[f64] = bytemuck::cast_slice(&self.front[..]);
        out.write(
            sym.col_ptr_for_val()[s],
            &front[..m * ns],
            &mut self.written,
        )?;
        if sh.plan.parent[s] != usize::MAX && nb > 0 {
            self.on_stack.push((s, self.stack.len()));
            for j in 0..nb {
                self.stack
                    .extend_from_slice(&front[(ns + j) * m + ns + j..(ns + j + 1) * m]);
            }
        }
        Ok(())
    }
}

/// Splits the supernodal tree into subtrees for `workers` threads (balanced by an estimate
/// of their flops, largest first to the least loaded) and the supernodes above them, which
/// are factorised afterwards with the dense work on all cores. Returns each worker's
/// subtree roots.
fn split(sh: &Shared<'_>, workers: usize) -> Vec<Vec<usize>> {
    let plan = sh.plan;
    let nsn = plan.parent.len();
    let mut cost = vec![0.0f64; nsn];
    for s in 0..nsn {
        let (ns, m) = (sh.ns(s) as f64, (sh.ns(s) + sh.nb(s)) as f64);
        cost[s] += ns * m * m + 4.0 * m * m;
        if plan.parent[s] != usize::MAX {
            let c = cost[s];
            cost[plan.parent[s]] += c;
        }
    }
    let total: f64 = (0..nsn)
        .filter(|&s| plan.parent[s] == usize::MAX)
        .map(|s| cost[s])
        .sum();
    let mut cand: Vec<usize> = (0..nsn).filter(|&s| plan.parent[s] == usize::MAX).collect();
    let assign = |cand: &[usize]| {
        let mut c = cand.to_vec();
        c.sort_by(|a, b| cost[*b].total_cmp(&cost[*a]).then(a.cmp(b)));
        let mut bins = vec![(0.0f64, Vec::new()); workers];
        for s in c {
            let b = (0..workers)
                .min_by(|&i, &j| bins[i].0.total_cmp(&bins[j].0).then(i.cmp(&j)))
                .unwrap_or(0);
            bins[b].0 += cost[s];
            bins[b].1.push(s);
        }
        bins
    };
    for _ in 0..4096 {
        let bins = assign(&cand);
        let (lo, hi) = bins.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), b| {
            (lo.min(b.0), hi.max(b.0))
        });
        // Balanced, or already most of the work above the subtrees: stop descending.
        let sum: f64 = bins.iter().map(|b| b.0).sum();
        if hi - lo <= 0.05 * sum || sum < 0.3 * total {
            break;
        }
        let Some(i) = (0..cand.len()).max_by(|&i, &j| cost[cand[i]].total_cmp(&cost[cand[j]]))
        else {
            break;
        };
        let h = cand.swap_remove(i);
        cand.extend(plan.children[h].iter().copied());
    }
    let mut out: Vec<Vec<usize>> = assign(&cand).into_iter().map(|b| b.1).collect();
    for roots in &mut out {
        roots.sort_unstable();
    }
    out
}

/// One column `j` of an `LDLᵀ` supernode (`col`: its rows from the diagonal block's top,
/// `d` on the diagonal, `L` below) in the signed form `G Σ Gᵀ`: `G = L·√|d|`, `σ = sign d`,
/// which must be negative exactly when `negative`. `Err` for a zero, non-finite or wrongly
/// signed pivot (the system is not quasi-definite: singular).
pub(crate) fn signed_column(col: &mut [f64], j: usize, negative: bool) -> Result<(), ()> {
    let d = col[j];
    if !d.is_finite() || d == 0.0 || (d < 0.0) != negative {
        return Err(());
    }
    let r = d.abs().sqrt();
    col[j] = r;
    for v in &mut col[j + 1..] {
        *v *= r;
    }
    Ok(())
}

/// Grows the dense kernels' `scratch` to `need`.
fn reserve(scratch: &mut faer::dyn_stack::MemBuffer, need: faer::dyn_stack::StackReq) {
    if scratch.len() < need.unaligned_bytes_required() + 64 {
        *scratch = faer::dyn_stack::MemBuffer::new(need);
    }
}

/// The elimination order of a factorisation: the permutation (`fwd`: new → old, `inv`:
/// old → new) and, per factor column, whether its pivot is negative (a mixed system's
/// pressures; empty for `K` itself).
#[derive(Clone, Copy)]
pub(crate) struct Elimination<'a> {
    /// New → old.
    pub fwd: &'a [usize],
    /// Old → new.
    pub inv: &'a [usize],
    /// Per factor column, a negative pivot.
    pub negative: &'a [bool],
}

/// Factorises `k` (free DOFs, both triangles, in the original order) with `sym`'s
/// structure and elimination `order` (signed pivots where it says) into `file`, which must
/// be empty and private to the caller, and returns its read-only map and the peak bytes of
/// the fronts and update stacks. `dof_owner` names the node of a DOF for the error of a
/// non-positive pivot. `workers` threads factorise disjoint subtrees first; the values do
/// not depend on how many.
pub(crate) fn factorize_to_file(
    sym: &SymbolicSupernodalCholesky<usize>,
    k: faer::sparse::SparseColMatRef<'_, usize, f64>,
    order: Elimination<'_>,
    file: &File,
    workers: usize,
    dof_owner: &(dyn Fn(usize) -> u32 + Sync),
) -> Result<(Values, usize), FemError> {
    let Elimination { fwd, inv, negative } = order;
    let io = |e: std::io::Error| FemError::Factorisation(format!("factor file: {e}"));
    let n = sym.nrows();
    let nsn = sym.n_supernodes();
    let plan = FrontPlan::new(sym);
    let vp = sym.col_ptr_for_val();
    file.set_len(8 * vp[nsn] as u64).map_err(io)?;
    let sh = Shared {
        sym,
        k,
        fwd,
        inv,
        plan: &plan,
        dof_owner,
        negative,
    };
    let workers = workers.max(1);
    let groups = if workers > 1 {
        split(&sh, workers)
    } else {
        Vec::new()
    };
    // Each supernode's place in the visiting order, and the size of its subtree (a
    // subtree is a contiguous run of the post-order ending at its root).
    let mut pos = vec![0usize; nsn];
    for (i, &s) in plan.order.iter().enumerate() {
        pos[s] = i;
    }
    let mut size = vec![1usize; nsn];
    for &s in &plan.order {
        if plan.parent[s] != usize::MAX {
            size[plan.parent[s]] += size[s];
        }
    }
    let mut in_sub = vec![false; nsn];
    let runs: Vec<Vec<&[usize]>> = groups
        .iter()
        .map(|roots| {
            roots
                .iter()
                .map(|&r| {
                    let run = &plan.order[pos[r] + 1 - size[r]..=pos[r]];
                    run.iter().for_each(|&s| in_sub[s] = true);
                    run
                })
                .collect()
        })
        .collect();
    let top: Vec<usize> = plan.order.iter().copied().filter(|&s| !in_sub[s]).collect();
    // SAFETY: the file is the caller's private temporary file, sized above; only the workers
    // below write it, each its own supernodes' values.
    let mut map = unsafe { memmap2::MmapOptions::new().map_mut(file) }.map_err(io)?;
    let out = Out {
        ptr: map.as_mut_ptr().cast::<f64>(),
        len: vp[nsn],
    };
    if map.len() < 8 * vp[nsn] || !(map.as_ptr() as usize).is_multiple_of(8) {
        return Err(FemError::Factorisation(
            "the factor file's map is short".into(),
        ));
    }
    let mut external: Vec<Option<Vec<f64>>> = vec![None; nsn];
    let mut peak = 0usize;
    let stop = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|sc| -> Result<(), FemError> {
        let (sh, out, stop) = (&sh, &out, &stop);
        // Subtrees, one thread per group; each returns its roots' updates.
        let mut sub_peak = 0usize;
        let handles: Vec<_> = runs
            .iter()
            .map(|runs| {
                let nodes: Vec<usize> = runs.iter().flat_map(|r| r.iter().copied()).collect();
                let (f, st) = sh.needs(&nodes, &|_| false);
                sub_peak += f + st;
                sc.spawn(move || -> Result<Vec<(usize, Vec<f64>)>, FemError> {
                    let mut w = Worker::new(n, f, st)?;
                    let mut none: Vec<Option<Vec<f64>>> = vec![None; nsn];
                    for &s in &nodes {
                        // Another worker's error (a negative pivot) ends this one's work.
                        if stop.load(std::sync::atomic::Ordering::Relaxed) {
                            return Ok(Vec::new());
                        }
                        w.visit(sh, s, &mut none, out).inspect_err(|_| {
                            stop.store(true, std::sync::atomic::Ordering::Relaxed)
                        })?;
                    }
                    if let Some(r) = w.written.rest() {
                        out.release(r);
                    }
                    Ok(w.on_stack
                        .iter()
                        .map(|&(s, off)| (s, w.stack[off..off + packed(sh.nb(s))].to_vec()))
                        .collect())
                })
            })
            .collect();
        let mut result = Ok(());
        for h in handles {
            match h.join() {
                Ok(Ok(ups)) => ups.into_iter().for_each(|(s, u)| external[s] = Some(u)),
                Ok(Err(e)) => result = result.and(Err(e)),
                Err(_) => {
                    result = result.and(Err(FemError::Factorisation(
                        "a factorisation thread panicked".into(),
                    )))
                }
            }
        }
        if result.is_ok() {
            let held: usize = external.iter().flatten().map(Vec::len).sum();
            let (f, st) = sh.needs(&top, &|c| in_sub[c]);
            peak = sub_peak.max(held + f + st);
            result = Worker::new(n, f, st).and_then(|mut w| {
                let r = top
                    .iter()
                    .try_for_each(|&s| w.visit(sh, s, &mut external, out));
                if let Some(r) = w.written.rest() {
                    out.release(r);
                }
                r
            });
        }
        result
    })?;
    out.release(0..vp[nsn]);
    let map = map.make_read_only().map_err(io)?;
    Ok((Values::Mapped(map), 8 * peak))
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    /// The visiting order is a post-order: every supernode once, each after its children,
    /// each subtree one contiguous run ending at its root (what the workers' runs rely on).
    #[cfg_attr(test, test)]
    pub(crate) fn the_plan_is_a_post_order_with_contiguous_subtrees() {
        let m = crate::mesh::mouse();
        let k = crate::fem::Stiffness::assemble(&m).expect("K");
        let f = k.factorize().expect("factor");
        let (sym, _) = f.supernodal().expect("supernodal");
        let plan = FrontPlan::new(sym);
        let nsn = sym.n_supernodes();
        assert!(nsn > 100, "{nsn} supernodes");
        let mut pos = vec![usize::MAX; nsn];
        for (i, &s) in plan.order.iter().enumerate() {
            assert_eq!(pos[s], usize::MAX, "supernode {s} twice");
            pos[s] = i;
        }
        assert!(pos.iter().all(|&p| p < nsn));
        let mut size = vec![1usize; nsn];
        for &s in &plan.order {
            if plan.parent[s] != usize::MAX {
                assert!(pos[plan.parent[s]] > pos[s]);
                size[plan.parent[s]] += size[s];
            }
        }
        for s in 0..nsn {
            // The run ending at `s` holds exactly `s`'s subtree.
            for &d in &plan.order[pos[s] + 1 - size[s]..pos[s]] {
                let mut a = d;
                while a != s {
                    a = plan.parent[a];
                    assert_ne!(a, usize::MAX, "{d} is not below {s}");
                }
            }
        }
    }
}
