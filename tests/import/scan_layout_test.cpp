// The raster arithmetic of `tipforce import` against rows worked out by hand.
#include <gtest/gtest.h>

#include "import_error.hpp"
#include "scan_layout.hpp"

namespace {
using tipforce::import::ScanGeometry;

ScanGeometry small() {
  ScanGeometry g;
  g.samples_per_pixel = 10;
  g.pixels_per_line = 3;
  g.lines = 2;
  return g;
}

TEST(ScanLayout, TraceOnlyWindowsFollowEachOther) {
  const ScanGeometry g = small();
  EXPECT_EQ(record_rows_needed(g), 60);
  EXPECT_EQ(window_count(g), 6);
  // rows 0, 10, 20 | 30, 40, 50
  const int rows[] = {0, 10, 20, 30, 40, 50};
  for (int i = 0; i < 6; ++i) {
    const auto s = window_slice(g, i);
    EXPECT_EQ(s.first_row, rows[i]);
    EXPECT_EQ(s.pixel_x, i % 3);
    EXPECT_EQ(s.pixel_y, i / 3);
    EXPECT_EQ(s.line_start, i % 3 == 0);
    EXPECT_EQ(s.continued, i % 3 != 0);
  }
}

TEST(ScanLayout, RetraceRunsRightToLeftAfterTheTrace) {
  ScanGeometry g = small();
  g.trace_and_retrace = true;
  g.keep_retrace = true;
  g.skip_samples = 5;
  g.line_gap_samples = 7;
  // line 0: trace rows 5..34, retrace 35..64; gap 65..71; line 1: trace 72..101, retrace 102..131
  EXPECT_EQ(record_rows_needed(g), 132);
  const int rows[] = {35, 45, 55, 102, 112, 122};
  const int xs[] = {2, 1, 0, 2, 1, 0};
  for (int i = 0; i < 6; ++i) {
    const auto s = window_slice(g, i);
    EXPECT_EQ(s.first_row, rows[i]) << i;
    EXPECT_EQ(s.pixel_x, xs[i]) << i;
    EXPECT_EQ(s.continued, i % 3 != 0) << i;
  }
}

TEST(ScanLayout, PartOfTheDwell) {
  ScanGeometry g = small();
  g.window_offset = 2;
  g.window_length = 5;
  EXPECT_EQ(window_length(g), 5);
  EXPECT_EQ(window_slice(g, 4).first_row, 42);
  EXPECT_FALSE(window_slice(g, 4).continued);
  g.window_length = 0;  // the rest of the dwell: 8 samples, still not contiguous
  EXPECT_EQ(window_length(g), 8);
  EXPECT_FALSE(window_slice(g, 1).continued);
}

TEST(ScanLayout, BadGeometryNamesTheOption) {
  auto message = [](ScanGeometry g) {
    try {
      check_geometry(g);
    } catch (const tipforce::import::ImportError& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  ScanGeometry g = small();
  EXPECT_EQ(message(g), "accepted");
  g.window_offset = 10;
  EXPECT_NE(message(g).find("--window-offset"), std::string::npos);
  g = small();
  g.window_offset = 4;
  g.window_length = 7;
  EXPECT_NE(message(g).find("runs past the dwell"), std::string::npos);
  g = small();
  g.lines = 0;
  EXPECT_NE(message(g).find("--lines"), std::string::npos);
  g = small();
  g.keep_retrace = true;
  EXPECT_NE(message(g).find("--line-layout trace-retrace"), std::string::npos);
  g = small();
  g.samples_per_pixel = 2'000'000;
  EXPECT_NE(message(g).find("more than tipforce inverts"), std::string::npos);
  // Shorter than the fewest samples any probe can be fitted from: every reader would reject it.
  g = small();
  g.window_length = 2;
  EXPECT_NE(message(g).find("--window-length must be 8 to 1000000 samples, got 2"), std::string::npos) << message(g);
  g = small();
  g.window_offset = 3;  // the rest of a 10-sample dwell: 7
  EXPECT_NE(message(g).find("a window of 7 samples"), std::string::npos) << message(g);
  g.window_offset = 2;  // 8: enough
  EXPECT_EQ(message(g), "accepted");
}

}  // namespace
