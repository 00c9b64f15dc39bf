//! Fingertip: sphere contact and friction against Hertz, Signorini and Coulomb.
