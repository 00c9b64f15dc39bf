//! Cutting without recomputing `L`. Every change a cut makes to `K` is local, and the
//! Sherman–Morrison–Woodbury identity (James & Pai's capacitance matrix) gives the new
//! compliance exactly from `L`'s columns at the changed DOFs `D`:
//!
//! `L′ = L + L_D (I − ΔK′ L_DD)⁻¹ ΔK′ L_Dᵀ`, with `ΔK′ = K₀ − K′` on `D`.
//!
//! `L_D` (every DOF's row, `D`'s columns, interior ones included) comes from solves with the
//! stiffness's factor, kept for that: a tet's 12 DOFs cost 12 solves, made up front for a
//! scene's cuttable region ([`Columns`], `Cut::precompute_columns`) or as the cut goes.
//! Nothing is recomputed.
//! A cut changes `K` in two ways, which share this machinery ([`Cut`]):
//! * **removal** ([`Cut::remove`]): tets go, their element stiffness subtracted (rank at most
//!   12 a tet);
//! * **separation** ([`Cut::split`], Nienhuys & van der Stappen's snap and split): the nodes
//!   next to a blade's swept quad ([`BladeQuad`]) are snapped onto it, the faces that then lie
//!   in it are cut, and each node on them gets a copy for every further side: the moved tets'
//!   couplings leave the node for its copy. The copies' DOFs join the system as
//!   `K₀ = blockdiag(K, S)` (`S` each copy's own diagonal, so `L₀ = blockdiag(L, S⁻¹)` is
//!   known), and the snapped tets' stiffness change, the moved couplings and `−S` are the local
//!   `ΔK′`. Slivers (tets the snapping flattens) are dropped and counted.
//!
//! Two kinds of DOF would make `K′` singular, and are handled before any solve:
//! * a node left with no tet is **pinned**: its DOFs keep a stiffness of their own diagonal
//!   in `K₀` and nothing else (so `L′` is exactly the inverse of the remaining tets' stiffness
//!   with that node removed); it does not move.
//! * a piece that nothing holds rigidly (cut right through, a flap hanging by nothing, or
//!   by an edge or a vertex alone) is **removed**: its tets join the cut and its nodes are
//!   pinned; the cut reports it.
//!
//! The standard formulation only (a locking-free mixed system's cut is not this rank).

mod blade;
pub(crate) mod body;
pub(crate) mod carried;
mod carry;
pub mod columns;
mod correct;
mod derive;
mod grown;
pub(crate) mod solved;
mod split;

pub use blade::{blade_tets, BladeQuad};
pub use body::{point_poke, point_poke_paper, tets_near, tets_near_keeping_nodes};
pub use body::{Cut, CutPoke, CutReport, Rebase};
pub use carry::V_SHARE_ABOVE;
pub use columns::Columns;
pub use split::{SplitReport, SLIVER_FRACTION};
