#include "cdpr/io/output_paths.hpp"

#include <filesystem>
#include <system_error>

namespace cdpr::io {

namespace fs = std::filesystem;

bool same_file(const std::string& a, const std::string& b) {
  std::error_code ea, eb;
  const bool a_exists = fs::exists(a, ea), b_exists = fs::exists(b, eb);
  if (a_exists && b_exists) {
    std::error_code e;
    const bool same = fs::equivalent(a, b, e);
    if (!e) return same;
  }
  std::error_code ca, cb;
  const fs::path pa = fs::weakly_canonical(fs::absolute(a, ca), ca);
  const fs::path pb = fs::weakly_canonical(fs::absolute(b, cb), cb);
  if (ca || cb) return fs::path(a).lexically_normal() == fs::path(b).lexically_normal();
  return pa == pb;
}

Status check_output_paths(const std::vector<NamedPath>& inputs,
                          const std::vector<NamedPath>& outputs) {
  for (std::size_t k = 0; k < outputs.size(); ++k) {
    const NamedPath& out = outputs[k];
    if (out.path.empty()) continue;
    for (const NamedPath& in : inputs) {
      if (in.path.empty() || !same_file(out.path, in.path)) continue;
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s %s is the same file as the input %s %s: refusing to overwrite it",
                           out.option.c_str(), out.path.c_str(), in.option.c_str(),
                           in.path.c_str());
    }
    for (std::size_t j = 0; j < k; ++j) {
      const NamedPath& other = outputs[j];
      if (other.path.empty() || !same_file(out.path, other.path)) continue;
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s %s is the same file as %s %s: each output needs its own file",
                           out.option.c_str(), out.path.c_str(), other.option.c_str(),
                           other.path.c_str());
    }
  }
  return Status::success();
}

}  // namespace cdpr::io
