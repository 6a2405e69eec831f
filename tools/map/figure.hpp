#pragma once
// Figures through Cairo and Pango (Debian's libcairo2 and libpango1.0): antialiased lines and
// text in a real font (DejaVu Sans), drawn once per output so that the PNG (1 px per point) and
// the PDF (vector, for papers) come from the same drawing code.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "colormap.hpp"

typedef struct _cairo cairo_t;

namespace tipforce::map {

// An RGB raster placed 1:1 at integer device coordinates: map pixels stay exact colours in the
// PNG (what the tests read back) and crisp, not interpolated, blocks in the PDF.
struct Raster {
  int width = 0, height = 0;
  std::vector<std::uint32_t> argb;  // cairo's ARGB32, opaque
  Raster(int w, int h, Rgb fill = kBackground);
  void set(int x, int y, Rgb c);
  void fill(int x, int y, int w, int h, Rgb c);
};

enum class Align { left, centre, right };

struct TextSize {
  double width = 0, height = 0;
};

class Painter {
 public:
  explicit Painter(cairo_t* cr) : cr_(cr) {}
  void fill_rect(double x, double y, double w, double h, Rgb c);
  // A 1-unit outline whose inner edge is the rectangle's boundary pixels' outside.
  void frame_rect(double x, double y, double w, double h, Rgb c, double line_width = 1.0);
  void line(double x0, double y0, double x1, double y1, Rgb c, double line_width = 1.0);
  void polyline(const std::vector<std::pair<double, double>>& points, Rgb c, double line_width = 1.0);
  void dot(double x, double y, double radius, Rgb c);
  void triangle(double x0, double y0, double x1, double y1, double x2, double y2, Rgb fill, Rgb outline);
  // Text with its line box's top at y; x is its left edge, centre or right edge. Returns its size.
  TextSize text(double x, double y, const std::string& s, double size_px, Align align = Align::left, Rgb c = kInk,
                bool bold = false);
  // Text turned 90 degrees counter-clockwise (a y-axis label), centred on (x, y).
  void text_vertical(double x, double y, const std::string& s, double size_px, Rgb c = kInk);
  void image(int x, int y, const Raster& r);
  // Clip further drawing to the rectangle until unclip().
  void clip(double x, double y, double w, double h);
  void unclip();

 private:
  cairo_t* cr_;
};

// The size `s` takes at `size_px`, for laying out a figure before it is drawn.
TextSize measure_text(const std::string& s, double size_px, bool bold = false);

// Draws a width x height figure twice, into `png_path` and beside it the same name with .pdf.
// Throws MapError naming the file when either cannot be written.
void write_figure(const std::string& png_path, int width, int height, const std::function<void(Painter&)>& draw);

// PATH.png -> PATH.pdf
std::string pdf_path_for(const std::string& png_path);

}  // namespace tipforce::map
