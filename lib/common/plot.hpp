#pragma once
/// @file
/// Line plots by PLplot (its cairo drivers: real fonts, no display): PNG, SVG or PDF, for the
/// recorder's tracking figures (like the thesis' figures 5.4–5.15), trocar bench's summaries and
/// anything else the core needs to show a person.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "common/image.hpp"

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

/// Writes the panels stacked vertically, `width` × `panel_height` pixels each (a PDF or SVG at the
/// same size in points), by the path's extension: .png, .svg or .pdf; atomically. Non-finite
/// points break a line instead of being drawn; each series is labelled in its colour.
/// @throws trocar::Error naming the path for another extension, no panels, a size out of
/// 64..8192, or a file that cannot be written.
void WritePlot(const std::string& path, const std::vector<PlotPanel>& panels, int width = 960,
               int panel_height = 280);

}  // namespace trocar
