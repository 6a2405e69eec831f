// libFuzzer: the bytes of an LCM log file -> LogReader, every event read. Damage must be skipped
// and counted, never crash, hang or allocate more than the file holds.
#include <sys/mman.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "tipforce/event_log.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  // An in-memory file, named through /proc, as LogReader reads paths.
  static const int fd = ::memfd_create("fuzz.lcmlog", 0);
  if (fd < 0) std::abort();
  if (::ftruncate(fd, 0) != 0 || ::pwrite(fd, data, size, 0) != static_cast<ssize_t>(size)) std::abort();
  tipforce::lcmio::LogReader reader("/proc/self/fd/" + std::to_string(fd));
  std::size_t bytes = 0;
  while (auto event = reader.next()) {
    bytes += event->data.size() + event->channel.size();
    if (bytes > size) std::abort();  // more read than the file holds
  }
  (void)reader.take_damage();
  return 0;
}
