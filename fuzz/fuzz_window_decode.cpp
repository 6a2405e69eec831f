// libFuzzer: bytes received on the window channel -> decode_window -> the checks against a probe
// (window_problem_for_probe) and the escaping of names for the log. Nothing may crash, leak, hang
// or allocate more than the message size allows.
#include <cstddef>
#include <cstdint>
#include <variant>

#include "tipforce/cantilever.hpp"
#include "tipforce/config.hpp"
#include "tipforce/lcm_convert.hpp"

namespace {

// The paper's cantilever, spring model with k and h unknown: the probe of the test scans.
const tipforce::Config& config() {
  static const tipforce::Config c = tipforce::parse_config(R"(
[daemon]
max_window_samples = 20000
[probe.tip]
length_m = 525e-6
width_m = 35e-6
thickness_m = 5e-6
youngs_modulus_pa = 1.76e11
density_kg_m3 = 2330
modes = 3
model = "spring"
unknowns = { k_n_per_m = [0.1, 20.0], h_m = [0.0, 60e-9] }
)",
                                                            "fuzz.toml");
  return c;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const tipforce::ModalModel modal(config().probes.at("tip").spec);
  static const tipforce::WindowLimits limits = tipforce::window_limits(
      modal, std::get<tipforce::BeamGeometry>(config().probes.at("tip").spec.cantilever).length_m,
      config().probes.at("tip").space, config().daemon.max_window_samples);
  tipforce::lcmio::DecodedWindow d = tipforce::lcmio::decode_window(data, size);
  if (d.attributable) (void)tipforce::lcmio::escape_for_log(d.header.probe);
  if (d.error.empty()) (void)tipforce::window_problem_for_probe(d.window, limits);
  return 0;
}
