// libFuzzer: configuration text -> parse_config, and every probe's model built from it. A bad
// configuration must end in a ConfigError (file: key: problem), never in a crash, a hang, another
// exception or an absurd allocation.
#include <cstddef>
#include <cstdint>
#include <string>

#include "tipforce/config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > tipforce::kMaxConfigBytes) return -1;  // load_config refuses these unread
  try {
    const tipforce::Config c =
        tipforce::parse_config(std::string(reinterpret_cast<const char*>(data), size), "fuzz.toml");
    for (const auto& [name, probe] : c.probes) (void)c.probe_model(name);
  } catch (const tipforce::ConfigError&) {
  }
  return 0;
}
