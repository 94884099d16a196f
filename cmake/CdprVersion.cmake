# The one version string of every cdpr program (`--version`): the project version of the root
# CMakeLists.txt, plus `git describe --always --dirty` of the source tree when it is a git checkout
# and git is installed ("0.1.0 (git a14659c-dirty)"), else the project version alone. Decided at
# configure time. Programs link the interface target cdpr_version and include cdpr/version.hpp.
set(CDPR_VERSION_STRING "${PROJECT_VERSION}")
find_package(Git QUIET)
if(GIT_FOUND AND EXISTS "${PROJECT_SOURCE_DIR}/.git")
  execute_process(COMMAND "${GIT_EXECUTABLE}" describe --always --dirty
                  WORKING_DIRECTORY "${PROJECT_SOURCE_DIR}"
                  OUTPUT_VARIABLE _cdpr_git_describe
                  OUTPUT_STRIP_TRAILING_WHITESPACE
                  ERROR_QUIET
                  RESULT_VARIABLE _cdpr_git_result)
  if(_cdpr_git_result EQUAL 0 AND NOT _cdpr_git_describe STREQUAL "")
    set(CDPR_VERSION_STRING "${PROJECT_VERSION} (git ${_cdpr_git_describe})")
  endif()
endif()
configure_file(${CMAKE_CURRENT_LIST_DIR}/version.hpp.in
               ${PROJECT_BINARY_DIR}/generated/cdpr/version.hpp @ONLY)
add_library(cdpr_version INTERFACE)
target_include_directories(cdpr_version INTERFACE ${PROJECT_BINARY_DIR}/generated)
