"""The CI's tier (issue 43, item 6): the tests that the default run deselects.

tests/conftest.py marks every test whose node id starts with a key of BENCH_IN_CI
`bench`; pyproject's `-m 'not bench'` then leaves it out of `python3 -m pytest tests`.
`python3 -m pytest -m bench tests` runs them, `-m "bench or not bench"` runs everything.
tests/test_ci_tier.py checks that every key names a test.
"""

# The grader's CI (a fresh 2-core machine, every program compiled cold) took 3 524 s on
# 44ba121 where .ci/run must stay under 20 minutes: 6 423 worker-seconds of tests, 63 % of
# them compiling (benchmarks/results/2026-12-02-tier50). The tests below stay in the suite,
# marked `bench` here, so that the default run deselects them (`python3 -m pytest -m bench
# tests` runs them; `-m "bench or not bench"` runs everything). Each one's key is a node id
# (or the start of one); its value says, with its cold wall seconds, where the default run
# still checks what it checks.
BENCH_IN_CI = {
    # test_fit.py
    "tests/test_fit.py::test_simulate_fit_recovers_every_parameter[geometry]":
        "30 s; [seed7] recovers every parameter of a simulated recording",
    "tests/test_fit.py::test_simulate_fit_recovers_every_parameter[one_body_marker]":
        "28 s; [seed7] (three body markers); one marker of a role: test_fit's markers entering "
        "and leaving the view",
    "tests/test_fit.py::test_levenberg_marquardt_ends_at_the_minimum_without_idle_steps":
        "30 s; the solver's steps: benchmarks/bench_fit.py",
    "tests/test_fit.py::test_a_held_parameter_is_solved_in_the_free_fits_program":
        "25 s; a compile-count check: benchmarks/bench_speed.py",
    "tests/test_fit.py::test_not_converged_far_from_the_data_says_so":
        "30 s; test_clean_errors (one-line errors of a failed fit)",
    "tests/test_fit.py::test_the_solver_ends_a_crawl_at_a_gross_misfit_as_it_goes":
        "36 s; test_glitches' gross misfit ends the glitch rounds after one refit",
    "tests/test_fit.py::test_a_fit_still_walking_at_a_gross_misfit_goes_on_before_it_fails":
        "92 s; as above",
    # test_straight_runs.py: the belt clock's cases on the independent simulator
    "tests/test_straight_runs.py::test_independent_recording_straight_runs_hold_the_truth":
        "34 s; the clock's window and truth: test_belt_clock_ends_its_window_before_a_gap",
    "tests/test_straight_runs.py::test_belt_clock_counts_the_belt_and_holds_the_truth":
        "110 s; N counted and the truth held: test_belt_clock_ends_its_window_before_a_gap",
    "tests/test_straight_runs.py::test_belt_clock_reads_a_cruise_that_ends_with_the_marked":
        "32 s; the window's end at a passage: test_belt_clock_ends_its_window_before_a_gap",
    "tests/test_straight_runs.py::test_no_reading_without_a_cruise_in_view":
        "29 s; test_the_clock_says_why_it_gives_no_reading",
    "tests/test_straight_runs.py::test_the_posterior_of_a_path_the_model_does_not_describe":
        "35 s; test_a_wide_straight_runs_slip_keeps_its_interval_in_the_posterior",
    "tests/test_straight_runs.py::test_the_final_fit_of_a_path_the_model_does_not_describe":
        "26 s; test_the_robust_result_takes_the_straight_runs_as_headline",
    "tests/test_straight_runs.py::test_a_long_cruise_reads_the_belt_clock": "40 s; as above",
    "tests/test_straight_runs.py::test_the_belt_clock_carries_the_belts_speed": "54 s; as above",
    "tests/test_straight_runs.py::test_the_belt_clock_reads_a_robot_that_drives_into":
        "35 s; as above",
    "tests/test_straight_runs.py::test_the_belt_clock_reads_the_whole_cruise_where":
        "30 s; as above",
    "tests/test_straight_runs.py::test_the_belt_clock_reads_the_body_over_its_settled":
        "54 s; as above",
    "tests/test_straight_runs.py::test_the_belt_clock_holds_the_surge_of_a_fast_robot":
        "37 s; the clock's error: test_batch_means_of_a_few_contact_times_hold_their_interval",
    "tests/test_straight_runs.py::test_a_body_that_surges_more_than_an_eighth": "36 s; as above",
    "tests/test_straight_runs.py::test_a_model_that_misses_the_markers_by_a_tenth":
        "34 s; test_partial_readings_of_a_gross_misfit_are_not_claimed",
    "tests/test_straight_runs.py::test_the_belt_clocks_error_holds_the_slow_surge":
        "39 s; test_batch_means_of_a_few_contact_times_hold_their_interval",
    "tests/test_straight_runs.py::test_one_marked_lug_reads_its_one_visit": "37 s; as above",
    "tests/test_straight_runs.py::test_the_belt_clock_reads_a_surging_body_off_its_line":
        "80 s; test_engine_slip_from_the_straight_runs (an engine body that surges)",
    # test_uncertainty.py: the knocked, speed-modulated, vibrating and ripple recordings
    "tests/test_uncertainty.py::test_unexplained_headline_interval_holds_the_truth":
        "130 s; test_drive_through's thin start; benchmarks/bench_posterior.py coverage",
    "tests/test_uncertainty.py::test_speed_modulation_headline_interval_holds_the_truth":
        "42 s; as above",
    "tests/test_uncertainty.py::test_a_camera_vibration_is_taken_out": "38 s; as above",
    "tests/test_uncertainty.py::test_posterior_and_least_squares_errors_agree_in_every_"
    "verdict[knocked]": "fixture; [cruise] stays, and test_posterior's std check",
    "tests/test_uncertainty.py::test_posterior_and_least_squares_errors_agree_in_every_"
    "verdict[speed_mod]": "fixture; as above",
    "tests/test_uncertainty.py::test_posterior_and_least_squares_errors_agree_in_every_"
    "verdict[vibration]": "fixture; as above",
    "tests/test_uncertainty.py::test_posterior_and_least_squares_errors_agree_in_every_"
    "verdict[ripple]": "63 s; as above",
    "tests/test_uncertainty.py::test_exact_marginal_follows_the_profile_on_a_free_speed":
        "87 s; test_posterior's exact marginal against its Gaussian limit",
    "tests/test_uncertainty.py::test_effect_parameter_without_information":
        "34 s; test_cruise_only_k_and_c_rr_are_not_identifiable",
    # test_families.py: frame_vibration, flap, speed_hunt and the null stay (frame_jitter
    # below), beside the file's unit tests: speed_hunt and flap came back after a coverage
    # run of the tier (the family terms' modules at 13-35 % without them)
    "tests/test_families.py::test_a_mechanism_outside_the_catalog_is_modelled_by_its_family"
    "[carrier_roller]": "72 s; path shape: benchmarks/bench_discovery.py",
    "tests/test_families.py::test_a_mechanism_outside_the_catalog_is_modelled_by_its_family"
    "[rail_bow]": "80 s; ground profile: benchmarks/bench_discovery.py",
    "tests/test_families.py::test_a_mechanism_outside_the_catalog_is_modelled_by_its_family"
    "[keystone]": "79 s; image map: benchmarks/bench_discovery.py; test_tracker_error's a warp beyond a "
    "lens is not a lens",
    "tests/test_families.py::test_a_mechanism_outside_the_catalog_is_modelled_by_its_family"
    "[squat]": "67 s; body motion: benchmarks/bench_discovery.py",
    "tests/test_families.py::test_no_family_term_on_a_null_or_a_catalog_recording"
    "[wheel_runout]": "38 s; [null]",
    # test_scale.py: the dense references of the chunked forms
    "tests/test_scale.py::test_chunked_normal_equations_equal_the_dense_jacobians":
        "165 s; test_5000_frames_fit_in_bounded_memory_and_find_the_slip (chunked LM)",
    "tests/test_scale.py::test_explanation_engine_in_normal_form_equals_the_dense_engine":
        "116 s; test_engine_residuals_by_time_blocks_equal_the_whole_batch",
    "tests/test_scale.py::test_posterior_exact_chi2_in_bounded_batches": "72 s; as above",
    # test_drive_through.py
    "tests/test_drive_through.py::test_only_the_cruise_in_view_k_and_crr_not_identifiable":
        "43 s; test_uncertainty's cruise-only k and C_rr",
    "tests/test_drive_through.py::test_a_catalog_effect_is_named_alone":
        "38 + 31 s; test_explain_independent's lug_sliding",
    "tests/test_drive_through.py::test_lugs_seen_without_the_body_at_the_ends[1033]":
        "39 s; test_fit's markers entering and leaving the view",
    "tests/test_drive_through.py::test_lugs_seen_without_the_body_at_the_ends[1041]":
        "35 s; as above",
    "tests/test_drive_through.py::test_lugs_seen_without_the_body_at_the_ends[1077]":
        "39 s; as above",
    # test_families_independent.py (issue 41 item 4): all three benched (arc radii below)
    "tests/test_families_independent.py::test_a_rolling_resistance_growing_with_speed":
        "157 s; a family term: test_families' frame_vibration; benchmarks/bench_discovery.py",
    "tests/test_families_independent.py::test_a_ground_bump_is_a_ground_profile":
        "81 s; benchmarks/bench_discovery.py",
    # test_explain_independent.py: lug_sliding stays (the rest in the rounds below too)
    "tests/test_explain_independent.py::test_independent_effects_are_named[lug_ripple]":
        "34 s; lug_sliding named in the tier; benchmarks/bench_explain.py",
    "tests/test_explain_independent.py::test_independent_effects_are_named[wheel_runout]":
        "22 s; test_explain's engine columns; benchmarks/bench_explain.py",
    "tests/test_explain_independent.py::test_independent_effects_are_named[body_bounce]":
        "19 s; as above",
    "tests/test_explain_independent.py::test_independent_effects_are_named[belt_sag]":
        "18 s; as above",
    "tests/test_explain_independent.py::test_independent_effects_are_named[ground_sinkage]":
        "15 s; benchmarks/bench_explain.py",
    "tests/test_explain_independent.py::test_independent_effects_are_named[lens_distortion]":
        "12 s; benchmarks/bench_explain.py",
    "tests/test_explain_independent.py::test_independent_effects_are_named[marker_depth]":
        "18 s; benchmarks/bench_explain.py",
    "tests/test_explain_independent.py::test_independent_effects_are_named[camera_tilt]":
        "20 s; benchmarks/bench_explain.py",
    # test_model.py: the all-effects reference Jacobians (each effect's gradient stays
    # checked against finite differences, the structured Jacobian against forward mode
    # without effects and with lug_shear)
    "tests/test_model.py::test_structured_jacobian_equals_forward_mode[effects1]":
        "120 s; test_gradients_match_finite_differences per effect; [effects0]",
    # test_posterior.py
    "tests/test_posterior.py::test_a_replacing_slip_law_is_sampled_with_its_parameter":
        "80 s; test_sampled_parameters_follow_the_slip_law",
    "tests/test_posterior.py::test_exact_marginal_is_the_profile_over_the_nuisance":
        "39 s; test_exact_marginal_agrees_with_its_gaussian_limit",
    # test_tracker_error.py: its unit tests and the drawn null stay (the adverse null
    # below)
    "tests/test_tracker_error.py::test_lens_still_named_under_trackers_error":
        "127 s; benchmarks/bench_explain.py",
    # test_explain.py: the frame-drop recording explained in full
    "tests/test_explain.py::test_a_lost_frame_is_found_where_it_happened":
        "84 s; benchmarks/bench_explain.py (frame_drop)",
    "tests/test_explain.py::test_the_reports_early_parts_do_not_read_the_posterior":
        "58 s; test_report's sections",
    # others
    "tests/test_lug_shear.py::test_identity_at_h_one_and_exact_jacobian":
        "55 s; test_model's structured Jacobian with lug_shear; h = 1 is every base fit",
    "tests/test_notebook.py::test_the_notebook_runs":
        "164 s; test_notebook's public-API check; test_library_api",
    "tests/test_buckets.py::test_a_new_length_in_a_seen_bucket_compiles_nothing":
        "64 s; benchmarks/bench_speed.py (first run against second)",
    "tests/test_friction_limit.py::test_one_recording_near_the_limit_is_lug_sliding":
        "148 s; test_explain_independent's lug_sliding",
    "tests/test_glitches.py::test_a_glitch_round_that_crawls_keeps_the_last_converged_fit":
        "48 s; test_a_gross_misfit_ends_the_glitch_rounds_after_one_refit",
    "tests/test_surge.py::": "108 s; benchmarks/bench_engine.py (the engine's surge)",
    "tests/test_render_chain.py::test_lens_distortion_rendered_in_is_named_alone":
        "28 s; benchmarks/bench_explain.py",
    "tests/test_campaign.py::test_a_pushed_robot_reads_its_rolling_resistance":
        "28 s; test_dask_two_workers_same_numbers (a campaign's fits)",
    # second round (the estimate above still 1 250 s wall): fits and explanations whose
    # stage another test in the tier runs
    "tests/test_explain_independent.py::test_independent_effects_are_named[frame_drop]":
        "29 s; test_glitches' reference recording (a lost frame is not a glitch); "
        "benchmarks/bench_explain.py",
    "tests/test_explain_independent.py::test_independent_effects_are_named[ripple+sag]":
        "29 s; two effects at once: benchmarks/bench_explain.py; lug_sliding stays",
    "tests/test_campaign.py::test_independent_recordings_recovered":
        "79 s; test_dask_two_workers_same_numbers fits recordings; the law: "
        "test_law_k_crr_fmax_recovered_and_law_named",
    "tests/test_realism.py::test_other_rig_250fps_time_offset_wide_export":
        "48 s; the wide export: test_import_formats",
    "tests/test_aside.py::test_child_draws_the_page_the_caller_would":
        "32 s; test_a_failing_child_is_replaced_by_the_caller",
    "tests/test_aside.py::test_a_failed_copy_leaves_its_parts_to_the_page":
        "18 s; test_a_failing_child_is_replaced_by_the_caller",
    "tests/test_buckets.py::test_padded_programs_give_the_unpadded_numbers":
        "97 s; every fit in the tier runs padded and is checked against its truth",
    "tests/test_fit.py::test_not_converged_is_an_error": "24 s; test_clean_errors",
    "tests/test_drive_through.py::test_lugs_seen_without_the_body_at_the_ends[1010]":
        "31 s; test_fit's markers entering and leaving the view",
    "tests/test_glitches.py::test_a_catalog_effect_is_named_through_glitches":
        "33 s; test_glitches_of_the_reference_recording_are_listed_and_kept_out",
    "tests/test_concealed.py::test_blind_explanation":
        "60 s; test_explain_independent (clean, lug_sliding); benchmarks/bench_explain.py "
        "--part concealed",
    "tests/test_exported.py::test_exported_solver_equals_the_plain_call":
        "48 s; every fit runs the exported solver (test_fit's bundled recording against the "
        "paper)",
    "tests/test_prewarm.py::test_first_run_compiles_the_later_stages_programs":
        "52 s; benchmarks/bench_speed.py (first runs)",
    # third round: a fresh-clone .ci/run of the two rounds above took 21 min 32 s (pytest
    # 1 244 s, 2 470 CPU s: a benched test's programs and fixtures, compiled and built in
    # the kept test that came next, cost 28 % more than the estimate)
    "tests/test_uncertainty.py::test_fit_json_says_why_a_quantity_is_null":
        "127 s (the knocked recording, explained); test_identifiable's posterior None with "
        "its reason; test_identifiability_is_decided_by_the_information",
    "tests/test_families_independent.py::": "84 s (arc radii per wheel; the rest above); "
        "benchmarks/bench_discovery.py; test_families' frame_vibration models a family term",
    "tests/test_render_chain.py::test_clean_render_tracked_says_none":
        "51 s; test_end_to_end's tracked clip (render, track, fit, slip against the truth)",
    "tests/test_render_chain.py::test_uncorrected_lens_is_named_alone":
        "28 s; a lens named: benchmarks/bench_explain.py; the chain: test_end_to_end",
    "tests/test_families.py::test_a_mechanism_outside_the_catalog_is_modelled_by_its_family"
    "[frame_jitter]": "63 s; frame_vibration, speed_hunt",
    "tests/test_fit.py::test_a_crawl_at_a_gross_misfit_is_stationary_in_its_units":
        "48 s; test_glitches' gross misfit ends the glitch rounds after one refit",
    "tests/test_straight_runs.py::test_two_contact_times_in_view_put_their_swing":
        "33 s; test_batch_means_of_a_few_contact_times_hold_their_interval",
    "tests/test_realism.py::test_fov_cut_recordings_fit_to_the_truth":
        "59 s; test_drive_through's thin start (a robot crossing the picture)",
    "tests/test_realism.py::test_fit_json_has_markers_and_joined":
        "fixture; the joining: test_fragments_joined_and_lugs_a_pitch_apart_kept_apart",
    "tests/test_explain_independent.py::test_independent_effects_are_named[clean]":
        "30 s; 'none' on a clean recording: test_tracker_error's drawn null; test_explain's "
        "white noise located nowhere",
    "tests/test_aside.py::test_executable_run_draws_early_parts_and_the_same_page":
        "38 s; test_a_failing_child_is_replaced_by_the_caller; test_cli",
    "tests/test_drive_through.py::test_enters_during_the_ramp_and_leaves_in_the_cruise":
        "31 s; test_a_thin_start_gives_the_slip_a_true_error",
    "tests/test_scale.py::test_robust_errors_and_systematics_check_in_normal_form":
        "~20 s; test_engine_residuals_by_time_blocks_equal_the_whole_batch",
    "tests/test_scale.py::test_glitch_search_by_time_blocks": "13 s; as above",
    "tests/test_tracker_error.py::test_no_physics_claimed_on_trackers_error[adverse]":
        "102 s; [drawn]; test_uncertainty's tracker systematics carried in the errors",
    "tests/test_explain.py::test_the_discrepancy_block_follows_data_md":
        "39 s (the frame-drop recording explained); test_report's discrepancy section",
    "tests/test_explain.py::test_the_report_section_shows_before_and_after": "as above",
}
