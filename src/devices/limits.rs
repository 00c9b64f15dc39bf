//! What a device can render, in the manner of CHAI3D's `cHapticDeviceInfo`: the largest force,
//! and the largest stiffness and damping it renders stably at 1 kHz. The virtual coupling
//! ([`crate::runtime::coupling`]) is sized from these.

/// A device's limits (SI).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DeviceLimits {
    /// Its name.
    pub name: String,
    /// Peak force, N.
    pub max_force_n: f64,
    /// Force it can hold indefinitely, N, where the vendor states one.
    pub max_continuous_force_n: Option<f64>,
    /// Largest stiffness rendered stably at 1 kHz, N/m.
    pub max_stiffness_n_per_m: f64,
    /// Largest damping rendered stably at 1 kHz, N·s/m.
    pub max_damping_ns_per_m: f64,
    /// Radius of the workspace, m.
    pub workspace_radius_m: f64,
}

/// The named presets.
pub const PRESETS: &[&str] = &["falcon"];

impl DeviceLimits {
    /// A named preset: `falcon` (Novint Falcon; the numbers of CHAI3D's `cFalconDevice`: 8 N,
    /// 3000 N/m, 20 N·s/m, 0.04 m; no continuous force stated).
    pub fn preset(name: &str) -> Option<DeviceLimits> {
        match name {
            "falcon" => Some(DeviceLimits {
                name: "falcon".into(),
                max_force_n: 8.0,
                max_continuous_force_n: None,
                max_stiffness_n_per_m: 3000.0,
                max_damping_ns_per_m: 20.0,
                workspace_radius_m: 0.04,
            }),
            _ => None,
        }
    }
}
