# Concealed-effect benchmark of the mismatch locator (issue 7): hidden effects switched on in the
# virtual robot's physics (cdpr-sim), diagnose() run blind, confusion matrix, detection and false
# finding rates, fitted-parameter error, residual and held-out RMS before/after. Printed figures:
#   build/<dir>/bench/mismatch_bench [--seeds N] [--quick] [--robot mini|large|both] [--effects a,b]
# See docs/mismatch-benchmark.md.
if(TARGET cdpr_sim)
  add_executable(mismatch_bench ${CMAKE_CURRENT_LIST_DIR}/mismatch_bench.cc)
  target_link_libraries(mismatch_bench
    PRIVATE cdpr_sim cdpr_report cdpr_calibration cdpr_calibration_testing cdpr_daemon
            Threads::Threads cdpr_options)
endif()
