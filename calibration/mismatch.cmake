# Mismatch locator: where simulation and recordings disagree, and which missing physics explains it.
target_sources(cdpr_calibration PRIVATE ${CMAKE_CURRENT_LIST_DIR}/src/mismatch.cc)

cdpr_add_gtest(NAME mismatch_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/mismatch_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing)
target_include_directories(mismatch_test PRIVATE ${CMAKE_CURRENT_LIST_DIR}/src)

# The complete mismatch locator (diagnosis.hpp): selection, refits, naming, verdict.
target_sources(cdpr_calibration PRIVATE ${CMAKE_CURRENT_LIST_DIR}/src/diagnosis.cc
                                        ${CMAKE_CURRENT_LIST_DIR}/src/residual_explanation.cc)
cdpr_add_gtest(NAME diagnosis_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/diagnosis_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing)
target_include_directories(diagnosis_test PRIVATE ${CMAKE_CURRENT_LIST_DIR}/src)

# The variables that would explain each effect, and the residuals against them (reports' plots).
cdpr_add_gtest(NAME residual_explanation_test
               SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/residual_explanation_test.cc
               LIBS cdpr_calibration cdpr_calibration_testing)
