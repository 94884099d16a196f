# The daemon: configuration, RT cycle, supervisor and calibration sequence, state directory,
# calibration report (library cdpr_daemon), and the executable cdprd (docs/daemon.md).
set(_d ${CDPR_CONTROLLER_DIR})
add_library(cdpr_daemon STATIC
  ${_d}/src/daemon_config.cc
  ${_d}/src/config_check.cc
  ${_d}/src/safety_config.cc
  ${_d}/src/canopen_robot_io.cc
  ${_d}/src/rt_controller.cc
  ${_d}/src/rt_controller_watch.cc
  ${_d}/src/rt_controller_motion.cc
  ${_d}/src/rt_controller_safety.cc
  ${_d}/src/rt_controller_tension.cc
  ${_d}/src/tension_control.cc
  ${_d}/src/state_store.cc
  ${_d}/src/calibration_report.cc
  ${_d}/src/calibration_report_iso9283.cc
  ${_d}/src/supervisor.cc
  ${_d}/src/measuring_sequence.cc
  ${_d}/src/daemon_text.cc
  ${_d}/src/daemon.cc
  ${_d}/src/daemon_state.cc
  ${_d}/src/daemon_service.cc
  ${_d}/src/daemon_homing.cc
  ${_d}/src/daemon_calibration.cc
  ${_d}/src/daemon_commands.cc
  ${_d}/src/log_coalescer.cc
  ${_d}/src/setpoint_stream.cc
  ${_d}/src/daemon_motion.cc
  ${_d}/src/daemon_health.cc)
target_include_directories(cdpr_daemon PUBLIC ${_d}/include)
target_link_libraries(cdpr_daemon
  PUBLIC cdpr_io cdpr_control cdpr_calibration_motion cdpr_canopen cdpr_can cdpr_modbus cdpr_config cdpr_recording
         cdpr_calibration cdpr_report nlohmann_json::nlohmann_json Threads::Threads cdpr_version
  PRIVATE spdlog::spdlog cdpr_yaml cdpr_options)

# Test support: a fake robot I/O for unit tests of the RT cycle (controller/testing).
if(CDPR_BUILD_TESTS)
  add_library(cdpr_daemon_testing STATIC ${_d}/testing/fake_robot_io.cc)
  target_include_directories(cdpr_daemon_testing PUBLIC ${_d}/testing)
  target_link_libraries(cdpr_daemon_testing PUBLIC cdpr_daemon PRIVATE cdpr_options)
endif()

cdpr_add_gtest(NAME daemon_rt_controller_test SOURCES ${_d}/src/rt_controller_test.cc
                                                       ${_d}/src/rt_controller_motion_test.cc
               LIBS cdpr_daemon cdpr_daemon_testing cdpr_calibration_testing cdpr_test_support)
cdpr_add_gtest(NAME daemon_tension_control_test SOURCES ${_d}/src/tension_control_test.cc
               LIBS cdpr_daemon cdpr_daemon_testing cdpr_calibration_testing cdpr_test_support)
cdpr_add_gtest(NAME daemon_config_test SOURCES ${_d}/src/daemon_config_test.cc LIBS cdpr_daemon)
cdpr_add_gtest(NAME daemon_state_store_test SOURCES ${_d}/src/state_store_test.cc LIBS cdpr_daemon)
cdpr_add_gtest(NAME daemon_log_coalescer_test SOURCES ${_d}/src/log_coalescer_test.cc
               LIBS cdpr_daemon)
cdpr_add_gtest(NAME daemon_calibration_report_test SOURCES ${_d}/src/calibration_report_test.cc
               ${_d}/src/calibration_report_iso9283_test.cc LIBS cdpr_daemon
               cdpr_calibration_testing)
cdpr_add_gtest(NAME daemon_supervisor_test SOURCES ${_d}/src/supervisor_test.cc LIBS cdpr_daemon)
cdpr_add_gtest(NAME daemon_measuring_sequence_test SOURCES ${_d}/src/measuring_sequence_test.cc
               LIBS cdpr_daemon)
foreach(t daemon_state_store_test daemon_config_test daemon_supervisor_test)
  if(TARGET ${t})
    target_compile_definitions(${t} PRIVATE CDPR_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
  endif()
endforeach()

add_executable(cdprd ${_d}/cdprd/main.cc)
target_link_libraries(cdprd PRIVATE cdpr_daemon cdpr_rt cdpr_control CLI11::CLI11 spdlog::spdlog
                                    cdpr_options)

# cdprd --check-config: the checks in-process and through the cdprd binary (no bus is touched).
cdpr_add_gtest(NAME daemon_config_check_test SOURCES ${_d}/src/config_check_test.cc
               LIBS cdpr_daemon cdpr_test_support)
if(TARGET daemon_config_check_test)
  target_compile_definitions(daemon_config_check_test PRIVATE CDPR_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
                                                              CDPR_CDPRD_BIN="$<TARGET_FILE:cdprd>")
  add_dependencies(daemon_config_check_test cdprd)
endif()
