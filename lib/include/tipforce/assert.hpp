#pragma once
// Two kinds of checks, after Drake: TIPFORCE_THROW_UNLESS for a caller's mistake (throws
// std::invalid_argument naming the condition), TIPFORCE_DEMAND for an internal invariant (aborts:
// if it fails, tipforce itself is wrong).
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>

namespace tipforce::detail {
[[noreturn]] inline void throw_unless_failed(const char* cond, const char* func, const char* file, int line,
                                             const std::string& what) {
  throw std::invalid_argument(std::string(func) + ": " + (what.empty() ? std::string("condition '") + cond +
                                                                            "' failed" : what) +
                              " (" + file + ":" + std::to_string(line) + ")");
}
[[noreturn]] inline void demand_failed(const char* cond, const char* func, const char* file, int line) {
  std::fprintf(stderr, "tipforce: internal invariant '%s' failed in %s at %s:%d\n", cond, func, file, line);
  std::abort();
}
}  // namespace tipforce::detail

#define TIPFORCE_THROW_UNLESS(cond, ...)                                                           \
  do {                                                                                             \
    if (!(cond)) ::tipforce::detail::throw_unless_failed(#cond, __func__, __FILE__, __LINE__,     \
                                                         std::string{__VA_ARGS__});               \
  } while (0)

#define TIPFORCE_DEMAND(cond)                                                                      \
  do {                                                                                             \
    if (!(cond)) ::tipforce::detail::demand_failed(#cond, __func__, __FILE__, __LINE__);          \
  } while (0)
