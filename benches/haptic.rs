//! The haptic force step (god-object update + force solve), the CPU reference of the visual
//! update u = L·F, and the precompute, side by side. Run: `cargo bench --bench haptic`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use glam::DVec3;
use std::hint::black_box;
use std::time::Duration;
use touchfem::compliance::{Compliance, Selection};
use touchfem::contact::finger::Finger;
use touchfem::contact::force::{ForceBc, ForceModel};
use touchfem::contact::Surface;
use touchfem::mesh::{cube, cube_with};
use touchfem::{Material, Mesh};

/// A box of about 2k nodes (12³ cells → 2197 nodes), the paper's mouse material, in mm.
fn box_2k() -> Mesh {
    cube_with(
        [12, 12, 12],
        [30.0; 3],
        Material {
            young_pa: 1000.0,
            poisson: 0.3,
        },
    )
    .unwrap()
}

/// Finger positions pressing 2 mm into the top face (z = 30 mm) and sliding over it.
fn slide(n: usize) -> Vec<DVec3> {
    (0..n)
        .map(|i| {
            let t = i as f64 / n as f64;
            let a = 2.0 * std::f64::consts::PI * t;
            DVec3::new(15.0 + 11.0 * a.cos(), 15.0 + 11.0 * (3.0 * a).sin(), 28.0) * 1e-3
        })
        .collect()
}

fn force_step(c: &mut Criterion) {
    let mut g = c.benchmark_group("force_step");
    for (name, mesh) in [("cube", cube()), ("box2k", box_2k())] {
        let comp = Compliance::compute(&mesh, &Selection::default()).unwrap();
        let surf = Surface::new(&mesh);
        let path = slide(4096);
        for model in [ForceModel::Paper, ForceModel::Exact] {
            let mut f = Finger::new(DVec3::new(0.026, 0.015, 0.032));
            for &x in &path[..8] {
                f.step(&surf, &comp, x, model, 8.5);
            }
            let mut i = 0usize;
            g.bench_function(
                BenchmarkId::new(format!("{model:?}").to_lowercase(), name),
                |b| {
                    b.iter(|| {
                        i = (i + 1) & 4095;
                        black_box(f.step(&surf, &comp, black_box(path[i]), model, 8.5))
                    })
                },
            );
            assert!(
                f.contact.is_some(),
                "the benchmark path must stay in contact"
            );
        }
    }
    g.finish();
}

fn displacement_cpu(c: &mut Criterion) {
    let mut g = c.benchmark_group("displacement_cpu_f64");
    for (name, mesh) in [("cube", cube()), ("box2k", box_2k())] {
        let comp = Compliance::compute(&mesh, &Selection::default()).unwrap();
        let mut out = vec![DVec3::ZERO; comp.rows().len()];
        for active in [3usize, 9] {
            let mut bc = ForceBc::default();
            for k in 0..active {
                bc.add(
                    (k * 7 % comp.cols().len()) as u32,
                    DVec3::new(0.01, -0.02, 0.1),
                );
            }
            // Scalar columns of L and nodes: one contact triangle is 9c_3n.
            let id = format!("{}c_{active}n", 3 * active);
            g.bench_function(BenchmarkId::new(id, name), |b| {
                b.iter(|| comp.displace(black_box(bc.entries()), &mut out))
            });
        }
    }
    g.finish();
}

fn precompute(c: &mut Criterion) {
    let mut g = c.benchmark_group("precompute");
    g.sample_size(10).measurement_time(Duration::from_secs(8));
    for (name, mesh) in [("cube", cube()), ("box2k", box_2k())] {
        g.bench_function(name, |b| {
            b.iter(|| Compliance::compute(black_box(&mesh), &Selection::default()).unwrap())
        });
    }
    g.finish();
}

/// The scene's whole tick (every finger's god-objects and the force solve) with one finger
/// pressing the cube's top, and with two fingers squeezing it (the coupled solve), side by side.
fn scene_tick(c: &mut Criterion) {
    use touchfem::runtime::{HapticWorld, WorldSample};
    let mut g = c.benchmark_group("scene_tick");
    let one = touchfem::scene::World::load_with("fig1", "script", None).unwrap();
    let two = touchfem::scene::World::load_with("pinch", "script", None).unwrap();
    let mm = 1e-3;
    let cases: [(&str, &touchfem::scene::World, Vec<Vec<DVec3>>); 2] = [
        (
            "one_finger",
            &one,
            (0..4096)
                .map(|i| {
                    let a = i as f64 / 4096.0 * std::f64::consts::TAU;
                    vec![DVec3::new(15.0 + 6.0 * a.cos(), 15.0 + 6.0 * a.sin(), 27.0) * mm]
                })
                .collect(),
        ),
        (
            "two_fingers_coupled",
            &two,
            (0..4096)
                .map(|i| {
                    let a = i as f64 / 4096.0 * std::f64::consts::TAU;
                    let (y, z) = (15.0 + 3.0 * a.cos(), 18.0 + 3.0 * a.sin());
                    vec![DVec3::new(3.0, y, z) * mm, DVec3::new(27.0, y, z) * mm]
                })
                .collect(),
        ),
    ];
    for (name, world, path) in &cases {
        let mut hw = HapticWorld::new(world);
        let mut s = WorldSample::default();
        let n = path[0].len();
        let mut f = [DVec3::ZERO; 4];
        // Enter from outside, then stay in contact along the path.
        let out: Vec<DVec3> = path[0]
            .iter()
            .map(|p| *p + (*p - DVec3::splat(15.0 * mm)).normalize() * 10.0 * mm)
            .collect();
        hw.step(&out, &mut f[..n], &mut s);
        hw.step(&path[0], &mut f[..n], &mut s);
        let mut i = 0usize;
        g.bench_function(*name, |b| {
            b.iter(|| {
                i = (i + 1) & 4095;
                hw.step(black_box(&path[i]), &mut f[..n], &mut s);
                black_box(&f);
            })
        });
        assert_eq!(
            s.contacts(0),
            n,
            "{name}: every finger must stay in contact"
        );
    }
    g.finish();
}

/// What the UDP bridge adds to a haptic tick: taking the newest position and sending the
/// force packet, over loopback, for both clocks. With the host clock the receiver thread has
/// already taken the datagram off the socket (waited for, untimed); with the device clock the
/// haptic thread's wait for it (untimed: it is the time between ticks) has returned. With
/// `--key` the force packet is signed (HMAC-SHA256) on the haptic thread; the position's tag
/// is checked on the receiver thread, timed here on its own (`verify_position_tag`).
fn udp_bridge(c: &mut Criterion) {
    use std::net::UdpSocket;
    use touchfem::devices::udp::{
        encode_position, BridgeConfig, Clock, Key, UdpBridge, MAX_PACKET, TAG_LEN,
    };
    use touchfem::devices::{FingerDevices, ForceState};
    let mut g = c.benchmark_group("udp_bridge");
    let secret = Key::new(b"benchmark secret, 32 bytes long!").unwrap();
    for (clock, key) in [
        (Clock::Host, None),
        (Clock::Host, Some(secret.clone())),
        (Clock::Device, None),
        (Clock::Device, Some(secret.clone())),
    ] {
        let keyed = key.is_some();
        let cfg = BridgeConfig {
            clock,
            key: key.clone(),
            // Long enough that no benchmark pause makes the positions stale.
            watchdog: Duration::from_secs(60),
            ..BridgeConfig::default()
        };
        let mut bridge = UdpBridge::bind("127.0.0.1:0".parse().unwrap(), &cfg).unwrap();
        let to = bridge.local_addr().unwrap();
        let client = UdpSocket::bind("127.0.0.1:0").unwrap();
        client.set_nonblocking(true).unwrap();
        let mut pkt = [0u8; MAX_PACKET];
        let mut seq = 0u32;
        let mut pos = [DVec3::ZERO; 1];
        let forces = [DVec3::new(0.1, 0.2, 0.3)];
        let state = [ForceState {
            touching: true,
            limited: false,
        }];
        let mut sink = [0u8; 256];
        let name = match (clock, keyed) {
            (Clock::Host, false) => "host_clock_read_and_send",
            (Clock::Host, true) => "host_clock_read_and_send_keyed",
            (Clock::Device, false) => "device_clock_read_and_send",
            (Clock::Device, true) => "device_clock_read_and_send_keyed",
        };
        g.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    seq += 1;
                    // A new position each time, so the wait below sees this packet arrive.
                    let p = DVec3::new(0.01, 0.02, 1e-6 * f64::from(seq % 1000));
                    let mut n = encode_position(seq, &[p], &mut pkt);
                    if let Some(k) = &key {
                        let tag = k.tag(&pkt[..n]);
                        pkt[n..n + TAG_LEN].copy_from_slice(&tag);
                        n += TAG_LEN;
                    }
                    client.send_to(&pkt[..n], to).unwrap();
                    match clock {
                        Clock::Host => loop {
                            bridge.read(0.0, &mut pos);
                            if pos[0] == p {
                                break;
                            }
                            std::hint::spin_loop();
                        },
                        Clock::Device => {
                            assert!(bridge.wait_reading(Duration::from_millis(20)));
                        }
                    }
                    let t = std::time::Instant::now();
                    bridge.read(0.0, black_box(&mut pos));
                    bridge.write(&forces, &state);
                    total += t.elapsed();
                    assert!(pos[0].is_finite());
                    while client.recv_from(&mut sink).is_ok() {}
                }
                total
            })
        });
    }
    let mut pkt = [0u8; MAX_PACKET];
    let n = encode_position(7, &[DVec3::new(0.01, 0.02, 0.03)], &mut pkt);
    let tag = secret.tag(&pkt[..n]);
    pkt[n..n + TAG_LEN].copy_from_slice(&tag);
    g.bench_function("verify_position_tag", |b| {
        b.iter(|| black_box(secret.open(black_box(&pkt[..n + TAG_LEN])).is_some()))
    });
    g.finish();
}

/// A sphere's tick (the contact problem, warm-started, the default budget) at about 10, 30
/// and 100 contact nodes on the Hertz block (0.7 mm cells under the contact), frictionless and
/// with friction, beside the point finger's exact tick on the same body.
fn sphere_tick(c: &mut Criterion) {
    use touchfem::contact::{Budget, Friction, Patch, Sphere};
    use touchfem_lab::hertz::{block_body, HertzSetup};
    let mut g = c.benchmark_group("sphere_tick");
    let setup = HertzSetup::block(0.3, 0.7);
    let (body, top) = block_body(&setup).unwrap();
    let r = setup.radius_mm * 1e-3;
    let mut point = Finger::new(top + DVec3::new(0.0, 0.0, 1e-3));
    for (k, x) in [top + DVec3::new(0.0, 0.0, -0.5e-3); 4].iter().enumerate() {
        point.step(&body.surface, &body.compliance, *x, ForceModel::Exact, 8.5);
        let _ = k;
    }
    let mut i = 0usize;
    g.bench_function("point_exact", |b| {
        b.iter(|| {
            i = (i + 1) & 63;
            let x = top + DVec3::new(1e-6 * (i as f64 / 64.0), 0.0, -0.5e-3);
            black_box(point.step(
                &body.surface,
                &body.compliance,
                black_box(x),
                ForceModel::Exact,
                8.5,
            ))
        })
    });
    for depth_mm in [0.17, 0.43, 1.5] {
        for friction in [None, Some(Friction::new(0.6, 0.4).unwrap())] {
            let mut patch = Patch::new();
            let centre = |t: f64| top + DVec3::new(2e-6 * t, 0.0, r - depth_mm * 1e-3);
            for s in 0..20 {
                let sp = [Sphere {
                    centre: centre(s as f64 / 20.0),
                    radius: r,
                }];
                patch.solve(
                    &body.compliance,
                    &body.surface,
                    &sp,
                    friction,
                    Budget::UNLIMITED,
                );
            }
            let nodes = patch.report().contacts;
            let name = format!(
                "{}_{}nodes",
                if friction.is_some() {
                    "friction"
                } else {
                    "frictionless"
                },
                nodes
            );
            let mut i = 0usize;
            g.bench_function(name, |b| {
                b.iter(|| {
                    i = (i + 1) & 63;
                    let sp = [Sphere {
                        centre: centre(1.0 + (i as f64) / 64.0),
                        radius: r,
                    }];
                    black_box(patch.solve(
                        &body.compliance,
                        &body.surface,
                        black_box(&sp),
                        friction,
                        Budget::default(),
                    ))
                })
            });
        }
    }
    g.finish();
}

/// Cutting the mouse: removing 1 and 50 tets near its back (the factor's solves at the new
/// DOFs and the capacitance), and the cut body's displacement under a press (a solve and the
/// correction), at the correction's rank after 50 tets.
fn cut(c: &mut Criterion) {
    use criterion::BatchSize;
    use touchfem::cut::Cut;
    let mut g = c.benchmark_group("cut");
    g.sample_size(10);
    let mesh = touchfem::mesh::mouse();
    let at = DVec3::new(-0.01, 0.0, 0.04);
    let near = touchfem::cut::tets_near(&mesh, at, 50);
    for n in [1usize, 50] {
        g.bench_function(format!("remove_{n}_tets_mouse"), |b| {
            b.iter_batched(
                || Cut::new(&mesh).unwrap(),
                |mut cut| black_box(cut.remove(&mesh, &near[..n]).unwrap()),
                BatchSize::PerIteration,
            )
        });
    }
    let mut cut = Cut::new(&mesh).unwrap();
    let rank = cut.remove(&mesh, &near).unwrap().rank;
    let node = mesh.surface_nodes[100];
    g.bench_function(format!("displace_mouse_rank_{rank}"), |b| {
        b.iter(|| black_box(cut.displace(&[(node, DVec3::new(0.0, 0.0, -0.01))])))
    });
    let compliance = touchfem::compliance::Compliance::compute(
        &mesh,
        &touchfem::compliance::Selection::default(),
    )
    .unwrap();
    g.bench_function(format!("fold_mouse_rank_{rank}"), |b| {
        b.iter(|| black_box(cut.fold(&compliance).unwrap()))
    });
    g.finish();
}

/// The haptic tick on a cut body: the mouse with tets removed near its back (a correction of
/// rank about 120, 160 and 360, carried beside `L`), a point finger pressing beside the cut with
/// the exact model (its 3×3 blocks read `L + U Vᵀ`), beside the same tick on the uncut mouse;
/// the cut body's construction (the correction's `V` and the opened surface), the visual
/// path's CPU product with the correction, and the fold (the new `L` and the new factor) at
/// each rank: what sets the rank past which a cutter folds.
fn cut_tick(c: &mut Criterion) {
    use std::sync::Arc;
    use touchfem::cut::Cut;
    let mut g = c.benchmark_group("cut_tick");
    let mesh = touchfem::mesh::mouse();
    let base = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let at = DVec3::new(-0.01, 0.0, 0.04);
    let order = touchfem::cut::tets_near(&mesh, at, mesh.tets.len());
    let plain = Surface::new(&mesh);
    // A press on the back, 20 mm from the cut's centre (clear of the largest cut).
    let (_, p) = plain.closest_global(at + DVec3::new(0.02, 0.0, 0.02));
    let nrm = DVec3::new(0.0, 0.0, 1.0);
    let nc = base.cols().len();
    let forces: Vec<(u32, DVec3)> = (1..4)
        .map(|k| ((k * nc / 5) as u32, DVec3::new(0.0, 0.0, -0.05)))
        .collect();
    let mut u = vec![DVec3::ZERO; base.rows().len()];
    let tick = |g: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
                name: &str,
                comp: &Compliance,
                surf: &Surface| {
        let mut f = Finger::new(p + nrm * 1e-3);
        let mut first = DVec3::ZERO;
        for _ in 0..4 {
            first = f.step(surf, comp, p - nrm * 5e-4, ForceModel::Exact, 8.5);
        }
        assert!(
            first.length() > 1e-4,
            "{name}: the press does not touch ({first})"
        );
        let mut i = 0usize;
        g.bench_function(format!("point_exact_{name}"), |b| {
            b.iter(|| {
                i = (i + 1) & 63;
                let x = p - nrm * 5e-4 + DVec3::new(1e-6 * (i as f64 / 64.0), 0.0, 0.0);
                black_box(f.step(surf, comp, black_box(x), ForceModel::Exact, 8.5))
            })
        });
    };
    tick(&mut g, "uncut", &base, &plain);
    g.bench_function("displace_cpu_uncut", |b| {
        b.iter(|| base.displace(black_box(&forces), &mut u))
    });
    let mut cut = Cut::new(&mesh).unwrap();
    let mut k = 0;
    for target in [120usize, 160, 360] {
        while cut.rank() < target && k < order.len() {
            cut.remove(&mesh, &[order[k]]).unwrap();
            k += 1;
        }
        let rank = cut.rank();
        let carried = base
            .with_correction(Arc::new(cut.correction(&base).unwrap()))
            .unwrap();
        let mut open = mesh.clone();
        open.surface = mesh.open_surface(cut.removed());
        let surface = Surface::new(&open);
        tick(&mut g, &format!("rank_{rank}"), &carried, &surface);
        g.bench_function(format!("displace_cpu_rank_{rank}"), |b| {
            b.iter(|| carried.displace(black_box(&forces), &mut u))
        });
        g.sample_size(10);
        g.bench_function(format!("cut_body_rank_{rank}"), |b| {
            b.iter(|| {
                let k = Arc::new(cut.correction(&base).unwrap());
                let c = base.with_correction(k).unwrap();
                let mut open = mesh.clone();
                open.surface = mesh.open_surface(cut.removed());
                black_box((c, Surface::new(&open)))
            })
        });
        g.bench_function(format!("fold_rank_{rank}"), |b| {
            b.iter(|| black_box(cut.fold(&base).unwrap()))
        });
        g.bench_function(format!("rebase_rank_{rank}"), |b| {
            b.iter(|| black_box(cut.rebase(&mesh).unwrap()))
        });
        g.sample_size(100);
    }
    g.finish();
}

criterion_group!(
    benches,
    cut_tick,
    cut,
    sphere_tick,
    force_step,
    scene_tick,
    udp_bridge,
    displacement_cpu,
    precompute
);
criterion_main!(benches);
