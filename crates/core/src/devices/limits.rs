//! What a device can render, in the manner of CHAI3D's `cHapticDeviceInfo`: the largest force,
//! and the largest stiffness and damping it renders stably at 1 kHz. The virtual coupling
//! (the runtime's `coupling`) is sized from these.
//!
//! The presets carry the numbers CHAI3D's own drivers declare for each device
//! (`cFalconDevice`, `cPhantomDevices`, `CDeltaDevices`): peak force, the closed-loop stiffness
//! and damping they render stably, and the workspace radius. No vendor states a continuous
//! force there, so `max_continuous_force_n` is `None` for all of them.
//!
//! `inverse3` (Haply Robotics Inverse3, driven through the Haply Inverse Service) carries the
//! numbers the Inverse3's CHAI3D driver declares (`cHaplyDevices`, the CHAI3D port of Haply's
//! HardwareAPI, `src/devices/CHaplyDevices.cpp`: `m_maxLinearForce = 10.0`,
//! `m_maxLinearStiffness = 1000.0`, `m_maxLinearDamping = 6.0`, `m_workspaceRadius = 0.15`),
//! the same kind of source as the others. Haply's product page
//! (<https://www.haply.co/inverse3>) is the reference to check them against; its published
//! peak force is the one this bound must never exceed.

/// A device's limits (SI).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceLimits {
    /// Its name.
    pub name: String,
    /// Peak force, N.
    pub max_force_n: f64,
    /// Force it can hold indefinitely, N, where the vendor states one.
    #[serde(default)]
    pub max_continuous_force_n: Option<f64>,
    /// Largest stiffness rendered stably at 1 kHz, N/m.
    pub max_stiffness_n_per_m: f64,
    /// Largest damping rendered stably at 1 kHz, N·s/m.
    pub max_damping_ns_per_m: f64,
    /// Radius of the workspace, m.
    pub workspace_radius_m: f64,
}

/// The named presets: name, peak force (N), stiffness (N/m), damping (N·s/m), workspace
/// radius (m), as CHAI3D 3.x declares them.
const TABLE: &[(&str, f64, f64, f64, f64)] = &[
    // Novint Falcon (cFalconDevice).
    ("falcon", 8.0, 3000.0, 20.0, 0.04),
    // 3D Systems / SensAble PHANTOM Omni, today's Touch (cPhantomDevice, "PHANTOM Omni").
    ("phantom-omni", 4.0, 700.0, 5.0, 0.10),
    // PHANTOM Premium 1.5 6DOF (cPhantomDevice).
    ("phantom-premium-1.5", 4.0, 800.0, 5.0, 0.10),
    // Force Dimension delta.3 (cDeltaDevice, DHD_DEVICE_DELTA3).
    ("delta.3", 20.0, 5000.0, 30.0, 0.15),
    // Force Dimension omega.3 (cDeltaDevice, DHD_DEVICE_OMEGA3).
    ("omega.3", 12.0, 5000.0, 30.0, 0.075),
    // Force Dimension sigma.7 (cDeltaDevice, DHD_DEVICE_SIGMA331).
    ("sigma.7", 12.0, 4000.0, 30.0, 0.075),
    // Haply Robotics Inverse3 (cHaplyDevices, C_HAPTIC_DEVICE_HAPLY_INVERSE3; see the module
    // docs).
    ("inverse3", 10.0, 1000.0, 6.0, 0.15),
];

/// The named presets.
pub(crate) const PRESETS: &[&str] = &[
    "falcon",
    "phantom-omni",
    "phantom-premium-1.5",
    "delta.3",
    "omega.3",
    "sigma.7",
    "inverse3",
];

/// Why limits are not usable.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LimitsError {
    /// Not a preset's name.
    #[error("'{0}' is not a device preset: use one of {presets}", presets = PRESETS.join(", "))]
    UnknownPreset(String),
    /// A number that is not finite and positive.
    #[error("{0} must be finite and positive, not {1}")]
    NotPositive(&'static str, f64),
}

impl DeviceLimits {
    /// A named preset (see `PRESETS`); e.g. `falcon`: 8 N, 3000 N/m, 20 N·s/m, 0.04 m.
    pub fn preset(name: &str) -> Option<DeviceLimits> {
        TABLE
            .iter()
            .find(|p| p.0 == name)
            .map(|&(name, f, k, b, r)| DeviceLimits {
                name: name.into(),
                max_force_n: f,
                max_continuous_force_n: None,
                max_stiffness_n_per_m: k,
                max_damping_ns_per_m: b,
                workspace_radius_m: r,
            })
    }

    /// [`DeviceLimits::preset`] with a typed error naming the presets.
    pub fn named(name: &str) -> Result<DeviceLimits, LimitsError> {
        Self::preset(name).ok_or_else(|| LimitsError::UnknownPreset(name.into()))
    }

    /// Checks that every number is finite and positive.
    pub fn validate(&self) -> Result<(), LimitsError> {
        let mut checks = vec![
            ("max_force_n", self.max_force_n),
            ("max_stiffness_n_per_m", self.max_stiffness_n_per_m),
            ("max_damping_ns_per_m", self.max_damping_ns_per_m),
            ("workspace_radius_m", self.workspace_radius_m),
        ];
        if let Some(c) = self.max_continuous_force_n {
            checks.push(("max_continuous_force_n", c));
        }
        for (k, v) in checks {
            if !(v.is_finite() && v > 0.0) {
                return Err(LimitsError::NotPositive(k, v));
            }
        }
        Ok(())
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn every_preset_resolves_and_is_valid() {
        for p in PRESETS {
            let l = DeviceLimits::named(p).unwrap();
            assert_eq!(l.name, *p);
            l.validate().unwrap();
        }
        assert_eq!(PRESETS.len(), TABLE.len());
        let f = DeviceLimits::preset("falcon").unwrap();
        assert_eq!(
            (
                f.max_force_n,
                f.max_stiffness_n_per_m,
                f.max_damping_ns_per_m
            ),
            (8.0, 3000.0, 20.0)
        );
        let i = DeviceLimits::preset("inverse3").unwrap();
        assert_eq!((i.max_force_n, i.max_stiffness_n_per_m), (10.0, 1000.0));
        assert!(matches!(
            DeviceLimits::named("phantom"),
            Err(LimitsError::UnknownPreset(_))
        ));
        let mut bad = f.clone();
        bad.max_stiffness_n_per_m = f64::NAN;
        assert!(bad.validate().is_err());
    }
}
