//! Mesh builders shared by the integration tests.
#![allow(dead_code)]

use std::collections::BTreeMap;
use touchfem::{LengthUnit, Material, Mesh, RawMesh};

/// A structured grid of `cells` cells of size `h` (metres), five tets per kept cell, keeping the
/// cells for which `keep(i, j, k)` holds (unused nodes are dropped by validation).
pub fn grid_mesh(
    cells: [usize; 3],
    h: [f64; 3],
    material: Material,
    keep: impl Fn(usize, usize, usize) -> bool,
) -> Mesh {
    let [nx, ny, nz] = cells;
    let id = |i: usize, j: usize, k: usize| (k * (ny + 1) + j) * (nx + 1) + i;
    let mut nodes = Vec::new();
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push([i as f64 * h[0], j as f64 * h[1], k as f64 * h[2]]);
            }
        }
    }
    let mut tets = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                if !keep(i, j, k) {
                    continue;
                }
                let c = |dx: usize, dy: usize, dz: usize| id(i + dx, j + dy, k + dz);
                if (i + j + k) % 2 == 0 {
                    tets.push([c(1, 0, 0), c(0, 1, 0), c(0, 0, 1), c(1, 1, 1)]);
                    tets.push([c(0, 0, 0), c(1, 0, 0), c(0, 1, 0), c(0, 0, 1)]);
                    tets.push([c(1, 1, 0), c(0, 1, 0), c(1, 0, 0), c(1, 1, 1)]);
                    tets.push([c(1, 0, 1), c(1, 0, 0), c(0, 0, 1), c(1, 1, 1)]);
                    tets.push([c(0, 1, 1), c(0, 0, 1), c(0, 1, 0), c(1, 1, 1)]);
                } else {
                    tets.push([c(0, 0, 0), c(1, 1, 0), c(0, 1, 1), c(1, 0, 1)]);
                    tets.push([c(1, 0, 0), c(0, 0, 0), c(1, 0, 1), c(1, 1, 0)]);
                    tets.push([c(0, 1, 0), c(1, 1, 0), c(0, 1, 1), c(0, 0, 0)]);
                    tets.push([c(0, 0, 1), c(0, 0, 0), c(0, 1, 1), c(1, 0, 1)]);
                    tets.push([c(1, 1, 1), c(1, 1, 0), c(1, 0, 1), c(0, 1, 1)]);
                }
            }
        }
    }
    let raw = RawMesh {
        nodes,
        tets,
        node_groups: BTreeMap::new(),
    };
    Mesh::from_raw(raw, LengthUnit::Metre, material).expect("valid grid mesh")
}

/// A deterministic pseudo-random number in [0, 1) (SplitMix64).
pub fn rand01(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}
