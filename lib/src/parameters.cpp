#include "tipforce/parameters.hpp"

#include <algorithm>
#include <cmath>

#include "tipforce/assert.hpp"

namespace tipforce {

ParameterSpace::ParameterSpace(ForceModelKind model) : model_(model) {
  for (auto n : force_model_parameters(model)) names_.emplace_back(n);
  for (auto n : kDriveParameterNames) names_.emplace_back(n);
  fixed_.assign(names_.size(), std::nan(""));
}

int ParameterSpace::index_of(std::string_view name) const {
  auto it = std::find(names_.begin(), names_.end(), name);
  return it == names_.end() ? -1 : static_cast<int>(it - names_.begin());
}

void ParameterSpace::fix(std::string_view name, double value) {
  const int i = index_of(name);
  TIPFORCE_THROW_UNLESS(i >= 0, "'" + std::string(name) + "' is not a parameter of model " + std::string(to_string(model_)));
  TIPFORCE_THROW_UNLESS(std::isfinite(value), "'" + std::string(name) + "' must be finite");
  TIPFORCE_THROW_UNLESS(std::find(unknown_index_.begin(), unknown_index_.end(), i) == unknown_index_.end(),
                        "'" + std::string(name) + "' is both fixed and unknown");
  fixed_[static_cast<std::size_t>(i)] = value;
}

void ParameterSpace::make_unknown(std::string_view name, double lower, double upper) {
  const int i = index_of(name);
  TIPFORCE_THROW_UNLESS(i >= 0, "'" + std::string(name) + "' is not a parameter of model " + std::string(to_string(model_)));
  TIPFORCE_THROW_UNLESS(std::isfinite(lower) && std::isfinite(upper), "bounds of '" + std::string(name) + "' must be finite");
  TIPFORCE_THROW_UNLESS(lower < upper, "bounds of '" + std::string(name) + "' are empty or inverted: [" +
                                           std::to_string(lower) + ", " + std::to_string(upper) + "]");
  TIPFORCE_THROW_UNLESS(std::isnan(fixed_[static_cast<std::size_t>(i)]), "'" + std::string(name) + "' is both fixed and unknown");
  TIPFORCE_THROW_UNLESS(std::find(unknown_index_.begin(), unknown_index_.end(), i) == unknown_index_.end(),
                        "'" + std::string(name) + "' is unknown twice");
  unknown_index_.push_back(i);
  lower_.push_back(lower);
  upper_.push_back(upper);
}

std::vector<std::string> ParameterSpace::unknown_names() const {
  std::vector<std::string> out;
  for (int i : unknown_index_) out.push_back(names_[static_cast<std::size_t>(i)]);
  return out;
}

bool ParameterSpace::from_window(std::string_view name) const {
  const int i = index_of(name);
  if (i < 0) return false;
  return std::isnan(fixed_[static_cast<std::size_t>(i)]) &&
         std::find(unknown_index_.begin(), unknown_index_.end(), i) == unknown_index_.end();
}

bool ParameterSpace::drive_is_unknown() const {
  const ParameterLayout layout(model_);
  return std::any_of(unknown_index_.begin(), unknown_index_.end(), [&](int i) { return layout.is_drive(i); });
}

std::vector<std::string> ParameterSpace::missing() const {
  std::vector<std::string> out;
  for (int i = 0; i < ParameterLayout(model_).n_model(); ++i) {
    const bool unknown = std::find(unknown_index_.begin(), unknown_index_.end(), i) != unknown_index_.end();
    if (!unknown && std::isnan(fixed_[static_cast<std::size_t>(i)])) out.push_back(names_[static_cast<std::size_t>(i)]);
  }
  return out;
}

void ParameterSpace::assemble(const Window& window, const double* unknowns, double* full) const {
  const ParameterLayout layout(model_);
  for (int i = 0; i < n_full(); ++i) full[i] = 0.0;
  full[layout.drive_index(DriveParameter::amplitude_m)] = window.drive.amplitude_m;
  full[layout.drive_index(DriveParameter::frequency_hz)] = window.drive.frequency_hz;
  full[layout.drive_index(DriveParameter::phase_rad)] = window.drive.phase_rad;
  full[layout.drive_index(DriveParameter::chirp_hz_per_s)] = window.drive.chirp_hz_per_s;
  for (int i = 0; i < n_full(); ++i) {
    const double f = fixed_[static_cast<std::size_t>(i)];
    if (!std::isnan(f)) full[i] = f;
  }
  for (std::size_t u = 0; u < unknown_index_.size(); ++u) full[unknown_index_[u]] = unknowns[u];
}

}  // namespace tipforce
