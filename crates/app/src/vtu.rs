//! VTK XML UnstructuredGrid output (readable by ParaView and meshio): the tets with point arrays
//! `displacement` (m), `force` (N, the external nodal force applied), `contact_force` (N, the
//! contact force on the object at each node, zero elsewhere) and `fixed` (1 on clamped nodes), and cell arrays `young` (Pa), `poisson` and `region` (0 for the object's material,
//! k for its k-th region, in the order given). Points in metres.

use glam::DVec3;
use std::fmt::Write as _;
use std::path::Path;

use touchfem_core::mesh::Mesh;

/// Writes the mesh with its displacement, applied nodal forces and contact forces (one entry
/// per node each).
pub(crate) fn write_vtu(
    path: &Path,
    mesh: &Mesh,
    displacement: &[DVec3],
    force: &[DVec3],
    contact_force: &[DVec3],
) -> Result<(), crate::error::Error> {
    let n = mesh.nodes.len();
    if displacement.len() != n || force.len() != n || contact_force.len() != n {
        return Err(crate::error::Error::Input(format!(
            "vtu: {n} nodes but {} displacements, {} forces and {} contact forces",
            displacement.len(),
            force.len(),
            contact_force.len()
        )));
    }
    let mut s = String::with_capacity(200 * n + 64 * mesh.tets.len());
    s.push_str("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<UnstructuredGrid>\n");
    let _ = writeln!(
        s,
        "<Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{}\">",
        mesh.tets.len()
    );
    s.push_str(
        "<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n",
    );
    for p in &mesh.nodes {
        let _ = writeln!(s, "{:e} {:e} {:e}", p.x, p.y, p.z);
    }
    s.push_str("</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for t in &mesh.tets {
        let _ = writeln!(s, "{} {} {} {}", t[0], t[1], t[2], t[3]);
    }
    s.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for i in 0..mesh.tets.len() {
        let _ = writeln!(s, "{}", 4 * (i + 1));
    }
    s.push_str("</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for _ in 0..mesh.tets.len() {
        s.push_str("10\n");
    }
    s.push_str("</DataArray>\n</Cells>\n<PointData Vectors=\"displacement\">\n");
    for (name, v) in [
        ("displacement", displacement),
        ("force", force),
        ("contact_force", contact_force),
    ] {
        let _ = writeln!(
            s,
            "<DataArray type=\"Float64\" Name=\"{name}\" NumberOfComponents=\"3\" format=\"ascii\">"
        );
        for p in v {
            let _ = writeln!(s, "{:e} {:e} {:e}", p.x, p.y, p.z);
        }
        s.push_str("</DataArray>\n");
    }
    s.push_str("<DataArray type=\"Int32\" Name=\"fixed\" format=\"ascii\">\n");
    for &f in &mesh.fixed {
        s.push_str(if f { "1\n" } else { "0\n" });
    }
    s.push_str("</DataArray>\n</PointData>\n<CellData Scalars=\"young\">\n");
    s.push_str("<DataArray type=\"Float64\" Name=\"young\" format=\"ascii\">\n");
    for t in 0..mesh.tets.len() {
        let _ = writeln!(s, "{:e}", mesh.tet_material(t).young_pa);
    }
    s.push_str("</DataArray>\n<DataArray type=\"Float64\" Name=\"poisson\" format=\"ascii\">\n");
    for t in 0..mesh.tets.len() {
        let _ = writeln!(s, "{:e}", mesh.tet_material(t).poisson);
    }
    s.push_str("</DataArray>\n<DataArray type=\"Int32\" Name=\"region\" format=\"ascii\">\n");
    for k in mesh.tet_region_index() {
        let _ = writeln!(s, "{k}");
    }
    s.push_str("</DataArray>\n</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    std::fs::write(path, s).map_err(|source| crate::error::Error::Write {
        path: path.to_path_buf(),
        source,
    })
}
