#include "binary_table.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstring>
#include <vector>

#include "import_error.hpp"

namespace tipforce::import {
namespace {

template <typename Int>
Int load(const unsigned char* p, bool big_endian) {
  Int v = 0;
  for (std::size_t i = 0; i < sizeof(Int); ++i) {
    const std::size_t k = big_endian ? i : sizeof(Int) - 1 - i;
    v = static_cast<Int>((v << 8) | p[k]);
  }
  return v;
}

double to_double(const unsigned char* p, ElementType t, bool big_endian) {
  switch (t) {
    case ElementType::int16: return static_cast<std::int16_t>(load<std::uint16_t>(p, big_endian));
    case ElementType::int32: return static_cast<std::int32_t>(load<std::uint32_t>(p, big_endian));
    case ElementType::float32: return std::bit_cast<float>(load<std::uint32_t>(p, big_endian));
    case ElementType::float64: return std::bit_cast<double>(load<std::uint64_t>(p, big_endian));
  }
  return 0;
}

}  // namespace

int element_bytes(ElementType t) {
  switch (t) {
    case ElementType::int16: return 2;
    case ElementType::int32: return 4;
    case ElementType::float32: return 4;
    case ElementType::float64: return 8;
  }
  return 1;
}

const char* element_name(ElementType t) {
  switch (t) {
    case ElementType::int16: return "int16";
    case ElementType::int32: return "int32";
    case ElementType::float32: return "float32";
    case ElementType::float64: return "float64";
  }
  return "?";
}

int open_for_reading(const std::string& path, std::int64_t& size_bytes) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw ImportError(path + ": cannot open: " + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    throw ImportError(path + ": not a regular file");
  }
  size_bytes = st.st_size;
  return fd;
}

BinaryTable::BinaryTable(int fd, std::string path, BinaryLayout layout, std::string description)
    : fd_(fd), path_(std::move(path)), layout_(layout), description_(std::move(description)) {}

BinaryTable::~BinaryTable() { ::close(fd_); }

void BinaryTable::pread_exact(void* dst, std::size_t bytes, std::int64_t offset) {
  auto* p = static_cast<unsigned char*>(dst);
  while (bytes > 0) {
    const ssize_t got = ::pread(fd_, p, bytes, offset);
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0)
      throw ImportError(path_ + ": read failed at byte " + std::to_string(offset) + ": " +
                        (got < 0 ? std::strerror(errno) : "unexpected end of file (was it truncated while importing?)"));
    p += got;
    bytes -= static_cast<std::size_t>(got);
    offset += got;
  }
}

void BinaryTable::read(int column, std::int64_t begin, std::int64_t n, double* out) {
  if (column < 0 || column >= layout_.columns || begin < 0 || n < 0 || begin + n > layout_.rows)
    throw ImportError(path_ + ": internal: rows " + std::to_string(begin) + "+" + std::to_string(n) + " of column " +
                      std::to_string(column) + " are outside the table");
  const int size = element_bytes(layout_.type);
  // Blocks of at most 1 MiB of rows, so memory stays bounded whatever the window length.
  const std::int64_t row_bytes = layout_.column_major ? size : static_cast<std::int64_t>(size) * layout_.columns;
  const std::int64_t block_rows = std::max<std::int64_t>(1, (std::int64_t{1} << 20) / row_bytes);
  std::vector<unsigned char> buf;
  for (std::int64_t done = 0; done < n;) {
    const std::int64_t k = std::min(block_rows, n - done);
    const std::int64_t row = begin + done;
    buf.resize(static_cast<std::size_t>(k * row_bytes));
    const std::int64_t offset =
        layout_.column_major
            ? layout_.data_offset + (static_cast<std::int64_t>(column) * layout_.rows + row) * size
            : layout_.data_offset + row * row_bytes;
    pread_exact(buf.data(), buf.size(), offset);
    const std::int64_t stride = layout_.column_major ? size : row_bytes;
    const std::int64_t first = layout_.column_major ? 0 : static_cast<std::int64_t>(column) * size;
    for (std::int64_t i = 0; i < k; ++i)
      out[done + i] = to_double(buf.data() + first + i * stride, layout_.type, layout_.big_endian);
    done += k;
  }
}

}  // namespace tipforce::import
