# Identification: measurement types, simulator, estimator, identifiability, the paper's method,
# pose design and predicted accuracy.
target_sources(cdpr_calibration PRIVATE
  ${CMAKE_CURRENT_LIST_DIR}/src/simulate.cc
  ${CMAKE_CURRENT_LIST_DIR}/src/identification.cc
  ${CMAKE_CURRENT_LIST_DIR}/src/identifiability.cc
  ${CMAKE_CURRENT_LIST_DIR}/src/paper_method.cc
  ${CMAKE_CURRENT_LIST_DIR}/src/predicted_accuracy.cc
  ${CMAKE_CURRENT_LIST_DIR}/src/pose_design.cc)

set(_ident_src ${CMAKE_CURRENT_LIST_DIR}/src)
cdpr_add_gtest(NAME identification_test SOURCES ${_ident_src}/identification_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing)
target_include_directories(identification_test PRIVATE ${_ident_src})
cdpr_add_gtest(NAME identification_methods_test
               SOURCES ${_ident_src}/paper_method_test.cc ${_ident_src}/pose_design_test.cc
                       ${_ident_src}/predicted_accuracy_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing)
target_include_directories(identification_methods_test PRIVATE ${_ident_src})
