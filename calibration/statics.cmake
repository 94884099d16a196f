# Model checks, statics (force distribution) and the elasto-static forward model.
target_sources(cdpr_calibration PRIVATE ${CMAKE_CURRENT_LIST_DIR}/src/model_check.cc
                                        ${CMAKE_CURRENT_LIST_DIR}/src/elastostatics.cc
                                        ${CMAKE_CURRENT_LIST_DIR}/src/force_distribution.cc)

# Unit tests beside their sources.
cdpr_add_gtest(NAME model_check_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/model_check_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing)
cdpr_add_gtest(NAME elastostatics_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/elastostatics_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing cdpr_test_support)
cdpr_add_gtest(NAME force_distribution_test
               SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/force_distribution_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing cdpr_test_support)
