#include "record_source.hpp"

#include <algorithm>
#include <cctype>
#include <filesystem>

#include "import_error.hpp"

namespace tipforce::import {

RecordFormat parse_record_format(const std::string& name) {
  if (name == "auto") return RecordFormat::automatic;
  if (name == "hdf5") return RecordFormat::hdf5;
  if (name == "npy") return RecordFormat::npy;
  if (name == "raw") return RecordFormat::raw;
  if (name == "csv") return RecordFormat::csv;
  throw ImportError("--format " + name + ": not a format (auto, hdf5, npy, raw, csv)");
}

RecordFormat format_from_name(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  if (ext == ".h5" || ext == ".hdf5" || ext == ".hdf" || ext == ".he5") return RecordFormat::hdf5;
  if (ext == ".npy") return RecordFormat::npy;
  if (ext == ".csv" || ext == ".txt") return RecordFormat::csv;
  if (ext == ".bin" || ext == ".raw" || ext == ".dat") return RecordFormat::raw;
  throw ImportError(path + ": cannot tell the format from the name \"" + ext +
                    "\"; give --format hdf5, npy, raw or csv");
}

std::unique_ptr<RecordSource> open_record(const RecordSpec& spec) {
  if (!std::filesystem::is_regular_file(spec.path))
    throw ImportError(spec.path + ": " + (std::filesystem::exists(spec.path) ? "not a regular file" : "no such file"));
  const RecordFormat f = spec.format == RecordFormat::automatic ? format_from_name(spec.path) : spec.format;
  switch (f) {
    case RecordFormat::hdf5: return open_hdf5(spec);
    case RecordFormat::npy: return open_npy(spec);
    case RecordFormat::raw: return open_raw(spec);
    case RecordFormat::csv: return open_csv(spec);
    case RecordFormat::automatic: break;
  }
  throw ImportError(spec.path + ": no format");
}

}  // namespace tipforce::import
