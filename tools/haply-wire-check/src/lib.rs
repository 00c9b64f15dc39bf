//! touchfem's Haply wire types, built on their own (the file depends on `serde` only).

#[path = "../../../crates/app/src/haply/wire.rs"]
pub mod wire;
