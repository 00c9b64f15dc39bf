//! The locking-free study in small (`touchfem_lab::locking_free`; the full one is
//! `touchfem bench --hard`): on both loads, at ν = 0.4999, the pressure projection — the
//! formulation's element — is the most accurate of the five against a converged reference,
//! by a margin, and at ν = 0.3 no worse than the standard element; on the issue's load (the
//! point press), against the bench's finer references, it meets the issue's floors and aim
//! on the coarse 4³ mesh.

use touchfem::fem::locking_free::Smoothing;
use touchfem_lab::locking_free::{study, Load, Method};

#[test]
fn the_pressure_projection_is_the_most_accurate_near_incompressibility_on_both_loads() {
    let proj = Method::LockingFree(Smoothing::Projection);
    let bubble = Method::LockingFree(Smoothing::Bubble);
    let nodal = Method::LockingFree(Smoothing::Nodal);
    for load in Load::ALL {
        // References from 4³, 8³, 16³ (the bench uses 8³–32³): rough (the point press's
        // extrapolations differ by up to 12 %), but the margins below are wider.
        let (rows, refs) = study(load, &[0.3, 0.4999], &[4], [4, 8, 16]).expect("study");
        for r in &refs {
            assert!(
                r.spread < 0.2,
                "{load:?} ν {}: spread {}",
                r.poisson,
                r.spread
            );
        }
        let err = |m: Method, nu: f64| {
            rows.iter()
                .find(|r| r.method == m && r.poisson == nu && r.cells == 4)
                .map(|r| r.field_error)
                .expect("row")
        };
        let (p, b, n, st) = (
            err(proj, 0.4999),
            err(bubble, 0.4999),
            err(nodal, 0.4999),
            err(Method::Standard, 0.4999),
        );
        let (p3, st3) = (err(proj, 0.3), err(Method::Standard, 0.3));
        eprintln!(
            "{load:?} 4³ at ν 0.4999: projection {p:.3}, bubble {b:.3}, nodal {n:.3}, \
             standard {st:.3}; at ν 0.3: projection {p3:.3}, standard {st3:.3}"
        );
        assert!(p < 0.75 * b.min(n).min(st), "{load:?}: {p} {b} {n} {st}");
        assert!(p3 <= 1.05 * st3, "{load:?} at ν 0.3: {p3} against {st3}");
    }
}

/// The issue's floors and its aim on its own test (the point press, compared away from the
/// load) on the coarse 4³ mesh, against references extrapolated from 8³, 16³ and 32³ as the
/// bench's are: the pressure projection at ν = 0.4999 within 1.5× of standard's error at
/// ν = 0.3 (the floor is 2.5×), and at most a third of standard's own error at ν = 0.4999.
#[test]
fn on_the_point_press_the_pressure_projection_meets_the_issues_floors_and_aim() {
    use touchfem_lab::locking_free::{field_error, richardson, solve};
    let proj = Method::LockingFree(Smoothing::Projection);
    let load = Load::PointPress;
    let reference = |m: Method, nu: f64| {
        let s: Vec<_> = [8, 16, 32]
            .iter()
            .map(|&c| solve(m, load, c, 4, nu).expect("solve"))
            .collect();
        let (_, order, field) = richardson([&s[0], &s[1], &s[2]]).expect("converges");
        assert!((1.5..3.0).contains(&order), "{m:?} ν {nu}: order {order}");
        field
    };
    let (r3, r5) = (reference(Method::Standard, 0.3), reference(proj, 0.4999));
    let err = |m: Method, nu: f64, r: &[glam::DVec3]| {
        field_error(&solve(m, load, 4, 4, nu).expect("solve").probes, r)
    };
    let st3 = err(Method::Standard, 0.3, &r3);
    let st5 = err(Method::Standard, 0.4999, &r5);
    let p5 = err(proj, 0.4999, &r5);
    eprintln!(
        "4³: projection at ν 0.4999 {p5:.3}; standard at ν 0.3 {st3:.3}, at ν 0.4999 {st5:.3}"
    );
    assert!(p5 <= 1.5 * st3, "{p5} against {st3}");
    assert!(p5 <= st5 / 3.0, "{p5} against {st5}");
}
