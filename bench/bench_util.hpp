// Helpers shared by the benchmark programs (bench/*.cc). Not installed, not a library.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <utility>

#include "cdpr/status.hpp"

namespace cdpr::bench {

// The value of `r`, or the reason on stderr and exit status 1: a benchmark cannot go on without it.
template <typename T>
T must(Result<T> r, const char* what) {
  if (!r.ok()) {
    std::fprintf(stderr, "%s failed: %s\n", what, r.status().to_string().c_str());
    std::exit(1);
  }
  return std::move(r).value();
}

}  // namespace cdpr::bench
