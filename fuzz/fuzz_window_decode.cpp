// libFuzzer: bytes received on the window channel -> decode_window -> the checks of the
// samples (window_problem) and against a probe (window_problem_for_probe) and the escaping of
// names for the log; and the header-only readers the daemon's IO thread uses to pick a window's
// shard and to judge an estimate seen on the estimate channel. Nothing may crash, leak, hang or
// allocate more than the message size allows.
#include <cstddef>
#include <cstdint>
#include <variant>

#include "tipforce/cantilever.hpp"
#include "tipforce/config.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/shard.hpp"

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
  if (d.error.empty() && !tipforce::window_problem(d.window)) (void)tipforce::window_problem_for_probe(d.window, limits);
  const tipforce::ShardSpec shards{1, 3, size % 2 ? tipforce::ShardBy::line : tipforce::ShardBy::probe};
  if (auto h = tipforce::lcmio::decode_window_header(data, size)) (void)shards.owns(h->probe, h->pixel_y);
  if (auto h = tipforce::lcmio::decode_estimate_header(data, size)) (void)shards.owns(h->probe, h->pixel_y);
  return 0;
}
