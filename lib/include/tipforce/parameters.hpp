#pragma once
// Which parameters of a probe's model are fixed and which are unknown, with bounds.
#include <limits>
#include <string>
#include <vector>

#include "tipforce/force_model.hpp"
#include "tipforce/parameter_layout.hpp"
#include "tipforce/window.hpp"

namespace tipforce {

// The full parameter vector is laid out by ParameterLayout (the model's parameters, then the four
// drive parameters). A drive parameter that is neither fixed nor unknown comes from the window.
class ParameterSpace {
 public:
  ParameterSpace() = default;
  explicit ParameterSpace(ForceModelKind model);

  ForceModelKind model() const { return model_; }
  int n_full() const { return static_cast<int>(names_.size()); }
  const std::vector<std::string>& names() const { return names_; }
  // Index of a name in the full vector, or -1.
  int index_of(std::string_view name) const;

  // Throw std::invalid_argument naming the parameter for unknown names, non-finite values,
  // empty or inverted bounds.
  void fix(std::string_view name, double value);
  void make_unknown(std::string_view name, double lower, double upper);

  int n_unknowns() const { return static_cast<int>(unknown_index_.size()); }
  const std::vector<int>& unknown_index() const { return unknown_index_; }
  const std::vector<double>& lower() const { return lower_; }
  const std::vector<double>& upper() const { return upper_; }
  std::vector<std::string> unknown_names() const;
  bool drive_is_unknown() const;
  // True for a parameter that is neither fixed nor unknown: a drive value taken from each window
  // (and so to be checked per window).
  bool from_window(std::string_view name) const;

  // Model parameters neither fixed nor unknown (a config must leave none).
  std::vector<std::string> missing() const;

  // The full vector for given unknowns; drive values not fixed or unknown come from the window.
  void assemble(const Window& window, const double* unknowns, double* full) const;

 private:
  ForceModelKind model_ = ForceModelKind::none;
  std::vector<std::string> names_;
  std::vector<double> fixed_;  // NaN where not fixed
  std::vector<int> unknown_index_;
  std::vector<double> lower_, upper_;
};

}  // namespace tipforce
