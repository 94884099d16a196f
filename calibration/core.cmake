# Shared value types: Status / Result.
cdpr_add_gtest(NAME status_test SOURCES ${CMAKE_CURRENT_LIST_DIR}/src/status_test.cc LIBS cdpr_status)
