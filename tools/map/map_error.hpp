#pragma once
#include <stdexcept>
#include <string>

namespace tipforce::map {
// A user-facing failure of `tipforce map` (unreadable input, nothing to map, unwritable output).
// The message names the file involved; the command prints it and exits non-zero.
class MapError : public std::runtime_error {
 public:
  explicit MapError(const std::string& what) : std::runtime_error(what) {}
};
}  // namespace tipforce::map
