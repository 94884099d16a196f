# The control socket (docs/control-protocol.md): protocol, server and client (cdpr_control), and
# the maintenance command cdprctl, whose logic lives in cdpr_ctl_app so that tests can call it.
set(_ctl ${CMAKE_CURRENT_LIST_DIR})
add_library(cdpr_control STATIC ${_ctl}/src/control_protocol.cc ${_ctl}/src/control_server.cc
                                ${_ctl}/src/control_client.cc)
target_include_directories(cdpr_control PUBLIC ${_ctl}/include)
target_link_libraries(cdpr_control PUBLIC cdpr_core nlohmann_json::nlohmann_json spdlog::spdlog
                                          Threads::Threads
                                   PRIVATE cdpr_options)

add_library(cdpr_ctl_app STATIC ${_ctl}/cdprctl/app.cc ${_ctl}/cdprctl/render.cc)
target_include_directories(cdpr_ctl_app PUBLIC ${_ctl}/cdprctl)
target_link_libraries(cdpr_ctl_app PUBLIC cdpr_control PRIVATE cdpr_io CLI11::CLI11 cdpr_version cdpr_options)

add_executable(cdprctl ${_ctl}/cdprctl/main.cc)
target_link_libraries(cdprctl PRIVATE cdpr_ctl_app cdpr_options)

cdpr_add_gtest(NAME control_protocol_test SOURCES ${_ctl}/src/control_protocol_test.cc
               LIBS cdpr_control)
cdpr_add_gtest(NAME control_server_test SOURCES ${_ctl}/src/control_server_test.cc
               LIBS cdpr_control spdlog::spdlog)
cdpr_add_gtest(NAME control_client_test SOURCES ${_ctl}/src/control_client_test.cc
               LIBS cdpr_control)
cdpr_add_gtest(NAME control_cdprctl_test SOURCES ${_ctl}/cdprctl/app_test.cc
               LIBS cdpr_ctl_app cdpr_control spdlog::spdlog)
