//! The page's measurements, natively: the same calls the page makes ([`touchfem_web::page`]),
//! timed the same way, for the measurement page's native column.
//!
//! `cargo run --profile web -p touchfem-web --example page_native -- SCENE PRESS [CACHE]`
//! (e.g. `mouse -10,0,60:0,0,-8 target/web/cache/mouse.tfc`) prints one JSON object:
//! `compliance_ms` (computed), `cache_ms` (read from CACHE, when given), `step_us` (the pointer
//! held where the press ended, 1000 ticks, as the page times it) and `force`.
//!
//! `page_native SCENE --run SECONDS` runs the scene's scripts as the page's `run=SECONDS` does
//! (`PageWorld::run_scripts`, a cut pass every 16 ticks) and prints `load_ms` (the compliance
//! and the cutter's factorisation), `run_ms`, `tets_removed`, `nodes_split` and `cut_bodies`.
use std::time::Instant;
use touchfem_web::page::{PageWorld, PressSpec, POKE_STEPS};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() == 3 && args[1] == "--run" {
        let run = || -> Result<serde_json::Value, Box<dyn std::error::Error>> {
            let seconds: f64 = args[2].parse()?;
            let t = Instant::now();
            let mut p = PageWorld::load(&args[0], None)?;
            let load_ms = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            p.run_scripts(seconds)?;
            Ok(serde_json::json!({
                "scene": args[0],
                "load_ms": load_ms,
                "run_ms": t.elapsed().as_secs_f64() * 1e3,
                "tets_removed": p.tets_removed,
                "nodes_split": p.nodes_split,
                "cut_bodies": p.cut_bodies,
            }))
        };
        match run() {
            Ok(v) => println!("{v}"),
            Err(e) => {
                eprintln!("error: {e}");
                std::process::exit(2);
            }
        }
        return;
    }
    if args.len() < 2 || args.len() > 3 {
        eprintln!("usage: page_native SCENE X,Y,Z:DX,DY,DZ [CACHE_FILE]");
        eprintln!("       page_native SCENE --run SECONDS");
        std::process::exit(2);
    }
    let run = || -> Result<serde_json::Value, Box<dyn std::error::Error>> {
        let t = Instant::now();
        let mut p = PageWorld::load(&args[0], None)?;
        let compliance_ms = t.elapsed().as_secs_f64() * 1e3;
        let cache_ms = match args.get(2) {
            Some(f) => {
                let bytes = std::fs::read(f)?;
                let t = Instant::now();
                let _ = PageWorld::load(&args[0], Some(&bytes))?;
                Some(t.elapsed().as_secs_f64() * 1e3)
            }
            None => None,
        };
        let out = p.press(&PressSpec::parse(&args[1])?, POKE_STEPS)?;
        p.set_pointer(out.finger);
        p.tick(10);
        let t = Instant::now();
        for _ in 0..10 {
            p.tick(100);
        }
        let step_us = t.elapsed().as_secs_f64() * 1e6 / 1000.0;
        Ok(serde_json::json!({
            "scene": args[0],
            "compliance_ms": compliance_ms,
            "cache_ms": cache_ms,
            "step_us": step_us,
            "force": out.force.to_array(),
        }))
    };
    match run() {
        Ok(v) => println!("{v}"),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(2);
        }
    }
}
