#pragma once
// A recorded signal as a table: rows are samples in time, columns are channels (a DAQ's
// deflection, a second channel with the measured base motion). Each file format reads its own
// kind of file behind this one interface, so the scan layout and the calibration never care
// which format the record came in.
#include <cstdint>
#include <memory>
#include <string>

namespace tipforce::import {

enum class RecordFormat { automatic, hdf5, npy, raw, csv };
// "auto", "hdf5", "npy", "raw", "csv"; throws ImportError for anything else.
RecordFormat parse_record_format(const std::string& name);
// The format a file name implies (.h5 .hdf5 .hdf .he5 -> hdf5, .npy, .csv .txt -> csv,
// .bin .raw .dat -> raw); throws ImportError naming the file when the name says nothing.
RecordFormat format_from_name(const std::string& path);

struct RecordSpec {
  std::string path;
  RecordFormat format = RecordFormat::automatic;
  std::string dataset;     // HDF5: the dataset's path in the file ("/scan/deflection")
  std::string raw_dtype;   // raw: "int16", "float32" or "float64" (little-endian)
  int raw_channels = 1;    // raw: channels interleaved sample by sample
};

class RecordSource {
 public:
  virtual ~RecordSource() = default;
  // Samples per channel.
  virtual std::int64_t rows() const = 0;
  virtual int columns() const = 0;
  // The column called `name` in the file (a CSV header), or -1.
  virtual int column_named(const std::string& name) const { (void)name; return -1; }
  // Column `column` of rows [begin, begin + n) as stored (counts or volts), widened to double.
  // Throws ImportError naming the file when the read fails.
  virtual void read(int column, std::int64_t begin, std::int64_t n, double* out) = 0;
  // Where row `row` is in the file, for error messages ("line 1234", "sample 1234").
  virtual std::string locate(std::int64_t row) const { return "sample " + std::to_string(row); }
  // The file, format, dataset and element type, for messages and the scan's record.
  virtual std::string describe() const = 0;
};

// Opens and checks the file: its header, its element type and that its size holds every sample
// the header promises (a truncated file is an error here, before anything is read). Throws
// ImportError naming the file and what is wrong.
std::unique_ptr<RecordSource> open_record(const RecordSpec& spec);

// One factory per format (record_source.cpp picks).
std::unique_ptr<RecordSource> open_npy(const RecordSpec& spec);
std::unique_ptr<RecordSource> open_raw(const RecordSpec& spec);
std::unique_ptr<RecordSource> open_csv(const RecordSpec& spec);
std::unique_ptr<RecordSource> open_hdf5(const RecordSpec& spec);

}  // namespace tipforce::import
