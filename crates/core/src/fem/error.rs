//! Why a stiffness cannot be built or factorised.

use thiserror::Error;

/// Errors from building or factorising the stiffness.
#[derive(Debug, Error)]
pub enum FemError {
    /// E or ν out of range.
    #[error("bad material: {0}")]
    BadMaterial(String),
    /// ν = 0.5 exactly: the bulk modulus is infinite, and a displacement-only `K` cannot hold
    /// it; the locking-free formulation's mixed system would lose the compressibility that
    /// makes its pressure block negative definite, which its factorisation without pivoting
    /// relies on, so both formulations refuse it.
    #[error(
        "Poisson's ratio 0.5 (exactly incompressible) has an infinite bulk modulus: no \
         displacement-only stiffness holds it; use 0.4999 with formulation \"locking-free\" \
         (the standard formulation locks there)"
    )]
    Incompressible,
    /// No node is clamped: the stiffness is singular (six rigid-body modes).
    #[error(
        "no node is fixed: the object can move freely and its stiffness is singular \
         (name a clamped node group with --fixed)"
    )]
    NoFixedNodes,
    /// A connected part of the mesh is not held by enough clamped nodes.
    #[error(
        "a part of the mesh ({part_nodes} nodes, including node {example_node}) is held by \
         {fixed_in_part} clamped node(s) {how}: it can move rigidly and its stiffness is singular"
    )]
    Unconstrained {
        /// Nodes in the floating part.
        part_nodes: usize,
        /// One node of that part.
        example_node: u32,
        /// Clamped nodes in that part.
        fixed_in_part: usize,
        /// "that are collinear", or "" when there are none.
        how: &'static str,
    },
    /// The factorisation met a non-positive pivot.
    #[error("the stiffness matrix is singular or indefinite at node {node} (DOF {dof})")]
    Singular {
        /// The node whose DOF failed.
        node: u32,
        /// The free DOF index.
        dof: usize,
    },
    /// faer reported an allocation or structural failure.
    #[error("sparse factorisation failed: {0}")]
    Factorisation(String),
    /// A touchable node is clamped, or a node index is out of range.
    #[error("bad node selection: {0}")]
    BadSelection(String),
}

impl From<crate::mesh::units::MaterialError> for FemError {
    fn from(e: crate::mesh::units::MaterialError) -> FemError {
        match e {
            crate::mesh::units::MaterialError::BadMaterial(m) => FemError::BadMaterial(m),
            crate::mesh::units::MaterialError::Incompressible => FemError::Incompressible,
        }
    }
}
