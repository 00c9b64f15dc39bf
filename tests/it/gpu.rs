//! GPU deformation vs the f64 CPU reference. These tests need an adapter and FAIL without one
//! (run them with `WGPU_BACKEND=vulkan` on a machine with Mesa's lavapipe).
//!
//! Tolerances: positions `|x_gpu − (x_rest + u_cpu)| ≤ 1e-5·max|u_cpu| + 4·ulp_f32(max|x_rest|)`;
//! normals `|n_gpu − n_cpu| ≤ 1e-4` (unit vectors, CPU = area-weighted normals of the f64
//! deformed surface).

use std::sync::OnceLock;

use crate::common::cpu_normals;
use glam::DVec3;
use touchfem::compliance::{Compliance, Selection};
use touchfem::gpu::{
    AdapterSelection, Deformer, DeformerOptions, Gpu, GpuError, LStorage, OutputTarget, MAX_ACTIVE,
};
use touchfem::mesh::{cube, Mesh};
use touchfem::wgpu;

/// Both layouts of `L`; every test below runs on each.
const LAYOUTS: [LStorage; 2] = [LStorage::Buffers, LStorage::Texture];

fn layout(storage: LStorage) -> DeformerOptions {
    DeformerOptions {
        storage,
        ..Default::default()
    }
}

fn gpu() -> &'static Gpu {
    static GPU: OnceLock<Gpu> = OnceLock::new();
    GPU.get_or_init(|| {
        Gpu::new_headless()
            .unwrap_or_else(|e| panic!("GPU tests need an adapter and must not be skipped: {e}"))
    })
}

struct CubeCase {
    mesh: Mesh,
    c: Compliance,
}

fn cube_case() -> &'static CubeCase {
    static C: OnceLock<CubeCase> = OnceLock::new();
    C.get_or_init(|| {
        let mesh = cube();
        let c = Compliance::compute(&mesh, &Selection::default()).expect("cube compliance");
        CubeCase { mesh, c }
    })
}

/// Tiny deterministic generator (xorshift64*), uniform in [-1, 1).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let v = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        (v >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
    fn vec(&mut self) -> DVec3 {
        DVec3::new(self.next(), self.next(), self.next())
    }
}

fn node_at(mesh: &Mesh, mm: [f64; 3]) -> u32 {
    let p = DVec3::from(mm) * 1e-3;
    mesh.nodes
        .iter()
        .position(|q| q.distance(p) < 1e-9)
        .unwrap_or_else(|| panic!("no node at {mm:?} mm")) as u32
}

fn run(d: &Deformer) -> (Vec<[f32; 3]>, Option<Vec<[f32; 3]>>) {
    let g = gpu();
    let mut enc = g
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
    d.encode(&mut enc);
    g.queue.submit([enc.finish()]);
    d.read_back(&g.device, &g.queue).expect("readback")
}

/// Checks the GPU vertices against `rest + Compliance::displace(forces)`; returns max|u|.
fn check(
    c: &Compliance,
    rest: &[DVec3],
    forces: &[(u32, [f32; 3])],
    d: &Deformer,
    check_normals: bool,
) -> f64 {
    let (pos, nrm) = run(d);
    let f64_forces: Vec<(u32, DVec3)> = forces
        .iter()
        .map(|&(col, f)| (col, DVec3::from(f.map(f64::from))))
        .collect();
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    c.displace(&f64_forces, &mut u);
    let x: Vec<DVec3> = c
        .rows()
        .iter()
        .zip(&u)
        .map(|(&node, u)| rest[node as usize] + *u)
        .collect();
    let (tol, umax) = crate::common::gpu_tolerance(&u, rest);
    let mut worst = 0.0f64;
    for (i, (g, want)) in pos.iter().zip(&x).enumerate() {
        let err = (DVec3::from(g.map(f64::from)) - *want).abs().max_element();
        worst = worst.max(err);
        assert!(
            err <= tol,
            "vertex {i}: gpu {g:?} vs cpu {want:?}: error {err:e} > tol {tol:e} (max|u| {umax:e})"
        );
    }
    eprintln!(
        "{} rows, {} forces: max error {worst:e} m, tol {tol:e}, max|u| {umax:e}",
        pos.len(),
        forces.len()
    );
    if check_normals {
        let want = cpu_normals(&x, d.triangles());
        let got = nrm.expect("normals written");
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            let err = (DVec3::from(g.map(f64::from)) - *w).length();
            assert!(err <= 1e-4, "normal {i}: gpu {g:?} vs cpu {w:?} ({err:e})");
        }
    }
    umax
}

fn new_deformer(c: &Compliance, mesh: &Mesh, opts: &DeformerOptions) -> Deformer {
    let g = gpu();
    let d =
        Deformer::new(&g.device, &g.queue, c, &mesh.nodes, &mesh.surface, opts).expect("deformer");
    if opts.storage != LStorage::Auto {
        assert_eq!(d.stats().storage, opts.storage);
    }
    d
}

/// F = L_ii⁻¹·u at one node (eq. 7), as f32.
fn force_for(c: &Compliance, col: usize, u: DVec3) -> [f32; 3] {
    let f: DVec3 = c.diag_inv(col) * u;
    f.as_vec3().to_array()
}

#[test]
fn no_adapter_is_an_error_naming_wgpu_backend() {
    let sel = AdapterSelection {
        name: Some("no-such-adapter-touchfem-test".into()),
        ..AdapterSelection::from_env()
    };
    match Gpu::new(&sel) {
        Err(e @ GpuError::NoAdapter { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("WGPU_BACKEND"), "{msg}");
            assert!(msg.contains("no-such-adapter-touchfem-test"), "{msg}");
        }
        Err(e) => panic!("expected NoAdapter, got {e}"),
        Ok(_) => panic!("an adapter named no-such-adapter-touchfem-test exists?"),
    }
}

#[test]
fn an_adapter_exists() {
    let info = gpu().adapter.get_info();
    eprintln!("adapter: {} ({:?})", info.name, info.backend);
}

#[test]
fn cube_rest_pose_with_no_active_columns() {
    let k = cube_case();
    for storage in LAYOUTS {
        let d = new_deformer(&k.c, &k.mesh, &layout(storage));
        assert_eq!(d.vertex_count() as usize, k.c.rows().len());
        assert_eq!(d.stats().chunks, 1);
        let umax = check(&k.c, &k.mesh.nodes, &[], &d, true);
        assert_eq!(umax, 0.0);
    }
}

#[test]
fn cube_push_top_centre_5mm() {
    let k = cube_case();
    let node = node_at(&k.mesh, [15.0, 15.0, 30.0]);
    let col = k.c.col_of(node).expect("touchable");
    let u = DVec3::new(0.0, 0.0, -5e-3);
    let forces = [(col as u32, force_for(&k.c, col, u))];
    for storage in LAYOUTS {
        let mut d = new_deformer(&k.c, &k.mesh, &layout(storage));
        d.set_forces(&gpu().queue, &forces).unwrap();
        let umax = check(&k.c, &k.mesh.nodes, &forces, &d, true);
        assert!(
            (umax - 5e-3).abs() < 1e-4,
            "the pushed node moves 5 mm: {umax}"
        );
        // The pushed node itself lands 5 mm down.
        let (pos, _) = run(&d);
        let r = k.c.row_of(node).unwrap();
        assert!((f64::from(pos[r][2]) - 0.025).abs() < 1e-7, "{:?}", pos[r]);
    }
}

#[test]
fn cube_three_node_force_and_sideways_push() {
    let k = cube_case();
    // Paper eq. 9–10: a contact inside a top triangle, area coordinates (0.5, 0.3, 0.2).
    let tri = k
        .mesh
        .surface
        .iter()
        .find(|t| t.iter().all(|&n| k.mesh.nodes[n as usize].z > 0.0299))
        .unwrap();
    let u = DVec3::new(0.5e-3, -1e-3, -4e-3);
    let forces: Vec<(u32, [f32; 3])> = tri
        .iter()
        .zip([0.5, 0.3, 0.2])
        .map(|(&n, a)| {
            let col = k.c.col_of(n).unwrap();
            (col as u32, force_for(&k.c, col, u * a))
        })
        .collect();
    let node = node_at(&k.mesh, [0.0, 15.0, 15.0]);
    let col = k.c.col_of(node).unwrap();
    let side = [(col as u32, force_for(&k.c, col, DVec3::new(5e-3, 0.0, 0.0)))];
    for storage in LAYOUTS {
        let mut d = new_deformer(&k.c, &k.mesh, &layout(storage));
        d.set_forces(&gpu().queue, &forces).unwrap();
        check(&k.c, &k.mesh.nodes, &forces, &d, true);
        // Next frame: the sideways push of the golden test, replacing the previous forces.
        d.set_forces(&gpu().queue, &side).unwrap();
        check(&k.c, &k.mesh.nodes, &side, &d, true);
    }
}

#[test]
fn cube_many_active_columns() {
    let k = cube_case();
    let nc = k.c.cols().len();
    for storage in LAYOUTS {
        let mut rng = Rng(7);
        let mut d = new_deformer(&k.c, &k.mesh, &layout(storage));
        // Every column once, then MAX_ACTIVE entries with repeats (their forces add).
        for n in [nc, 900, MAX_ACTIVE] {
            let forces: Vec<(u32, [f32; 3])> = (0..n)
                .map(|i| ((i % nc) as u32, (rng.vec() * 0.02).as_vec3().to_array()))
                .collect();
            d.set_forces(&gpu().queue, &forces).unwrap();
            check(&k.c, &k.mesh.nodes, &forces, &d, true);
        }
        // Back to rest.
        d.set_forces(&gpu().queue, &[]).unwrap();
        assert_eq!(check(&k.c, &k.mesh.nodes, &[], &d, true), 0.0);
    }
}

#[test]
fn bad_force_lists_are_typed_errors_and_change_nothing() {
    let k = cube_case();
    let nc = k.c.cols().len();
    for storage in LAYOUTS {
        let mut d = new_deformer(&k.c, &k.mesh, &layout(storage));
        let good = [(3u32, [0.01f32, 0.0, -0.02])];
        d.set_forces(&gpu().queue, &good).unwrap();
        let too_many = vec![(0u32, [0.0f32; 3]); MAX_ACTIVE + 1];
        assert!(matches!(
            d.set_forces(&gpu().queue, &too_many),
            Err(GpuError::TooManyActive { count, max }) if count == MAX_ACTIVE + 1 && max == MAX_ACTIVE
        ));
        assert!(matches!(
            d.set_forces(&gpu().queue, &[(nc as u32, [0.0; 3])]),
            Err(GpuError::ColumnOutOfRange { col, n_cols }) if col == nc as u32 && n_cols == nc
        ));
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert!(matches!(
                d.set_forces(&gpu().queue, &[(1, [0.0, bad, 0.0])]),
                Err(GpuError::NonFiniteForce { col: 1, .. })
            ));
        }
        check(&k.c, &k.mesh.nodes, &good, &d, true);
    }
}

#[test]
fn forced_split_across_chunks_matches() {
    let k = cube_case();
    // Only the free rows are stored: the cube's clamped face holds none.
    let nr = k.c.l_rows() as u64;
    assert!(nr < k.c.rows().len() as u64);
    let nc = k.c.cols().len();
    let opts = DeformerOptions {
        max_binding_bytes: Some(36 * nr * 10 + 20),
        storage: LStorage::Buffers,
        ..Default::default()
    };
    let buffers = new_deformer(&k.c, &k.mesh, &opts);
    assert_eq!(buffers.stats().columns_per_chunk, Some(10));
    assert_eq!(buffers.stats().chunks, nc.div_ceil(10));
    // Texture layers of 2 rows of 1024 texels (16 B each); L has 3·C·R' texels.
    let opts = DeformerOptions {
        max_binding_bytes: Some(16 * 1024 * 2 + 100),
        storage: LStorage::Texture,
        ..Default::default()
    };
    let texture = new_deformer(&k.c, &k.mesh, &opts);
    let texels = 3 * nc * nr as usize;
    assert_eq!(texture.stats().columns_per_chunk, None);
    assert_eq!(texture.stats().chunks, texels.div_ceil(1024).div_ceil(2));
    assert!(texture.stats().chunks >= 5);
    for mut d in [buffers, texture] {
        let mut rng = Rng(11);
        // Forces only in a later chunk (chunk 0 still starts from rest), then in every chunk,
        // unsorted and with repeats, then fewer again.
        let frames: Vec<Vec<u32>> = vec![
            vec![35],
            (0..nc as u32)
                .rev()
                .chain([5, 5, 72.min(nc as u32 - 1)])
                .collect(),
            vec![12, 61],
        ];
        for cols in frames {
            let forces: Vec<(u32, [f32; 3])> = cols
                .iter()
                .map(|&c| (c, (rng.vec() * 0.05).as_vec3().to_array()))
                .collect();
            d.set_forces(&gpu().queue, &forces).unwrap();
            check(&k.c, &k.mesh.nodes, &forces, &d, true);
        }
    }
}

#[test]
fn caller_supplied_buffer_with_offset_and_stride() {
    let k = cube_case();
    let g = gpu();
    let nr = k.c.rows().len() as u64;
    let (offset, stride, normal_offset) = (272u64, 40u64, 16u64);
    let size = offset + nr * stride + 64;
    for storage in LAYOUTS {
        let buffer = g.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("caller vertices"),
            size,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::VERTEX
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        g.queue
            .write_buffer(&buffer, 0, &vec![0xABu8; size as usize]);
        let target = OutputTarget {
            buffer: buffer.clone(),
            offset,
            stride,
            normal_offset: Some(normal_offset),
        };
        let mut d = new_deformer(
            &k.c,
            &k.mesh,
            &DeformerOptions {
                output: Some(target),
                storage,
                ..Default::default()
            },
        );
        let node = node_at(&k.mesh, [15.0, 15.0, 30.0]);
        let col = k.c.col_of(node).unwrap();
        let forces = [(
            col as u32,
            force_for(&k.c, col, DVec3::new(0.0, 0.0, -5e-3)),
        )];
        d.set_forces(&g.queue, &forces).unwrap();
        check(&k.c, &k.mesh.nodes, &forces, &d, true);
        // Bytes outside positions and normals are untouched.
        let bytes = touchfem::gpu::read_buffer(&g.device, &g.queue, &buffer, 0, size).unwrap();
        for (i, b) in bytes.iter().enumerate() {
            let i = i as u64;
            let written = i >= offset && i < offset + nr * stride && {
                let w = (i - offset) % stride;
                w < 12 || (normal_offset..normal_offset + 12).contains(&w)
            };
            if !written {
                assert_eq!(*b, 0xAB, "byte {i} was overwritten ({storage:?})");
            }
        }
        // Unusable targets are typed errors.
        let no_storage = g.device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size,
            usage: wgpu::BufferUsages::VERTEX,
            mapped_at_creation: false,
        });
        for t in [
            OutputTarget {
                buffer: no_storage,
                offset: 0,
                stride: 32,
                normal_offset: None,
            },
            OutputTarget {
                buffer: buffer.clone(),
                offset: 2,
                stride: 32,
                normal_offset: None,
            },
            OutputTarget {
                buffer: buffer.clone(),
                offset: 0,
                stride: 16,
                normal_offset: Some(8),
            },
            OutputTarget {
                buffer,
                offset: size - 64,
                stride: 32,
                normal_offset: None,
            },
        ] {
            let r = Deformer::new(
                &g.device,
                &g.queue,
                &k.c,
                &k.mesh.nodes,
                &k.mesh.surface,
                &DeformerOptions {
                    output: Some(t),
                    ..Default::default()
                },
            );
            assert!(matches!(r, Err(GpuError::BadOutput(_))), "{r:?}");
        }
    }
}

/// A random `R`-row compliance with `C` columns at rows `0, step, 2·step, …` (dominant diagonal
/// blocks, so that `L_ii` is invertible), and random rest positions within 5 cm.
fn random_compliance(rng: &mut Rng, r: usize, c: usize, step: u32) -> (Compliance, Vec<DVec3>) {
    let rows: Vec<u32> = (0..r as u32).collect();
    let cols: Vec<u32> = (0..c as u32).map(|i| i * step).collect();
    let mut l: Vec<f64> = (0..9 * r * c).map(|_| rng.next() * 1e-4).collect();
    for (ci, &row) in cols.iter().enumerate() {
        for a in 0..3 {
            l[(3 * ci + a) * 3 * r + 3 * row as usize + a] += 1e-2;
        }
    }
    let compliance = Compliance::from_dense(rows, cols, l, r).expect("random compliance");
    let rest = (0..r).map(|_| rng.vec() * 0.05).collect();
    (compliance, rest)
}

/// A random compliance whose f32 `L` exceeds 128 MiB, so that it needs several bindings on
/// devices with the WebGPU default `max_storage_buffer_binding_size` (lavapipe included).
#[test]
fn large_random_compliance_needs_the_split() {
    const R: usize = 6000;
    const C: usize = 1500;
    let g = gpu();
    let t0 = std::time::Instant::now();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let (c, rest) = random_compliance(&mut rng, R, C, 4);
    // A strip of triangles over the rows, to exercise the normal pass too.
    let tris: Vec<[u32; 3]> = (0..R as u32 - 2)
        .map(|i| {
            if i % 2 == 0 {
                [i, i + 1, i + 2]
            } else {
                [i + 1, i, i + 2]
            }
        })
        .collect();
    eprintln!(
        "built {} MB of f32 L in {:?}",
        36 * R * C / 1_000_000,
        t0.elapsed()
    );
    let bytes = 36 * R as u64 * C as u64;
    assert!(bytes > 128 << 20);
    // The split under the storage binding limit is the buffer layout's.
    let d = Deformer::new(
        &g.device,
        &g.queue,
        &c,
        &rest,
        &tris,
        &layout(LStorage::Buffers),
    )
    .expect("large deformer");
    let lim = g.device.limits();
    let max = lim.max_storage_buffer_binding_size.min(lim.max_buffer_size);
    let cpc = (max / (36 * R as u64)) as usize;
    assert_eq!(d.stats().columns_per_chunk, Some(cpc));
    assert_eq!(d.stats().chunks, C.div_ceil(cpc));
    if max < bytes {
        assert!(d.stats().chunks >= 2);
    }
    eprintln!(
        "{} chunks of {} columns; uploaded in {:?}",
        d.stats().chunks,
        cpc,
        t0.elapsed()
    );
    let mut d = d;
    // Forces in the first, a middle and the last column (spread over the chunks), plus 40 more.
    let mut forces: Vec<(u32, [f32; 3])> = [0u32, 700, 1499]
        .iter()
        .map(|&col| (col, (rng.vec()).as_vec3().to_array()))
        .collect();
    forces.extend((0..40).map(|i| ((i * 37 % C) as u32, rng.vec().as_vec3().to_array())));
    d.set_forces(&g.queue, &forces).unwrap();
    check(&c, &rest, &forces, &d, true);
    eprintln!("large case done in {:?}", t0.elapsed());
}

#[test]
fn deformer_rejects_inconsistent_input() {
    let k = cube_case();
    let g = gpu();
    let opts = DeformerOptions::default();
    // A triangle using a node that is not displayed.
    let interior = (0..k.mesh.nodes.len() as u32)
        .find(|&n| k.c.row_of(n).is_none())
        .unwrap();
    let r = Deformer::new(
        &g.device,
        &g.queue,
        &k.c,
        &k.mesh.nodes,
        &[[interior, 0, 1]],
        &opts,
    );
    assert!(matches!(r, Err(GpuError::BadInput(_))), "{r:?}");
    // Too few rest positions.
    let r = Deformer::new(&g.device, &g.queue, &k.c, &k.mesh.nodes[..10], &[], &opts);
    assert!(matches!(r, Err(GpuError::BadInput(_))), "{r:?}");
    // A cap below one column node (buffers) or one texel row (texture).
    for storage in LAYOUTS {
        let r = Deformer::new(
            &g.device,
            &g.queue,
            &k.c,
            &k.mesh.nodes,
            &k.mesh.surface,
            &DeformerOptions {
                max_binding_bytes: Some(64),
                storage,
                ..Default::default()
            },
        );
        assert!(matches!(r, Err(GpuError::BufferTooLarge { .. })), "{r:?}");
    }
}

#[test]
fn auto_layout_is_the_texture_on_cpu_adapters_only() {
    let k = cube_case();
    let d = new_deformer(&k.c, &k.mesh, &DeformerOptions::default());
    let cpu = gpu().adapter.get_info().device_type == wgpu::DeviceType::Cpu;
    let want = if cpu {
        LStorage::Texture
    } else {
        LStorage::Buffers
    };
    assert_eq!(d.stats().storage, want);
}

/// The two layouts against each other on a rectangular random compliance (rows ≠ columns, a
/// row count that is not a multiple of the workgroup or of the texture row), many forces.
#[test]
fn layouts_agree_on_a_random_compliance() {
    const R: usize = 1111;
    const C: usize = 57;
    let g = gpu();
    let mut rng = Rng(99);
    let (c, rest) = random_compliance(&mut rng, R, C, 19);
    let tris: Vec<[u32; 3]> = (0..R as u32 - 2).map(|i| [i, i + 1, i + 2]).collect();
    let forces: Vec<(u32, [f32; 3])> = (0..40)
        .map(|i| ((i * 13 % C) as u32, rng.vec().as_vec3().to_array()))
        .collect();
    let mut out = Vec::new();
    for storage in LAYOUTS {
        let mut d = Deformer::new(&g.device, &g.queue, &c, &rest, &tris, &layout(storage))
            .expect("deformer");
        d.set_forces(&g.queue, &forces).unwrap();
        check(&c, &rest, &forces, &d, true);
        out.push(run(&d));
    }
    let (pb, nb) = &out[0];
    let (pt, nt) = &out[1];
    for i in 0..R {
        for a in 0..3 {
            assert!((pb[i][a] - pt[i][a]).abs() <= 1e-6, "position {i}");
            let (x, y) = (nb.as_ref().unwrap()[i][a], nt.as_ref().unwrap()[i][a]);
            assert!((x - y).abs() <= 1e-5, "normal {i}: {x} vs {y}");
        }
    }
}

/// A device created with limits below what a layout needs: `LStorage::Texture` is a typed
/// error and `Auto` falls back to storage buffers; a uniform binding too small for the active
/// list is a typed error in both layouts. Nothing panics.
#[test]
fn limited_devices_get_typed_errors_or_the_buffer_layout() {
    let k = cube_case();
    let adapter = &gpu().adapter;
    let device_with = |limits: wgpu::Limits| {
        pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("limited"),
            required_features: wgpu::Features::empty(),
            required_limits: limits,
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .expect("a device with lower limits")
    };
    let new = |device: &wgpu::Device, queue: &wgpu::Queue, storage| {
        Deformer::new(
            device,
            queue,
            &k.c,
            &k.mesh.nodes,
            &k.mesh.surface,
            &layout(storage),
        )
    };
    let (device, queue) = device_with(wgpu::Limits {
        max_storage_textures_per_shader_stage: 2,
        ..adapter.limits()
    });
    let r = new(&device, &queue, LStorage::Texture);
    assert!(matches!(r, Err(GpuError::Unsupported(_))), "{r:?}");
    let d = new(&device, &queue, LStorage::Auto).expect("Auto falls back");
    assert_eq!(d.stats().storage, LStorage::Buffers);
    let (device, queue) = device_with(wgpu::Limits {
        max_uniform_buffer_binding_size: 8 << 10,
        ..adapter.limits()
    });
    for storage in LAYOUTS {
        let r = new(&device, &queue, storage);
        assert!(
            matches!(r, Err(GpuError::BufferTooLarge { bytes: 16384, .. })),
            "{r:?}"
        );
    }
}

/// The texture layout's two ways of passing the active list — immediates (inline up to
/// `INLINE_ACTIVE` entries, the uniform list beyond) and the uniform list alone — give the
/// same vertices, against the f64 reference, through a sequence of frames that crosses the
/// inline limit both ways (no stale entries or counts survive a switch).
#[test]
fn immediates_and_uniform_list_agree() {
    let k = cube_case();
    let g = gpu();
    let nc = k.c.cols().len();
    let has = g.device.features().contains(wgpu::Features::IMMEDIATES);
    let mut with = new_deformer(&k.c, &k.mesh, &layout(LStorage::Texture));
    assert_eq!(
        with.stats().uses_immediates,
        has,
        "Gpu::new requests IMMEDIATES where offered"
    );
    let mut without = new_deformer(
        &k.c,
        &k.mesh,
        &DeformerOptions {
            storage: LStorage::Texture,
            no_immediates: true,
            ..Default::default()
        },
    );
    assert!(!without.stats().uses_immediates);
    assert!(
        !new_deformer(&k.c, &k.mesh, &layout(LStorage::Buffers))
            .stats()
            .uses_immediates
    );
    let mut rng = Rng(11);
    let inline = touchfem::gpu::INLINE_ACTIVE;
    // Every inline count (each has its own specialised pipeline), and switches both ways.
    for n in [3, inline, inline + 1, 1, 40, 0, inline, 2, 4, 5, 6, 9, 3] {
        let forces: Vec<(u32, [f32; 3])> = (0..n)
            .map(|i| ((i * 5 % nc) as u32, (rng.vec() * 0.02).as_vec3().to_array()))
            .collect();
        with.set_forces(&g.queue, &forces).unwrap();
        without.set_forces(&g.queue, &forces).unwrap();
        let umax = check(&k.c, &k.mesh.nodes, &forces, &with, true);
        assert_eq!(umax > 0.0, n > 0);
        check(&k.c, &k.mesh.nodes, &forces, &without, true);
        assert_eq!(run(&with), run(&without), "{n} entries");
    }
}

/// Normals where the triangle fans overflow the 7 inline slots per vertex: a closed cone of 20
/// triangles around an apex (21 fan entries), a wheel sharing its rim, and a non-manifold bow
/// tie, with forces on the hub; against the f64 reference in both layouts.
#[test]
fn normals_of_high_valence_and_non_manifold_vertices() {
    const RIM: u32 = 20;
    let g = gpu();
    let mut rng = Rng(5);
    // Rows: 0 = apex, 1 = hub (below), 2..22 = rim, 22..26 = a bow tie touching the rim.
    let r = 2 + RIM as usize + 4;
    let (c, mut rest) = random_compliance(&mut rng, r, 6, 4);
    for k in 0..RIM {
        let a = std::f64::consts::TAU * f64::from(k) / f64::from(RIM);
        rest[2 + k as usize] = DVec3::new(a.cos(), a.sin(), 0.0) * 0.02;
    }
    rest[0] = DVec3::new(0.0, 0.0, 0.01);
    rest[1] = DVec3::new(0.0, 0.0, -0.01);
    let mut tris: Vec<[u32; 3]> = Vec::new();
    for k in 0..RIM {
        let (a, b) = (2 + k, 2 + (k + 1) % RIM);
        tris.push([0, a, b]);
        tris.push([1, b, a]);
    }
    // Bow tie: two triangles meeting only at rim vertex 2.
    tris.push([2, 22, 23]);
    tris.push([2, 24, 25]);
    let forces: Vec<(u32, [f32; 3])> = (0..6)
        .map(|i| (i, (rng.vec() * 0.3).as_vec3().to_array()))
        .collect();
    for storage in LAYOUTS {
        let mut d = Deformer::new(&g.device, &g.queue, &c, &rest, &tris, &layout(storage))
            .expect("deformer");
        for n in [0, 1, 3, 6] {
            d.set_forces(&g.queue, &forces[..n]).unwrap();
            check(&c, &rest, &forces[..n], &d, true);
        }
    }
}

/// The deformer's own buffer holds whole `Vertex`es after a frame, in both layouts: position
/// `w` = |u| (metres), normal `w = 0` (the texture layout stores each as one vec4), xyz as `read_back`.
#[test]
fn own_vertex_buffer_has_the_documented_layout() {
    let k = cube_case();
    let g = gpu();
    for storage in LAYOUTS {
        let mut d = new_deformer(&k.c, &k.mesh, &layout(storage));
        d.set_forces(&g.queue, &[(4, [0.01, -0.02, 0.03])]).unwrap();
        let (pos, nrm) = run(&d);
        let nrm = nrm.expect("normals");
        let n = d.vertex_count() as usize;
        let bytes = touchfem::gpu::read_buffer(
            &g.device,
            &g.queue,
            d.vertex_buffer(),
            0,
            touchfem::gpu::VERTEX_STRIDE * n as u64,
        )
        .unwrap();
        let v: Vec<touchfem::gpu::Vertex> = bytemuck::pod_collect_to_vec(&bytes);
        assert_eq!(v.len(), n);
        let mut moved = 0f32;
        for i in 0..n {
            // position.w = |u| = |deformed − rest| (metres), from the same pass.
            let rest = k.mesh.nodes[k.c.rows()[i] as usize].as_vec3();
            let u = glam::Vec3::from_slice(&pos[i]) - rest;
            assert!(
                (v[i].position[3] - u.length()).abs() < 1e-7,
                "{storage:?} vertex {i}: w {} vs |u| {}",
                v[i].position[3],
                u.length()
            );
            moved = moved.max(v[i].position[3]);
            assert_eq!(v[i].normal[3], 0.0, "{storage:?} vertex {i}");
            assert_eq!(&v[i].position[..3], &pos[i][..]);
            assert_eq!(&v[i].normal[..3], &nrm[i][..]);
            let len: f32 = v[i].normal[..3].iter().map(|x| x * x).sum::<f32>().sqrt();
            assert!((len - 1.0).abs() < 1e-5, "unit normal {i}: {len}");
        }
        assert!(
            moved > 0.0,
            "{storage:?}: the push moves some vertex, max |u| {moved}"
        );
    }
}
