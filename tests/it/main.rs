//! The integration tests, one binary: each module is one area (`cargo test --test it MODULE`).

mod bad_input;
mod cli;
#[allow(dead_code)]
mod common;
mod contact_force;
mod core_checks;
mod coupling;
mod cut;
mod cut_grown;
mod cut_hostile;
mod cut_live;
mod cut_split;
mod fingertip;
mod fingertip_cli;
mod frontal;
mod golden;
mod gpu;
mod gpu_cut;
mod gpu_f16;
mod gpu_hier;
mod gpu_split;
mod gram;
mod haply;
mod haptics;
mod hard_cases;
mod hier;
mod hier_cache;
mod lab;
mod ladder;
mod locking_free;
mod mesh_io;
mod near;
mod physics;
mod precompute;
mod regions;
mod runtime;
mod scene_file;
mod session;
mod udp;
mod view;
mod web;

/// The simulated device of `examples/udp_device.rs`, driven by the `udp` and `coupling` tests.
#[allow(dead_code)]
#[path = "../../examples/udp_device.rs"]
mod udp_device;
