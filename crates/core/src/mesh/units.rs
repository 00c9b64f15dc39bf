//! Units. Everything inside touchfem is SI: metres, newtons, pascals, seconds.
//! Mesh files may declare millimetres; the conversion happens once, at load time.

use std::fmt;
use std::str::FromStr;
use thiserror::Error;

/// Why a material cannot be used (the FEM room wraps it as
/// `FemError::Material`).
#[derive(Debug, Error)]
pub enum MaterialError {
    /// E or ν out of range.
    #[error("bad material: {0}")]
    BadMaterial(String),
    /// ν = 0.5 exactly: the bulk modulus is infinite, and a displacement-only `K` cannot hold
    /// it; the locking-free formulation's mixed system would lose the compressibility that
    /// makes its pressure block negative definite, which its factorisation without pivoting
    /// relies on, so both formulations refuse it.
    #[error(
        "Poisson's ratio 0.5 (exactly incompressible) has an infinite bulk modulus: no \
         displacement-only stiffness holds it; use 0.4999 with formulation \"locking-free\" \
         (the standard formulation locks there)"
    )]
    Incompressible,
}

/// The length unit a mesh file's coordinates are written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LengthUnit {
    /// Metres (the default for files).
    #[default]
    Metre,
    /// Millimetres (the paper's unit; the bundled meshes use it).
    Millimetre,
}

impl LengthUnit {
    /// Metres per one unit.
    pub fn to_metres(self) -> f64 {
        match self {
            LengthUnit::Metre => 1.0,
            LengthUnit::Millimetre => 1e-3,
        }
    }
    /// The unit's symbol as used on the command line (`m`, `mm`).
    pub fn symbol(self) -> &'static str {
        match self {
            LengthUnit::Metre => "m",
            LengthUnit::Millimetre => "mm",
        }
    }
}

impl fmt::Display for LengthUnit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.symbol())
    }
}

impl FromStr for LengthUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "m" => Ok(LengthUnit::Metre),
            "mm" => Ok(LengthUnit::Millimetre),
            other => Err(format!("unknown length unit '{other}': use m or mm")),
        }
    }
}

/// How the volumetric (bulk) part of the linear-elastic energy is discretised. Both give a
/// linear, symmetric, positive definite `K` on the same DOFs, so `L = K⁻¹`, the force solve
/// and the GPU pass do not change.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Formulation {
    /// Constant-strain tets as in the paper: locks as ν → 0.5.
    #[default]
    Standard,
    /// The volumetric strain averaged over the tets around each node (Bonet & Burton 1998), the
    /// deviatoric part per tet: one volume constraint per node instead of one per tet, so a
    /// coarse mesh locks far less as ν → 0.5 (about half the standard element's error at
    /// ν = 0.4999 on the paper's cube), at about three times the precompute (see
    /// `fem::locking_free`). Experimental.
    LockingFree,
}

impl Formulation {
    /// The name used in scene files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Formulation::Standard => "standard",
            Formulation::LockingFree => "locking-free",
        }
    }
}

impl fmt::Display for Formulation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Formulation {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "standard" => Ok(Formulation::Standard),
            "locking-free" => Ok(Formulation::LockingFree),
            other => Err(format!(
                "unknown formulation '{other}': use \"standard\" or \"locking-free\""
            )),
        }
    }
}

/// Isotropic linear-elastic material, SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Young's modulus in pascals.
    pub young_pa: f64,
    /// Poisson's ratio (dimensionless, in (-1, 0.5)).
    pub poisson: f64,
}

impl Material {
    /// The default for meshes that do not say: 1000 Pa, 0.3 (the paper's mouse).
    pub const DEFAULT: Material = Material {
        young_pa: 1000.0,
        poisson: 0.3,
    };

    /// Checks that E > 0 and -1 < ν < 0.5, both finite; ν = 0.5 exactly is
    /// [`MaterialError::Incompressible`].
    pub fn validate(&self) -> Result<(), MaterialError> {
        if !(self.young_pa.is_finite() && self.young_pa > 0.0) {
            return Err(MaterialError::BadMaterial(format!(
                "Young's modulus must be finite and > 0 Pa, got {}",
                self.young_pa
            )));
        }
        if self.poisson == 0.5 {
            return Err(MaterialError::Incompressible);
        }
        if !(self.poisson.is_finite() && self.poisson > -1.0 && self.poisson < 0.5) {
            return Err(MaterialError::BadMaterial(format!(
                "Poisson's ratio must be in (-1, 0.5), got {}",
                self.poisson
            )));
        }
        Ok(())
    }

    /// Lamé parameters (λ, μ) in pascals.
    pub(crate) fn lame(&self) -> (f64, f64) {
        let e = self.young_pa;
        let nu = self.poisson;
        let lambda = e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
        let mu = e / (2.0 * (1.0 + nu));
        (lambda, mu)
    }
}
