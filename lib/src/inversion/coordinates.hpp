#pragma once
// The coordinates every stage works in: the unknowns normalised to their bounds ([0, 1] each, so
// that one step size and one tolerance serve k in N/m and h in m alike), and, for a window whose
// start is not known exactly, shifts of modes 1-2's initial displacement and velocity scaled to
// the window's signal (so that a shift of 1 moves the tip by about the signal's rms).
#include <algorithm>
#include <vector>

#include <Eigen/Dense>

#include "tipforce/cantilever.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/parameters.hpp"

namespace tipforce::inversion {

// Modes whose initial state a free start estimates: mode 1 carries the oscillation, and the
// impacts keep mode 2 ringing, which no steady state predicts.
inline constexpr int kStartModes = 2;

inline double clamp01(double v) { return std::clamp(v, 0.0, 1.0); }

// A normalised unknown within `tolerance` of either bound (InversionOptions::at_bound_tolerance).
inline bool at_bound(double x, double tolerance) { return x <= tolerance || x >= 1 - tolerance; }

// The bounds as prior knowledge: a uniform distribution over [0, 1] has variance 1/12, so as
// Gaussian information on a normalised unknown they count 12.
inline constexpr double kBoundsInformation = 12.0;

// One candidate: unknowns (normalised) and start shifts (scaled units).
struct Point {
  std::vector<double> x;
  double dq[kStartModes] = {0, 0}, dv[kStartModes] = {0, 0};
  bool shifted() const { return dq[0] != 0 || dv[0] != 0 || dq[1] != 0 || dv[1] != 0; }
};

class Coordinates {
 public:
  // signal_scale_m: the window's signal rms (floored by the caller). start_free: whether the start
  // shifts are unknowns of the polish (every start but rest).
  Coordinates(const ParameterSpace& space, const ModalModel& modal, double signal_scale_m, bool start_free);

  int n_unknowns() const { return m_; }
  int n_start_modes() const { return n_modes_; }
  // The start block: displacement and velocity of each start mode (the prior's size).
  int n_start_block() const { return 2 * n_modes_; }
  // Start shifts among the packed unknowns: the start block when the start is free, else none.
  int n_start_unknowns() const { return start_free_ ? 2 * n_modes_ : 0; }
  int n_packed() const { return m_ + n_start_unknowns(); }
  double q_scale(int mode) const { return q_scale_[mode]; }
  double v_scale(int mode) const { return v_scale_[mode]; }
  double width(int j) const { return hi_[j] - lo_[j]; }

  // The unknowns' values for normalised x.
  std::vector<double> values(const std::vector<double>& x) const;
  // A value's normalised coordinate, clamped to the bounds.
  double unit(int j, double value) const { return clamp01((value - lo_[j]) / (hi_[j] - lo_[j])); }
  // The middle of the bounds, unshifted.
  Point centre() const;

  // Unknowns, then (start free) dq, dv of each start mode.
  Eigen::VectorXd pack(const Point& p) const;
  // The inverse, with the unknowns clamped to their bounds.
  Point unpack(const Eigen::VectorXd& v) const;
  // `start` moved by p's shifts.
  ModalState shifted(const ModalState& start, const Point& p) const;

 private:
  int m_ = 0, n_modes_ = 0;
  bool start_free_ = false;
  std::vector<double> lo_, hi_;
  double q_scale_[kStartModes] = {0, 0}, v_scale_[kStartModes] = {0, 0};
};

}  // namespace tipforce::inversion
