//! The out-of-core factorisation (`touchfem::fem::frontal`): its factor against faer's, its bits on
//! any number of threads, the precompute from a factor in a file against one in memory, its
//! errors, and the pages it leaves mapped.

use touchfem::compliance::{Compliance, Method, NodeSet, Selection};
use touchfem::fem::{FactorStore, FemError, Ordering, Stiffness};
use touchfem::mesh::{cube_with, mouse};
use touchfem::Material;

fn file(threads: usize) -> FactorStore {
    FactorStore::File {
        dir: std::env::temp_dir(),
        threads,
    }
}

/// The values of a supernodal factor.
fn values(f: &touchfem::fem::Factor) -> Vec<f64> {
    f.supernodal().expect("supernodal").1.to_vec()
}

#[test]
fn the_file_factor_equals_faers_and_its_bits_do_not_depend_on_threads() {
    let m = mouse();
    let k = Stiffness::assemble(&m).unwrap();
    let (heap, _, _) = k.factorize_in(Ordering::Metis, &FactorStore::Heap).unwrap();
    assert!(!heap.is_mapped());
    let (one, _, _) = k.factorize_in(Ordering::Metis, &file(1)).unwrap();
    assert!(one.is_mapped());
    assert!(one.front_bytes() > 0 && heap.front_bytes() == 0);
    let (a, b) = (values(&heap), values(&one));
    assert_eq!(a.len(), b.len());
    let max = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let diff = a
        .iter()
        .zip(&b)
        .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
    // Both are the Cholesky factor of one matrix, summed in different orders.
    assert!(
        diff <= 1e-13 * max,
        "relative difference {:.2e}",
        diff / max
    );
    for t in [2, 3, 5] {
        let (f, _, _) = k.factorize_in(Ordering::Metis, &file(t)).unwrap();
        let c = values(&f);
        assert!(
            b.iter().zip(&c).all(|(p, q)| p.to_bits() == q.to_bits()),
            "{t} threads"
        );
    }
}

#[test]
fn auto_keeps_small_factors_in_memory() {
    let m = mouse();
    let k = Stiffness::assemble(&m).unwrap();
    let auto = |above| FactorStore::Auto {
        dir: std::env::temp_dir(),
        threads: 2,
        above,
    };
    let (f, _, _) = k.factorize_in(Ordering::Metis, &auto(usize::MAX)).unwrap();
    assert!(!f.is_mapped());
    let (f, _, _) = k.factorize_in(Ordering::Metis, &auto(0)).unwrap();
    assert!(f.is_mapped());
}

/// max |a − b| / max |a| over the stored entries (same selection, same order).
fn relative(a: &Compliance, b: &Compliance) -> f64 {
    assert_eq!(a.rows(), b.rows());
    assert_eq!(a.cols(), b.cols());
    let max = a.l_f64().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(max > 0.0);
    let d = a
        .l_f64()
        .iter()
        .zip(b.l_f64())
        .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
    d / max
}

#[test]
fn the_precompute_from_a_file_factor_equals_the_one_in_memory() {
    let m = mouse();
    // A patch (the column method's pruned sweeps) and the whole surface (the Gram method).
    let c = m.nodes[m.free_surface_nodes()[0] as usize];
    let patch: Vec<u32> = m
        .free_surface_nodes()
        .into_iter()
        .filter(|&n| (m.nodes[n as usize] - c).length() < 0.012)
        .collect();
    assert!(patch.len() > 5);
    for (sel, how, method) in [
        (
            Selection {
                rows: NodeSet::Surface,
                cols: NodeSet::Nodes(patch),
            },
            Method::Columns,
            "columns",
        ),
        (Selection::default(), Method::Gram, "gram"),
    ] {
        let heap =
            Compliance::compute_in(&m, &sel, how, &FactorStore::Heap, &mut |_, _| {}).unwrap();
        let mapped = Compliance::compute_in(&m, &sel, how, &file(2), &mut |_, _| {}).unwrap();
        assert_eq!(mapped.stats.phases.method, method);
        assert!(mapped.stats.phases.factor_in_file && !heap.stats.phases.factor_in_file);
        assert!(mapped.stats.residual < 1e-9, "{}", mapped.stats.residual);
        let d = relative(&heap, &mapped);
        assert!(d < 1e-12, "{method}: relative difference {d:.2e}");
    }
}

#[test]
fn a_negative_pivot_names_its_node() {
    let m = cube_with([4, 4, 4], [30.0, 30.0, 30.0], Material::DEFAULT).unwrap();
    let mut k = Stiffness::assemble(&m).unwrap();
    // Free DOF 40's diagonal made negative: its pivot is at most that, so the factorisation
    // must stop at its node, whatever the order.
    let d = 40;
    {
        let col = k.k.as_ref().col_ptr()[d];
        let rows: Vec<usize> = k.k.as_ref().row_idx_of_col(d).collect();
        let at = col + rows.iter().position(|&r| r == d).expect("diagonal");
        let v = &mut k.k.val_mut()[at];
        *v = -v.abs();
    }
    let owner = k.dofs.owner[d].0;
    for store in [file(1), file(2), FactorStore::Heap] {
        match k.factorize_in(Ordering::Metis, &store) {
            Err(FemError::Singular { node, dof }) => {
                // The node is exact; faer's blocked dense Cholesky may name a later pivot of
                // the same block (here the node's next DOF), in memory and in the file alike.
                assert_eq!(node, owner, "{store:?}");
                assert_eq!(k.dofs.owner[dof].0, owner, "{store:?}: DOF {dof}");
            }
            Err(e) => panic!("{store:?}: another error: {e}"),
            Ok(_) => panic!("{store:?}: a negative pivot was factorised"),
        }
    }
}

/// Resident bytes of the mapping that holds `addr` (from /proc/self/smaps).
fn resident_of_map(addr: usize) -> Option<usize> {
    let smaps = std::fs::read_to_string("/proc/self/smaps").ok()?;
    let mut inside = false;
    for line in smaps.lines() {
        let head = line.split_whitespace().next().unwrap_or("");
        if let Some((lo, hi)) = head.split_once('-') {
            if let (Ok(lo), Ok(hi)) = (usize::from_str_radix(lo, 16), usize::from_str_radix(hi, 16))
            {
                inside = lo <= addr && addr < hi;
                continue;
            }
        }
        if inside {
            if let Some(kb) = line.strip_prefix("Rss:") {
                return kb
                    .trim()
                    .trim_end_matches("kB")
                    .trim()
                    .parse::<usize>()
                    .ok()
                    .map(|k| k * 1024);
            }
        }
    }
    None
}

#[test]
fn a_solve_from_the_file_leaves_its_pages_unmapped() {
    let m = cube_with([14, 14, 14], [30.0, 30.0, 30.0], Material::DEFAULT).unwrap();
    let k = Stiffness::assemble(&m).unwrap();
    let (f, _, _) = k.factorize_in(Ordering::Metis, &file(2)).unwrap();
    let bytes = 8 * f.nonzeros();
    assert!(
        bytes > 8 << 20,
        "a factor of {bytes} bytes is too small to tell"
    );
    let addr = f.supernodal().unwrap().1.as_ptr() as usize;
    let after_factor = resident_of_map(addr).expect("the factor's mapping");
    assert!(
        after_factor < bytes / 8,
        "{after_factor} of {bytes} bytes mapped after the factorisation"
    );
    // Every supernode visited: the full solve of one column.
    let shown = m.free_surface_nodes();
    let dofs = &k.dofs;
    let u = touchfem::fem::gram::UnitSolver::new(
        &f,
        shown
            .iter()
            .flat_map(|&r| (0..3).filter_map(move |a| dofs.free(r, a))),
    )
    .unwrap();
    let mut x = faer::Mat::<f64>::zeros(k.dofs.n_free, 1);
    u.solve_full(&f, &[7], x.as_mut());
    let after_solve = resident_of_map(addr).expect("the factor's mapping");
    assert!(
        after_solve < bytes / 8,
        "{after_solve} of {bytes} bytes mapped after a solve"
    );
    // The solve is right: K·x = e₇.
    let xs: Vec<f64> = (0..k.dofs.n_free).map(|d| x[(u.row(d), 0)]).collect();
    let mut kx = vec![0.0; xs.len()];
    k.mul(&xs, &mut kx);
    let scale = xs.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (i, v) in kx.iter().enumerate() {
        let e = if i == 7 { 1.0 } else { 0.0 };
        assert!((v - e).abs() < 1e-9, "row {i}: {v} (max |x| {scale:.2e})");
    }
}

#[test]
fn a_directory_that_cannot_hold_the_file() {
    let m = mouse();
    let k = Stiffness::assemble(&m).unwrap();
    let nowhere = std::path::PathBuf::from("/nonexistent/touchfem-factor");
    // `Auto` falls back to memory, with the same values.
    let auto = FactorStore::Auto {
        dir: nowhere.clone(),
        threads: 2,
        above: 0,
    };
    let (f, _, _) = k.factorize_in(Ordering::Metis, &auto).unwrap();
    assert!(!f.is_mapped());
    let (heap, _, _) = k.factorize_in(Ordering::Metis, &FactorStore::Heap).unwrap();
    assert_eq!(values(&f), values(&heap));
    // `File` is a typed error naming the directory.
    let file = FactorStore::File {
        dir: nowhere,
        threads: 2,
    };
    match k.factorize_in(Ordering::Metis, &file) {
        Err(FemError::Factorisation(msg)) => {
            assert!(msg.contains("/nonexistent/touchfem-factor"), "{msg}")
        }
        Err(e) => panic!("another error: {e}"),
        Ok(_) => panic!("factorised into a directory that does not exist"),
    }
}
