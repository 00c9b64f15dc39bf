//! Measures `serve --haply` against the mock Haply Inverse Service on loopback (no hardware):
//! the cube, a cursor that presses 3 mm into its top face and holds, for S seconds. Prints one
//! JSON line: the sustained exchange rate (state updates per second), the round trip (command
//! sent → state received) median and p99, the haptic tick's median step and period error, and
//! the process's CPU use (user + system seconds per wall second, every thread).
//!
//! ```sh
//! cargo run --release --features app --example haply_loopback -- 10
//! ```

use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use touchfem::runtime::serve::{haply_world, LoopOptions};
use touchfem_app::haply::mock::{MockConfig, MockService};
use touchfem_app::haply::{serve_haply, HaplyOptions};

fn cpu_seconds() -> f64 {
    // SAFETY: getrusage writes into the zeroed struct it is given.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

fn main() {
    let Some(secs) = std::env::args()
        .nth(1)
        .and_then(|s| s.parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s > 0.0 && *s <= 3600.0)
    else {
        eprintln!("usage: haply_loopback SECONDS   (serve the cube against a mock Haply Inverse Service for SECONDS, in (0, 3600])");
        std::process::exit(2);
    };
    // Device frame: the default workspace centre maps to the top face's middle; 3 mm below it.
    let mock = MockService::start(MockConfig::one("049D", |t| {
        let z = if t < 0.3 { 0.156 } else { 0.147 };
        [-0.003, -0.121, z]
    }))
    .expect("a loopback port");
    let world = haply_world("cube", Some(&mock.url()), None).expect("the cube");
    let opts = HaplyOptions {
        loop_options: LoopOptions {
            seconds: Some(secs),
            ..LoopOptions::default()
        },
        watchdog: Duration::from_millis(20),
    };
    let (wall0, cpu0) = (Instant::now(), cpu_seconds());
    let r = serve_haply(&world, &opts, &AtomicBool::new(false), |_| {}).expect("serve");
    let (wall, cpu) = (wall0.elapsed().as_secs_f64(), cpu_seconds() - cpu0);
    let log = mock.stop();
    let c = &r.haply[0];
    println!(
        "{}",
        serde_json::json!({
            "seconds": secs,
            "rate_hz": c.rate_hz,
            "rtt_us_p50": c.rtt_us_p50,
            "rtt_us_p99": c.rtt_us_p99,
            "states": c.states,
            "messages": c.messages,
            "stale": c.stale,
            "malformed": c.malformed,
            "step_us_median": r.run.haptic.step_us_median,
            "haptic_rate_hz": r.run.haptic.haptic_rate_hz,
            "period_error_us_p999": r.run.haptic.period_error_us_p999,
            "missed_deadlines": r.run.haptic.missed_deadlines,
            "max_force_n": r.run.max_force_n,
            "last_force": log.received.last().map(|m| m.force),
            "cpu_per_wall": cpu / wall,
        })
    );
}
