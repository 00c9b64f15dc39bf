//! The hierarchical layout of `L` (`shaders/deform_hier.wgsl`): an [`HMatrix`]'s
//! compressed form on the GPU — its values (dense near blocks, low-rank factors of far blocks)
//! in f32 or half floats, split over up to [`HIER_VALUE_BINDINGS`] storage buffers with whole
//! blocks in each, and its tables (row permutation, block table, per column leaf its blocks by
//! row start). Per frame the host sorts the active columns by position, lists the active
//! column leaves and, per leaf, every block of its column as a hit (the block's row-side values
//! as a matrix with its base and strides, and its coefficients: a dense block's active
//! columns and forces, a low-rank block's `z_b`) in a uniform window (no read-back). One
//! dispatch computes `z_b = V_bᵀ·f` for the low-rank hits, a copy puts them in the window,
//! one dispatch a window computes `u` per row along a single code path, and the storage-buffer
//! normal pass ([`crate::surface`], deform.wgsl's) follows.

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use crate::bind::{buffer, compute_pipeline, specialised_pipeline, storage_entry, uniform_entry};
use crate::buffer_path::pack_f16;
use crate::context::GpuError;
use crate::input::{FrameGpu, Shared, MAX_ACTIVE, WORKGROUP};
use crate::shaders::{deform_source, with_frame, DEFORM_HIER_WGSL};
use touchfem_core::compliance::hmatrix::{BlockInfo, HMatrix};

/// Storage bindings the values may be split over (`deform_hier.wgsl`'s `v0` … `v4`): with
/// the block table, the output and the work buffer, eight storage buffers a stage — WebGPU's
/// default limit.
pub const HIER_VALUE_BINDINGS: usize = 5;

/// A block's rank in the GPU table when it is stored dense.
const DENSE: u32 = u32::MAX;
/// Flag (in a block's column count) of a block read as its source's transpose.
const TRANSPOSED: u32 = 1 << 31;
/// Words of one block in the table.
const BLOCK_WORDS: usize = 7;
/// Bytes of `Params` (the header and the active list).
const PARAMS_BYTES: u64 = 16 + 16 * MAX_ACTIVE as u64;
/// vec4s of one window of the per-frame tables (`deform_hier.wgsl`'s `tab`).
pub(crate) const WINDOW_VEC4S: usize = 4096;
/// Bytes of one window: WebGPU's least `max_uniform_buffer_binding_size`.
const WINDOW_BYTES: u64 = 16 * WINDOW_VEC4S as u64;
/// Largest value buffer, bytes: element indices stay below 2³¹ (u32 arithmetic in WGSL).
const MAX_VALUE_BUFFER: u64 = 1 << 31;

/// `shaders/deform_hier.wgsl` for `buffers` value buffers (1 ..= [`HIER_VALUE_BINDINGS`]): its
/// per-buffer block (what reads `v0`) repeated for `v1` …, their sums added where the file
/// says so; with `half`, the values read as half floats, two per `u32` word.
pub(crate) fn deform_hier_wgsl(buffers: usize, half: bool) -> String {
    const BEGIN: &str = "// BEGIN PER BUFFER";
    const END: &str = "// END PER BUFFER\n";
    const MORE_ADD: &str = "    // MORE BUFFERS: u += addB(h, r);\n";
    const MORE_REDUCE: &str =
        "            // MORE BUFFERS: z += reduceB(base, rs, cs, l, a0, a1, col_start, b.buf);\n";
    const F32_WORD: &str = "alias Word = f32;";
    let src = DEFORM_HIER_WGSL;
    let (Some(a), Some(b)) = (src.find(BEGIN), src.find(END)) else {
        unreachable!("deform_hier.wgsl marks its per-buffer block (a unit test checks)");
    };
    let b = b + END.len();
    let block = &src[a..b];
    let mut out = String::with_capacity(src.len() + buffers * block.len());
    out.push_str(&src[..b]);
    for k in 1..buffers {
        out.push_str(
            &block
                .replace("val0", &format!("val{k}"))
                .replace("add0", &format!("add{k}"))
                .replace("reduce0", &format!("reduce{k}"))
                .replace("v0[", &format!("v{k}["))
                .replace("== 0u", &format!("== {k}u")),
        );
    }
    out.push_str(&src[b..]);
    let adds: String = (1..buffers)
        .map(|k| format!("    u += add{k}(h, r);\n"))
        .collect();
    let reduces: String = (1..buffers)
        .map(|k| {
            format!("            z += reduce{k}(base, rs, cs, l, a0, a1, col_start, b.buf);\n")
        })
        .collect();
    out = with_frame(&out.replace(MORE_ADD, &adds).replace(MORE_REDUCE, &reduces));
    if half {
        out = out.replace(F32_WORD, "alias Word = u32;");
        for k in 0..buffers {
            out = out.replace(
                &format!("    return v{k}[i];\n"),
                &format!(
                    "    let w = unpack2x16float(v{k}[i >> 1u]);\n    \
                     return select(w.x, w.y, (i & 1u) == 1u);\n"
                ),
            );
        }
    }
    out
}

/// Values a block holds: `9mn` dense, `3(m + n)k` low-rank.
fn block_len(b: &BlockInfo) -> usize {
    let (m, n) = (3 * b.rows.len(), 3 * b.cols.len());
    match b.rank {
        None => m * n,
        Some(k) => (m + n) * k,
    }
}

/// Words of the tables (row permutation and segments, block table, leaf × segment table) and
/// of the work buffer (4 a low-rank block for the hit list, then two per rank for the
/// `(l, z_l)` pairs).
fn table_and_work_words(h: &HMatrix) -> (usize, usize) {
    let (mut lr, mut ranks) = (0, 0);
    for b in h.blocks() {
        if let Some(k) = b.rank.filter(|&k| k > 0) {
            lr += 1;
            ranks += k;
        }
    }
    let segments = row_segments(h).len();
    let tables = 2 * h.rows() + BLOCK_WORDS * h.blocks().count() + h.col_leaves() * segments;
    (tables, (4 * lr + 2 * ranks).max(4))
}

/// Most coefficients a block's hit takes in one frame: its rank, or three per column node
/// (a dense block's active columns; at most [`MAX_ACTIVE`] entries).
fn max_coefs(b: &BlockInfo) -> usize {
    match b.rank {
        Some(k) => k,
        None => 3 * b.cols.len().min(MAX_ACTIVE),
    }
}

/// The per-frame windows: per column leaf the most vec4s it can take in a window (its entry,
/// two a hit, its hits' coefficients two a vec4, and the rounding of a window's two
/// coefficient regions), and the windows a frame can need at most (each window but the last
/// is filled to within one leaf's need). An error if one leaf cannot fit a window.
fn windows_of(h: &HMatrix) -> Result<(Vec<u32>, usize), GpuError> {
    let info: Vec<BlockInfo> = h.blocks().collect();
    let mut need = Vec::with_capacity(h.col_leaves());
    let mut entries = 0usize;
    for l in 0..h.col_leaves() {
        let list = h.leaf_blocks(l);
        let coefs: usize = list.iter().map(|&b| max_coefs(&info[b as usize])).sum();
        let n = 1 + 2 * list.len() + coefs.div_ceil(2) + 2;
        if n + 1 > WINDOW_VEC4S {
            return Err(GpuError::Unsupported(format!(
                "a hierarchical L whose column leaf {l} needs {n} vec4s of per-frame tables \
                 (one uniform window holds {})",
                WINDOW_VEC4S - 1
            )));
        }
        entries += 1 + 2 * list.len();
        need.push(n as u32);
    }
    // Each block's coefficients are listed once a frame (at its first active leaf).
    let coefs: usize = info.iter().map(|b| max_coefs(b).div_ceil(2)).sum();
    let most = need.iter().copied().max().unwrap_or(0) as usize;
    let per_window = WINDOW_VEC4S - 1 - most;
    let leaves = h.col_leaves().min(MAX_ACTIVE);
    let windows = ((entries + coefs).div_ceil(per_window.max(1)) + 1).min(leaves.max(1));
    Ok((need, windows))
}

/// The row segments: the row positions where some block starts (ascending). Within a
/// segment every column leaf's block is the same, so a row's block for an active leaf is one
/// lookup in the leaf × segment table instead of a bisection of the leaf's list.
fn row_segments(h: &HMatrix) -> Vec<u32> {
    let mut s: Vec<u32> = h.blocks().map(|b| b.rows.start as u32).collect();
    s.sort_unstable();
    s.dedup();
    s
}

/// Bytes the GPU holds for a hierarchical `L` in one value buffer (the layout
/// [`Deformer::new`](crate::Deformer::new) makes for [`LData::Hier`](crate::LData::Hier)):
/// the values in f32 (or half floats, `f16`), the tables (row permutation and segments, 28
/// bytes a block, 4 bytes an entry of the leaf × segment table), the per-frame work buffer (16
/// bytes a low-rank block, 8 a rank) and the per-frame uniform windows (64 KiB each, as many
/// as the largest frame can need). A split over several buffers adds at most 16 bytes a
/// buffer; [`DeformerStats::l_bytes`](crate::DeformerStats::l_bytes) is the exact figure. No GPU needed.
pub fn hier_gpu_bytes(h: &HMatrix, f16: bool) -> u64 {
    let n = unique_values(h) as u64;
    let values = if f16 { (2 * n).div_ceil(4) * 4 } else { 4 * n };
    let (tables, work) = table_and_work_words(h);
    let windows = windows_of(h).map_or(1, |w| w.1) as u64;
    values.max(16) + 4 * (tables + work) as u64 + WINDOW_BYTES * windows
}

/// Values the GPU holds: every block's but the mirrors' (each read as its source's
/// transpose).
fn unique_values(h: &HMatrix) -> usize {
    h.blocks()
        .filter(|b| b.mirror_of.is_none())
        .map(|b| block_len(&b))
        .sum()
}

/// Per block its (value buffer, first element); per buffer its elements.
type Placement = (Vec<(u32, u32)>, Vec<usize>);

/// Where each block's values go: `(buffer, first element)` per block (a mirror: its source's),
/// and the elements of each buffer. Greedy in block order; an error if a block exceeds
/// `max_bytes` or the blocks need more than [`HIER_VALUE_BINDINGS`] buffers.
fn place_blocks(h: &HMatrix, half: bool, max_bytes: u64) -> Result<Placement, GpuError> {
    let max_bytes = max_bytes.min(MAX_VALUE_BUFFER);
    // Half floats: whole words.
    let cap = if half {
        max_bytes / 4 * 2
    } else {
        max_bytes / 4
    } as usize;
    let bytes = |n: usize| if half { 2 * n as u64 } else { 4 * n as u64 };
    let mut place = Vec::with_capacity(h.blocks().count());
    let mut lens = vec![0usize];
    for b in h.blocks() {
        if let Some(src) = b.mirror_of {
            let at = *place
                .get(src)
                .ok_or_else(|| GpuError::BadInput("a mirror block before its source".into()))?;
            place.push(at);
            continue;
        }
        let n = block_len(&b);
        if n > cap {
            return Err(GpuError::BufferTooLarge {
                what: "one block of the hierarchical L",
                bytes: bytes(n),
                limit: max_bytes,
            });
        }
        if lens.last().is_some_and(|&l| l + n > cap) {
            lens.push(0);
        }
        let k = lens.len() - 1;
        place.push((k as u32, lens[k] as u32));
        lens[k] += n;
    }
    if lens.len() > HIER_VALUE_BINDINGS {
        return Err(GpuError::BufferTooLarge {
            what: "the hierarchical L's values (5 storage bindings)",
            bytes: bytes(unique_values(h)),
            limit: HIER_VALUE_BINDINGS as u64 * max_bytes,
        });
    }
    Ok((place, lens))
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct HierFrameGpu {
    base: FrameGpu,
    perm_off: u32,
    blocks_off: u32,
    lb_off: u32,
    z_off: u32,
}

/// What the host keeps of a block to list the hits.
#[derive(Clone, Copy, Debug)]
struct HostBlock {
    col_start: u32,
    col_end: u32,
    /// [`DENSE`] or k.
    rank: u32,
    /// Its row-side values as a matrix (rows × columns for a dense block, rows × rank for a
    /// low-rank one): entry (r, c) at `base + r·rs + c·cs` of buffer `buf`.
    base: u32,
    rs: u32,
    cs: u32,
    buf: u32,
    /// First row position.
    row_start: u32,
}

/// One window of a frame's tables, as uploaded.
#[derive(Clone, Copy, Debug, Default)]
struct Window {
    /// vec4s written by the host.
    used: u32,
    /// Where its low-rank coefficients go (vec4 index), and their run of pairs in `work`.
    lr_at: u32,
    lr_start: u32,
    lr_pairs: u32,
}

/// The window being filled: its leaves (row of the leaf × segment table, first hit), hits
/// (the block's base, strides and first row; columns, first coefficient of its kind, buffer,
/// 1 for a low-rank hit) and dense coefficients.
#[derive(Debug, Default)]
struct Filling {
    leaves: Vec<[u32; 2]>,
    hits: Vec<[u32; 8]>,
    dense: Vec<[u32; 2]>,
    lr_pairs: u32,
}

impl Filling {
    /// vec4s it will take.
    fn used(&self) -> usize {
        1 + self.leaves.len()
            + 2 * self.hits.len()
            + (self.lr_pairs as usize).div_ceil(2)
            + self.dense.len().div_ceil(2)
    }
}

/// A hierarchical `L` on the GPU, and the passes that read it.
pub(super) struct HierPath {
    half: bool,
    /// Forces are multiplied by this before upload; the dense blocks and `U` are stored
    /// divided by it (`V` as is): a power of two near their max |·| for half floats, 1 for f32.
    force_scale: f32,
    /// Per column index, its position; per position, its leaf.
    col_pos: Vec<u32>,
    col_leaf: Vec<u32>,
    /// Each leaf's run of `leaf_list` (`leaf_start[l]..leaf_start[l + 1]`).
    leaf_start: Vec<u32>,
    leaf_list: Vec<u32>,
    /// Row segments (columns of the leaf × segment table).
    n_segments: u32,
    blocks: Vec<HostBlock>,
    /// Value buffers (kept alive by the bind group too) and their bytes.
    values: Vec<wgpu::Buffer>,
    l_bytes: u64,
    params: wgpu::Buffer,
    work: wgpu::Buffer,
    /// Word offset of the `(l, z_l)` pairs in `work`.
    z_off: u32,
    frame_buf: wgpu::Buffer,
    group0: wgpu::BindGroup,
    values_group: wgpu::BindGroup,
    /// `deform.wgsl`, whose `normals` entry is the normal pass's.
    normals_module: wgpu::ShaderModule,
    reduce: wgpu::ComputePipeline,
    deform: wgpu::ComputePipeline,
    max_groups: u32,
    /// This frame's active entries by column position (position, scaled force).
    active: Vec<(u32, [f32; 3])>,
    /// Upload scratch: the `Params` header and active list, the low-rank hits.
    head: Vec<[u32; 4]>,
    hits: Vec<[u32; 4]>,
    n_hits: u32,
    /// Per column leaf the most vec4s it takes in a window.
    leaf_need: Vec<u32>,
    /// The per-frame tables: a uniform buffer of windows, its host copy, this frame's windows
    /// and the one being filled.
    tab_buf: wgpu::Buffer,
    tab: Vec<[u32; 4]>,
    windows: Vec<Window>,
    filling: Filling,
}

impl Filling {
    fn clear(&mut self) {
        self.leaves.clear();
        self.hits.clear();
        self.dense.clear();
        self.lr_pairs = 0;
    }
}

impl HierPath {
    pub(super) fn new(sh: &Shared<'_>, h: &HMatrix) -> Result<HierPath, GpuError> {
        let (device, queue, nr) = (sh.device, sh.queue, sh.nr);
        if h.rows() != sh.nl || h.cols() != sh.nc || h.out_rows() > nr {
            return Err(GpuError::BadInput(format!(
                "a hierarchical L of {} × {} nodes ({} output rows) for {} rows that hold L of \
                 {nr} and {} columns",
                h.rows(),
                h.cols(),
                h.out_rows(),
                sh.nl,
                sh.nc
            )));
        }
        let limits = device.limits();
        if limits.max_storage_buffers_per_shader_stage < 3 + HIER_VALUE_BINDINGS as u32 {
            return Err(GpuError::Unsupported(format!(
                "a hierarchical L: it needs {} storage buffers per shader stage, the device \
                 allows {}",
                3 + HIER_VALUE_BINDINGS,
                limits.max_storage_buffers_per_shader_stage
            )));
        }
        if limits.max_uniform_buffer_binding_size < WINDOW_BYTES {
            return Err(GpuError::BufferTooLarge {
                what: "the hierarchical pass's per-frame window (one uniform binding)",
                bytes: WINDOW_BYTES,
                limit: limits.max_uniform_buffer_binding_size,
            });
        }

        let info: Vec<BlockInfo> = h.blocks().collect();
        let (place, lens) = place_blocks(h, sh.half, sh.max_chunk)?;

        // Tables: rest positions, row_perm, blocks, leaf lists.
        let mut z = 0u32;
        let mut idx: Vec<u32> = Vec::with_capacity(4 * nr + table_and_work_words(h).0);
        idx.extend(sh.rest_rows.iter().flatten().map(|v| v.to_bits()));
        let perm_off = idx.len() as u32;
        idx.extend_from_slice(h.row_perm());
        // Each row position's segment, after row_perm.
        let segs = row_segments(h);
        let mut seg = 0u32;
        for p in 0..h.rows() as u32 {
            while (seg as usize + 1) < segs.len() && segs[seg as usize + 1] <= p {
                seg += 1;
            }
            idx.push(seg);
        }
        let blocks_off = idx.len() as u32;
        let mut blocks = Vec::with_capacity(info.len());
        let mut n_lr = 0u32;
        for (b, &(buf, off)) in info.iter().zip(&place) {
            let rank = b.rank.map_or(DENSE, |k| k as u32);
            let t = b.mirror_of.is_some();
            let transposed = if t { TRANSPOSED } else { 0 };
            idx.extend_from_slice(&[
                b.rows.start as u32,
                b.rows.len() as u32,
                b.cols.start as u32,
                b.cols.len() as u32 | transposed,
                rank,
                buf,
                off,
            ]);
            if let Some(k) = b.rank.filter(|&k| k > 0) {
                z += k as u32;
                n_lr += 1;
            }
            let (m3, n3) = (3 * b.rows.len() as u32, 3 * b.cols.len() as u32);
            // A stored block: dense 3m × 3n or U 3m × k, column-major. A mirror is read
            // across its source: a dense 3n × 3m, or the source's V (3m × k, row-major, after
            // its U of 3n × k).
            let (base, rs, cs) = match (b.rank, t) {
                (None, false) | (Some(_), false) => (off, 1, m3),
                (None, true) => (off, n3, 1),
                (Some(k), true) => (off + n3 * k as u32, k as u32, 1),
            };
            blocks.push(HostBlock {
                col_start: b.cols.start as u32,
                col_end: b.cols.end as u32,
                rank,
                base,
                rs,
                cs,
                buf,
                row_start: b.rows.start as u32,
            });
        }
        let lb_off = idx.len() as u32;
        let mut leaf_start = Vec::with_capacity(h.col_leaves() + 1);
        let mut leaf_list = Vec::new();
        leaf_start.push(0u32);
        for l in 0..h.col_leaves() {
            // The leaf × segment table: each segment's block in this leaf's list (sorted by
            // row start, partitioning the rows).
            let list = h.leaf_blocks(l);
            let mut k = 0;
            for &s in &segs {
                while k + 1 < list.len() && info[list[k + 1] as usize].rows.start as u32 <= s {
                    k += 1;
                }
                idx.push(k as u32);
            }
            leaf_list.extend_from_slice(list);
            leaf_start.push(leaf_list.len() as u32);
        }
        sh.check("the hierarchical L's tables", 4 * idx.len() as u64)?;
        let idx_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem hierarchical tables"),
            contents: bytemuck::cast_slice(&idx),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let work_words = (4 * n_lr + 2 * z).max(4) as u64;
        sh.check("the hierarchical pass's work buffer", 4 * work_words)?;
        let work = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem hierarchical hits and z"),
            size: 4 * work_words,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let (leaf_need, n_windows) = windows_of(h)?;
        let tab_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem hierarchical per-frame windows"),
            size: WINDOW_BYTES * n_windows as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        // Values, one buffer at a time (the host holds one buffer's f32 copy).
        let force_scale = if sh.half {
            let mut max = 0.0f32;
            for (b, v) in info
                .iter()
                .filter(|b| b.mirror_of.is_none())
                .map(|b| (b, &h.values()[b.offset..]))
            {
                // The dense entries and U, not V (unit columns).
                let n = match b.rank {
                    None => block_len(b),
                    Some(k) => 3 * b.rows.len() * k,
                };
                max = v[..n].iter().fold(max, |m, &x| m.max((x as f32).abs()));
            }
            touchfem_core::compliance::f16_scale_of_max(max)
        } else {
            1.0
        };
        let mut values = Vec::with_capacity(lens.len());
        let mut l_bytes = 4 * (idx.len() as u64 - 4 * nr as u64) + 4 * work_words + tab_buf.size();
        let mut staging: Vec<f32> = Vec::new();
        let mut next = 0;
        for (k, &len) in lens.iter().enumerate() {
            staging.clear();
            staging.reserve(len);
            while next < info.len() && (info[next].mirror_of.is_some() || place[next].0 == k as u32)
            {
                let b = &info[next];
                if b.mirror_of.is_some() {
                    next += 1;
                    continue;
                }
                let v = &h.values()[b.offset..][..block_len(b)];
                let scaled = match b.rank {
                    None => v.len(),
                    Some(k) => 3 * b.rows.len() * k,
                };
                let s = f64::from(force_scale);
                staging.extend(v[..scaled].iter().map(|&x| (x / s) as f32));
                staging.extend(v[scaled..].iter().map(|&x| x as f32));
                next += 1;
            }
            debug_assert_eq!(staging.len(), len);
            let packed;
            let bytes: &[u8] = if sh.half {
                packed = pack_f16(&staging);
                bytemuck::cast_slice(&packed)
            } else {
                bytemuck::cast_slice(&staging)
            };
            let size = (bytes.len() as u64).max(16);
            let b = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("touchfem hierarchical values"),
                size,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            if !bytes.is_empty() {
                queue.write_buffer(&b, 0, bytes);
                // Flush each buffer's staging copy so that peak memory stays near one buffer.
                queue.submit([]);
            }
            l_bytes += size;
            values.push(b);
        }
        let dummy = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem unused value binding"),
            size: 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });

        let frame = HierFrameGpu {
            base: sh.frame,
            perm_off,
            blocks_off,
            lb_off,
            z_off: 4 * n_lr,
        };
        let frame_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem hierarchical frame"),
            contents: bytemuck::bytes_of(&frame),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem hierarchical active lists"),
            size: PARAMS_BYTES,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let layout0 = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem hierarchical group 0"),
            entries: &[
                uniform_entry(0),
                uniform_entry(1),
                storage_entry(2, true),
                storage_entry(3, false),
                storage_entry(4, false),
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: true,
                        min_binding_size: wgpu::BufferSize::new(WINDOW_BYTES),
                    },
                    count: None,
                },
            ],
        });
        let value_entries: Vec<_> = (0..HIER_VALUE_BINDINGS as u32)
            .map(|b| storage_entry(b, true))
            .collect();
        let layout1 = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem hierarchical values"),
            entries: &value_entries,
        });
        let (out, out_start, out_size) = sh.out;
        let frame_bytes = std::mem::size_of::<HierFrameGpu>() as u64;
        let group0 = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem hierarchical group 0"),
            layout: &layout0,
            entries: &[
                buffer(0, &frame_buf, 0, frame_bytes),
                buffer(1, &params, 0, PARAMS_BYTES),
                buffer(2, &idx_buf, 0, 4 * idx.len() as u64),
                buffer(3, out, out_start, out_size),
                buffer(4, &work, 0, 4 * work_words),
                buffer(5, &tab_buf, 0, WINDOW_BYTES),
            ],
        });
        let value_bindings: Vec<_> = (0..HIER_VALUE_BINDINGS)
            .map(|k| {
                let b = values.get(k).unwrap_or(&dummy);
                buffer(k as u32, b, 0, b.size())
            })
            .collect();
        let values_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem hierarchical values"),
            layout: &layout1,
            entries: &value_bindings,
        });
        let source = deform_hier_wgsl(values.len(), sh.half).into();
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("touchfem deform_hier.wgsl"),
            source: wgpu::ShaderSource::Wgsl(source),
        });
        let normals_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("touchfem deform.wgsl (normals)"),
            source: wgpu::ShaderSource::Wgsl(deform_source().into()),
        });
        // The deformer's own `Vertex`es carry |u| in position.w (word 3).
        let with_word = [("DISPLACEMENT_WORD", 3.0)];
        let constants = if sh.vertex_layout {
            &with_word[..]
        } else {
            &[]
        };
        let mut path = HierPath {
            half: sh.half,
            force_scale,
            col_pos: (0..h.cols())
                .map(|c| h.col_pos(c).expect("a column") as u32)
                .collect(),
            col_leaf: (0..h.cols()).map(|p| h.leaf_of(p) as u32).collect(),
            leaf_start,
            leaf_list,
            n_segments: segs.len() as u32,
            blocks,
            values,
            l_bytes,
            params,
            work,
            z_off: 4 * n_lr,
            frame_buf,
            group0,
            values_group,
            normals_module,
            reduce: compute_pipeline(device, &module, "reduce", &[&layout0, &layout1], 0),
            deform: specialised_pipeline(
                device,
                &module,
                "deform",
                &[&layout0, &layout1],
                0,
                constants,
            ),
            max_groups: limits.max_compute_workgroups_per_dimension,
            active: Vec::with_capacity(MAX_ACTIVE),
            head: Vec::with_capacity(MAX_ACTIVE + 1),
            hits: Vec::with_capacity(n_lr as usize),
            n_hits: 0,
            leaf_need,
            tab_buf,
            tab: vec![[0; 4]; n_windows * WINDOW_VEC4S],
            windows: Vec::with_capacity(n_windows),
            filling: Filling {
                leaves: Vec::with_capacity(WINDOW_VEC4S),
                hits: Vec::with_capacity(WINDOW_VEC4S / 2),
                dense: Vec::with_capacity(2 * WINDOW_VEC4S),
                lr_pairs: 0,
            },
        };
        // The rest pose until the first forces.
        path.set_forces(queue, &[]);
        Ok(path)
    }

    /// Sorts the active entries by column position and lists, per active column leaf, every
    /// block of its column as a hit in the frame's windows: a dense block with its active
    /// columns and forces, a low-rank one with its `z_b` (computed on the GPU, listed once
    /// for the reduction), both at the block's first active leaf; elsewhere with no columns.
    /// Uploads the windows, the active list and the low-rank hits. `forces` is already
    /// validated (at most [`MAX_ACTIVE`], columns in range). Allocates nothing.
    pub(super) fn set_forces(&mut self, queue: &wgpu::Queue, forces: &[(u32, [f32; 3])]) {
        let s = self.force_scale;
        self.active.clear();
        self.active.extend(
            forces
                .iter()
                .map(|&(c, f)| (self.col_pos[c as usize], f.map(|v| v * s))),
        );
        self.active.sort_unstable_by_key(|a| a.0);
        self.hits.clear();
        self.windows.clear();
        self.filling.clear();
        let mut lr_total = 0u32;
        let mut a = 0;
        while a < self.active.len() {
            let leaf = self.col_leaf[self.active[a].0 as usize] as usize;
            let mut e = a + 1;
            while e < self.active.len() && self.col_leaf[self.active[e].0 as usize] as usize == leaf
            {
                e += 1;
            }
            if !self.filling.leaves.is_empty()
                && self.filling.used() + self.leaf_need[leaf] as usize > WINDOW_VEC4S
            {
                // This window and the last must fit. Not reached: the windows are sized for
                // the largest frame.
                if self.windows.len() + 2 > self.tab.len() / WINDOW_VEC4S {
                    log::error!("the hierarchical pass's windows are full; columns left out");
                    break;
                }
                self.flush(lr_total);
            }
            let (l0, l1) = (self.leaf_start[leaf], self.leaf_start[leaf + 1]);
            let act = &self.active;
            let f = &mut self.filling;
            f.leaves
                .push([leaf as u32 * self.n_segments, f.hits.len() as u32]);
            for &bi in &self.leaf_list[l0 as usize..l1 as usize] {
                let b = self.blocks[bi as usize];
                // Listed with its columns at its first active leaf (the entries are sorted).
                let first = a == 0 || act[a - 1].0 < b.col_start;
                let end = if first {
                    a + act[a..].partition_point(|x| x.0 < b.col_end)
                } else {
                    a
                };
                let (cols, coef, lr) = if end == a || b.rank == 0 {
                    (0, 0, 0)
                } else if b.rank == DENSE {
                    let at = f.dense.len() as u32;
                    for &(p, force) in &act[a..end] {
                        for (c, v) in force.iter().enumerate() {
                            f.dense
                                .push([3 * (p - b.col_start) + c as u32, v.to_bits()]);
                        }
                    }
                    (3 * (end - a) as u32, at, 0)
                } else {
                    let at = f.lr_pairs;
                    f.lr_pairs += b.rank;
                    self.hits.push([bi, a as u32, end as u32, lr_total]);
                    lr_total += b.rank;
                    (b.rank, at, 1)
                };
                f.hits
                    .push([b.base, b.rs, b.cs, b.row_start, cols, coef, b.buf, lr]);
            }
            a = e;
        }
        if !self.filling.leaves.is_empty() || self.windows.is_empty() {
            self.flush(lr_total);
        }
        self.n_hits = self.hits.len() as u32;
        self.head.clear();
        self.head.push([self.n_hits, 0, 0, 0]);
        self.head.extend(
            self.active
                .iter()
                .map(|&(p, f)| [f[0].to_bits(), f[1].to_bits(), f[2].to_bits(), p]),
        );
        queue.write_buffer(&self.params, 0, bytemuck::cast_slice(&self.head));
        if !self.hits.is_empty() {
            queue.write_buffer(&self.work, 0, bytemuck::cast_slice(&self.hits));
        }
        for (w, win) in self.windows.iter().enumerate() {
            let at = w * WINDOW_VEC4S;
            queue.write_buffer(
                &self.tab_buf,
                w as u64 * WINDOW_BYTES,
                bytemuck::cast_slice(&self.tab[at..at + win.used as usize]),
            );
        }
    }

    /// Lays the window being filled out in the host copy of the windows (its low-rank
    /// coefficients, pairs from `lr_end − lr_pairs` on in `work`, are copied in on the GPU)
    /// and starts the next.
    fn flush(&mut self, lr_end: u32) {
        let w = self.windows.len();
        let f = &self.filling;
        let tab = &mut self.tab[w * WINDOW_VEC4S..(w + 1) * WINDOW_VEC4S];
        let n_leaves = f.leaves.len();
        tab[0] = [n_leaves as u32, u32::from(w == 0), 0, 0];
        let hits_at = 1 + n_leaves;
        for (q, l) in f.leaves.iter().enumerate() {
            tab[1 + q] = [l[0], (hits_at + 2 * l[1] as usize) as u32, 0, 0];
        }
        let lr_at = hits_at + 2 * f.hits.len();
        let dense_at = lr_at + (f.lr_pairs as usize).div_ceil(2);
        for (i, h) in f.hits.iter().enumerate() {
            let region = if h[7] == 1 { lr_at } else { dense_at };
            tab[hits_at + 2 * i] = [h[0], h[1], h[2], h[3]];
            tab[hits_at + 2 * i + 1] = [h[4], 2 * region as u32 + h[5], h[6], 0];
        }
        for (j, pair) in f.dense.chunks(2).enumerate() {
            let second = pair.get(1).copied().unwrap_or([0, 0]);
            tab[dense_at + j] = [pair[0][0], pair[0][1], second[0], second[1]];
        }
        self.windows.push(Window {
            used: f.used() as u32,
            lr_at: lr_at as u32,
            lr_start: lr_end - f.lr_pairs,
            lr_pairs: f.lr_pairs,
        });
        self.filling.clear();
    }

    /// Records the reduction over the low-rank hits (when there are any) and the copies of
    /// their `z` into the windows: before the compute pass of
    /// [`record_deform`](Self::record_deform).
    pub(super) fn record_reduce(&self, encoder: &mut wgpu::CommandEncoder) {
        if self.n_hits == 0 {
            return;
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("touchfem hierarchical z"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.reduce);
            pass.set_bind_group(0, &self.group0, &[0]);
            pass.set_bind_group(1, &self.values_group, &[]);
            pass.dispatch_workgroups(self.n_hits.min(self.max_groups), 1, 1);
        }
        for (w, win) in self.windows.iter().enumerate() {
            if win.lr_pairs > 0 {
                encoder.copy_buffer_to_buffer(
                    &self.work,
                    4 * (u64::from(self.z_off) + 2 * u64::from(win.lr_start)),
                    &self.tab_buf,
                    w as u64 * WINDOW_BYTES + 16 * u64::from(win.lr_at),
                    8 * u64::from(win.lr_pairs),
                );
            }
        }
    }

    /// Records the row pass, once a window (after [`record_reduce`](Self::record_reduce)).
    pub(super) fn record_deform(&self, pass: &mut wgpu::ComputePass<'_>, n_rows: u32) {
        pass.set_pipeline(&self.deform);
        pass.set_bind_group(1, &self.values_group, &[]);
        for w in 0..self.windows.len() {
            pass.set_bind_group(0, &self.group0, &[(w as u64 * WINDOW_BYTES) as u32]);
            pass.dispatch_workgroups(n_rows.div_ceil(WORKGROUP), 1, 1);
        }
    }

    /// Whether the values are half floats.
    pub(super) fn half(&self) -> bool {
        self.half
    }

    /// Windows of the last frame's tables.
    pub(super) fn frame_windows(&self) -> usize {
        self.windows.len()
    }

    /// Storage buffers holding the values.
    pub(super) fn value_buffers(&self) -> usize {
        self.values.len()
    }

    /// Bytes the GPU holds for `L`: values, tables, work buffer.
    pub(super) fn l_bytes(&self) -> u64 {
        self.l_bytes
    }

    /// `deform.wgsl`'s module (the normal pass's `normals` entry).
    pub(super) fn normals_module(&self) -> &wgpu::ShaderModule {
        &self.normals_module
    }

    /// The frame uniform (its first 32 bytes are the normal pass's frame).
    pub(super) fn frame(&self) -> &wgpu::Buffer {
        &self.frame_buf
    }
}
