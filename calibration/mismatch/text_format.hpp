// printf-style formatting into a std::string of any length, for the words calibration/mismatch
// puts in its reports (private to this folder).
#pragma once

#include <cstdio>
#include <string>

namespace cdpr::mismatch_detail {

std::string format(const char* fmt, auto... args) {
  const int len = std::snprintf(nullptr, 0, fmt, args...);
  if (len <= 0) return std::string();
  std::string out(static_cast<std::size_t>(len) + 1, '\0');
  std::snprintf(out.data(), out.size(), fmt, args...);
  out.resize(static_cast<std::size_t>(len));
  return out;
}

}  // namespace cdpr::mismatch_detail
