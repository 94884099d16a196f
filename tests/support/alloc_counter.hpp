// Counts calls of the global operator new, to prove that a code path does not allocate.
//
// Linking cdpr_test_support replaces the global operator new/delete (all forms) of the test
// binary with versions that count. Use:
//
//   cdpr::test::AllocationCounter count;     // starts counting on this thread
//   bus.send(frame);
//   EXPECT_EQ(count.allocations(), 0u);      // operator new calls on this thread since creation
//
// Counts are per thread (so gtest's or other threads' allocations do not disturb a measurement)
// plus a process-wide total.
#pragma once

#include <cstdint>

namespace cdpr::test {

// operator new calls made by the calling thread since it started.
std::uint64_t thread_allocations();
// operator new calls made by all threads since the process started.
std::uint64_t total_allocations();

class AllocationCounter {
 public:
  AllocationCounter() : thread_start_(thread_allocations()), total_start_(total_allocations()) {}
  // On this thread since construction.
  std::uint64_t allocations() const { return thread_allocations() - thread_start_; }
  // On all threads since construction.
  std::uint64_t all_threads() const { return total_allocations() - total_start_; }

 private:
  std::uint64_t thread_start_;
  std::uint64_t total_start_;
};

}  // namespace cdpr::test
