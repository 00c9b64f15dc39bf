//! Tetrahedral meshes: the validated [`Mesh`], its outward boundary surface, the clamped node set,
//! the bundled meshes and the file loaders.
//!
//! Loaders produce a [`RawMesh`] (coordinates in the file's unit, 0-based indices, named node
//! groups and, from Gmsh physical volumes, named tet groups); [`Mesh::from_raw`] validates it, converts it to metres, reorients inverted tets, drops
//! unused nodes and extracts the boundary. Every problem is a typed [`MeshError`] naming the tet or
//! node; nothing here panics on bad input.

pub(crate) mod cube;
pub mod io;
pub(crate) mod slit;
pub mod units;

pub use cube::{cube, cube_with, graded_block, grid_raw, mouse, phantom, CUBE_EDGE_MM};
pub use slit::slit_edges;

use glam::DVec3;
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use thiserror::Error;

use crate::mesh::units::{Formulation, LengthUnit, Material, MaterialError};

/// Errors found while reading or validating a mesh. Indices are 0-based, in the file's numbering.
#[derive(Debug, Error)]
pub enum MeshError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file is not a mesh in a format we read, or is malformed.
    #[error("{path}: {msg}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong, with a line or section where known.
        msg: String,
    },
    /// The mesh has no tetrahedra.
    #[error("the mesh has no tetrahedra")]
    NoTets,
    /// A coordinate is NaN or infinite.
    #[error("node {node} has a non-finite coordinate {coords:?}")]
    NonFinite {
        /// The node.
        node: usize,
        /// Its coordinates.
        coords: [f64; 3],
    },
    /// A tet references a node that does not exist.
    #[error("tet {tet} references node {index}, but the mesh has {nodes} nodes")]
    IndexOutOfRange {
        /// The tet.
        tet: usize,
        /// The bad index.
        index: usize,
        /// The number of nodes.
        nodes: usize,
    },
    /// A tet has (numerically) zero volume: repeated or coplanar nodes.
    #[error("tet {tet} {nodes:?} is degenerate (volume {volume:e} m³, quality {quality:e})")]
    Degenerate {
        /// The tet.
        tet: usize,
        /// Its nodes.
        nodes: [usize; 4],
        /// Its signed volume in m³.
        volume: f64,
        /// Its volume relative to the cube of its longest edge.
        quality: f64,
    },
    /// A face is shared by more than two tets, or a boundary edge by other than two boundary
    /// triangles: the boundary is not a 2-manifold.
    #[error("non-manifold boundary: {what}")]
    NonManifold {
        /// Which face or edge, with node indices.
        what: String,
    },
    /// A node group named on the command line is not in the file.
    #[error("no node group named '{name}' (the mesh has: {available})")]
    MissingGroup {
        /// The requested name.
        name: String,
        /// The groups the mesh does have, comma-separated.
        available: String,
    },
    /// A bundled mesh name that does not exist.
    #[error("unknown bundled mesh '{0}' (bundled: cube, mouse, phantom) and no such file")]
    UnknownBundled(String),
    /// A region names a group the mesh does not have at all.
    #[error("no physical volume group named '{name}' (volume groups: {available})")]
    NoVolumeGroup {
        /// The requested name.
        name: String,
        /// The volume groups the mesh does have, comma-separated.
        available: String,
    },
    /// A region names a group of points, curves or surfaces: it holds no tets.
    #[error(
        "'{name}' is a physical point, curve or surface group, not a physical volume group: a \
         region needs tets (volume groups: {available})"
    )]
    NotVolumeGroup {
        /// The requested name.
        name: String,
        /// The volume groups the mesh does have, comma-separated.
        available: String,
    },
    /// A region names a physical volume group that holds no tet.
    #[error("physical volume group '{name}' holds no tetrahedra")]
    EmptyVolumeGroup {
        /// The group.
        name: String,
    },
    /// Two regions share a tet (or name the same group twice).
    #[error("regions '{first}' and '{second}' overlap: tet {tet} is in both")]
    OverlappingRegions {
        /// The earlier region's group.
        first: String,
        /// The later region's group.
        second: String,
        /// A tet in both.
        tet: u32,
    },
    /// A region's material is out of range.
    #[error("region '{group}': {msg}")]
    BadRegionMaterial {
        /// The region's group.
        group: String,
        /// What is wrong.
        msg: String,
    },
}

/// A mesh as a loader read it: coordinates in the file's unit, 0-based node indices.
#[derive(Clone, Debug, Default)]
pub struct RawMesh {
    /// Node coordinates, in the file's length unit.
    pub nodes: Vec<[f64; 3]>,
    /// Tetrahedra as 0-based node indices (any orientation).
    pub tets: Vec<[usize; 4]>,
    /// Named node sets (Gmsh physical groups of any dimension, expanded to their nodes).
    pub node_groups: BTreeMap<String, Vec<usize>>,
    /// Named tet sets: each Gmsh physical volume group's tets, as 0-based indices into `tets`
    /// (a group declared in `$PhysicalNames` without elements is present and empty).
    pub tet_groups: BTreeMap<String, Vec<usize>>,
}

/// What validation changed, so that nothing is lost silently.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshReport {
    /// Tets (input indices) whose orientation was inverted and has been flipped.
    pub reoriented_tets: Vec<usize>,
    /// Nodes (input indices) used by no tet, dropped from the mesh.
    pub dropped_nodes: Vec<usize>,
}

impl MeshReport {
    /// True when validation changed nothing.
    pub fn is_clean(&self) -> bool {
        self.reoriented_tets.is_empty() && self.dropped_nodes.is_empty()
    }
}

/// A validated tetrahedral mesh in metres, with positively oriented tets, its outward boundary
/// surface and its clamped node set.
#[derive(Clone, Debug)]
pub struct Mesh {
    /// Node positions in metres.
    pub nodes: Vec<DVec3>,
    /// Tets, positively oriented: det[b−a, c−a, d−a] > 0.
    pub tets: Vec<[u32; 4]>,
    /// Boundary triangles, counter-clockwise seen from outside (normal points out).
    pub surface: Vec<[u32; 3]>,
    /// Nodes on the boundary, ascending.
    pub surface_nodes: Vec<u32>,
    /// Clamped (displacement zero) flag per node.
    pub fixed: Vec<bool>,
    /// Named node groups, renumbered to this mesh's nodes.
    pub groups: BTreeMap<String, Vec<u32>>,
    /// Named tet groups (Gmsh physical volumes): ascending indices into `tets`, which keep the
    /// file's tet order (validation reorients tets in place and drops none).
    pub tet_groups: BTreeMap<String, Vec<u32>>,
    /// The material (SI) of every tet outside [`Mesh::regions`].
    pub material: Material,
    /// Tets of another material, set by [`Mesh::set_regions`]; disjoint.
    pub regions: Vec<Region>,
    /// Per tet: 0 for [`Mesh::material`], k + 1 for `regions[k]` (empty: no regions).
    tet_region: Vec<u32>,
    /// How the stiffness discretises the volumetric strain (standard by default).
    pub formulation: Formulation,
    /// What validation changed.
    pub report: MeshReport,
}

/// The tets of one physical volume group, of their own material.
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    /// The physical volume group.
    pub group: String,
    /// Its material (SI).
    pub material: Material,
    /// Its tets, ascending indices into [`Mesh::tets`].
    pub tets: Vec<u32>,
}

/// Outward faces of a positively oriented tet, as local indices.
pub(crate) const TET_FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// Signed volume of the tet (a, b, c, d): det[b−a, c−a, d−a] / 6.
pub fn tet_volume(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    (b - a).cross(c - a).dot(d - a) / 6.0
}

/// The triangles around each vertex as a CSR list: the triangles of vertex `v` are
/// `list[start[v]..start[v + 1]]`, in triangle order. `n` is the vertex count; every index in
/// `tris` must be below it.
pub fn vertex_triangles(n: usize, tris: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let mut start = vec![0u32; n + 1];
    for t in tris {
        for &v in t {
            start[v as usize + 1] += 1;
        }
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut list = vec![0u32; 3 * tris.len()];
    for (ti, t) in tris.iter().enumerate() {
        for &v in t {
            list[fill[v as usize] as usize] = ti as u32;
            fill[v as usize] += 1;
        }
    }
    (start, list)
}

/// Marks the first entry of a chain in [`vertex_fans`].
pub const FAN_START: u32 = 1 << 31;

/// The triangles around each vertex as chains of its neighbours (triangle fans), for gathering
/// vertex normals with one position load per neighbour instead of two per triangle.
///
/// Returns `(ranges, list)`: vertex `v`'s entries are `list[first..first + count]` with
/// `[first, count] = ranges[v]`. Each entry is a neighbour index; an entry with [`FAN_START`]
/// set begins a chain. Consecutive entries `a, b` inside a chain stand for one triangle
/// `(v, a, b)`, counter-clockwise as in `tris`, and every triangle of `v` appears exactly once,
/// so `Σ cross(p_a − p_v, p_b − p_v)` over consecutive pairs is the area-weighted normal. A
/// closed (manifold) fan of k triangles is one chain of k + 1 entries that ends where it
/// began; open or non-manifold fans split into several chains. With `pad4`, every `first` is a
/// multiple of 4 (the padding between ranges is never part of one). Indices must be below `n`,
/// and `n` below `FAN_START`.
pub fn vertex_fans(n: usize, tris: &[[u32; 3]], pad4: bool) -> (Vec<[u32; 2]>, Vec<u32>) {
    let (start, list) = vertex_triangles(n, tris);
    let mut ranges = Vec::with_capacity(n);
    let mut out = Vec::with_capacity(4 * tris.len() + 4 * n);
    // Directed pairs (a, b) of the current vertex's triangles, and whether each is used.
    let mut pairs: Vec<(u32, u32)> = Vec::new();
    let mut used: Vec<bool> = Vec::new();
    for v in 0..n {
        if pad4 {
            out.resize(out.len().next_multiple_of(4), FAN_START);
        }
        let first = out.len() as u32;
        pairs.clear();
        for &t in &list[start[v] as usize..start[v + 1] as usize] {
            let tri = tris[t as usize];
            let k = tri.iter().position(|&i| i as usize == v).unwrap_or(0);
            pairs.push((tri[(k + 1) % 3], tri[(k + 2) % 3]));
        }
        used.clear();
        used.resize(pairs.len(), false);
        let mut left = pairs.len();
        while left > 0 {
            // Start an open chain where no pair ends in its first corner; else anywhere.
            let open = (0..pairs.len())
                .find(|&i| !used[i] && !pairs.iter().any(|&(_, b)| b == pairs[i].0));
            let mut i = open.unwrap_or_else(|| used.iter().position(|&u| !u).unwrap_or(0));
            out.push(FAN_START | pairs[i].0);
            loop {
                used[i] = true;
                left -= 1;
                let b = pairs[i].1;
                out.push(b);
                match (0..pairs.len()).find(|&j| !used[j] && pairs[j].0 == b) {
                    Some(j) => i = j,
                    None => break,
                }
            }
        }
        ranges.push([first, out.len() as u32 - first]);
    }
    (ranges, out)
}

/// Below this |6V| / (longest edge)³ a tet is degenerate (a regular tet has ≈ 0.118).
pub(crate) const DEGENERATE_QUALITY: f64 = 1e-8;

impl Mesh {
    /// The mean length of the tets' edges (each counted once per tet), in the mesh's unit.
    pub fn mean_edge(&self) -> f64 {
        let mut sum = 0.0;
        for t in &self.tets {
            for (a, b) in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)] {
                sum += self.nodes[t[a] as usize].distance(self.nodes[t[b] as usize]);
            }
        }
        sum / (6 * self.tets.len()).max(1) as f64
    }

    /// Validates a raw mesh: converts to metres, checks coordinates and indices, reorients
    /// inverted tets, rejects degenerate ones, drops unused nodes and extracts the boundary.
    /// No node is fixed yet: see [`Mesh::set_fixed_group`].
    pub fn from_raw(raw: RawMesh, unit: LengthUnit, material: Material) -> Result<Mesh, MeshError> {
        if raw.tets.is_empty() {
            return Err(MeshError::NoTets);
        }
        let n_in = raw.nodes.len();
        for (tet, t) in raw.tets.iter().enumerate() {
            for &i in t {
                if i >= n_in {
                    return Err(MeshError::IndexOutOfRange {
                        tet,
                        index: i,
                        nodes: n_in,
                    });
                }
            }
        }
        // Only nodes that tets use must be finite; unused ones are dropped anyway.
        let mut used = vec![false; n_in];
        for t in &raw.tets {
            for &i in t {
                used[i] = true;
            }
        }
        let s = unit.to_metres();
        for (node, p) in raw.nodes.iter().enumerate() {
            if used[node] && !p.iter().all(|c| c.is_finite()) {
                return Err(MeshError::NonFinite { node, coords: *p });
            }
        }
        let mut remap = vec![u32::MAX; n_in];
        let mut nodes = Vec::with_capacity(n_in);
        let mut report = MeshReport::default();
        for (i, p) in raw.nodes.iter().enumerate() {
            if used[i] {
                remap[i] = nodes.len() as u32;
                nodes.push(DVec3::new(p[0] * s, p[1] * s, p[2] * s));
            } else {
                report.dropped_nodes.push(i);
            }
        }
        let mut tets = Vec::with_capacity(raw.tets.len());
        for (tet, t) in raw.tets.iter().enumerate() {
            let p = t.map(|i| nodes[remap[i] as usize]);
            let vol = tet_volume(p[0], p[1], p[2], p[3]);
            let mut longest: f64 = 0.0;
            for a in 0..4 {
                for b in a + 1..4 {
                    longest = longest.max(p[a].distance(p[b]));
                }
            }
            let quality = if longest > 0.0 {
                6.0 * vol / longest.powi(3)
            } else {
                0.0
            };
            let distinct = (0..4).all(|a| (a + 1..4).all(|b| t[a] != t[b]));
            if !distinct || quality.is_nan() || quality.abs() <= DEGENERATE_QUALITY {
                return Err(MeshError::Degenerate {
                    tet,
                    nodes: *t,
                    volume: vol,
                    quality,
                });
            }
            let mut m = t.map(|i| remap[i]);
            if vol < 0.0 {
                m.swap(2, 3);
                report.reoriented_tets.push(tet);
            }
            tets.push(m);
        }
        let surface = boundary(&tets)?;
        let mut on_surface = vec![false; nodes.len()];
        for f in &surface {
            for &i in f {
                on_surface[i as usize] = true;
            }
        }
        let surface_nodes = (0..nodes.len() as u32)
            .filter(|&i| on_surface[i as usize])
            .collect();
        let groups = remap_groups(raw.node_groups, |i| {
            (i < n_in && remap[i] != u32::MAX).then(|| remap[i])
        });
        // Tets keep their index (reoriented in place, none dropped): only range and order.
        let n_tets = tets.len();
        let tet_groups = remap_groups(raw.tet_groups, |i| (i < n_tets).then_some(i as u32));
        Ok(Mesh {
            fixed: vec![false; nodes.len()],
            nodes,
            tets,
            surface,
            surface_nodes,
            groups,
            tet_groups,
            material,
            regions: Vec::new(),
            tet_region: Vec::new(),
            formulation: Formulation::Standard,
            report,
        })
    }

    /// The material of tet `t`: its region's, else [`Mesh::material`]. `t` must be below
    /// `tets.len()`.
    #[inline]
    pub fn tet_material(&self, t: usize) -> Material {
        match self.tet_region.get(t) {
            Some(&k) if k > 0 => self.regions[k as usize - 1].material,
            _ => self.material,
        }
    }

    /// This mesh without the tets `removed[t]` (a cut body, for output): the tets renumbered,
    /// regions and tet groups following them; nodes, surface and clamps as they are, except
    /// that a node left with no tet is not clamped.
    pub fn without_tets(&self, removed: &[bool]) -> Mesh {
        let mut new_index = vec![u32::MAX; self.tets.len()];
        let mut m = self.clone();
        m.tets.clear();
        m.tet_region.clear();
        for (t, tet) in self.tets.iter().enumerate() {
            if !removed.get(t).copied().unwrap_or(false) {
                new_index[t] = m.tets.len() as u32;
                m.tets.push(*tet);
                if let Some(&k) = self.tet_region.get(t) {
                    m.tet_region.push(k);
                }
            }
        }
        let remap = |v: &Vec<u32>| -> Vec<u32> {
            v.iter()
                .filter_map(|&t| {
                    new_index
                        .get(t as usize)
                        .copied()
                        .filter(|&i| i != u32::MAX)
                })
                .collect()
        };
        for r in &mut m.regions {
            r.tets = remap(&r.tets);
        }
        for g in m.tet_groups.values_mut() {
            *g = remap(g);
        }
        let mut has_tet = vec![false; m.nodes.len()];
        for t in &m.tets {
            for &v in t {
                has_tet[v as usize] = true;
            }
        }
        for (f, h) in m.fixed.iter_mut().zip(has_tet) {
            *f &= h;
        }
        m
    }

    /// The outward boundary triangles of the tets not `removed` (a cut body's surface, its
    /// cut faces included), sorted. Unlike a loaded mesh's, it is not checked to be a closed
    /// 2-manifold: a cut may leave two tets touching along an edge.
    pub fn open_surface(&self, removed: &[bool]) -> Vec<[u32; 3]> {
        open_surface_of(&self.tets, removed)
    }

    /// The region index of each tet: 0 for the base material, k + 1 for `regions[k]`.
    pub fn tet_region_index(&self) -> Vec<u32> {
        if self.tet_region.is_empty() {
            vec![0; self.tets.len()]
        } else {
            self.tet_region.clone()
        }
    }

    /// Gives the tets of each named physical volume group its material (replacing any previous
    /// regions; the other tets keep [`Mesh::material`]). Errors: a group the mesh lacks, a group
    /// of points, curves or surfaces, an empty volume group, two regions sharing a tet, a
    /// material with E ≤ 0, ν outside (−1, 0.5) or a non-finite value. On error the mesh is
    /// unchanged.
    pub fn set_regions(&mut self, specs: &[(String, Material)]) -> Result<(), MeshError> {
        let available = || {
            if self.tet_groups.is_empty() {
                "none".to_string()
            } else {
                self.tet_groups
                    .keys()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        };
        let mut tet_region = vec![0u32; self.tets.len()];
        let mut regions = Vec::with_capacity(specs.len());
        for (k, (group, material)) in specs.iter().enumerate() {
            let Some(tets) = self.tet_groups.get(group) else {
                let name = group.clone();
                return Err(if self.groups.contains_key(group) {
                    MeshError::NotVolumeGroup {
                        name,
                        available: available(),
                    }
                } else {
                    MeshError::NoVolumeGroup {
                        name,
                        available: available(),
                    }
                });
            };
            if tets.is_empty() {
                return Err(MeshError::EmptyVolumeGroup {
                    name: group.clone(),
                });
            }
            material
                .validate()
                .map_err(|e| MeshError::BadRegionMaterial {
                    group: group.clone(),
                    msg: match e {
                        MaterialError::BadMaterial(m) => m,
                        other => other.to_string(),
                    },
                })?;
            for &t in tets {
                let slot = &mut tet_region[t as usize];
                if *slot != 0 {
                    return Err(MeshError::OverlappingRegions {
                        first: specs[*slot as usize - 1].0.clone(),
                        second: group.clone(),
                        tet: t,
                    });
                }
                *slot = k as u32 + 1;
            }
            regions.push(Region {
                group: group.clone(),
                material: *material,
                tets: tets.clone(),
            });
        }
        if regions.is_empty() {
            tet_region.clear();
        }
        self.regions = regions;
        self.tet_region = tet_region;
        Ok(())
    }

    /// Checks the base material and every region's (see [`Material::validate`]).
    pub fn validate_materials(&self) -> Result<(), MaterialError> {
        self.material.validate()?;
        for r in &self.regions {
            // A region's bad material (ν = 0.5 included) names the region.
            r.material.validate().map_err(|e| match e {
                MaterialError::BadMaterial(m) => {
                    MaterialError::BadMaterial(format!("region '{}': {m}", r.group))
                }
                MaterialError::Incompressible => {
                    MaterialError::BadMaterial(format!("region '{}': {e}", r.group))
                }
            })?;
        }
        Ok(())
    }

    /// Clamps the nodes of the named group (replacing any previous fixed set).
    pub fn set_fixed_group(&mut self, name: &str) -> Result<(), MeshError> {
        let Some(ids) = self.groups.get(name) else {
            let available = if self.groups.is_empty() {
                "no groups".to_string()
            } else {
                self.groups.keys().cloned().collect::<Vec<_>>().join(", ")
            };
            return Err(MeshError::MissingGroup {
                name: name.to_string(),
                available,
            });
        };
        self.fixed = vec![false; self.nodes.len()];
        for &i in ids {
            self.fixed[i as usize] = true;
        }
        Ok(())
    }

    /// Clamps every node for which `pred(position)` holds (replacing any previous fixed set).
    pub fn set_fixed_where(&mut self, pred: impl Fn(DVec3) -> bool) {
        self.fixed = self.nodes.iter().map(|&p| pred(p)).collect();
    }

    /// Surface nodes that are not clamped: the nodes a finger can move.
    pub fn free_surface_nodes(&self) -> Vec<u32> {
        self.surface_nodes
            .iter()
            .copied()
            .filter(|&i| !self.fixed[i as usize])
            .collect()
    }

    /// Number of clamped nodes.
    pub fn fixed_count(&self) -> usize {
        self.fixed.iter().filter(|&&f| f).count()
    }

    /// Axis-aligned bounds (min, max) in metres.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for &p in &self.nodes {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        (lo, hi)
    }

    /// The paper's Table 1 row for this mesh.
    pub fn table1(&self) -> Table1 {
        Table1 {
            nodes: self.nodes.len(),
            surface_nodes: self.surface_nodes.len(),
            free_surface_nodes: self.free_surface_nodes().len(),
            surface_triangles: self.surface.len(),
            tets: self.tets.len(),
            young_pa: self.material.young_pa,
            poisson: self.material.poisson,
        }
    }
}

/// One row of the paper's Table 1 ("Specifications of models").
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Table1 {
    /// All nodes.
    pub nodes: usize,
    /// Nodes on the boundary surface.
    pub surface_nodes: usize,
    /// Boundary nodes that are not clamped.
    pub free_surface_nodes: usize,
    /// Boundary triangles ("surface patches").
    pub surface_triangles: usize,
    /// Tetrahedral elements.
    pub tets: usize,
    /// Young's modulus, Pa.
    pub young_pa: f64,
    /// Poisson's ratio.
    pub poisson: f64,
}

/// A file's groups with each id mapped through `map` (`None` drops it), sorted and without
/// repeats.
fn remap_groups(
    groups: BTreeMap<String, Vec<usize>>,
    map: impl Fn(usize) -> Option<u32>,
) -> BTreeMap<String, Vec<u32>> {
    groups
        .into_iter()
        .map(|(name, ids)| {
            let mut v: Vec<u32> = ids.into_iter().filter_map(&map).collect();
            v.sort_unstable();
            v.dedup();
            (name, v)
        })
        .collect()
}

/// [`Mesh::open_surface`] of bare `tets` (a cut body's, whose tets name copies of nodes).
pub fn open_surface_of(tets: &[[u32; 4]], removed: &[bool]) -> Vec<[u32; 3]> {
    let kept = (tets.iter().enumerate())
        .filter(|&(k, _)| !removed.get(k).copied().unwrap_or(false))
        .map(|(_, t)| t);
    single_faces(kept, tets.len()).0
}

/// The face of `t` opposite its node `k` ([`TET_FACES`]), sorted.
pub(crate) fn tet_face(t: [u32; 4], k: usize) -> [u32; 3] {
    let mut f = TET_FACES[k].map(|i| t[i]);
    f.sort_unstable();
    f
}

/// Per tet: the tet across each face (the face opposite each node), or `u32::MAX`.
pub(crate) fn face_neighbours(tets: &[[u32; 4]]) -> Vec<[u32; 4]> {
    let mut nbr = vec![[u32::MAX; 4]; tets.len()];
    let mut faces: HashMap<[u32; 3], (u32, u8)> = HashMap::with_capacity(2 * tets.len());
    for (ti, &t) in tets.iter().enumerate() {
        for k in 0..4 {
            match faces.entry(tet_face(t, k)) {
                std::collections::hash_map::Entry::Occupied(o) => {
                    let (tj, kj) = *o.get();
                    nbr[ti][k] = tj;
                    nbr[tj as usize][kj as usize] = ti as u32;
                }
                std::collections::hash_map::Entry::Vacant(v) => {
                    v.insert((ti as u32, k as u8));
                }
            }
        }
    }
    nbr
}

/// [`open_surface_of`] from the tets' face neighbours (`nbr[t][k]`: the tet across the face
/// opposite node `k` of tet `t`, [`TET_FACES`], or `u32::MAX`): the faces of the tets not
/// `removed` with no such tet across them, as their tets hold them, sorted. The same faces
/// in the same order, without matching every face (a cut keeps its tets' neighbours).
pub(crate) fn open_surface_from_neighbours(
    tets: &[[u32; 4]],
    nbr: &[[u32; 4]],
    removed: &[bool],
) -> Vec<[u32; 3]> {
    let gone = |t: usize| removed.get(t).copied().unwrap_or(false);
    let mut out = Vec::new();
    for (t, (tet, across)) in tets.iter().zip(nbr).enumerate() {
        if gone(t) {
            continue;
        }
        for (k, &o) in across.iter().enumerate() {
            if o == u32::MAX || gone(o as usize) {
                out.push(TET_FACES[k].map(|i| tet[i]));
            }
        }
    }
    out.sort_unstable();
    out
}

/// The faces that exactly one of `tets` (`n` of them at most) holds, as that tet holds them
/// (outward for a positively oriented tet), sorted; and the first face (its vertices sorted),
/// in the tets' order, that more than two tets hold.
fn single_faces<'a>(
    tets: impl Iterator<Item = &'a [u32; 4]>,
    n: usize,
) -> (Vec<[u32; 3]>, Option<[u32; 3]>) {
    let mut faces: HashMap<[u32; 3], (u32, [u32; 3])> = HashMap::with_capacity(n * 4);
    let mut shared = None;
    for t in tets {
        for lf in TET_FACES {
            let f = [t[lf[0]], t[lf[1]], t[lf[2]]];
            let mut key = f;
            key.sort_unstable();
            let e = faces.entry(key).or_insert((0, f));
            e.0 += 1;
            if e.0 > 2 && shared.is_none() {
                shared = Some(key);
            }
        }
    }
    let mut surface: Vec<[u32; 3]> = faces
        .into_values()
        .filter(|(c, _)| *c == 1)
        .map(|(_, f)| f)
        .collect();
    surface.sort_unstable();
    (surface, shared)
}

/// Extracts the outward boundary triangles of positively oriented tets and checks that the
/// boundary is a closed 2-manifold (every face in at most two tets, every boundary edge in
/// exactly two boundary triangles, used once in each direction).
fn boundary(tets: &[[u32; 4]]) -> Result<Vec<[u32; 3]>, MeshError> {
    let (surface, shared) = single_faces(tets.iter(), tets.len());
    if let Some(key) = shared {
        return Err(MeshError::NonManifold {
            what: format!("face {key:?} is shared by more than two tets"),
        });
    }
    let mut edges: HashMap<(u32, u32), i32> = HashMap::with_capacity(surface.len() * 2);
    for f in &surface {
        for k in 0..3 {
            *edges.entry((f[k], f[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    for (&(a, b), &n) in &edges {
        let back = edges.get(&(b, a)).copied().unwrap_or(0);
        if n != 1 || back != 1 {
            return Err(MeshError::NonManifold {
                what: format!(
                    "boundary edge ({a}, {b}) is used {n} time(s) one way and {back} the other \
                     (two tets touching along an edge, or a hole)"
                ),
            });
        }
    }
    Ok(surface)
}

/// Worst `6V/ℓ³` over the tets.
pub fn worst_quality(mesh: &Mesh) -> f64 {
    mesh.tets
        .iter()
        .map(|t| {
            let p = t.map(|i| mesh.nodes[i as usize]);
            let v = tet_volume(p[0], p[1], p[2], p[3]).abs();
            let mut l: f64 = 0.0;
            for a in 0..4 {
                for b in a + 1..4 {
                    l = l.max(p[a].distance(p[b]));
                }
            }
            6.0 * v / l.powi(3)
        })
        .fold(f64::INFINITY, f64::min)
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    fn one_tet() -> RawMesh {
        RawMesh {
            nodes: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ],
            tets: vec![[0, 1, 2, 3]],
            ..RawMesh::default()
        }
    }

    /// Area-weighted normals from the fans equal those summed over triangles, on a closed
    /// surface (one chain per vertex), an open strip and a non-manifold bow tie.
    #[cfg_attr(test, test)]
    pub(crate) fn fans_cover_every_triangle_once() {
        let cube = cube();
        // A jittered copy of the cube's nodes, so no two normals are trivially equal.
        let p: Vec<DVec3> = cube
            .nodes
            .iter()
            .enumerate()
            .map(|(i, q)| *q + DVec3::splat(1e-3 * ((i * 37 % 11) as f64)))
            .collect();
        let n = p.len();
        let strip: Vec<[u32; 3]> = vec![[0, 1, 2], [2, 1, 3], [2, 3, 4]];
        let bow: Vec<[u32; 3]> = vec![[0, 1, 2], [0, 3, 4]];
        let cases: [(&[[u32; 3]], usize); 3] = [(&cube.surface, 1), (&strip, 0), (&bow, 0)];
        for (tris, chains_each) in cases {
            for pad4 in [false, true] {
                let (ranges, list) = vertex_fans(n, tris, pad4);
                assert_eq!(ranges.len(), n);
                let mut by_tri = vec![DVec3::ZERO; n];
                for t in tris {
                    let [a, b, c] = t.map(|i| p[i as usize]);
                    let f = (b - a).cross(c - a);
                    for &v in t {
                        by_tri[v as usize] += f;
                    }
                }
                for v in 0..n {
                    let [first, count] = ranges[v];
                    if pad4 {
                        assert_eq!(first % 4, 0);
                    }
                    let e = &list[first as usize..(first + count) as usize];
                    let mut sum = DVec3::ZERO;
                    let mut prev = DVec3::ZERO;
                    let mut chains = 0;
                    for &x in e {
                        let q = p[(x & !FAN_START) as usize] - p[v];
                        if x & FAN_START != 0 {
                            chains += 1;
                        } else {
                            sum += prev.cross(q);
                        }
                        prev = q;
                    }
                    assert!((sum - by_tri[v]).length() <= 1e-15, "vertex {v}");
                    let incident = tris.iter().filter(|t| t.contains(&(v as u32))).count();
                    assert_eq!(count as usize, incident + chains, "vertex {v}");
                    if chains_each > 0 && incident > 0 {
                        assert_eq!(chains, chains_each, "closed fan at {v}");
                    }
                }
            }
        }
        // The bow tie's centre has two chains; the strip's corner vertex 1 one open chain.
        let (r, _) = vertex_fans(5, &bow, false);
        assert_eq!(r[0][1], 4);
        let (r, l) = vertex_fans(5, &strip, false);
        assert_eq!(
            &l[r[1][0] as usize..(r[1][0] + r[1][1]) as usize],
            &[3 | FAN_START, 2, 0]
        );
    }

    #[cfg_attr(test, test)]
    pub(crate) fn single_tet_surface_is_outward() {
        let m = Mesh::from_raw(one_tet(), LengthUnit::Metre, Material::DEFAULT).unwrap();
        assert_eq!(m.surface.len(), 4);
        let centroid = m.nodes.iter().copied().sum::<DVec3>() / 4.0;
        for f in &m.surface {
            let [a, b, c] = f.map(|i| m.nodes[i as usize]);
            let n = (b - a).cross(c - a);
            assert!(n.dot(a - centroid) > 0.0, "face {f:?} points inward");
        }
    }
}
