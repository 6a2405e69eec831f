#pragma once
#include <array>
#include <cstdint>

namespace tipforce::map {
struct Rgb {
  std::uint8_t r = 0, g = 0, b = 0;
  friend bool operator==(const Rgb&, const Rgb&) = default;
};

// matplotlib's viridis (perceptually uniform, colour-blind safe), 256 entries.
const std::array<Rgb, 256>& viridis();

// Colour of value v on the scale lo..hi (hi > lo): index round((v-lo)/(hi-lo)*255), clamped.
int colour_index(double v, double lo, double hi);
Rgb colour_of(double v, double lo, double hi);

// Fixed colours shared by the images and the tests.
inline constexpr Rgb kNoEstimate{128, 128, 128};      // pixel without a (valid) estimate
inline constexpr Rgb kNoEstimateHatch{96, 96, 96};    // its cross-hatch lines (large pixels)
inline constexpr Rgb kStatusOk{26, 152, 80};          // STATUS_OK
inline constexpr Rgb kStatusNotConverged{253, 174, 97};  // STATUS_NOT_CONVERGED
inline constexpr Rgb kStatusRejected{215, 48, 39};    // STATUS_REJECTED (and unknown codes)
inline constexpr Rgb kBackground{255, 255, 255};
inline constexpr Rgb kInk{0, 0, 0};
}  // namespace tipforce::map
