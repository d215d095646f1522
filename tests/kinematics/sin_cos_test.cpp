// The inline sine-cosine forward kinematics uses agrees with the C library to 2 ulps, keeps the
// identities a rotation needs, and hands what it cannot reduce (huge, infinite, NaN) to the
// library.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "kinematics/sin_cos.hpp"

namespace trocar::kinematics {
namespace {

double Ulps(double got, double want) {
  const double ulp = std::nextafter(std::abs(want), HUGE_VAL) - std::abs(want);
  return std::abs(got - want) / ulp;
}

TEST(SinCos, WithinTwoUlpsOfTheLibraryOverManyAngles) {
  std::mt19937_64 rng(5);
  for (double range : {1e-6, 0.1, 1.0, 2 * M_PI, 10.0, 1e3, 1e6, 9e7}) {
    std::uniform_real_distribution<double> angle(-range, range);
    double worst_sin = 0, worst_cos = 0;
    for (int k = 0; k < 200000; ++k) {
      const double x = angle(rng);
      double s, c;
      SinCos(x, &s, &c);
      worst_sin = std::max(worst_sin, Ulps(s, std::sin(x)));
      worst_cos = std::max(worst_cos, Ulps(c, std::cos(x)));
      ASSERT_NEAR(s * s + c * c, 1.0, 1e-15) << x;
    }
    EXPECT_LE(worst_sin, 2.0) << "range " << range;
    EXPECT_LE(worst_cos, 2.0) << "range " << range;
  }
}

TEST(SinCos, QuadrantBoundariesSignsAndSpecialValues) {
  for (int k = -16; k <= 16; ++k) {  // multiples of π/4, where the reduction switches branches
    for (double nudge : {-1e-12, 0.0, 1e-12}) {
      const double x = k * M_PI / 4 + nudge;
      double s, c;
      SinCos(x, &s, &c);
      EXPECT_NEAR(s, std::sin(x), 3e-16) << x;
      EXPECT_NEAR(c, std::cos(x), 3e-16) << x;
    }
  }
  double s, c;
  SinCos(0.0, &s, &c);
  EXPECT_EQ(s, 0.0);
  EXPECT_EQ(c, 1.0);
  SinCos(1e300, &s, &c);  // beyond the reduction: the library's values
  EXPECT_EQ(s, std::sin(1e300));
  EXPECT_EQ(c, std::cos(1e300));
  SinCos(std::numeric_limits<double>::quiet_NaN(), &s, &c);
  EXPECT_TRUE(std::isnan(s) && std::isnan(c));
  SinCos(HUGE_VAL, &s, &c);
  EXPECT_TRUE(std::isnan(s) && std::isnan(c));
}

}  // namespace
}  // namespace trocar::kinematics
