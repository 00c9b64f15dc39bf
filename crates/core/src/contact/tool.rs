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
    /// A blade's depth that is not a positive finite length.
    #[error("blade depth {0} must be a positive, finite length")]
    Depth(f64),
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
    /// A blade ([`crate::runtime::cutting`]): the segment from the device position down to
    /// `depth_m` below it, along the inward surface normal where it entered; moving through a
    /// cuttable object it removes every tet its swept surface crosses. It presses nothing
    /// (the device feels no force from it: the resistance of tissue to a blade is not
    /// modelled).
    Blade {
        /// Depth, m.
        depth_m: f64,
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

    /// A blade of depth `depth_m` (m), checked: positive and finite.
    pub fn blade(depth_m: f64) -> Result<Tool, ContactError> {
        if depth_m.is_finite() && depth_m > 0.0 {
            Ok(Tool::Blade { depth_m })
        } else {
            Err(ContactError::Depth(depth_m))
        }
    }
    /// The sphere's radius, m (`None` for a point or a blade).
    pub fn radius(&self) -> Option<f64> {
        match *self {
            Tool::Sphere { radius_m } => Some(radius_m),
            Tool::Point | Tool::Blade { .. } => None,
        }
    }
    /// The blade's depth, m (`None` for a point or a sphere).
    pub fn blade_depth(&self) -> Option<f64> {
        match *self {
            Tool::Blade { depth_m } => Some(depth_m),
            _ => None,
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
