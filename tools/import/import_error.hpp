#pragma once
#include <stdexcept>
#include <string>

namespace tipforce::import {
// A user-facing failure of `tipforce import`: a file that cannot be read, is not what it claims,
// is truncated, holds non-finite samples or is too short for the scan geometry. The message
// names the file and what is wrong; the command prints it and exits 2 (nothing is left behind).
class ImportError : public std::runtime_error {
 public:
  explicit ImportError(const std::string& what) : std::runtime_error(what) {}
};
}  // namespace tipforce::import
