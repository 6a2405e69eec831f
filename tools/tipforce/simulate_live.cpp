// `tipforce simulate --live`: the simulated microscope of the closed-loop example (issue 13).
//
// The instrument model: two setpoints, the free amplitude A (the drive amplitude is A divided by
// the free cantilever's response at the drive frequency) and a z offset from the scan's nominal
// separation. Its z feedback is modelled as ideal height tracking: each pixel's separation is
// the scan's truth h (the topography) plus the z offset, exactly and at once. An amplitude
// feedback, which moves z to hold the tapping amplitude, is not modelled. Setpoints received in
// answer to window n apply from window n + 1 on, as a step at the window's first sample; the
// cantilever's own response to them (its ring-up over 2Q/omega) is in the simulation.
#include "simulate_live.hpp"

#include <chrono>
#include <cmath>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <random>

#include <CLI/CLI.hpp>
#include <lcm/lcm-cpp.hpp>

#include "tipforce/deflection_window_t.hpp"
#include "tipforce/force_estimate_t.hpp"
#include "tipforce/instrument_setpoint_t.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/setpoint_advisor.hpp"

namespace tipforce::cli {
namespace {

[[noreturn]] void fail(int code, const std::string& what) {
  std::cerr << "tipforce simulate --live: " << what << "\n";
  throw CLI::RuntimeError(code);
}

// What came back for each window, by seq.
class Answers {
 public:
  explicit Answers(std::string probe) : probe_(std::move(probe)) {}
  void on_estimate(const lcm::ReceiveBuffer*, const std::string&, const force_estimate_t* e) {
    if (e->probe == probe_) estimates_[e->seq] = e->status;
  }
  void on_setpoint(const lcm::ReceiveBuffer*, const std::string&, const instrument_setpoint_t* s) {
    if (s->probe == probe_) setpoints_[s->seq] = *s;
  }
  bool has_estimate(std::int64_t seq) const { return estimates_.count(seq) > 0; }
  const instrument_setpoint_t* setpoint(std::int64_t seq) const {
    auto it = setpoints_.find(seq);
    return it == setpoints_.end() ? nullptr : &it->second;
  }

 private:
  std::string probe_;
  std::map<std::int64_t, int> estimates_;
  std::map<std::int64_t, instrument_setpoint_t> setpoints_;
};

struct PixelTruth {
  double peak_force_n = 0, max_indentation_m = 0, tapping_amplitude_m = 0;
};

PixelTruth pixel_truth(const ProbeModel& probe, const std::vector<double>& full, const ReferenceResult& r) {
  PixelTruth t;
  const ForceParams fp = force_params_from(probe.space.model(), std::span<const double>(full.data(),
                                                  static_cast<std::size_t>(ParameterLayout(probe.space.model()).n_model())));
  double lo = INFINITY, hi = -INFINITY;
  for (std::size_t n = 0; n < r.signal.size(); ++n) {
    t.peak_force_n = std::max(t.peak_force_n, -r.force_n[n]);
    t.max_indentation_m = std::max(t.max_indentation_m, indentation_m(probe.space.model(), fp, r.tip_z_m[n]));
    lo = std::min(lo, r.signal[n]);
    hi = std::max(hi, r.signal[n]);
  }
  t.tapping_amplitude_m = 0.5 * (hi - lo);
  return t;
}

}  // namespace

void run_live_simulation(const LiveOptions& o, const ProbeModel& probe, const Scan& scan, const ScanTruth& truth) {
  if (scan.drive.kind != DriveKind::sine) fail(2, o.config_path + ": --live needs a sine drive (a free amplitude)");
  const ParameterLayout layout(probe.space.model());
  const int h_index = probe.space.index_of("h_m");
  if (h_index < 0) fail(2, "the model has no separation h_m for a z offset");
  const int amplitude_index = layout.drive_index(DriveParameter::amplitude_m);
  const double gain = free_amplitude_per_drive_amplitude(probe.modal, scan.drive.frequency_hz);

  lcm::LCM lcm(o.lcm_url);
  if (!lcm.good()) fail(1, "cannot open LCM \"" + o.lcm_url + "\"");
  Answers answers(o.probe);
  const bool closed_loop = o.lockstep == "instrument";
  if (closed_loop)
    lcm.subscribe(o.instrument_channel, &Answers::on_setpoint, &answers)->setQueueCapacity(1024);
  else
    lcm.subscribe(o.estimate_channel, &Answers::on_estimate, &answers)->setQueueCapacity(1024);

  std::ofstream csv(o.truth_csv);
  if (!csv) fail(1, o.truth_csv + ": cannot be written");
  csv << "seq,pixel_x,pixel_y";
  for (const auto& n : truth.names()) csv << "," << n;
  csv << ",free_amplitude_m,drive_amplitude_m,z_offset_m,separation_m,peak_force_n,max_indentation_m,"
         "tapping_amplitude_m,action\n";
  csv.precision(10);

  const int N = scan.samples_per_window;
  const double dt = scan.sample_period_s;
  const int pixels = scan.pixels_x * scan.pixels_y;
  double free_amplitude_m = scan.drive.amplitude_m * gain, z_offset_m = 0;
  int action = -1;  // none received yet
  std::mt19937_64 rng(scan.seed);
  std::normal_distribution<double> noise(0.0, scan.noise_m > 0 ? scan.noise_m : 1.0);
  ModalState state = scan_start_state(scan, probe, truth.full_at(0));
  const std::int64_t utime0 = lcmio::now_utime();
  const auto timeout = std::chrono::duration<double>(o.timeout_s);
  double max_peak_n = 0;
  std::vector<std::uint8_t> buf;
  for (int px = 0; px < pixels; ++px) {
    std::vector<double> full = truth.full_at(px);
    full[static_cast<std::size_t>(h_index)] += z_offset_m;
    full[static_cast<std::size_t>(amplitude_index)] = free_amplitude_m / gain;
    Window w;
    w.drive = scan.drive;
    w.drive.amplitude_m = free_amplitude_m / gain;
    w.sample_period_s = dt;
    w.t0_s = static_cast<double>(px) * N * dt;
    w.deflection_m.assign(static_cast<std::size_t>(N), 0.0);
    w.initial = scan_initial_state(scan, px);
    const ReferenceResult r = reference_simulate(probe.modal, probe.space.model(), w, full, state);
    state = r.end_state;
    for (int i = 0; i < N; ++i) w.deflection_m[static_cast<std::size_t>(i)] = r.signal[static_cast<std::size_t>(i)] + (scan.noise_m > 0 ? noise(rng) : 0.0);
    const PixelTruth t = pixel_truth(probe, full, r);
    max_peak_n = std::max(max_peak_n, t.peak_force_n);

    lcmio::WindowHeader h;
    h.probe = o.probe;
    h.seq = px;
    h.pixel_x = px % scan.pixels_x;
    h.pixel_y = px / scan.pixels_x;
    h.utime = utime0 + static_cast<std::int64_t>(std::llround(w.t0_s * 1e6));
    const deflection_window_t msg = lcmio::to_message(h, w);
    buf.resize(static_cast<std::size_t>(msg.getEncodedSize()));
    msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
    if (lcm.publish(o.channel, buf.data(), static_cast<unsigned>(buf.size())) != 0)
      fail(1, "could not publish window " + std::to_string(px) + " on " + o.channel);

    csv << px << "," << h.pixel_x << "," << h.pixel_y;
    for (const auto& n : truth.names()) csv << "," << truth.value(n, px);
    csv << "," << free_amplitude_m << "," << free_amplitude_m / gain << "," << z_offset_m << ","
        << full[static_cast<std::size_t>(h_index)] << "," << t.peak_force_n << "," << t.max_indentation_m << ","
        << t.tapping_amplitude_m << "," << action << "\n";
    if (!csv) fail(1, o.truth_csv + ": write failed");

    // Lock-step: the next pixel waits for this one's answer.
    const auto start = std::chrono::steady_clock::now();
    while (closed_loop ? answers.setpoint(px) == nullptr : !answers.has_estimate(px)) {
      if (std::chrono::steady_clock::now() - start > timeout)
        fail(1, "no " + std::string(closed_loop ? "instrument_setpoint_t on " + o.instrument_channel
                                                : "force_estimate_t on " + o.estimate_channel) +
                    " for window " + std::to_string(px) + " within " + std::to_string(o.timeout_s) + " s");
      if (lcm.handleTimeout(50) < 0) fail(1, "LCM failed while waiting for answers");
    }
    if (const instrument_setpoint_t* s = closed_loop ? answers.setpoint(px) : nullptr) {
      if (!(s->free_amplitude_m > 0) || !std::isfinite(s->free_amplitude_m) || !std::isfinite(s->z_offset_m))
        fail(1, "window " + std::to_string(px) + ": unusable setpoints (free amplitude " +
                    std::to_string(s->free_amplitude_m) + " m, z offset " + std::to_string(s->z_offset_m) + " m)");
      free_amplitude_m = s->free_amplitude_m;
      z_offset_m = s->z_offset_m;
      action = s->action;
    }
  }
  csv.flush();
  if (!csv) fail(1, o.truth_csv + ": write failed");
  std::cout << "simulated " << pixels << " windows of " << N << " samples in lock-step ("
            << (closed_loop ? "closed loop, setpoints from " + o.instrument_channel : std::string("open loop"))
            << "); largest true peak force " << max_peak_n * 1e9 << " nN; truth in " << o.truth_csv << "\n";
}

}  // namespace tipforce::cli
