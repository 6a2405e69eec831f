#pragma once
#include <string>
#include <string_view>
#include <vector>

#include "colormap.hpp"

namespace tipforce::map {
// An 8-bit RGB raster, row 0 at the top. Drawing outside the canvas is clipped silently.
class Canvas {
 public:
  Canvas(int width, int height, Rgb fill = kBackground);

  int width() const { return width_; }
  int height() const { return height_; }
  const std::vector<std::uint8_t>& pixels() const { return px_; }  // RGBRGB..., row-major

  void set(int x, int y, Rgb c);
  Rgb get(int x, int y) const;
  void fill_rect(int x, int y, int w, int h, Rgb c);
  void frame_rect(int x, int y, int w, int h, Rgb c);  // 1 px outline
  void hline(int x0, int x1, int y, Rgb c);
  void vline(int x, int y0, int y1, Rgb c);
  void line(int x0, int y0, int x1, int y1, Rgb c);  // Bresenham
  // Text with the embedded font; (x, y) is the top-left of the first glyph cell.
  void text(int x, int y, std::string_view s, Rgb c, int scale = 2);

 private:
  int width_, height_;
  std::vector<std::uint8_t> px_;
};
}  // namespace tipforce::map
