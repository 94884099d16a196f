# Motion: task-space trajectories (double-S, straight line with the orientation on the geodesic),
# multi-segment paths (lines, arcs, splines) and the path file reader, feasibility along a path, the per-cycle tension plan and encoder targets, the joint-space slew
# limiter. Planning and checks run in the supervisor; sampling, command_counts and the slew
# limiter in the RT cycle (allocation-free).
# cdpr_motion_path: what needs only the robot model (trajectories, paths, the path file, the slew
# limiter), so the path file's fuzz target does not compile the identification; cdpr_motion adds
# the checks along a path, which use the tension planner's defaults (calibration/).
add_library(cdpr_motion_path STATIC ${CMAKE_CURRENT_LIST_DIR}/src/trajectory.cc
                                    ${CMAKE_CURRENT_LIST_DIR}/src/slew.cc
                                    ${CMAKE_CURRENT_LIST_DIR}/src/path.cc
                                    ${CMAKE_CURRENT_LIST_DIR}/src/path_file.cc)
target_include_directories(cdpr_motion_path PUBLIC ${CMAKE_CURRENT_LIST_DIR}/include)
target_link_libraries(cdpr_motion_path PUBLIC cdpr_calibration_model cdpr_core
                                       PRIVATE cdpr_options)
add_library(cdpr_motion STATIC ${CMAKE_CURRENT_LIST_DIR}/src/path_check.cc)
target_link_libraries(cdpr_motion PUBLIC cdpr_motion_path cdpr_calibration cdpr_core
                                  PRIVATE cdpr_options)

cdpr_add_gtest(NAME motion_trajectory_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/trajectory_test.cc
               LIBS cdpr_motion cdpr_test_support)
cdpr_add_gtest(NAME motion_path_check_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/path_check_test.cc
               LIBS cdpr_motion cdpr_calibration_testing cdpr_test_support)
cdpr_add_gtest(NAME motion_slew_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/slew_test.cc
               LIBS cdpr_motion cdpr_calibration_testing cdpr_test_support)
cdpr_add_gtest(NAME motion_path_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/path_test.cc
               LIBS cdpr_motion cdpr_calibration_testing cdpr_test_support)
cdpr_add_gtest(NAME motion_path_file_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/path_file_test.cc
               LIBS cdpr_motion cdpr_calibration_testing cdpr_test_support)
if(TARGET motion_path_file_test)
  target_compile_definitions(motion_path_file_test PRIVATE CDPR_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
endif()
