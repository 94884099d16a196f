# daemon_bench: cdprd's RT cycle and a full calibration with the virtual robot in one process
# (tests/daemon/virtual_cell.hpp). Figures only.
add_executable(daemon_bench ${CMAKE_CURRENT_LIST_DIR}/daemon_bench.cc)
target_include_directories(daemon_bench PRIVATE ${PROJECT_SOURCE_DIR}/tests/daemon)
target_link_libraries(daemon_bench PRIVATE cdpr_daemon cdpr_sim cdpr_options)
target_compile_definitions(daemon_bench PRIVATE CDPR_SOURCE_DIR="${PROJECT_SOURCE_DIR}")

# daemon_soak: the daemon and the virtual robot for 30 minutes of simulated motion with repeated
# calibrations, accepts, rejects and rollbacks; RSS, fds and the cycle's compute time (docs/reliability.md).
add_executable(daemon_soak ${CMAKE_CURRENT_LIST_DIR}/daemon_soak.cc)
target_include_directories(daemon_soak PRIVATE ${PROJECT_SOURCE_DIR}/tests/daemon)
target_link_libraries(daemon_soak PRIVATE cdpr_daemon cdpr_sim cdpr_options spdlog::spdlog)
target_compile_definitions(daemon_soak PRIVATE CDPR_SOURCE_DIR="${PROJECT_SOURCE_DIR}")

# stream_latency_bench: the setpoint stream's latency and jitter with the real clock (a sender, the
# receiver thread, the RT loop's ring and a loop at the cycle period; docs/motion.md "Setpoint stream").
add_executable(stream_latency_bench ${CMAKE_CURRENT_LIST_DIR}/stream_latency_bench.cc)
target_link_libraries(stream_latency_bench PRIVATE cdpr_daemon cdpr_options)
