#include "common/plot.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <mutex>

#include <plplot/plstream.h>
#include <unistd.h>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar {
namespace {

/// PLplot keeps global state: one figure at a time.
std::mutex& PlplotMutex() {
  static std::mutex m;
  return m;
}

std::string Extension(const std::string& path) {
  const std::string ext = std::filesystem::path(path).extension().string();
  std::string lower;
  for (char c : ext) lower += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return lower;
}

/// Finite x, y extent of a panel's series, padded by 5 % (±1 where flat).
void Extent(const PlotPanel& panel, double* x0, double* x1, double* y0, double* y1) {
  double xl = std::numeric_limits<double>::infinity(), xh = -xl, yl = xl, yh = -xl;
  for (const PlotSeries& s : panel.series) {
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      xl = std::min(xl, s.x[i]);
      xh = std::max(xh, s.x[i]);
      yl = std::min(yl, s.y[i]);
      yh = std::max(yh, s.y[i]);
    }
  }
  if (!(xl <= xh)) xl = 0, xh = 1;
  if (!(yl <= yh)) yl = 0, yh = 1;
  if (xh - xl < 1e-12) xl -= 1, xh += 1;
  if (yh - yl < 1e-12) yl -= 1, yh += 1;
  const double py = 0.05 * (yh - yl);
  *x0 = xl, *x1 = xh, *y0 = yl - py, *y1 = yh + py;
}

}  // namespace

void WritePlot(const std::string& path, const std::vector<PlotPanel>& panels, int width, int panel_height) {
  const std::string ext = Extension(path);
  const char* device = ext == ".png" ? "pngcairo" : ext == ".svg" ? "svgcairo" : ext == ".pdf" ? "pdfcairo" : nullptr;
  TROCAR_THROW_UNLESS(device, path << ": a figure is .png, .svg or .pdf, not '" << ext << "'");
  TROCAR_THROW_UNLESS(!panels.empty(), path << ": a figure needs at least one panel");
  const long height = static_cast<long>(panel_height) * static_cast<long>(panels.size());
  TROCAR_THROW_UNLESS(width >= 64 && width <= 8192 && panel_height >= 64 && height <= 8192,
                      path << ": figure size " << width << "x" << height << ": expected 64..8192 a side");
  // PLplot ends the process when it cannot open its file: it writes into a fresh temporary file
  // of ours, which is then moved into place (WriteFileAtomically).
  const std::string tmp = (std::filesystem::temp_directory_path() /
                           ("trocar-plot-" + std::to_string(::getpid()) + "-" +
                            std::to_string(reinterpret_cast<std::uintptr_t>(&panels)) + ext))
                              .string();
  {
    std::lock_guard<std::mutex> lock(PlplotMutex());
    plstream pls;
    pls.sdev(device);
    pls.sfnam(tmp.c_str());
    const std::string geometry = std::to_string(width) + "x" + std::to_string(height);
    pls.setopt("geometry", geometry.c_str());
    pls.scolbg(255, 255, 255);
    pls.scol0(1, 0, 0, 0);
    pls.scol0(15, 215, 215, 215);
    pls.ssub(1, static_cast<PLINT>(panels.size()));
    pls.init();
    for (const PlotPanel& panel : panels) {
      double x0, x1, y0, y1;
      Extent(panel, &x0, &x1, &y0, &y1);
      pls.adv(0);
      pls.vsta();
      pls.wind(x0, x1, y0, y1);
      pls.col0(15);  // the grid in light grey, under the axes in black
      pls.width(1);
      pls.box("g", 0, 0, "g", 0, 0);
      pls.col0(1);
      pls.box("bcnst", 0, 0, "bcnstv", 0, 0);
      pls.lab(panel.x_label.c_str(), panel.y_label.c_str(), panel.title.c_str());
      for (std::size_t k = 0; k < panel.series.size(); ++k) {
        const PlotSeries& s = panel.series[k];
        const PLINT colour = static_cast<PLINT>(2 + k % 13);
        pls.scol0(colour, s.rgb[0], s.rgb[1], s.rgb[2]);
        pls.col0(colour);
        pls.width(2);
        std::vector<PLFLT> x, y;
        auto flush = [&] {
          if (x.size() >= 2) pls.line(static_cast<PLINT>(x.size()), x.data(), y.data());
          x.clear();
          y.clear();
        };
        for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
          if (std::isfinite(s.x[i]) && std::isfinite(s.y[i])) {
            x.push_back(s.x[i]);
            y.push_back(s.y[i]);
          } else {
            flush();
          }
        }
        flush();
        if (!s.label.empty()) pls.mtex("t", -1.5 - 1.3 * static_cast<double>(k), 0.98, 1.0, s.label.c_str());
      }
    }
  }  // plend: the file is complete
  std::string bytes;
  try {
    bytes = ReadBinaryFile(tmp);
  } catch (const Error&) {
  }
  std::error_code ec;
  std::filesystem::remove(tmp, ec);
  TROCAR_THROW_UNLESS(!bytes.empty(), path << ": PLplot wrote no figure");
  WriteFileAtomically(path, bytes);
}

}  // namespace trocar
