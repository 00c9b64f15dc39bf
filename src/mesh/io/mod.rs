//! Mesh file loaders: Gmsh MSH 4.1 and 2.2 (ASCII and binary), TetGen `.node`/`.ele`.
//! Each returns a [`RawMesh`] in the file's own length unit; [`Mesh::from_raw`](super::Mesh::from_raw)
//! validates it.

use super::{MeshError, RawMesh};
use std::path::Path;

/// Reads a mesh file, choosing the format by extension (`.msh`, `.node`, `.ele`).
pub fn read(path: &Path) -> Result<RawMesh, MeshError> {
    Err(MeshError::Parse {
        path: path.to_path_buf(),
        msg: "mesh file loading is not implemented yet".into(),
    })
}
