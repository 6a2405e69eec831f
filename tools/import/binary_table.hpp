#pragma once
// A table of fixed-size numbers in a binary file, at a known offset: what a .npy array and a raw
// DAQ dump both are once their (header or command-line) description has been read. Reads with
// pread in blocks, so a record of any length is imported without holding it in memory.
#include <cstdint>
#include <string>

#include "record_source.hpp"

namespace tipforce::import {

enum class ElementType { int16, int32, float32, float64 };
int element_bytes(ElementType t);
const char* element_name(ElementType t);

struct BinaryLayout {
  ElementType type = ElementType::float64;
  bool big_endian = false;
  bool column_major = false;   // Fortran order: each channel contiguous (else interleaved rows)
  std::int64_t data_offset = 0;
  std::int64_t rows = 0;
  int columns = 1;
};

class BinaryTable : public RecordSource {
 public:
  // Takes ownership of the open descriptor.
  BinaryTable(int fd, std::string path, BinaryLayout layout, std::string description);
  ~BinaryTable() override;
  BinaryTable(const BinaryTable&) = delete;
  BinaryTable& operator=(const BinaryTable&) = delete;

  std::int64_t rows() const override { return layout_.rows; }
  int columns() const override { return layout_.columns; }
  void read(int column, std::int64_t begin, std::int64_t n, double* out) override;
  std::string describe() const override { return description_; }

 private:
  void pread_exact(void* dst, std::size_t bytes, std::int64_t offset);
  int fd_;
  std::string path_;
  BinaryLayout layout_;
  std::string description_;
};

// Opens `path` for reading and returns the descriptor and the file's size; throws ImportError.
int open_for_reading(const std::string& path, std::int64_t& size_bytes);

}  // namespace tipforce::import
