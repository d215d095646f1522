#include "common/plot.hpp"

#include <cmath>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar {
namespace {

int CountColour(const Image& image, const std::array<std::uint8_t, 3>& rgb) {
  int n = 0;
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) n += image.Pixel(x, y) == rgb;
  }
  return n;
}

TEST(Plot, PngRoundTripsExactly) {
  Image image;
  image.width = 37;
  image.height = 11;
  image.rgb.resize(3 * 37 * 11);
  for (std::size_t i = 0; i < image.rgb.size(); ++i) image.rgb[i] = static_cast<std::uint8_t>(i * 7);
  const Image back = DecodePng(EncodePng(image));
  EXPECT_EQ(back.width, 37);
  EXPECT_EQ(back.height, 11);
  EXPECT_EQ(back.rgb, image.rgb);
  std::string corrupt = EncodePng(image);
  corrupt[40] ^= 0x55;
  EXPECT_THROW(DecodePng(corrupt), Error);
}

TEST(Plot, DrawsEachSeriesWhereItsDataIs) {
  // A rising line in red and a flat line in blue: red pixels climb from left to right, blue
  // pixels stay on one row; text and axes are drawn too.
  PlotPanel panel;
  panel.title = "test";
  panel.x_label = "time (s)";
  PlotSeries rising{"rising", {}, {}, {255, 0, 0}}, flat{"flat", {}, {}, {0, 0, 255}};
  for (int i = 0; i <= 100; ++i) {
    rising.x.push_back(i * 0.1);
    rising.y.push_back(i * 0.1);
    flat.x.push_back(i * 0.1);
    flat.y.push_back(2.0);
  }
  panel.series = {rising, flat};
  const Image image = DecodePng(EncodePng(RenderPlot({panel}, 600, 300)));
  ASSERT_EQ(image.width, 600);
  ASSERT_EQ(image.height, 300);
  auto mean_row = [&](const std::array<std::uint8_t, 3>& rgb, int x_from, int x_to) {
    double sum = 0;
    int n = 0;
    for (int y = 40; y < 250; ++y) {  // inside the plot area, below the legend
      for (int x = x_from; x < x_to; ++x) {
        if (image.Pixel(x, y) == rgb) {
          sum += y;
          ++n;
        }
      }
    }
    return n ? sum / n : NAN;
  };
  const double red_left = mean_row({255, 0, 0}, 130, 200), red_right = mean_row({255, 0, 0}, 500, 570);
  ASSERT_TRUE(std::isfinite(red_left) && std::isfinite(red_right));
  EXPECT_GT(red_left, red_right + 100);  // image rows grow downward: the line rises
  const double blue_left = mean_row({0, 0, 255}, 130, 200), blue_right = mean_row({0, 0, 255}, 500, 570);
  EXPECT_NEAR(blue_left, blue_right, 1.0);
  EXPECT_GT(CountColour(image, {0, 0, 0}), 500);  // axes and text
  EXPECT_GT(CountColour(image, {255, 255, 255}), 600 * 300 / 2);  // mostly background
}

TEST(Plot, NonFinitePointsBreakTheLine) {
  PlotPanel panel;
  PlotSeries s{"s", {0, 1, 2, 3, 4}, {0, 1, NAN, 1, 0}, {0, 200, 0}};
  panel.series = {s};
  const Image image = RenderPlot({panel}, 400, 200);
  EXPECT_GT(CountColour(image, {0, 200, 0}), 50);
}

}  // namespace
}  // namespace trocar
