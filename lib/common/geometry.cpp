#include "common/geometry.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <cstdlib>
#include <iomanip>
#include <sstream>

namespace trocar {

Eigen::Matrix3d RotationFromRpy(const Eigen::Vector3d& rpy) {
  return (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

Eigen::Vector3d RpyFromRotation(const Eigen::Matrix3d& R) {
  const double pitch = std::atan2(-R(2, 0), std::hypot(R(0, 0), R(1, 0)));
  double roll = 0.0;
  double yaw = 0.0;
  if (std::abs(std::cos(pitch)) > 1e-12) {
    roll = std::atan2(R(2, 1), R(2, 2));
    yaw = std::atan2(R(1, 0), R(0, 0));
  } else {
    // Gimbal lock: only roll - yaw (or roll + yaw) is defined; put it all in yaw.
    yaw = std::atan2(-R(0, 1), R(1, 1));
  }
  return {roll, pitch, yaw};
}

Eigen::Isometry3d MakeTransform(const Eigen::Vector3d& xyz, const Eigen::Vector3d& rpy) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = RotationFromRpy(rpy);
  X.translation() = xyz;
  return X;
}

Eigen::Isometry3d RotX(double angle) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  const double c = std::cos(angle), s = std::sin(angle);
  X.linear() << 1, 0, 0, 0, c, -s, 0, s, c;
  return X;
}

Eigen::Isometry3d RotZ(double angle) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  const double c = std::cos(angle), s = std::sin(angle);
  X.linear() << c, -s, 0, s, c, 0, 0, 0, 1;
  return X;
}

Eigen::Isometry3d TransX(double distance) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation().x() = distance;
  return X;
}

Eigen::Isometry3d TransZ(double distance) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation().z() = distance;
  return X;
}

double WrapAngle(double angle) {
  if (angle > -M_PI && angle <= M_PI) return angle;  // the common case, exactly as below
  double a = std::remainder(angle, 2.0 * M_PI);
  if (a <= -M_PI) a += 2.0 * M_PI;
  return a;
}

double RotationDistance(const Eigen::Matrix3d& R_a, const Eigen::Matrix3d& R_b) {
  return Eigen::AngleAxisd(R_a.transpose() * R_b).angle();
}

namespace {

std::string Trim(const std::string& s) {
  const auto begin = s.find_first_not_of(" \t");
  if (begin == std::string::npos) return "";
  const auto end = s.find_last_not_of(" \t");
  return s.substr(begin, end - begin + 1);
}

bool ParsePlainNumber(const std::string& text, double* value) {
  if (text.empty()) return false;
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (end != text.c_str() + text.size()) return false;
  *value = v;
  return true;
}

}  // namespace

bool ParseScalarExpression(const std::string& raw, double* value) {
  std::string text = Trim(raw);
  if (text.empty()) return false;
  double v = 0.0;
  if (ParsePlainNumber(text, &v)) {
    *value = v;
    return true;
  }
  // "<number> deg" / "<number>deg"
  if (text.size() > 3 && text.compare(text.size() - 3, 3, "deg") == 0) {
    if (!ParsePlainNumber(Trim(text.substr(0, text.size() - 3)), &v)) return false;
    *value = v * M_PI / 180.0;
    return true;
  }
  // [-][k*]pi[/n]
  double sign = 1.0;
  if (text[0] == '-' || text[0] == '+') {
    sign = text[0] == '-' ? -1.0 : 1.0;
    text = Trim(text.substr(1));
  }
  const auto pi_pos = text.find("pi");
  if (pi_pos == std::string::npos) return false;
  double factor = 1.0;
  const std::string before = Trim(text.substr(0, pi_pos));
  if (!before.empty()) {
    if (before.back() != '*') return false;
    if (!ParsePlainNumber(Trim(before.substr(0, before.size() - 1)), &factor)) return false;
  }
  double divisor = 1.0;
  const std::string after = Trim(text.substr(pi_pos + 2));
  if (!after.empty()) {
    if (after[0] != '/') return false;
    if (!ParsePlainNumber(Trim(after.substr(1)), &divisor) || divisor == 0.0) return false;
  }
  *value = sign * factor * M_PI / divisor;
  return true;
}

std::string FormatVector(const Eigen::Ref<const Eigen::VectorXd>& v, int precision) {
  std::ostringstream out;
  out << std::setprecision(precision) << "[";
  for (Eigen::Index i = 0; i < v.size(); ++i) {
    if (i > 0) out << ", ";
    out << v[i];
  }
  out << "]";
  return out.str();
}

std::string FormatError(double value, const char* unit, double resolution) {
  std::ostringstream out;
  const int decimals = std::max(0, static_cast<int>(std::ceil(-std::log10(resolution) - 1e-9)));
  if (std::abs(value) < resolution) {
    out << "under " << std::fixed << std::setprecision(decimals) << resolution << " " << unit;
  } else {
    out << std::fixed << std::setprecision(decimals) << value << " " << unit;
  }
  return out.str();
}

double Median(std::vector<double> values) {
  if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::sort(values.begin(), values.end());
  const std::size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

}  // namespace trocar
