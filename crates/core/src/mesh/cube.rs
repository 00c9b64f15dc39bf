//! The paper's cube (Table 1): 30 mm edge, 4×4×4 cells of five tets each, bottom face clamped.

use super::{Mesh, MeshError, RawMesh};
use crate::mesh::units::{LengthUnit, Material};
use std::collections::BTreeMap;

/// Edge length of the paper's cube, in millimetres.
pub const CUBE_EDGE_MM: f64 = 30.0;

/// The paper's cube: [0, 30 mm]³, 4×4×4 cells, 5 tets per cell, E = 10 kPa, ν = 0.49, the bottom
/// face z = 0 clamped (group `fixed`). 125 nodes, 98 surface nodes, 73 free, 192 triangles, 320 tets.
pub fn cube() -> Mesh {
    cube_with(
        [4, 4, 4],
        [CUBE_EDGE_MM; 3],
        Material {
            young_pa: 10_000.0,
            poisson: 0.49,
        },
    )
    .expect("the bundled cube is valid")
}

/// A box of `cells` cells spanning `[0, size_mm]` (millimetres), each cell cut into five tets with
/// alternating orientation so that neighbouring cells' face diagonals match. The bottom face
/// (z = 0) is the group `fixed` and is clamped.
pub fn cube_with(
    cells: [usize; 3],
    size_mm: [f64; 3],
    material: Material,
) -> Result<Mesh, MeshError> {
    let raw = grid_raw(cells, size_mm, |_, _, _| true);
    let mut mesh = Mesh::from_raw(raw, LengthUnit::Millimetre, material)?;
    mesh.set_fixed_group("fixed")?;
    Ok(mesh)
}

/// A structured grid of `cells` cells spanning `[0, size]` (any unit), five tets per cell with
/// alternating orientation, keeping only the cells for which `keep(i, j, k)` holds (nodes of
/// dropped cells are removed by validation). The nodes at z = 0 form the group `fixed`.
pub fn grid_raw(
    cells: [usize; 3],
    size: [f64; 3],
    keep: impl Fn(usize, usize, usize) -> bool,
) -> RawMesh {
    let [nx, ny, nz] = cells;
    let id = |i: usize, j: usize, k: usize| (k * (ny + 1) + j) * (nx + 1) + i;
    let mut nodes = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push([
                    size[0] * i as f64 / nx as f64,
                    size[1] * j as f64 / ny as f64,
                    size[2] * k as f64 / nz as f64,
                ]);
            }
        }
    }
    let mut tets = Vec::with_capacity(nx * ny * nz * 5);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                if !keep(i, j, k) {
                    continue;
                }
                // Corner c = (dx, dy, dz) of this cell.
                let c = |dx: usize, dy: usize, dz: usize| id(i + dx, j + dy, k + dz);
                if (i + j + k) % 2 == 0 {
                    // Central tet on the odd corners; one tet at each even corner.
                    tets.push([c(1, 0, 0), c(0, 1, 0), c(0, 0, 1), c(1, 1, 1)]);
                    tets.push([c(0, 0, 0), c(1, 0, 0), c(0, 1, 0), c(0, 0, 1)]);
                    tets.push([c(1, 1, 0), c(0, 1, 0), c(1, 0, 0), c(1, 1, 1)]);
                    tets.push([c(1, 0, 1), c(1, 0, 0), c(0, 0, 1), c(1, 1, 1)]);
                    tets.push([c(0, 1, 1), c(0, 0, 1), c(0, 1, 0), c(1, 1, 1)]);
                } else {
                    // Mirror image in x of the even cell (so the last two nodes are swapped to
                    // keep the orientation positive).
                    tets.push([c(0, 0, 0), c(1, 1, 0), c(0, 1, 1), c(1, 0, 1)]);
                    tets.push([c(1, 0, 0), c(0, 0, 0), c(1, 0, 1), c(1, 1, 0)]);
                    tets.push([c(0, 1, 0), c(1, 1, 0), c(0, 1, 1), c(0, 0, 0)]);
                    tets.push([c(0, 0, 1), c(0, 0, 0), c(0, 1, 1), c(1, 0, 1)]);
                    tets.push([c(1, 1, 1), c(1, 1, 0), c(1, 0, 1), c(0, 1, 1)]);
                }
            }
        }
    }
    let bottom: Vec<usize> = (0..=ny)
        .flat_map(|j| (0..=nx).map(move |i| (i, j)))
        .map(|(i, j)| id(i, j, 0))
        .collect();
    let mut node_groups = BTreeMap::new();
    node_groups.insert("fixed".to_string(), bottom);
    RawMesh {
        nodes,
        tets,
        node_groups,
        tet_groups: BTreeMap::new(),
    }
}

/// The Gmsh file of the bundled mouse (MSH 4.1, millimetres), made by `scripts/make_mouse.py`.
const MOUSE_MSH: &[u8] = include_bytes!("../../../../meshes/mouse.msh");

/// The paper's mouse (Table 1), remade with Gmsh: about 120 mm long along x, standing on z = 0
/// on four clamped pads (group `fixed`), E = 1000 Pa, ν = 0.3. 1699 nodes, 1169 surface nodes,
/// 1029 free surface nodes, 2334 surface triangles, 6139 tets (the paper: 1713, 1175, 1036,
/// 2346, 6312).
pub fn mouse() -> Mesh {
    let raw = super::io::parse_msh(MOUSE_MSH, std::path::Path::new("meshes/mouse.msh"))
        .expect("the bundled mouse parses");
    let mut m = Mesh::from_raw(raw, LengthUnit::Millimetre, Material::DEFAULT)
        .expect("the bundled mouse is valid");
    m.set_fixed_group("fixed").expect("the mouse has pads");
    m
}

/// The Gmsh file of the bundled palpation phantom (MSH 4.1 binary, millimetres), made by
/// `scripts/make_palpate.py`.
const PHANTOM_MSH: &[u8] = include_bytes!("../../../../meshes/phantom.msh");

/// The palpation phantom: a soft block [−30, 30] × [−20, 20] × [0, 20] mm standing on z = 0
/// (group `fixed`, clamped) with a ball of radius 5 mm centred on (0, 0, 12) mm, meshed
/// conformingly: physical volume groups `nodule` (the ball) and `tissue` (the rest). Every
/// tet has E = 3000 Pa, ν = 0.45 until regions say otherwise (the scene `palpate` makes the
/// nodule ten times stiffer).
pub fn phantom() -> Mesh {
    let raw = super::io::parse_msh(PHANTOM_MSH, std::path::Path::new("meshes/phantom.msh"))
        .expect("the bundled phantom parses");
    let material = Material {
        young_pa: 3000.0,
        poisson: 0.45,
    };
    let mut m = Mesh::from_raw(raw, LengthUnit::Millimetre, material)
        .expect("the bundled phantom is valid");
    m.set_fixed_group("fixed")
        .expect("the phantom has a bottom");
    m
}

/// Node coordinates from `0` to `len` with spacing `h` over the first `fine` and then growing
/// by `growth` a cell (the last cell stretched or merged to end exactly at `len`).
fn graded_axis(len: f64, fine: f64, h: f64, growth: f64) -> Vec<f64> {
    let mut xs = vec![0.0];
    let mut step = h;
    loop {
        let last = *xs.last().unwrap_or(&0.0);
        if last >= len - 1e-9 {
            break;
        }
        if last + 1e-9 >= fine {
            step *= growth;
        }
        let next = last + step;
        if next >= len - 0.5 * step {
            xs.push(len);
            break;
        }
        xs.push(next);
    }
    xs
}

/// A box `[0, size]` (millimetres) whose cells are `h_mm` wide within `fine_mm` of the middle
/// of its top face (in x and y, and down from the top in z) and grow by `growth` a cell
/// beyond: a block for contact studies, fine under the contact and coarse where nothing
/// happens. Five tets a cell as in [`cube_with`]; the bottom face z = 0 is the group `fixed`
/// and is clamped.
pub fn graded_block(
    size_mm: [f64; 3],
    fine_mm: f64,
    h_mm: f64,
    growth: f64,
    material: Material,
) -> Result<Mesh, MeshError> {
    let h = h_mm.max(1e-6);
    let g = growth.max(1.0);
    let half = |len: f64| {
        let right = graded_axis(0.5 * len, fine_mm, h, g);
        let mut axis: Vec<f64> = right.iter().rev().map(|v| 0.5 * len - v).collect();
        axis.extend(right.iter().skip(1).map(|v| 0.5 * len + v));
        axis
    };
    let xs = half(size_mm[0]);
    let ys = half(size_mm[1]);
    let zs: Vec<f64> = graded_axis(size_mm[2], fine_mm, h, g)
        .iter()
        .rev()
        .map(|v| size_mm[2] - v)
        .collect();
    let cells = [xs.len() - 1, ys.len() - 1, zs.len() - 1];
    let mut raw = grid_raw(cells, [1.0; 3], |_, _, _| true);
    let [nx, ny, _] = cells;
    for (k, &z) in zs.iter().enumerate() {
        for (j, &y) in ys.iter().enumerate() {
            for (i, &x) in xs.iter().enumerate() {
                raw.nodes[(k * (ny + 1) + j) * (nx + 1) + i] = [x, y, z];
            }
        }
    }
    let mut mesh = Mesh::from_raw(raw, LengthUnit::Millimetre, material)?;
    mesh.set_fixed_group("fixed")?;
    Ok(mesh)
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn cube_table1_counts_are_the_papers() {
        let m = cube();
        let t = m.table1();
        assert_eq!(t.nodes, 125);
        assert_eq!(t.surface_nodes, 98);
        assert_eq!(t.free_surface_nodes, 73);
        assert_eq!(t.surface_triangles, 192);
        assert_eq!(t.tets, 320);
        assert_eq!(t.young_pa, 10_000.0);
        assert_eq!(t.poisson, 0.49);
        assert!(m.report.is_clean(), "{:?}", m.report);
    }

    #[cfg_attr(test, test)]
    pub(crate) fn mouse_table1_counts_and_pads() {
        let m = mouse();
        let t = m.table1();
        assert_eq!(
            (
                t.nodes,
                t.surface_nodes,
                t.free_surface_nodes,
                t.surface_triangles,
                t.tets
            ),
            (1699, 1169, 1029, 2334, 6139)
        );
        assert_eq!((t.young_pa, t.poisson), (1000.0, 0.3));
        assert_eq!(m.fixed_count(), 140);
        // The pads stand on z = 0; the mouse is about 120 mm long along x.
        assert!(m
            .nodes
            .iter()
            .zip(&m.fixed)
            .all(|(p, &f)| !f || p.z.abs() < 1e-12));
        let (lo, hi) = m.bounds();
        assert!(lo.z.abs() < 1e-12 && (0.11..0.13).contains(&(hi.x - lo.x)));
        assert!(m.report.is_clean());
    }

    /// The phantom's groups: the nodule's tets fill the ball (volume within the mesh's chord
    /// error), tissue and nodule share no tet and cover the block.
    #[cfg_attr(test, test)]
    pub(crate) fn phantom_has_a_conforming_nodule() {
        let m = phantom();
        let vol = |ids: &[u32]| -> f64 {
            ids.iter()
                .map(|&t| {
                    let p = m.tets[t as usize].map(|i| m.nodes[i as usize]);
                    super::super::tet_volume(p[0], p[1], p[2], p[3])
                })
                .sum()
        };
        let nodule = &m.tet_groups["nodule"];
        let tissue = &m.tet_groups["tissue"];
        assert_eq!(nodule.len() + tissue.len(), m.tets.len());
        assert!(nodule.iter().all(|t| tissue.binary_search(t).is_err()));
        let ball = 4.0 / 3.0 * std::f64::consts::PI * 0.005f64.powi(3);
        let vn = vol(nodule);
        assert!((vn / ball - 1.0).abs() < 0.05, "{vn} vs {ball}");
        assert!((vn + vol(tissue) - 0.06 * 0.04 * 0.02).abs() < 1e-12);
        // Every nodule node is within the ball (to round-off).
        let c = glam::DVec3::new(0.0, 0.0, 0.012);
        for &t in nodule {
            for i in m.tets[t as usize] {
                assert!(m.nodes[i as usize].distance(c) <= 0.005 + 1e-9);
            }
        }
        assert!(m.fixed_count() > 0 && m.report.is_clean());
        assert_eq!((m.material.young_pa, m.material.poisson), (3000.0, 0.45));
    }

    #[cfg_attr(test, test)]
    pub(crate) fn cube_volume_is_exact() {
        let m = cube();
        let v: f64 = m
            .tets
            .iter()
            .map(|t| {
                let p = t.map(|i| m.nodes[i as usize]);
                super::super::tet_volume(p[0], p[1], p[2], p[3])
            })
            .sum();
        assert!((v - 0.03f64.powi(3)).abs() < 1e-15, "{v}");
    }
}
