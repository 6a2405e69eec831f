// tipforce_setpoint_controller: an example controller for tipforced's setpoint advisor (issue 13;
// README "Closing the loop", tools/examples/setpoint_controller/README.md).
//
// In:  setpoint_command_t on --setpoint-channel (TIPFORCE_SETPOINT), for one probe.
// Out: the setpoints the instrument should use from the next pixel on. Here an
//      instrument_setpoint_t on --instrument-channel (TIPFORCE_INSTRUMENT), which the simulated
//      microscope (`tipforce simulate --live`) obeys; one for every command, so that it can keep
//      in lock-step. A lab replaces LcmInstrument with a call to its instrument's own interface.
//
// The decisions are ControllerPolicy's (controller_policy.hpp): rate limits, hysteresis, ranges.
#include <csignal>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>
#include <lcm/lcm-cpp.hpp>

#include "controller_policy.hpp"
#include "tipforce/instrument_setpoint_t.hpp"
#include "tipforce/setpoint_command_t.hpp"

namespace {

volatile std::sig_atomic_t g_stop = 0;
void on_signal(int) { g_stop = 1; }

std::int64_t now_utime() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000 + ts.tv_nsec / 1000;
}

// Where decisions go. Adapt this to the instrument.
class Instrument {
 public:
  virtual ~Instrument() = default;
  // Called for every command answered; decision.action says whether anything changed.
  virtual bool apply(const tipforce_example::Decision& decision, const tipforce::setpoint_command_t& answered) = 0;
};

// The simulated microscope's interface: one instrument_setpoint_t per command.
class LcmInstrument : public Instrument {
 public:
  LcmInstrument(lcm::LCM& lcm, std::string channel) : lcm_(lcm), channel_(std::move(channel)) {}
  bool apply(const tipforce_example::Decision& d, const tipforce::setpoint_command_t& c) override {
    tipforce::instrument_setpoint_t m;
    m.utime = now_utime();
    m.probe = c.probe;
    m.seq = c.seq;
    m.free_amplitude_m = d.setpoints.free_amplitude_m;
    m.z_offset_m = d.setpoints.z_offset_m;
    m.action = static_cast<std::int8_t>(d.action);
    m.reason = d.reason;
    return lcm_.publish(channel_, &m) == 0;
  }

 private:
  lcm::LCM& lcm_;
  std::string channel_;
};

class Controller {
 public:
  Controller(tipforce_example::ControllerOptions options, std::string probe, Instrument& instrument, std::ostream* csv)
      : policy_(options), probe_(std::move(probe)), instrument_(instrument), csv_(csv) {
    if (csv_) *csv_ << "seq,status,action,free_amplitude_m,z_offset_m,reason\n";
  }

  void on_command(const lcm::ReceiveBuffer*, const std::string&, const tipforce::setpoint_command_t* c) {
    if (c->probe != probe_) return;
    const tipforce_example::Decision d = policy_.on_command(*c);
    if (!instrument_.apply(d, *c)) {
      ++errors_;
      std::cerr << "setpoint_controller: could not send the setpoints for seq " << c->seq << "\n";
    }
    ++commands_;
    if (d.action != tipforce_example::Action::hold) {
      ++changes_;
      std::cerr << "setpoint_controller: seq " << c->seq << ": " << d.reason << " -> free amplitude "
                << d.setpoints.free_amplitude_m * 1e9 << " nm, z offset " << d.setpoints.z_offset_m * 1e9 << " nm\n";
    }
    if (csv_) {
      *csv_ << c->seq << "," << static_cast<int>(c->status) << "," << static_cast<int>(d.action) << ","
            << d.setpoints.free_amplitude_m << "," << d.setpoints.z_offset_m << ",\"" << d.reason << "\"\n";
      csv_->flush();
    }
  }

  long commands() const { return commands_; }
  long changes() const { return changes_; }
  long errors() const { return errors_; }

 private:
  tipforce_example::ControllerPolicy policy_;
  std::string probe_;
  Instrument& instrument_;
  std::ostream* csv_;
  long commands_ = 0, changes_ = 0, errors_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Example setpoint controller for tipforced's advisor: rate limits, hysteresis, ranges"};
  tipforce_example::ControllerOptions o;
  std::string url, probe, setpoint_channel = "TIPFORCE_SETPOINT", instrument_channel = "TIPFORCE_INSTRUMENT", csv_path;
  app.add_option("--lcm-url", url, "LCM URL (default: LCM's)");
  app.add_option("--probe", probe, "Probe whose commands to follow")->required();
  app.add_option("--setpoint-channel", setpoint_channel, "Advisor's channel");
  app.add_option("--instrument-channel", instrument_channel, "Where the setpoints go (the simulated microscope)");
  app.add_option("--free-amplitude-m", o.nominal_free_amplitude_m,
                 "Nominal free amplitude (m); the controller never goes above it (default: the first command's)");
  app.add_option("--min-free-amplitude-m", o.min_free_amplitude_m, "Lowest free amplitude allowed (m; 0: keep the nominal)");
  app.add_option("--max-retract-m", o.max_retract_m, "Largest z offset from the nominal separation (m)")->check(CLI::NonNegativeNumber);
  app.add_option("--max-z-step-m", o.max_z_step_m, "Largest retraction per command (m)")->check(CLI::NonNegativeNumber);
  app.add_option("--max-amplitude-step-m", o.max_amplitude_step_m, "Largest amplitude reduction per command (m)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--relax-z-step-m", o.relax_z_step_m, "Approach per command when under the limit (m)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--relax-amplitude-step-m", o.relax_amplitude_step_m, "Amplitude increase per command when relaxing (m)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--relax-after", o.relax_after, "Commands under the limit in a row before relaxing")->check(CLI::NonNegativeNumber);
  app.add_option("--relax-band", o.relax_band, "Relax only while the prediction stays under (1 - band) x aim")
      ->check(CLI::Range(0.0, 0.9));
  app.add_option("--sigma-multiplier", o.sigma_multiplier, "Sigmas added to the prediction when relaxing")
      ->check(CLI::Range(0.0, 10.0));
  app.add_option("--dead-pixels", o.dead_pixels, "Windows after a change acquired before it took effect (loop latency)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--csv", csv_path, "Write every decision to this CSV file");
  CLI11_PARSE(app, argc, argv);

  lcm::LCM lcm(url);
  if (!lcm.good()) {
    std::cerr << "setpoint_controller: cannot open LCM \"" << url << "\"\n";
    return 1;
  }
  std::unique_ptr<std::ofstream> csv;
  if (!csv_path.empty()) {
    csv = std::make_unique<std::ofstream>(csv_path);
    if (!*csv) {
      std::cerr << "setpoint_controller: cannot write " << csv_path << "\n";
      return 2;
    }
  }
  LcmInstrument instrument(lcm, instrument_channel);
  Controller controller(o, probe, instrument, csv.get());
  lcm::Subscription* sub = lcm.subscribe(setpoint_channel, &Controller::on_command, &controller);
  if (sub == nullptr) {
    std::cerr << "setpoint_controller: cannot subscribe to " << setpoint_channel << "\n";
    return 1;
  }
  sub->setQueueCapacity(1024);
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  std::cerr << "setpoint_controller: following probe '" << probe << "' on " << setpoint_channel << ", setpoints to "
            << instrument_channel << "\n";
  while (!g_stop)
    if (lcm.handleTimeout(100) < 0 && !g_stop) {  // a stop signal interrupts the wait: not a failure
      std::cerr << "setpoint_controller: LCM failed\n";
      return 1;
    }
  std::cerr << "setpoint_controller: " << controller.commands() << " commands, " << controller.changes()
            << " changes, " << controller.errors() << " send errors\n";
  return controller.errors() > 0 ? 1 : 0;
}
