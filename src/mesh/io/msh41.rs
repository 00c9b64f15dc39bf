//! Gmsh MSH 4.1 (ASCII and binary) through the `mshio` crate, plus `$PhysicalNames`, which
//! mshio skips.
//!
//! mshio 0.4.2 notes: it keeps the node tags of a `$Nodes` section only when they are sparse
//! (`max − min ≥ count`); otherwise the tags are `min_node_tag, min_node_tag + 1, …` in file
//! order, which is what Gmsh writes (it numbers nodes entity by entity, in the order it saves
//! them). mshio panics on a few malformed inputs (a `$Nodes`/`$Elements` count of 0, binary
//! data-sizes it has no parser for, numbers too long for their type): those are rejected before
//! the call, and the call runs under `catch_unwind` as a last line of defence.

use super::cursor::{self, Cursor, Endian};
use super::{find_physical_names, finish_groups, group_name, Groups, MshHeader};
use crate::mesh::{MeshError, RawMesh};
use mshio::{ElementType, MshFile};
use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

pub(super) fn parse(data: &[u8], path: &Path, header: &MshHeader) -> Result<RawMesh, MeshError> {
    let err = |msg: String| MeshError::Parse {
        path: path.to_path_buf(),
        msg,
    };
    if !matches!(header.data_size, 4 | 8) {
        return Err(err(format!(
            "line {}: unsupported data-size {} (size_t must be 4 or 8 bytes)",
            header.version_line, header.data_size
        )));
    }
    precheck_counts(data, header).map_err(err)?;
    let names = find_physical_names(data, path)?;

    let parsed = catch_unwind(AssertUnwindSafe(|| {
        mshio::parse_msh_bytes(data).map_err(|e| describe(&e, data, header.binary))
    }));
    let msh = match parsed {
        Ok(Ok(msh)) => msh,
        Ok(Err(msg)) => return Err(err(msg)),
        Err(_) => {
            return Err(err(
                "malformed MSH 4.1 file (the mshio parser panicked)".into()
            ))
        }
    };
    convert(msh, &names).map_err(err)
}

/// Rejects `$Nodes` / `$Elements` sections that declare 0 entries (mshio computes `count − 1`).
fn precheck_counts(data: &[u8], header: &MshHeader) -> Result<(), String> {
    let endian = if header.binary {
        // The endianness check integer follows the format line.
        let mut c = Cursor::new(data, Path::new(""));
        if let Some(fmt) = cursor::find_line(data, b"$MeshFormat", 0) {
            c.seek(fmt);
        }
        c.skip_line_end();
        c.skip_line_end();
        match c.bytes(4) {
            Some(b) if b == 1i32.to_le_bytes() => Some(Endian::Little),
            Some(b) if b == 1i32.to_be_bytes() => Some(Endian::Big),
            _ => return Err("binary MSH 4.1: the endianness check integer 1 is missing".into()),
        }
    } else {
        None
    };
    for section in ["$Nodes", "$Elements"] {
        let Some(start) = cursor::find_line(data, section.as_bytes(), 0) else {
            continue;
        };
        let body = match data[start..].iter().position(|&b| b == b'\n') {
            Some(i) => start + i + 1,
            None => continue,
        };
        let count = match endian {
            None => data[body..]
                .split(|b| b.is_ascii_whitespace())
                .filter(|t| !t.is_empty())
                .nth(1)
                .and_then(|t| std::str::from_utf8(t).ok())
                .and_then(|t| t.parse::<u64>().ok()),
            Some(e) => {
                let size = header.data_size;
                data.get(body + size..body + 2 * size).map(|b| {
                    let mut v = [0u8; 8];
                    match e {
                        Endian::Little => {
                            v[..size].copy_from_slice(b);
                            u64::from_le_bytes(v)
                        }
                        Endian::Big => {
                            v[8 - size..].copy_from_slice(b);
                            u64::from_be_bytes(v)
                        }
                    }
                })
            }
        };
        if count == Some(0) {
            return Err(format!(
                "{section} declares 0 entries (a mesh needs nodes and tetrahedra)"
            ));
        }
    }
    Ok(())
}

/// A one-line description of an mshio error: its innermost cause, its contexts, and where.
fn describe(e: &mshio::MshParserError<&[u8]>, data: &[u8], binary: bool) -> String {
    let bt = e.filtered_backtrace();
    let (at, kind) = match bt.first().or(e.backtrace.first()) {
        Some((input, kind)) => (Some(*input), kind.to_string()),
        None => (None, "unknown error".to_string()),
    };
    let contexts: Vec<String> = bt
        .iter()
        .skip(1)
        .rev()
        .map(|(_, k)| {
            k.context()
                .map(str::to_string)
                .unwrap_or_else(|| k.to_string())
        })
        .collect();
    let mut msg = String::new();
    if let Some(input) = at {
        let off = (input.as_ptr() as usize).wrapping_sub(data.as_ptr() as usize);
        if off <= data.len() {
            if binary {
                msg.push_str(&format!("byte offset {off}: "));
            } else {
                let line = 1 + data[..off].iter().filter(|&&b| b == b'\n').count();
                msg.push_str(&format!("line {line}: "));
            }
        }
    }
    msg.push_str(&kind);
    if !contexts.is_empty() {
        msg.push_str(&format!(" (in {})", contexts.join(" > ")));
    }
    msg
}

/// Builds the raw mesh: nodes in file order, linear tets, physical groups.
fn convert(msh: MshFile<u64, i32, f64>, names: &super::PhysicalNames) -> Result<RawMesh, String> {
    let nodes_sec = msh.data.nodes.ok_or("no $Nodes section")?;
    let elements = msh.data.elements.ok_or("no $Elements section")?;

    // Physical tags of each entity (dim, tag).
    let mut phys: HashMap<(i32, i32), Vec<i32>> = HashMap::new();
    if let Some(ent) = &msh.data.entities {
        for p in &ent.points {
            phys.insert((0, p.tag), p.physical_tags.clone());
        }
        for c in &ent.curves {
            phys.insert((1, c.tag), c.physical_tags.clone());
        }
        for s in &ent.surfaces {
            phys.insert((2, s.tag), s.physical_tags.clone());
        }
        for v in &ent.volumes {
            phys.insert((3, v.tag), v.physical_tags.clone());
        }
    }
    let mut groups = Groups::new();

    let mut nodes = Vec::new();
    let mut tag_index: HashMap<u64, usize> = HashMap::new();
    let mut next_tag = nodes_sec.min_node_tag;
    for (b, block) in nodes_sec.node_blocks.iter().enumerate() {
        let len = block.nodes.len();
        let tags: Vec<u64> = match &block.node_tags {
            Some(map) => {
                let mut tags = vec![0u64; len];
                let mut seen = vec![false; len];
                for (&tag, &i) in map {
                    if let (Some(t), Some(s)) = (tags.get_mut(i), seen.get_mut(i)) {
                        *t = tag;
                        *s = true;
                    }
                }
                if seen.iter().any(|s| !s) {
                    return Err(format!(
                        "$Nodes block {} (entity {} of dimension {}) repeats a node tag",
                        b + 1,
                        block.entity_tag,
                        block.entity_dim
                    ));
                }
                tags
            }
            None => (0..len as u64)
                .map(|k| next_tag.saturating_add(k))
                .collect(),
        };
        next_tag = next_tag.saturating_add(len as u64);
        let first = nodes.len();
        for (node, tag) in block.nodes.iter().zip(tags) {
            if tag_index.insert(tag, nodes.len()).is_some() {
                return Err(format!("$Nodes: node tag {tag} appears twice"));
            }
            nodes.push([node.x, node.y, node.z]);
        }
        if block.entity_dim == 0 {
            for &p in phys.get(&(0, block.entity_tag)).into_iter().flatten() {
                groups
                    .entry(group_name(names, 0, p))
                    .or_default()
                    .extend(first..nodes.len());
            }
        }
    }
    if nodes.len() as u64 != nodes_sec.num_nodes {
        return Err(format!(
            "$Nodes declares {} nodes but its blocks hold {}",
            nodes_sec.num_nodes,
            nodes.len()
        ));
    }

    let mut tets = Vec::new();
    for (b, block) in elements.element_blocks.iter().enumerate() {
        let key = (block.entity_dim, block.entity_tag);
        let block_phys = phys.get(&key).map(Vec::as_slice).unwrap_or(&[]);
        let is_tet = block.element_type == ElementType::Tet4;
        if !is_tet && block.entity_dim == 3 {
            return Err(format!(
                "$Elements block {} (volume {}): {}",
                b + 1,
                block.entity_tag,
                super::msh22::unsupported_3d(block.element_type as i32)
            ));
        }
        if !is_tet && block_phys.is_empty() {
            continue;
        }
        let mut group_nodes = Vec::new();
        for el in &block.elements {
            let mut idx = Vec::with_capacity(el.nodes.len());
            for &t in &el.nodes {
                idx.push(*tag_index.get(&t).ok_or_else(|| {
                    format!(
                        "element {} ($Elements block {}) references node {t}, which is not in \
                         $Nodes",
                        el.element_tag,
                        b + 1
                    )
                })?);
            }
            if is_tet {
                let t: [usize; 4] = idx
                    .as_slice()
                    .try_into()
                    .map_err(|_| format!("element {}: a tet needs 4 nodes", el.element_tag))?;
                tets.push(t);
            }
            group_nodes.extend(idx);
        }
        for &p in block_phys {
            groups
                .entry(group_name(names, block.entity_dim, p))
                .or_default()
                .extend_from_slice(&group_nodes);
        }
    }
    Ok(RawMesh {
        nodes,
        tets,
        node_groups: finish_groups(groups),
    })
}
