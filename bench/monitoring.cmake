# In-service monitoring on the virtual MINI: time and travel to detection per slow hidden change,
# the effect named and its size, false alarms of a clean run against the stated rates. Printed:
# build/<dir>/bench/monitoring_bench. See docs/monitoring.md.
if(TARGET cdpr_sim)
  add_executable(monitoring_bench ${CMAKE_CURRENT_LIST_DIR}/monitoring_bench.cc)
  target_compile_definitions(monitoring_bench PRIVATE CDPR_SOURCE_DIR="${CMAKE_SOURCE_DIR}")
  target_link_libraries(monitoring_bench PRIVATE cdpr_calibration_monitoring cdpr_sim cdpr_config
                                                 cdpr_options)
endif()
