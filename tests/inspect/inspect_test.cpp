// `tipforce inspect` (issue 11): the four figures (decoded with libpng, PDFs opened with pdfinfo)
// and the CSV curves checked against what they claim to be: the window's samples, the spring law
// of SPEC 1 on the tip position, the independent reference integrator from the stated start, and a
// refit with the library's public API (Inverter).
#include <gtest/gtest.h>
#include <png.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "tipforce/config.hpp"
#include "tipforce/event_log.hpp"
#include "tipforce/force_estimate_t.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/tipforce.hpp"

namespace {
namespace fs = std::filesystem;

struct Outcome {
  int status;
  std::string output;
};

Outcome run(const std::string& cmd) {
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  std::string out;
  std::array<char, 4096> buf{};
  while (std::size_t n = fread(buf.data(), 1, buf.size(), p)) out.append(buf.data(), n);
  const int rc = pclose(p);
  return {WIFEXITED(rc) ? WEXITSTATUS(rc) : -1, out};
}

std::pair<int, int> png_size(const fs::path& path) {
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&img, path.string().c_str())) return {0, 0};
  img.format = PNG_FORMAT_RGB;
  std::vector<unsigned char> px(PNG_IMAGE_SIZE(img));
  if (!png_image_finish_read(&img, nullptr, px.data(), 0, nullptr)) return {0, 0};
  return {static_cast<int>(img.width), static_cast<int>(img.height)};
}

std::vector<std::vector<std::string>> read_csv(const fs::path& p) {
  std::vector<std::vector<std::string>> rows;
  std::ifstream in(p);
  for (std::string line; std::getline(in, line);) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) cells.push_back(c);
    rows.push_back(cells);
  }
  return rows;
}

class Inspect : public ::testing::Test {
 protected:
  static fs::path dir;
  static void SetUpTestSuite() {
    dir = fs::temp_directory_path() / ("tipforce_inspect_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    std::ofstream(dir / "scan.toml") << "sample_period_s = 2e-7\nsamples_per_window = 400\npixels_x = 4\npixels_y = 2\n"
                                        "start = \"steady\"\nnoise_m = 1e-10\nseed = 5\n[drive]\nkind = \"sine\"\n"
                                        "amplitude_m = 0.6e-9\nfrequency_hz = 25468.9\n[truth]\nk_n_per_m = 3.0\nh_m = 40e-9\n";
    const std::string bin = TIPFORCE_BIN;
    Outcome s = run(bin + " simulate --config " + config() + " --probe afm1 --scan " + (dir / "scan.toml").string() +
                    " --out " + (dir / "scan.lcmlog").string());
    ASSERT_EQ(s.status, 0) << s.output;
    Outcome i = run(bin + " invert --backend cpu --config " + config() + " --in " + (dir / "scan.lcmlog").string() +
                    " --out " + (dir / "est.lcmlog").string());
    ASSERT_EQ(i.status, 0) << i.output;
  }
  static void TearDownTestSuite() { fs::remove_all(dir); }
  static std::string config() { return std::string(TIPFORCE_SOURCE_DIR) + "/tools/demo/demo.toml"; }

  static tipforce::Window window_at(int x, int y) {
    tipforce::lcmio::LogReader r(dir / "scan.lcmlog");
    while (auto ev = r.next()) {
      auto d = tipforce::lcmio::decode_window(ev->data.data(), ev->data.size());
      if (d.attributable && d.header.pixel_x == x && d.header.pixel_y == y) return d.window;
    }
    ADD_FAILURE() << "no window at " << x << "," << y;
    return {};
  }
};
fs::path Inspect::dir;

TEST_F(Inspect, WritesFourFiguresAndCurvesThatAreTheFit) {
  const fs::path out = dir / "refit";
  Outcome o = run(std::string(TIPFORCE_BIN) + " inspect --config " + config() + " --in " + (dir / "scan.lcmlog").string() +
                  " --pixel 2,1 --out " + out.string());
  ASSERT_EQ(o.status, 0) << o.output;
  const std::map<std::string, std::pair<int, int>> sizes{{"deflection", {900, 570}},
                                                         {"force_time", {900, 560}},
                                                         {"force_distance", {900, 560}},
                                                         {"misfit_landscape", {960, 560}}};
  for (const auto& [stem, size] : sizes) {
    EXPECT_EQ(png_size(out / (stem + ".png")), size) << stem;
    ASSERT_TRUE(fs::exists(out / (stem + ".pdf"))) << stem;
    if (std::system("command -v pdfinfo > /dev/null 2>&1") == 0) {
      const Outcome info = run("pdfinfo " + (out / (stem + ".pdf")).string());
      EXPECT_EQ(info.status, 0) << info.output;
      EXPECT_NE(info.output.find(std::to_string(size.first) + " x " + std::to_string(size.second) + " pts"),
                std::string::npos)
          << info.output;
    }
  }

  // The refit, with the library's public API, as inspect says it does it.
  const tipforce::Config config = tipforce::load_config(Inspect::config());
  const tipforce::ProbeModel probe = config.probe_model("afm1");
  tipforce::Window w = window_at(2, 1);
  w.initial = tipforce::InitialState::unknown;
  auto backend = tipforce::make_cpu_backend();
  tipforce::Inverter inverter(probe, *backend);
  const tipforce::Estimate refit = inverter.invert(w);
  ASSERT_EQ(refit.status, tipforce::EstimateStatus::ok) << refit.message;

  std::map<std::string, double> est;
  for (const auto& row : read_csv(out / "estimate.csv"))
    if (row.size() >= 2 && row[0] != "name") est[row[0]] = std::stod(row[1]);
  for (std::size_t i = 0; i < refit.names.size(); ++i) EXPECT_DOUBLE_EQ(est.at(refit.names[i]), refit.values[i]);
  const double k = est.at("k_n_per_m"), h = est.at("h_m");

  const auto rows = read_csv(out / "curves.csv");
  ASSERT_EQ(rows.size(), w.deflection_m.size() + 1);
  EXPECT_EQ(rows[0], (std::vector<std::string>{"t_s", "measured_m", "fitted_m", "residual_m", "force_n", "tip_z_m"}));
  std::vector<double> fitted;
  double r2 = 0, u2 = 0, fmax = 0;
  for (std::size_t n = 0; n < w.deflection_m.size(); ++n) {
    const auto& c = rows[n + 1];
    const double measured = std::stod(c[1]), fit = std::stod(c[2]), residual = std::stod(c[3]), force = std::stod(c[4]),
                 z = std::stod(c[5]);
    EXPECT_EQ(measured, w.deflection_m[n]);
    EXPECT_NEAR(residual, measured - fit, 1e-20);
    // SPEC 1, spring: f = -k (z - h) in contact, 0 out of it.
    EXPECT_NEAR(force, z > h ? -k * (z - h) : 0.0, 1e-15) << n;
    fmax = std::max(fmax, std::abs(force));
    fitted.push_back(fit);
    r2 += (measured - fit) * (measured - fit);
    u2 += measured * measured;
  }
  EXPECT_GT(fmax, 1e-9);  // the tip does touch the surface
  // As good a fit as the refit reports: the drawn curve is the fit, not an approximation of it.
  EXPECT_LE(std::sqrt(r2 / u2), refit.misfit * 1.02);
  EXPECT_NEAR(est.at("misfit_curve"), std::sqrt(r2 / u2), 1e-12);

  // The independent reference integrator from the stated start gives the same curve.
  tipforce::ModalState start = tipforce::ModalState::rest(probe.modal.n_modes());
  for (int i = 0; i < probe.modal.n_modes(); ++i) {
    start.q[static_cast<std::size_t>(i)] = est.at("start_q_mode" + std::to_string(i + 1));
    start.v[static_cast<std::size_t>(i)] = est.at("start_v_mode" + std::to_string(i + 1));
  }
  std::vector<double> full(static_cast<std::size_t>(probe.space.n_full()));
  probe.space.assemble(w, refit.values.data(), full.data());
  const auto ref = tipforce::reference_simulate(probe.modal, probe.space.model(), w, full, start);
  double d2 = 0;
  for (std::size_t n = 0; n < fitted.size(); ++n) d2 += (ref.signal[n] - fitted[n]) * (ref.signal[n] - fitted[n]);
  EXPECT_LT(std::sqrt(d2 / u2), 1e-3);

  // The landscape: the estimate sits in its valley.
  double lowest = INFINITY;
  const auto land = read_csv(out / "landscape.csv");
  ASSERT_EQ(land.size(), 31u * 31u + 1);
  for (std::size_t i = 1; i < land.size(); ++i) lowest = std::min(lowest, std::stod(land[i][2]));
  EXPECT_GE(lowest, 0.98 * est.at("misfit_curve"));
}

TEST_F(Inspect, TakesTheEstimateFromALog) {
  const fs::path out = dir / "from_log";
  Outcome o = run(std::string(TIPFORCE_BIN) + " inspect --config " + config() + " --in " + (dir / "scan.lcmlog").string() +
                  " --estimates " + (dir / "est.lcmlog").string() + " --pixel 3,0 --out " + out.string());
  ASSERT_EQ(o.status, 0) << o.output;
  tipforce::force_estimate_t e;
  {
    tipforce::lcmio::LogReader r(dir / "est.lcmlog");
    while (auto ev = r.next()) {
      tipforce::force_estimate_t m;
      if (m.decode(ev->data.data(), 0, static_cast<int>(ev->data.size())) >= 0 && m.pixel_x == 3 && m.pixel_y == 0) e = m;
    }
  }
  std::map<std::string, std::pair<double, double>> est;
  for (const auto& row : read_csv(out / "estimate.csv"))
    if (row.size() >= 3 && row[0] != "name" && !row[2].empty()) est[row[0]] = {std::stod(row[1]), std::stod(row[2])};
  for (int i = 0; i < e.n_params; ++i) {
    EXPECT_DOUBLE_EQ(est.at(e.param_names[static_cast<std::size_t>(i)]).first, e.params[static_cast<std::size_t>(i)]);
    EXPECT_DOUBLE_EQ(est.at(e.param_names[static_cast<std::size_t>(i)]).second, e.param_sigma[static_cast<std::size_t>(i)]);
  }
}

// Estimates of another scan are not drawn against this window's data as if they were its own:
// another layout (the estimate answers another seq and utime) is refused; the same layout (only
// the misfits can tell) gets a note. The right log gets neither.
TEST_F(Inspect, EstimatesOfAnotherScanAreRefusedOrNoted) {
  const std::string bin = TIPFORCE_BIN;
  auto other_scan = [&](const std::string& name, const std::string& from, const std::string& to) {
    std::ifstream in(dir / "scan.toml");
    std::string text((std::istreambuf_iterator<char>(in)), {});
    text.replace(text.find(from), from.size(), to);
    std::ofstream(dir / (name + ".toml")) << text;
    Outcome s = run(bin + " simulate --config " + config() + " --probe afm1 --scan " + (dir / (name + ".toml")).string() +
                    " --out " + (dir / (name + ".lcmlog")).string());
    EXPECT_EQ(s.status, 0) << s.output;
    Outcome i = run(bin + " invert --backend cpu --config " + config() + " --in " + (dir / (name + ".lcmlog")).string() +
                    " --out " + (dir / (name + "_est.lcmlog")).string());
    EXPECT_EQ(i.status, 0) << i.output;
    return (dir / (name + "_est.lcmlog")).string();
  };
  auto inspect_with = [&](const std::string& estimates) {
    return run(bin + " inspect --config " + config() + " --in " + (dir / "scan.lcmlog").string() + " --estimates " +
               estimates + " --pixel 1,1 --out " + (dir / "other").string());
  };
  const std::string note = "the reported misfit and the curve's differ by more than 10 %";
  const Outcome own = inspect_with((dir / "est.lcmlog").string());
  EXPECT_EQ(own.status, 0) << own.output;
  EXPECT_EQ(own.output.find(note), std::string::npos) << own.output;

  const Outcome layout = inspect_with(other_scan("longer", "samples_per_window = 400", "samples_per_window = 500"));
  EXPECT_EQ(layout.status, 2) << layout.output;
  EXPECT_NE(layout.output.find("longer_est.lcmlog: the estimate at pixel 1,1 answers window seq 5 (utime "),
            std::string::npos)
      << layout.output;
  EXPECT_NE(layout.output.find("estimates of another scan?"), std::string::npos) << layout.output;

  const Outcome same = inspect_with(other_scan("lower", "h_m = 40e-9", "h_m = 30e-9"));
  EXPECT_EQ(same.status, 0) << same.output;
  EXPECT_NE(same.output.find(note), std::string::npos) << same.output;
}

// An --out that cannot be written was found only after the fit (seconds on a long window): it is
// checked first, so the refusal comes before any fit is reported.
TEST_F(Inspect, UnwritableOutIsRefusedBeforeTheFit) {
  const fs::path file = dir / "a_file";
  std::ofstream(file) << "not a directory\n";
  for (const fs::path& out : {file, file / "inside"}) {
    Outcome o = run(std::string(TIPFORCE_BIN) + " inspect --config " + config() + " --in " +
                    (dir / "scan.lcmlog").string() + " --pixel 2,1 --out " + out.string());
    EXPECT_EQ(o.status, 2) << o.output;
    EXPECT_NE(o.output.find("tipforce inspect: error: --out"), std::string::npos) << o.output;
    EXPECT_NE(o.output.find(out.string()), std::string::npos) << o.output;
    EXPECT_EQ(o.output.find("misfit:"), std::string::npos) << "fitted before refusing --out\n" << o.output;
  }
}

// A log cut short: a pixel past the cut is not "no window there" but damaged input (exit 3, as
// invert and map), and a pixel before it is inspected with a note of the damage.
TEST_F(Inspect, ACutShortLogSaysSo) {
  const fs::path cut = dir / "cut.lcmlog";
  {
    std::ifstream in(dir / "scan.lcmlog", std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), {});
    std::ofstream(cut, std::ios::binary) << bytes.substr(0, bytes.size() * 5 / 8 + 7);
  }
  auto inspect = [&](const std::string& pixel) {
    return run(std::string(TIPFORCE_BIN) + " inspect --config " + config() + " --in " + cut.string() + " --pixel " +
               pixel + " --out " + (dir / "cut_out").string());
  };
  const Outcome past = inspect("3,1");
  EXPECT_EQ(past.status, 3) << past.output;
  EXPECT_NE(past.output.find("cut.lcmlog has no window at pixel 3,1; but the log is damaged (1 stretch skipped, the "
                             "first: skipped "),
            std::string::npos)
      << past.output;
  const Outcome before = inspect("0,0");
  EXPECT_EQ(before.status, 0) << before.output;
  EXPECT_NE(before.output.find("cut.lcmlog is damaged elsewhere: skipped "), std::string::npos) << before.output;
}

TEST_F(Inspect, MissingPixelIsAClearError) {
  Outcome o = run(std::string(TIPFORCE_BIN) + " inspect --config " + config() + " --in " + (dir / "scan.lcmlog").string() +
                  " --pixel 9,9 --out " + (dir / "none").string());
  EXPECT_EQ(o.status, 2) << o.output;
  EXPECT_NE(o.output.find("scan.lcmlog has no window at pixel 9,9"), std::string::npos) << o.output;
}

}  // namespace
