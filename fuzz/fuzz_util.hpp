// Shared helpers of the fuzz targets: a check that aborts (so that libFuzzer reports the input)
// with a message naming what did not hold.
#pragma once

#include <cstdio>
#include <cstdlib>

#define CDPR_FUZZ_CHECK(cond, what)                                                           \
  do {                                                                                        \
    if (!(cond)) {                                                                            \
      std::fprintf(stderr, "fuzz check failed at %s:%d: %s (%s)\n", __FILE__, __LINE__, what, \
                   #cond);                                                                    \
      std::abort();                                                                           \
    }                                                                                         \
  } while (0)
