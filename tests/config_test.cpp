#include <gtest/gtest.h>

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

}  // namespace
}  // namespace tipforce

namespace tipforce {
namespace {

TEST(Config, InversionTuningIsReadAndRangeChecked) {
  const std::string tuned = std::string(kGood) + "[probe.tip1.inversion]\ntracking_misfit_ratio = 1.3\nmax_misfit = 0.2\n";
  const ProbeModel p = parse_config(tuned, "test.toml").probe_model("tip1");
  EXPECT_DOUBLE_EQ(p.options.tracking_misfit_ratio, 1.3);
  EXPECT_DOUBLE_EQ(p.options.max_misfit, 0.2);
  EXPECT_DOUBLE_EQ(p.options.start_prior_floor_rel, InversionOptions{}.start_prior_floor_rel);
  const std::string e = error_of(std::string(kGood) + "[probe.tip1.inversion]\ntracking_misfit_ratio = 0.5\n");
  EXPECT_NE(e.find("probe.tip1.inversion.tracking_misfit_ratio: must be in"), std::string::npos) << e;
}

}  // namespace
}  // namespace tipforce
