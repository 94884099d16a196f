# CANopen master: per-cycle CPU cost for 8 CiA 402 drives + 1 force node (target <= 5 us, 0 allocations).
if(TARGET cdpr_test_support)
  add_executable(bench_canopen_cycle ${CMAKE_CURRENT_LIST_DIR}/canopen_cycle_bench.cc)
  target_include_directories(bench_canopen_cycle PRIVATE ${CMAKE_SOURCE_DIR}/drivers/canopen)
  target_compile_definitions(bench_canopen_cycle PRIVATE CDPR_SOURCE_DIR="${CMAKE_SOURCE_DIR}")
  target_link_libraries(bench_canopen_cycle PRIVATE cdpr_canopen cdpr_canopen_slave cdpr_can
                                                    cdpr_test_support benchmark::benchmark cdpr_options)
endif()
