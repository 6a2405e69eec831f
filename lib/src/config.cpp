// Strict TOML configuration: every key is known, typed and checked; problems name file and key.
#include "tipforce/config.hpp"

#include <cmath>
#include <fstream>
#include <set>
#include <sstream>

#include <toml++/toml.h>

namespace tipforce {
namespace {

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

DaemonSettings read_daemon(const Reader& rd, const toml::table& t) {
  rd.only_keys(t, "daemon.", {"input_url", "output_url", "window_channel", "estimate_channel", "stats_channel",
                              "stats_period_s", "queue_capacity", "backend"});
  DaemonSettings d;
  for (auto&& [k, v] : t) {
    const std::string key = "daemon." + std::string(k.str());
    const std::string_view name = k.str();
    if (name == "input_url") d.input_url = rd.string(v, key);
    else if (name == "output_url") d.output_url = rd.string(v, key);
    else if (name == "window_channel") d.window_channel = rd.string(v, key);
    else if (name == "estimate_channel") d.estimate_channel = rd.string(v, key);
    else if (name == "stats_channel") d.stats_channel = rd.string(v, key);
    else if (name == "stats_period_s") d.stats_period_s = rd.positive(v, key);
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
  for (const std::string* ch : {&d.window_channel, &d.estimate_channel, &d.stats_channel})
    if (ch->empty()) rd.fail("daemon", "channel names must not be empty");
  return d;
}

ProbeConfig read_probe(const Reader& rd, const std::string& name, const toml::table& t) {
  const std::string p = "probe." + name + ".";
  rd.only_keys(t, p, {"length_m", "width_m", "thickness_m", "youngs_modulus_pa", "density_kg_m3", "f1_hz",
                      "k_c_n_per_m", "quality_factor", "modes", "sensor", "model", "fixed", "unknowns", "inversion"});
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
    g.length_m = rd.positive(need("length_m"), p + "length_m");
    g.width_m = rd.positive(need("width_m"), p + "width_m");
    g.thickness_m = rd.positive(need("thickness_m"), p + "thickness_m");
    g.youngs_modulus_pa = rd.positive(need("youngs_modulus_pa"), p + "youngs_modulus_pa");
    g.density_kg_m3 = rd.positive(need("density_kg_m3"), p + "density_kg_m3");
    pc.spec.cantilever = g;
  } else {
    pc.spec.cantilever = CalibratedProbe{rd.positive(need("f1_hz"), p + "f1_hz"),
                                         rd.positive(need("k_c_n_per_m"), p + "k_c_n_per_m")};
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
        pc.spec.quality_factors.push_back(rd.positive(*arr->get(i), p + "quality_factor[" + std::to_string(i) + "]"));
      if (static_cast<int>(pc.spec.quality_factors.size()) != pc.spec.modes)
        rd.fail(p + "quality_factor", "has " + std::to_string(arr->size()) + " values for " + std::to_string(pc.spec.modes) +
                                          " modes");
    } else {
      pc.spec.quality_factors.push_back(rd.positive(*q, p + "quality_factor"));
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
        pc.space.fix(k.str(), rd.number(v, key));
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
      const double low = rd.number(*arr->get(0), key + "[0]"), high = rd.number(*arr->get(1), key + "[1]");
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
                                        "max_misfit", "start_prior_floor_rel", "trade_off_correlation"});
    auto int_in = [&](const char* key, int lo, int hi, int& dst) {
      if (auto* n = it.get(key)) {
        const int64_t v = rd.integer(*n, p + "inversion." + key);
        if (v < lo || v > hi)
          rd.fail(p + "inversion." + key, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
        dst = static_cast<int>(v);
      }
    };
    int_in("swarm_size", 4, 100000, pc.options.swarm_size);
    int_in("max_generations", 1, 100000, pc.options.max_generations);
    int_in("warm_swarm_size", 4, 100000, pc.options.warm_swarm_size);
    int_in("warm_max_generations", 1, 100000, pc.options.warm_max_generations);
    int_in("stall_generations", 1, 100000, pc.options.stall_generations);
    int_in("lm_max_iterations", 0, 1000, pc.options.lm_max_iterations);
    int_in("cold_lm_max_iterations", 0, 1000, pc.options.cold_lm_max_iterations);
    auto number_in = [&](const char* key, double lo, double hi, double& dst) {
      if (auto* n = it.get(key)) {
        const double v = rd.number(*n, p + "inversion." + key);
        if (!(v >= lo && v <= hi))
          rd.fail(p + "inversion." + key, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
        dst = v;
      }
    };
    number_in("tracking_misfit_ratio", 1.0, 100.0, pc.options.tracking_misfit_ratio);
    number_in("max_misfit", 1e-6, 10.0, pc.options.max_misfit);
    number_in("start_prior_floor_rel", 0.0, 1.0, pc.options.start_prior_floor_rel);
    number_in("trade_off_correlation", 0.5, 1.0, pc.options.trade_off_correlation);
    if (auto* n = it.get("seed")) pc.options.seed = static_cast<std::uint64_t>(rd.integer(*n, p + "inversion.seed"));
  }
  try {
    ModalModel check(pc.spec);
    (void)check;
  } catch (const std::invalid_argument& e) {
    param_error(p.substr(0, p.size() - 1), e);
  }
  return pc;
}

}  // namespace

ProbeModel Config::probe_model(const std::string& name) const {
  auto it = probes.find(name);
  if (it == probes.end()) throw ConfigError(source + ": probe." + name + ": no such probe in the config");
  return ProbeModel{name, ModalModel(it->second.spec), it->second.space, it->second.options};
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
  std::ifstream in(path);
  if (!in) throw ConfigError(path.string() + ": cannot be read");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_config(ss.str(), path.string());
}

}  // namespace tipforce
