#include "tipforce/process_memory.hpp"

// A C library header first: it is what defines __GLIBC__ (without one, the test below was always
// false and this function did nothing).
#include <cstdlib>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace tipforce {

bool keep_freed_memory_in_process() {
#if defined(__GLIBC__)
  // 32 MiB is glibc's largest mmap threshold on 64-bit (DEFAULT_MMAP_THRESHOLD_MAX); a block
  // larger than that is rare here (a Jacobian of 1e6 samples) and still mapped. Setting it also
  // stops glibc's dynamic threshold from moving. The trim threshold keeps the heap's top.
  const bool mmap_set = mallopt(M_MMAP_THRESHOLD, 32 * 1024 * 1024) == 1;
  const bool trim_set = mallopt(M_TRIM_THRESHOLD, 1024 * 1024 * 1024) == 1;
  return mmap_set && trim_set;
#else
  return false;
#endif
}

}  // namespace tipforce
