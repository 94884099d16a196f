# Robot model, kinematics and cable physics.
target_sources(
  cdpr_calibration
  PRIVATE ${CMAKE_CURRENT_LIST_DIR}/src/kinematics.cc
          ${CMAKE_CURRENT_LIST_DIR}/src/elongation.cc
          ${CMAKE_CURRENT_LIST_DIR}/src/catenary.cc
          ${CMAKE_CURRENT_LIST_DIR}/src/force_sensor.cc
          ${CMAKE_CURRENT_LIST_DIR}/src/forward_kinematics.cc)

# Header-only helpers for tests and benchmarks (#include "testing/test_robots.hpp").
add_library(cdpr_calibration_testing INTERFACE)
target_include_directories(cdpr_calibration_testing INTERFACE ${CMAKE_CURRENT_LIST_DIR})
target_link_libraries(cdpr_calibration_testing INTERFACE cdpr_calibration)

# Unit tests live beside their sources: calibration/src/<unit>_test.cc.
set(_model_src ${CMAKE_CURRENT_LIST_DIR}/src)
cdpr_add_gtest(NAME kinematics_test SOURCES ${_model_src}/kinematics_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing cdpr_test_support)
cdpr_add_gtest(NAME forward_kinematics_test SOURCES ${_model_src}/forward_kinematics_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing cdpr_test_support)
cdpr_add_gtest(
  NAME cable_physics_test
  SOURCES ${_model_src}/winch_test.cc
          ${_model_src}/force_sensor_test.cc
          ${_model_src}/elongation_test.cc
          ${_model_src}/catenary_test.cc
          ${_model_src}/ik_compensation_test.cc
  LIBS cdpr_calibration cdpr_calibration_testing cdpr_test_support)
