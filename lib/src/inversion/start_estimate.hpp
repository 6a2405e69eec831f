#pragma once
// Where a window whose start is unknown begins: the drive's linear steady state (the free
// oscillation a far surface leaves), with mode 1 moved to the window's first samples. The start
// shifts of modes 1-2 are then estimated with the parameters; this only has to put them close.
#include <optional>

#include "tipforce/cantilever.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/inversion.hpp"
#include "tipforce/window.hpp"

namespace tipforce::inversion {

// The steady state of every mode (rest for a sampled drive, which has no closed form), then mode
// 1's displacement and velocity from a quadratic fitted to the first samples (over
// options.start_fit_period_fraction of mode 1's period, at least 3 samples), less what the other
// modes contribute to the signal there.
ModalState estimate_unknown_start(const ModalModel& modal, const Window& window, const InversionOptions& options);

// The tip's furthest excursion toward the sample in the window (m): base motion plus measured
// deflection, for a displacement sensor. The surface stops the tip near there, so it is where h
// lies when the tip taps: a cold start's guess at h. Nothing for an optical lever (its reading is
// a slope, not the tip's displacement).
std::optional<double> tip_reach_m(const ModalModel& modal, const Window& window);

}  // namespace tipforce::inversion
