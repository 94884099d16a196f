# cdpr-fit: the offline identification tool (docs/cdpr-fit.md). The logic lives in the library
# cdpr_fit_app so that tests can call it; main() only calls cdpr::fit::run().
set(_fit ${CMAKE_CURRENT_LIST_DIR}/cdpr-fit)
add_library(cdpr_fit_app STATIC ${_fit}/app.cc ${_fit}/common.cc ${_fit}/recording_options.cc ${_fit}/progress.cc ${_fit}/cmd_simulate.cc
                                ${_fit}/cmd_calibrate.cc ${_fit}/cmd_fit_sensors.cc
                                ${_fit}/cmd_design.cc ${_fit}/cmd_diagnose.cc
                                ${_fit}/cmd_validate.cc)
target_include_directories(cdpr_fit_app PUBLIC ${_fit})
target_link_libraries(cdpr_fit_app PUBLIC cdpr_recording cdpr_config cdpr_io cdpr_report cdpr_calibration
                                          nlohmann_json::nlohmann_json CLI11::CLI11 spdlog::spdlog
                                          cdpr_version
                                   PRIVATE cdpr_options)

add_executable(cdpr-fit ${_fit}/main.cc)
target_link_libraries(cdpr-fit PRIVATE cdpr_fit_app cdpr_options)
