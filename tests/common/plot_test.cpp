// Figures by PLplot (cairo) and PNG through VTK's codec: what is drawn is read back from the file.
#include "common/plot.hpp"

#include <cmath>
#include <filesystem>

#include <gtest/gtest.h>
#include <unistd.h>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/image.hpp"

namespace trocar {
namespace {

std::string Temp(const std::string& name) {
  return (std::filesystem::temp_directory_path() / ("trocar_plot_" + std::to_string(::getpid()) + "_" + name)).string();
}

/// A pixel of (antialiased) `rgb`: within 60 of it in each channel, and not grey when `rgb` is
/// not.
bool Like(const std::array<std::uint8_t, 3>& p, const std::array<std::uint8_t, 3>& rgb) {
  for (int c = 0; c < 3; ++c)
    if (std::abs(int(p[c]) - int(rgb[c])) > 60) return false;
  return true;
}

TEST(Png, RoundTripsExactlyAndRefusesWhatIsNotAWholePng) {
  Image image;
  image.width = 37;
  image.height = 11;
  image.rgb.resize(3 * 37 * 11);
  for (std::size_t i = 0; i < image.rgb.size(); ++i) image.rgb[i] = static_cast<std::uint8_t>(i * 7);
  const std::string png = EncodePng(image);
  const Image back = DecodePng(png);
  EXPECT_EQ(back.width, 37);
  EXPECT_EQ(back.height, 11);
  EXPECT_EQ(back.rgb, image.rgb);
  EXPECT_THROW(DecodePng("not a png at all"), Error);
  EXPECT_THROW(DecodePng(png.substr(0, 8)), Error);
  Image empty;
  EXPECT_THROW(EncodePng(empty), Error);
  const std::string path = Temp("round.png");
  WritePng(image, path);
  EXPECT_EQ(ReadPng(path).rgb, image.rgb);
  std::filesystem::remove(path);
  EXPECT_THROW(ReadPng(path), Error);
}

TEST(Plot, DrawsEachSeriesWhereItsDataIsWithRealText) {
  // A rising line in red and a flat line in blue: red pixels climb from left to right, blue
  // pixels stay on one row; axes and text are drawn in black.
  PlotPanel panel;
  panel.title = "Tracking error";
  panel.x_label = "time (s)";
  panel.y_label = "error (mm)";
  PlotSeries rising{"rising", {}, {}, {255, 0, 0}}, flat{"flat", {}, {}, {0, 0, 255}};
  for (int i = 0; i <= 100; ++i) {
    rising.x.push_back(i * 0.1);
    rising.y.push_back(i * 0.1);
    flat.x.push_back(i * 0.1);
    flat.y.push_back(2.0);
  }
  panel.series = {rising, flat};
  const std::string path = Temp("lines.png");
  WritePlot(path, {panel}, 600, 300);
  const Image image = ReadPng(path);
  std::filesystem::remove(path);
  ASSERT_EQ(image.width, 600);
  ASSERT_EQ(image.height, 300);
  auto mean_row = [&](const std::array<std::uint8_t, 3>& rgb, int x_from, int x_to) {
    double sum = 0;
    int n = 0;
    for (int y = 0; y < image.height; ++y)
      for (int x = x_from; x < x_to; ++x)
        if (Like(image.Pixel(x, y), rgb)) sum += y, ++n;
    return n ? sum / n : NAN;
  };
  const double red_left = mean_row({255, 0, 0}, 120, 200), red_right = mean_row({255, 0, 0}, 420, 500);
  ASSERT_TRUE(std::isfinite(red_left) && std::isfinite(red_right));
  EXPECT_GT(red_left, red_right + 60);  // image rows grow downward: the line rises
  const double blue_left = mean_row({0, 0, 255}, 120, 200), blue_right = mean_row({0, 0, 255}, 420, 500);
  ASSERT_TRUE(std::isfinite(blue_left) && std::isfinite(blue_right));
  EXPECT_NEAR(blue_left, blue_right, 2.0);
  long dark = 0, white = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const auto p = image.Pixel(x, y);
      dark += p[0] < 80 && p[1] < 80 && p[2] < 80;
      white += p[0] == 255 && p[1] == 255 && p[2] == 255;
    }
  EXPECT_GT(dark, 800);  // axes, ticks, labels, title
  EXPECT_GT(white, 600 * 300 / 2);  // mostly background
}

TEST(Plot, NonFinitePointsBreakTheLineAndEveryFormatIsWritten) {
  PlotPanel panel;
  // Two stretches of a green line with a hole between x = 1.5 and 2.5.
  PlotSeries s{"s", {0, 1, 1.5, 2, 2.5, 3, 4}, {0, 0, 0, NAN, 0, 0, 0}, {0, 200, 0}};
  panel.series = {s};
  const std::string path = Temp("gap.png");
  WritePlot(path, {panel}, 400, 200);
  const Image image = ReadPng(path);
  std::filesystem::remove(path);
  std::vector<int> columns(image.width, 0);
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) columns[x] += Like(image.Pixel(x, y), {0, 200, 0});
  int drawn = 0, first = -1, last = -1;
  for (int x = 0; x < image.width; ++x)
    if (columns[x]) drawn++, last = x, first = first < 0 ? x : first;
  ASSERT_GT(drawn, 100);
  // The middle of the line's extent (x = 2, the NaN) is not drawn.
  const int middle = (first + last) / 2;
  int around = 0;
  for (int x = middle - 5; x <= middle + 5; ++x) around += columns[x];
  EXPECT_EQ(around, 0);
  for (const char* ext : {".svg", ".pdf"}) {
    const std::string f = Temp(std::string("fmt") + ext);
    WritePlot(f, {panel});
    const std::string bytes = ReadBinaryFile(f);
    EXPECT_NE(bytes.find(ext == std::string(".svg") ? "<svg" : "%PDF"), std::string::npos) << ext;
    std::filesystem::remove(f);
  }
  EXPECT_THROW(WritePlot(Temp("x.gif"), {panel}), Error);
  EXPECT_THROW(WritePlot(Temp("x.png"), {}), Error);
  EXPECT_THROW(WritePlot("/no/such/folder/x.png", {panel}), Error);
}

}  // namespace
}  // namespace trocar
