#pragma once
/// @file
/// Sine and cosine of one angle together, inline, for forward kinematics (a revolute joint needs
/// both of its value, and the library call is most of a joint's cost). The method is Cephes'
/// (S. Moshier): reduction by π/4 in three parts (Cody-Waite), then minimax polynomials on
/// [-π/4, π/4]; within 2 ulps of the C library's results for |x| < 1e8 (tested against it over
/// millions of angles). Larger or non-finite angles go to the C library.

#include <cmath>

namespace trocar::kinematics {

inline void SinCos(double x, double* sin_x, double* cos_x) {
  if (!(std::abs(x) < 1e8)) {  // also NaN and infinities: the library's answer
    *sin_x = std::sin(x);
    *cos_x = std::cos(x);
    return;
  }
  constexpr double kFourOverPi = 1.27323954473516268615;
  constexpr double kDp1 = 7.85398125648498535156e-1;  // π/4 = kDp1 + kDp2 + kDp3
  constexpr double kDp2 = 3.77489470793079817668e-8;
  constexpr double kDp3 = 2.69515142907905952645e-15;
  double sin_sign = 1.0;
  double a = x;
  if (a < 0) {
    a = -a;
    sin_sign = -1.0;
  }
  long j = static_cast<long>(a * kFourOverPi);  // a >= 0: truncation is the floor
  double y = static_cast<double>(j);
  if (j & 1) {  // map zeros to origin
    j += 1;
    y += 1.0;
  }
  j &= 7;
  const double z = ((a - y * kDp1) - y * kDp2) - y * kDp3;
  const double zz = z * z;
  // sin(z) and cos(z) on [-π/4, π/4].
  const double s = z + z * zz *
      ((((((1.58962301576546568060e-10 * zz - 2.50507477628578072866e-8) * zz +
           2.75573136213857245213e-6) * zz - 1.98412698295895385996e-4) * zz +
         8.33333333332211858878e-3) * zz) - 1.66666666666666307295e-1);
  const double c = 1.0 - 0.5 * zz + zz * zz *
      ((((((-1.13585365213876817300e-11 * zz + 2.08757008419747316778e-9) * zz -
           2.75573141792967388112e-7) * zz + 2.48015872888517045348e-5) * zz -
         1.38888888888730564116e-3) * zz) + 4.16666666666665929218e-2);
  double cos_sign = 1.0;
  if (j > 3) {
    j -= 4;
    sin_sign = -sin_sign;
    cos_sign = -cos_sign;
  }
  if (j > 1) cos_sign = -cos_sign;
  const bool swap = (j == 1 || j == 2);
  *sin_x = sin_sign * (swap ? c : s);
  *cos_x = cos_sign * (swap ? s : c);
}

}  // namespace trocar::kinematics
