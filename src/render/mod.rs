//! Offscreen rendering.
