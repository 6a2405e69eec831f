// Raw little-endian samples without a header, as DAQ cards and FPGA captures dump them: int16
// counts, float32 or float64 volts, one channel or several interleaved sample by sample. The
// file's size must be a whole number of samples of every channel, else it was cut short.
#include <unistd.h>

#include "binary_table.hpp"
#include "import_error.hpp"

namespace tipforce::import {

std::unique_ptr<RecordSource> open_raw(const RecordSpec& spec) {
  BinaryLayout layout;
  if (spec.raw_dtype == "int16") layout.type = ElementType::int16;
  else if (spec.raw_dtype == "float32") layout.type = ElementType::float32;
  else if (spec.raw_dtype == "float64") layout.type = ElementType::float64;
  else if (spec.raw_dtype.empty()) throw ImportError(spec.path + ": a raw file needs --dtype int16, float32 or float64");
  else throw ImportError(spec.path + ": --dtype " + spec.raw_dtype + " is not supported for raw files (int16, float32, float64)");
  if (spec.raw_channels < 1 || spec.raw_channels > 4096)
    throw ImportError(spec.path + ": --raw-channels must be 1 to 4096, got " + std::to_string(spec.raw_channels));
  std::int64_t size = 0;
  const int fd = open_for_reading(spec.path, size);
  const std::int64_t frame = static_cast<std::int64_t>(element_bytes(layout.type)) * spec.raw_channels;
  if (size % frame != 0) {
    ::close(fd);
    throw ImportError(spec.path + ": truncated: " + std::to_string(size) + " bytes is not a whole number of " +
                      std::to_string(spec.raw_channels) + "-channel " + spec.raw_dtype + " samples (" +
                      std::to_string(frame) + " bytes each); the last " + std::to_string(size % frame) +
                      " bytes are a cut sample");
  }
  if (size == 0) {
    ::close(fd);
    throw ImportError(spec.path + ": the file is empty");
  }
  layout.rows = size / frame;
  layout.columns = spec.raw_channels;
  const std::string what = spec.path + " (raw " + spec.raw_dtype + " little-endian, " +
                           std::to_string(spec.raw_channels) + " channel" + (spec.raw_channels > 1 ? "s" : "") + ")";
  return std::make_unique<BinaryTable>(fd, spec.path, layout, what);
}

}  // namespace tipforce::import
