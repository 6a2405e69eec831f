#pragma once
#include <array>
#include <cstdint>
#include <string_view>

namespace tipforce::map {
// An embedded 5x8 pixel ASCII font (printable 32..126; row 7 holds descenders). Each glyph
// occupies a cell of kGlyphAdvance x kLineHeight pixels at scale 1.
inline constexpr int kGlyphWidth = 5;
inline constexpr int kGlyphHeight = 8;
inline constexpr int kGlyphAdvance = 6;
inline constexpr int kLineHeight = 10;

// Rows top to bottom; bit 4 is the leftmost column. Characters outside 32..126 draw as '?'.
const std::array<std::uint8_t, 8>& glyph(char c);

// Width in pixels of s drawn at the given integer scale.
int text_width(std::string_view s, int scale);
}  // namespace tipforce::map
