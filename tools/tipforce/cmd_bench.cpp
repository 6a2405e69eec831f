// `tipforce bench`: forward-solver throughput against odeint's RK4 measured in the same run, and
// inversion latency, as medians; a work-precision table (error against the reference beside the
// solves/s, per force model and sample period); GPU figures beside the CPU ones when a GPU works.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <iostream>
#include <random>
#include <stdexcept>

#include "bench_cases.hpp"
#include "cli_common.hpp"
#include "commands.hpp"
#include "tipforce/backend.hpp"
#include "tipforce/tipforce.hpp"

namespace tipforce::cli {
namespace {

using Clock = std::chrono::steady_clock;

Window sine_window(int n, double t0 = 0) {
  Window w;
  w.sample_period_s = 1e-7;
  w.t0_s = t0;
  w.drive.amplitude_m = 2e-9;
  w.drive.frequency_hz = 25600;
  w.deflection_m.assign(static_cast<std::size_t>(n), 0.0);
  return w;
}

// Median over repetitions of a rate (items / s).
double median_rate(int reps, double items, const std::function<void()>& fn) {
  std::vector<double> rates;
  for (int r = 0; r < reps; ++r) {
    const auto t0 = Clock::now();
    fn();
    rates.push_back(items / std::chrono::duration<double>(Clock::now() - t0).count());
  }
  return percentile(rates, 0.5);
}

// Solves/s of a case's batch (median over reps, after one untimed solve that also builds the step
// levels).
double batch_solves_per_s(ForwardBackend& backend, const bench::ForwardCase& c, int reps) {
  const ForwardProblem pb = c.problem();
  const ForwardBatch b = c.forward_batch();
  ForwardOutput out;
  backend.solve(pb, b, out);
  return median_rate(reps, c.batch(), [&] { backend.solve(pb, b, out); });
}

// Issue 8's setup (bench::issue8_tapping): the solves/s of a batch of 4096, and the worst
// relative L2 error against the reference of k 1, 2.5 and 4 N/m.
struct IssueCase {
  double solves_per_s = 0, worst_error = 0;
};
IssueCase issue_case(ForwardBackend& backend, int samples, double sample_period_s, int reps) {
  IssueCase r;
  for (double k : {1.0, 2.5, 4.0})
    r.worst_error = std::max(r.worst_error, bench::issue8_tapping(samples, sample_period_s, 1, k)->error_against_reference(backend));
  r.solves_per_s = batch_solves_per_s(backend, *bench::issue8_tapping(samples, sample_period_s, 4096), reps);
  return r;
}

// The inversion of a scan line: tracked (continued) windows and the same windows as cold starts.
struct LineFigures {
  double warm_solves_mean = 0, warm_iterations_mean = 0;
  double warm_p50_us = 0, warm_p99_us = 0, cold_p50_us = 0, cold_p99_us = 0, windows_per_s = 0;
};

struct Figures {
  double forward_solves_per_s = 0;
  LineFigures line_10mhz, line_1mhz;
};

// A scan line of contiguous 1250-sample windows, k and h unknown, the first window UNKNOWN.
// smooth: k 4 +- 2 N/m and h 25 +- 3 nm varying smoothly, no noise (the 10 MHz figure kept from
// before). Otherwise the issue's 1 MHz line: stiffness domains of 1 and 4 N/m, h rising in 2 nm
// steps, 0.05 nm sensor noise.
std::vector<Window> scan_line(const ModalModel& modal, int windows, double sample_period_s, bool smooth) {
  auto truth_backend = make_cpu_backend();
  std::mt19937_64 rng(7);
  std::normal_distribution<double> noise(0.0, 0.05e-9);
  std::vector<Window> line;
  ModalState state = linear_steady_state(modal, 2e-9, 25600.0, 0.0, 0.0);
  for (int px = 0; px < windows; ++px) {
    Window lw = sine_window(1250, px * 1250 * sample_period_s);
    lw.sample_period_s = sample_period_s;
    const double k = smooth ? 4.0 + 2.0 * std::sin(px * 0.1) : ((px / 16) % 2 == 0 ? 1.0 : 4.0);
    const double h = smooth ? 25e-9 + 3e-9 * std::cos(px * 0.07) : 20e-9 + 2e-9 * ((px / 24) % 4);
    const double full[6] = {k, h, 2e-9, 25600.0, 0.0, 0.0};
    ForwardOutput o = simulate_one(*truth_backend, modal, ForceModelKind::spring, lw, full, state);
    state = o.end_state[0];
    lw.deflection_m = o.signal;
    if (!smooth)
      for (double& d : lw.deflection_m) d += noise(rng);
    lw.initial = px == 0 ? InitialState::unknown : InitialState::continued;
    line.push_back(std::move(lw));
  }
  return line;
}

LineFigures invert_line(ForwardBackend& backend, const ModalModel& modal, const std::vector<Window>& line) {
  LineFigures f;
  ParameterSpace space(ForceModelKind::spring);
  space.make_unknown("k_n_per_m", 0.5, 20.0);
  space.make_unknown("h_m", 10e-9, 60e-9);
  Inverter warm(ProbeModel{"bench", modal, space, {}}, backend);
  std::vector<double> warm_us;
  const auto t0 = Clock::now();
  for (const Window& lw : line) {
    const auto s = Clock::now();
    const Estimate e = warm.invert(lw);
    warm_us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - s).count());
    f.warm_solves_mean += e.forward_solves / static_cast<double>(line.size());
    f.warm_iterations_mean += e.iterations / static_cast<double>(line.size());
  }
  f.windows_per_s = line.size() / std::chrono::duration<double>(Clock::now() - t0).count();
  warm_us.erase(warm_us.begin());  // the first window is a cold start
  f.warm_p50_us = percentile(warm_us, 0.5);
  f.warm_p99_us = percentile(warm_us, 0.99);
  // A cold start in a stream (a line start, a window after a gap) finds the probe's caches for its
  // sample period and window length (the step coefficients, the free decay basis) made by the
  // windows before it; the first window of a new Inverter makes them (~12 ms at 1 MHz), which is
  // start-up, not a cold start's latency: one untimed window first.
  Inverter cold(ProbeModel{"bench", modal, space, {}}, backend);
  {
    Window lw = line.front();
    lw.initial = InitialState::unknown;
    cold.invert(lw);
  }
  std::vector<double> cold_us;
  for (std::size_t i = 0; i < std::min<std::size_t>(line.size(), 20); ++i) {
    cold.reset();
    Window lw = line[i];
    lw.initial = InitialState::unknown;
    const auto s = Clock::now();
    cold.invert(lw);
    cold_us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - s).count());
  }
  f.cold_p50_us = percentile(cold_us, 0.5);
  f.cold_p99_us = percentile(cold_us, 0.99);
  return f;
}

Figures measure(ForwardBackend& backend, int batch, int reps, int line_windows) {
  Figures f;
  const ModalModel modal(paper_probe_spec());
  // Forward: 1000 samples, 8 modes, spring contact from the free steady state (firm tapping).
  f.forward_solves_per_s = batch_solves_per_s(backend, *bench::firm_tapping(1000, 1e-7, batch), reps);
  f.line_10mhz = invert_line(backend, modal, scan_line(modal, line_windows, 1e-7, true));
  f.line_1mhz = invert_line(backend, modal, scan_line(modal, line_windows, 1e-6, false));
  return f;
}

struct WorkPrecision {
  std::string model;
  double sample_period_s = 0, rel_l2_error = 0, solves_per_s = 0;
};

// Accuracy and speed side by side: per model and sample period (bench::work_precision_cases),
// the error against the reference integrator and the solves per second of a batch of 256 sets.
std::vector<WorkPrecision> work_precision(ForwardBackend& backend, int reps) {
  std::vector<WorkPrecision> out;
  for (const auto& c : bench::work_precision_cases(256))
    out.push_back({c->name(), c->window().sample_period_s, c->error_against_reference(backend),
                   batch_solves_per_s(backend, *c, reps)});
  return out;
}

}  // namespace

void add_bench_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("bench", "Benchmark the forward solver and the inversion (medians)");
  auto json = std::make_shared<std::string>();
  auto quick = std::make_shared<bool>(false);
  cmd->add_option("--json", *json, "Also write the figures as a JSON object to this file");
  cmd->add_flag("--quick", *quick, "Fewer repetitions (a smoke test, not a measurement)");
  cmd->callback([json, quick] {
    const int reps = *quick ? 3 : 9, line = *quick ? 20 : 200;
    // The JSON file is opened before the measurement (minutes), so that a path that cannot be
    // written is said at once, not lost after it.
    std::ofstream o;
    if (!json->empty()) {
      o.open(*json);
      if (!o) throw std::runtime_error("--json " + *json + ": cannot be opened for writing");
    }
    // Baseline in the same run: odeint's classic RK4, one step per sample, one set at a time.
    // Its set is the core definition's central one (tipforce_benchmarks times the same).
    const auto core = bench::firm_tapping(1000, 1e-7, 1);
    const int rk_n = *quick ? 20 : 100;
    const double rk4_per_s = median_rate(reps, rk_n, [&] {
      for (int i = 0; i < rk_n; ++i)
        odeint_rk4_simulate(core->modal(), core->model(), core->window(), core->central(), core->start());
    });
    auto cpu = make_cpu_backend();
    const Figures c = measure(*cpu, 4096, reps, line);
    const double mhz1 = batch_solves_per_s(*cpu, *bench::firm_tapping(1250, 1e-6, 4096), reps);
    const IssueCase issue10 = issue_case(*cpu, 1000, 1e-7, reps), issue1 = issue_case(*cpu, 1250, 1e-6, reps);
    const std::vector<WorkPrecision> wp = work_precision(*cpu, reps);
    const std::string machine = cpu->description() + ", " + bench::cpu_model_name();
    std::printf("machine: %s\n", machine.c_str());
    std::printf("%-34s %14s\n", "figure (medians)", "cpu");
    std::printf("%-34s %14.0f\n", "forward_solves_per_s", c.forward_solves_per_s);
    std::printf("%-34s %14.0f\n", "odeint_rk4_solves_per_s", rk4_per_s);
    std::printf("%-34s %14.1f\n", "forward / odeint_rk4", c.forward_solves_per_s / rk4_per_s);
    std::printf("%-34s %14.0f\n", "forward_1mhz_solves_per_s", mhz1);
    std::printf("issue 8's setup (45 nm free amplitude at f1, spring k 1-4 N/m at h 20 nm, batch of 4096):\n");
    std::printf("%-34s %14.0f   (error %.1e)\n", "issue_10mhz_solves_per_s", issue10.solves_per_s, issue10.worst_error);
    std::printf("%-34s %14.0f   (error %.1e)\n", "issue_1mhz_solves_per_s", issue1.solves_per_s, issue1.worst_error);
    auto print_line = [](const char* prefix, const LineFigures& l) {
      auto row = [&](const char* name, double v, const char* fmt) {
        std::printf("%-34s ", (std::string(prefix) + name).c_str());
        std::printf(fmt, v);
        std::printf("\n");
      };
      row("warm_inversion_p50_us", l.warm_p50_us, "%14.0f");
      row("warm_inversion_p99_us", l.warm_p99_us, "%14.0f");
      row("cold_inversion_p50_us", l.cold_p50_us, "%14.0f");
      row("cold_inversion_p99_us", l.cold_p99_us, "%14.0f");
      row("windows_per_s", l.windows_per_s, "%14.1f");
      row("warm_solves_per_window", l.warm_solves_mean, "%14.1f");
      row("warm_iterations_per_window", l.warm_iterations_mean, "%14.1f");
    };
    print_line("", c.line_10mhz);
    std::printf("1 MHz scan line (1250 samples at 1e-6 s, k domains 1 / 4 N/m, h steps of 2 nm, noise 0.05 nm):\n");
    print_line("line_1mhz_", c.line_1mhz);
    std::printf("\nwork-precision (1250 samples, firm tapping from the free steady state, batch of 256; error against the reference):\n");
    std::printf("%-12s %10s %14s %14s\n", "model", "period_s", "rel_l2_error", "solves_per_s");
    for (const WorkPrecision& x : wp)
      std::printf("%-12s %10.0e %14.1e %14.0f\n", x.model.c_str(), x.sample_period_s, x.rel_l2_error, x.solves_per_s);
    Figures g;
    std::string gpu_name;
    try {
      BackendChoice gpu = make_backend("cuda");
      gpu_name = gpu.backend->description();
      g = measure(*gpu.backend, 1 << 20, reps, line);
      std::printf("GPU %s: forward_solves_per_s %.0f (x%.1f cpu), warm p50 %.0f us p99 %.0f us, cold p50 %.0f us, windows/s %.1f\n",
                  gpu_name.c_str(), g.forward_solves_per_s, g.forward_solves_per_s / c.forward_solves_per_s,
                  g.line_10mhz.warm_p50_us, g.line_10mhz.warm_p99_us, g.line_10mhz.cold_p50_us, g.line_10mhz.windows_per_s);
    } catch (const std::exception& e) {
      std::printf("GPU: none (%s)\n", e.what());
    }
    if (!json->empty()) {
      o << "{\"machine\": \"" << machine << "\", \"forward_solves_per_s\": " << c.forward_solves_per_s
        << ", \"odeint_rk4_solves_per_s\": " << rk4_per_s << ", \"forward_over_odeint_rk4\": " << c.forward_solves_per_s / rk4_per_s
        << ", \"warm_inversion_p50_us\": " << c.line_10mhz.warm_p50_us << ", \"warm_inversion_p99_us\": " << c.line_10mhz.warm_p99_us
        << ", \"cold_inversion_p50_us\": " << c.line_10mhz.cold_p50_us << ", \"cold_inversion_p99_us\": " << c.line_10mhz.cold_p99_us
        << ", \"windows_per_s\": " << c.line_10mhz.windows_per_s << ", \"forward_1mhz_solves_per_s\": " << mhz1
        << ", \"issue_10mhz_solves_per_s\": " << issue10.solves_per_s
        << ", \"issue_10mhz_rel_l2_error\": " << issue10.worst_error
        << ", \"issue_1mhz_solves_per_s\": " << issue1.solves_per_s
        << ", \"issue_1mhz_rel_l2_error\": " << issue1.worst_error
        << ", \"line_1mhz_warm_inversion_p50_us\": " << c.line_1mhz.warm_p50_us
        << ", \"line_1mhz_warm_inversion_p99_us\": " << c.line_1mhz.warm_p99_us
        << ", \"line_1mhz_cold_inversion_p50_us\": " << c.line_1mhz.cold_p50_us
        << ", \"line_1mhz_cold_inversion_p99_us\": " << c.line_1mhz.cold_p99_us
        << ", \"line_1mhz_windows_per_s\": " << c.line_1mhz.windows_per_s
        << ", \"work_precision\": [";
      for (std::size_t i = 0; i < wp.size(); ++i)
        o << (i ? ", " : "") << "{\"model\": \"" << wp[i].model << "\", \"sample_period_s\": " << wp[i].sample_period_s
          << ", \"rel_l2_error\": " << wp[i].rel_l2_error << ", \"solves_per_s\": " << wp[i].solves_per_s << "}";
      o << "]";
      if (!gpu_name.empty())
        o << ", \"gpu\": {\"device\": \"" << gpu_name << "\", \"forward_solves_per_s\": " << g.forward_solves_per_s
          << ", \"warm_inversion_p50_us\": " << g.line_10mhz.warm_p50_us << ", \"warm_inversion_p99_us\": " << g.line_10mhz.warm_p99_us
          << ", \"cold_inversion_p50_us\": " << g.line_10mhz.cold_p50_us << ", \"cold_inversion_p99_us\": " << g.line_10mhz.cold_p99_us
          << ", \"windows_per_s\": " << g.line_10mhz.windows_per_s << "}";
      o << "}\n";
      o.close();
      if (!o) throw std::runtime_error("--json " + *json + ": writing the figures failed");
    }
  });
}

}  // namespace tipforce::cli
