//! The keys a cache file must match: what the mesh, material, selection (and, compressed, the
//! compression options) hash to.

use xxhash_rust::xxh3::Xxh3;

use crate::compliance::hmatrix::HOptions;
use crate::compliance::Selection;
use crate::mesh::Mesh;

/// Version of what [`key`] hashes (not of the file layout, which the header's version names):
/// scene hashes and recorded sessions include the key, so it changes only when the hashed
/// content does.
const KEY_VERSION: u32 = 1;

/// The hash that a cache file must match: mesh geometry and topology, material, regions (each
/// one's group, material and tets), clamp set and the row/column selection.
pub fn key(mesh: &Mesh, sel: &Selection) -> u64 {
    let mut h = Xxh3::new();
    h.update(&KEY_VERSION.to_le_bytes());
    for p in &mesh.nodes {
        for c in p.to_array() {
            h.update(&c.to_bits().to_le_bytes());
        }
    }
    for t in &mesh.tets {
        for i in t {
            h.update(&i.to_le_bytes());
        }
    }
    h.update(&mesh.material.young_pa.to_bits().to_le_bytes());
    h.update(&mesh.material.poisson.to_bits().to_le_bytes());
    // Regions (none: nothing hashed, so keys without regions are those of before).
    for r in &mesh.regions {
        h.update(b"|region|");
        h.update(r.group.as_bytes());
        h.update(&r.material.young_pa.to_bits().to_le_bytes());
        h.update(&r.material.poisson.to_bits().to_le_bytes());
        for t in &r.tets {
            h.update(&t.to_le_bytes());
        }
    }
    // Only a non-standard formulation is hashed, so standard files keep their keys.
    if mesh.formulation != crate::mesh::units::Formulation::Standard {
        h.update(b"formulation:");
        h.update(mesh.formulation.name().as_bytes());
        // Which element the locking-free formulation is: a file made with another (the
        // nodal average, or the MINI bubble before 2026-12-03's pressure projection) must
        // not be reused.
        if mesh.formulation == crate::mesh::units::Formulation::LockingFree {
            h.update(b":");
            h.update(
                crate::fem::locking_free::Smoothing::CHOSEN
                    .name()
                    .as_bytes(),
            );
        }
    }
    for &f in &mesh.fixed {
        h.update(&[f as u8]);
    }
    for set in [&sel.rows, &sel.cols] {
        h.update(b"|");
        for n in set.resolve(mesh) {
            h.update(&n.to_le_bytes());
        }
    }
    h.digest()
}

/// The key a file of this kind must match: [`key_hier`] with `compression`, else [`key`].
pub fn key_for(mesh: &Mesh, sel: &Selection, compression: Option<&HOptions>) -> u64 {
    match compression {
        Some(opts) => key_hier(mesh, sel, opts),
        None => key(mesh, sel),
    }
}

/// The key of a compressed (hierarchical) cache file: [`key`]'s content, a tag that keeps it
/// from ever equalling the dense key, and every compression option (tolerance, admissibility,
/// leaf and panel sizes), so that a file made with other options is stale.
pub fn key_hier(mesh: &Mesh, sel: &Selection, opts: &HOptions) -> u64 {
    let mut h = Xxh3::new();
    h.update(b"touchfem hierarchical compliance|");
    h.update(&key(mesh, sel).to_le_bytes());
    h.update(&opts.tolerance.to_bits().to_le_bytes());
    h.update(&opts.eta.to_bits().to_le_bytes());
    h.update(&(opts.leaf_size as u64).to_le_bytes());
    h.update(&(opts.panel_size as u64).to_le_bytes());
    h.digest()
}
