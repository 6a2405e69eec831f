// CSV (or tab- or semicolon-separated) text: one sample per line, one channel per column. Blank
// lines and lines starting with '#' are skipped; a first line with a cell that is not a number is
// the header, whose names --column may use. Text must be parsed in order, so the channels are read
// once into memory (8 bytes per value).
#include <charconv>
#include <fstream>
#include <string>
#include <vector>

#include "import_error.hpp"
#include "record_source.hpp"

namespace tipforce::import {
namespace {

std::vector<std::string> split(const std::string& line, char sep) {
  std::vector<std::string> cells;
  std::size_t pos = 0;
  while (true) {
    const std::size_t at = line.find(sep, pos);
    std::string c = line.substr(pos, at == std::string::npos ? std::string::npos : at - pos);
    const auto a = c.find_first_not_of(" \t\r");
    const auto b = c.find_last_not_of(" \t\r");
    cells.push_back(a == std::string::npos ? std::string() : c.substr(a, b - a + 1));
    if (at == std::string::npos) break;
    pos = at + 1;
  }
  return cells;
}

bool parse_number(const std::string& s, double& v) {
  if (s.empty()) return false;
  const char* b = s.data();
  if (*b == '+') ++b;  // from_chars takes no leading '+', which numpy.savetxt never writes but people do
  const auto [end, ec] = std::from_chars(b, s.data() + s.size(), v);
  return ec == std::errc() && end == s.data() + s.size();
}

class CsvTable : public RecordSource {
 public:
  explicit CsvTable(const std::string& path) : path_(path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw ImportError(path + ": cannot open");
    std::string line;
    std::int64_t line_no = 0;
    char sep = 0;
    std::size_t width = 0;
    std::int64_t blank_after_data = 0;  // the first blank line after a sample, 0: none yet
    while (std::getline(in, line)) {
      ++line_no;
      // A writer ends every line, the last one too; a last line without its newline is where a
      // copy or a capture stopped, and its last number may be cut short ("0.0123" of "0.012345").
      if (in.eof() && !line.empty())
        throw ImportError(path + ": line " + std::to_string(line_no) +
                          " has no newline at its end: the file looks truncated (if it is complete, end it with a "
                          "newline)");
      if (!line.empty() && line.back() == '\r') line.pop_back();
      const auto first = line.find_first_not_of(" \t");
      if (first == std::string::npos) {
        if (blank_after_data == 0 && !line_of_row_.empty()) blank_after_data = line_no;
        continue;
      }
      if (line[first] == '#') continue;
      // A blank line between samples is a missing sample (a one-column file has no other way to
      // show one): skipped, it shifted every later sample by one. Blank lines at the end are fine.
      if (blank_after_data != 0)
        throw ImportError(path + ": line " + std::to_string(blank_after_data) + " is blank between the samples of line " +
                          std::to_string(line_of_row_.back()) + " and line " + std::to_string(line_no) +
                          ": a missing sample would shift every later one (fill it, or remove the line if nothing is "
                          "missing)");
      if (sep == 0) sep = line.find(',') != std::string::npos ? ',' : line.find(';') != std::string::npos ? ';' : '\t';
      std::vector<std::string> cells = split(line, sep);
      if (width == 0) {
        width = cells.size();
        columns_.resize(width);
        bool all_numbers = true;
        double v = 0;
        for (const auto& c : cells) all_numbers = all_numbers && parse_number(c, v);
        if (!all_numbers) {
          header_ = cells;
          continue;
        }
      }
      if (cells.size() != width)
        throw ImportError(path + ": line " + std::to_string(line_no) + " has " + std::to_string(cells.size()) +
                          " cells, the first has " + std::to_string(width));
      for (std::size_t c = 0; c < width; ++c) {
        double v = 0;
        if (!parse_number(cells[c], v))
          throw ImportError(path + ": line " + std::to_string(line_no) + ", column " + std::to_string(c + 1) + ": '" +
                            cells[c] + "' is not a number");
        columns_[c].push_back(v);
      }
      line_of_row_.push_back(line_no);
    }
    if (in.bad()) throw ImportError(path + ": read error");
    if (line_of_row_.empty()) throw ImportError(path + ": no samples (only blank lines, comments or a header)");
  }

  std::int64_t rows() const override { return static_cast<std::int64_t>(line_of_row_.size()); }
  int columns() const override { return static_cast<int>(columns_.size()); }
  int column_named(const std::string& name) const override {
    for (std::size_t i = 0; i < header_.size(); ++i)
      if (header_[i] == name) return static_cast<int>(i);
    return -1;
  }
  void read(int column, std::int64_t begin, std::int64_t n, double* out) override {
    const auto& c = columns_.at(static_cast<std::size_t>(column));
    for (std::int64_t i = 0; i < n; ++i) out[i] = c.at(static_cast<std::size_t>(begin + i));
  }
  std::string locate(std::int64_t row) const override {
    return "line " + std::to_string(line_of_row_.at(static_cast<std::size_t>(row)));
  }
  std::string describe() const override {
    return path_ + " (csv, " + std::to_string(columns_.size()) + " column" + (columns_.size() > 1 ? "s" : "") + ")";
  }

 private:
  std::string path_;
  std::vector<std::string> header_;
  std::vector<std::vector<double>> columns_;
  std::vector<std::int64_t> line_of_row_;
};

}  // namespace

std::unique_ptr<RecordSource> open_csv(const RecordSpec& spec) { return std::make_unique<CsvTable>(spec.path); }

}  // namespace tipforce::import
