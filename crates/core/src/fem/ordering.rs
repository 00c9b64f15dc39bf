//! The fill-reducing orderings of the sparse factorisation: AMD, nested dissection by
//! coordinate bisection, METIS.

use glam::DVec3;

/// The fill-reducing ordering of the sparse Cholesky factorisation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Ordering {
    /// faer's approximate minimum degree.
    Amd,
    /// Nested dissection of the node graph by coordinate bisection (separators last), on
    /// 3-DOF node blocks: less fill than AMD on 3D meshes (see README, precompute).
    NestedDissection,
    /// METIS's multilevel nested dissection (`METIS_NodeND`) of the node graph, on 3-DOF
    /// node blocks: the least fill of the three (falls back to `NestedDissection` if METIS
    /// fails).
    #[default]
    Metis,
}

/// Without the `native` feature there is no METIS (a C library): `None`, so
/// [`Ordering::Metis`] takes its documented fallback, [`Ordering::NestedDissection`].
#[cfg(not(feature = "native"))]
pub(super) fn metis_order(_ptr: &[usize], _idx: &[usize]) -> Option<Vec<usize>> {
    None
}

/// METIS's fill-reducing order of the graph `ptr`/`idx` (new → old), `None` if METIS fails.
#[cfg(feature = "native")]
pub(super) fn metis_order(ptr: &[usize], idx: &[usize]) -> Option<Vec<usize>> {
    let n = ptr.len().checked_sub(1)?;
    if n == 0 {
        return Some(Vec::new());
    }
    let mut nv = i32::try_from(n).ok()?;
    let mut xadj: Vec<i32> = ptr
        .iter()
        .map(|&p| i32::try_from(p).ok())
        .collect::<Option<_>>()?;
    let mut adj: Vec<i32> = idx
        .iter()
        .map(|&p| i32::try_from(p).ok())
        .collect::<Option<_>>()?;
    let mut opts = [0i32; metis_sys::METIS_NOPTIONS as usize];
    let mut perm = vec![0i32; n];
    let mut iperm = vec![0i32; n];
    // METIS seeds one process-wide random generator at the start of each call: two calls at
    // once would share it and give orderings (and factors' bits) that depend on timing.
    static METIS: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one_at_a_time = METIS.lock().unwrap_or_else(|e| e.into_inner());
    // SAFETY: the arrays have the lengths METIS_NodeND requires (xadj n + 1, adjncy xadj[n],
    // options METIS_NOPTIONS, perm and iperm n); METIS only reads the inputs and writes the
    // outputs during the call.
    let rc = unsafe {
        metis_sys::METIS_SetDefaultOptions(opts.as_mut_ptr());
        metis_sys::METIS_NodeND(
            &mut nv,
            xadj.as_mut_ptr(),
            adj.as_mut_ptr(),
            std::ptr::null_mut(),
            opts.as_mut_ptr(),
            perm.as_mut_ptr(),
            iperm.as_mut_ptr(),
        )
    };
    if rc != metis_sys::rstatus_et_METIS_OK {
        return None;
    }
    let order: Vec<usize> = perm.iter().map(|&p| p as usize).collect();
    let mut seen = vec![false; n];
    for &o in &order {
        if o >= n || std::mem::replace(&mut seen[o], true) {
            return None;
        }
    }
    Some(order)
}

/// Leaves of the nested dissection hold at most this many nodes.
const ND_LEAF: usize = 96;

/// Nested dissection of the node graph `adj` (CSR: `ptr`, `idx`) by coordinate bisection:
/// the nodes are split at the median of the bounding box's longest axis, the nodes of the first
/// half that touch the second half form the separator, which is ordered after both halves.
/// Returns the nodes in elimination order.
pub(super) fn nested_dissection(coords: &[DVec3], ptr: &[usize], idx: &[usize]) -> Vec<usize> {
    fn rec(
        nodes: &mut [usize],
        coords: &[DVec3],
        ptr: &[usize],
        idx: &[usize],
        side: &mut [u8],
        order: &mut Vec<usize>,
    ) {
        if nodes.len() <= ND_LEAF {
            order.extend_from_slice(nodes);
            return;
        }
        // Try a median cut across each axis; keep the one with the smallest separator.
        let mid = nodes.len() / 2;
        let mut best: Option<(usize, usize)> = None; // (separator size, axis)
        for ax in 0..3 {
            split(nodes, coords, ax, mid);
            let sep = separator(nodes, mid, ptr, idx, side).len();
            if best.is_none_or(|(s, _)| sep < s) {
                best = Some((sep, ax));
            }
        }
        let ax = best.map_or(0, |b| b.1);
        split(nodes, coords, ax, mid);
        let sep = separator(nodes, mid, ptr, idx, side);
        for &i in sep.iter() {
            side[i] = 3;
        }
        let mut a: Vec<usize> = nodes[..mid]
            .iter()
            .copied()
            .filter(|&i| side[i] != 3)
            .collect();
        for &i in sep.iter() {
            side[i] = 0;
        }
        let mut b = nodes[mid..].to_vec();
        rec(&mut a, coords, ptr, idx, side, order);
        rec(&mut b, coords, ptr, idx, side, order);
        order.extend_from_slice(&sep);
    }
    /// Puts the nodes below the median of axis `ax` first.
    fn split(nodes: &mut [usize], coords: &[DVec3], ax: usize, mid: usize) {
        nodes.select_nth_unstable_by(mid, |&a, &b| {
            coords[a][ax]
                .partial_cmp(&coords[b][ax])
                .unwrap_or(std::cmp::Ordering::Equal)
                .then(a.cmp(&b))
        });
    }
    /// The nodes of `nodes[..mid]` with a neighbour in `nodes[mid..]`.
    fn separator(
        nodes: &[usize],
        mid: usize,
        ptr: &[usize],
        idx: &[usize],
        side: &mut [u8],
    ) -> Vec<usize> {
        for &i in &nodes[mid..] {
            side[i] = 2;
        }
        let sep = nodes[..mid]
            .iter()
            .copied()
            .filter(|&i| idx[ptr[i]..ptr[i + 1]].iter().any(|&j| side[j] == 2))
            .collect();
        for &i in &nodes[mid..] {
            side[i] = 0;
        }
        sep
    }
    let n = coords.len();
    let mut nodes: Vec<usize> = (0..n).collect();
    let mut side = vec![0u8; n];
    let mut order = Vec::with_capacity(n);
    rec(&mut nodes, coords, ptr, idx, &mut side, &mut order);
    order
}
