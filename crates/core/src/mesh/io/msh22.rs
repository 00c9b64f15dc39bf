//! Gmsh MSH 2.x (2.0–2.2), ASCII and binary, written from the format description in the Gmsh
//! manual (mshio reads 4.1 only).
//!
//! Sections read: `$MeshFormat`, `$PhysicalNames`, `$Nodes`, `$Elements`; any other `$Section`
//! is skipped up to its `$EndSection`. Element physical group = the element's first tag (0 = none).

use super::cursor::{self, Cursor, Endian};
use super::{finish_groups, group_name, parse_physical_names, Groups, PhysicalNames};
use crate::mesh::{MeshError, RawMesh};
use std::collections::HashMap;
use std::path::Path;

/// (number of nodes, dimension) of the element types of MSH 2.2 (types 1–31, 92, 93).
fn element_info(ty: i32) -> Option<(usize, i32)> {
    Some(match ty {
        1 => (2, 1),
        2 => (3, 2),
        3 => (4, 2),
        4 => (4, 3),
        5 => (8, 3),
        6 => (6, 3),
        7 => (5, 3),
        8 => (3, 1),
        9 => (6, 2),
        10 => (9, 2),
        11 => (10, 3),
        12 => (27, 3),
        13 => (18, 3),
        14 => (14, 3),
        15 => (1, 0),
        16 => (8, 2),
        17 => (20, 3),
        18 => (15, 3),
        19 => (13, 3),
        20 => (9, 2),
        21 => (10, 2),
        22 => (12, 2),
        23 => (15, 2),
        24 => (15, 2),
        25 => (21, 2),
        26 => (4, 1),
        27 => (5, 1),
        28 => (6, 1),
        29 => (20, 3),
        30 => (35, 3),
        31 => (56, 3),
        92 => (64, 3),
        93 => (125, 3),
        _ => return None,
    })
}

/// Why a 3-D element other than a linear tet is refused.
pub(super) fn unsupported_3d(ty: i32) -> String {
    let what = match ty {
        11 | 29 | 30 | 31 => "higher-order tetrahedra",
        5 | 12 | 17 | 92 | 93 => "hexahedra",
        6 | 13 | 18 => "prisms",
        _ => "pyramids",
    };
    format!(
        "element type {ty} ({what}): only linear 4-node tetrahedra (type 4) are supported; \
         re-mesh with Mesh.ElementOrder = 1 and tetrahedra only"
    )
}

/// A tet as read: its element tag, where it was (for errors), its node tags and its physical
/// group (0: none).
struct RawTet {
    tag: u64,
    pos: usize,
    nodes: [u64; 4],
    phys: i32,
}

/// Node coordinates in file order and the index of each node tag.
type NodeTable = (Vec<[f64; 3]>, HashMap<u64, usize>);

/// Everything read so far; node tags are resolved once all sections are read.
#[derive(Default)]
struct Sections {
    names: PhysicalNames,
    nodes: Option<NodeTable>,
    tets: Option<Vec<RawTet>>,
    /// (dimension, physical tag) → node tags of its elements.
    groups: HashMap<(i32, i32), Vec<u64>>,
}

pub(super) fn parse(data: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    let mut c = Cursor::new(data, path);
    // $MeshFormat (the dispatcher has checked the first line and the version).
    c.expect_text_line("$MeshFormat")?;
    let (pos, line) = c.expect_text_line("the MSH format line")?;
    let mut tok = line.split_ascii_whitespace().skip(1);
    let file_type: u8 = cursor::parse_num(tok.next(), "file-type").map_err(|m| c.err(pos, m))?;
    let data_size: usize = cursor::parse_num(tok.next(), "data-size").map_err(|m| c.err(pos, m))?;
    let endian = if file_type == 1 {
        if data_size != 8 {
            return Err(c.err(
                pos,
                format!("binary MSH 2 needs data-size 8 (doubles), found {data_size}"),
            ));
        }
        let at = c.pos();
        let e = match c.bytes(4) {
            Some(b) if b == 1i32.to_le_bytes() => Endian::Little,
            Some(b) if b == 1i32.to_be_bytes() => Endian::Big,
            Some(_) => {
                return Err(c.err_bin(
                    at,
                    "binary endianness check: expected the integer 1 after the format line",
                ))
            }
            None => return Err(c.err_bin(at, "unexpected end of file in $MeshFormat")),
        };
        c.skip_line_end();
        Some(e)
    } else {
        None
    };
    expect_end(&mut c, "$EndMeshFormat")?;

    let mut s = Sections::default();
    while let Some((pos, line)) = c.text_line()? {
        let Some(name) = line.strip_prefix('$') else {
            return Err(c.err(
                pos,
                format!(
                    "expected a section header such as $Nodes, found '{}'",
                    cursor::shorten(line)
                ),
            ));
        };
        match name {
            "PhysicalNames" => s.names = parse_physical_names(&mut c)?,
            "Nodes" if s.nodes.is_some() => {
                return Err(c.err(pos, "a second $Nodes section (only one is supported)"))
            }
            "Elements" if s.tets.is_some() => {
                return Err(c.err(pos, "a second $Elements section (only one is supported)"))
            }
            "Nodes" => s.nodes = Some(read_nodes(&mut c, endian)?),
            "Elements" => s.tets = Some(read_elements(&mut c, endian, &mut s.groups)?),
            _ => skip_section(&mut c, pos, name)?,
        }
    }
    let (nodes, tag_index) = s.nodes.ok_or_else(|| c.err(0, "no $Nodes section"))?;
    let raw_tets = s.tets.ok_or_else(|| c.err(0, "no $Elements section"))?;
    let resolve = |t: u64| tag_index.get(&t).copied();
    let mut tets = Vec::with_capacity(raw_tets.len());
    // Tet sets of the physical volume groups: every named or used volume group, even if empty.
    let mut tet_groups = Groups::new();
    for &(dim, phys) in s.names.keys() {
        if dim == 3 {
            tet_groups.entry(group_name(&s.names, 3, phys)).or_default();
        }
    }
    for t in &raw_tets {
        if t.phys != 0 {
            tet_groups
                .entry(group_name(&s.names, 3, t.phys))
                .or_default()
                .push(tets.len());
        }
        let mut idx = [0usize; 4];
        for (k, &n) in t.nodes.iter().enumerate() {
            idx[k] = resolve(n).ok_or_else(|| {
                located(
                    &c,
                    endian,
                    t.pos,
                    format!(
                        "tetrahedron {} references node {n}, which is not in $Nodes",
                        t.tag
                    ),
                )
            })?;
        }
        tets.push(idx);
    }
    let mut groups = Groups::new();
    let mut keys: Vec<_> = s.groups.keys().copied().collect();
    keys.sort_unstable();
    for (dim, phys) in keys {
        let name = group_name(&s.names, dim, phys);
        let out = groups.entry(name.clone()).or_default();
        for &n in &s.groups[&(dim, phys)] {
            out.push(resolve(n).ok_or_else(|| {
                c.err(
                    0,
                    format!(
                        "an element of physical group '{name}' references node {n}, \
                         which is not in $Nodes"
                    ),
                )
            })?);
        }
    }
    Ok(RawMesh {
        nodes,
        tets,
        node_groups: finish_groups(groups),
        tet_groups: finish_groups(tet_groups),
    })
}

/// An error at `pos`: a line number in ASCII files, a byte offset in binary ones.
fn located(c: &Cursor, endian: Option<Endian>, pos: usize, msg: String) -> MeshError {
    match endian {
        None => c.err(pos, msg),
        Some(_) => c.err_bin(pos, msg),
    }
}

/// Reads a count line (`what` names it) of a section.
fn count_line(c: &mut Cursor, what: &str) -> Result<usize, MeshError> {
    let (pos, line) = c.expect_text_line(what)?;
    cursor::parse_single(line, what).map_err(|m| c.err(pos, m))
}

/// `$Nodes` body: `n`, then `n` × (`tag x y z` lines | binary i32 tag + 3 f64), `$EndNodes`.
fn read_nodes(c: &mut Cursor, endian: Option<Endian>) -> Result<NodeTable, MeshError> {
    let n = count_line(c, "the number of nodes in $Nodes")?;
    // Never trust a count for allocation: each node takes at least 8 bytes (ASCII) or 28.
    let cap = n.min(c.remaining() / 8);
    let mut nodes = Vec::with_capacity(cap);
    let mut tag_index = HashMap::with_capacity(cap);
    for i in 0..n {
        let (pos, tag, xyz) = match endian {
            None => {
                let (pos, line) = c.text_line()?.ok_or_else(|| {
                    c.err(
                        usize::MAX,
                        format!("unexpected end of file in $Nodes after {i} of {n} nodes"),
                    )
                })?;
                if line.starts_with('$') {
                    return Err(c.err(pos, format!("$Nodes declares {n} nodes but holds {i}")));
                }
                let e = |m: String| c.err(pos, format!("node {}: {m}", i + 1));
                let mut tok = line.split_ascii_whitespace();
                let tag: u64 = cursor::parse_num(tok.next(), "node tag").map_err(e)?;
                let mut xyz = [0.0; 3];
                for (k, v) in xyz.iter_mut().enumerate() {
                    *v = cursor::parse_num(tok.next(), ["x", "y", "z"][k]).map_err(e)?;
                }
                if let Some(t) = tok.next() {
                    return Err(e(format!(
                        "unexpected '{}' after the coordinates",
                        cursor::shorten(t)
                    )));
                }
                (pos, tag, xyz)
            }
            Some(en) => {
                let pos = c.pos();
                let trunc = |c: &Cursor| {
                    c.err_bin(
                        pos,
                        format!("binary $Nodes ends after {i} of {n} nodes (truncated file?)"),
                    )
                };
                let tag = c.i32(en).ok_or_else(|| trunc(c))?;
                let mut xyz = [0.0; 3];
                for v in &mut xyz {
                    *v = c.f64(en).ok_or_else(|| trunc(c))?;
                }
                let tag = u64::try_from(tag)
                    .map_err(|_| c.err_bin(pos, format!("node {}: negative tag {tag}", i + 1)))?;
                (pos, tag, xyz)
            }
        };
        if tag_index.insert(tag, nodes.len()).is_some() {
            return Err(located(
                c,
                endian,
                pos,
                format!("node tag {tag} appears twice"),
            ));
        }
        nodes.push(xyz);
    }
    if endian.is_some() {
        c.skip_line_end();
    }
    expect_end(c, "$EndNodes")?;
    Ok((nodes, tag_index))
}

/// `$Elements` body. ASCII: `n`, then lines `tag type ntags tags… nodes…`. Binary: `n`, then
/// blocks of i32 `type count ntags` followed by `count` × i32 (`tag`, `ntags` tags, nodes).
/// Returns the tets; adds the node tags of elements with a physical tag to `groups`.
fn read_elements(
    c: &mut Cursor,
    endian: Option<Endian>,
    groups: &mut HashMap<(i32, i32), Vec<u64>>,
) -> Result<Vec<RawTet>, MeshError> {
    let n = count_line(c, "the number of elements in $Elements")?;
    let mut tets = Vec::new();
    let mut take = |pos: usize, tag: u64, ty: i32, phys: i32, nodes: &[u64]| {
        let Some((_, dim)) = element_info(ty) else {
            return Err(format!("element {tag}: unknown element type {ty}"));
        };
        if ty == 4 {
            let Ok(t) = <[u64; 4]>::try_from(nodes) else {
                return Err(format!("element {tag}: a tetrahedron needs 4 nodes"));
            };
            tets.push(RawTet {
                tag,
                pos,
                nodes: t,
                phys,
            });
        } else if dim == 3 {
            return Err(format!("element {tag}: {}", unsupported_3d(ty)));
        }
        if phys != 0 {
            groups
                .entry((dim, phys))
                .or_default()
                .extend_from_slice(nodes);
        }
        Ok(())
    };
    match endian {
        None => {
            for i in 0..n {
                let (pos, line) = c.text_line()?.ok_or_else(|| {
                    c.err(
                        usize::MAX,
                        format!("unexpected end of file in $Elements after {i} of {n} elements"),
                    )
                })?;
                if line.starts_with('$') {
                    return Err(c.err(
                        pos,
                        format!("$Elements declares {n} elements but holds {i}"),
                    ));
                }
                let e = |m: String| c.err(pos, format!("element {}: {m}", i + 1));
                let mut tok = line.split_ascii_whitespace();
                let tag: u64 = cursor::parse_num(tok.next(), "element tag").map_err(e)?;
                let ty: i32 = cursor::parse_num(tok.next(), "element type").map_err(e)?;
                let ntags: usize = cursor::parse_num(tok.next(), "number of tags").map_err(e)?;
                let mut phys = 0;
                for k in 0..ntags {
                    let t: i32 = cursor::parse_num(tok.next(), "tag").map_err(e)?;
                    if k == 0 {
                        phys = t;
                    }
                }
                let nodes: Vec<u64> = tok
                    .map(|t| cursor::parse_num(Some(t), "node tag"))
                    .collect::<Result<_, _>>()
                    .map_err(e)?;
                if let Some((nn, _)) = element_info(ty) {
                    if nodes.len() != nn {
                        return Err(e(format!(
                            "element type {ty} has {nn} nodes, found {} node tags",
                            nodes.len()
                        )));
                    }
                }
                take(pos, tag, ty, phys, &nodes).map_err(|m| c.err(pos, m))?;
            }
        }
        Some(en) => {
            let mut done = 0usize;
            while done < n {
                let pos = c.pos();
                let trunc = |c: &Cursor, what: &str| {
                    c.err_bin(
                        pos,
                        format!(
                            "binary $Elements ends in {what} after {done} of {n} elements \
                             (truncated file?)"
                        ),
                    )
                };
                let (Some(ty), Some(count), Some(ntags)) = (c.i32(en), c.i32(en), c.i32(en)) else {
                    return Err(trunc(c, "a block header"));
                };
                let Some((nn, _)) = element_info(ty) else {
                    return Err(c.err_bin(pos, format!("unknown element type {ty}")));
                };
                let (Ok(count), Ok(ntags)) = (usize::try_from(count), usize::try_from(ntags))
                else {
                    return Err(c.err_bin(
                        pos,
                        format!("element block with negative count {count} or tags {ntags}"),
                    ));
                };
                if count == 0 || count > n - done {
                    return Err(c.err_bin(
                        pos,
                        format!(
                            "element block of {count} elements, but {} of the {n} declared \
                             remain",
                            n - done
                        ),
                    ));
                }
                let per = 1 + ntags + nn;
                if per
                    .checked_mul(4)
                    .and_then(|b| b.checked_mul(count))
                    .is_none_or(|b| b > c.remaining())
                {
                    return Err(trunc(c, "an element block"));
                }
                let mut ints = vec![0u64; per];
                for _ in 0..count {
                    let epos = c.pos();
                    for v in ints.iter_mut() {
                        let x = c.i32(en).ok_or_else(|| trunc(c, "an element"))?;
                        *v = x as i64 as u64;
                    }
                    let phys = if ntags > 0 { ints[1] as i64 as i32 } else { 0 };
                    let tag = ints[0];
                    let nodes = &ints[1 + ntags..];
                    if nodes
                        .iter()
                        .chain(std::iter::once(&tag))
                        .any(|&v| v as i64 <= 0)
                    {
                        return Err(c.err_bin(
                            epos,
                            format!("element {}: a tag or node tag is not positive", tag as i64),
                        ));
                    }
                    take(epos, tag, ty, phys, nodes).map_err(|m| c.err_bin(epos, m))?;
                }
                done += count;
            }
            c.skip_line_end();
        }
    }
    expect_end(c, "$EndElements")?;
    Ok(tets)
}

/// Skips a section whose header line started at `pos` up to its `$End…` line.
fn skip_section(c: &mut Cursor, pos: usize, name: &str) -> Result<(), MeshError> {
    let end = format!("$End{name}");
    match cursor::find_line(c.data(), end.as_bytes(), c.pos()) {
        Some(at) => {
            c.seek(at);
            c.skip_line_end();
            Ok(())
        }
        None => Err(c.err(pos, format!("section ${name} has no {end}"))),
    }
}

/// Reads the next non-blank line and checks that it is `end`.
fn expect_end(c: &mut Cursor, end: &str) -> Result<(), MeshError> {
    let (pos, line) = c.expect_text_line(end)?;
    if line == end {
        Ok(())
    } else {
        Err(c.err(
            pos,
            format!("expected {end}, found '{}'", cursor::shorten(line)),
        ))
    }
}
