#pragma once
#include <cstddef>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "map_grid.hpp"
#include "map_image.hpp"

namespace tipforce::map {
// The truth CSV of `tipforce simulate`: header seq,pixel_x,pixel_y,<param>,... (one column per
// model parameter). Columns are found by name, so their order does not matter.
struct TruthTable {
  std::vector<std::string> params;
  std::map<std::pair<int, int>, std::vector<double>> values;  // (x, y) -> one value per param
  int width = 0, height = 0;   // max pixel + 1
  std::size_t rows = 0;
};
// Throws MapInputError naming the file when it cannot be read or lacks pixel_x / pixel_y, and
// naming the line and what is wrong for a row with too few or too many cells, a pixel index that
// is not a whole number >= 0, a value that is not a finite number, or a pixel already given.
TruthTable read_truth_csv(const std::string& path);

// Accuracy against the truth over a set of pixels.
struct TruthFigures {
  std::size_t compared = 0;            // pixels with a truth and a (non-rejected) estimate
  double median_rel_err = 0;           // |estimate - truth| / |truth| (pixels with truth != 0)
  double p90_rel_err = 0;
  double frac_within_2sigma = 0;       // |estimate - truth| <= 2 sigma (non-finite sigma: no)
  // The error bars' size, so that coverage bought with huge sigmas shows (finite sigmas only):
  double median_rel_sigma = 0;         // median of sigma / |estimate|
  double max_over_median_sigma = 0;    // largest sigma / median sigma
};

// Over every compared pixel (the base), and over the pixels whose estimate is OK only: a
// NOT_CONVERGED window says that its values and sigma are not to be trusted (an undetermined one's
// sigma spans the bounds), and a user's map of trusted pixels is the one `ok` describes.
struct ParamAccuracy : TruthFigures {
  std::string name;
  TruthFigures ok;
  std::string comparison_png;          // truth_<name>.png
  ComparisonImageInfo image;
};

// For every parameter both in the truth and estimated: accuracy and a truth | estimate |
// difference image in out_dir. Parameters only on one side are listed in `only_truth`.
std::vector<ParamAccuracy> compare_with_truth(const TruthTable& truth, const MapSet& maps, const std::string& out_dir,
                                              std::vector<std::string>* only_truth = nullptr);
}  // namespace tipforce::map
