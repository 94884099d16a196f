# Motion benchmarks: trajectory sampling, the per-cycle tension plan and encoder targets
# (command_counts), the slew limiter step, planning and the feasibility check of a move.
if(TARGET benchmark::benchmark)
  add_executable(motion_bench ${CMAKE_CURRENT_LIST_DIR}/motion_bench.cc)
  target_link_libraries(motion_bench PRIVATE cdpr_calibration_motion cdpr_calibration_testing cdpr_test_support
                                             benchmark::benchmark cdpr_options)
endif()
