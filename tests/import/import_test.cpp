// `tipforce import` as a user runs it (issue 11). A simulated scan's deflection is written by
// numpy and h5py (write_formats.py, independent of the importer) as HDF5, .npy, raw int16 with a
// sensitivity, and CSV. Each is imported: its windows must equal the simulated ones to the
// format's quantisation, and its estimates those of the simulated windows. Malformed files must
// each get an error that names the file and what is wrong, and leave no log behind.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "tipforce/deflection_window_t.hpp"
#include "tipforce/event_log.hpp"
#include "tipforce/force_estimate_t.hpp"
#include "tipforce/scan_geometry_t.hpp"

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

std::string number(double v) {
  char b[40];
  std::snprintf(b, sizeof b, "%.17g", v);
  return b;
}

std::string tipforce(const std::string& args) { return std::string(TIPFORCE_BIN) + " " + args; }

template <typename Msg>
std::vector<Msg> read_log(const fs::path& path, const std::string& channel) {
  std::vector<Msg> out;
  tipforce::lcmio::LogReader r(path);
  while (auto ev = r.next()) {
    if (ev->channel != channel) continue;
    Msg m;
    if (m.decode(ev->data.data(), 0, static_cast<int>(ev->data.size())) < 0) ADD_FAILURE() << "undecodable event";
    out.push_back(m);
  }
  return out;
}

// The scan: 8 pixels x 4 lines of 400 samples at 5 MHz, the demo's probe and drive, a stiffness
// that changes along x and a height that changes along y (so that a pixel put in the wrong place
// shows), 0.1 nm noise.
constexpr int kPixelsX = 8, kLines = 4, kSamples = 400;
constexpr double kNoiseM = 1e-10;
constexpr double kSensitivityMPerV = 2e-8;           // 20 nm/V
constexpr double kVoltsPerCount = 10.0 / 32768.0;    // a +-10 V, 16-bit DAQ

class Import : public ::testing::Test {
 protected:
  static fs::path dir;
  static std::vector<tipforce::deflection_window_t> reference_windows;
  static std::vector<tipforce::force_estimate_t> reference_estimates;

  static void SetUpTestSuite() {
    if (!TIPFORCE_PYTHON_HAS_NUMPY_H5PY) return;
    dir = fs::temp_directory_path() / ("tipforce_import_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    {
      std::ofstream k(dir / "k.csv"), h(dir / "h.csv");
      for (int y = 0; y < kLines; ++y)
        for (int x = 0; x < kPixelsX; ++x) {
          k << 2.0 + x << (x + 1 < kPixelsX ? "," : "\n");
          h << 40e-9 - 3e-9 * y << (x + 1 < kPixelsX ? "," : "\n");
        }
      std::ofstream s(dir / "scan.toml");
      s << "sample_period_s = 2e-7\nsamples_per_window = " << kSamples << "\npixels_x = " << kPixelsX
        << "\npixels_y = " << kLines << "\nstart = \"steady\"\nnoise_m = " << kNoiseM
        << "\nseed = 7\n[drive]\nkind = \"sine\"\namplitude_m = 0.6e-9\nfrequency_hz = 25468.9\n"
           "[truth]\nk_n_per_m = \"k.csv\"\nh_m = \"h.csv\"\n";
    }
    Outcome sim = run(tipforce("simulate --config " + config() + " --probe afm1 --scan " + (dir / "scan.toml").string() +
                               " --out " + (dir / "scan.lcmlog").string()));
    ASSERT_EQ(sim.status, 0) << sim.output;
    Outcome py = run(std::string(TIPFORCE_PYTHON3) + " " + std::string(TIPFORCE_SOURCE_DIR) + "/tests/import/write_formats.py " +
                     TIPFORCE_PY_TYPES + " " + (dir / "scan.lcmlog").string() + " " + dir.string() + " " +
                     number(kSensitivityMPerV) + " " + number(kVoltsPerCount));
    ASSERT_EQ(py.status, 0) << py.output;
    reference_windows = read_log<tipforce::deflection_window_t>(dir / "reference.lcmlog", "TIPFORCE_WINDOW");
    ASSERT_EQ(reference_windows.size(), std::size_t{kPixelsX * kLines});
    Outcome inv = run(tipforce("invert --backend cpu --config " + config() + " --in " +
                               (dir / "reference.lcmlog").string() + " --out " + (dir / "reference_est.lcmlog").string()));
    ASSERT_EQ(inv.status, 0) << inv.output;
    reference_estimates = read_log<tipforce::force_estimate_t>(dir / "reference_est.lcmlog", "TIPFORCE_ESTIMATE");
  }
  static void TearDownTestSuite() {
    if (!dir.empty()) fs::remove_all(dir);
  }
  void SetUp() override {
    if (!TIPFORCE_PYTHON_HAS_NUMPY_H5PY)
      GTEST_SKIP() << TIPFORCE_PYTHON3 << " cannot import numpy and h5py (tools/setup.sh installs python3-numpy, python3-h5py)";
  }

  static std::string config() { return std::string(TIPFORCE_SOURCE_DIR) + "/tools/demo/demo.toml"; }
  static std::string geometry() {
    return " --probe afm1 --sample-period-s 2e-7 --samples-per-pixel " + std::to_string(kSamples) +
           " --pixels-per-line " + std::to_string(kPixelsX) + " --lines " + std::to_string(kLines) +
           " --scan-size-m 2e-6,1e-6 --start-utime 1700000000000000";
  }
  static std::string sine() { return " --drive sine --drive-amplitude-m 0.6e-9 --drive-frequency-hz 25468.9"; }

  // Imports `args`, checks the windows against the simulated ones sample by sample (at most
  // `sample_tolerance_m` apart), inverts them and checks every estimate against the reference's:
  // each parameter within `sigmas` of its reported 1-sigma.
  void round_trip(const std::string& name, const std::string& args, double sample_tolerance_m, double sigmas) {
    const fs::path windows = dir / (name + ".lcmlog");
    Outcome imp = run(tipforce("import " + args + geometry() + sine() + " --out " + windows.string()));
    ASSERT_EQ(imp.status, 0) << imp.output;
    EXPECT_NE(imp.output.find("imported 32 windows of 400 samples"), std::string::npos) << imp.output;

    const auto got = read_log<tipforce::deflection_window_t>(windows, "TIPFORCE_WINDOW");
    ASSERT_EQ(got.size(), reference_windows.size());
    for (std::size_t i = 0; i < got.size(); ++i) {
      const auto& a = got[i];
      const auto& b = reference_windows[i];
      SCOPED_TRACE("window " + std::to_string(i));
      EXPECT_EQ(a.seq, b.seq);
      EXPECT_EQ(a.pixel_x, b.pixel_x);
      EXPECT_EQ(a.pixel_y, b.pixel_y);
      EXPECT_EQ(a.initial_state, b.initial_state);
      EXPECT_EQ(a.utime, b.utime);
      EXPECT_EQ(a.t0_s, b.t0_s);
      EXPECT_EQ(a.sample_period_s, b.sample_period_s);
      EXPECT_EQ(a.drive_kind, b.drive_kind);
      EXPECT_EQ(a.drive_amplitude_m, b.drive_amplitude_m);
      EXPECT_EQ(a.drive_frequency_hz, b.drive_frequency_hz);
      ASSERT_EQ(a.n_samples, b.n_samples);
      double worst = 0;
      for (int k = 0; k < a.n_samples; ++k) worst = std::max(worst, std::abs(double(a.deflection_m[k]) - b.deflection_m[k]));
      EXPECT_LE(worst, sample_tolerance_m);
    }
    const auto scan = read_log<tipforce::scan_geometry_t>(windows, "TIPFORCE_SCAN");
    ASSERT_EQ(scan.size(), 1u);
    EXPECT_EQ(scan[0].pixels_x, kPixelsX);
    EXPECT_EQ(scan[0].pixels_y, kLines);
    EXPECT_EQ(scan[0].size_x_m, 2e-6);
    EXPECT_EQ(scan[0].size_y_m, 1e-6);
    EXPECT_EQ(scan[0].probe, "afm1");

    invert_and_compare(windows, name, sigmas);
  }

  // Inverts `windows` with `tipforce invert` and the demo config, and checks every estimate against
  // the reference windows' estimate: each parameter within `sigmas` of the latter's 1-sigma.
  void invert_and_compare(const fs::path& windows, const std::string& name, double sigmas) {
    const fs::path estimates = dir / (name + "_est.lcmlog");
    Outcome inv = run(tipforce("invert --backend cpu --config " + config() + " --in " + windows.string() + " --out " +
                               estimates.string()));
    ASSERT_EQ(inv.status, 0) << inv.output;
    const auto est = read_log<tipforce::force_estimate_t>(estimates, "TIPFORCE_ESTIMATE");
    ASSERT_EQ(est.size(), reference_estimates.size());
    double worst_in_sigma = 0;
    for (std::size_t i = 0; i < est.size(); ++i) {
      const auto& a = est[i];
      const auto& b = reference_estimates[i];
      SCOPED_TRACE("estimate " + std::to_string(i));
      EXPECT_EQ(a.status, b.status);
      ASSERT_EQ(a.param_names, b.param_names);
      for (int p = 0; p < a.n_params; ++p) {
        const double in_sigma = std::abs(a.params[p] - b.params[p]) / b.param_sigma[p];
        worst_in_sigma = std::max(worst_in_sigma, in_sigma);
        EXPECT_LE(in_sigma, sigmas) << a.param_names[p] << ": " << a.params[p] << " against " << b.params[p]
                                    << " (sigma " << b.param_sigma[p] << ")";
      }
    }
    std::printf("%s: largest estimate difference %.3g sigma\n", name.c_str(), worst_in_sigma);
  }

  // A malformed import: exit 2, the message names `file` and contains `what`, no log left.
  void refused(const std::string& args, const std::string& file, const std::string& what,
               const std::string& scan = geometry()) {
    const fs::path out = dir / "refused.lcmlog";
    fs::remove(out);
    Outcome imp = run(tipforce("import " + args + scan + sine() + " --out " + out.string()));
    EXPECT_EQ(imp.status, 2) << imp.output;
    EXPECT_NE(imp.output.find(file), std::string::npos) << imp.output;
    EXPECT_NE(imp.output.find(what), std::string::npos) << imp.output;
    EXPECT_FALSE(fs::exists(out));
    for (const auto& e : fs::directory_iterator(dir))
      EXPECT_EQ(e.path().filename().string().find("refused.lcmlog.partial"), std::string::npos);
  }
};
fs::path Import::dir;
std::vector<tipforce::deflection_window_t> Import::reference_windows;
std::vector<tipforce::force_estimate_t> Import::reference_estimates;

// float64 volts: (v * s) rounded to float gives back the simulated float exactly, so the
// windows, and with them the estimates, are the same.
TEST_F(Import, Hdf5Float64RoundTripsExactly) {
  round_trip("hdf5", "--in " + (dir / "record.h5").string() + " --dataset /daq/deflection_v --sensitivity-m-per-v 2e-8",
             0.0, 1e-9);
}

TEST_F(Import, CsvByHeaderNameRoundTripsExactly) {
  round_trip("csv", "--in " + (dir / "record.csv").string() + " --column deflection_v --sensitivity-m-per-v 2e-8", 0.0,
             1e-9);
}

// float32 volts: one float rounding of the volts (2^-24 relative) and one of the metres; the
// samples (at most ~60 nm) are within 2^-22 x 60 nm. Such a change, 1e-4 of the noise, cannot
// move the least-squares minimum by a measurable part of its sigma; what it can move is where the
// polish stops (it stops once a step gains less than lm_chi2_tolerance = 0.01 of a chi-square,
// ~0.1 sigma from the exact minimum): 0.013 sigma on one window since 2026-12-02's polish
// changes. 0.05 sigma still catches a loss of precision in the import (the int16 case below: a
// change of 2 % of the noise per sample can move an estimate by up to 0.35 sigma).
TEST_F(Import, NpyFloat32RoundTripsToFloatPrecision) {
  round_trip("npy", "--in " + (dir / "record.npy").string() + " --sensitivity-m-per-v 2e-8", 60e-9 / (1 << 22), 5e-2);
}

// int16 counts: each sample is off by at most half a count, 10/32768 V x 20 nm/V / 2 = 3 pm. Over
// a window of 400 samples that is an rms change of 1.8 pm against 100 pm of noise: a linear least
// squares estimate moves by at most sigma x |change| / noise = 0.35 sigma (Cauchy-Schwarz on the
// normal equations); the iterative fit's own stopping tolerance adds a little.
TEST_F(Import, RawInt16WithSensitivityRoundTripsToHalfACount) {
  const double count_m = kVoltsPerCount * kSensitivityMPerV;
  round_trip("int16",
             "--in " + (dir / "record_i16.bin").string() + " --dtype int16 --volts-per-count " + number(kVoltsPerCount) + " --sensitivity-m-per-v 2e-8",
             count_m / 2 * 1.0001 + 1e-15, 0.5);
}

TEST_F(Import, SampledBaseChannelBecomesDriveSampled) {
  const fs::path out = dir / "sampled.lcmlog";
  Outcome imp = run(tipforce("import --in " + (dir / "record.h5").string() +
                             " --dataset /daq/deflection_v --sensitivity-m-per-v 2e-8 --base-dataset /daq/base_v"
                             " --base-sensitivity-m-per-v 2e-8" + geometry() + " --drive sampled --out " + out.string()));
  ASSERT_EQ(imp.status, 0) << imp.output;
  const auto got = read_log<tipforce::deflection_window_t>(out, "TIPFORCE_WINDOW");
  ASSERT_EQ(got.size(), std::size_t{kPixelsX * kLines});
  for (const auto& w : got) {
    ASSERT_EQ(w.drive_kind, tipforce::deflection_window_t::DRIVE_SAMPLED);
    ASSERT_EQ(w.n_base_samples, w.n_samples);
    for (int k = 0; k < w.n_samples; k += 37) {
      const double t = w.t0_s + k * w.sample_period_s;
      EXPECT_NEAR(w.base_m[k], 0.6e-9 * std::sin(2 * M_PI * 25468.9 * t), 1e-16);
    }
  }
  // Inverted, the sampled base says what the sine does: every estimate where the sine-driven
  // import's is, well inside its sigma (the base travels as float samples, read to fourth order;
  // 0.05 as for the float32 round trip: the polish's stopping alone moves 0.013).
  invert_and_compare(out, "sampled", 0.05);
}

TEST_F(Import, TraceRetraceRecordKeepsTheRetraceRightToLeft) {
  // The simulated record read as 2 lines of trace + retrace (4 pixels each way): the retrace
  // pass of line y starts at record row (2y + 1) * 4 * 400 and runs from pixel 3 to pixel 0.
  const fs::path out = dir / "retrace.lcmlog";
  Outcome imp = run(tipforce("import --in " + (dir / "record.npy").string() +
                             " --sensitivity-m-per-v 2e-8 --probe afm1 --sample-period-s 2e-7 --samples-per-pixel 400"
                             " --pixels-per-line 4 --lines 4 --line-layout trace-retrace --keep retrace --drive sine"
                             " --drive-amplitude-m 0.6e-9 --drive-frequency-hz 25468.9 --out " + out.string()));
  ASSERT_EQ(imp.status, 0) << imp.output;
  const auto got = read_log<tipforce::deflection_window_t>(out, "TIPFORCE_WINDOW");
  ASSERT_EQ(got.size(), 16u);
  for (std::size_t i = 0; i < got.size(); ++i) {
    const int line = static_cast<int>(i / 4), dwell = static_cast<int>(i % 4);
    const auto& ref = reference_windows[static_cast<std::size_t>((2 * line + 1) * 4 + dwell)];
    EXPECT_EQ(got[i].pixel_x, 3 - dwell);
    EXPECT_EQ(got[i].pixel_y, line);
    EXPECT_EQ(got[i].t0_s, ref.t0_s);
    EXPECT_EQ(got[i].initial_state, dwell == 0 ? 2 : 1);
    EXPECT_NEAR(got[i].deflection_m[123], ref.deflection_m[123], 60e-9 / (1 << 22));
  }
}

TEST_F(Import, PartOfTheDwellIsNeverContinued) {
  const fs::path out = dir / "part.lcmlog";
  Outcome imp = run(tipforce("import --in " + (dir / "record.npy").string() + " --sensitivity-m-per-v 2e-8" +
                             geometry() + sine() + " --window-offset 100 --window-length 250 --out " + out.string()));
  ASSERT_EQ(imp.status, 0) << imp.output;
  const auto got = read_log<tipforce::deflection_window_t>(out, "TIPFORCE_WINDOW");
  ASSERT_EQ(got.size(), std::size_t{kPixelsX * kLines});
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].n_samples, 250);
    EXPECT_EQ(got[i].initial_state, tipforce::deflection_window_t::INITIAL_UNKNOWN);
    EXPECT_NEAR(got[i].deflection_m[0], reference_windows[i].deflection_m[100], 60e-9 / (1 << 22));
    EXPECT_NEAR(got[i].t0_s, reference_windows[i].t0_s + 100 * 2e-7, 1e-15);
  }
}

TEST_F(Import, TruncatedFilesAreRefused) {
  refused("--in " + (dir / "truncated.npy").string() + " --sensitivity-m-per-v 2e-8", "truncated.npy", "truncated");
  refused("--in " + (dir / "truncated_i16.bin").string() + " --dtype int16 --sensitivity-m-per-v 2e-8",
          "truncated_i16.bin", "truncated");
  refused("--in " + (dir / "truncated.h5").string() + " --dataset /daq/deflection_v --sensitivity-m-per-v 2e-8",
          "truncated.h5", "truncated");
  refused("--in " + (dir / "truncated.csv").string() + " --column 1 --sensitivity-m-per-v 2e-8", "truncated.csv",
          "truncated");
}

TEST_F(Import, WrongTypesAreRefused) {
  refused("--in " + (dir / "complex.npy").string() + " --sensitivity-m-per-v 2e-8", "complex.npy", "dtype '<c16'");
  refused("--in " + (dir / "record.h5").string() + " --dataset /daq/label --sensitivity-m-per-v 2e-8", "record.h5",
          "holds strings");
  refused("--in " + (dir / "record.h5").string() + " --dataset /daq/two_d --sensitivity-m-per-v 2e-8", "record.h5",
          "3 dimensions");
  refused("--in " + (dir / "record_i16.bin").string() + " --sensitivity-m-per-v 2e-8", "record_i16.bin",
          "needs --dtype");
}

TEST_F(Import, MissingDatasetIsRefusedWithTheDatasetsThereAre) {
  refused("--in " + (dir / "record.h5").string() + " --dataset /daq/nope --sensitivity-m-per-v 2e-8", "record.h5",
          "no dataset /daq/nope");
  refused("--in " + (dir / "record.h5").string() + " --dataset /nogroup/x --sensitivity-m-per-v 2e-8", "record.h5",
          "/daq/deflection_v");
  refused("--in " + (dir / "record.csv").string() + " --column force --sensitivity-m-per-v 2e-8", "record.csv",
          "--column force: no such column");
}

TEST_F(Import, NanSamplesAreRefusedWithTheirPlace) {
  refused("--in " + (dir / "nan.npy").string() + " --sensitivity-m-per-v 2e-8", "nan.npy",
          "sample 2017 (deflection of pixel 5,0) is NaN");
  refused("--in " + (dir / "nan.csv").string() + " --sensitivity-m-per-v 2e-8", "nan.csv",
          "line 5 (deflection of pixel 0,0) is NaN; a record with gaps must be cut or repaired");
  // A calibration that overflows a float is the options' fault, not a gap in the record.
  refused("--in " + (dir / "record.csv").string() + " --column deflection_v --sensitivity-m-per-v 1e300",
          "record.csv", "is too large for a float once calibrated (check --volts-per-count, --offset-v and the sensitivity)");
}

// A blank line among the samples is a missing sample, refused with its place; blank lines after
// the last sample are not (the record imports as without them).
TEST_F(Import, BlankLineBetweenCsvSamplesIsRefusedNotSkipped) {
  refused("--in " + (dir / "gap.csv").string() + " --sensitivity-m-per-v 2e-8", "gap.csv",
          "line 5 is blank between the samples of line 4 and line 6");
  round_trip("csv_trailing", "--in " + (dir / "trailing_blank.csv").string() + " --column deflection_v --sensitivity-m-per-v 2e-8",
             0.0, 1e-9);
}

// With --config the probe's limits hold too: windows longer than daemon.max_window_samples were
// imported, then rejected one by one by tipforced and tipforce invert. Within them, the same
// record imports as without --config.
TEST_F(Import, WithConfigWindowsTheProbeRejectsAreRefused) {
  std::string text;
  {
    std::ifstream in(config());
    text.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_NE(text.find("[daemon]\n"), std::string::npos);
  text.replace(text.find("[daemon]\n"), 9, "[daemon]\nmax_window_samples = " + std::to_string(kSamples - 1) + "\n");
  const fs::path small = dir / "small_windows.toml";
  std::ofstream(small) << text;
  refused("--in " + (dir / "record.csv").string() + " --column deflection_v --sensitivity-m-per-v 2e-8 --config " +
              small.string(),
          "pixel (0, 0): window has " + std::to_string(kSamples) + " samples, more than the limit of " +
              std::to_string(kSamples - 1) + " (daemon.max_window_samples)",
          "tipforced and tipforce invert reject such a window for probe afm1 (--config)");
  round_trip("csv_config",
             "--in " + (dir / "record.csv").string() + " --column deflection_v --sensitivity-m-per-v 2e-8 --config " +
                 config(),
             0.0, 1e-9);
}

// An empty channel, or the windows on the scan geometry's channel, wrote a log no reader takes the
// windows from.
TEST_F(Import, ChannelsMustBeNamedAndApart) {
  const std::string in = "--in " + (dir / "record.csv").string() + " --column deflection_v --sensitivity-m-per-v 2e-8";
  refused(in + " --channel ''", "--channel", "--channel and --scan-channel must not be empty");
  refused(in + " --channel TIPFORCE_SCAN", "--channel",
          "--channel and --scan-channel are both TIPFORCE_SCAN; the windows and the scan's geometry need channels");
}

TEST_F(Import, RecordTooShortIsRefusedNotCut) {
  refused("--in " + (dir / "short.npy").string() + " --sensitivity-m-per-v 2e-8", "short.npy",
          "need 12800 samples, the file holds 12799 (3 whole lines and 3199 samples)");
  // One line more than the record holds.
  refused("--in " + (dir / "record.npy").string() + " --sensitivity-m-per-v 2e-8", "record.npy",
          "need 16000 samples, the file holds 12800 (4 whole lines)",
          " --probe afm1 --sample-period-s 2e-7 --samples-per-pixel 400 --pixels-per-line 8 --lines 5");
}

// Options that make windows every reader rejects were accepted with exit 0: --window-length 0
// (taken as "the rest of the dwell") or 2, a NaN or negative drive frequency. Each is refused
// naming the option and the range the config allows for the same quantity. A raw float64 record
// written here, so that this runs without numpy.
TEST(ImportOptions, OutOfRangeValuesAreRefusedNamingTheOptionAndTheRange) {
  const fs::path d = fs::temp_directory_path() / ("tipforce_import_options_" + std::to_string(::getpid()));
  fs::create_directories(d);
  {
    std::ofstream rec(d / "record.bin", std::ios::binary);
    for (int i = 0; i < 400 * 4 * 2; ++i) {
      const double v = 1.5 * std::sin(2 * M_PI * 25468.9 * 2e-7 * i);
      rec.write(reinterpret_cast<const char*>(&v), sizeof v);  // little-endian on the machines tipforce runs on
    }
  }
  const fs::path out = d / "windows.lcmlog";
  auto import = [&](const std::map<std::string, std::string>& changed) {
    std::map<std::string, std::string> o = {{"--in", (d / "record.bin").string()}, {"--dtype", "float64"},
                                            {"--sensitivity-m-per-v", "2e-8"}, {"--sample-period-s", "2e-7"},
                                            {"--samples-per-pixel", "400"}, {"--pixels-per-line", "4"},
                                            {"--lines", "2"}, {"--probe", "afm1"}, {"--drive", "sine"},
                                            {"--drive-amplitude-m", "0.6e-9"}, {"--drive-frequency-hz", "25468.9"},
                                            {"--out", out.string()}};
    for (const auto& [k, v] : changed) o[k] = v;
    std::string args = "import";
    for (const auto& [k, v] : o) args += " " + k + " " + v;
    fs::remove(out);
    return run(tipforce(args));
  };
  const Outcome good = import({});
  ASSERT_EQ(good.status, 0) << good.output;
  EXPECT_NE(good.output.find("imported 8 windows of 400 samples"), std::string::npos) << good.output;
  const std::map<std::pair<std::string, std::string>, std::string> refused = {
      {{"--window-length", "0"}, "--window-length must be 8 to 1000000 samples, got 0"},
      {{"--window-length", "2"}, "--window-length must be 8 to 1000000 samples, got 2"},
      {{"--window-length", "-3"}, "--window-length must be 8 to 1000000 samples, got -3"},
      {{"--samples-per-pixel", "5"}, "a window of 5 samples (--samples-per-pixel - --window-offset) is fewer than"},
      {{"--drive-frequency-hz", "nan"}, "--drive-frequency-hz must be between 0 and 10 GHz, got nan"},
      {{"--drive-frequency-hz", "-5"}, "--drive-frequency-hz must be between 0 and 10 GHz, got -5"},
      {{"--drive-frequency-hz", "0"}, "--drive-frequency-hz must be positive for --drive sine, got 0"},
      {{"--drive-amplitude-m", "2e-3"}, "--drive-amplitude-m must be between -1 mm and 1 mm, got 0.002"},
      {{"--drive-phase-rad", "inf"}, "--drive-phase-rad must be between -1000 and 1000 rad, got inf"},
      {{"--sample-period-s", "0.5"}, "--sample-period-s must be between 0.1 ns and 1 ms, got 0.5"},
  };
  for (const auto& [option, message] : refused) {
    const Outcome r = import({option});
    EXPECT_EQ(r.status, 2) << option.first << " " << option.second << "\n" << r.output;
    EXPECT_NE(r.output.find("tipforce import: error: " + message), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(out)) << option.first << " " << option.second;
  }
  fs::remove_all(d);
}

}  // namespace
