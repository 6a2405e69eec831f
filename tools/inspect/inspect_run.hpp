#pragma once
// `tipforce inspect`: one pixel, looked at the way an AFM user checks a fit before believing a
// map. The pixel's window is refitted with the library's Inverter (or its estimate is read from an
// estimates log); the fitted deflection, the tip-sample force and the tip position come from the
// forward solver, started from the start state that fits the window best with the estimate
// held (the inversion fits that state too); the misfit is mapped over the two most
// correlated unknowns around the estimate.
#include <optional>
#include <ostream>
#include <string>
#include <vector>

namespace tipforce::inspect {

class InspectError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};
// The pixel's window is not in the log, and part of the log was damaged: it may have been there
// (exit 3, as tipforce invert and map for damaged input).
class InspectDamagedError : public InspectError {
 public:
  using InspectError::InspectError;
};

struct InspectOptions {
  std::string config, in, estimates, out;
  int pixel_x = 0, pixel_y = 0;
  std::string probe;          // "" = the only probe with a window at the pixel
  int landscape_points = 31;  // per axis
  double landscape_sigmas = 4;
};

struct Curves {
  std::vector<double> t_s, measured_m, fitted_m, residual_m, force_n, tip_z_m;
};

struct Landscape {
  std::string x_name, y_name;       // the two unknowns
  std::vector<double> x, y;         // grid values, SI
  std::vector<double> misfit;       // [iy * x.size() + ix], relative L2
  double x_est = 0, y_est = 0;      // the estimate
  double sx = 0, sy = 0, rho = 0;   // 1-sigma and correlation (the ellipse)
  bool two_d = true;                // false: one unknown, a misfit curve
};

struct InspectReport {
  std::string probe, model;
  std::vector<std::string> names;
  std::vector<double> values, sigma;
  std::string source;               // "refit" or the estimates log
  double estimate_misfit = 0;       // as the fit (or the log) reports it
  double curve_misfit = 0;          // of the fitted curve drawn here
  double h_m = 0;                   // the surface position for force-distance (NaN if none)
  std::vector<double> full;         // the full parameter vector the curves were drawn with
  std::vector<double> start_q, start_v;  // the modal start state of the curves
  Curves curves;
  Landscape landscape;
  std::vector<std::string> files;
};

// Throws InspectError naming the file or the pixel when something is missing or malformed.
InspectReport run_inspect(const InspectOptions& options, std::ostream& out);

// Creates options.out and checks that a file can be written there; throws InspectError naming
// --out otherwise. Called before the fit, which takes seconds: a typo in --out is said at once.
void prepare_output_dir(const InspectOptions& options);

// The figures and CSV files of a report into options.out (inspect_plots.cpp).
void write_inspect_files(const InspectOptions& options, InspectReport& report);

}  // namespace tipforce::inspect
