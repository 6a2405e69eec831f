// tipforce_benchmarks: the forward solver's throughput under Google Benchmark, with odeint's
// classic RK4 (one step per sample, one set at a time) timed in the same run as the baseline.
// Each figure is a median over repetitions (9 unless --benchmark_repetitions says otherwise),
// and the summary at the end gives every benchmark's median solves/s as a ratio to the
// baseline's. --threads=N sets the CPU backend's threads (default: every core). The workloads
// are `tipforce bench`'s (bench_cases.hpp); that command adds the inversion's latencies and the
// errors against the reference integrator.
#include <benchmark/benchmark.h>

#include <unistd.h>

#include <charconv>
#include <cstdio>
#include <map>
#include <stdexcept>
#include <memory>
#include <string>
#include <vector>

#include "bench_cases.hpp"
#include "tipforce/reference.hpp"

namespace tipforce::bench {
namespace {

// Sets solved per iteration are counted as items: items_per_second is solves/s.
void run_batch(benchmark::State& state, const ForwardCase& c, ForwardBackend& backend) {
  const ForwardProblem problem = c.problem();
  const ForwardBatch batch = c.forward_batch();
  ForwardOutput out;
  backend.solve(problem, batch, out);  // builds the step levels, untimed
  for (auto _ : state) {
    backend.solve(problem, batch, out);
    benchmark::DoNotOptimize(out.cost.data());
  }
  state.SetItemsProcessed(state.iterations() * c.batch());
}

void odeint_baseline(benchmark::State& state, const ForwardCase& c) {
  for (auto _ : state) {
    const std::vector<double> signal = odeint_rk4_simulate(c.modal(), c.model(), c.window(), c.central(), c.start());
    benchmark::DoNotOptimize(signal.data());
  }
  state.SetItemsProcessed(state.iterations());
}

// Collects each benchmark's median solves/s while the console reporter prints as usual, then
// prints them against the baseline's.
class RatioReporter : public benchmark::ConsoleReporter {
 public:
  RatioReporter(std::string baseline, OutputOptions options) : ConsoleReporter(options), baseline_(std::move(baseline)) {}
  void ReportRuns(const std::vector<Run>& runs) override {
    ConsoleReporter::ReportRuns(runs);
    for (const Run& r : runs) {
      const auto it = r.counters.find("items_per_second");
      if (it == r.counters.end()) continue;
      // With repetitions the median aggregate; with one run that run.
      if (r.aggregate_name == "median" || (r.run_type == Run::RT_Iteration && r.repetitions <= 1))
        medians_[r.run_name.str()] = it->second.value;
    }
  }
  void Finalize() override {
    ConsoleReporter::Finalize();
    const auto base = medians_.find(baseline_);
    std::printf("\nmedian solves/s against the baseline measured in this run (%s):\n", baseline_.c_str());
    for (const auto& [name, rate] : medians_) {
      if (base == medians_.end())
        std::printf("%-62s %12.0f solves/s\n", name.c_str(), rate);
      else
        std::printf("%-62s %12.0f solves/s  %8.1f x baseline\n", name.c_str(), rate, rate / base->second);
    }
  }

 private:
  std::string baseline_;
  std::map<std::string, double> medians_;
};

}  // namespace
}  // namespace tipforce::bench

int main(int argc, char** argv) {
  using namespace tipforce;
  using namespace tipforce::bench;
  // --threads=N: the CPU backend's threads (default: every core), e.g. 1 for one core's figure.
  // Medians over 9 repetitions unless the command line says otherwise (a later flag wins).
  int threads = 0;
  std::vector<char*> args{argv[0]};
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a.rfind("--threads=", 0) != 0) {
      args.push_back(argv[i]);
      continue;
    }
    const std::string v = a.substr(10);
    const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), threads);
    if (ec != std::errc() || end != v.data() + v.size() || threads < 1 || threads > 1024) {
      std::fprintf(stderr, "tipforce_benchmarks: %s: the thread count must be a whole number in [1, 1024]\n", a.c_str());
      return 2;
    }
  }
  // What Google Benchmark's own reporter would be told (the last of each flag wins): the ratios'
  // summary is console output, so another format gets Google Benchmark's reporter alone. A
  // negative repetition count made it abort (std::length_error), so it is refused here.
  std::string format = "console", color = "auto";
  for (std::size_t i = 1; i < args.size(); ++i) {
    const std::string a = args[i];
    if (a.rfind("--benchmark_format=", 0) == 0) format = a.substr(19);
    if (a.rfind("--benchmark_color=", 0) == 0) color = a.substr(18);
    if (a.rfind("--benchmark_repetitions=", 0) == 0 && a.size() > 24 && a[24] == '-') {
      std::fprintf(stderr, "tipforce_benchmarks: %s: the repetitions must be at least 1\n", a.c_str());
      return 2;
    }
  }
  std::string reps = "--benchmark_repetitions=9", aggregates = "--benchmark_report_aggregates_only=true";
  args.insert(args.begin() + 1, {reps.data(), aggregates.data()});
  int n = static_cast<int>(args.size());
  benchmark::Initialize(&n, args.data());
  if (benchmark::ReportUnrecognizedArguments(n, args.data())) return 1;

  auto backend = make_cpu_backend(threads);
  benchmark::AddCustomContext("tipforce_backend", backend->description());
  benchmark::AddCustomContext("cpu_model", cpu_model_name());

  // The cases live until the benchmarks have run: the registered lambdas refer to them.
  std::vector<std::unique_ptr<ForwardCase>> cases;
  cases.push_back(firm_tapping(1000, 1e-7, 4096));
  const ForwardCase& core = *cases.back();
  benchmark::RegisterBenchmark("odeint_rk4/firm_tapping/1000x1e-7s", [&core](benchmark::State& s) { odeint_baseline(s, core); })
      ->Unit(benchmark::kMillisecond);
  benchmark::RegisterBenchmark("forward/firm_tapping/1000x1e-7s/4096", [&core, &backend](benchmark::State& s) {
    run_batch(s, core, *backend);
  })->Unit(benchmark::kMillisecond)->UseRealTime();
  cases.push_back(firm_tapping(1250, 1e-6, 4096));
  cases.push_back(issue8_tapping(1000, 1e-7, 4096));
  cases.push_back(issue8_tapping(1250, 1e-6, 4096));
  cases.push_back(cold_grid(1e-6));
  cases.push_back(scattered_search(1250, 1e-6, 128));
  for (std::size_t i = 1; i < cases.size(); ++i) {
    const ForwardCase& c = *cases[i];
    const std::string name = "forward/" + c.name() + "/" + std::to_string(c.window().n_samples()) + "x" +
                             (c.window().sample_period_s < 5e-7 ? "1e-7s" : "1e-6s") + "/" + std::to_string(c.batch());
    benchmark::RegisterBenchmark(name.c_str(), [&c, &backend](benchmark::State& s) { run_batch(s, c, *backend); })
        ->Unit(benchmark::kMillisecond)->UseRealTime();
  }
  for (auto& wp : work_precision_cases(256)) {
    const ForwardCase& c = *wp;
    char period[16];
    std::snprintf(period, sizeof period, "%.0es", c.window().sample_period_s);
    const std::string name = "forward/work_precision/" + c.name() + "/1250x" + period + "/256";
    benchmark::RegisterBenchmark(name.c_str(), [&c, &backend](benchmark::State& s) { run_batch(s, c, *backend); })
        ->Unit(benchmark::kMillisecond)->UseRealTime();
    cases.push_back(std::move(wp));
  }

  std::size_t ran = 0;
  if (format == "console") {
    const bool colour = color == "true" || color == "yes" || color == "1" ||
                        (color == "auto" && ::isatty(STDOUT_FILENO));
    RatioReporter reporter("odeint_rk4/firm_tapping/1000x1e-7s",
                           colour ? benchmark::ConsoleReporter::OO_Defaults : benchmark::ConsoleReporter::OO_Tabular);
    ran = benchmark::RunSpecifiedBenchmarks(&reporter);
  } else {
    ran = benchmark::RunSpecifiedBenchmarks();
  }
  benchmark::Shutdown();
  if (ran == 0) {
    std::fprintf(stderr, "tipforce_benchmarks: no benchmark ran (see --benchmark_filter and --benchmark_repetitions)\n");
    return 1;
  }
  return 0;
}
