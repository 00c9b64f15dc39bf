//! The lab's studies, checked (moved from the lab's unit tests, so that `cargo test` does not
//! compile the lab a second time as a unit-test harness).

mod hmatrix_study {
    use touchfem_lab::hmatrix_study::*;

    /// The study's rows hold the guarantee and the measured storage; prints the table with
    /// `--nocapture` (a test, not the library, prints).
    #[test]
    fn hmatrix_rows_hold_their_bounds() {
        // (One tolerance: the core module's tests hold the bound at 1e-2, 1e-4 and 1e-6.)
        let rows = hmatrix_rows(&[1e-3], 5).expect("rows");
        for r in &rows {
            println!("{}", serde_json::to_string(r).expect("json"));
            assert!(r.frobenius_rel <= r.tolerance, "{r:?}");
            assert!(r.l2_median <= r.l2_worst && r.l2_worst.is_finite(), "{r:?}");
        }
        let mouse3 = rows
            .iter()
            .find(|r| r.mesh == "mouse" && r.tolerance == 1e-3)
            .expect("mouse at 1e-3");
        // Measured: 0.333 of the dense values; one finger's matvec 33 µs against 47 µs dense.
        assert!(mouse3.ratio < 0.36, "{mouse3:?}");
        assert!(
            mouse3.l2_median <= 2e-3 && mouse3.l2_worst <= 1e-2,
            "{mouse3:?}"
        );
    }
}

mod bench_plot {
    use touchfem_lab::bench_plot::*;
    use touchfem_lab::tradeoff::Row;

    #[test]
    fn the_plot_has_a_marker_per_row() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.png");
        let row = |m: &str, t: f64, e: f64| Row {
            method: m.into(),
            mesh: "cube".into(),
            nodes: 125,
            active_columns: 9,
            time_us: t,
            rel_error: e,
        };
        let rows = vec![
            row("cpu-f64", 2.0, 0.0),
            row("cpu-f32", 3.0, 1e-7),
            row("cg-1e-6", 1000.0, 5e-7),
            row("force-paper", 0.1, 0.4),
        ];
        write_plot(&path, &rows, &["cube"], &[]).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (780, 480));
        // With memory points: one more panel, the mesh's colour drawn in it.
        let mem = [1e-2, 1e-3].map(|t| MemoryPoint {
            mesh: "mouse".into(),
            tolerance: t,
            error: 3.0 * t,
            gpu_bytes: 12e6 / t.log10().abs(),
            dense_gpu_bytes: 38e6,
        });
        write_plot(&path, &rows, &["cube"], &mem).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (1340, 480));
        let right = (780..1340)
            .flat_map(|x| (0..480).map(move |y| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0 == [230u8, 25, 75])
            .count();
        assert!(right > 20, "memory markers: {right} pixels");
        // The three visual methods' colours are drawn (black, red, green markers).
        for c in [[230u8, 25, 75], [60, 180, 75]] {
            let n = img.pixels().filter(|p| p.0 == c).count();
            assert!(n > 10, "colour {c:?}: {n} pixels");
        }
    }
}

mod ladder {
    use touchfem_lab::ladder::*;

    #[test]
    fn richardson_recovers_a_known_limit() {
        // f(h) = 2 + 3 h²: at h = 1, 1/2, 1/4.
        let (l, p) = richardson([5.0, 2.75, 2.1875], 2.0).unwrap();
        assert!(
            (l - 2.0).abs() < 1e-12 && (p - 2.0).abs() < 1e-12,
            "{l} {p}"
        );
        assert!(richardson([1.0, 2.0, 1.5], 2.0).is_none());
    }
}

mod hertz {
    use touchfem_lab::hertz::*;

    #[test]
    #[ignore = "a study: run with --release --ignored --nocapture"]
    fn hertz_scratch() {
        let h: f64 = std::env::var("H")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.5);
        let nu: f64 = std::env::var("NU")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.3);
        let scale: f64 = std::env::var("SCALE")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(1.0);
        let mut setup = HertzSetup::block(nu, h);
        setup.size_mm = setup.size_mm.map(|v| v * scale);
        let t = std::time::Instant::now();
        let table = study(&setup).unwrap();
        println!("{}", serde_json::to_string_pretty(&table).unwrap());
        println!("took {:?}", t.elapsed());
    }

    /// The docs' plot and table: `cargo test --release --features app --test it hertz_docs -- --ignored`.
    #[test]
    #[ignore = "writes docs/fingertip_hertz.png; a study"]
    fn hertz_docs() {
        let mut tables = Vec::new();
        for (nu, h, scale) in [
            (0.3, 0.7, 1.0),
            (0.3, 0.35, 1.0),
            (0.45, 0.7, 1.0),
            (0.3, 1.0, 4.0),
        ] {
            let mut s = HertzSetup::block(nu, h);
            s.size_mm = s.size_mm.map(|v| v * scale);
            let t = study(&s).unwrap();
            println!(
                "nu {nu} h {h} mm block ×{scale}: nodes {} exponent {:.4} prefactor {:.4} point exponent {:.4} contacts {:?}",
                t.nodes,
                t.exponent,
                t.prefactor_ratio,
                t.point_exponent,
                t.rows.iter().map(|r| r.contact_nodes).collect::<Vec<_>>()
            );
            for r in &t.rows {
                println!(
                    "  d {:.1} mm: sphere {:.5} N hertz {:.5} N point {:.5} N",
                    r.depth_m * 1e3,
                    r.sphere_n,
                    r.hertz_n,
                    r.point_n
                );
            }
            tables.push((format!("ν {nu}, h {h} mm, block ×{scale}"), t));
        }
        let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/fingertip_hertz.png");
        write_plot(&out, &tables).unwrap();
    }
}

mod cg {
    use touchfem::fem::Stiffness;
    use touchfem_lab::cg::*;

    #[test]
    fn cg_matches_the_direct_solve_and_warm_starts_cut_the_iterations() {
        let mesh = touchfem_core::mesh::cube();
        let k = Stiffness::assemble(&mesh).unwrap();
        let f = k.factorize().unwrap();
        let n = k.dofs.n_free;
        let mut cg = CgSolver::new(&k);
        let mut b = vec![0.0; n];
        b[n - 1] = -0.1;
        b[n - 5] = 0.05;
        let mut direct = faer::Mat::<f64>::zeros(n, 1);
        for (i, v) in b.iter().enumerate() {
            direct[(i, 0)] = *v;
        }
        f.solve_in_place(&mut direct);
        let cold = cg.solve(&b, 1e-12, 10_000);
        assert!(cold.converged, "{cold:?}");
        let scale = (0..n).map(|i| direct[(i, 0)].abs()).fold(0.0, f64::max);
        let err = (0..n)
            .map(|i| (cg.solution()[i] - direct[(i, 0)]).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-9 * scale, "{err:e} of {scale:e}");
        // A slightly different load (0.1 %) from the last solution: the residual starts 1000×
        // smaller, so CG needs about half the iterations for 1e-6.
        b[n - 1] = -0.1001;
        let warm = cg.solve(&b, 1e-6, 10_000);
        cg.reset();
        let fresh = cg.solve(&b, 1e-6, 10_000);
        assert!(warm.converged && fresh.converged);
        assert!(
            warm.iterations * 3 <= fresh.iterations * 2,
            "warm {} vs cold {}",
            warm.iterations,
            fresh.iterations
        );
        // A zero load is solved by zero.
        let z = cg.solve(&vec![0.0; n], 1e-8, 10);
        assert_eq!(z.iterations, 0);
        assert!(cg.solution().iter().all(|v| *v == 0.0));
    }
}
