# Statics benchmarks: elasto-static equilibrium (the virtual robot's physics) and force
# distribution (closed form vs exact QP): ns per call and heap allocations per call.
#   build/<dir>/bench/statics_bench --benchmark_counter_tabular=true
if(TARGET benchmark::benchmark)
  add_executable(statics_bench ${CMAKE_CURRENT_LIST_DIR}/statics_bench.cc)
  target_link_libraries(statics_bench PRIVATE cdpr_calibration cdpr_calibration_testing
                                              cdpr_test_support benchmark::benchmark cdpr_options)
endif()
