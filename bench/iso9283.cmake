# ISO 9283 figures of the virtual MINI (AP, RP, AT, RT; nominal vs calibrated geometry; the
# paper's figures beside). Printed: build/<dir>/bench/iso9283_bench. See docs/motion.md.
if(TARGET cdpr_sim)
  add_executable(iso9283_bench ${CMAKE_CURRENT_LIST_DIR}/iso9283_bench.cc)
  target_compile_definitions(iso9283_bench PRIVATE CDPR_SOURCE_DIR="${CMAKE_SOURCE_DIR}")
  target_link_libraries(iso9283_bench PRIVATE cdpr_calibration_motion cdpr_sim cdpr_config cdpr_recording
                                              cdpr_calibration cdpr_report cdpr_io cdpr_options cdpr_daemon)
endif()
