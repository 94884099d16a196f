# controller/platform.cmake: the daemon's platform layer (cdpr_rt).
#   rt_thread.hpp    SCHED_FIFO, affinity, mlockall, pre-faulting; PeriodicTimer and RtLoop on
#                    absolute CLOCK_MONOTONIC wake-ups, overrun detection and re-alignment
#   cycle_stats.hpp  log-linear latency/compute histograms, lock-free snapshot (seqlock)
#   sd_notify.hpp    READY/STATUS/WATCHDOG/STOPPING to systemd (libsystemd)
# Included from controller/CMakeLists.txt (CDPR_CONTROLLER_DIR is controller/).
pkg_check_modules(SYSTEMD REQUIRED IMPORTED_TARGET libsystemd)

add_library(cdpr_rt
  ${CDPR_CONTROLLER_DIR}/src/cycle_stats.cc
  ${CDPR_CONTROLLER_DIR}/src/rt_thread.cc
  ${CDPR_CONTROLLER_DIR}/src/sd_notify.cc
)
# The seqlock is header-only and lives in drivers/modbus (cdpr::modbus::SeqLock): only its
# include directory is used, not the Modbus library.
target_include_directories(cdpr_rt PUBLIC
  ${CDPR_CONTROLLER_DIR}/include
  $<TARGET_PROPERTY:cdpr_modbus,INTERFACE_INCLUDE_DIRECTORIES>)
target_link_libraries(cdpr_rt
  PUBLIC cdpr_core Threads::Threads
  PRIVATE PkgConfig::SYSTEMD cdpr_options)

cdpr_add_gtest(NAME rt_cycle_stats_test
               SOURCES ${CDPR_CONTROLLER_DIR}/src/cycle_stats_test.cc
               LIBS cdpr_rt cdpr_test_support)
cdpr_add_gtest(NAME rt_thread_test
               SOURCES ${CDPR_CONTROLLER_DIR}/src/rt_thread_test.cc
               LIBS cdpr_rt cdpr_test_support)
cdpr_add_gtest(NAME rt_sd_notify_test
               SOURCES ${CDPR_CONTROLLER_DIR}/src/sd_notify_test.cc
               LIBS cdpr_rt)
