# RT loop: wake-up latency at 250 Hz of RtLoop against a plain std::this_thread::sleep_until loop
# in the same run, and the loop's own bookkeeping cost per cycle (printed, never asserted).
if(TARGET cdpr_rt)
  add_executable(rt_loop_bench ${CMAKE_CURRENT_LIST_DIR}/rt_loop_bench.cc)
  target_link_libraries(rt_loop_bench PRIVATE cdpr_rt cdpr_options)
endif()
