//! Why a stiffness cannot be built or factorised.

use thiserror::Error;

/// Errors from building or factorising the stiffness.
#[derive(Debug, Error)]
pub enum FemError {
    /// A material that cannot be used: E or ν out of range, or ν = 0.5 exactly (the same
    /// error, and message, as the mesh's check gives).
    #[error(transparent)]
    Material(#[from] crate::mesh::units::MaterialError),
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
