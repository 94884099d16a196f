# The calibrate verdict (calibration_verdict.hpp): how often the chi-square fit test rejects MINI
# calibrations with a concealed drum scale error of growing size, and passes null data. Printed,
# not asserted:
#   build/<dir>/bench/calibrate_verdict_bench [--seeds N] [--alpha P]
add_executable(calibrate_verdict_bench ${CMAKE_CURRENT_LIST_DIR}/calibrate_verdict_bench.cc)
target_link_libraries(calibrate_verdict_bench PRIVATE cdpr_calibration cdpr_calibration_testing)
