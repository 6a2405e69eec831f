// keep_freed_memory_in_process() against glibc's own bookkeeping: a block of a few MB comes from
// the heap afterwards, not from a fresh mapping (which would be faulted in again on every use).
#include <gtest/gtest.h>

#include <cstdlib>

#include "tipforce/process_memory.hpp"

#if defined(__GLIBC__)
#include <malloc.h>

namespace {

// Bytes glibc holds in mmap'ed blocks right now.
std::size_t mapped_bytes() { return mallinfo2().hblkhd; }

TEST(ProcessMemory, LargeBlocksComeFromTheHeapAfterwards) {
  constexpr std::size_t kBlockBytes = 4 * 1024 * 1024;  // a physics grid's buffers are ~1 MB
  {
    const std::size_t before = mapped_bytes();
    void* block = std::malloc(kBlockBytes);
    ASSERT_NE(block, nullptr);
    // glibc's default (128 KiB threshold) maps such a block: the precondition that makes the
    // check below mean something.
    EXPECT_GE(mapped_bytes(), before + kBlockBytes);
    std::free(block);
  }
  ASSERT_TRUE(tipforce::keep_freed_memory_in_process());
  const std::size_t before = mapped_bytes();
  void* block = std::malloc(kBlockBytes);
  ASSERT_NE(block, nullptr);
  EXPECT_EQ(mapped_bytes(), before) << "a 4 MiB block was still mapped, not taken from the heap";
  std::free(block);
}

}  // namespace
#else
TEST(ProcessMemory, SkippedWithoutGlibc) {
  GTEST_SKIP() << "keep_freed_memory_in_process() acts on glibc's allocator only";
}
#endif
