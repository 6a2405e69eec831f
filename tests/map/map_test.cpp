// Tests of `tipforce map` (tools/map). Each test writes a synthetic estimates log with
// lcm::LogFile, runs the map code and checks its output independently: PNGs decoded with
// libpng, .gsf files parsed byte by byte, the CSV read back as text.
#include <gtest/gtest.h>
#include <png.h>

#include <CLI/CLI.hpp>
#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <future>
#include <iostream>
#include <iterator>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <tipforce/force_estimate_t.hpp>
#include <tipforce/latency_stats_t.hpp>
#include <tipforce/scan_geometry_t.hpp>

#include "colormap.hpp"
#include "map_command.hpp"
#include "map_error.hpp"
#include "map_image.hpp"
#include "map_run.hpp"
#include "quantity.hpp"

namespace fs = std::filesystem;
using tipforce::force_estimate_t;
using tipforce::latency_stats_t;
using namespace tipforce::map;

namespace {
// ---- helpers -------------------------------------------------------------------------------
fs::path fresh_dir(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  fs::path d = fs::temp_directory_path() / ("tipforce_map_test_" + std::to_string(::getpid())) /
               (std::string(info->test_suite_name()) + "_" + info->name() + "_" + name);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

force_estimate_t estimate(int x, int y, int8_t status, double k, double h, double k_sigma = 0.1,
                          double h_sigma = 1e-9) {
  force_estimate_t e{};
  e.utime = 1700000000000000LL + (y * 100 + x) * 1000;
  e.probe = "afm1";
  e.seq = y * 100 + x;
  e.pixel_x = x;
  e.pixel_y = y;
  e.status = status;
  e.message = status == force_estimate_t::STATUS_OK ? "" : "window rejected: non-finite, samples";
  e.model = "spring";
  e.n_params = 2;
  e.param_names = {"k_n_per_m", "h_m"};
  e.params = {k, h};
  e.param_sigma = {k_sigma, h_sigma};
  e.misfit = 0.01 + 0.001 * x;
  e.peak_force_n = 5e-9 + 1e-9 * x;
  e.mean_force_n = 1e-10;
  e.max_indentation_m = 2e-9;
  e.dissipated_energy_j = 3e-18 + 1e-19 * y;
  e.iterations = 40;
  e.forward_solves = 1200;
  e.receive_utime = e.utime + 500;
  e.publish_utime = e.receive_utime + 1000 + 37 * x + 11 * y;
  return e;
}

template <typename T>
void put(lcm::LogFile& log, const std::string& channel, const T& msg, int64_t t) {
  std::vector<uint8_t> buf(static_cast<size_t>(msg.getEncodedSize()));
  ASSERT_GE(msg.encode(buf.data(), 0, static_cast<int>(buf.size())), 0);
  lcm::LogEvent ev{};
  ev.timestamp = t;
  ev.channel = channel;
  ev.datalen = static_cast<int32_t>(buf.size());
  ev.data = buf.data();
  ASSERT_EQ(log.writeEvent(&ev), 0);
}

void put_raw(lcm::LogFile& log, const std::string& channel, std::vector<uint8_t> bytes, int64_t t) {
  lcm::LogEvent ev{};
  ev.timestamp = t;
  ev.channel = channel;
  ev.datalen = static_cast<int32_t>(bytes.size());
  ev.data = bytes.data();
  ASSERT_EQ(log.writeEvent(&ev), 0);
}

void write_log(const fs::path& path, const std::vector<force_estimate_t>& est,
               const std::vector<latency_stats_t>& stats = {}) {
  lcm::LogFile log(path.string(), "w");
  ASSERT_TRUE(log.good());
  int64_t t = 1;
  for (const auto& e : est) put(log, "TIPFORCE_ESTIMATE", e, t++);
  for (const auto& s : stats) put(log, "TIPFORCE_STATS", s, t++);
}

struct Png {
  int w = 0, h = 0;
  std::vector<uint8_t> rgb;
  Rgb at(int x, int y) const {
    const size_t i = (static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x)) * 3;
    return {rgb[i], rgb[i + 1], rgb[i + 2]};
  }
};

Png read_png(const fs::path& path) {
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  Png out;
  if (!png_image_begin_read_from_file(&img, path.string().c_str())) {
    ADD_FAILURE() << "cannot read " << path << ": " << img.message;
    return out;
  }
  img.format = PNG_FORMAT_RGB;
  out.w = static_cast<int>(img.width);
  out.h = static_cast<int>(img.height);
  out.rgb.resize(PNG_IMAGE_SIZE(img));
  if (!png_image_finish_read(&img, nullptr, out.rgb.data(), 0, nullptr)) ADD_FAILURE() << img.message;
  return out;
}

// Colour at the centre-ish (local offset 1, 2: never a hatch pixel) of map pixel (x, y).
Rgb map_pixel(const Png& p, const MapImageInfo& info, int x, int y) {
  return p.at(info.map_x0 + x * info.scale + 1, info.map_y0 + y * info.scale + 2);
}

struct Gsf {
  std::map<std::string, std::string> header;
  size_t data_offset = 0;
  size_t nul_count = 0;
  std::vector<float> data;
  bool ok = false;
};

Gsf read_gsf(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  Gsf g;
  const std::string magic = "Gwyddion Simple Field 1.0\n";
  if (bytes.compare(0, magic.size(), magic) != 0) return g;
  const size_t nul = bytes.find('\0');
  if (nul == std::string::npos) return g;
  std::istringstream hs(bytes.substr(magic.size(), nul - magic.size()));
  std::string line;
  while (std::getline(hs, line)) {
    const auto eq = line.find('=');
    if (eq == std::string::npos) continue;
    auto trim = [](std::string s) {
      s.erase(0, s.find_first_not_of(' '));
      s.erase(s.find_last_not_of(' ') + 1);
      return s;
    };
    g.header[trim(line.substr(0, eq))] = trim(line.substr(eq + 1));
  }
  size_t off = nul;
  while (off < bytes.size() && bytes[off] == '\0' && off - nul < 4 && (off == nul || off % 4 != 0)) ++off;
  g.nul_count = off - nul;
  g.data_offset = off;
  const size_t n = (bytes.size() - off) / 4;
  g.data.resize(n);
  for (size_t i = 0; i < n; ++i) {
    uint32_t bits = 0;
    for (int b = 0; b < 4; ++b) bits |= static_cast<uint32_t>(static_cast<uint8_t>(bytes[off + i * 4 + static_cast<size_t>(b)])) << (8 * b);
    std::memcpy(&g.data[i], &bits, 4);
  }
  g.ok = (bytes.size() - off) % 4 == 0;
  return g;
}

std::vector<std::string> read_lines(const fs::path& path) {
  std::ifstream in(path);
  std::vector<std::string> out;
  std::string l;
  while (std::getline(in, l)) out.push_back(l);
  return out;
}

std::vector<std::string> split_csv(const std::string& line) {  // no quoted commas in these tests' data
  std::vector<std::string> out;
  std::string cell;
  bool quoted = false;
  for (char ch : line) {
    if (ch == '"') quoted = !quoted;
    else if (ch == ',' && !quoted) {
      out.push_back(cell);
      cell.clear();
    } else cell += ch;
  }
  out.push_back(cell);
  return out;
}

const MapImageInfo& image(const MapReport& r, const std::string& key) {
  for (const auto& i : r.images)
    if (i.key == key) return i;
  static MapImageInfo none;
  ADD_FAILURE() << "no image " << key;
  return none;
}

// The 4 x 3 grid used by several tests: pixel (2,1) missing, (0,2) rejected, (3,2) not converged.
// k = 1 + x + 4 y, so the minimum valid k is pixel (0,0) = 1 and the maximum (3,2) = 12.
std::vector<force_estimate_t> grid_4x3() {
  std::vector<force_estimate_t> est;
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 4; ++x) {
      if (x == 2 && y == 1) continue;
      int8_t status = force_estimate_t::STATUS_OK;
      if (x == 0 && y == 2) status = force_estimate_t::STATUS_REJECTED;
      if (x == 3 && y == 2) status = force_estimate_t::STATUS_NOT_CONVERGED;
      est.push_back(estimate(x, y, status, 1.0 + x + 4 * y, 40e-9 + 1e-9 * x - 2e-9 * y));
    }
  return est;
}

MapReport run(const fs::path& log, const fs::path& out, const std::string& truth = "", const std::string& probe = "") {
  MapOptions opt;
  opt.in = log.string();
  opt.out = out.string();
  opt.truth = truth;
  opt.probe = probe;
  std::ostringstream summary;
  MapReport r = run_map(opt, summary);
  std::cout << summary.str();
  return r;
}

double parse_label(const std::string& s) { return std::stod(s); }
}  // namespace

// Removes this run's temporary directories unless TIPFORCE_MAP_KEEP is set (to look at images).
class TempCleanup : public ::testing::Environment {
 public:
  void TearDown() override {
    if (std::getenv("TIPFORCE_MAP_KEEP")) return;
    std::error_code ec;
    fs::remove_all(fs::temp_directory_path() / ("tipforce_map_test_" + std::to_string(::getpid())), ec);
  }
};
const auto* const kCleanup = ::testing::AddGlobalTestEnvironment(new TempCleanup);

// ---- tests ---------------------------------------------------------------------------------
TEST(MapUnits, DisplayPrefixes) {
  EXPECT_EQ(display_unit("m", 45e-9).label, "nm");
  EXPECT_DOUBLE_EQ(display_unit("m", 45e-9).factor, 1e9);
  EXPECT_EQ(display_unit("N/m", 12.0).label, "N/m");
  EXPECT_EQ(display_unit("N/m", 0.5).label, "N/m");
  EXPECT_EQ(display_unit("N", 5e-9).label, "nN");
  EXPECT_EQ(display_unit("J", 3e-18).label, "aJ");
  EXPECT_EQ(display_unit("J", 3e-15).label, "fJ");
  EXPECT_EQ(display_unit("Pa", 2e9).label, "GPa");
  EXPECT_EQ(display_unit("Pa", 3e6).label, "MPa");
  EXPECT_EQ(display_unit("Pa", 4e3).label, "kPa");
  EXPECT_EQ(display_unit("N*s/m", 2e-6).label, "uN*s/m");
  EXPECT_EQ(display_unit("", 0.01).label, "");
  EXPECT_EQ(si_unit_of_param("k_n_per_m"), "N/m");
  EXPECT_EQ(si_unit_of_param("c_ns_per_m"), "N*s/m");
  EXPECT_EQ(si_unit_of_param("e_star_pa"), "Pa");
  EXPECT_EQ(si_unit_of_param("eta_pa_s"), "Pa*s");
  EXPECT_EQ(si_unit_of_param("h_m"), "m");
  EXPECT_EQ(si_unit_of_param("hamaker_j"), "J");
}

TEST(MapColour, ViridisEndsAndIndex) {
  EXPECT_EQ(viridis()[0], (Rgb{68, 1, 84}));
  EXPECT_EQ(viridis()[255], (Rgb{253, 231, 37}));
  EXPECT_EQ(colour_index(1.0, 1.0, 12.0), 0);
  EXPECT_EQ(colour_index(12.0, 1.0, 12.0), 255);
  EXPECT_EQ(colour_index(6.5, 1.0, 12.0), 128);
  for (const auto& c : viridis()) EXPECT_FALSE(c == kNoEstimate);
}

TEST(MapRun, Grid4x3MapsColoursAndRange) {
  const auto dir = fresh_dir("");
  const auto est = grid_4x3();
  write_log(dir / "est.lcmlog", est);
  const MapReport r = run(dir / "est.lcmlog", dir / "out");
  EXPECT_EQ(r.estimates, 11u);
  EXPECT_EQ(r.width, 4);
  EXPECT_EQ(r.height, 3);
  ASSERT_EQ(r.missing.size(), 1u);
  EXPECT_EQ(r.missing[0], std::make_pair(2, 1));
  ASSERT_EQ(r.rejected.size(), 1u);
  EXPECT_EQ(r.rejected[0], std::make_pair(0, 2));
  EXPECT_EQ(r.per_status.at(0), 9u);
  EXPECT_EQ(r.per_status.at(1), 1u);
  EXPECT_EQ(r.per_status.at(2), 1u);

  for (const char* f : {"k_n_per_m.png", "k_n_per_m_sigma.png", "h_m.png", "h_m_sigma.png", "peak_force_n.png",
                        "mean_force_n.png", "max_indentation_m.png", "misfit.png", "status.png", "k_n_per_m.gsf",
                        "h_m.gsf", "status.gsf", "estimates.csv", "latency_histogram.png", "latency_over_time.png",
                        "k_n_per_m.pdf", "h_m.pdf", "status.pdf", "latency_histogram.pdf", "latency_over_time.pdf"})
    EXPECT_TRUE(fs::exists(dir / "out" / f)) << f;
  // A spring contact dissipates nothing by construction: no map of the integrator's error.
  EXPECT_FALSE(fs::exists(dir / "out" / "dissipated_energy_j.png"));
  EXPECT_FALSE(r.dissipation_mapped);
  EXPECT_TRUE(std::any_of(r.notes.begin(), r.notes.end(),
                          [](const std::string& n) { return n.find("does not dissipate") != std::string::npos; }));

  const auto& k = image(r, "k_n_per_m");
  const Png png = read_png(dir / "out" / "k_n_per_m.png");
  EXPECT_EQ(png.w, k.width);
  EXPECT_EQ(png.h, k.height);
  EXPECT_GE(4 * k.scale, 384);  // a small map is magnified to be readable
  // Valid k: all pixels but (2,1) missing and (0,2) rejected: min 1 at (0,0), max 12 at (3,2).
  EXPECT_DOUBLE_EQ(k.range.lo, 1.0);
  EXPECT_DOUBLE_EQ(k.range.hi, 12.0);
  EXPECT_EQ(map_pixel(png, k, 0, 0), viridis()[0]);
  EXPECT_EQ(map_pixel(png, k, 3, 2), viridis()[255]);
  EXPECT_EQ(map_pixel(png, k, 1, 1), viridis()[static_cast<size_t>(colour_index(6.0, 1.0, 12.0))]);
  EXPECT_EQ(map_pixel(png, k, 2, 1), kNoEstimate);  // missing
  EXPECT_EQ(map_pixel(png, k, 0, 2), kNoEstimate);  // rejected
  // Colour bar: top row = viridis[255], bottom row = viridis[0]; labelled range = data range.
  EXPECT_EQ(png.at(k.bar_x0 + k.bar_w / 2, k.bar_y0), viridis()[255]);
  EXPECT_EQ(png.at(k.bar_x0 + k.bar_w / 2, k.bar_y0 + k.bar_h - 1), viridis()[0]);
  EXPECT_EQ(k.unit.label, "N/m");
  // Round ticks inside the range, each where the bar has its colour.
  EXPECT_EQ(k.tick_labels, (std::vector<std::string>{"2", "4", "6", "8", "10", "12"}));
  for (size_t i = 0; i < k.tick_values.size(); ++i) {
    EXPECT_NEAR(parse_label(k.tick_labels[i]), k.tick_values[i], 1e-12);
    // The bar's row holds the tick value's colour, to the one step that rounding to a row allows.
    const Rgb c = png.at(k.bar_x0 + k.bar_w / 2, k.tick_y[i]);
    const int expected = colour_index(k.tick_values[i], 1.0, 12.0);
    bool near = false;
    for (int d = -1; d <= 1; ++d)
      near = near || (expected + d >= 0 && expected + d <= 255 && viridis()[static_cast<size_t>(expected + d)] == c);
    EXPECT_TRUE(near) << k.tick_labels[i];
  }
  EXPECT_FALSE(k.physical_axes);  // the log has no scan size

  // h is shown as height -h (topography): the smallest h, (1,2) at 37 nm, is the highest point
  // and the brightest pixel; the largest, (3,0) at 43 nm, the darkest.
  const auto& h = image(r, "h_m");
  const Png hp = read_png(dir / "out" / "h_m.png");
  EXPECT_EQ(h.unit.label, "nm");
  EXPECT_EQ(h.display_factor, -1.0);
  EXPECT_NEAR(h.range.lo, -43e-9, 1e-18);
  EXPECT_NEAR(h.range.hi, -37e-9, 1e-18);
  EXPECT_EQ(map_pixel(hp, h, 1, 2), viridis()[255]);
  EXPECT_EQ(map_pixel(hp, h, 3, 0), viridis()[0]);
  EXPECT_NEAR(parse_label(h.tick_labels.front()), -43.0, 1e-6);
  EXPECT_NEAR(parse_label(h.tick_labels.back()), -37.0, 1e-6);

  // Status: discrete colours.
  const auto& st = image(r, "status");
  const Png sp = read_png(dir / "out" / "status.png");
  EXPECT_EQ(map_pixel(sp, st, 0, 0), kStatusOk);
  EXPECT_EQ(map_pixel(sp, st, 3, 2), kStatusNotConverged);
  EXPECT_EQ(map_pixel(sp, st, 0, 2), kStatusRejected);
  EXPECT_EQ(map_pixel(sp, st, 2, 1), kNoEstimate);
}

// Percentiles of the valid values by nearest rank (the rule tipforce::percentile documents),
// written here so that the test does not use the code it checks.
double test_percentile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  const auto rank = static_cast<size_t>(std::ceil(q * static_cast<double>(v.size())));
  return v[rank > 0 ? rank - 1 : 0];
}

// One wild pixel must not flatten a map: the colour range is the 1st-99th percentile, and the
// outlier is drawn in the end colour with a mark.
TEST(MapRun, RobustRangeClipsAnOutlierAndMarksIt) {
  const auto dir = fresh_dir("");
  std::vector<force_estimate_t> est;
  std::vector<double> k;
  for (int y = 0; y < 10; ++y)
    for (int x = 0; x < 10; ++x) {
      const double v = (x == 7 && y == 4) ? 1000.0 : 2.0 + 0.1 * x + 0.01 * y;
      k.push_back(v);
      est.push_back(estimate(x, y, force_estimate_t::STATUS_OK, v, 40e-9));
    }
  write_log(dir / "est.lcmlog", est);
  const MapReport r = run(dir / "est.lcmlog", dir / "out");
  const auto& m = image(r, "k_n_per_m");
  const double p1 = test_percentile(k, 0.01), p99 = test_percentile(k, 0.99);
  // The range reaches the extreme values within 10 % of the percentile span beyond p1 and p99:
  // here all but the outlier, whose 1000 is far above.
  double lo = INFINITY, hi = -INFINITY;
  for (double v : k) {
    if (v >= p1 - 0.1 * (p99 - p1)) lo = std::min(lo, v);
    if (v <= p99 + 0.1 * (p99 - p1)) hi = std::max(hi, v);
  }
  EXPECT_DOUBLE_EQ(lo, 2.0);
  EXPECT_DOUBLE_EQ(hi, 2.99);
  EXPECT_DOUBLE_EQ(m.range.lo, lo);
  EXPECT_DOUBLE_EQ(m.range.hi, hi);
  EXPECT_EQ(m.range.above, 1u);
  EXPECT_EQ(m.range.below, 0u);
  const Png png = read_png(dir / "out" / "k_n_per_m.png");
  // The bar spans the robust range: its ends are viridis' ends, its ticks round values inside.
  EXPECT_EQ(png.at(m.bar_x0 + m.bar_w / 2, m.bar_y0), viridis()[255]);
  EXPECT_EQ(png.at(m.bar_x0 + m.bar_w / 2, m.bar_y0 + m.bar_h - 1), viridis()[0]);
  for (double t : m.tick_values) {
    EXPECT_GE(t, m.range.lo);
    EXPECT_LE(t, m.range.hi);
  }
  // The outlier: top colour, with the black mark at its centre; its neighbours keep their colours.
  const int s = m.scale;
  ASSERT_GE(s, 4);
  EXPECT_EQ(png.at(m.map_x0 + 7 * s, m.map_y0 + 4 * s), viridis()[255]);
  EXPECT_EQ(png.at(m.map_x0 + 7 * s + s / 2, m.map_y0 + 4 * s + s / 2), kClippedAbove);
  EXPECT_EQ(map_pixel(png, m, 6, 4), colour_of(k[46], m.range.lo, m.range.hi));
  // Without the robust range the other 99 pixels would all be one colour; now they span it.
  EXPECT_EQ(map_pixel(png, m, 0, 0), viridis()[0]);
  EXPECT_EQ(map_pixel(png, m, 9, 9), viridis()[255]);
}

// tipforce import puts a scan_geometry_t in the log (tipforce invert passes it on): axes in
// metres, a scale bar, and the .gsf files' size.
TEST(MapRun, ScanGeometryInTheLogGivesPhysicalAxes) {
  const auto dir = fresh_dir("");
  {
    lcm::LogFile log((dir / "est.lcmlog").string(), "w");
    tipforce::scan_geometry_t g{};
    g.probe = "afm1";
    g.pixels_x = 4;
    g.pixels_y = 3;
    g.size_x_m = 2e-6;
    g.size_y_m = 1.5e-6;
    g.source = "test";
    put(log, "TIPFORCE_SCAN", g, 1);
    int64_t t = 2;
    for (const auto& e : grid_4x3()) put(log, "TIPFORCE_ESTIMATE", e, t++);
  }
  const MapReport r = run(dir / "est.lcmlog", dir / "out");
  EXPECT_EQ(r.scan.x_m, 2e-6);
  EXPECT_EQ(r.scan.y_m, 1.5e-6);
  const auto& k = image(r, "k_n_per_m");
  EXPECT_TRUE(k.physical_axes);
  EXPECT_DOUBLE_EQ(k.scale_bar_m, 500e-9);  // the longest 1-2-5 length within a quarter of 2 um
  const Gsf g = read_gsf(dir / "out" / "k_n_per_m.gsf");
  EXPECT_NEAR(std::stod(g.header.at("XReal")), 2e-6, 1e-21);
  EXPECT_NEAR(std::stod(g.header.at("YReal")), 1.5e-6, 1e-21);
  EXPECT_EQ(g.header.at("XYUnits"), "m");
  // --scan-size-m overrides the log.
  MapOptions opt;
  opt.in = (dir / "est.lcmlog").string();
  opt.out = (dir / "out2").string();
  opt.scan_size_x_m = 8e-6;
  std::ostringstream sink;
  const MapReport r2 = run_map(opt, sink);
  EXPECT_EQ(r2.scan.x_m, 8e-6);
  EXPECT_EQ(r2.scan.y_m, 6e-6);  // square pixels
}

// Two logs of different scans merged (a stale log caught by a wildcard): the map takes the last
// scan's geometry, as before, and the notes now say that the logs hold two scans and which; the
// scan's source is named as the merged logs, not as the first of them.
TEST(MapRun, LogsOfDifferentScansMergedAreSaidInTheNotes) {
  const auto dir = fresh_dir("");
  auto write_scan = [&](const std::string& name, int px, double size_m, const std::string& source) {
    lcm::LogFile log((dir / name).string(), "w");
    tipforce::scan_geometry_t g{};
    g.probe = "afm1";
    g.pixels_x = px;
    g.pixels_y = 3;
    g.size_x_m = size_m;
    g.size_y_m = size_m;
    g.source = source;
    put(log, "TIPFORCE_SCAN", g, 1);
    int64_t t = 2;
    for (const auto& e : grid_4x3()) put(log, "TIPFORCE_ESTIMATE", e, t++);
  };
  write_scan("a.lcmlog", 4, 2e-6, "scan a");
  write_scan("b.lcmlog", 4, 2e-6, "scan a");  // a shard of the same scan: no note
  write_scan("c.lcmlog", 8, 5e-6, "scan c");
  MapOptions opt;
  opt.in = (dir / "a.lcmlog").string();
  opt.more_in = {(dir / "b.lcmlog").string()};
  opt.out = (dir / "same").string();
  std::ostringstream sink;
  const MapReport same = run_map(opt, sink);
  for (const auto& n : same.notes) EXPECT_EQ(n.find("different scans"), std::string::npos) << n;
  opt.more_in = {(dir / "c.lcmlog").string()};
  opt.out = (dir / "mixed").string();
  const MapReport mixed = run_map(opt, sink);
  bool said = false;
  for (const auto& n : mixed.notes)
    said = said || n.find("the estimates come from 2 different scans of probe afm1 (4 x 3 pixels, 2e-06 x 2e-06 m from "
                          "'scan a'; 8 x 3 pixels, 5e-06 x 5e-06 m from 'scan c')") != std::string::npos;
  EXPECT_TRUE(said);
  EXPECT_NE(mixed.scan_source.find("the 2 logs ("), std::string::npos) << mixed.scan_source;
}

// A --scan-log whose geometry follows a damaged stretch: the geometry is still used, and the
// damage is said (the geometry sought could have been in what was skipped).
TEST(MapRun, DamagedScanLogIsSaidInTheNotes) {
  const auto dir = fresh_dir("");
  {
    lcm::LogFile log((dir / "est.lcmlog").string(), "w");
    int64_t t = 1;
    for (const auto& e : grid_4x3()) put(log, "TIPFORCE_ESTIMATE", e, t++);
  }
  const fs::path scan = dir / "scan.lcmlog";
  {
    lcm::LogFile log(scan.string(), "w");
    tipforce::scan_geometry_t g{};
    g.probe = "afm1";
    g.pixels_x = 4;
    g.pixels_y = 3;
    g.size_x_m = 2e-6;
    g.size_y_m = 1.5e-6;
    g.source = "test";
    put(log, "TIPFORCE_SCAN", g, 1);
    put(log, "TIPFORCE_SCAN", g, 2);
  }
  std::string bytes;
  {
    std::ifstream in(scan, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  bytes[24] = '\x7f';  // the first event's data length becomes 2 GB
  {
    std::ofstream out(scan, std::ios::binary | std::ios::trunc);
    out << bytes;
  }
  MapOptions opt;
  opt.in = (dir / "est.lcmlog").string();
  opt.out = (dir / "out").string();
  opt.scan_log = scan.string();
  std::ostringstream sink;
  const MapReport r = run_map(opt, sink);
  EXPECT_EQ(r.scan.x_m, 2e-6);
  EXPECT_EQ(r.damaged_stretches, 0u) << "the estimates log is intact";
  bool said = false;
  for (const auto& n : r.notes) said = said || n.find(scan.string() + " (--scan-log): 1 damaged stretch skipped") == 0;
  EXPECT_TRUE(said) << ::testing::PrintToString(r.notes);
}

TEST(MapRun, DissipativeModelGetsItsDissipationMap) {
  const auto dir = fresh_dir("");
  auto est = grid_4x3();
  for (auto& e : est) e.model = "kelvin_voigt";
  write_log(dir / "est.lcmlog", est);
  const MapReport r = run(dir / "est.lcmlog", dir / "out");
  EXPECT_TRUE(r.dissipation_mapped);
  EXPECT_EQ(image(r, "dissipated_energy_j").unit.label, "aJ");
  EXPECT_TRUE(fs::exists(dir / "out" / "dissipated_energy_j.png"));
}

// Every figure is also a PDF that a PDF reader opens (poppler's pdfinfo), of the PNG's size in points.
TEST(MapRun, PdfsOpen) {
  if (std::system("command -v pdfinfo > /dev/null 2>&1") != 0) GTEST_SKIP() << "pdfinfo not installed (poppler-utils)";
  const auto dir = fresh_dir("");
  write_log(dir / "est.lcmlog", grid_4x3());
  const MapReport r = run(dir / "est.lcmlog", dir / "out");
  const auto& k = image(r, "k_n_per_m");
  for (const char* f : {"k_n_per_m.pdf", "status.pdf", "latency_histogram.pdf", "latency_over_time.pdf"}) {
    const std::string cmd = "pdfinfo " + (dir / "out" / f).string() + " 2>&1";
    FILE* p = popen(cmd.c_str(), "r");
    std::string out;
    char buf[512];
    while (std::size_t n = fread(buf, 1, sizeof buf, p)) out.append(buf, n);
    EXPECT_EQ(pclose(p), 0) << f << ": " << out;
    std::map<std::string, std::string> info;  // "Key:   value" lines
    std::istringstream lines(out);
    for (std::string l; std::getline(lines, l);)
      if (const auto c = l.find(':'); c != std::string::npos) info[l.substr(0, c)] = l.substr(l.find_first_not_of(' ', c + 1));
    EXPECT_EQ(info["Pages"], "1") << out;
    if (std::string(f) == "k_n_per_m.pdf") {
      EXPECT_EQ(info["Page size"], std::to_string(k.width) + " x " + std::to_string(k.height) + " pts") << out;
    }
  }
}

TEST(MapRun, GsfHeaderAndData) {
  const auto dir = fresh_dir("");
  const auto est = grid_4x3();
  write_log(dir / "est.lcmlog", est);
  run(dir / "est.lcmlog", dir / "out");
  const Gsf g = read_gsf(dir / "out" / "k_n_per_m.gsf");
  ASSERT_TRUE(g.ok);
  EXPECT_EQ(g.data_offset % 4, 0u);
  EXPECT_GE(g.nul_count, 1u);
  EXPECT_LE(g.nul_count, 4u);
  EXPECT_EQ(g.header.at("XRes"), "4");
  EXPECT_EQ(g.header.at("YRes"), "3");
  // No scan size anywhere: one unit per pixel, and the file says so (no invented 100 nm).
  EXPECT_EQ(g.header.at("XReal"), "4");
  EXPECT_EQ(g.header.at("YReal"), "3");
  EXPECT_EQ(g.header.at("tipforce_scan_size"), "unknown (XReal, YReal count pixels)");
  EXPECT_EQ(g.header.at("ZUnits"), "N/m");
  EXPECT_NE(g.header.at("Title").find("k_n_per_m"), std::string::npos);
  ASSERT_EQ(g.data.size(), 12u);
  std::map<std::pair<int, int>, const force_estimate_t*> by_px;
  for (const auto& e : est) by_px[{e.pixel_x, e.pixel_y}] = &e;
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 4; ++x) {
      const float v = g.data[static_cast<size_t>(y * 4 + x)];
      const auto it = by_px.find({x, y});
      if (it == by_px.end() || it->second->status == force_estimate_t::STATUS_REJECTED)
        EXPECT_TRUE(std::isnan(v)) << x << "," << y;
      else
        EXPECT_EQ(v, static_cast<float>(it->second->params[0])) << x << "," << y;
    }
  const Gsf hg = read_gsf(dir / "out" / "h_m.gsf");
  EXPECT_EQ(hg.header.at("ZUnits"), "m");
  EXPECT_FLOAT_EQ(hg.data[0], -40e-9f);  // height = -h, as the images
  EXPECT_NE(hg.header.at("Title").find("height = -h_m"), std::string::npos);
  EXPECT_EQ(hg.header.at("tipforce_convention"), "values are -h_m: height, bright = high");
  const Gsf pg = read_gsf(dir / "out" / "peak_force_n.gsf");
  EXPECT_EQ(pg.header.at("ZUnits"), "N");
}

TEST(MapRun, GsfPixelSizeOption) {
  const auto dir = fresh_dir("");
  write_log(dir / "est.lcmlog", grid_4x3());
  MapOptions opt;
  opt.in = (dir / "est.lcmlog").string();
  opt.out = (dir / "out").string();
  opt.pixel_size_m = 2.5e-6;
  std::ostringstream sink;
  run_map(opt, sink);
  const Gsf g = read_gsf(dir / "out" / "misfit.gsf");
  EXPECT_NEAR(std::stod(g.header.at("XReal")), 1e-5, 1e-18);
  EXPECT_EQ(g.header.at("XYUnits"), "m");
  EXPECT_EQ(g.header.count("ZUnits"), 0u);  // dimensionless
}

TEST(MapRun, CsvHasOneRowPerEstimate) {
  const auto dir = fresh_dir("");
  const auto est = grid_4x3();
  write_log(dir / "est.lcmlog", est);
  run(dir / "est.lcmlog", dir / "out");
  const auto lines = read_lines(dir / "out" / "estimates.csv");
  ASSERT_EQ(lines.size(), est.size() + 1);
  const auto head = split_csv(lines[0]);
  const std::vector<std::string> expected{"utime", "probe", "seq", "pixel_x", "pixel_y", "status", "message", "model",
                                          "k_n_per_m", "k_n_per_m_sigma", "h_m", "h_m_sigma", "misfit",
                                          "peak_force_n", "mean_force_n", "max_indentation_m", "dissipated_energy_j",
                                          "iterations", "forward_solves", "receive_utime", "publish_utime",
                                          "latency_us"};
  EXPECT_EQ(head, expected);
  for (size_t i = 0; i < est.size(); ++i) {
    const auto row = split_csv(lines[i + 1]);
    ASSERT_EQ(row.size(), expected.size()) << lines[i + 1];
    EXPECT_EQ(std::stoi(row[3]), est[i].pixel_x);
    EXPECT_EQ(std::stoi(row[4]), est[i].pixel_y);
    EXPECT_DOUBLE_EQ(std::stod(row[8]), est[i].params[0]);  // exact round trip
    EXPECT_DOUBLE_EQ(std::stod(row[10]), est[i].params[1]);
    EXPECT_EQ(std::stoll(row[21]), est[i].publish_utime - est[i].receive_utime);
  }
  const auto rejected_row = split_csv(lines[8]);  // (0,2) is the 8th estimate
  EXPECT_EQ(rejected_row[3], "0");
  EXPECT_EQ(rejected_row[4], "2");
  EXPECT_EQ(rejected_row[5], "rejected");
  EXPECT_EQ(rejected_row[6], "window rejected: non-finite, samples");  // quoted comma survives
  EXPECT_EQ(split_csv(lines[1])[5], "ok");
}

TEST(MapRun, SinglePixelLog) {
  const auto dir = fresh_dir("");
  write_log(dir / "one.lcmlog", {estimate(0, 0, force_estimate_t::STATUS_OK, 3.0, 45e-9)});
  const MapReport r = run(dir / "one.lcmlog", dir / "out");
  EXPECT_EQ(r.width, 1);
  EXPECT_EQ(r.height, 1);
  EXPECT_TRUE(r.missing.empty());
  const auto& k = image(r, "k_n_per_m");
  EXPECT_TRUE(k.range.constant);
  EXPECT_LT(k.range.lo, 3.0);
  EXPECT_GT(k.range.hi, 3.0);
  EXPECT_GE(k.scale, 384);
  ASSERT_EQ(k.tick_labels.size(), 1u);  // one tick at the value
  EXPECT_EQ(k.tick_labels[0], "3");
  const Png png = read_png(dir / "out" / "k_n_per_m.png");
  EXPECT_EQ(png.w, k.width);
  EXPECT_EQ(map_pixel(png, k, 0, 0), viridis()[128]);  // mid-scale: no division by zero
  const Gsf g = read_gsf(dir / "out" / "k_n_per_m.gsf");
  ASSERT_EQ(g.data.size(), 1u);
  EXPECT_FLOAT_EQ(g.data[0], 3.0f);
  EXPECT_TRUE(fs::exists(dir / "out" / "status.png"));
  EXPECT_EQ(read_lines(dir / "out" / "estimates.csv").size(), 2u);
}

TEST(MapRun, AllRejectedLogStillGivesFiles) {
  const auto dir = fresh_dir("");
  std::vector<force_estimate_t> est;
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 3; ++x) est.push_back(estimate(x, y, force_estimate_t::STATUS_REJECTED, NAN, NAN));
  for (auto& e : est) e.model = "";  // as tipforced rejects a window of an unknown probe
  write_log(dir / "rej.lcmlog", est);
  MapOptions opt;
  opt.in = (dir / "rej.lcmlog").string();
  opt.out = (dir / "out").string();
  std::ostringstream summary;
  const MapReport r = run_map(opt, summary);
  // The header named an empty model ("model )").
  EXPECT_NE(summary.str().find("model none (every estimate rejected))"), std::string::npos) << summary.str();
  EXPECT_EQ(r.rejected.size(), 6u);
  const auto& k = image(r, "k_n_per_m");
  EXPECT_FALSE(k.range.any);
  const Png png = read_png(dir / "out" / "k_n_per_m.png");
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 3; ++x) EXPECT_EQ(map_pixel(png, k, x, y), kNoEstimate);
  const auto& st = image(r, "status");
  const Png sp = read_png(dir / "out" / "status.png");
  EXPECT_EQ(map_pixel(sp, st, 2, 1), kStatusRejected);
  const Gsf g = read_gsf(dir / "out" / "k_n_per_m.gsf");
  ASSERT_EQ(g.data.size(), 6u);
  for (float v : g.data) EXPECT_TRUE(std::isnan(v));
  EXPECT_EQ(read_lines(dir / "out" / "estimates.csv").size(), 7u);
}

TEST(MapRun, NonFiniteValuesCountAsMissing) {
  const auto dir = fresh_dir("");
  auto est = grid_4x3();
  est[1].params[0] = INFINITY;  // pixel (1,0)
  est[2].params[0] = NAN;       // pixel (2,0)
  write_log(dir / "est.lcmlog", est);
  const MapReport r = run(dir / "est.lcmlog", dir / "out");
  const auto& k = image(r, "k_n_per_m");
  const Png png = read_png(dir / "out" / "k_n_per_m.png");
  EXPECT_EQ(map_pixel(png, k, 1, 0), kNoEstimate);
  EXPECT_EQ(map_pixel(png, k, 2, 0), kNoEstimate);
  EXPECT_DOUBLE_EQ(k.range.hi, 12.0);
  EXPECT_DOUBLE_EQ(k.range.lo, 1.0);
}

TEST(MapRun, UndecodableMessagesAreCountedNotFatal) {
  const auto dir = fresh_dir("");
  {
    lcm::LogFile log((dir / "mixed.lcmlog").string(), "w");
    put(log, "TIPFORCE_ESTIMATE", estimate(0, 0, 0, 2.0, 40e-9), 1);
    put_raw(log, "TIPFORCE_ESTIMATE", {1, 2, 3, 4, 5, 6, 7, 8, 9, 10}, 2);
    put_raw(log, "TIPFORCE_STATS", {0xde, 0xad}, 3);
    put_raw(log, "TIPFORCE_WINDOW", {1, 2, 3}, 4);
    put(log, "TIPFORCE_ESTIMATE", estimate(1, 0, 0, 3.0, 41e-9), 5);
  }
  const MapReport r = run(dir / "mixed.lcmlog", dir / "out");
  EXPECT_EQ(r.estimates, 2u);
  EXPECT_EQ(r.undecodable_estimates, 1u);
  EXPECT_EQ(r.undecodable_stats, 1u);
  EXPECT_EQ(r.width, 2);
}

TEST(MapRun, DamagedEventIsSkippedAndTheRestOfTheLogRead) {
  // LCM's own reader took a damaged event header for the end of the log: the map lost the rest.
  const auto dir = fresh_dir("");
  const fs::path path = dir / "damaged.lcmlog";
  {
    lcm::LogFile log(path.string(), "w");
    for (int i = 0; i < 4; ++i) put(log, "TIPFORCE_ESTIMATE", estimate(i, i, 0, 2.0 + i, 40e-9), i + 1);
  }
  std::string bytes;
  {
    std::ifstream in(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  // Every event is the same size here: the second one's data length becomes 2 GB.
  const std::size_t event = bytes.size() / 4;
  bytes[event + 24] = '\x7f';
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out << bytes;
  }
  const MapReport r = run(path, dir / "out");
  EXPECT_EQ(r.estimates, 3u);
  EXPECT_EQ(r.damaged_stretches, 1u);
  EXPECT_EQ(r.width, 4);
}

TEST(MapRun, EmptyMissingAndGarbageLogsAreClearErrors) {
  const auto dir = fresh_dir("");
  MapOptions opt;
  opt.out = (dir / "out").string();
  std::ostringstream sink;
  auto expect_error_naming = [&](const fs::path& p) {
    opt.in = p.string();
    try {
      run_map(opt, sink);
      ADD_FAILURE() << "no error for " << p;
    } catch (const MapInputError& e) {  // the user's to fix: exit 2
      EXPECT_NE(std::string(e.what()).find(p.string()), std::string::npos) << e.what();
    }
  };
  expect_error_naming(dir / "does_not_exist.lcmlog");
  { std::ofstream(dir / "empty.lcmlog"); }
  expect_error_naming(dir / "empty.lcmlog");
  { std::ofstream(dir / "garbage.lcmlog") << "this is not an LCM log at all\n"; }
  expect_error_naming(dir / "garbage.lcmlog");
  {  // a log without estimates
    lcm::LogFile log((dir / "other.lcmlog").string(), "w");
    put_raw(log, "TIPFORCE_WINDOW", {1, 2, 3}, 1);
  }
  expect_error_naming(dir / "other.lcmlog");
}

TEST(MapCli, ErrorExitsNonZeroAndSuccessZero) {
  const auto dir = fresh_dir("");
  write_log(dir / "est.lcmlog", grid_4x3());
  {
    CLI::App app{"tipforce"};
    tipforce::cli::add_map_command(app);
    const std::string missing = (dir / "nope.lcmlog").string();
    const std::string out = (dir / "out").string();
    int code = 0;
    try {
      app.parse(std::vector<std::string>{out, "--out", missing, "--in", "map"});  // reversed argv
    } catch (const CLI::ParseError& e) {
      code = e.get_exit_code();
    }
    EXPECT_NE(code, 0);
  }
  {
    CLI::App app{"tipforce"};
    tipforce::cli::add_map_command(app);
    const std::string in = (dir / "est.lcmlog").string();
    const std::string out = (dir / "out").string();
    EXPECT_NO_THROW(app.parse(std::vector<std::string>{out, "--out", in, "--in", "map"}));
    EXPECT_TRUE(fs::exists(dir / "out" / "k_n_per_m.png"));
  }
  {
    CLI::App app{"tipforce"};
    tipforce::cli::add_map_command(app);
    std::string help = app.get_subcommand("map")->help();
    EXPECT_NE(help.find("--pixel-size-m"), std::string::npos);
    EXPECT_NE(help.find("--scan-size-m"), std::string::npos);
    EXPECT_NE(help.find("--scan-log"), std::string::npos);
  }
}

namespace {
// `tipforce map ARGS` through the command's CLI11 code, as main() runs it: the exit code (0, or
// the RuntimeError's), with what went to stdout and stderr.
struct MapOutcome {
  int code = 0;
  std::string out, err;
};
MapOutcome run_map_command(std::vector<std::string> args) {
  CLI::App app{"tipforce"};
  tipforce::cli::add_map_command(app);
  args.insert(args.begin(), "map");
  std::reverse(args.begin(), args.end());  // CLI11 takes argv reversed
  std::ostringstream out, err;
  auto* old_out = std::cout.rdbuf(out.rdbuf());
  auto* old_err = std::cerr.rdbuf(err.rdbuf());
  MapOutcome r;
  try {
    app.parse(args);
  } catch (const CLI::ParseError& e) {
    r.code = e.get_exit_code();
  }
  std::cout.rdbuf(old_out);
  std::cerr.rdbuf(old_err);
  r.out = out.str();
  r.err = err.str();
  return r;
}
}  // namespace

// A log cut short (here after 8 of the scan's 12 estimates) was mapped as a smaller scan: "missing
// pixels: none", exit 0. The scan_geometry_t in the log says the scan has 4 x 3 pixels: the
// map keeps that size, the lost row counts as missing, and the damage is said on stderr with exit
// 3, as tipforce invert and tipforced say it.
TEST(MapCli, DamagedLogExitsThreeAndCountsTheScansLostPixels) {
  const auto dir = fresh_dir("");
  const fs::path path = dir / "cut.lcmlog";
  {
    lcm::LogFile log(path.string(), "w");
    tipforce::scan_geometry_t g{};
    g.probe = "afm1";
    g.pixels_x = 4;
    g.pixels_y = 3;
    g.size_x_m = 2e-6;
    g.size_y_m = 1.5e-6;
    g.source = "test";
    put(log, "TIPFORCE_SCAN", g, 1);
    int64_t t = 2;
    for (int y = 0; y < 3; ++y)
      for (int x = 0; x < 4; ++x) put(log, "TIPFORCE_ESTIMATE", estimate(x, y, 0, 2.0 + x, 40e-9), t++);
  }
  const auto size = fs::file_size(path);
  // Every estimate event is the same size: keep the first two rows and 30 bytes of the third.
  std::string bytes;
  {
    std::ifstream in(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  force_estimate_t probe = estimate(0, 0, 0, 2.0, 40e-9);
  const std::size_t event = 4 + 8 + 8 + 4 + 4 + std::string("TIPFORCE_ESTIMATE").size() +
                            static_cast<std::size_t>(probe.getEncodedSize());
  const std::size_t cut = size - 4 * event + 30;
  { std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes.substr(0, cut); }

  const MapOutcome m = run_map_command({"--in", path.string(), "--out", (dir / "out").string()});
  EXPECT_EQ(m.code, 3) << m.out << m.err;
  EXPECT_NE(m.err.find(path.string() + ": skipped 30 damaged bytes at offset " + std::to_string(cut - 30)),
            std::string::npos)
      << m.err;
  EXPECT_NE(m.out.find("missing pixels (no estimate, grey): 4: (0,2) (1,2) (2,2) (3,2)"), std::string::npos) << m.out;
  EXPECT_TRUE(fs::exists(dir / "out" / "k_n_per_m.png"));  // what could be read is mapped

  std::ostringstream sink;
  MapOptions opt;
  opt.in = path.string();
  opt.out = (dir / "out2").string();
  const MapReport r = run_map(opt, sink);
  EXPECT_EQ(r.width, 4);
  EXPECT_EQ(r.height, 3);
  EXPECT_EQ(r.missing, (std::vector<std::pair<int, int>>{{0, 2}, {1, 2}, {2, 2}, {3, 2}}));
  EXPECT_EQ(r.damaged_stretches, 1u);
  EXPECT_EQ(r.scan.y_m, 1.5e-6);  // the whole scan's height, not two thirds of it
  const Gsf gsf = read_gsf(dir / "out2" / "k_n_per_m.gsf");
  EXPECT_EQ(gsf.header.at("YRes"), "3");
  ASSERT_EQ(gsf.data.size(), 12u);
  for (int x = 0; x < 4; ++x) EXPECT_TRUE(std::isnan(gsf.data[static_cast<std::size_t>(8 + x)])) << x;

  // The same log intact: exit 0, nothing missing.
  { std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes; }
  const MapOutcome whole = run_map_command({"--in", path.string(), "--out", (dir / "out3").string()});
  EXPECT_EQ(whole.code, 0) << whole.out << whole.err;
  EXPECT_NE(whole.out.find("missing pixels: none"), std::string::npos) << whole.out;
}

// A truth row that cannot be read was skipped (or its cell taken as NaN, or a second row for a
// pixel taken over the first) with exit 0 and figures over fewer pixels. Each is refused, naming
// the file, the line and what is wrong, with exit 2, before anything is written.
TEST(MapCli, BadTruthRowIsRefusedNamingFileLineAndProblem) {
  const auto dir = fresh_dir("");
  write_log(dir / "est.lcmlog", grid_4x3());
  const std::string header = "seq,pixel_x,pixel_y,k_n_per_m,h_m\n";
  std::string good = header;
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 4; ++x)
      good += std::to_string(y * 100 + x) + "," + std::to_string(x) + "," + std::to_string(y) + ",2.5,4e-08\n";
  {
    std::ofstream(dir / "good.csv") << good;
    const MapOutcome ok = run_map_command({"--in", (dir / "est.lcmlog").string(), "--out", (dir / "ok").string(),
                                           "--truth", (dir / "good.csv").string()});
    EXPECT_EQ(ok.code, 0) << ok.out << ok.err;
  }
  const fs::path truth = dir / "truth.csv";
  const std::map<std::string, std::string> broken = {
      // line 3 is pixel (1,0)
      {"line 3: k_n_per_m \"abc\" is not a finite number", header + "0,0,0,2.5,4e-08\n1,1,0,abc,4e-08\n"},
      {"line 3: h_m \"nan\" is not a finite number", header + "0,0,0,2.5,4e-08\n1,1,0,2.5,nan\n"},
      {"line 3: 4 cells, the header has 5", header + "0,0,0,2.5,4e-08\n1,1,0,2.5\n"},
      {"line 3: pixel_x \"x1\" is not a pixel index", header + "0,0,0,2.5,4e-08\n1,x1,0,2.5,4e-08\n"},
      {"line 4: pixel (0, 0) again; line 2 already gave its truth",
       header + "0,0,0,2.5,4e-08\n1,1,0,2.5,4e-08\n2,0,0,2.6,4e-08\n"},
  };
  for (const auto& [expect, text] : broken) {
    { std::ofstream(truth) << text; }
    const fs::path out = dir / "refused";
    const MapOutcome m = run_map_command(
        {"--in", (dir / "est.lcmlog").string(), "--out", out.string(), "--truth", truth.string()});
    EXPECT_EQ(m.code, 2) << expect << "\n" << m.out << m.err;
    EXPECT_NE(m.err.find("truth file " + truth.string() + ": " + expect), std::string::npos) << m.err;
    EXPECT_FALSE(fs::exists(out)) << expect;  // refused before anything was written
  }
}

// A log the user gave by mistake (missing, empty, not an LCM log, a directory, one without
// estimates, or without the probe asked for) exited 1, as if the machine had failed. It is bad
// input: exit 2, naming the file and what is wrong, before anything is written.
TEST(MapCli, BadInputLogExitsTwoNamingFileAndProblem) {
  const auto dir = fresh_dir("");
  const std::string est = (dir / "est.lcmlog").string();
  write_log(est, grid_4x3());
  const std::string two = (dir / "two.lcmlog").string();
  {
    auto both = grid_4x3();
    both.back().probe = "afm2";
    write_log(two, both);
  }
  const std::string nope = (dir / "nope.lcmlog").string();
  const std::string empty = (dir / "empty.lcmlog").string();
  { std::ofstream(dir / "empty.lcmlog"); }
  const std::string notes = (dir / "notes.txt").string();
  { std::ofstream(dir / "notes.txt") << "this is not an LCM log at all\n"; }
  const std::string folder = (dir / "a_folder").string();
  fs::create_directories(folder);
  const std::string windows = (dir / "windows.lcmlog").string();  // what tipforce invert reads, not writes
  {
    lcm::LogFile log(windows, "w");
    put_raw(log, "TIPFORCE_WINDOW", {1, 2, 3}, 1);
  }
  const std::string negative = (dir / "negative.lcmlog").string();
  write_log(negative, {estimate(-1, -1, 0, 2.0, 40e-9)});
  const std::string far = (dir / "far.lcmlog").string();
  write_log(far, {estimate(0, 0, 0, 2.0, 40e-9), estimate(99999, 99999, 0, 2.0, 40e-9)});
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"--in", nope}, "cannot read " + nope + ": no such file"},
      {{"--in", negative}, negative + ": no estimate has a valid pixel (pixel_x, pixel_y >= 0)"},
      {{"--in", far}, far + ": the map would be 100000 x 100000 pixels"},
      {{"--in", empty}, empty + " is empty (0 bytes)"},
      {{"--in", notes}, notes + " is not an LCM log: its 30 bytes hold no LCM event"},
      {{"--in", folder}, "cannot read " + folder + ": it is a directory"},
      {{"--in", windows}, windows + " holds no decodable force_estimate_t on channel TIPFORCE_ESTIMATE (1 events"},
      {{"--in", est, "--probe", "nobody"}, est + " has no estimates of probe \"nobody\""},
      {{"--in", two}, two + " holds estimates of 2 probes"},
      {{"--in", est, "--scan-log", nope}, "cannot read " + nope + ": no such file"},
      {{"--in", est, notes}, notes + " is not an LCM log"},  // one of several logs
      {{"--in", empty, empty}, "all 2 input logs are empty (" + empty},
      {{"--in", est, "--pixel-size-m", "-1e-9"}, "--pixel-size-m must be a positive number of metres, got -1e-09"},
      {{"--in", est, "--scan-size-m", "2e-6,nan"}, "--scan-size-m must be positive numbers of metres, got 2e-06,nan"},
  };
  const fs::path out = dir / "out";
  for (auto [args, expect] : cases) {
    args.insert(args.end(), {"--out", out.string()});
    const MapOutcome m = run_map_command(args);
    EXPECT_EQ(m.code, 2) << expect << "\n" << m.out << m.err;
    EXPECT_NE(m.err.find("tipforce map: error: " + expect), std::string::npos) << m.err;
    EXPECT_FALSE(fs::exists(out)) << expect;  // refused before anything was written
  }
  // The same command line with a good log maps it: the refusals above are the inputs'.
  const MapOutcome ok = run_map_command({"--in", est, "--out", out.string()});
  EXPECT_EQ(ok.code, 0) << ok.out << ok.err;
}

// An output directory that cannot be made is the machine's failure, not the input's: exit 1.
TEST(MapCli, OutputDirectoryThatCannotBeMadeExitsOne) {
  const auto dir = fresh_dir("");
  const std::string est = (dir / "est.lcmlog").string();
  write_log(est, grid_4x3());
  const std::string file = (dir / "a_file").string();
  { std::ofstream(file) << "x\n"; }
  for (const std::string& out : {file, file + "/maps"}) {
    const MapOutcome m = run_map_command({"--in", est, "--out", out});
    EXPECT_EQ(m.code, 1) << out << "\n" << m.out << m.err;
    EXPECT_NE(m.err.find("tipforce map: error: "), std::string::npos) << m.err;
    EXPECT_NE(m.err.find(out), std::string::npos) << m.err;
  }
}

// A log cut short inside its first event, or whose estimates all lie in damaged stretches, said
// "holds no LCM events (empty, truncated or not an LCM log)" or "no force_estimate_t" and exited
// 1. It is damaged input, as tipforce invert says of such a log: the damage on stderr and exit 3.
// As one shard among several it is damage within the whole: the others are mapped, exit 3.
TEST(MapCli, LogDamagedBeforeItsFirstEstimateExitsThree) {
  const auto dir = fresh_dir("");
  const fs::path whole = dir / "whole.lcmlog";
  write_log(whole, grid_4x3());
  std::string bytes;
  {
    std::ifstream in(whole, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  const std::string cut = (dir / "cut.lcmlog").string();
  { std::ofstream(cut, std::ios::binary) << bytes.substr(0, 30); }
  const fs::path out = dir / "out";
  {
    const MapOutcome m = run_map_command({"--in", cut, "--out", out.string()});
    EXPECT_EQ(m.code, 3) << m.out << m.err;
    EXPECT_NE(m.err.find("tipforce map: " + cut + ": skipped 30 damaged bytes at offset 0"), std::string::npos) << m.err;
    EXPECT_NE(m.err.find("tipforce map: error: " + cut + " is an LCM log damaged from its first event on"),
              std::string::npos)
        << m.err;
    EXPECT_FALSE(fs::exists(out));
  }
  // An intact scan_geometry_t, then the estimate cut short: an LCM log whose estimates were lost.
  const std::string geometry_then_cut = (dir / "geometry_then_cut.lcmlog").string();
  {
    lcm::LogFile log(geometry_then_cut, "w");
    tipforce::scan_geometry_t g{};
    g.probe = "afm1";
    g.pixels_x = 4;
    g.pixels_y = 3;
    g.source = "test";
    put(log, "TIPFORCE_SCAN", g, 1);
    put(log, "TIPFORCE_ESTIMATE", estimate(0, 0, 0, 2.0, 40e-9), 2);
  }
  fs::resize_file(geometry_then_cut, fs::file_size(geometry_then_cut) - 20);
  {
    const MapOutcome m = run_map_command({"--in", geometry_then_cut, "--out", out.string()});
    EXPECT_EQ(m.code, 3) << m.out << m.err;
    EXPECT_NE(m.err.find("tipforce map: " + geometry_then_cut + ": skipped "), std::string::npos) << m.err;
    EXPECT_NE(m.err.find("tipforce map: error: " + geometry_then_cut +
                         " holds no decodable force_estimate_t on channel TIPFORCE_ESTIMATE (1 events"),
              std::string::npos)
        << m.err;
    EXPECT_NE(m.err.find("1 damaged stretch was skipped"), std::string::npos) << m.err;
    EXPECT_FALSE(fs::exists(out));
  }
  {
    const MapOutcome m = run_map_command({"--in", whole.string(), cut, "--out", out.string()});
    EXPECT_EQ(m.code, 3) << m.out << m.err;
    EXPECT_NE(m.err.find("tipforce map: " + cut + ": skipped 30 damaged bytes at offset 0"), std::string::npos) << m.err;
    EXPECT_NE(m.out.find("estimates: 11 "), std::string::npos) << m.out;
    EXPECT_TRUE(fs::exists(out / "k_n_per_m.png"));
  }
}

// `tipforce map --in FIFO` waited for a writer that never came (opening a FIFO blocks). It is
// refused as not a log file, exit 2. Should it hang again, the test opens the FIFO for writing
// after 10 s so that it fails instead of hanging.
TEST(MapCli, FifoGivenAsTheLogIsRefusedNotWaitedOn) {
  const auto dir = fresh_dir("");
  const std::string fifo = (dir / "fifo.lcmlog").string();
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  auto run = std::async(std::launch::async,
                        [&] { return run_map_command({"--in", fifo, "--out", (dir / "out").string()}); });
  if (run.wait_for(std::chrono::seconds(10)) == std::future_status::timeout) {
    ADD_FAILURE() << "tipforce map --in FIFO is still waiting after 10 s";
    const int fd = ::open(fifo.c_str(), O_WRONLY);
    if (fd >= 0) ::close(fd);
  }
  const MapOutcome m = run.get();
  EXPECT_EQ(m.code, 2) << m.out << m.err;
  EXPECT_NE(m.err.find("tipforce map: error: cannot read " + fifo + ": not a regular file"), std::string::npos) << m.err;
}

TEST(MapRun, SeveralProbesNeedProbeOption) {
  const auto dir = fresh_dir("");
  auto est = grid_4x3();
  auto other = estimate(7, 7, 0, 5.0, 40e-9);
  other.probe = "afm2";
  est.push_back(other);
  write_log(dir / "two.lcmlog", est);
  EXPECT_THROW(run(dir / "two.lcmlog", dir / "out"), MapInputError);
  const MapReport r = run(dir / "two.lcmlog", dir / "out", "", "afm1");
  EXPECT_EQ(r.width, 4);
  EXPECT_EQ(r.estimates, 11u);
  const MapReport r2 = run(dir / "two.lcmlog", dir / "out2", "", "afm2");
  EXPECT_EQ(r2.width, 8);
  EXPECT_EQ(r2.missing.size(), 63u);
  EXPECT_THROW(run(dir / "two.lcmlog", dir / "out3", "", "nobody"), MapInputError);
}

TEST(MapRun, NoLatencyTimesSkipsPlots) {
  const auto dir = fresh_dir("");
  auto est = grid_4x3();
  for (auto& e : est) e.receive_utime = e.publish_utime = 0;
  write_log(dir / "est.lcmlog", est);
  const MapReport r = run(dir / "est.lcmlog", dir / "out");
  EXPECT_FALSE(r.latency.has_value());
  EXPECT_FALSE(fs::exists(dir / "out" / "latency_histogram.png"));
  EXPECT_TRUE(std::any_of(r.notes.begin(), r.notes.end(), [](const std::string& n) { return n.find("latency") != std::string::npos; }));
}

TEST(MapRun, LatencyWithStats) {
  const auto dir = fresh_dir("");
  const auto est = grid_4x3();
  std::vector<latency_stats_t> stats;
  for (int i = 0; i < 3; ++i) {
    latency_stats_t s{};
    s.utime = est.front().receive_utime + i * 1000000LL;
    s.backend = "cpu: 2 threads";
    s.period_s = 1.0;
    s.windows_done = 4;
    s.latency_p50_us = 1100 + i;
    s.latency_p99_us = 1200 + i;
    stats.push_back(s);
  }
  write_log(dir / "est.lcmlog", est, stats);
  const MapReport r = run(dir / "est.lcmlog", dir / "out");
  ASSERT_TRUE(r.latency.has_value());
  EXPECT_EQ(r.latency->n, 11u);
  EXPECT_EQ(r.stats_messages, 3u);
  EXPECT_DOUBLE_EQ(r.latency->min_us, 1000.0);
  EXPECT_DOUBLE_EQ(r.latency->max_us, 1000.0 + 37 * 3 + 11 * 2);
  const Png p = read_png(dir / "out" / "latency_over_time.png");
  EXPECT_GT(p.w, 400);
}

TEST(MapRun, TruthComparisonAccuracy) {
  const auto dir = fresh_dir("");
  auto est = grid_4x3();
  // Truth k = estimate / 1.1 exactly: relative error 0.1 everywhere. Sigma: every second valid
  // pixel has 2 sigma >= the error.
  std::ofstream t(dir / "truth.csv");
  t << "seq,pixel_x,pixel_y,k_n_per_m,h_m,radius_m\n";
  size_t valid = 0, within = 0;
  std::vector<double> k_sigmas, k_rel_sigmas;
  for (auto& e : est) {
    const double truth_k = e.params[0] / 1.1;
    const bool ok = e.status != force_estimate_t::STATUS_REJECTED;
    if (ok) {
      const bool in = (valid++ % 2) == 0;
      e.param_sigma[0] = (e.params[0] - truth_k) * (in ? 0.6 : 0.4);
      within += in ? 1 : 0;
      k_sigmas.push_back(e.param_sigma[0]);
      k_rel_sigmas.push_back(e.param_sigma[0] / std::abs(e.params[0]));
    }
    t << e.seq << "," << e.pixel_x << "," << e.pixel_y << "," << exact_number(truth_k) << "," << exact_number(e.params[1])
      << ",1e-8\n";
  }
  t << "99,2,1,5.0,4e-8,1e-8\n";  // truth for the missing pixel: no estimate to compare
  t.close();
  write_log(dir / "est.lcmlog", est);
  const MapReport r = run(dir / "est.lcmlog", dir / "out", (dir / "truth.csv").string());
  ASSERT_EQ(r.accuracy.size(), 2u);  // k and h; radius_m is not estimated
  const auto& k = r.accuracy[0];
  EXPECT_EQ(k.name, "k_n_per_m");
  EXPECT_EQ(k.compared, valid);
  EXPECT_NEAR(k.median_rel_err, 0.1, 1e-12);
  EXPECT_NEAR(k.p90_rel_err, 0.1, 1e-12);
  EXPECT_NEAR(k.frac_within_2sigma, static_cast<double>(within) / static_cast<double>(valid), 1e-12);
  // The error bars' size beside their coverage: medians by nearest rank (tipforce::percentile's
  // rule, as every tool reports), the lower of the two middle values.
  auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[(v.size() - 1) / 2];
  };
  EXPECT_NEAR(k.median_rel_sigma, median(k_rel_sigmas), 1e-12);
  EXPECT_NEAR(k.max_over_median_sigma, *std::max_element(k_sigmas.begin(), k_sigmas.end()) / median(k_sigmas), 1e-12);
  // Over the OK pixels only: the not-converged pixel (3, 2) is left out too.
  EXPECT_EQ(k.ok.compared, valid - 1);
  EXPECT_NEAR(k.ok.median_rel_err, 0.1, 1e-12);
  const auto& h = r.accuracy[1];
  EXPECT_EQ(h.name, "h_m");
  EXPECT_NEAR(h.median_rel_err, 0.0, 1e-15);
  EXPECT_DOUBLE_EQ(h.frac_within_2sigma, 1.0);
  ASSERT_TRUE(fs::exists(dir / "out" / "truth_k_n_per_m.png"));
  const Png p = read_png(dir / "out" / "truth_k_n_per_m.png");
  EXPECT_EQ(p.w, k.image.width);
  // Truth and estimate share one scale: the largest estimate (12 at (3,2)) is its top colour.
  const int s = k.image.scale;
  EXPECT_EQ(p.at(k.image.panel_x0[1] + 3 * s + 1, k.image.panel_y0 + 2 * s + 2), viridis()[255]);
  EXPECT_DOUBLE_EQ(k.image.shared.hi, 12.0);
  EXPECT_DOUBLE_EQ(k.image.shared.lo, 1.0 / 1.1);
  // Missing estimate at (2,1): grey in the estimate and difference panels.
  EXPECT_EQ(p.at(k.image.panel_x0[1] + 2 * s + 1, k.image.panel_y0 + 1 * s + 2), kNoEstimate);
  EXPECT_EQ(p.at(k.image.panel_x0[2] + 2 * s + 1, k.image.panel_y0 + 1 * s + 2), kNoEstimate);
}

TEST(MapRun, BadTruthFileIsAClearError) {
  const auto dir = fresh_dir("");
  write_log(dir / "est.lcmlog", grid_4x3());
  { std::ofstream(dir / "bad.csv") << "a,b,c\n1,2,3\n"; }
  try {
    run(dir / "est.lcmlog", dir / "out", (dir / "bad.csv").string());
    ADD_FAILURE() << "no error";
  } catch (const MapError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.csv"), std::string::npos);
  }
}

#ifdef TIPFORCE_DEMO_DIR
// The demo sample (tools/demo): a soft cell on a hard substrate. Estimates = truth + noise with
// honest sigmas; the maps must show the cell, and the truth comparison must find the noise.
TEST(MapDemo, CellSample) {
  auto read_grid = [](const fs::path& p) {
    std::vector<std::vector<double>> g;
    for (const auto& l : read_lines(p)) {
      std::vector<double> row;
      for (const auto& c : split_csv(l)) row.push_back(std::stod(c));
      g.push_back(row);
    }
    return g;
  };
  const auto k = read_grid(fs::path(TIPFORCE_DEMO_DIR) / "cell_k_n_per_m.csv");
  const auto h = read_grid(fs::path(TIPFORCE_DEMO_DIR) / "cell_h_m.csv");
  ASSERT_EQ(k.size(), 64u);
  ASSERT_EQ(h.size(), 64u);
  const auto dir = fresh_dir("");
  std::mt19937 rng(7);
  std::normal_distribution<double> n01;
  std::vector<force_estimate_t> est;
  std::ofstream t(dir / "truth.csv");
  t << "seq,pixel_x,pixel_y,k_n_per_m,h_m\n";
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 64; ++x) {
      ASSERT_EQ(k[static_cast<size_t>(y)].size(), 64u);
      const double kt = k[static_cast<size_t>(y)][static_cast<size_t>(x)], ht = h[static_cast<size_t>(y)][static_cast<size_t>(x)];
      EXPECT_GE(kt, 0.5);
      EXPECT_LE(kt, 15.0);
      EXPECT_GE(ht, 25e-9);
      EXPECT_LE(ht, 55e-9);
      t << y * 64 + x << "," << x << "," << y << "," << exact_number(kt) << "," << exact_number(ht) << "\n";
      if (x == 5 && y == 60) continue;  // one lost window
      const double ks = 0.03 * kt, hs = 0.3e-9;
      auto e = estimate(x, y, force_estimate_t::STATUS_OK, kt + ks * n01(rng), ht + hs * n01(rng), ks, hs);
      const double delta = std::max(0.0, 50e-9 - ht);  // a plausible indentation-like quantity
      e.peak_force_n = kt * delta;
      e.max_indentation_m = delta * 0.1;
      if (x == 60 && y == 3) e.status = force_estimate_t::STATUS_REJECTED;
      est.push_back(e);
    }
  t.close();
  write_log(dir / "cell.lcmlog", est);
  const MapReport r = run(dir / "cell.lcmlog", dir / "out", (dir / "truth.csv").string());
  EXPECT_EQ(r.width, 64);
  EXPECT_EQ(r.missing.size(), 1u);
  ASSERT_EQ(r.accuracy.size(), 2u);
  EXPECT_GT(r.accuracy[0].frac_within_2sigma, 0.9);
  EXPECT_LT(r.accuracy[0].median_rel_err, 0.05);
  const auto& hm = image(r, "h_m");
  EXPECT_EQ(hm.unit.label, "nm");
  EXPECT_GT(hm.range.data_max, -35e-9);  // the top of the cell is raised toward the cantilever (-h)
  if (std::getenv("TIPFORCE_MAP_KEEP")) std::cout << "demo output kept in " << (dir / "out") << "\n";
}
#endif
