#include "common/plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>

#include <zlib.h>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar {
namespace {

// A 5x7 bitmap font for the characters plots need (upper case is drawn as lower case).
const std::map<char, const char*>& Font() {
  static const std::map<char, const char*> font = {
      {'0', ".###.#...##..###.#.###..##...#.###."}, {'1', "..#...##....#....#....#....#...###."},
      {'2', ".###.#...#....#...#...#...#...#####"}, {'3', "#####...#...#.....#.....##...#.###."},
      {'4', "...#...##..#.#.#..#.#####...#....#."}, {'5', "######....####.....#....##...#.###."},
      {'6', "..##..#...#....####.#...##...#.###."}, {'7', "#####....#...#...#...#....#....#..."},
      {'8', ".###.#...##...#.###.#...##...#.###."}, {'9', ".###.#...##...#.####....#...#..##.."},
      {'a', "...........###.....#.#####...#.####"}, {'b', "#....#....#.##.##..##...##...#####."},
      {'c', "...........###.#....#....#...#.###."}, {'d', "....#....#.##.##..###...##...#.####"},
      {'e', "...........###.#...#######.....###."}, {'f', "..##..#..#.#...###...#....#....#..."},
      {'g', "......#####...##...#.####....#.###."}, {'h', "#....#....#.##.##..##...##...##...#"},
      {'i', "..#........##....#....#....#...###."}, {'j', "...#........##....#....#.#..#..##.."},
      {'k', "#....#....#..#.#.#..##...#.#..#..#."}, {'l', ".##....#....#....#....#....#...###."},
      {'m', "..........##.#.#.#.##.#.##...##...#"}, {'n', "..........#.##.##..##...##...##...#"},
      {'o', "...........###.#...##...##...#.###."}, {'p', "..........####.#...#####.#....#...."},
      {'q', "...........##.##..##.####....#....#"}, {'r', "..........#.##.##..##....#....#...."},
      {'s', "...........###.#.....###.....#####."}, {'t', ".#....#...###...#....#....#..#..##."},
      {'u', "..........#...##...##...##..##.##.#"}, {'v', "..........#...##...##...#.#.#...#.."},
      {'w', "..........#...##...##.#.##.#.#.#.#."}, {'x', "..........#...#.#.#...#...#.#.#...#"},
      {'y', "..........#...##...#.####....#.###."}, {'z', "..........#####...#...#...#...#####"},
      {' ', "..................................."}, {'.', "..........................##...##.."},
      {',', ".....................##....#...#..."}, {'-', "...............#####..............."},
      {'+', ".......#....#..#####..#....#......."}, {'(', "...#...#...#....#....#.....#.....#."},
      {')', ".#.....#.....#....#....#...#...#..."}, {':', "......##...##........##...##......."},
      {'/', ".........#...#...#...#...#........."}, {'%', "##...##..#...#...#...#...#..##...##"},
      {'_', "..............................#####"}, {'=', "..........#####.....#####.........."},
      {'?', ".###.#...#....#...#...#.........#.."}, {'[', ".###..#....#....#....#....#....###."},
      {']', ".###....#....#....#....#....#..###."},
  };
  return font;
}

constexpr int kTextScale = 2;

struct Canvas {
  Image image;
  void Set(int x, int y, const std::array<std::uint8_t, 3>& c) {
    if (x < 0 || y < 0 || x >= image.width || y >= image.height) return;
    const std::size_t i = 3 * (static_cast<std::size_t>(y) * image.width + x);
    image.rgb[i] = c[0];
    image.rgb[i + 1] = c[1];
    image.rgb[i + 2] = c[2];
  }
  void Line(int x0, int y0, int x1, int y1, const std::array<std::uint8_t, 3>& c, int thickness) {
    const int dx = std::abs(x1 - x0), dy = -std::abs(y1 - y0);
    const int sx = x0 < x1 ? 1 : -1, sy = y0 < y1 ? 1 : -1;
    int err = dx + dy;
    for (;;) {
      for (int a = 0; a < thickness; ++a) {
        for (int b = 0; b < thickness; ++b) Set(x0 + a, y0 + b, c);
      }
      if (x0 == x1 && y0 == y1) break;
      const int e2 = 2 * err;
      if (e2 >= dy) { err += dy; x0 += sx; }
      if (e2 <= dx) { err += dx; y0 += sy; }
    }
  }
  static int TextWidth(const std::string& text) {
    return static_cast<int>(text.size()) * 6 * kTextScale;
  }
  void Text(int x, int y, const std::string& text, const std::array<std::uint8_t, 3>& c) {
    for (char ch : text) {
      const char lower = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
      const auto it = Font().find(lower);
      const char* glyph = it != Font().end() ? it->second : Font().at('?');
      for (int row = 0; row < 7; ++row) {
        for (int col = 0; col < 5; ++col) {
          if (glyph[row * 5 + col] != '#') continue;
          for (int a = 0; a < kTextScale; ++a) {
            for (int b = 0; b < kTextScale; ++b) Set(x + col * kTextScale + a, y + row * kTextScale + b, c);
          }
        }
      }
      x += 6 * kTextScale;
    }
  }
};

// 1-2-5 tick spacing giving about `target` ticks over [lo, hi].
double TickStep(double lo, double hi, int target) {
  const double raw = (hi - lo) / target;
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0, 10.0}) {
    if (m * magnitude >= raw) return m * magnitude;
  }
  return 10 * magnitude;
}

std::string TickLabel(double v, double step) {
  if (std::abs(v) < step * 1e-9) v = 0.0;
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.4g", v);
  return buffer;
}

void AppendChunk(std::string* png, const char* type, const std::string& data) {
  auto be32 = [&](std::uint32_t v) {
    for (int s = 24; s >= 0; s -= 8) png->push_back(static_cast<char>((v >> s) & 0xff));
  };
  be32(static_cast<std::uint32_t>(data.size()));
  std::string body = std::string(type, 4) + data;
  png->append(body);
  be32(static_cast<std::uint32_t>(crc32(0, reinterpret_cast<const Bytef*>(body.data()),
                                        static_cast<uInt>(body.size()))));
}

}  // namespace

Image RenderPlot(const std::vector<PlotPanel>& panels, int width, int panel_height) {
  TROCAR_THROW_UNLESS(!panels.empty() && width >= 200 && panel_height >= 120,
                      "plot: need at least one panel of at least 200 x 120 pixels");
  Canvas canvas;
  canvas.image.width = width;
  canvas.image.height = panel_height * static_cast<int>(panels.size());
  canvas.image.rgb.assign(3 * static_cast<std::size_t>(canvas.image.width) * canvas.image.height, 255);
  const std::array<std::uint8_t, 3> black{0, 0, 0}, grey{220, 220, 220}, dark{90, 90, 90};
  for (std::size_t p = 0; p < panels.size(); ++p) {
    const PlotPanel& panel = panels[p];
    const int top = static_cast<int>(p) * panel_height;
    const int left = 110, right = width - 20, plot_top = top + 44, plot_bottom = top + panel_height - 50;
    // Data range.
    double x_lo = HUGE_VAL, x_hi = -HUGE_VAL, y_lo = HUGE_VAL, y_hi = -HUGE_VAL;
    for (const PlotSeries& s : panel.series) {
      for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
        if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
        x_lo = std::min(x_lo, s.x[i]);
        x_hi = std::max(x_hi, s.x[i]);
        y_lo = std::min(y_lo, s.y[i]);
        y_hi = std::max(y_hi, s.y[i]);
      }
    }
    if (!(x_lo <= x_hi)) { x_lo = 0; x_hi = 1; y_lo = 0; y_hi = 1; }
    if (x_hi - x_lo < 1e-12) { x_lo -= 0.5; x_hi += 0.5; }
    if (y_hi - y_lo < 1e-12 * std::max(1.0, std::abs(y_hi))) {
      const double pad = std::max(1e-9, 0.5 * std::abs(y_hi));
      y_lo -= pad;
      y_hi += pad;
    }
    const double y_step = TickStep(y_lo, y_hi, 5), x_step = TickStep(x_lo, x_hi, 8);
    y_lo = std::floor(y_lo / y_step) * y_step;
    y_hi = std::ceil(y_hi / y_step) * y_step;
    auto px = [&](double x) { return left + static_cast<int>(std::lround((x - x_lo) / (x_hi - x_lo) * (right - left))); };
    auto py = [&](double y) { return plot_bottom - static_cast<int>(std::lround((y - y_lo) / (y_hi - y_lo) * (plot_bottom - plot_top))); };
    // Grid, ticks and labels.
    for (double y = y_lo; y <= y_hi + 0.5 * y_step; y += y_step) {
      canvas.Line(left, py(y), right, py(y), grey, 1);
      const std::string label = TickLabel(y, y_step);
      canvas.Text(left - 8 - Canvas::TextWidth(label), py(y) - 7, label, dark);
    }
    for (double x = std::ceil(x_lo / x_step) * x_step; x <= x_hi + 1e-9 * x_step; x += x_step) {
      canvas.Line(px(x), plot_top, px(x), plot_bottom, grey, 1);
      const std::string label = TickLabel(x, x_step);
      canvas.Text(px(x) - Canvas::TextWidth(label) / 2, plot_bottom + 8, label, dark);
    }
    canvas.Line(left, plot_top, left, plot_bottom, black, 1);
    canvas.Line(left, plot_bottom, right, plot_bottom, black, 1);
    canvas.Line(right, plot_top, right, plot_bottom, black, 1);
    canvas.Line(left, plot_top, right, plot_top, black, 1);
    canvas.Text(left, top + 8, panel.title + (panel.y_label.empty() ? "" : "  [" + panel.y_label + "]"), black);
    canvas.Text((left + right - Canvas::TextWidth(panel.x_label)) / 2, plot_bottom + 28, panel.x_label, dark);
    // Series, then the legend.
    int legend_x = right;
    for (auto it = panel.series.rbegin(); it != panel.series.rend(); ++it) {
      legend_x -= Canvas::TextWidth(it->label) + 40;
      canvas.Line(legend_x, top + 15, legend_x + 24, top + 15, it->rgb, 3);
      canvas.Text(legend_x + 30, top + 8, it->label, black);
    }
    for (const PlotSeries& s : panel.series) {
      bool have_previous = false;
      int x0 = 0, y0 = 0;
      for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
        if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) {
          have_previous = false;
          continue;
        }
        const int x1 = px(s.x[i]), y1 = py(s.y[i]);
        if (have_previous) canvas.Line(x0, y0, x1, y1, s.rgb, 2);
        x0 = x1;
        y0 = y1;
        have_previous = true;
      }
    }
  }
  return canvas.image;
}

std::string EncodePng(const Image& image) {
  std::string raw;
  raw.reserve(static_cast<std::size_t>(image.height) * (1 + 3 * image.width));
  for (int y = 0; y < image.height; ++y) {
    raw.push_back('\0');
    raw.append(reinterpret_cast<const char*>(image.rgb.data()) + 3 * static_cast<std::size_t>(y) * image.width,
               3 * static_cast<std::size_t>(image.width));
  }
  uLongf compressed_size = compressBound(static_cast<uLong>(raw.size()));
  std::string compressed(compressed_size, '\0');
  TROCAR_THROW_UNLESS(compress2(reinterpret_cast<Bytef*>(&compressed[0]), &compressed_size,
                                reinterpret_cast<const Bytef*>(raw.data()), static_cast<uLong>(raw.size()),
                                6) == Z_OK,
                      "PNG: compression failed");
  compressed.resize(compressed_size);
  std::string png("\x89PNG\r\n\x1a\n", 8);
  std::string header;
  for (std::uint32_t v : {static_cast<std::uint32_t>(image.width), static_cast<std::uint32_t>(image.height)}) {
    for (int s = 24; s >= 0; s -= 8) header.push_back(static_cast<char>((v >> s) & 0xff));
  }
  header += std::string("\x08\x02\x00\x00\x00", 5);  // 8-bit RGB, deflate, filter 0, no interlace
  AppendChunk(&png, "IHDR", header);
  AppendChunk(&png, "IDAT", compressed);
  AppendChunk(&png, "IEND", "");
  return png;
}

Image DecodePng(const std::string& bytes) {
  TROCAR_THROW_UNLESS(bytes.size() > 8 && bytes.compare(0, 8, std::string("\x89PNG\r\n\x1a\n", 8)) == 0,
                      "PNG: bad signature");
  auto be32 = [&](std::size_t at) {
    std::uint32_t v = 0;
    for (int k = 0; k < 4; ++k) v = (v << 8) | static_cast<std::uint8_t>(bytes[at + k]);
    return v;
  };
  Image image;
  std::string idat;
  for (std::size_t at = 8; at + 12 <= bytes.size();) {
    const std::uint32_t length = be32(at);
    const std::string type = bytes.substr(at + 4, 4);
    TROCAR_THROW_UNLESS(at + 12 + length <= bytes.size(), "PNG: chunk " << type << " is truncated");
    const std::string data = bytes.substr(at + 8, length);
    const std::uint32_t crc = static_cast<std::uint32_t>(
        crc32(0, reinterpret_cast<const Bytef*>(bytes.data() + at + 4), length + 4));
    TROCAR_THROW_UNLESS(crc == be32(at + 8 + length), "PNG: chunk " << type << " fails its CRC");
    if (type == "IHDR") {
      image.width = static_cast<int>(be32(at + 8));
      image.height = static_cast<int>(be32(at + 12));
      TROCAR_THROW_UNLESS(data[8] == 8 && data[9] == 2 && data[12] == 0, "PNG: only 8-bit RGB");
    } else if (type == "IDAT") {
      idat += data;
    }
    at += 12 + length;
  }
  TROCAR_THROW_UNLESS(image.width > 0 && image.height > 0, "PNG: no IHDR");
  uLongf size = static_cast<uLongf>(image.height) * (1 + 3 * image.width);
  std::string raw(size, '\0');
  TROCAR_THROW_UNLESS(uncompress(reinterpret_cast<Bytef*>(&raw[0]), &size,
                                 reinterpret_cast<const Bytef*>(idat.data()), static_cast<uLong>(idat.size())) == Z_OK &&
                          size == raw.size(),
                      "PNG: image data does not decompress to " << raw.size() << " bytes");
  image.rgb.resize(3 * static_cast<std::size_t>(image.width) * image.height);
  for (int y = 0; y < image.height; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * (1 + 3 * image.width);
    TROCAR_THROW_UNLESS(raw[row] == 0, "PNG: row " << y << " uses a filter (only filter 0 is read)");
    std::memcpy(&image.rgb[3 * static_cast<std::size_t>(y) * image.width], &raw[row + 1], 3 * static_cast<std::size_t>(image.width));
  }
  return image;
}

void WritePlotPng(const std::string& path, const std::vector<PlotPanel>& panels, int width,
                  int panel_height) {
  WriteFileAtomically(path, EncodePng(RenderPlot(panels, width, panel_height)));
}

}  // namespace trocar
