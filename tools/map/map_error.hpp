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

// A file the user gave that is malformed in a way they can fix (a truth CSV row that cannot be
// read): exit 2, as for any other bad input, and it is found before anything is written.
class MapInputError : public MapError {
 public:
  explicit MapInputError(const std::string& what) : MapError(what) {}
};
}  // namespace tipforce::map
