# Robot model, kinematics and cable physics.
target_sources(cdpr_calibration PRIVATE ${CMAKE_CURRENT_LIST_DIR}/src/kinematics.cc)
