#include <cstdio>
#include <iostream>

#include "cli_common.hpp"
#include "commands.hpp"

namespace tipforce::cli {

void add_modes_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("modes", "Modal analysis of a configured probe");
  auto config = std::make_shared<std::string>();
  auto probe = std::make_shared<std::string>();
  auto json = std::make_shared<bool>(false);
  cmd->add_option("--config", *config, "Config file (TOML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--probe", *probe, "Probe name ([probe.NAME] in the config)")->required();
  cmd->add_flag("--json", *json, "Print JSON instead of a table");
  cmd->callback([=] {
    const Config c = load_config_or_exit(*config);
    if (!c.probes.count(*probe)) {
      std::cerr << "tipforce modes: " << *config << ": probe." << *probe << ": no such probe in the config\n";
      throw CLI::RuntimeError(2);
    }
    const ProbeModel p = c.probe_model(*probe);
    const auto& modes = p.modal.modes();
    if (*json) {
      std::printf("{\"modes\": [");
      for (std::size_t i = 0; i < modes.size(); ++i)
        std::printf("%s{\"frequency_hz\": %.10g, \"quality_factor\": %.10g, \"phi_tip\": %.10g, \"gamma\": %.10g}",
                    i ? ", " : "", modes[i].frequency_hz, modes[i].quality_factor, modes[i].phi_tip, modes[i].gamma);
      std::printf("], \"static_stiffness_n_per_m\": %.10g}\n", p.modal.static_stiffness_n_per_m());
      return;
    }
    std::printf("probe %s: static stiffness %.6g N/m, modal mass (mu L) %.6g kg\n", probe->c_str(),
                p.modal.static_stiffness_n_per_m(), p.modal.modal_mass_kg());
    std::printf("%4s %16s %14s %10s %10s\n", "mode", "frequency_hz", "quality_factor", "phi_tip", "gamma");
    for (std::size_t i = 0; i < modes.size(); ++i)
      std::printf("%4zu %16.3f %14.3f %10.5f %10.5f\n", i + 1, modes[i].frequency_hz, modes[i].quality_factor,
                  modes[i].phi_tip, modes[i].gamma);
  });
}

}  // namespace tipforce::cli
