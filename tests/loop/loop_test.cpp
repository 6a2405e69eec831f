// Closing the loop (issue 13), end to end over LCM inside a private network namespace: the
// simulated microscope (`tipforce simulate --live`, reference integrator) scans one line across
// soft (1 N/m) and hard (10 N/m) domains, tipforced fits every window and, with an advisor
// table, answers it with a setpoint_command_t, and the example controller turns those into the
// microscope's setpoints for the next pixel. Once open loop (no advisor, no controller: the
// microscope waits for each estimate), once closed. The truth is the reference integrator's peak
// force per pixel, which nothing in the loop sees.
//
// The acceptance of issue 13 is checked on those two runs (one ctest entry, the runs are shared):
// open loop over the limit on the hard domains; closed loop under it on >= 95 % of pixels, back
// under within 3 pixels of each soft-to-hard step, the setpoints within the user's range; and the
// advisor's prediction after a correction within 2 sigma of the simulated peak force for >= 90 %
// of corrections. The data and the figure go to $LOOP_OUT (README "Closing the loop").
// $LOOP_SEED (default 3) changes the detection noise's seed, to see the spread of the results.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include <lcm/lcm-cpp.hpp>

#include "loop_plot.hpp"
#include "testlib.hpp"
#include "tipforce/setpoint_advisor.hpp"
#include "tipforce/setpoint_command_t.hpp"
#include "tipforce/tipforce.hpp"

namespace {

namespace fs = std::filesystem;
using tipforce::setpoint_command_t;

constexpr const char* kUrl = "udpm://239.255.76.67:7667?ttl=0";

// The scan line: domains of (pixels, k in N/m), flat (h the same everywhere).
const std::vector<std::pair<int, double>> kDomains{{64, 1.0}, {32, 10.0}, {64, 1.0}, {32, 10.0}, {64, 1.0}};
// 1000 samples at 5 MHz (200 us, five periods of the drive): the windows invert in a few ms here;
// at the demo's 400 samples the soft domain's stiffness is so uncertain (sigma ~50 %) that the
// advisor's 2-sigma aim retracts there too.
constexpr int kSamples = 1000;
constexpr double kSamplePeriodS = 2e-7;
constexpr double kNoiseM = 5e-11;          // 50 pm rms detection noise
constexpr double kFreeAmplitudeM = 20e-9;  // the user's imaging amplitude
constexpr double kSeparationM = 16e-9;     // nominal h: 0.8 of the free amplitude
constexpr double kLimitN = 2e-9;           // steady tapping: ~1 nN on the soft domain, 2.3-2.6 nN on the hard one
constexpr double kMinFreeAmplitudeM = 18e-9;
constexpr double kMaxRetractM = 6e-9;
constexpr double kDriveHz = 25468.9;

std::string num(double v) {
  std::ostringstream o;
  o.precision(17);
  o << v;
  return o.str();
}

std::string env_or_skip(const char* name) {
  const char* v = std::getenv(name);
  return v ? std::string(v) : std::string();
}

std::string probe_section() {
  return "[probe.afm1]\n"
         "length_m = 525e-6\nwidth_m = 35e-6\nthickness_m = 5e-6\nyoungs_modulus_pa = 1.76e11\ndensity_kg_m3 = 2330\n"
         "quality_factor = 100\nmodes = 3\nmodel = \"spring\"\n"
         "unknowns = { k_n_per_m = [0.5, 20.0], h_m = [5e-9, 30e-9] }\n"
         "[probe.afm1.inversion]\nswarm_size = 24\nmax_generations = 25\n";
}

std::string config_text(bool advisor) {
  std::ostringstream s;
  s << "[daemon]\nbackend = \"cpu\"\ncpu_threads = 1\nstats_period_s = 1.0\nqueue_capacity = 64\n\n" << probe_section();
  if (advisor)
    s << "[probe.afm1.advisor]\nmax_peak_force_n = " << kLimitN << "\n"
      << "min_free_amplitude_m = " << kMinFreeAmplitudeM << "\nmax_z_step_m = 2e-9\n";
  return s.str();
}

int line_pixels() {
  int n = 0;
  for (const auto& [count, k] : kDomains) n += count;
  return n;
}
double k_at(int pixel) {
  for (const auto& [count, k] : kDomains) {
    if (pixel < count) return k;
    pixel -= count;
  }
  return kDomains.back().second;
}

void write_scan(const fs::path& dir, double drive_amplitude_m) {
  std::ofstream k(dir / "line_k.csv");
  for (int i = 0; i < line_pixels(); ++i) k << (i ? "," : "") << k_at(i);
  k << "\n";
  std::ofstream s(dir / "line.toml");
  s.precision(12);
  s << "sample_period_s = " << kSamplePeriodS << "\nsamples_per_window = " << kSamples << "\npixels_x = "
    << line_pixels() << "\npixels_y = 1\nstart = \"steady\"\nnoise_m = " << kNoiseM << "\nseed = " << (std::getenv("LOOP_SEED") ? std::getenv("LOOP_SEED") : "3") << "\n"
    << "[drive]\nkind = \"sine\"\namplitude_m = " << drive_amplitude_m << "\nfrequency_hz = " << kDriveHz << "\n"
    << "[truth]\nk_n_per_m = \"line_k.csv\"\nh_m = " << kSeparationM << "\n";
}

struct Pixel {
  double k = 0, free_amplitude_m = 0, z_offset_m = 0, separation_m = 0, peak_force_n = 0, tapping_amplitude_m = 0;
};

std::vector<Pixel> read_truth(const fs::path& path) {
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  std::map<std::string, int> col;
  {
    std::stringstream ss(line);
    std::string name;
    for (int i = 0; std::getline(ss, name, ','); ++i) col[name] = i;
  }
  std::vector<Pixel> out;
  while (std::getline(in, line)) {
    std::vector<double> v;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) v.push_back(std::stod(cell));
    Pixel p;
    p.k = v.at(col.at("k_n_per_m"));
    p.free_amplitude_m = v.at(col.at("free_amplitude_m"));
    p.z_offset_m = v.at(col.at("z_offset_m"));
    p.separation_m = v.at(col.at("separation_m"));
    p.peak_force_n = v.at(col.at("peak_force_n"));
    p.tapping_amplitude_m = v.at(col.at("tapping_amplitude_m"));
    out.push_back(p);
  }
  return out;
}

// The advisor's commands as they go by (for the prediction check), on a thread of its own.
class CommandRecorder {
 public:
  CommandRecorder() : lcm_(kUrl) {
    lcm_.subscribe("TIPFORCE_SETPOINT", &CommandRecorder::on_command, this)->setQueueCapacity(4096);
    thread_ = std::thread([this] {
      while (running_) lcm_.handleTimeout(50);
    });
  }
  ~CommandRecorder() {
    running_ = false;
    thread_.join();
  }
  std::map<std::int64_t, setpoint_command_t> take() {
    std::lock_guard<std::mutex> lock(mutex_);
    return commands_;
  }

 private:
  void on_command(const lcm::ReceiveBuffer*, const std::string&, const setpoint_command_t* c) {
    std::lock_guard<std::mutex> lock(mutex_);
    commands_[c->seq] = *c;
  }
  lcm::LCM lcm_;
  std::atomic<bool> running_{true};
  std::thread thread_;
  std::mutex mutex_;
  std::map<std::int64_t, setpoint_command_t> commands_;
};

struct LoopRun {
  std::vector<Pixel> pixels;
  std::map<std::int64_t, setpoint_command_t> commands;
  double seconds = 0;
  std::string error;
};

LoopRun run_line(bool closed, const fs::path& dir) {
  LoopRun run;
  fs::create_directories(dir);
  tfdtest::write_text(dir / "tipforced.toml", config_text(closed));
  const tipforce::ProbeSpec spec = tipforce::paper_probe_spec(3);
  const double gain = tipforce::free_amplitude_per_drive_amplitude(tipforce::ModalModel(spec), kDriveHz);
  write_scan(dir, kFreeAmplitudeM / gain);

  tfdtest::LiveProcess daemon;
  if (!daemon.start(std::getenv("TIPFORCED"), dir, dir / "tipforced.toml", kUrl, "")) {
    run.error = "tipforced did not become ready: " + tfdtest::read_text(daemon.stderr_path);
    return run;
  }
  tfdtest::Child controller;
  std::unique_ptr<CommandRecorder> recorder;
  if (closed) {
    recorder = std::make_unique<CommandRecorder>();
    const fs::path log = dir / "controller.txt";
    controller = tfdtest::spawn({std::getenv("TIPFORCE_CONTROLLER"), "--lcm-url", kUrl, "--probe", "afm1",
                                 "--free-amplitude-m", num(kFreeAmplitudeM), "--min-free-amplitude-m",
                                 num(kMinFreeAmplitudeM), "--max-retract-m", num(kMaxRetractM),
                                 "--max-z-step-m", "2e-9", "--relax-z-step-m", "0.15e-9", 
                                 "--csv", (dir / "controller.csv").string()},
                                log);
    if (!tfdtest::wait_until([&] { return tfdtest::read_text(log).find("following probe") != std::string::npos; },
                             std::chrono::seconds(30))) {
      run.error = "the controller did not start: " + tfdtest::read_text(log);
      return run;
    }
  }
  const auto t0 = std::chrono::steady_clock::now();
  tfdtest::Child microscope =
      tfdtest::spawn({std::getenv("TIPFORCE_CLI"), "simulate", "--config", (dir / "tipforced.toml").string(), "--probe",
                      "afm1", "--scan", (dir / "line.toml").string(), "--live", "--lcm-url", kUrl, "--lockstep",
                      closed ? "instrument" : "estimate", "--timeout-s", "60", "--out", (dir / "truth.csv").string()},
                     dir / "microscope.txt");
  const auto code = microscope.wait(std::chrono::seconds(500));
  run.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (code != 0) {
    microscope.kill_and_reap();
    run.error = "the simulated microscope exited " + (code ? std::to_string(*code) : std::string("(timeout)")) + ": " +
                tfdtest::read_text(dir / "microscope.txt");
  }
  if (closed) {
    controller.signal(SIGTERM);
    if (controller.wait(std::chrono::seconds(10)) != 0) run.error += " controller did not stop cleanly";
    run.commands = recorder->take();
    std::ofstream csv(dir / "commands.csv");
    csv.precision(10);
    csv << "seq,status,free_amplitude_m,z_offset_m,predicted_peak_force_n,predicted_peak_force_sigma_n,"
           "hold_peak_force_n,hold_peak_force_sigma_n,dpeak_dz_n_per_m,dpeak_dfree_amplitude_n_per_m,separation_m,"
           "forward_solves,reason\n";
    for (const auto& [seq, c] : run.commands)
      csv << seq << "," << int(c.status) << "," << c.free_amplitude_m << "," << c.z_offset_m << ","
          << c.predicted_peak_force_n << "," << c.predicted_peak_force_sigma_n << "," << c.hold_peak_force_n << ","
          << c.hold_peak_force_sigma_n << "," << c.dpeak_dz_n_per_m << "," << c.dpeak_dfree_amplitude_n_per_m << ","
          << c.separation_m << "," << c.forward_solves << ",\"" << c.reason << "\"\n";
  }
  const auto [stopped, _] = daemon.stop();
  if (stopped != 0) run.error += " tipforced exit " + (stopped ? std::to_string(*stopped) : std::string("(killed)"));
  if (run.error.empty()) run.pixels = read_truth(dir / "truth.csv");
  return run;
}

std::vector<int> soft_to_hard_steps() {
  std::vector<int> steps;
  int start = 0;
  for (std::size_t d = 0; d < kDomains.size(); ++d) {
    if (d > 0 && kDomains[d].second > kDomains[d - 1].second) steps.push_back(start);
    start += kDomains[d].first;
  }
  return steps;
}

class ClosedLoop : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (env_or_skip("TIPFORCED").empty() || env_or_skip("TIPFORCE_CLI").empty() ||
        env_or_skip("TIPFORCE_CONTROLLER").empty())
      return;
    out_ = fs::path(env_or_skip("LOOP_OUT").empty() ? "loop_out" : env_or_skip("LOOP_OUT"));
    fs::remove_all(out_);
    open_ = new LoopRun(run_line(false, out_ / "open"));
    closed_ = new LoopRun(run_line(true, out_ / "closed"));
    std::printf("open loop: %zu pixels in %.1f s; closed loop: %zu pixels, %zu commands in %.1f s\n",
                open_->pixels.size(), open_->seconds, closed_->pixels.size(), closed_->commands.size(),
                closed_->seconds);
  }
  static void TearDownTestSuite() {
    delete open_;
    delete closed_;
  }
  void SetUp() override {
    if (open_ == nullptr) GTEST_SKIP() << "TIPFORCED, TIPFORCE_CLI or TIPFORCE_CONTROLLER not set";
    ASSERT_EQ(open_->error, "");
    ASSERT_EQ(closed_->error, "");
    ASSERT_EQ(open_->pixels.size(), static_cast<std::size_t>(line_pixels()));
    ASSERT_EQ(closed_->pixels.size(), static_cast<std::size_t>(line_pixels()));
  }
  static inline fs::path out_;
  static inline LoopRun* open_ = nullptr;
  static inline LoopRun* closed_ = nullptr;
};

TEST_F(ClosedLoop, OpenLoopTheTruePeakForceExceedsTheLimitOnTheHardDomains) {
  int hard = 0, over = 0;
  double max_soft = 0, max_hard = 0;
  for (const Pixel& p : open_->pixels) {
    if (p.k > 5) {
      ++hard;
      over += p.peak_force_n > kLimitN;
      max_hard = std::max(max_hard, p.peak_force_n);
    } else {
      max_soft = std::max(max_soft, p.peak_force_n);
    }
  }
  std::printf("open loop: %d of %d hard pixels over the %.2f nN limit (largest %.2f nN); soft pixels at most %.2f nN\n",
              over, hard, kLimitN * 1e9, max_hard * 1e9, max_soft * 1e9);
  EXPECT_GT(over, hard / 2) << "the hard domain must exceed the limit open loop for the test to mean anything";
}

TEST_F(ClosedLoop, ClosedLoopStaysUnderTheLimitOnAtLeast95PercentOfPixels) {
  int over = 0;
  std::string where;
  for (std::size_t i = 0; i < closed_->pixels.size(); ++i)
    if (closed_->pixels[i].peak_force_n > kLimitN) {
      ++over;
      where += " " + std::to_string(i);
    }
  const double under = 1.0 - static_cast<double>(over) / static_cast<double>(closed_->pixels.size());
  std::printf("closed loop: %.1f %% of %zu pixels under the limit; over at pixels%s\n", 100 * under,
              closed_->pixels.size(), where.c_str());
  EXPECT_GE(under, 0.95);
}

TEST_F(ClosedLoop, ClosedLoopComesBackUnderWithin3PixelsAfterEachSoftToHardStep) {
  for (int step : soft_to_hard_steps()) {
    int first_under = -1;
    for (int i = step; i < static_cast<int>(closed_->pixels.size()); ++i)
      if (closed_->pixels[static_cast<std::size_t>(i)].peak_force_n <= kLimitN) {
        first_under = i;
        break;
      }
    std::string later;
    for (int i = first_under + 1; i >= 0 && i < step + 32 && i < static_cast<int>(closed_->pixels.size()); ++i)
      if (closed_->pixels[static_cast<std::size_t>(i)].peak_force_n > kLimitN)
        later += " " + std::to_string(i) + " (" +
                 std::to_string(closed_->pixels[static_cast<std::size_t>(i)].peak_force_n * 1e9).substr(0, 4) + " nN)";
    std::printf("soft-to-hard step at pixel %d: %.2f nN there, under the limit again at pixel %d (%d pixels later); "
                "over it again later in the domain at%s\n",
                step, closed_->pixels[static_cast<std::size_t>(step)].peak_force_n * 1e9, first_under,
                first_under - step, later.empty() ? " no pixel" : later.c_str());
    EXPECT_GE(first_under, step);
    EXPECT_LE(first_under - step, 3) << "step at pixel " << step;
  }
}

TEST_F(ClosedLoop, ClosedLoopKeepsTheSetpointsInTheRangeTheUserAllows) {
  double a_lo = INFINITY, a_hi = 0, z_lo = INFINITY, z_hi = -INFINITY, tap_lo = INFINITY, tap_hi = 0;
  for (const Pixel& p : closed_->pixels) {
    a_lo = std::min(a_lo, p.free_amplitude_m);
    a_hi = std::max(a_hi, p.free_amplitude_m);
    z_lo = std::min(z_lo, p.z_offset_m);
    z_hi = std::max(z_hi, p.z_offset_m);
    tap_lo = std::min(tap_lo, p.tapping_amplitude_m);
    tap_hi = std::max(tap_hi, p.tapping_amplitude_m);
  }
  std::printf("closed loop: free amplitude %.3f-%.3f nm (allowed %.1f-%.1f), z offset %.3f-%.3f nm (allowed 0-%.1f), "
              "tapping amplitude %.2f-%.2f nm\n",
              a_lo * 1e9, a_hi * 1e9, kMinFreeAmplitudeM * 1e9, kFreeAmplitudeM * 1e9, z_lo * 1e9, z_hi * 1e9,
              kMaxRetractM * 1e9, tap_lo * 1e9, tap_hi * 1e9);
  EXPECT_GE(a_lo, kMinFreeAmplitudeM * (1 - 1e-9));
  EXPECT_LE(a_hi, kFreeAmplitudeM * (1 + 1e-9));
  EXPECT_GE(z_lo, 0.0);
  EXPECT_LE(z_hi, kMaxRetractM * (1 + 1e-9));
}

TEST_F(ClosedLoop, PredictedPeakForceAfterACorrectionMatchesTheSimulationWithin2SigmaFor90Percent) {
  int corrections = 0, applied = 0, within = 0, holds = 0, holds_within = 0;
  double worst = 0;
  const auto& px = closed_->pixels;
  for (const auto& [seq, c] : closed_->commands) {
    if (seq + 1 >= static_cast<std::int64_t>(px.size())) continue;
    const Pixel& now = px[static_cast<std::size_t>(seq)];
    const Pixel& next = px[static_cast<std::size_t>(seq + 1)];
    const bool correction =
        c.status == setpoint_command_t::STATUS_CORRECTION || c.status == setpoint_command_t::STATUS_OUT_OF_RANGE;
    const double tol = 1e-15;
    const bool as_asked = std::abs(next.z_offset_m - now.z_offset_m - c.z_offset_m) < tol &&
                          std::abs(next.free_amplitude_m - c.free_amplitude_m) < tol;
    const bool unchanged = next.z_offset_m == now.z_offset_m && next.free_amplitude_m == now.free_amplitude_m;
    const double miss = std::abs(c.predicted_peak_force_n - next.peak_force_n) / c.predicted_peak_force_sigma_n;
    if (correction) {
      ++corrections;
      if (!as_asked) continue;  // the controller's limits changed it: the prediction is for another setpoint
      ++applied;
      within += std::abs(c.predicted_peak_force_n - next.peak_force_n) <= 2 * c.predicted_peak_force_sigma_n;
      worst = std::max(worst, miss);
    } else if (c.status == setpoint_command_t::STATUS_UNDER_LIMIT && unchanged) {
      ++holds;
      holds_within += std::abs(c.hold_peak_force_n - next.peak_force_n) <= 2 * c.hold_peak_force_sigma_n;
    }
  }
  std::printf("corrections: %d, applied as asked %d, predicted within 2 sigma of the simulated peak force: %d "
              "(%.1f %%); holds: %d within 2 sigma of %d\n",
              corrections, applied, within, applied ? 100.0 * within / applied : 0.0, holds_within, holds);
  ASSERT_GT(applied, 20);
  EXPECT_GE(static_cast<double>(within) / applied, 0.90);
}

TEST_F(ClosedLoop, WritesThePeakForcePlotFromTheRuns) {
  std::vector<double> open, closed;
  std::vector<bool> hard;
  for (const Pixel& p : open_->pixels) {
    open.push_back(p.peak_force_n);
    hard.push_back(p.k > 5);
  }
  for (const Pixel& p : closed_->pixels) closed.push_back(p.peak_force_n);
  const fs::path png = out_ / "closing_the_loop_peak_force.png";
  tipforce::map::write_peak_force_per_pixel(
      png.string(), "true peak force per pixel: soft 1 N/m and hard 10 N/m domains, limit " + std::to_string(kLimitN * 1e9).substr(0, 4) + " nN",
      {{"open loop", open, tipforce::map::Rgb{49, 104, 142}}, {"advisor + example controller", closed, tipforce::map::Rgb{53, 183, 121}}},
      kLimitN, hard, "hard domain (10 N/m)");
  EXPECT_TRUE(fs::exists(png));
  EXPECT_GT(fs::file_size(png), 10000u);
  std::printf("wrote %s\n", png.c_str());
}

}  // namespace
