# Install rules (`cmake --install build/release [--prefix P]`); included at the end of the root
# CMakeLists.txt so that every target exists. Layout (docs/deployment.md):
#
#   bin/                         cdprd, cdprctl, cdpr-fit, cdpr-sim (those that are targets)
#   lib/systemd/system/          cdprd.service, cdpr-calibrate.service, cdpr-calibrate.timer
#   lib/sysusers.d/cdpr.conf     the service user and group cdpr
#   <sysconfdir>/cdpr/           config/*.yaml and config/<dir>/ (robot, CANopen, laser, daemon)
#   share/doc/cdpr/              docs/*.md, README.md
#   share/doc/cdpr/examples/     network/ (systemd-networkd), data/ (config/examples),
#                                scenarios/ (config/scenarios)
#
# <sysconfdir> is /etc when the prefix is /usr (as for a Debian package: the units name
# /usr/bin/cdprd and /etc/cdpr/cdprd.yaml), else <prefix>/etc. It is decided at install time, so
# `cmake --install build --prefix /tmp/x` keeps everything under /tmp/x. A configuration file
# that already exists there is left as it is (an operator's edits survive a reinstall).
#
# No tmpfiles.d entry: StateDirectory=, RuntimeDirectory= and ConfigurationDirectory= in
# cdprd.service create /var/lib/cdpr, /run/cdpr and /etc/cdpr with the right owner and mode.
include(GNUInstallDirs)

set(CDPR_INSTALL_SYSTEMD_UNITDIR "lib/systemd/system" CACHE STRING
    "Where the systemd units go (relative to the prefix, or absolute)")
set(CDPR_INSTALL_SYSUSERSDIR "lib/sysusers.d" CACHE STRING
    "Where the sysusers.d entry goes (relative to the prefix, or absolute)")

# Programs: every program the project ships. systemd/tests/install-layout.sh (CTest
# install_layout) fails when a program defined in controller/, sim/ or tools/ is missing here, and
# runs each installed one's --version.
set(CDPR_INSTALLED_PROGRAMS "")
foreach(_prog IN ITEMS cdprd cdprctl cdpr-fit cdpr-sim)
  if(TARGET ${_prog})
    install(TARGETS ${_prog} RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
    list(APPEND CDPR_INSTALLED_PROGRAMS ${_prog})
  endif()
endforeach()

# systemd units and the service user.
install(FILES
  ${PROJECT_SOURCE_DIR}/systemd/cdprd.service
  ${PROJECT_SOURCE_DIR}/systemd/cdpr-calibrate.service
  ${PROJECT_SOURCE_DIR}/systemd/cdpr-calibrate.timer
  DESTINATION ${CDPR_INSTALL_SYSTEMD_UNITDIR})
install(FILES ${PROJECT_SOURCE_DIR}/systemd/cdpr.sysusers
  DESTINATION ${CDPR_INSTALL_SYSUSERSDIR} RENAME cdpr.conf)

# Documentation and examples.
install(FILES ${PROJECT_SOURCE_DIR}/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR})
install(DIRECTORY ${PROJECT_SOURCE_DIR}/docs/ DESTINATION ${CMAKE_INSTALL_DOCDIR}
  FILES_MATCHING PATTERN "*.md")
install(DIRECTORY ${PROJECT_SOURCE_DIR}/systemd/network/
  DESTINATION ${CMAKE_INSTALL_DOCDIR}/examples/network)
set(_dest_examples data)  # recordings and pose files
set(_dest_scenarios scenarios)  # cdpr-sim scenarios
foreach(_dir IN ITEMS examples scenarios)
  if(IS_DIRECTORY ${PROJECT_SOURCE_DIR}/config/${_dir})
    install(DIRECTORY ${PROJECT_SOURCE_DIR}/config/${_dir}/
      DESTINATION ${CMAKE_INSTALL_DOCDIR}/examples/${_dest_${_dir}}
      PATTERN "*.py" EXCLUDE)
  endif()
endforeach()

# Configuration: config/*.yaml and every config/<dir>/ except the examples above, into
# <sysconfdir>/cdpr, without replacing existing files. The source tree is read at install time.
install(CODE "set(_cdpr_config_src \"${PROJECT_SOURCE_DIR}/config\")
set(_cdpr_sysconfdir \"${CMAKE_INSTALL_SYSCONFDIR}\")")
install(CODE [==[
  if(IS_ABSOLUTE "${_cdpr_sysconfdir}")
    set(_etc "${_cdpr_sysconfdir}/cdpr")
  elseif(CMAKE_INSTALL_PREFIX STREQUAL "/usr")
    set(_etc "/etc/cdpr")
  else()
    set(_etc "${CMAKE_INSTALL_PREFIX}/${_cdpr_sysconfdir}/cdpr")
  endif()
  file(GLOB_RECURSE _configs RELATIVE "${_cdpr_config_src}"
       "${_cdpr_config_src}/*.yaml" "${_cdpr_config_src}/*.eds")
  list(SORT _configs)
  foreach(_f IN LISTS _configs)
    if(_f MATCHES "^(examples|scenarios)/")
      continue()
    endif()
    get_filename_component(_sub "${_etc}/${_f}" DIRECTORY)
    # file(INSTALL) puts DESTDIR in front of an absolute destination; EXISTS does not.
    if(EXISTS "$ENV{DESTDIR}${_etc}/${_f}")
      message(STATUS "Kept (exists): $ENV{DESTDIR}${_etc}/${_f}")
    else()
      file(INSTALL "${_cdpr_config_src}/${_f}" DESTINATION "${_sub}"
           FILE_PERMISSIONS OWNER_READ OWNER_WRITE GROUP_READ WORLD_READ)
    endif()
  endforeach()
]==])

# Tests of the installed tree: the layout, and `systemd-analyze verify` of every unit in a
# temporary root populated by `cmake --install` (systemd/tests/).
if(CDPR_BUILD_TESTS)
  add_test(NAME install_layout
           COMMAND ${PROJECT_SOURCE_DIR}/systemd/tests/install-layout.sh
                   ${CMAKE_COMMAND} ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR}
                   "${CDPR_INSTALLED_PROGRAMS}")
  set_tests_properties(install_layout PROPERTIES LABELS "install" TIMEOUT 120
                                                 RESOURCE_LOCK cdpr_install)
  find_program(CDPR_SYSTEMD_ANALYZE systemd-analyze)
  add_test(NAME systemd_units_verify
           COMMAND ${PROJECT_SOURCE_DIR}/systemd/tests/verify-units.sh
                   ${CMAKE_COMMAND} ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR}
                   "${CDPR_INSTALLED_PROGRAMS}")
  set_tests_properties(systemd_units_verify PROPERTIES LABELS "systemd" TIMEOUT 180
                                                       RESOURCE_LOCK cdpr_install
                                                       SKIP_RETURN_CODE 77)
endif()
