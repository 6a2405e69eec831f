#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <map>
#include <string>

#include "tipforce/config.hpp"

namespace tipforce {
namespace {

const char* kGood = R"(
[daemon]
queue_capacity = 8
[probe.tip1]
length_m = 525e-6
width_m = 35e-6
thickness_m = 5e-6
youngs_modulus_pa = 1.76e11
density_kg_m3 = 2330
quality_factor = 100
modes = 8
model = "spring"
unknowns = { k_n_per_m = [0.1, 20.0], h_m = [0.0, 60e-9] }
)";

std::string error_of(const std::string& text) {
  try {
    parse_config(text, "test.toml");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(Config, GoodConfigParses) {
  const Config c = parse_config(kGood, "test.toml");
  EXPECT_EQ(c.daemon.queue_capacity, 8);
  ASSERT_EQ(c.probes.count("tip1"), 1u);
  const ProbeModel p = c.probe_model("tip1");
  EXPECT_EQ(p.space.n_unknowns(), 2);
  EXPECT_NEAR(p.modal.modes()[0].frequency_hz, 25468.9, 0.5);
}

TEST(Config, UnknownKeyIsNamedWithFile) {
  const std::string e = error_of(std::string(kGood) + "colour = 3\n");
  EXPECT_NE(e.find("test.toml: probe.tip1.colour: unknown key"), std::string::npos) << e;
  const std::string e2 = error_of("[daemon]\nqueue_capacty = 3\n" + std::string(kGood).substr(std::string(kGood).find("[probe")));
  EXPECT_NE(e2.find("test.toml: daemon.queue_capacty: unknown key"), std::string::npos) << e2;
}

TEST(Config, InvertedBoundsAreNamed) {
  std::string text = kGood;
  text.replace(text.find("[0.1, 20.0]"), 11, "[20.0, 0.1]");
  const std::string e = error_of(text);
  EXPECT_NE(e.find("test.toml: probe.tip1.unknowns.k_n_per_m: bounds are empty or inverted"), std::string::npos) << e;
}

TEST(Config, MissingParameterIsNamed) {
  std::string text = kGood;
  text.replace(text.find(", h_m = [0.0, 60e-9]"), 20, "");
  const std::string e = error_of(text);
  EXPECT_NE(e.find("test.toml: probe.tip1.fixed: parameter 'h_m' of model spring is neither fixed nor unknown"),
            std::string::npos)
      << e;
}

TEST(Config, WrongTypesAndValuesAreNamed) {
  std::string text = kGood;
  text.replace(text.find("modes = 8"), 9, "modes = \"eight\"");
  EXPECT_NE(error_of(text).find("probe.tip1.modes: expected an integer"), std::string::npos) << error_of(text);
  text = kGood;
  text.replace(text.find("model = \"spring\""), 16, "model = \"sprung\"");
  EXPECT_NE(error_of(text).find("probe.tip1.model: unknown model \"sprung\""), std::string::npos);
  EXPECT_NE(error_of("[probe.x]\nmodel = \"none\"\n").find("probe.x: missing the cantilever"), std::string::npos);
  EXPECT_NE(error_of("not toml ===").find("test.toml: line 1"), std::string::npos);
}

// Issue 10: values that parse but are absurd are refused at start, naming the key and the limit.
std::string with(const std::string& from, const std::string& to) {
  std::string text = kGood;
  const auto at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

TEST(ConfigLimits, StatsPeriodBelowTenMillisecondsIsRefused) {
  const std::string e = error_of(with("queue_capacity = 8", "queue_capacity = 8\nstats_period_s = 1e-9"));
  EXPECT_NE(e.find("daemon.stats_period_s: must be between 0.01 s and 86400 s, got 1e-09"), std::string::npos) << e;
  EXPECT_EQ(error_of(with("queue_capacity = 8", "queue_capacity = 8\nstats_period_s = 0.01")), "");
}

TEST(ConfigLimits, GeometryMustBePhysical) {
  std::string e = error_of(with("length_m = 525e-6", "length_m = 1e308"));
  EXPECT_NE(e.find("probe.tip1.length_m: must be between 1 µm and 10 mm, got 1e+308"), std::string::npos) << e;
  e = error_of(with("youngs_modulus_pa = 1.76e11", "youngs_modulus_pa = 1e308"));
  EXPECT_NE(e.find("probe.tip1.youngs_modulus_pa: must be between"), std::string::npos) << e;
  e = error_of(with("quality_factor = 100", "quality_factor = 1e300"));
  EXPECT_NE(e.find("probe.tip1.quality_factor: must be between 0.5 and 1e7"), std::string::npos) << e;
  e = error_of(with("quality_factor = 100", "quality_factor = 0.3"));
  EXPECT_NE(e.find("probe.tip1.quality_factor: must be between 0.5 and 1e7 (an overdamped mode, Q < 0.5, is not "
                   "supported), got 0.3"),
            std::string::npos)
      << e;
  e = error_of(with("quality_factor = 100", "quality_factor = nan"));
  EXPECT_NE(e.find("probe.tip1.quality_factor: must be finite"), std::string::npos) << e;
}

TEST(ConfigLimits, BoundsAndFixedValuesMustBePhysical) {
  std::string e = error_of(with("k_n_per_m = [0.1, 20.0]", "k_n_per_m = [-1e308, 1e308]"));
  EXPECT_NE(e.find("probe.tip1.unknowns.k_n_per_m[0]: must be between 0 and 1e6 N/m, got -1e+308"), std::string::npos)
      << e;
  e = error_of(with("h_m = [0.0, 60e-9]", "h_m = [0.0, inf]"));
  EXPECT_NE(e.find("probe.tip1.unknowns.h_m[1]: must be finite"), std::string::npos) << e;
  e = error_of(with("unknowns = { k_n_per_m = [0.1, 20.0], h_m = [0.0, 60e-9] }",
                    "fixed = { h_m = 1e300 }\nunknowns = { k_n_per_m = [0.1, 20.0] }"));
  EXPECT_NE(e.find("probe.tip1.fixed.h_m: must be between -1 mm and 1 mm"), std::string::npos) << e;
}

TEST(ConfigLimits, ChannelsMustBeDistinct) {
  const std::string e =
      error_of(with("queue_capacity = 8", "queue_capacity = 8\nestimate_channel = \"TIPFORCE_WINDOW\""));
  EXPECT_NE(e.find("daemon: window_channel, estimate_channel and stats_channel must be distinct"), std::string::npos)
      << e;
}

TEST(ConfigLimits, SwarmAndGenerationsAreCapped) {
  const std::string inv = "\n[probe.tip1.inversion]\n";
  std::string e = error_of(kGood + inv + "swarm_size = 100000\n");
  EXPECT_NE(e.find("probe.tip1.inversion.swarm_size: must be in [4, 1000]"), std::string::npos) << e;
  e = error_of(kGood + inv + "max_generations = 100000\n");
  EXPECT_NE(e.find("probe.tip1.inversion.max_generations: must be in [1, 2000]"), std::string::npos) << e;
  e = error_of(kGood + inv + "swarm_size = 1000\nmax_generations = 1000\n");
  EXPECT_NE(e.find("swarm_size x max_generations is 1000000, more than the 200000"), std::string::npos) << e;
  EXPECT_EQ(error_of(kGood + inv + "swarm_size = 100\nmax_generations = 2000\n"), "");
}

TEST(Config, ShardIsReadAndChecked) {
  const ShardSpec none = parse_config(kGood, "t").daemon.shard;
  EXPECT_EQ(none.count, 1);
  EXPECT_FALSE(none.sharded());
  const ShardSpec s =
      parse_config(with("queue_capacity = 8", "shard = { index = 2, count = 3, by = \"line\" }"), "t").daemon.shard;
  EXPECT_EQ(s.index, 2);
  EXPECT_EQ(s.count, 3);
  EXPECT_EQ(s.by, ShardBy::line);
  // The index may come from the command line instead (tipforced --shard-index): 0 until then.
  EXPECT_EQ(parse_config(with("queue_capacity = 8", "shard = { count = 2, by = \"probe\" }"), "t").daemon.shard.index, 0);
  const std::map<std::string, std::string> bad = {
      {"shard = { index = 2, count = 2, by = \"line\" }", "daemon.shard.index: must be in [0, count - 1] = [0, 1], got 2"},
      {"shard = { index = -1, count = 2, by = \"line\" }", "daemon.shard.index: must be in [0, count - 1]"},
      {"shard = { count = 0, by = \"line\" }", "daemon.shard.count: must be in [1, 4096], got 0"},
      {"shard = { count = 100000, by = \"line\" }", "daemon.shard.count: must be in [1, 4096]"},
      {"shard = { count = 2 }", "daemon.shard.by: missing"},
      {"shard = { by = \"line\" }", "daemon.shard.count: missing"},
      {"shard = { count = 2, by = \"pixel\" }", "daemon.shard.by: must be \"probe\" or \"line\", got \"pixel\""},
      {"shard = { count = 2, by = \"line\", colour = 1 }", "daemon.shard.colour: unknown key"},
      {"shard = { count = 2.5, by = \"line\" }", "daemon.shard.count: expected an integer"},
      {"shard = 2", "daemon.shard: expected a table"},
      {"cpu_threads = -1", "daemon.cpu_threads: must be in [0, 1024]"},
  };
  for (const auto& [line, expected] : bad) {
    const std::string e = error_of(with("queue_capacity = 8", line));
    EXPECT_NE(e.find("test.toml: " + expected), std::string::npos) << line << " -> " << e;
  }
  EXPECT_EQ(parse_config(with("queue_capacity = 8", "cpu_threads = 1"), "t").daemon.cpu_threads, 1);
}

TEST(ConfigLimits, WindowSampleCapIsConfigurableUpToTheSpecLimit) {
  EXPECT_EQ(parse_config(kGood, "t").daemon.max_window_samples, 100000);
  EXPECT_EQ(parse_config(with("queue_capacity = 8", "max_window_samples = 1000000"), "t").daemon.max_window_samples,
            1000000);
  const std::string e = error_of(with("queue_capacity = 8", "max_window_samples = 1000001"));
  EXPECT_NE(e.find("daemon.max_window_samples: must be in [16, 1000000]"), std::string::npos) << e;
}

TEST(ConfigLimits, OversizedOrEndlessFileIsRefusedUnread) {
  const auto t0 = std::chrono::steady_clock::now();
  try {
    load_config("/dev/zero");
    ADD_FAILURE() << "/dev/zero accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("/dev/zero: larger than the 1024 KiB a configuration may have"),
              std::string::npos)
        << e.what();
  }
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_LT(took, 2.0);
  std::printf("--config /dev/zero refused after %.3f s\n", took);
}

TEST(Config, PrepareSamplePeriodsAreAListOfAtMostFourPeriods) {
  EXPECT_TRUE(parse_config(kGood, "test.toml").probe_model("tip1").options.prepare_sample_periods_s.empty());
  const auto periods = parse_config(std::string(kGood) + "[probe.tip1.inversion]\nprepare_sample_periods_s = [1e-6, 2e-7]\n",
                                    "test.toml")
                           .probe_model("tip1")
                           .options.prepare_sample_periods_s;
  EXPECT_EQ(periods, (std::vector<double>{1e-6, 2e-7}));
  for (auto [bad, why] : {std::pair{"1e-6", "expected a list of sample periods"},
                          std::pair{"[0.0]", "prepare_sample_periods_s[0]: must be between 0.1 ns and 1 ms"},
                          std::pair{"[1e-6, -1e-6]", "prepare_sample_periods_s[1]: must be between"},
                          std::pair{"[\"1 MHz\"]", "prepare_sample_periods_s[0]: expected a number"},
                          std::pair{"[1e-6, 2e-6, 5e-7, 1e-7, 2e-7]", "has 5 periods; at most 4"}}) {
    const std::string e = error_of(std::string(kGood) + "[probe.tip1.inversion]\nprepare_sample_periods_s = " + bad + "\n");
    EXPECT_NE(e.find(why), std::string::npos) << bad << ": " << e;
  }
}

}  // namespace
}  // namespace tipforce

namespace tipforce {
namespace {

TEST(Config, InversionTuningIsReadAndRangeChecked) {
  const std::string tuned =
      std::string(kGood) + "[probe.tip1.inversion]\ntracking_misfit_ratio = 1.3\nmax_misfit = 0.2\nbound_max_lag1 = 1\n";
  const ProbeModel p = parse_config(tuned, "test.toml").probe_model("tip1");
  EXPECT_DOUBLE_EQ(p.options.tracking_misfit_ratio, 1.3);
  EXPECT_DOUBLE_EQ(p.options.max_misfit, 0.2);
  EXPECT_DOUBLE_EQ(p.options.bound_max_lag1, 1.0);
  const std::string lag = error_of(std::string(kGood) + "[probe.tip1.inversion]\nbound_max_lag1 = 1.5\n");
  EXPECT_NE(lag.find("probe.tip1.inversion.bound_max_lag1: must be in"), std::string::npos) << lag;
  EXPECT_DOUBLE_EQ(p.options.start_prior_floor_rel, InversionOptions{}.start_prior_floor_rel);
  const std::string e = error_of(std::string(kGood) + "[probe.tip1.inversion]\ntracking_misfit_ratio = 0.5\n");
  EXPECT_NE(e.find("probe.tip1.inversion.tracking_misfit_ratio: must be in"), std::string::npos) << e;
}

// The per-probe latency budget: a default that no ordinary fit reaches, 0 for none, and a negative
// or absurd value named.
TEST(Config, DeadlineIsReadWithItsDefaultAndRangeChecked) {
  EXPECT_DOUBLE_EQ(parse_config(kGood, "test.toml").probe_model("tip1").options.deadline_ms, 1000.0);
  const auto budget = [](const std::string& value) {
    return parse_config(std::string(kGood) + "[probe.tip1.inversion]\ndeadline_ms = " + value + "\n", "test.toml")
        .probe_model("tip1")
        .options.deadline_ms;
  };
  EXPECT_DOUBLE_EQ(budget("3"), 3.0);
  EXPECT_DOUBLE_EQ(budget("2.5"), 2.5);
  EXPECT_DOUBLE_EQ(budget("0"), 0.0);
  for (const char* bad : {"-1", "1e9"}) {
    const std::string e = error_of(std::string(kGood) + "[probe.tip1.inversion]\ndeadline_ms = " + bad + "\n");
    EXPECT_NE(e.find("probe.tip1.inversion.deadline_ms: must be in"), std::string::npos) << bad << ": " << e;
  }
}

// Resuming cut fits departs from SPEC 5's letter: off unless the config says true, and anything
// but a boolean named.
TEST(Config, ResumeCutFitsIsOffByDefaultAndMustBeABoolean) {
  EXPECT_FALSE(parse_config(kGood, "test.toml").probe_model("tip1").options.resume_cut_fits);
  EXPECT_TRUE(parse_config(std::string(kGood) + "[probe.tip1.inversion]\nresume_cut_fits = true\n", "test.toml")
                  .probe_model("tip1")
                  .options.resume_cut_fits);
  for (const char* bad : {"1", "\"yes\""}) {
    const std::string e = error_of(std::string(kGood) + "[probe.tip1.inversion]\nresume_cut_fits = " + bad + "\n");
    EXPECT_NE(e.find("probe.tip1.inversion.resume_cut_fits: expected true or false"), std::string::npos)
        << bad << ": " << e;
  }
}

// Pooling along the line: off by default; one number for every unknown, or a table naming each;
// a missing or foreign unknown and a value out of range named.
TEST(Config, ParameterDriftIsOffByDefaultAndNamesEveryUnknown) {
  EXPECT_TRUE(parse_config(kGood, "test.toml").probe_model("tip1").options.parameter_drift_rel.empty());
  const auto drift = [](const std::string& value) {
    return parse_config(std::string(kGood) + "[probe.tip1.inversion]\nparameter_drift_rel = " + value + "\n", "test.toml")
        .probe_model("tip1")
        .options.parameter_drift_rel;
  };
  EXPECT_EQ(drift("0.05"), (std::map<std::string, double>{{"k_n_per_m", 0.05}, {"h_m", 0.05}}));
  EXPECT_EQ(drift("{ k_n_per_m = 0.05, h_m = 0.01 }"), (std::map<std::string, double>{{"k_n_per_m", 0.05}, {"h_m", 0.01}}));
  EXPECT_TRUE(drift("0").empty());
  const std::string key = "probe.tip1.inversion.parameter_drift_rel";
  for (const auto& [bad, expected] :
       std::map<std::string, std::string>{{"-0.1", key + ": must be in [0, 10]"},
                                          {"11", key + ": must be in [0, 10]"},
                                          {"\"5 %\"", key},
                                          {"{ k_n_per_m = 0.05 }", key + ": names no drift for unknown 'h_m'"},
                                          {"{ k_n_per_m = 0.05, h_m = 0.01, c = 1 }", key + ".c: is not an unknown"},
                                          {"{ k_n_per_m = 0.05, h_m = 0 }", key + ".h_m: must be above 0"}}) {
    const std::string e = error_of(std::string(kGood) + "[probe.tip1.inversion]\nparameter_drift_rel = " + bad + "\n");
    EXPECT_NE(e.find(expected), std::string::npos) << bad << ": " << e;
  }
  const std::string gate = error_of(std::string(kGood) + "[probe.tip1.inversion]\npool_gate_chi2 = 1\n");
  EXPECT_NE(gate.find("probe.tip1.inversion.pool_gate_chi2: must be in"), std::string::npos) << gate;
  EXPECT_EQ(parse_config(std::string(kGood) + "[probe.tip1.inversion]\npool_max_iterations = 3\n", "test.toml")
                .probe_model("tip1")
                .options.pool_max_iterations,
            3);
  const std::string its = error_of(std::string(kGood) + "[probe.tip1.inversion]\npool_max_iterations = -1\n");
  EXPECT_NE(its.find("probe.tip1.inversion.pool_max_iterations: must be in"), std::string::npos) << its;
  const InversionOptions valley =
      parse_config(std::string(kGood) + "[probe.tip1.inversion]\npool_gated_iterations = 0\npool_valley_chi2 = 2.5\n",
                   "test.toml")
          .probe_model("tip1")
          .options;
  EXPECT_EQ(valley.pool_gated_iterations, 0);
  EXPECT_EQ(valley.pool_valley_chi2, 2.5);
  for (const auto& [bad, key] : {std::pair{"pool_gated_iterations = -2", "pool_gated_iterations"},
                                 std::pair{"pool_valley_chi2 = -1", "pool_valley_chi2"}}) {
    const std::string e = error_of(std::string(kGood) + "[probe.tip1.inversion]\n" + bad + "\n");
    EXPECT_NE(e.find(std::string("probe.tip1.inversion.") + key + ": must be in"), std::string::npos) << e;
  }
}

}  // namespace
}  // namespace tipforce
