#pragma once
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace tipforce::map {
// A failure of `tipforce map` that is not the input's fault (an output directory that cannot be
// created, a read error of the disk): exit 1. The message names the file involved.
class MapError : public std::runtime_error {
 public:
  explicit MapError(const std::string& what) : std::runtime_error(what) {}
};

// Input the user can fix (a missing, empty or non-LCM log, one without estimates, a --probe the
// log lacks, a truth CSV row that cannot be read): exit 2, as for any other bad input, and it is
// found before anything is written.
class MapInputError : public MapError {
 public:
  explicit MapInputError(const std::string& what) : MapError(what) {}
};

// An LCM log so damaged that no estimate in it could be read (cut short inside its first event,
// say): damaged input, exit 3, as tipforce invert says of a log damaged from its first window on,
// not "not an LCM log". damage() lists the stretches skipped, each naming its file.
class MapDamagedError : public MapError {
 public:
  MapDamagedError(const std::string& what, std::vector<std::string> damage)
      : MapError(what), damage_(std::move(damage)) {}
  const std::vector<std::string>& damage() const { return damage_; }

 private:
  std::vector<std::string> damage_;
};
}  // namespace tipforce::map
