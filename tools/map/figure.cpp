#include "figure.hpp"

#include <cairo-pdf.h>
#include <cairo.h>
#include <pango/pangocairo.h>

#include <cmath>
#include <cstring>
#include <memory>

#include "map_error.hpp"

namespace tipforce::map {
namespace {

void set_colour(cairo_t* cr, Rgb c) { cairo_set_source_rgb(cr, c.r / 255.0, c.g / 255.0, c.b / 255.0); }

// Absolute sizes in device units: 1 px in the PNG is 1 pt in the PDF.
PangoLayout* make_layout(cairo_t* cr, const std::string& s, double size_px, bool bold) {
  PangoLayout* layout = pango_cairo_create_layout(cr);
  PangoFontDescription* font = pango_font_description_from_string("DejaVu Sans");
  pango_font_description_set_absolute_size(font, size_px * PANGO_SCALE);
  if (bold) pango_font_description_set_weight(font, PANGO_WEIGHT_BOLD);
  pango_layout_set_font_description(layout, font);
  pango_font_description_free(font);
  pango_layout_set_text(layout, s.c_str(), -1);
  return layout;
}

TextSize layout_size(PangoLayout* layout) {
  int w = 0, h = 0;
  pango_layout_get_pixel_size(layout, &w, &h);
  return {static_cast<double>(w), static_cast<double>(h)};
}

struct SurfaceDeleter {
  void operator()(cairo_surface_t* s) const { cairo_surface_destroy(s); }
};
struct ContextDeleter {
  void operator()(cairo_t* c) const { cairo_destroy(c); }
};

}  // namespace

Raster::Raster(int w, int h, Rgb fill) : width(w), height(h), argb(static_cast<std::size_t>(w) * h) {
  this->fill(0, 0, w, h, fill);
}

void Raster::set(int x, int y, Rgb c) {
  if (x < 0 || y < 0 || x >= width || y >= height) return;
  argb[static_cast<std::size_t>(y) * width + x] = 0xFF000000u | (std::uint32_t{c.r} << 16) | (std::uint32_t{c.g} << 8) | c.b;
}

void Raster::fill(int x, int y, int w, int h, Rgb c) {
  for (int j = y; j < y + h; ++j)
    for (int i = x; i < x + w; ++i) set(i, j, c);
}

void Painter::fill_rect(double x, double y, double w, double h, Rgb c) {
  set_colour(cr_, c);
  cairo_rectangle(cr_, x, y, w, h);
  cairo_fill(cr_);
}

void Painter::frame_rect(double x, double y, double w, double h, Rgb c, double lw) {
  set_colour(cr_, c);
  cairo_set_line_width(cr_, lw);
  cairo_rectangle(cr_, x - lw / 2, y - lw / 2, w + lw, h + lw);
  cairo_stroke(cr_);
}

void Painter::line(double x0, double y0, double x1, double y1, Rgb c, double lw) {
  set_colour(cr_, c);
  cairo_set_line_width(cr_, lw);
  cairo_move_to(cr_, x0, y0);
  cairo_line_to(cr_, x1, y1);
  cairo_stroke(cr_);
}

void Painter::polyline(const std::vector<std::pair<double, double>>& pts, Rgb c, double lw) {
  if (pts.size() < 2) return;
  set_colour(cr_, c);
  cairo_set_line_width(cr_, lw);
  cairo_set_line_join(cr_, CAIRO_LINE_JOIN_ROUND);
  cairo_move_to(cr_, pts[0].first, pts[0].second);
  for (std::size_t i = 1; i < pts.size(); ++i) cairo_line_to(cr_, pts[i].first, pts[i].second);
  cairo_stroke(cr_);
}

void Painter::dot(double x, double y, double r, Rgb c) {
  set_colour(cr_, c);
  cairo_arc(cr_, x, y, r, 0, 2 * M_PI);
  cairo_fill(cr_);
}

void Painter::triangle(double x0, double y0, double x1, double y1, double x2, double y2, Rgb fill, Rgb outline) {
  cairo_move_to(cr_, x0, y0);
  cairo_line_to(cr_, x1, y1);
  cairo_line_to(cr_, x2, y2);
  cairo_close_path(cr_);
  set_colour(cr_, fill);
  cairo_fill_preserve(cr_);
  set_colour(cr_, outline);
  cairo_set_line_width(cr_, 1.0);
  cairo_stroke(cr_);
}

TextSize Painter::text(double x, double y, const std::string& s, double size_px, Align align, Rgb c, bool bold) {
  PangoLayout* layout = make_layout(cr_, s, size_px, bold);
  const TextSize size = layout_size(layout);
  const double left = align == Align::left ? x : align == Align::centre ? x - size.width / 2 : x - size.width;
  set_colour(cr_, c);
  cairo_move_to(cr_, left, y);
  pango_cairo_show_layout(cr_, layout);
  g_object_unref(layout);
  return size;
}

void Painter::text_vertical(double x, double y, const std::string& s, double size_px, Rgb c) {
  PangoLayout* layout = make_layout(cr_, s, size_px, false);
  const TextSize size = layout_size(layout);
  cairo_save(cr_);
  cairo_translate(cr_, x, y);
  cairo_rotate(cr_, -M_PI / 2);
  set_colour(cr_, c);
  cairo_move_to(cr_, -size.width / 2, -size.height / 2);
  pango_cairo_update_layout(cr_, layout);
  pango_cairo_show_layout(cr_, layout);
  cairo_restore(cr_);
  g_object_unref(layout);
}

void Painter::image(int x, int y, const Raster& r) {
  if (r.width <= 0 || r.height <= 0) return;
  // A surface that owns its pixels: a PDF keeps a reference to it until the page is written.
  std::unique_ptr<cairo_surface_t, SurfaceDeleter> s(cairo_image_surface_create(CAIRO_FORMAT_RGB24, r.width, r.height));
  cairo_surface_flush(s.get());
  unsigned char* data = cairo_image_surface_get_data(s.get());
  const int stride = cairo_image_surface_get_stride(s.get());
  for (int j = 0; j < r.height; ++j)
    std::memcpy(data + static_cast<std::size_t>(j) * stride, r.argb.data() + static_cast<std::size_t>(j) * r.width,
                static_cast<std::size_t>(r.width) * 4);
  cairo_surface_mark_dirty(s.get());
  cairo_save(cr_);
  cairo_set_source_surface(cr_, s.get(), x, y);
  cairo_pattern_set_filter(cairo_get_source(cr_), CAIRO_FILTER_NEAREST);
  cairo_rectangle(cr_, x, y, r.width, r.height);
  cairo_fill(cr_);
  cairo_restore(cr_);
}

void Painter::clip(double x, double y, double w, double h) {
  cairo_save(cr_);
  cairo_rectangle(cr_, x, y, w, h);
  cairo_clip(cr_);
}

void Painter::unclip() { cairo_restore(cr_); }

TextSize measure_text(const std::string& s, double size_px, bool bold) {
  std::unique_ptr<cairo_surface_t, SurfaceDeleter> surface(cairo_image_surface_create(CAIRO_FORMAT_RGB24, 1, 1));
  std::unique_ptr<cairo_t, ContextDeleter> cr(cairo_create(surface.get()));
  PangoLayout* layout = make_layout(cr.get(), s, size_px, bold);
  const TextSize size = layout_size(layout);
  g_object_unref(layout);
  return size;
}

std::string pdf_path_for(const std::string& png_path) {
  const auto dot = png_path.rfind(".png");
  return (dot != std::string::npos && dot + 4 == png_path.size() ? png_path.substr(0, dot) : png_path) + ".pdf";
}

void write_figure(const std::string& png_path, int width, int height, const std::function<void(Painter&)>& draw) {
  {
    std::unique_ptr<cairo_surface_t, SurfaceDeleter> surface(cairo_image_surface_create(CAIRO_FORMAT_RGB24, width, height));
    if (cairo_surface_status(surface.get()) != CAIRO_STATUS_SUCCESS)
      throw MapError("cannot make a " + std::to_string(width) + " x " + std::to_string(height) + " image for " + png_path);
    std::unique_ptr<cairo_t, ContextDeleter> cr(cairo_create(surface.get()));
    Painter p(cr.get());
    p.fill_rect(0, 0, width, height, kBackground);
    draw(p);
    cairo_surface_flush(surface.get());
    const cairo_status_t st = cairo_surface_write_to_png(surface.get(), png_path.c_str());
    if (st != CAIRO_STATUS_SUCCESS) throw MapError("cannot write " + png_path + ": " + cairo_status_to_string(st));
  }
  const std::string pdf = pdf_path_for(png_path);
  std::unique_ptr<cairo_surface_t, SurfaceDeleter> surface(cairo_pdf_surface_create(pdf.c_str(), width, height));
  std::unique_ptr<cairo_t, ContextDeleter> cr(cairo_create(surface.get()));
  Painter p(cr.get());
  p.fill_rect(0, 0, width, height, kBackground);
  draw(p);
  cairo_show_page(cr.get());
  cr.reset();
  cairo_surface_finish(surface.get());
  const cairo_status_t st = cairo_surface_status(surface.get());
  if (st != CAIRO_STATUS_SUCCESS) throw MapError("cannot write " + pdf + ": " + cairo_status_to_string(st));
}

}  // namespace tipforce::map
