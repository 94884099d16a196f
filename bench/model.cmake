# Robot model benchmarks: IK with pulleys, IK with elongation compensation, FK.
if(TARGET benchmark::benchmark)
  add_executable(model_bench ${CMAKE_CURRENT_LIST_DIR}/model_bench.cc)
  target_link_libraries(model_bench PRIVATE cdpr_calibration cdpr_calibration_testing cdpr_test_support
                                            benchmark::benchmark cdpr_options)
endif()
