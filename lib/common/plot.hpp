#pragma once
/// @file
/// Line plots written as PNG, with no graphics library: for the recorder's tracking figures (like
/// the thesis' figures 5.4–5.15) and anything else the core needs to show a person.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace trocar {

struct PlotSeries {
  std::string label;
  std::vector<double> x, y;
  std::array<std::uint8_t, 3> rgb{0, 0, 0};
};

struct PlotPanel {
  std::string title;
  std::string x_label;
  std::string y_label;
  std::vector<PlotSeries> series;
};

/// An RGB image in memory.
struct Image {
  int width = 0, height = 0;
  std::vector<std::uint8_t> rgb;  ///< row-major, 3 bytes a pixel
  std::array<std::uint8_t, 3> Pixel(int x, int y) const {
    const std::size_t i = 3 * (static_cast<std::size_t>(y) * width + x);
    return {rgb[i], rgb[i + 1], rgb[i + 2]};
  }
};

/// Draws the panels stacked vertically. Non-finite points break a line instead of being drawn.
Image RenderPlot(const std::vector<PlotPanel>& panels, int width = 960, int panel_height = 280);

/// PNG bytes of an image (8-bit RGB, zlib-compressed).
std::string EncodePng(const Image& image);

/// Decodes PNGs written by EncodePng (8-bit RGB, filter 0), for tests and tools.
/// @throws trocar::Error for anything else.
Image DecodePng(const std::string& bytes);

/// RenderPlot + EncodePng, written atomically. @throws trocar::Error naming the path.
void WritePlotPng(const std::string& path, const std::vector<PlotPanel>& panels,
                  int width = 960, int panel_height = 280);

}  // namespace trocar
