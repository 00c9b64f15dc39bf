//! `touchfem serve SCENE --haply [URL]` (and a scene's own Haply fingers without `--udp`).

use crate::args::ServeArgs;
use crate::error::Error;

use super::{serve_haply, HaplyOptions};

/// Runs `serve` for Haply fingers (`a.udp` is `None`).
pub fn serve(a: &ServeArgs) -> Result<(), Error> {
    use touchfem_core::runtime::serve::{haply_world, stop_on_interrupt, LoopOptions, INTERRUPTED};
    use touchfem_core::scene::SceneSource;
    if a.haply.is_none() && SceneSource::find(&a.scene)?.is_none() {
        return Err(Error::Input(format!(
            "serve {}: give --udp ADDR (UDP fingers) or --haply [URL] (a Haply Inverse3)",
            a.scene
        )));
    }
    let udp_only = [
        (a.key.is_some(), "--key"),
        (a.allow_remote, "--allow-remote"),
        (
            a.clock != touchfem_core::devices::udp::Clock::Host,
            "--clock",
        ),
        (a.view, "--view"),
    ];
    if let Some((_, flag)) = udp_only.iter().find(|(on, _)| *on) {
        return Err(Error::Input(format!(
            "{flag} serves UDP fingers only (with --udp ADDR); not a Haply finger"
        )));
    }
    let limits = match &a.limits {
        Some(name) => Some(
            touchfem_core::devices::limits::DeviceLimits::named(name)
                .map_err(|e| Error::Input(format!("--limits: {e}")))?,
        ),
        None => None,
    };
    let world = haply_world(&a.scene, a.haply.as_deref(), limits.as_ref())?;
    stop_on_interrupt();
    let opts = HaplyOptions {
        loop_options: LoopOptions {
            seconds: a.seconds,
            record: a.record.clone(),
            placement: touchfem_core::threads::VisualPlacement::split(),
            floor_seconds: a.floor_seconds,
        },
        watchdog: std::time::Duration::from_secs_f64(a.haply_watchdog_ms * 1e-3),
    };
    let report = serve_haply(&world, &opts, &INTERRUPTED, |ids| {
        eprintln!("driving Haply Inverse3 {}", ids.join(", "));
    })?;
    crate::report::report_out(
        &report,
        a.report.as_deref(),
        report.run.recording_error.as_deref(),
    )
}
