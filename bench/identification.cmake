# Identification benchmark: accuracy versus the Cramer-Rao bound and the paper's method, ISO 9283
# box position error, speed (ours vs the paper's method, 25 -> 2,500 poses), Monte Carlo bias and
# coverage. Printed figures, not timed tests:
#   build/<dir>/bench/identification_bench [--seeds N] [--quick]
add_executable(identification_bench ${CMAKE_CURRENT_LIST_DIR}/identification_bench.cc)
target_link_libraries(identification_bench PRIVATE cdpr_calibration cdpr_calibration_testing cdpr_options)

# Issue 18: MINI or LARGE with laser / with swivel angles + inclinometer / with nothing extra / all,
# side by side (poses designed per configuration; Monte Carlo, Cramer-Rao bound, prediction,
# coverage, box position error):
#   build/<dir>/bench/sensors_bench [--seeds N] [--robot mini|large] [--laser-poses]
add_executable(sensors_bench ${CMAKE_CURRENT_LIST_DIR}/sensors_bench.cc)
target_link_libraries(sensors_bench PRIVATE cdpr_calibration cdpr_calibration_testing cdpr_options)
# Issue 18, second part: the 4-cable suspended crane (config/crane4.yaml) with swivel angles,
# inclinometer and load cells (Monte Carlo, Cramer-Rao bound, coverage, box position error):
#   build/<dir>/bench/crane_bench [--seeds N]
add_executable(crane_bench ${CMAKE_CURRENT_LIST_DIR}/crane_bench.cc)
target_link_libraries(crane_bench PRIVATE cdpr_calibration cdpr_calibration_testing cdpr_options)
