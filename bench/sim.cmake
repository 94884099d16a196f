# cdpr-sim physics: CPU cost per step (SYNC) for 8 cables, ns, against solve_elastostatics from a
# cold start measured in the same run.
if(TARGET cdpr_sim)
  add_executable(bench_sim ${CMAKE_CURRENT_LIST_DIR}/sim_bench.cc)
  target_compile_definitions(bench_sim PRIVATE CDPR_SOURCE_DIR="${CMAKE_SOURCE_DIR}")
  target_link_libraries(bench_sim PRIVATE cdpr_sim benchmark::benchmark cdpr_options)
endif()
