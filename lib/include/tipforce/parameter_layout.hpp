#pragma once
// Where each value sits in a full parameter vector: the force model's parameters (in
// force_model_parameters order), then the four drive parameters (kDriveParameterNames). The layout
// is read through this one type, for a single vector or for set s of a structure-of-arrays batch
// (value k of set s at [k * n_sets + s]), never by hand-computed index.
#include <array>
#include <cstddef>
#include <span>

#include "tipforce/force_model.hpp"

namespace tipforce {

enum class DriveParameter { amplitude_m = 0, frequency_hz = 1, phase_rad = 2, chirp_hz_per_s = 3 };

class ParameterLayout {
 public:
  explicit ParameterLayout(ForceModelKind model)
      : model_(model), n_model_(static_cast<int>(force_model_parameters(model).size())) {}

  ForceModelKind model() const { return model_; }
  int n_model() const { return n_model_; }
  int n_full() const { return n_model_ + kDriveParameterCount; }
  int drive_index(DriveParameter d) const { return n_model_ + static_cast<int>(d); }
  bool is_drive(int index) const { return index >= n_model_ && index < n_full(); }

 private:
  ForceModelKind model_;
  int n_model_;
};

// One set's full parameter vector, read through the layout.
class FullParams {
 public:
  // A contiguous full vector.
  FullParams(const ParameterLayout& layout, std::span<const double> full)
      : layout_(layout), data_(full.data()), stride_(1) {}
  // Set `set` of a structure-of-arrays batch of n_sets sets.
  FullParams(const ParameterLayout& layout, std::span<const double> soa, int n_sets, int set)
      : layout_(layout), data_(soa.data() + set), stride_(static_cast<std::size_t>(n_sets)) {}

  double operator[](int index) const { return data_[static_cast<std::size_t>(index) * stride_]; }
  double model(int k) const { return (*this)[k]; }
  double drive(DriveParameter d) const { return (*this)[layout_.drive_index(d)]; }
  // amplitude, frequency, phase, chirp
  std::array<double, kDriveParameterCount> drive() const {
    return {drive(DriveParameter::amplitude_m), drive(DriveParameter::frequency_hz), drive(DriveParameter::phase_rad),
            drive(DriveParameter::chirp_hz_per_s)};
  }
  ForceParams force_params() const {
    std::array<double, 8> v{};
    for (int k = 0; k < layout_.n_model(); ++k) v[static_cast<std::size_t>(k)] = model(k);
    return force_params_from(layout_.model(), std::span<const double>(v.data(), static_cast<std::size_t>(layout_.n_model())));
  }

 private:
  ParameterLayout layout_;
  const double* data_;
  std::size_t stride_;
};

}  // namespace tipforce
