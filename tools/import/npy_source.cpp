// NumPy .npy files (format versions 1.0, 2.0 and 3.0, numpy/lib/format.py): the magic
// "\x93NUMPY", the version, the header's length, a Python dict literal with 'descr',
// 'fortran_order' and 'shape', then the array's bytes. A 1-D array is one channel; a 2-D array of
// shape (samples, channels) holds several.
#include <unistd.h>

#include <cstring>
#include <string>
#include <vector>

#include "binary_table.hpp"
#include "import_error.hpp"

namespace tipforce::import {
namespace {

// The value text after 'key': in the header dict, up to the next top-level ',' or '}'.
std::string dict_value(const std::string& header, const std::string& key, const std::string& path) {
  const std::string quoted[2] = {"'" + key + "'", "\"" + key + "\""};
  std::size_t at = std::string::npos;
  for (const auto& q : quoted)
    if ((at = header.find(q)) != std::string::npos) {
      at += q.size();
      break;
    }
  if (at == std::string::npos) throw ImportError(path + ": the .npy header has no '" + key + "' (" + header + ")");
  at = header.find(':', at);
  if (at == std::string::npos) throw ImportError(path + ": the .npy header is malformed at '" + key + "'");
  ++at;
  int depth = 0;
  std::size_t end = at;
  for (; end < header.size(); ++end) {
    const char c = header[end];
    if (c == '(' || c == '[') ++depth;
    else if (c == ')' || c == ']') --depth;
    else if ((c == ',' || c == '}') && depth == 0) break;
  }
  std::string v = header.substr(at, end - at);
  const auto first = v.find_first_not_of(" \t");
  const auto last = v.find_last_not_of(" \t");
  return first == std::string::npos ? std::string() : v.substr(first, last - first + 1);
}

}  // namespace

std::unique_ptr<RecordSource> open_npy(const RecordSpec& spec) {
  const std::string& path = spec.path;
  std::int64_t size = 0;
  const int fd = open_for_reading(path, size);
  auto fail = [&](const std::string& what) {
    ::close(fd);
    throw ImportError(path + ": " + what);
  };
  unsigned char pre[12] = {};
  if (size < 10 || ::pread(fd, pre, sizeof pre, 0) < 10 || std::memcmp(pre, "\x93NUMPY", 6) != 0)
    fail("not a NumPy .npy file (no \\x93NUMPY magic at the start)");
  const int major = pre[6];
  std::int64_t header_len = 0, header_at = 0;
  if (major == 1) {
    header_len = pre[8] | (pre[9] << 8);
    header_at = 10;
  } else if (major == 2 || major == 3) {
    header_len = static_cast<std::int64_t>(pre[8]) | (pre[9] << 8) | (pre[10] << 16) | (static_cast<std::int64_t>(pre[11]) << 24);
    header_at = 12;
  } else {
    fail(".npy format version " + std::to_string(major) + "." + std::to_string(pre[7]) + " is not known (1, 2, 3 are)");
  }
  if (header_at + header_len > size) fail("truncated: the .npy header runs past the end of the file");
  std::string header(static_cast<std::size_t>(header_len), '\0');
  if (::pread(fd, header.data(), header.size(), header_at) != static_cast<ssize_t>(header.size()))
    fail("cannot read the .npy header");

  const std::string descr = dict_value(header, "descr", path);
  const std::string fortran = dict_value(header, "fortran_order", path);
  const std::string shape = dict_value(header, "shape", path);
  // descr is a quoted string such as '<f8'; a list here is a structured (record) array.
  if (descr.size() < 3 || (descr.front() != '\'' && descr.front() != '"'))
    fail("dtype " + descr + " is a structured array; a plain numeric array (int16, int32, float32, float64) is needed");
  const std::string d = descr.substr(1, descr.size() - 2);
  BinaryLayout layout;
  const char order = d.empty() ? '?' : d[0];
  const std::string kind = d.size() > 1 ? d.substr(1) : "";
  if (kind == "i2") layout.type = ElementType::int16;
  else if (kind == "i4") layout.type = ElementType::int32;
  else if (kind == "f4") layout.type = ElementType::float32;
  else if (kind == "f8") layout.type = ElementType::float64;
  else fail("dtype '" + d + "' is not supported (int16 '<i2', int32 '<i4', float32 '<f4' and float64 '<f8' are)");
  if (order != '<' && order != '>' && order != '|' && order != '=')
    fail("dtype '" + d + "' has no byte order");
  layout.big_endian = order == '>';
  layout.column_major = fortran == "True";
  if (fortran != "True" && fortran != "False") fail("fortran_order is " + fortran + ", expected True or False");
  // shape: "(n,)" or "(n, c)".
  std::vector<std::int64_t> dims;
  {
    std::string s = shape;
    if (s.size() < 2 || s.front() != '(' || s.back() != ')') fail("shape " + shape + " is not a tuple");
    s = s.substr(1, s.size() - 2);
    std::size_t pos = 0;
    while (pos < s.size()) {
      const std::size_t comma = s.find(',', pos);
      std::string item = s.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
      item.erase(0, item.find_first_not_of(' '));
      item.erase(item.find_last_not_of(' ') + 1);
      if (!item.empty()) {
        try {
          std::size_t used = 0;
          dims.push_back(std::stoll(item, &used));
          if (used != item.size() || dims.back() < 0) throw std::invalid_argument(item);
        } catch (const std::exception&) {
          fail("shape " + shape + " has a dimension that is not a number");
        }
      }
      if (comma == std::string::npos) break;
      pos = comma + 1;
    }
  }
  if (dims.empty() || dims.size() > 2)
    fail("shape " + shape + ": a 1-D array (samples) or a 2-D array (samples, channels) is needed");
  layout.rows = dims[0];
  layout.columns = dims.size() == 2 ? static_cast<int>(dims[1]) : 1;
  if (dims.size() == 2 && (dims[1] < 1 || dims[1] > 4096)) fail("shape " + shape + ": 1 to 4096 channels expected");
  layout.data_offset = header_at + header_len;
  const std::int64_t need = layout.rows * layout.columns * element_bytes(layout.type);
  const std::int64_t have = size - layout.data_offset;
  if (have < need)
    fail("truncated: the header promises shape " + shape + " of " + element_name(layout.type) + " (" +
         std::to_string(need) + " bytes of data), the file holds " + std::to_string(have));
  if (have > need)
    fail(std::to_string(have - need) + " bytes follow the array of shape " + shape +
         " (numpy writes none: a damaged file, or the header is wrong)");
  const std::string what = path + " (npy, " + element_name(layout.type) + (layout.big_endian ? " big-endian" : "") +
                           ", shape " + shape + ")";
  return std::make_unique<BinaryTable>(fd, path, layout, what);
}

}  // namespace tipforce::import
