//! What a finger touches with (a point or a sphere) and an object's Coulomb friction, with the
//! checks a scene file or a flag goes through.

use thiserror::Error;

/// A tool or friction value that cannot be used. The message names the value at fault; the
/// scene loader and the command line add the key or flag.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ContactError {
    /// A sphere's radius that is not a positive finite length.
    #[error("sphere radius {} must be a positive, finite length", show_length(*.0))]
    Radius(f64),
    /// A blade's depth that is not a positive finite length.
    #[error("blade depth {} must be a positive, finite length", show_length(*.0))]
    Depth(f64),
    /// A sphere larger than the object it is meant to touch.
    #[error(
        "sphere radius {} m is larger than the object ({} m across)",
        show_length(*radius_m),
        show_length(*extent_m)
    )]
    RadiusTooLarge {
        /// The radius, m.
        radius_m: f64,
        /// The object's bounding-box diagonal, m.
        extent_m: f64,
    },
    /// A length the user gave (a tool's size, a finger's motion) that is not zero but shorter
    /// than [`MIN_LENGTH_FRACTION`] of the object's size: below what the object resolves.
    #[error(
        "{what} {} m is shorter than {} m, the smallest length touchfem resolves on this object \
         ({MIN_LENGTH_FRACTION:e} of its {} m across)",
        show_length(*length_m),
        show_length(MIN_LENGTH_FRACTION * *extent_m),
        show_length(*extent_m)
    )]
    TooShort {
        /// What the length is (`sphere radius`, `blade depth`, `push`, `slide`).
        what: &'static str,
        /// The length, m (0 when the value underflowed converting to metres).
        length_m: f64,
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

/// The smallest length a user may give, as a fraction of the object's size (its bounding-box
/// diagonal): a tool's size (a sphere's radius, a blade's depth) and a finger's motion, unless
/// the motion is zero. `1e-6` is about 16 times the resolution of an `f32` vertex position
/// (2⁻²⁴ ≈ 6·10⁻⁸ of the coordinates' magnitude): a shorter length cannot be told from none on
/// the GPU, and a blade or sphere that small cuts or presses as a point would.
pub const MIN_LENGTH_FRACTION: f64 = 1e-6;

/// A length in metres for a message: four significant digits, scientific below `1e-3` and
/// from `1e5` (never hundreds of digits).
pub fn show_length(m: f64) -> String {
    if !m.is_finite() || m == 0.0 {
        return format!("{m}");
    }
    let e = m.abs().log10().floor();
    if (-3.0..5.0).contains(&e) {
        let decimals = (3.0 - e).max(0.0) as usize;
        let s = format!("{m:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        let s = format!("{m:.3e}");
        match s.split_once('e') {
            Some((mant, exp)) if mant.contains('.') => {
                format!("{}e{exp}", mant.trim_end_matches('0').trim_end_matches('.'))
            }
            _ => s,
        }
    }
}

/// Checks a length the user gave against the object (bounding-box diagonal `extent_m`): zero
/// (allowed when `zero_ok`, a motion) or at least [`MIN_LENGTH_FRACTION`] of the object's size.
/// The one rule for every user length: `--sphere`, `--depth`, `--push`, `--slide` and a scene's
/// `tool`.
pub fn check_length(
    what: &'static str,
    length_m: f64,
    extent_m: f64,
    zero_ok: bool,
) -> Result<(), ContactError> {
    if (zero_ok && length_m == 0.0) || length_m >= MIN_LENGTH_FRACTION * extent_m {
        Ok(())
    } else {
        Err(ContactError::TooShort {
            what,
            length_m,
            extent_m,
        })
    }
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

    /// Checks the tool against the object it will touch (its bounding-box diagonal
    /// `extent_m`): a sphere's radius and a blade's depth are at least [`MIN_LENGTH_FRACTION`]
    /// of it ([`check_length`]), and a sphere is not larger than the object.
    pub fn check_fits(&self, extent_m: f64) -> Result<(), ContactError> {
        match *self {
            Tool::Sphere { radius_m } if radius_m > extent_m => {
                Err(ContactError::RadiusTooLarge { radius_m, extent_m })
            }
            Tool::Sphere { radius_m } => check_length("sphere radius", radius_m, extent_m, false),
            Tool::Blade { depth_m } => check_length("blade depth", depth_m, extent_m, false),
            Tool::Point => Ok(()),
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
