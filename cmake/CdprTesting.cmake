# Helpers that keep every test registration uniform.
#
# cdpr_add_gtest(NAME <target> SOURCES <files...> LIBS <targets...> [LABELS <labels...>])
#   Builds one GoogleTest executable and registers its cases with CTest (label "unit" by default).
#   Test targets are named <folder>_<stem>_test: <folder> is the directory that holds the test
#   (for tests/<dir>: <dir>), <stem> the source's name without _test.cc (or what a multi-file test
#   covers), and the folder is not repeated when the stem starts with it: core_status_test,
#   model_kinematics_test, modbus_register_map_test, fit_cdpr_fit_test, recording_test,
#   sim_master_vcan_test. In controller/, whose units share one folder, <folder> is the area of
#   the CMake fragment: rt_thread_test, motion_trajectory_test, control_cdprctl_test,
#   daemon_fault_matrix_test.
#
# cdpr_add_vcan_test(NAME <test> COMMAND <cmd...> [LABELS ...] [TIMEOUT s])
#   Registers a test that needs a kernel CAN bus. It runs through tests/vcan/vcan-run, which uses
#   native vcan where the kernel has it and boots user-mode-linux where it has not.
#
# cdpr_add_cell_vcan_test(NAME <test> SCRIPT <file.py> [LABELS ...] [TIMEOUT s])
#   A vcan test of cdprd, cdprctl and cdpr-sim as separate processes: the Python SCRIPT (in the
#   calling folder; it uses tests/support/vcan_harness.py) is given the three programs, the source
#   tree and its work directory, <binary folder>/<script's stem without _test>_work.
set(CDPR_VCAN_RUN ${CMAKE_SOURCE_DIR}/tests/vcan/vcan-run)

function(cdpr_add_gtest)
  cmake_parse_arguments(T "" "NAME" "SOURCES;LIBS;LABELS" ${ARGN})
  if(NOT CDPR_BUILD_TESTS)
    return()
  endif()
  add_executable(${T_NAME} ${T_SOURCES})
  target_link_libraries(${T_NAME} PRIVATE ${T_LIBS} GTest::gtest GTest::gtest_main GTest::gmock cdpr_options)
  if(NOT T_LABELS)
    set(T_LABELS unit)
  endif()
  gtest_discover_tests(${T_NAME} PROPERTIES LABELS "${T_LABELS}" DISCOVERY_TIMEOUT 60)
endfunction()

function(cdpr_add_vcan_test)
  cmake_parse_arguments(T "" "NAME;TIMEOUT" "COMMAND;LABELS" ${ARGN})
  if(NOT CDPR_BUILD_TESTS)
    return()
  endif()
  if(NOT T_TIMEOUT)
    set(T_TIMEOUT 300)
  endif()
  # vcan-run's own limit ends the command (and user-mode-linux) a little before CTest's.
  math(EXPR _inner "${T_TIMEOUT} - 30")
  add_test(NAME ${T_NAME} COMMAND ${CDPR_VCAN_RUN} --timeout ${_inner} -- ${T_COMMAND})
  # One user-mode-linux kernel at a time: two at once on a 2-core machine make both late.
  set_tests_properties(${T_NAME} PROPERTIES LABELS "vcan;${T_LABELS}" TIMEOUT ${T_TIMEOUT}
                                            RESOURCE_LOCK cdpr_kernel_can
                                            WORKING_DIRECTORY ${CMAKE_BINARY_DIR})
endfunction()

function(cdpr_add_cell_vcan_test)
  cmake_parse_arguments(T "" "NAME;SCRIPT;TIMEOUT" "LABELS" ${ARGN})
  get_filename_component(_stem ${T_SCRIPT} NAME_WE)
  string(REGEX REPLACE "_test$" "" _stem ${_stem})
  cdpr_add_vcan_test(NAME ${T_NAME}
                     COMMAND /usr/bin/python3 ${CMAKE_CURRENT_SOURCE_DIR}/${T_SCRIPT}
                             $<TARGET_FILE:cdprd> $<TARGET_FILE:cdprctl> $<TARGET_FILE:cdpr-sim>
                             ${PROJECT_SOURCE_DIR} ${CMAKE_CURRENT_BINARY_DIR}/${_stem}_work
                     LABELS ${T_LABELS}
                     TIMEOUT ${T_TIMEOUT})
endfunction()
