//! Gmsh MSH 4.1 (ASCII and binary) through the `mshio` crate, plus `$PhysicalNames`, which
//! mshio skips.
//!
//! mshio 0.4.2 notes: it keeps the node tags of a `$Nodes` section only when they are sparse
//! (`max − min ≥ count`); otherwise they are a permutation of `min..=max` that it drops. Gmsh
//! writes them in file order (it numbers nodes entity by entity, in the order it saves
//! them), but other writers need not: for such "dense" files we read the tags ourselves
//! ([`scan_node_tags`]). mshio panics on a few malformed inputs (a `$Nodes`/`$Elements` count of
//! 0, a binary data-size it has no parser for, an over-long data-size field): those are rejected
//! before the call, and the call runs under `catch_unwind` as a last line of defence, with the
//! panic message kept off stderr for this thread only ([`quietly`]).

use super::cursor::{self, Cursor, Endian};
use super::{find_physical_names, finish_groups, group_name, Groups, MshHeader};
use crate::mesh::{MeshError, RawMesh};
use mshio::{ElementType, MshFile};
use std::cell::Cell;
use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::sync::Once;

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

    let parsed =
        quietly(|| mshio::parse_msh_bytes(data).map_err(|e| describe(&e, data, header.binary)));
    let msh = match parsed {
        Ok(Ok(msh)) => msh,
        Ok(Err(msg)) => return Err(err(msg)),
        Err(_) => {
            return Err(err(
                "malformed MSH 4.1 file (the mshio parser panicked)".into()
            ))
        }
    };
    // mshio drops dense node tags; read them ourselves rather than assume their order.
    let dense = msh
        .data
        .nodes
        .as_ref()
        .is_some_and(|n| n.node_blocks.iter().all(|b| b.node_tags.is_none()));
    let file_tags = if dense {
        let tags = scan_node_tags(data, header);
        Some(tags.ok_or_else(|| err("cannot read the node tags of $Nodes".into()))?)
    } else {
        None
    };
    convert(msh, &names, file_tags).map_err(err)
}

thread_local! {
    /// Set while this thread runs mshio: its panics are caught and reported as errors.
    static QUIET: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` under `catch_unwind`, keeping a panic inside it off stderr. The panic hook is wrapped
/// once per process; the wrapper forwards every panic of other threads (and of this thread outside
/// `quietly`) to the hook that was installed before.
fn quietly<T>(f: impl FnOnce() -> T) -> std::thread::Result<T> {
    static WRAP: Once = Once::new();
    WRAP.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !QUIET.with(Cell::get) {
                previous(info);
            }
        }));
    });
    QUIET.with(|q| q.set(true));
    let r = catch_unwind(AssertUnwindSafe(f));
    QUIET.with(|q| q.set(false));
    r
}

/// Rejects `$Nodes` / `$Elements` sections that declare 0 entries (mshio computes `count − 1`).
fn precheck_counts(data: &[u8], header: &MshHeader) -> Result<(), String> {
    let endian = if header.binary {
        let e = binary_endian(data);
        Some(e.ok_or("binary MSH 4.1: the endianness check integer 1 is missing")?)
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
                data.get(body + size..body + 2 * size)
                    .and_then(|b| size_t(b, e))
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

/// A binary `size_t` of 1 to 8 bytes.
fn size_t(b: &[u8], e: Endian) -> Option<u64> {
    let mut v = [0u8; 8];
    match e {
        Endian::Little => {
            v.get_mut(..b.len())?.copy_from_slice(b);
            Some(u64::from_le_bytes(v))
        }
        Endian::Big => {
            v.get_mut(8usize.checked_sub(b.len())?..)?
                .copy_from_slice(b);
            Some(u64::from_be_bytes(v))
        }
    }
}

/// The byte order of a binary file, from the integer 1 that follows the format line.
fn binary_endian(data: &[u8]) -> Option<Endian> {
    let mut c = Cursor::new(data, Path::new(""));
    c.seek(cursor::find_line(data, b"$MeshFormat", 0)?);
    c.skip_line_end();
    c.skip_line_end();
    match c.bytes(4)? {
        b if b == 1i32.to_le_bytes() => Some(Endian::Little),
        b if b == 1i32.to_be_bytes() => Some(Endian::Big),
        _ => None,
    }
}

/// A one-line description of an mshio error: its innermost cause, its contexts, and where.
fn describe(e: &mshio::MshParserError<&[u8]>, data: &[u8], binary: bool) -> String {
    let bt = e.filtered_backtrace();
    let (at, kind) = match bt.first().or(e.backtrace.first()) {
        Some((input, kind)) => (
            Some(*input),
            match kind.context() {
                Some(ctx) => format!("invalid or missing {ctx}"),
                None => kind.to_string(),
            },
        ),
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
fn convert(
    msh: MshFile<u64, i32, f64>,
    names: &super::PhysicalNames,
    file_tags: Option<Vec<u64>>,
) -> Result<RawMesh, String> {
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
    // Tet sets of the physical volume groups: every named or used volume group, even if empty.
    let mut tet_groups = Groups::new();
    for &(dim, tag) in names.keys() {
        if dim == 3 {
            tet_groups.entry(group_name(names, 3, tag)).or_default();
        }
    }
    for (&(dim, _), tags) in &phys {
        if dim == 3 {
            for &p in tags {
                tet_groups.entry(group_name(names, 3, p)).or_default();
            }
        }
    }

    let mut nodes = Vec::new();
    let mut tag_index: HashMap<u64, usize> = HashMap::new();
    let mut next_tag = nodes_sec.min_node_tag;
    let mut first_tag = 0usize;
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
            None => match &file_tags {
                Some(all) => all
                    .get(first_tag..first_tag + len)
                    .ok_or("$Nodes: fewer node tags than nodes")?
                    .to_vec(),
                None => (0..len as u64)
                    .map(|k| next_tag.saturating_add(k))
                    .collect(),
            },
        };
        next_tag = next_tag.saturating_add(len as u64);
        first_tag += len;
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
        let first_tet = tets.len();
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
            if is_tet && block.entity_dim == 3 {
                tet_groups
                    .entry(group_name(names, 3, p))
                    .or_default()
                    .extend(first_tet..tets.len());
            }
        }
    }
    Ok(RawMesh {
        nodes,
        tets,
        node_groups: finish_groups(groups),
        tet_groups: finish_groups(tet_groups),
    })
}

/// The node tags of the first `$Nodes` section, in file order (mshio keeps them only when they
/// are sparse). Runs after mshio accepted the file, so the layout is known to be sound; `None`
/// if it is not after all.
fn scan_node_tags(data: &[u8], header: &MshHeader) -> Option<Vec<u64>> {
    let start = cursor::find_line(data, b"$Nodes", 0)?;
    let mut c = Cursor::new(data, Path::new(""));
    c.seek(start);
    c.skip_line_end();
    let mut tags = Vec::new();
    if header.binary {
        let e = binary_endian(data)?;
        let size = header.data_size;
        let next = |c: &mut Cursor| size_t(c.bytes(size)?, e);
        let blocks = next(&mut c)?;
        c.bytes(3 * size)?;
        for _ in 0..blocks {
            c.bytes(12)?; // entity dim, entity tag, parametric (0: mshio refuses 1)
            let n = usize::try_from(next(&mut c)?).ok()?;
            for _ in 0..n {
                tags.push(next(&mut c)?);
            }
            c.bytes(n.checked_mul(24)?)?;
        }
    } else {
        let mut tok = data[c.pos()..]
            .split(|b| b.is_ascii_whitespace())
            .filter(|t| !t.is_empty())
            .map(|t| std::str::from_utf8(t).ok()?.parse::<u64>().ok());
        let blocks = tok.next()??;
        for _ in 0..3 {
            tok.next()?;
        }
        for _ in 0..blocks {
            for _ in 0..3 {
                tok.next()?;
            }
            let n = usize::try_from(tok.next()??).ok()?;
            for _ in 0..n {
                tags.push(tok.next()??);
            }
            for _ in 0..n.checked_mul(3)? {
                tok.next()?;
            }
        }
    }
    Some(tags)
}
