#pragma once
#include <string>

#include "canvas.hpp"

namespace tipforce::map {
// Writes the canvas as an 8-bit RGB PNG through libpng; throws MapError naming the file.
void write_png(const std::string& path, const Canvas& canvas);
}  // namespace tipforce::map
