//! The engine's unit checks, compiled into the library behind the `self-check` feature so
//! that the test command runs them from its one integration binary (`tests/it/core_checks.rs`)
//! instead of compiling the engine a second time as a unit-test harness (45 s of a cold
//! build). Each check is still a `#[test]` under `cargo test -p touchfem-core --lib`, and
//! `cargo test -p touchfem-core --no-default-features --lib` runs them without `native`.
//! Not part of the engine's interface.

/// One unit check: where it lives, its name and the function, which panics on failure.
pub struct Check {
    /// The module it lives in, under the crate root (`fem::locking_free::tests`).
    pub module: &'static str,
    /// The check's name (the test's name under `cargo test`).
    pub name: &'static str,
    /// Runs the check; panics where it fails.
    pub run: fn(),
}

macro_rules! check {
    ($first:ident $(:: $m:ident)*, $name:ident) => {
        Check {
            module: concat!(stringify!($first) $(, "::", stringify!($m))*),
            name: stringify!($name),
            run: crate::$first $(::$m)*::$name,
        }
    };
}

/// Every unit check of the engine this build has (some need `native`, one Linux).
pub fn all() -> Vec<Check> {
    #[allow(unused_mut)]
    let mut v = vec![
        check!(cache::format::tests, the_common_header_reads_what_it_writes),
        check!(cache::format::tests, byte_sources_read_within_their_length),
        check!(
            compliance::conditioning::tests,
            a_mixed_system_is_estimated_against_its_condensed_stiffness
        ),
        check!(
            compliance::conditioning::tests,
            the_cube_is_estimated_against_its_dense_eigenvalues
        ),
        check!(
            compliance::hmatrix::compress::tests,
            a_sketch_meets_the_tolerance_with_a_near_optimal_rank
        ),
        check!(compliance::hmatrix::tests, bad_build_input_is_a_typed_error),
        check!(
            compliance::hmatrix::tests,
            coincident_points_and_a_zero_matrix_build
        ),
        check!(
            compliance::plan::tests,
            every_method_gives_the_locking_free_compliance
        ),
        check!(
            compliance::near::tests,
            pairs_are_the_triangles_edges_and_the_diagonal
        ),
        check!(
            devices::external::tests,
            readings_age_out_forces_flow_and_release_is_final
        ),
        check!(devices::limits::tests, every_preset_resolves_and_is_valid),
        check!(devices::script::tests, keyframes_interpolate_and_hold),
        check!(
            devices::udp::tests,
            packets_round_trip_and_malformed_ones_are_refused
        ),
        check!(
            devices::workspace::tests,
            points_map_both_ways_and_forces_are_unchanged
        ),
        check!(
            fem::frontal::tests,
            the_plan_is_a_post_order_with_contiguous_subtrees
        ),
        check!(
            fem::gram::tests,
            w_is_the_same_bit_for_bit_on_any_number_of_threads
        ),
        check!(fem::gram::tests, apply_equals_the_tiles_times_the_vectors),
        check!(
            fem::locking_free::tests,
            patch_test_linear_field_is_reproduced_exactly
        ),
        check!(
            fem::locking_free::tests,
            a_free_patch_has_exactly_six_zero_modes_and_no_spurious_ones
        ),
        check!(
            fem::locking_free::tests,
            the_mixed_system_gives_the_assembled_displacements_on_every_path
        ),
        check!(
            fem::locking_free::tests,
            the_mixed_factor_is_about_half_the_assembled_one
        ),
        check!(
            fem::locking_free::tests,
            sparse_equals_dense_and_regions_are_honoured
        ),
        check!(
            fem::locking_free::tests,
            converges_under_refinement_where_the_standard_element_locks
        ),
        check!(
            fem::locking_free::tests,
            the_stabilised_elements_keep_the_whole_bodys_volume
        ),
        check!(fem::locking_free::tests, poisson_one_half_is_a_typed_error),
        check!(
            cut::carried::tests,
            a_spare_buffer_is_reused_only_when_free_and_large_enough
        ),
        check!(cut::solved::tests, l_d_grows_into_room_that_doubles),
        check!(
            cut::body::tests,
            face_neighbours_kept_through_splits_equal_those_found_afresh
        ),
        check!(fem::tests, direct_assembly_equals_the_dense_assembly),
        check!(
            fem::tests,
            element_stiffness_is_symmetric_and_kills_rigid_modes
        ),
        check!(fem::tests, cube_assembles_and_factorizes),
        check!(
            haptic::bound::tests,
            the_bound_is_the_smaller_of_the_scene_and_the_device
        ),
        check!(
            haptic::bound::tests,
            any_input_gives_a_finite_force_within_the_bound
        ),
        check!(
            haptic::bound::tests,
            the_force_rises_at_the_rate_in_measured_time
        ),
        check!(
            haptic::bound::tests,
            a_held_force_falls_to_the_continuous_force
        ),
        check!(
            haptic::pure_tests,
            compliance_from_text_matches_the_threaded_solve
        ),
        check!(haptic::pure_tests, caches_round_trip_through_bytes),
        check!(haptic::pure_tests, a_haptic_press_gives_the_native_force),
        check!(haptic::pure_tests, fan_out_keeps_the_order),
        check!(mesh::cube::tests, cube_table1_counts_are_the_papers),
        check!(mesh::cube::tests, mouse_table1_counts_and_pads),
        check!(mesh::cube::tests, phantom_has_a_conforming_nodule),
        check!(mesh::cube::tests, cube_volume_is_exact),
        check!(mesh::tests, fans_cover_every_triangle_once),
        check!(
            mesh::slit::tests,
            the_slit_is_where_twinned_faces_meet_the_rest
        ),
        check!(mesh::tests, single_tet_surface_is_outward),
        check!(runtime::pacer::tests, quantiles_of_a_histogram),
        check!(runtime::pacer::tests, the_floor_runs_at_its_rate),
        check!(scene::file::tests, lines_are_counted_from_one),
    ];
    // The native runtime's checks (sockets, threads).
    #[cfg(feature = "native")]
    v.extend([
        check!(
            devices::udp::gate_tests,
            sequence_numbers_compare_in_serial_arithmetic
        ),
        check!(devices::udp::gate_tests, a_wrapping_counter_loses_no_packet),
        check!(
            devices::udp::gate_tests,
            one_packet_with_seq_max_does_not_lock_the_client_out
        ),
        check!(
            devices::udp::gate_tests,
            keyed_packets_verify_and_others_are_rejected
        ),
        check!(
            devices::udp::gate_tests,
            random_and_mutated_datagrams_never_panic_the_gate
        ),
        check!(
            haptic::sample::tests,
            the_haptic_side_waits_for_the_visual_side_or_a_stop
        ),
    ]);
    #[cfg(all(feature = "native", target_os = "linux"))]
    v.push(check!(threads::tests, pin_and_restore));
    #[cfg(all(feature = "native", target_os = "linux"))]
    v.push(check!(
        threads::tests,
        workers_find_their_cores_from_a_pinned_thread
    ));
    #[cfg(all(feature = "native", target_os = "linux"))]
    v.push(check!(
        threads::tests,
        a_helper_left_working_is_lent_the_waiting_threads_class
    ));
    v
}
