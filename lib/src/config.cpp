// Strict TOML configuration: every key is known, typed and checked; problems name file and key.
#include "tipforce/config.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <set>
#include <tuple>
#include <sstream>

#include <toml++/toml.h>

namespace tipforce {
namespace {

// Physical ranges (SI). Wide enough for any AFM probe and sample, narrow enough that a typo of a
// few orders of magnitude, or 1e308, is refused at start instead of producing inf estimates.
struct Range {
  double low, high;
  const char* what;
};
constexpr Range kLengthRange{1e-6, 1e-2, "between 1 µm and 10 mm"};
constexpr Range kWidthRange{1e-7, 1e-2, "between 0.1 µm and 10 mm"};
constexpr Range kThicknessRange{1e-9, 1e-3, "between 1 nm and 1 mm"};
constexpr Range kModulusRange{1e6, 1e13, "between 1 MPa and 10 TPa"};
constexpr Range kDensityRange{10, 1e5, "between 10 and 100000 kg/m^3"};
constexpr Range kSamplePeriodRange{1e-10, 1e-3, "between 0.1 ns and 1 ms"};
constexpr Range kF1Range{1, 1e9, "between 1 Hz and 1 GHz"};
constexpr Range kKcRange{1e-6, 1e6, "between 1e-6 and 1e6 N/m"};
// An overdamped mode (Q < 0.5) is not supported: its step back from a step's end grows as
// e^{3 omega h} and lost the state (NaN or 1e12 off at 1e-6 s with 8 modes at Q 0.3).
constexpr Range kQualityRange{0.5, 1e7, "between 0.5 and 1e7 (an overdamped mode, Q < 0.5, is not supported)"};
// The highest modelled mode must stay far below any sample rate the messages can carry.
constexpr double kMaxModeFrequencyHz = 1e11;

// Values a model or drive parameter may take (fixed, or as a bound).
Range parameter_range(std::string_view name) {
  if (name == "k_n_per_m") return {0, 1e6, "between 0 and 1e6 N/m"};
  if (name == "c_ns_per_m") return {0, 1e3, "between 0 and 1000 N s/m"};
  if (name == "h_m") return {-1e-3, 1e-3, "between -1 mm and 1 mm"};
  if (name == "e_star_pa") return {0, 1e13, "between 0 and 10 TPa"};
  if (name == "radius_m") return {0, 1e-3, "between 0 and 1 mm"};
  if (name == "hamaker_j") return {0, 1e-15, "between 0 and 1e-15 J"};
  if (name == "a0_m") return {0, 1e-6, "between 0 and 1 µm"};
  if (name == "eta_pa_s") return {0, 1e6, "between 0 and 1e6 Pa s"};
  if (name == "drive_amplitude_m") return {-1e-3, 1e-3, "between -1 mm and 1 mm"};
  if (name == "drive_frequency_hz") return {0, 1e10, "between 0 and 10 GHz"};
  if (name == "drive_phase_rad") return {-1e3, 1e3, "between -1000 and 1000 rad"};
  if (name == "drive_chirp_hz_per_s") return {-1e15, 1e15, "between -1e15 and 1e15 Hz/s"};
  return {-1e15, 1e15, "between -1e15 and 1e15"};
}

}  // namespace

ValueRange parameter_value_range(std::string_view name) {
  const Range r = parameter_range(name);
  return {r.low, r.high, r.what};
}
ValueRange sample_period_range() { return {kSamplePeriodRange.low, kSamplePeriodRange.high, kSamplePeriodRange.what}; }

namespace {

// The inversion's cost grows with swarm x generations; past these a window takes seconds.
constexpr int kMaxSwarmSize = 1000;
constexpr int kMaxGenerations = 2000;
constexpr std::int64_t kMaxSwarmEvaluations = 200'000;  // swarm_size x max_generations, each start

class Reader {
 public:
  explicit Reader(std::string source) : source_(std::move(source)) {}
  [[noreturn]] void fail(const std::string& key, const std::string& problem) const {
    throw ConfigError(source_ + ": " + key + ": " + problem);
  }
  void only_keys(const toml::table& t, const std::string& prefix, const std::set<std::string>& allowed) const {
    for (auto&& [k, v] : t) {
      (void)v;
      if (!allowed.count(std::string(k.str())))
        fail(prefix + std::string(k.str()), "unknown key");
    }
  }
  double number(const toml::node& n, const std::string& key) const {
    if (auto d = n.value_exact<double>()) return check_finite(*d, key);
    if (auto i = n.value_exact<int64_t>()) return static_cast<double>(*i);
    fail(key, "expected a number");
  }
  double positive(const toml::node& n, const std::string& key) const {
    const double v = number(n, key);
    if (!(v > 0)) fail(key, "must be positive, got " + fmt(v));
    return v;
  }
  double in_range(const toml::node& n, const std::string& key, const Range& r) const {
    const double v = number(n, key);
    check_range(v, key, r);
    return v;
  }
  void check_range(double v, const std::string& key, const Range& r) const {
    if (!(v >= r.low && v <= r.high)) fail(key, std::string("must be ") + r.what + ", got " + fmt(v));
  }
  bool boolean(const toml::node& n, const std::string& key) const {
    if (auto b = n.value_exact<bool>()) return *b;
    fail(key, "expected true or false");
  }
  int64_t integer(const toml::node& n, const std::string& key) const {
    if (auto i = n.value_exact<int64_t>()) return *i;
    fail(key, "expected an integer");
  }
  std::string string(const toml::node& n, const std::string& key) const {
    if (auto s = n.value_exact<std::string>()) return *s;
    fail(key, "expected a string");
  }
  const toml::table& table(const toml::node& n, const std::string& key) const {
    if (auto t = n.as_table()) return *t;
    fail(key, "expected a table");
  }
  static std::string fmt(double v) {
    std::ostringstream o;
    o << v;
    return o.str();
  }

 private:
  double check_finite(double v, const std::string& key) const {
    if (!std::isfinite(v)) fail(key, "must be finite");
    return v;
  }
  std::string source_;
};

// daemon.shard = { index = I, count = N, by = "probe" | "line" }. `count` and `by` are required:
// shards that disagree on either would answer some windows twice and others never. `index` may
// come from the command line instead (tipforced --shard-index, one configuration for all shards).
ShardSpec read_shard(const Reader& rd, const toml::table& t) {
  rd.only_keys(t, "daemon.shard.", {"index", "count", "by"});
  ShardSpec s;
  if (!t.contains("count")) rd.fail("daemon.shard.count", "missing (how many shards share the stream)");
  if (!t.contains("by")) rd.fail("daemon.shard.by", "missing (\"probe\" or \"line\")");
  const int64_t count = rd.integer(*t.get("count"), "daemon.shard.count");
  if (count < 1 || count > kMaxShardCount)
    rd.fail("daemon.shard.count", "must be in [1, " + std::to_string(kMaxShardCount) + "], got " + std::to_string(count));
  s.count = static_cast<int>(count);
  if (auto* i = t.get("index")) {
    const int64_t index = rd.integer(*i, "daemon.shard.index");
    if (index < 0 || index >= count)
      rd.fail("daemon.shard.index", "must be in [0, count - 1] = [0, " + std::to_string(count - 1) + "], got " +
                                        std::to_string(index));
    s.index = static_cast<int>(index);
  }
  const std::string by = rd.string(*t.get("by"), "daemon.shard.by");
  if (by == "probe") s.by = ShardBy::probe;
  else if (by == "line") s.by = ShardBy::line;
  else rd.fail("daemon.shard.by", "must be \"probe\" or \"line\", got \"" + by + "\"");
  return s;
}

DaemonSettings read_daemon(const Reader& rd, const toml::table& t) {
  rd.only_keys(t, "daemon.", {"input_url", "output_url", "window_channel", "estimate_channel", "stats_channel",
                              "stats_period_s", "queue_capacity", "backend", "max_window_samples", "shard",
                              "cpu_threads", "setpoint_channel"});
  DaemonSettings d;
  for (auto&& [k, v] : t) {
    const std::string key = "daemon." + std::string(k.str());
    const std::string_view name = k.str();
    if (name == "input_url") d.input_url = rd.string(v, key);
    else if (name == "output_url") d.output_url = rd.string(v, key);
    else if (name == "window_channel") d.window_channel = rd.string(v, key);
    else if (name == "estimate_channel") d.estimate_channel = rd.string(v, key);
    else if (name == "stats_channel") d.stats_channel = rd.string(v, key);
    else if (name == "setpoint_channel") d.setpoint_channel = rd.string(v, key);
    else if (name == "stats_period_s") {
      // Each period publishes a message and logs a line: a few ms would flood both.
      d.stats_period_s = rd.in_range(v, key, Range{0.01, 86400, "between 0.01 s and 86400 s"});
    } else if (name == "max_window_samples") {
      const int64_t n = rd.integer(v, key);
      if (n < 16 || n > kMaxWindowSamples)
        rd.fail(key, "must be in [16, " + std::to_string(kMaxWindowSamples) + "], got " + std::to_string(n));
      d.max_window_samples = static_cast<int>(n);
    }
    else if (name == "cpu_threads") {
      const int64_t n = rd.integer(v, key);
      if (n < 0 || n > 1024) rd.fail(key, "must be in [0, 1024] (0: one per core), got " + std::to_string(n));
      d.cpu_threads = static_cast<int>(n);
    }
    else if (name == "shard") {
      d.shard = read_shard(rd, rd.table(v, key));
    }
    else if (name == "queue_capacity") {
      const int64_t q = rd.integer(v, key);
      if (q < 1 || q > 1'000'000) rd.fail(key, "must be in [1, 1000000], got " + std::to_string(q));
      d.queue_capacity = static_cast<int>(q);
    } else if (name == "backend") {
      d.backend = rd.string(v, key);
      if (d.backend != "auto" && d.backend != "cpu" && d.backend != "cuda")
        rd.fail(key, "must be \"auto\", \"cpu\" or \"cuda\", got \"" + d.backend + "\"");
    }
  }
  for (const std::string* ch : {&d.window_channel, &d.estimate_channel, &d.stats_channel, &d.setpoint_channel})
    if (ch->empty()) rd.fail("daemon", "channel names must not be empty");
  if (d.setpoint_channel == d.window_channel || d.setpoint_channel == d.estimate_channel ||
      d.setpoint_channel == d.stats_channel)
    rd.fail("daemon.setpoint_channel", "must differ from the window, estimate and stats channels, got \"" +
                                           d.setpoint_channel + "\"");
  // A daemon that receives on its own estimate channel would answer its own output.
  if (d.window_channel == d.estimate_channel || d.window_channel == d.stats_channel ||
      d.estimate_channel == d.stats_channel)
    rd.fail("daemon", "window_channel, estimate_channel and stats_channel must be distinct, got \"" +
                          d.window_channel + "\", \"" + d.estimate_channel + "\", \"" + d.stats_channel + "\"");
  return d;
}

// [probe.NAME.advisor] (issue 13). max_peak_force_n is required; min_free_amplitude_m makes the
// free amplitude a setpoint the advisor may lower, down to it (without it, corrections retract).
AdvisorOptions read_advisor(const Reader& rd, const std::string& p, const toml::table& t, const ParameterSpace& space) {
  rd.only_keys(t, p, {"max_peak_force_n", "margin", "sigma_multiplier", "min_free_amplitude_m", "max_z_step_m"});
  AdvisorOptions a;
  if (space.index_of("h_m") < 0) rd.fail(p.substr(0, p.size() - 1), "the model has no separation h_m to advise on");
  const toml::node* max = t.get("max_peak_force_n");
  if (max == nullptr) rd.fail(p + "max_peak_force_n", "missing (the limit on the peak force, N)");
  a.max_peak_force_n = rd.in_range(*max, p + "max_peak_force_n", Range{1e-15, 1e-3, "between 1e-15 N and 1 mN"});
  if (auto* n = t.get("margin")) a.margin = rd.in_range(*n, p + "margin", Range{0, 0.9, "between 0 and 0.9"});
  if (auto* n = t.get("sigma_multiplier"))
    a.sigma_multiplier = rd.in_range(*n, p + "sigma_multiplier", Range{0, 10, "between 0 and 10"});
  if (auto* n = t.get("max_z_step_m"))
    a.max_z_step_m = rd.in_range(*n, p + "max_z_step_m", Range{0, 1e-6, "between 0 and 1 µm"});
  if (auto* n = t.get("min_free_amplitude_m"))
    a.min_free_amplitude_m = rd.in_range(*n, p + "min_free_amplitude_m", Range{1e-12, 1e-3, "between 1 pm and 1 mm"});
  return a;
}

ProbeConfig read_probe(const Reader& rd, const std::string& name, const toml::table& t) {
  const std::string p = "probe." + name + ".";
  rd.only_keys(t, p, {"length_m", "width_m", "thickness_m", "youngs_modulus_pa", "density_kg_m3", "f1_hz",
                      "k_c_n_per_m", "quality_factor", "modes", "sensor", "model", "fixed", "unknowns", "inversion",
                      "advisor"});
  ProbeConfig pc;
  const bool geometry = t.contains("length_m") || t.contains("width_m") || t.contains("thickness_m") ||
                        t.contains("youngs_modulus_pa") || t.contains("density_kg_m3");
  const bool calibrated = t.contains("f1_hz") || t.contains("k_c_n_per_m");
  if (geometry == calibrated)
    rd.fail(p.substr(0, p.size() - 1), geometry ? "give either geometry (length_m, ...) or f1_hz + k_c_n_per_m, not both"
                                                : "missing the cantilever: geometry (length_m, width_m, thickness_m, "
                                                  "youngs_modulus_pa, density_kg_m3) or f1_hz + k_c_n_per_m");
  auto need = [&](const char* key) -> const toml::node& {
    const toml::node* n = t.get(key);
    if (!n) rd.fail(p + key, "missing");
    return *n;
  };
  if (geometry) {
    BeamGeometry g;
    g.length_m = rd.in_range(need("length_m"), p + "length_m", kLengthRange);
    g.width_m = rd.in_range(need("width_m"), p + "width_m", kWidthRange);
    g.thickness_m = rd.in_range(need("thickness_m"), p + "thickness_m", kThicknessRange);
    g.youngs_modulus_pa = rd.in_range(need("youngs_modulus_pa"), p + "youngs_modulus_pa", kModulusRange);
    g.density_kg_m3 = rd.in_range(need("density_kg_m3"), p + "density_kg_m3", kDensityRange);
    pc.spec.cantilever = g;
  } else {
    pc.spec.cantilever = CalibratedProbe{rd.in_range(need("f1_hz"), p + "f1_hz", kF1Range),
                                         rd.in_range(need("k_c_n_per_m"), p + "k_c_n_per_m", kKcRange)};
  }
  if (auto* m = t.get("modes")) {
    const int64_t modes = rd.integer(*m, p + "modes");
    if (modes < 1 || modes > 32) rd.fail(p + "modes", "must be in [1, 32], got " + std::to_string(modes));
    pc.spec.modes = static_cast<int>(modes);
  }
  if (auto* q = t.get("quality_factor")) {
    pc.spec.quality_factors.clear();
    if (auto* arr = q->as_array()) {
      for (std::size_t i = 0; i < arr->size(); ++i)
        pc.spec.quality_factors.push_back(
            rd.in_range(*arr->get(i), p + "quality_factor[" + std::to_string(i) + "]", kQualityRange));
      if (static_cast<int>(pc.spec.quality_factors.size()) != pc.spec.modes)
        rd.fail(p + "quality_factor", "has " + std::to_string(arr->size()) + " values for " + std::to_string(pc.spec.modes) +
                                          " modes");
    } else {
      pc.spec.quality_factors.push_back(rd.in_range(*q, p + "quality_factor", kQualityRange));
    }
  }
  if (auto* s = t.get("sensor")) {
    const std::string sensor = rd.string(*s, p + "sensor");
    if (sensor == "displacement") pc.spec.sensor = Sensor::displacement;
    else if (sensor == "optical_lever") pc.spec.sensor = Sensor::optical_lever;
    else rd.fail(p + "sensor", "must be \"displacement\" or \"optical_lever\", got \"" + sensor + "\"");
  }
  const std::string model_name = rd.string(need("model"), p + "model");
  const auto model = force_model_from_string(model_name);
  if (!model) rd.fail(p + "model", "unknown model \"" + model_name + "\" (none, spring, kelvin_voigt, hertz, dmt, dmt_viscous)");
  pc.space = ParameterSpace(*model);
  auto param_error = [&](const std::string& key, const std::exception& e) {
    std::string what = e.what();
    const auto pos = what.find(": ");
    const auto at = what.rfind(" (");
    rd.fail(key, what.substr(pos == std::string::npos ? 0 : pos + 2,
                             at == std::string::npos ? std::string::npos : at - (pos + 2)));
  };
  if (auto* f = t.get("fixed")) {
    for (auto&& [k, v] : rd.table(*f, p + "fixed")) {
      const std::string key = p + "fixed." + std::string(k.str());
      if (pc.space.index_of(k.str()) < 0)
        rd.fail(key, "not a parameter of model " + model_name + " or of the drive");
      try {
        pc.space.fix(k.str(), rd.in_range(v, key, parameter_range(k.str())));
      } catch (const std::invalid_argument& e) {
        param_error(key, e);
      }
    }
  }
  if (auto* u = t.get("unknowns")) {
    for (auto&& [k, v] : rd.table(*u, p + "unknowns")) {
      const std::string key = p + "unknowns." + std::string(k.str());
      if (pc.space.index_of(k.str()) < 0)
        rd.fail(key, "not a parameter of model " + model_name + " or of the drive");
      const auto* arr = v.as_array();
      if (!arr || arr->size() != 2) rd.fail(key, "expected bounds [low, high]");
      const Range range = parameter_range(k.str());
      const double low = rd.in_range(*arr->get(0), key + "[0]", range),
                   high = rd.in_range(*arr->get(1), key + "[1]", range);
      if (!(low < high))
        rd.fail(key, "bounds are empty or inverted: [" + Reader::fmt(low) + ", " + Reader::fmt(high) + "]");
      try {
        pc.space.make_unknown(k.str(), low, high);
      } catch (const std::invalid_argument& e) {
        param_error(key, e);
      }
    }
  }
  for (const std::string& missing : pc.space.missing())
    rd.fail(p + "fixed", "parameter '" + missing + "' of model " + model_name + " is neither fixed nor unknown");
  if (auto* inv = t.get("inversion")) {
    const auto& it = rd.table(*inv, p + "inversion");
    rd.only_keys(it, p + "inversion.", {"swarm_size", "max_generations", "warm_swarm_size", "warm_max_generations",
                                        "stall_generations", "lm_max_iterations", "cold_lm_max_iterations", "seed", "tracking_misfit_ratio",
                                        "max_misfit", "bound_max_lag1", "start_prior_floor_rel", "trade_off_correlation",
                                        "deadline_ms", "resume_cut_fits", "false_continuation_chi2",
                                        "parameter_drift_rel", "pool_gate_chi2", "pool_max_iterations", "pool_gated_iterations", "pool_valley_chi2",
                                        "prepare_sample_periods_s"});
    auto int_in = [&](const char* key, int lo, int hi, int& dst) {
      if (auto* n = it.get(key)) {
        const int64_t v = rd.integer(*n, p + "inversion." + key);
        if (v < lo || v > hi)
          rd.fail(p + "inversion." + key, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
        dst = static_cast<int>(v);
      }
    };
    int_in("swarm_size", 4, kMaxSwarmSize, pc.options.swarm_size);
    int_in("max_generations", 1, kMaxGenerations, pc.options.max_generations);
    int_in("warm_swarm_size", 4, kMaxSwarmSize, pc.options.warm_swarm_size);
    int_in("warm_max_generations", 1, kMaxGenerations, pc.options.warm_max_generations);
    int_in("stall_generations", 1, kMaxGenerations, pc.options.stall_generations);
    const auto& o = pc.options;
    for (auto [swarm, generations, key] : {std::tuple{o.swarm_size, o.max_generations, "swarm_size x max_generations"},
                                           std::tuple{o.warm_swarm_size, o.warm_max_generations,
                                                      "warm_swarm_size x warm_max_generations"}})
      if (static_cast<std::int64_t>(swarm) * generations > kMaxSwarmEvaluations)
        rd.fail(p + "inversion", std::string(key) + " is " +
                                     std::to_string(static_cast<std::int64_t>(swarm) * generations) +
                                     ", more than the " + std::to_string(kMaxSwarmEvaluations) +
                                     " forward solves a window may take in the swarm");
    int_in("lm_max_iterations", 0, 1000, pc.options.lm_max_iterations);
    int_in("cold_lm_max_iterations", 0, 1000, pc.options.cold_lm_max_iterations);
    int_in("pool_max_iterations", 0, 1000, pc.options.pool_max_iterations);
    int_in("pool_gated_iterations", 0, 1000, pc.options.pool_gated_iterations);
    auto number_in = [&](const char* key, double lo, double hi, double& dst) {
      if (auto* n = it.get(key)) {
        const double v = rd.number(*n, p + "inversion." + key);
        if (!(v >= lo && v <= hi)) {
          // %g-style: "[5, 1e+300]", not std::to_string's 300 digits
          std::ostringstream range;
          range << "must be in [" << lo << ", " << hi << "]";
          rd.fail(p + "inversion." + key, range.str());
        }
        dst = v;
      }
    };
    number_in("tracking_misfit_ratio", 1.0, 100.0, pc.options.tracking_misfit_ratio);
    number_in("max_misfit", 1e-6, 10.0, pc.options.max_misfit);
    // 1: never (a residual's lag-1 autocorrelation is at most 1).
    number_in("bound_max_lag1", 0.0, 1.0, pc.options.bound_max_lag1);
    number_in("start_prior_floor_rel", 0.0, 1.0, pc.options.start_prior_floor_rel);
    number_in("trade_off_correlation", 0.5, 1.0, pc.options.trade_off_correlation);
    // 0: none; at most an hour (a larger value is a typo for "none").
    number_in("deadline_ms", 0.0, 3.6e6, pc.options.deadline_ms);
    if (auto* n = it.get("resume_cut_fits"))
      pc.options.resume_cut_fits = rd.boolean(*n, p + "inversion.resume_cut_fits");
    if (auto* n = it.get("prepare_sample_periods_s")) {
      const std::string key = p + "inversion.prepare_sample_periods_s";
      const auto* arr = n->as_array();
      if (!arr) rd.fail(key, "expected a list of sample periods in s, e.g. [1e-6]");
      // The backends keep the step tables of the last four periods (detail::StepLevels).
      if (arr->size() > 4) rd.fail(key, "has " + std::to_string(arr->size()) + " periods; at most 4 are kept ready");
      for (std::size_t i = 0; i < arr->size(); ++i)
        pc.options.prepare_sample_periods_s.push_back(
            rd.in_range(*arr->get(i), key + "[" + std::to_string(i) + "]", kSamplePeriodRange));
    }
    // Below ~10 a continuing window's own chi-square (4 degrees of freedom) would set it off.
    number_in("false_continuation_chi2", 10.0, 1e300, pc.options.false_continuation_chi2);
    // One number for every unknown, or a table by unknown naming each; 0 (or absent): pixels
    // independent. At most 10 (a drift of 1000 % per pixel pools nothing).
    if (auto* n = it.get("parameter_drift_rel")) {
      const std::string key = p + "inversion.parameter_drift_rel";
      auto drift_in = [&](const toml::node& v, const std::string& at) {
        const double d = rd.number(v, at);
        if (!(d >= 0 && d <= 10)) rd.fail(at, "must be in [0, 10] (a relative drift per window)");
        return d;
      };
      const std::vector<std::string> names = pc.space.unknown_names();
      pc.options.parameter_drift_rel.clear();
      if (n->is_table()) {
        for (auto&& [k, v] : rd.table(*n, key)) {
          const std::string name(k.str());
          if (std::find(names.begin(), names.end(), name) == names.end())
            rd.fail(key + "." + name, "is not an unknown of this probe");
          const double d = drift_in(v, key + "." + name);
          if (!(d > 0)) rd.fail(key + "." + name, "must be above 0 (to pool nothing, leave parameter_drift_rel out)");
          pc.options.parameter_drift_rel[name] = d;
        }
        for (const std::string& name : names)
          if (!pc.options.parameter_drift_rel.contains(name))
            rd.fail(key, "names no drift for unknown '" + name + "' (pooling needs one for every unknown)");
      } else if (const double d = drift_in(*n, key); d > 0) {
        for (const std::string& name : names) pc.options.parameter_drift_rel[name] = d;
      }
    }
    // Below ~5 the parameters' own chi-square (one degree of freedom each) would refuse pooling.
    number_in("pool_gate_chi2", 5.0, 1e300, pc.options.pool_gate_chi2);
    number_in("pool_valley_chi2", 0.0, 1e300, pc.options.pool_valley_chi2);
    if (auto* n = it.get("seed")) pc.options.seed = static_cast<std::uint64_t>(rd.integer(*n, p + "inversion.seed"));
  }
  if (auto* adv = t.get("advisor")) pc.advisor = read_advisor(rd, p + "advisor.", rd.table(*adv, p + "advisor"), pc.space);
  try {
    ModalModel check(pc.spec);
    const double f_high = check.modes().back().frequency_hz;
    if (!std::isfinite(f_high) || f_high > kMaxModeFrequencyHz)
      rd.fail(p + "modes", "mode " + std::to_string(check.n_modes()) + " of this cantilever is at " +
                               Reader::fmt(f_high) + " Hz, above the 1e11 Hz any window could sample");
  } catch (const std::invalid_argument& e) {
    param_error(p.substr(0, p.size() - 1), e);
  }
  return pc;
}

}  // namespace

ProbeModel Config::probe_model(const std::string& name) const {
  auto it = probes.find(name);
  if (it == probes.end()) throw ConfigError(source + ": probe." + name + ": no such probe in the config");
  ModalModel modal(it->second.spec);
  const auto* beam = std::get_if<BeamGeometry>(&it->second.spec.cantilever);
  WindowLimits limits =
      window_limits(modal, beam != nullptr ? beam->length_m : 0.0, it->second.space, daemon.max_window_samples);
  return ProbeModel{name, std::move(modal), it->second.space, it->second.options, limits};
}

Config parse_config(const std::string& text, const std::string& source) {
  Reader rd(source);
  toml::table root;
  try {
    root = toml::parse(text, source);
  } catch (const toml::parse_error& e) {
    std::ostringstream o;
    o << "line " << e.source().begin.line << ": " << e.description();
    throw ConfigError(source + ": " + o.str());
  }
  rd.only_keys(root, "", {"daemon", "probe"});
  Config c;
  c.source = source;
  if (auto* d = root.get("daemon")) c.daemon = read_daemon(rd, rd.table(*d, "daemon"));
  if (auto* p = root.get("probe")) {
    for (auto&& [k, v] : rd.table(*p, "probe")) {
      const std::string name(k.str());
      c.probes.emplace(name, read_probe(rd, name, rd.table(v, "probe." + name)));
    }
  }
  if (c.probes.empty()) rd.fail("probe", "no probe configured (add a [probe.NAME] table)");
  return c;
}

Config load_config(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError(path.string() + ": cannot be read");
  // Read at most one byte more than allowed: /dev/zero or a mistaken multi-GB file is refused
  // after kMaxConfigBytes, not read into memory.
  std::string text(kMaxConfigBytes + 1, '\0');
  in.read(text.data(), static_cast<std::streamsize>(text.size()));
  if (in.bad()) throw ConfigError(path.string() + ": cannot be read");
  text.resize(static_cast<std::size_t>(in.gcount()));
  if (text.size() > kMaxConfigBytes)
    throw ConfigError(path.string() + ": larger than the " + std::to_string(kMaxConfigBytes / 1024) +
                      " KiB a configuration may have (is it the right file?)");
  return parse_config(text, path.string());
}

}  // namespace tipforce
