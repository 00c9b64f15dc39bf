//! What a finger touches with (a point or a sphere) and an object's Coulomb friction, with the
//! checks a scene file or a flag goes through.

use thiserror::Error;

/// A tool or friction value that cannot be used. The message names the value at fault; the
/// scene loader and the command line add the key or flag.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ContactError {
    /// A sphere's radius that is not a positive finite length.
    #[error("sphere radius {0} must be a positive, finite length")]
    Radius(f64),
    /// A sphere larger than the object it is meant to touch.
    #[error("sphere radius {radius_m} m is larger than the object ({extent_m} m across)")]
    RadiusTooLarge {
        /// The radius, m.
        radius_m: f64,
        /// The object's bounding-box diagonal, m.
        extent_m: f64,
    },
    /// A friction coefficient that is negative or not finite.
    #[error("friction coefficient {which} = {value} must be finite and >= 0")]
    Coefficient {
        /// `static` or `dynamic`.
        which: &'static str,
        /// The value given.
        value: f64,
    },
    /// A dynamic coefficient above the static one.
    #[error("dynamic friction {dynamic_mu} exceeds static friction {static_mu}")]
    DynamicAboveStatic {
        /// μ_s.
        static_mu: f64,
        /// μ_d.
        dynamic_mu: f64,
    },
}

/// What a finger touches with.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum Tool {
    /// The paper's point and its god-object (the default).
    #[default]
    Point,
    /// A rigid sphere (a fingertip, a ball-ended probe) centred on the device position, that
    /// presses an area of the deformed surface ([`crate::contact::Patch`]).
    Sphere {
        /// Radius, m.
        radius_m: f64,
    },
}

impl Tool {
    /// A sphere of radius `radius_m` (m), checked: positive and finite.
    pub fn sphere(radius_m: f64) -> Result<Tool, ContactError> {
        if radius_m.is_finite() && radius_m > 0.0 {
            Ok(Tool::Sphere { radius_m })
        } else {
            Err(ContactError::Radius(radius_m))
        }
    }

    /// The sphere's radius, m (`None` for a point).
    pub fn radius(&self) -> Option<f64> {
        match *self {
            Tool::Point => None,
            Tool::Sphere { radius_m } => Some(radius_m),
        }
    }

    /// Checks the tool against the object it will touch: a sphere must not be larger than the
    /// object's bounding-box diagonal `extent_m`.
    pub fn check_fits(&self, extent_m: f64) -> Result<(), ContactError> {
        match *self {
            Tool::Sphere { radius_m } if radius_m > extent_m => {
                Err(ContactError::RadiusTooLarge { radius_m, extent_m })
            }
            _ => Ok(()),
        }
    }
}

/// Coulomb friction of an object: a contact sticks while its tangential force stays inside
/// the static cone `|F_t| ≤ μ_s F_n`, and slides at the edge of the dynamic cone
/// `|F_t| = μ_d F_n` once it slips (until it sticks again inside the dynamic cone).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Friction {
    /// The static coefficient μ_s.
    pub static_mu: f64,
    /// The dynamic coefficient μ_d ≤ μ_s.
    pub dynamic_mu: f64,
}

impl Friction {
    /// Friction with static `static_mu` and dynamic `dynamic_mu`, checked: both finite and
    /// ≥ 0, dynamic ≤ static.
    pub fn new(static_mu: f64, dynamic_mu: f64) -> Result<Friction, ContactError> {
        for (which, value) in [("static", static_mu), ("dynamic", dynamic_mu)] {
            if !value.is_finite() || value < 0.0 {
                return Err(ContactError::Coefficient { which, value });
            }
        }
        if dynamic_mu > static_mu {
            return Err(ContactError::DynamicAboveStatic {
                static_mu,
                dynamic_mu,
            });
        }
        Ok(Friction {
            static_mu,
            dynamic_mu,
        })
    }

    /// True when both coefficients are zero (no friction at all).
    pub fn is_none(&self) -> bool {
        self.static_mu == 0.0 && self.dynamic_mu == 0.0
    }
}
