#include "png_writer.hpp"

#include <png.h>

#include <cstring>

#include "map_error.hpp"

namespace tipforce::map {
void write_png(const std::string& path, const Canvas& canvas) {
  png_image image;
  std::memset(&image, 0, sizeof image);
  image.version = PNG_IMAGE_VERSION;
  image.width = static_cast<png_uint_32>(canvas.width());
  image.height = static_cast<png_uint_32>(canvas.height());
  image.format = PNG_FORMAT_RGB;
  const int ok = png_image_write_to_file(&image, path.c_str(), 0, canvas.pixels().data(),
                                         canvas.width() * 3, nullptr);
  if (!ok) {
    const std::string why = image.message[0] ? image.message : "unknown libpng error";
    png_image_free(&image);
    throw MapError("cannot write " + path + ": " + why);
  }
}
}  // namespace tipforce::map
