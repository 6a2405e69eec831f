#pragma once
// One rule for every percentile the project reports (the daemon's latency statistics, tipforce
// bench, invert and map, the test tools): three functions with two rules could print two p99s
// for one run.
#include <vector>

namespace tipforce {

// The q-quantile (q clamped to [0, 1]) of the values by nearest rank: the smallest value with at
// least a fraction q of the values at or below it. A value that occurred: a p99 of 3 ms means 99 %
// of the windows were answered within 3 ms. NaN for no values.
double percentile(std::vector<double> values, double q);

}  // namespace tipforce
