#include <gtest/gtest.h>
#include <lcm/lcm-cpp.hpp>

#include <sys/stat.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "tipforce/deflection_window_t.hpp"
#include "tipforce/force_estimate_t.hpp"

namespace {

namespace fs = std::filesystem;

struct Outcome {
  int status;
  std::string output;  // stdout and stderr
};

Outcome run(const std::string& args) {
  const std::string cmd = std::string(TIPFORCE_BIN) + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  std::string out;
  std::array<char, 4096> buf{};
  while (std::size_t n = fread(buf.data(), 1, buf.size(), p)) out.append(buf.data(), n);
  const int rc = pclose(p);
  return {WIFEXITED(rc) ? WEXITSTATUS(rc) : -1, out};
}

class Cli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("tipforce_cli_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
    write("scan.toml", R"(sample_period_s = 1e-7
samples_per_window = 1250
pixels_x = 4
pixels_y = 1
start = "steady"
noise_m = 0.1e-9
seed = 3
[drive]
kind = "sine"
amplitude_m = 2e-9
frequency_hz = 25600.0
[truth]
k_n_per_m = 4.0
h_m = 30e-9
)");
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / name) << text;
    return (dir_ / name).string();
  }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  std::string read(const std::string& name) const {
    std::ifstream in(dir_ / name);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }
  // The samples of the first window in log `name` (empty when there is none).
  std::vector<float> first_window_samples(const std::string& name) const {
    lcm::LogFile in(path(name), "r");
    const lcm::LogEvent* ev = in.readNextEvent();
    tipforce::deflection_window_t w;
    if (ev == nullptr || w.decode(ev->data, 0, static_cast<int>(ev->datalen)) < 0) return {};
    return w.deflection_m;
  }
  fs::path dir_;
};

const std::string kGoodConfig = R"([probe.tip1]
length_m = 525e-6
width_m = 35e-6
thickness_m = 5e-6
youngs_modulus_pa = 1.76e11
density_kg_m3 = 2330
quality_factor = 100
modes = 8
model = "spring"
unknowns = { k_n_per_m = [0.5, 20.0], h_m = [10e-9, 60e-9] }
)";

TEST_F(Cli, EveryCommandRefusesABadConfigNamingFileKeyAndProblem) {
  const std::map<std::string, std::string> broken = {
      {"probe.tip1.colour: unknown key", kGoodConfig + "colour = 3\n"},
      {"probe.tip1.unknowns.k_n_per_m: bounds are empty or inverted",
       std::string(kGoodConfig).replace(kGoodConfig.find("[0.5, 20.0]"), 11, "[20.0, 0.5]")},
      {"probe.tip1.fixed: parameter 'h_m' of model spring is neither fixed nor unknown",
       std::string(kGoodConfig).replace(kGoodConfig.find(", h_m = [10e-9, 60e-9]"), 22, "")},
  };
  const std::string good = write("good.toml", kGoodConfig);
  ASSERT_EQ(run("simulate --config " + good + " --probe tip1 --scan " + path("scan.toml") + " --out " + path("w.lcmlog")).status, 0);
  for (const auto& [expect, text] : broken) {
    const std::string bad = write("bad.toml", text);
    for (const std::string& cmd :
         {"modes --config " + bad + " --probe tip1",
          "simulate --config " + bad + " --probe tip1 --scan " + path("scan.toml") + " --out " + path("x.lcmlog"),
          "invert --config " + bad + " --in " + path("w.lcmlog") + " --out " + path("y.lcmlog")}) {
      const Outcome r = run(cmd);
      EXPECT_NE(r.status, 0) << cmd;
      EXPECT_NE(r.output.find(bad + ": " + expect), std::string::npos) << cmd << "\n" << r.output;
    }
  }
}

// A scan description with a value outside what the config would accept for the same quantity
// is refused naming the file, key and value (a 1e12 Hz drive hung, a NaN truth cell wrote windows
// that every reader rejects, 4.5 pixels became 4): nothing is written.
TEST_F(Cli, SimulateRefusesAScanValueOutOfRangeNamingIt) {
  const std::string good = write("good.toml", kGoodConfig);
  write("k.csv", "4,4,nan,4\n");
  const std::string scan = path("scan.toml");
  std::string text;
  {
    std::ifstream in(scan);
    text.assign(std::istreambuf_iterator<char>(in), {});
  }
  const std::map<std::string, std::pair<std::string, std::string>> broken = {
      {"pixels_x: must be a whole number in [1, 1048576], got 4.5", {"pixels_x = 4", "pixels_x = 4.5"}},
      {"pixels_x: must be a whole number in [1, 1048576], got 2147483648", {"pixels_x = 4", "pixels_x = 2147483648"}},
      // Windows shorter than the readers' minimum were written, then every one rejected by tipforced
      // and tipforce invert ("window has 3 samples; at least 8 are needed").
      {"samples_per_window: must be a whole number in [8, 1000000], got 3.000000: tipforced and tipforce invert "
       "reject a window of fewer than 8 samples",
       {"samples_per_window = 1250", "samples_per_window = 3"}},
      {"samples_per_window: must be a whole number in [8, 1000000]", {"samples_per_window = 1250", "samples_per_window = 7"}},
      {"drive.frequency_hz: must be between 0 and 10 GHz", {"frequency_hz = 25600.0", "frequency_hz = 1e12"}},
      {"drive.frequency_hz: must be positive", {"frequency_hz = 25600.0", "frequency_hz = 0"}},
      {"drive.chirp_hz_per_s: is for kind = \"chirp\"", {"frequency_hz = 25600.0", "frequency_hz = 25600.0\nchirp_hz_per_s = 1e6"}},
      {"sample_period_s: must be between 0.1 ns and 1 ms", {"sample_period_s = 1e-7", "sample_period_s = 1e-2"}},
      {"truth.h_m: pixel (0, 0) is inf", {"h_m = 30e-9", "h_m = inf"}},
      // Every window's samples were infinite, and every reader rejected them.
      {"noise_m: must be a finite number >= 0, got inf", {"noise_m = 0.1e-9", "noise_m = inf"}},
      // A cast made 1.5 seed 1 and -0.5 or 1e300 seed 0.
      {"seed: must be a whole number from 0 (an integer up to 2^63 - 1), got 1.5", {"seed = 3", "seed = 1.5"}},
      {"seed: must be a whole number from 0 (an integer up to 2^63 - 1), got 1e+300", {"seed = 3", "seed = 1e300"}},
      {"scan_size_m: must be positive metres", {"seed = 3", "seed = 3\nscan_size_m = inf"}},
      // The window minimum's reason only where the value is below it.
      {"samples_per_window: must be a whole number in [8, 1000000], got 8.500000\n",
       {"samples_per_window = 1250", "samples_per_window = 8.5"}},
      {"truth.k_n_per_m: pixel (0, 0) is -2", {"k_n_per_m = 4.0", "k_n_per_m = -2.0"}},
      {"truth.k_n_per_m: pixel (2, 0) is nan", {"k_n_per_m = 4.0", "k_n_per_m = \"k.csv\""}},
      // Beyond the documented size (a 1048576 x 1048576 scan crashed or started writing without end).
      {"pixels_x x pixels_y: 1048576 x 1048576 = 1099511627776 pixels, more than the 16777216 (4096 x 4096)",
       {"pixels_x = 4\npixels_y = 1", "pixels_x = 1048576\npixels_y = 1048576"}},
      {"pixels_x x pixels_y x samples_per_window: 16777216 x 4000 = 67108864000 samples, more than the 34359738368",
       {"samples_per_window = 1250\npixels_x = 4\npixels_y = 1",
        "samples_per_window = 4000\npixels_x = 4096\npixels_y = 4096"}},
  };
  for (const auto& [expect, edit] : broken) {
    std::string bad = text;
    ASSERT_NE(bad.find(edit.first), std::string::npos) << edit.first;
    bad.replace(bad.find(edit.first), edit.first.size(), edit.second);
    const std::string bad_scan = write("bad_scan.toml", bad);
    fs::remove(path("x.lcmlog"));
    const Outcome r = run("simulate --config " + good + " --probe tip1 --scan " + bad_scan + " --out " + path("x.lcmlog"));
    EXPECT_EQ(r.status, 2) << edit.second << "\n" << r.output;
    EXPECT_NE(r.output.find(bad_scan + ": " + expect), std::string::npos) << edit.second << "\n" << r.output;
    EXPECT_FALSE(fs::exists(path("x.lcmlog"))) << edit.second;
  }
  // A truth cell is a number as a whole ("3abc" was read as 3), named by its line in the file.
  write("k2.csv", "\n4,4,4,4\n4,3abc,4,4\n");
  std::string two_rows = text;
  two_rows.replace(two_rows.find("pixels_y = 1"), 12, "pixels_y = 2");
  two_rows.replace(two_rows.find("k_n_per_m = 4.0"), 15, "k_n_per_m = \"k2.csv\"");
  const Outcome r = run("simulate --config " + good + " --probe tip1 --scan " + write("bad_scan.toml", two_rows) +
                        " --out " + path("x.lcmlog"));
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find(path("k2.csv") + ": line 3 (row 2): '3abc' is not a number"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(path("x.lcmlog")));
}

// A scan inside its own ranges whose windows the probe's readers reject (tipforce invert answered
// each with "rejected" after simulate had written them all and exited 0) is refused up front,
// naming the pixel and the reader's reason; nothing is written. Just inside each limit, the
// windows are written and invert rejects none of them.
TEST_F(Cli, SimulateRefusesAScanWhoseWindowsTheProbeRejects) {
  const std::string config = write("c.toml", "[daemon]\nmax_window_samples = 1250\n" + kGoodConfig);
  std::string text = read("scan.toml");
  auto edited = [&](const std::string& from, const std::string& to) {
    std::string t = text;
    EXPECT_NE(t.find(from), std::string::npos) << from;
    return t.replace(t.find(from), from.size(), to);
  };
  // Mode 1 of tip1 is at 25.5 kHz, its mode 8 at 4.0 MHz; 1e-7 s sampling has its Nyquist at 5 MHz.
  const std::string chirp = "kind = \"chirp\"\nchirp_hz_per_s = ";
  const std::map<std::string, std::pair<std::string, std::string>> refused = {
      {"pixel (0, 0): drive_frequency_hz 1000 Hz is outside", {"frequency_hz = 25600.0", "frequency_hz = 1000.0"}},
      {"pixel (0, 0): sample_period_s 2e-05 s cannot resolve the probe's first mode",
       {"sample_period_s = 1e-7", "sample_period_s = 2e-5"}},
      {"pixel (0, 0): window has 1300 samples, more than the limit of 1250 (daemon.max_window_samples)",
       {"samples_per_window = 1250", "samples_per_window = 1300"}},
      // 25.6 kHz + 2 x 1e10 Hz/s x t passes 5 MHz within the last pixel (t from 3.75e-4 to 5e-4 s).
      {"pixel (3, 0): the chirp's instantaneous frequency at t = 0.000375 s,",
       {"kind = \"sine\"", chirp + "1e10"}},
  };
  for (const auto& [expect, edit] : refused) {
    const std::string scan = write("bad_scan.toml", edited(edit.first, edit.second));
    fs::remove(path("x.lcmlog"));
    const Outcome r = run("simulate --config " + config + " --probe tip1 --scan " + scan + " --out " + path("x.lcmlog"));
    EXPECT_EQ(r.status, 2) << edit.second << "\n" << r.output;
    EXPECT_NE(r.output.find(scan + ": " + expect), std::string::npos) << edit.second << "\n" << r.output;
    EXPECT_NE(r.output.find("tipforced and tipforce invert reject such a window for probe tip1"), std::string::npos)
        << r.output;
    EXPECT_FALSE(fs::exists(path("x.lcmlog"))) << edit.second;
  }
  const std::vector<std::pair<std::string, std::string>> accepted = {
      {"frequency_hz = 25600.0", "frequency_hz = 2600.0"},
      {"kind = \"sine\"", chirp + "4e9"},  // 4.03 MHz at the last sample
  };
  for (const auto& edit : accepted) {
    const std::string scan = write("ok_scan.toml", edited(edit.first, edit.second));
    const Outcome sim = run("simulate --config " + config + " --probe tip1 --scan " + scan + " --out " + path("w.lcmlog"));
    ASSERT_EQ(sim.status, 0) << edit.second << "\n" << sim.output;
    const Outcome inv = run("invert --config " + config + " --in " + path("w.lcmlog") + " --out " + path("e.lcmlog"));
    EXPECT_NE(inv.output.find("windows 4,"), std::string::npos) << edit.second << "\n" << inv.output;
    EXPECT_NE(inv.output.find("rejected 0 "), std::string::npos) << edit.second << "\n" << inv.output;
  }
}

// A chirp scan that starts "steady" starts in the steady tapping of the sine at the chirp's
// frequency at t = 0, so its first samples are the sine twin's until the chirp's phase 2 pi g t^2
// tells them apart. (The lead-in used to run the chirp itself back to t = -6 tau, at 4e9 Hz/s a
// 60 MHz drive: the first window started far from either, and simulating it took 17 s.)
TEST_F(Cli, SimulateStartsAChirpScanSteadyAsItsSineTwin) {
  const std::string config = write("c.toml", kGoodConfig);
  std::string text = read("scan.toml");
  text.replace(text.find("noise_m = 0.1e-9"), 16, "noise_m = 0");
  auto first_window = [&](const std::string& name, const std::string& scan_text) {
    const std::string scan = write(name + ".toml", scan_text);
    const Outcome r = run("simulate --config " + config + " --probe tip1 --scan " + scan + " --out " + path(name + ".lcmlog"));
    EXPECT_EQ(r.status, 0) << r.output;
    return first_window_samples(name + ".lcmlog");
  };
  const std::vector<float> sine = first_window("sine", text);
  const double g_hz_per_s = 4e9;
  std::string chirp_text = text;
  chirp_text.replace(chirp_text.find("kind = \"sine\""), 13, "kind = \"chirp\"\nchirp_hz_per_s = 4e9");
  const std::vector<float> chirp = first_window("chirp", chirp_text);
  ASSERT_EQ(sine.size(), 1250u);
  ASSERT_EQ(chirp.size(), 1250u);
  double amplitude_m = 0;
  for (float v : sine) amplitude_m = std::max(amplitude_m, std::abs(static_cast<double>(v)));
  ASSERT_GT(amplitude_m, 1e-9);
  // The chirp's phase lead 2 pi g t^2 reaches 0.1 rad at the 20th sample (2 us), and the tip has
  // had no time to follow it further than the base: both bounded by that lead times the tip's
  // amplitude (the base's is 2 nm). From a junk state the two differ from the first sample on.
  for (int i = 0; i < 20; ++i) {
    const double t = i * 1e-7;
    const double bound = amplitude_m * (2 * M_PI * g_hz_per_s * t * t + 1e-4) + 1e-12;
    EXPECT_NEAR(chirp[static_cast<std::size_t>(i)], sine[static_cast<std::size_t>(i)], bound) << "sample " << i;
  }
  // Later the chirp leaves the sine (1 MHz by the window's end).
  double diff = 0;
  for (std::size_t i = 1150; i < 1250; ++i) diff = std::max(diff, std::abs(static_cast<double>(chirp[i] - sine[i])));
  EXPECT_GT(diff, 0.05 * amplitude_m);
}

// An output over one of the command's inputs is refused before anything is opened for writing
// (`simulate --out c.toml` left the config an LCM log, which the next command could not read;
// `--out` over a truth CSV destroyed the truth), and the input is left as it was.
TEST_F(Cli, SimulateAndInvertRefuseToWriteOverTheirInputs) {
  const std::string config = write("c.toml", kGoodConfig);
  write("k.csv", "4,4,4,4\n");
  std::string text = read("scan.toml");
  const std::string scan = write("csv_scan.toml", text.replace(text.find("k_n_per_m = 4.0"), 15, "k_n_per_m = \"k.csv\""));
  ASSERT_EQ(run("simulate --config " + config + " --probe tip1 --scan " + scan + " --out " + path("w.lcmlog")).status, 0);
  const std::map<std::string, std::string> before = {{"c.toml", read("c.toml")},
                                                     {"k.csv", read("k.csv")},
                                                     {"csv_scan.toml", read("csv_scan.toml")}};
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"simulate --config " + config + " --probe tip1 --scan " + scan + " --out " + config, "is the config"},
      {"simulate --config " + config + " --probe tip1 --scan " + scan + " --out " + path("k.csv"),
       "is a truth CSV of the scan"},
      {"simulate --config " + config + " --probe tip1 --scan " + scan + " --out " + path("./csv_scan.toml"),
       "is the scan description"},
      {"invert --config " + config + " --in " + path("w.lcmlog") + " --out " + config, "is the config"},
      {"invert --config " + config + " --in " + path("w.lcmlog") + " --out " + path("w.lcmlog"), "is the input log"},
  };
  for (const auto& [cmd, expect] : cases) {
    const Outcome r = run(cmd);
    EXPECT_EQ(r.status, 2) << cmd << "\n" << r.output;
    EXPECT_NE(r.output.find(expect), std::string::npos) << cmd << "\n" << r.output;
    EXPECT_NE(r.output.find("(the same file); writing there would destroy it"), std::string::npos) << r.output;
    for (const auto& [name, text_before] : before) EXPECT_EQ(read(name), text_before) << name << " after " << cmd;
  }
  EXPECT_EQ(run("invert --config " + config + " --in " + path("w.lcmlog") + " --out " + path("e.lcmlog")).status, 0);
}

// The truth table goes to --truth, else beside the log. `--out /dev/null` (a dry run) used to write
// /dev/null.truth.csv (a file in /dev, or a write error): the truth is discarded with the log. An
// --out that is another non-regular file (a FIFO) has no place beside it and needs --truth.
TEST_F(Cli, SimulateWritesTheTruthWhereTold) {
  const std::string config = write("c.toml", kGoodConfig);
  const std::string sim = "simulate --config " + config + " --probe tip1 --scan " + path("scan.toml");
  const Outcome told = run(sim + " --out " + path("w.lcmlog") + " --truth " + path("t.csv"));
  ASSERT_EQ(told.status, 0) << told.output;
  EXPECT_NE(told.output.find("(truth: " + path("t.csv") + ")"), std::string::npos) << told.output;
  EXPECT_FALSE(fs::exists(path("w.lcmlog.truth.csv")));
  const std::string truth = read("t.csv");
  EXPECT_EQ(truth.rfind("seq,pixel_x,pixel_y,k_n_per_m,h_m\n", 0), 0u) << truth;
  EXPECT_EQ(std::count(truth.begin(), truth.end(), '\n'), 5) << truth;  // header and 4 pixels
  EXPECT_FALSE(first_window_samples("w.lcmlog").empty());

  const bool dev_null_truth_before = fs::exists("/dev/null.truth.csv");
  const Outcome dry = run(sim + " --out /dev/null");
  EXPECT_EQ(dry.status, 0) << dry.output;
  EXPECT_NE(dry.output.find("to /dev/null (truth: /dev/null)"), std::string::npos) << dry.output;
  if (!dev_null_truth_before) {
    EXPECT_FALSE(fs::exists("/dev/null.truth.csv"));
  }

  ASSERT_EQ(::mkfifo(path("fifo").c_str(), 0600), 0);
  const Outcome fifo = run(sim + " --out " + path("fifo"));
  EXPECT_EQ(fifo.status, 2) << fifo.output;
  EXPECT_NE(fifo.output.find(path("fifo") + ": --out is not a regular file, so there is no OUT.truth.csv beside it: "
                                           "name the truth table with --truth"),
            std::string::npos)
      << fifo.output;

  const Outcome unwritable = run(sim + " --out " + path("u.lcmlog") + " --truth " + path("no_such_dir/t.csv"));
  EXPECT_EQ(unwritable.status, 1) << unwritable.output;
  EXPECT_NE(unwritable.output.find(path("no_such_dir/t.csv") + ": cannot open the truth table for writing"),
            std::string::npos)
      << unwritable.output;
  EXPECT_FALSE(fs::exists(path("u.lcmlog")));  // refused before the log was created

  const Outcome same = run(sim + " --out " + path("x.lcmlog") + " --truth " + path("./x.lcmlog"));
  EXPECT_EQ(same.status, 2) << same.output;
  EXPECT_NE(same.output.find("--truth is --out"), std::string::npos) << same.output;
  const Outcome over = run(sim + " --out " + path("y.lcmlog") + " --truth " + config);
  EXPECT_EQ(over.status, 2) << over.output;
  EXPECT_NE(over.output.find("--truth " + config + " is the config"), std::string::npos) << over.output;
  EXPECT_EQ(read("c.toml"), kGoodConfig);
}

// A steady start runs in for six decay times of mode 1. With a high Q (the config allows up to
// 1e7) that ran for minutes or overflowed the sample count; it now stops after 2000 drive periods
// and says how much of the transient is left. At 1e-10 s sampling (6 decay times are 7.5e7
// samples: it hung) the run-in is sampled coarser, and lands where a run-in at the scan's own
// sampling (1e-8 s, 7.5e5 samples) does.
TEST_F(Cli, SimulateBoundsTheSteadyRunIn) {
  std::string text = read("scan.toml");
  text.replace(text.find("noise_m = 0.1e-9"), 16, "noise_m = 0");
  text.replace(text.find("samples_per_window = 1250"), 25, "samples_per_window = 100");
  std::string high_q = kGoodConfig;
  high_q.replace(high_q.find("quality_factor = 100"), 20, "quality_factor = 1e6");
  high_q.replace(high_q.find("modes = 8"), 9, "modes = 2");
  const Outcome capped = run("simulate --config " + write("q.toml", high_q) + " --probe tip1 --scan " +
                             write("s.toml", text) + " --out " + path("q.lcmlog"));
  EXPECT_EQ(capped.status, 0) << capped.output;
  EXPECT_NE(capped.output.find("the run-in stops after 2000 drive periods"), std::string::npos) << capped.output;
  EXPECT_NE(capped.output.find("so the first windows still carry 0.99 of the start's transient"), std::string::npos)
      << capped.output;

  const std::string config = write("c.toml", kGoodConfig);
  auto first_sample = [&](const std::string& period) {
    std::string t = text;
    t.replace(t.find("sample_period_s = 1e-7"), 22, "sample_period_s = " + period);
    const Outcome r = run("simulate --config " + config + " --probe tip1 --scan " + write("p.toml", t) + " --out " +
                          path("p.lcmlog"));
    EXPECT_EQ(r.status, 0) << r.output;
    const std::vector<float> w = first_window_samples("p.lcmlog");
    return w.empty() ? NAN : static_cast<double>(w[0]);
  };
  const double fine = first_sample("1e-8"), coarse = first_sample("1e-10");
  EXPECT_GT(std::abs(fine), 1e-9);
  EXPECT_NEAR(coarse, fine, 1e-4 * 30e-9);
}

// The other side of samples_per_window's lower bound: a scan of the shortest windows simulate
// writes is one that tipforce invert answers, none rejected for its length.
TEST_F(Cli, SimulateAtTheShortestWindowWritesWindowsInvertAccepts) {
  const std::string config = write("c.toml", kGoodConfig);
  std::string text = read("scan.toml");
  text.replace(text.find("samples_per_window = 1250"), 25, "samples_per_window = 8");
  const std::string scan = write("short.toml", text);
  const Outcome sim = run("simulate --config " + config + " --probe tip1 --scan " + scan + " --out " + path("w.lcmlog"));
  ASSERT_EQ(sim.status, 0) << sim.output;
  EXPECT_NE(sim.output.find("wrote 4 windows of 8 samples"), std::string::npos) << sim.output;
  const Outcome inv = run("invert --config " + config + " --in " + path("w.lcmlog") + " --out " + path("e.lcmlog"));
  EXPECT_EQ(inv.status, 0) << inv.output;
  EXPECT_NE(inv.output.find("windows 4,"), std::string::npos) << inv.output;
  EXPECT_NE(inv.output.find("rejected 0 "), std::string::npos) << inv.output;
}

TEST_F(Cli, InvertAnswersAMalformedWindowWithRejectionAndCarriesOn) {
  const std::string config = write("c.toml", kGoodConfig);
  ASSERT_EQ(run("simulate --config " + config + " --probe tip1 --scan " + path("scan.toml") + " --out " + path("w.lcmlog")).status, 0);
  // Rewrite the scan with bad windows in between the good ones.
  std::vector<std::vector<uint8_t>> events;
  {
    lcm::LogFile in(path("w.lcmlog"), "r");
    while (const lcm::LogEvent* ev = in.readNextEvent())
      events.emplace_back(static_cast<const uint8_t*>(ev->data), static_cast<const uint8_t*>(ev->data) + ev->datalen);
  }
  ASSERT_EQ(events.size(), 4u);
  tipforce::deflection_window_t nan_window;
  ASSERT_GT(nan_window.decode(events[1].data(), 0, static_cast<int>(events[1].size())), 0);
  nan_window.seq = 100;
  nan_window.deflection_m[10] = std::nanf("");
  std::vector<uint8_t> nan_bytes(static_cast<std::size_t>(nan_window.getEncodedSize()));
  nan_window.encode(nan_bytes.data(), 0, static_cast<int>(nan_bytes.size()));
  const std::vector<uint8_t> garbage = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12};
  {
    lcm::LogFile out(path("mixed.lcmlog"), "w");
    int64_t n = 0;
    for (const std::vector<uint8_t>* bytes : std::vector<const std::vector<uint8_t>*>{&events[0], &nan_bytes, &garbage, &events[1], &events[2]}) {
      lcm::LogEvent ev;
      ev.eventnum = n;
      ev.timestamp = n++;
      ev.channel = "TIPFORCE_WINDOW";
      ev.datalen = static_cast<int32_t>(bytes->size());
      ev.data = const_cast<uint8_t*>(bytes->data());
      out.writeEvent(&ev);
    }
  }
  const Outcome r = run("invert --config " + config + " --in " + path("mixed.lcmlog") + " --out " + path("est.lcmlog"));
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("rejected 2 (unattributable 1)"), std::string::npos) << r.output;
  std::vector<tipforce::force_estimate_t> est;
  lcm::LogFile in(path("est.lcmlog"), "r");
  while (const lcm::LogEvent* ev = in.readNextEvent()) {
    tipforce::force_estimate_t e;
    ASSERT_GT(e.decode(ev->data, 0, ev->datalen), 0);
    est.push_back(e);
  }
  ASSERT_EQ(est.size(), 4u) << "garbage is counted, every attributable window answered";
  EXPECT_EQ(est[1].seq, 100);
  EXPECT_EQ(est[1].status, tipforce::force_estimate_t::STATUS_REJECTED);
  EXPECT_NE(est[1].message.find("not finite"), std::string::npos) << est[1].message;
  for (int i : {0, 2, 3}) {
    EXPECT_NE(est[i].status, tipforce::force_estimate_t::STATUS_REJECTED) << est[i].message;
    ASSERT_EQ(est[i].n_params, 2);
    const int k = est[i].param_names[0] == "k_n_per_m" ? 0 : 1, h = 1 - k;
    ASSERT_EQ(est[i].param_names[static_cast<std::size_t>(h)], "h_m");
    // Within 3 sigma plus 2 %: the first window's start is estimated, not known.
    EXPECT_NEAR(est[i].params[k], 4.0, 3 * est[i].param_sigma[k] + 0.08) << "k of window " << est[i].seq;
    EXPECT_NEAR(est[i].params[h], 30e-9, 3 * est[i].param_sigma[h] + 0.6e-9) << "h of window " << est[i].seq;
  }
}

TEST_F(Cli, InvertRefusesAFileThatHoldsNoWindows) {
  const std::string config = write("c.toml", kGoodConfig);
  const std::string not_a_log = write("notes.txt", "this is not an LCM log\n");
  const Outcome r = run("invert --config " + config + " --in " + not_a_log + " --out " + path("o.lcmlog"));
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.output.find(not_a_log + ": no windows on channel TIPFORCE_WINDOW"), std::string::npos) << r.output;
}

// A log cut short inside its first window holds no intact window, but it is a damaged log, not
// an empty one: the damage is reported with its offset and the exit is 3, as tipforced's (it was
// "no windows on channel", exit 2).
TEST_F(Cli, InvertReportsALogDamagedFromItsFirstWindow) {
  const std::string config = write("c.toml", kGoodConfig);
  ASSERT_EQ(run("simulate --config " + config + " --probe tip1 --scan " + path("scan.toml") + " --out " + path("w.lcmlog")).status, 0);
  std::string bytes;
  {
    std::ifstream in(path("w.lcmlog"), std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_GT(bytes.size(), 4000u);  // 4 windows of 1250 floats: the first event alone is over 5000 bytes
  std::ofstream(path("cut.lcmlog"), std::ios::binary) << bytes.substr(0, 1000);
  const Outcome r = run("invert --config " + config + " --in " + path("cut.lcmlog") + " --out " + path("est.lcmlog"));
  EXPECT_EQ(r.status, 3) << r.output;
  EXPECT_NE(r.output.find(path("cut.lcmlog") + ": skipped 1000 damaged bytes at offset 0"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("no windows on channel"), std::string::npos) << r.output;
}

// Every window rejected (here: a config without the windows' probe): no solve latency to report
// ("p50 nan us" was printed) and no estimate to use, so not exit 0.
TEST_F(Cli, InvertWithEveryWindowRejectedSaysNoneWasSolved) {
  const std::string good = write("c.toml", kGoodConfig);
  ASSERT_EQ(run("simulate --config " + good + " --probe tip1 --scan " + path("scan.toml") + " --out " + path("w.lcmlog")).status, 0);
  std::string other = kGoodConfig;
  other.replace(other.find("[probe.tip1]"), 12, "[probe.tip2]");
  const std::string config = write("other.toml", other);
  const Outcome r = run("invert --config " + config + " --in " + path("w.lcmlog") + " --out " + path("est.lcmlog"));
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("rejected 4 (unattributable 0)"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("no window solved"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("every one of the 4 windows was rejected"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("nan"), std::string::npos) << r.output;
}

// The README promises exit 2 for a bad command line; CLI11's own codes (105 validation, 106
// required, 109 extra arguments, 104 conversion) leaked through. Its message is still printed.
TEST_F(Cli, UsageErrorsExitTwoWithCli11sMessage) {
  const std::string config = write("c.toml", kGoodConfig);
  const std::map<std::string, std::string> usage = {
      {"", "A subcommand is required"},
      {"invert --config " + config + " --out " + path("o.lcmlog"), "--in is required"},
      {"invert --config " + config + " --in " + path("none.lcmlog") + " --out " + path("o.lcmlog"),
       "--in: File does not exist: " + path("none.lcmlog")},
      {"modes --config " + config + " --probe tip1 surplus", "The following argument was not expected: surplus"},
      {"map --in a.lcmlog --out m --scan-size-m wide", "Could not convert: --scan-size-m = wide"},
      {"invert --config " + config + " --in " + config + " --out " + path("o.lcmlog") + " --backend gpu",
       "--backend: gpu not in {auto,cpu,cuda}"},
      {"invert --config " + config + " --in " + config + " --out " + path("o.lcmlog") + " --shard 3",
       "--shard: expected I/N"},
      {"no-such-command", "A subcommand is required"},
  };
  for (const auto& [args, message] : usage) {
    const Outcome r = run(args);
    EXPECT_EQ(r.status, 2) << args << "\n" << r.output;
    EXPECT_NE(r.output.find(message), std::string::npos) << args << "\n" << r.output;
  }
  for (const std::string help : {"--help", "invert --help", "--version"}) EXPECT_EQ(run(help).status, 0) << help;
}

TEST_F(Cli, ModesJsonHasThePaperCantilever) {
  const Outcome r = run("modes --json --config " + write("c.toml", kGoodConfig) + " --probe tip1");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("\"modes\": [{\"frequency_hz\": 25468.89"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("\"static_stiffness_n_per_m\": 1.3303"), std::string::npos) << r.output;
  EXPECT_NE(run("modes --config " + path("c.toml") + " --probe nope").status, 0);
}

}  // namespace
