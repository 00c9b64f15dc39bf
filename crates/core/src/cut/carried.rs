//! What a [`super::Cut`] carries from one cut to the next for its `V` (made in
//! [`super::carry`]).

use std::sync::Arc;

use nalgebra::DMatrix;

use crate::compliance::Compliance;

/// A matrix's entries, shared between the cut that made them and the correction that holds
/// them (no copy).
pub(super) type Shared = Arc<Vec<f64>>;

/// One cut's term of the capacitance: `S G Sᵀ`.
pub(super) struct Update {
    /// `S`, `rank × |T|` at the rank of its cut.
    pub(super) s: DMatrix<f64>,
    /// `G`, `|T| × |T|`.
    pub(super) g: DMatrix<f64>,
}

/// The multiply-adds a column of `V` costs to take in an update of `t` places at rank `r`
/// (`Sᵀ`, `G`, `S`: `2·r·t + t²`).
pub(super) fn update_cost(r: usize, t: usize) -> usize {
    2 * r * t + t * t
}

/// The last `U` and `V` made and the updates since.
#[derive(Default)]
pub(super) struct Carried {
    pub(super) pending: Vec<Update>,
    /// `Vᵀ` (`rank × 3·C`, column-major) of the compliance `L` it was made for, at `rank`.
    pub(super) v: Option<(Compliance, usize, Shared)>,
    /// `U` at the rows and, transposed, at the columns of the compliance it was read for,
    /// at `rank` ([`super::Cut::correction`]'s `rows` and `u_cols`).
    pub(super) u: Option<(Compliance, usize, Shared, Shared)>,
    /// The buffers of the last passes' `U` and `V`, kept to be written again once nothing
    /// else holds them (the bodies that read them were replaced): a pass then writes memory
    /// it has written before instead of fresh pages, and a thread that reads a body seldom frees
    /// tens of megabytes.
    pub(super) spare: Vec<Shared>,
    /// Cores where a helper thread makes part of a `V` of more multiply-adds than the number
    /// in their idle time (the haptic loop's; [`super::Cut::share_v_with`]).
    pub(super) helper: Option<(Arc<[usize]>, usize)>,
}

/// How many of the last buffers [`Carried::spare`] keeps (three a pass: `U` at the rows, at
/// the columns, and `V`).
const SPARE: usize = 9;

impl Carried {
    /// What the updates waiting for `V` cost a column at rank `r` ([`update_cost`]).
    pub(super) fn waiting(&self, r: usize) -> usize {
        (self.pending.iter())
            .map(|u| update_cost(r, u.g.nrows()))
            .sum()
    }

    /// An empty buffer with room for `len` entries: a spare one that nothing else holds and
    /// that is large enough where there is one, else a new one with a quarter more room (a
    /// cut's rank grows pass by pass; a spare too small is let go).
    pub(super) fn buffer(&mut self, len: usize) -> Vec<f64> {
        let mut k = 0;
        while k < self.spare.len() {
            if Arc::strong_count(&self.spare[k]) == 1 {
                if let Ok(mut v) = Arc::try_unwrap(self.spare.remove(k)) {
                    if v.capacity() >= len {
                        v.clear();
                        return v;
                    }
                }
                continue;
            }
            k += 1;
        }
        Vec::with_capacity(len + len / 4)
    }

    /// Shares `v`, keeping it among the spares.
    pub(super) fn share(&mut self, v: Vec<f64>) -> Shared {
        let v = Arc::new(v);
        if self.spare.len() >= SPARE {
            self.spare.remove(0);
        }
        self.spare.push(v.clone());
        v
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    /// A spare buffer is written again once nothing else holds it and it is large enough;
    /// one still held is not, one too small is let go, and at most [`SPARE`] are kept.
    #[cfg_attr(test, test)]
    pub(crate) fn a_spare_buffer_is_reused_only_when_free_and_large_enough() {
        let mut c = Carried::default();
        let a = c.share(vec![1.0; 100]);
        let at = a.as_ptr();
        // Held (by `a`): a new buffer, with a quarter more room.
        let b = c.buffer(48);
        assert_ne!(b.as_ptr(), at);
        assert!(b.is_empty() && b.capacity() >= 60, "{}", b.capacity());
        drop(a);
        // Free and large enough: the same memory, empty.
        let r = c.buffer(80);
        assert_eq!(r.as_ptr(), at);
        assert!(r.is_empty() && c.spare.is_empty());
        // Too small: let go, and a new one.
        drop(c.share(vec![0.0; 10]));
        let t = c.buffer(1000);
        assert!(t.capacity() >= 1250 && c.spare.is_empty());
        for _ in 0..2 * SPARE {
            drop(c.share(vec![0.0; 1]));
        }
        assert_eq!(c.spare.len(), SPARE);
    }
}
