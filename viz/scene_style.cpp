#include "scene.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "common/error.hpp"

// The scene's style (colours, opacities and visibility by group) and the parsing of style and
// base-pose text (no VTK: the scene file's reader and its fuzz target use them without the
// renderer).
namespace trocar::viz {
namespace {

bool IsBone(const std::string& name) {
  return name == "ribs" || name == "sternum" || name == "spine" || name == "bone" ||
         name == "girdle" || name == "costal_cartilage";
}

std::string KindOf(const std::string& group) {
  if (group.rfind("target:", 0) == 0) return "target";
  return group;
}

}  // namespace

SceneStyle SceneStyle::Default() {
  SceneStyle s;
  s.colours = {
      {"skin", {0.93, 0.74, 0.62}},         {"ribs", {0.95, 0.93, 0.84}},
      {"sternum", {0.92, 0.90, 0.78}},      {"spine", {0.86, 0.84, 0.74}},
      {"bone", {0.90, 0.88, 0.80}},         {"heart", {0.80, 0.16, 0.16}},
      {"aorta", {0.85, 0.25, 0.20}},        {"organ", {0.70, 0.45, 0.55}},
      {"target", {1.00, 0.85, 0.10}},       {"cones", {0.30, 0.85, 0.95}},
      {"candidates", {0.20, 0.75, 0.35}},   {"ports", {0.15, 0.95, 0.25}},
      {"pivots", {0.95, 0.30, 0.95}},       {"table", {0.45, 0.50, 0.58}},
      {"floor", {0.28, 0.29, 0.31}},        {"robot", {0.78, 0.80, 0.86}},
      {"collision", {1.00, 0.10, 0.05}},    {"near_miss", {1.00, 0.65, 0.00}},
      {"pointer", {0.10, 0.55, 1.00}},      {"reach:served", {0.00, 0.70, 0.35}},
      {"reach:partly", {1.00, 0.78, 0.00}}, {"reach:none", {0.60, 0.20, 1.00}},
      {"reach:labels", {0.95, 0.95, 0.95}}, {"marker:head", {0.95, 0.30, 0.30}},
      {"marker:left", {0.30, 0.85, 0.35}},  {"marker:anterior", {0.35, 0.55, 1.00}},
  };
  s.opacities = {{"skin", 0.35}, {"cones", 0.55}};
  return s;
}

Eigen::Vector3d SceneStyle::Colour(const std::string& group) const {
  if (auto it = colours.find(group); it != colours.end()) return it->second;
  if (auto it = colours.find(KindOf(group)); it != colours.end()) return it->second;
  if (IsBone(group)) {
    if (auto it = colours.find("bone"); it != colours.end()) return it->second;
  }
  if (auto it = colours.find("organ"); it != colours.end()) return it->second;
  return {0.7, 0.7, 0.7};
}

double SceneStyle::Opacity(const std::string& group) const {
  if (auto it = opacities.find(group); it != opacities.end()) return it->second;
  if (auto it = opacities.find(KindOf(group)); it != opacities.end()) return it->second;
  return 1.0;
}

bool SceneStyle::Visible(const std::string& group) const {
  if (auto it = visible.find(group); it != visible.end()) return it->second;
  if (auto it = visible.find(KindOf(group)); it != visible.end()) return it->second;
  return true;
}

namespace {
std::pair<std::string, std::string> SplitAssignment(const std::string& text, const char* what) {
  const auto eq = text.find('=');
  TROCAR_THROW_UNLESS(eq != std::string::npos && eq > 0 && eq + 1 < text.size(),
                      "'" << text << "': expected " << what);
  return {text.substr(0, eq), text.substr(eq + 1)};
}
double ParseNumber(const std::string& text, const std::string& whole, const char* what) {
  std::size_t used = 0;
  double v = 0;
  try {
    v = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  TROCAR_THROW_UNLESS(used == text.size() && std::isfinite(v),
                      "'" << whole << "': '" << text << "' is not a number (" << what << ")");
  return v;
}
}  // namespace

void SceneStyle::ParseColour(const std::string& text) {
  const char* what = "name=r,g,b with each in 0..1 (or all in 0..255)";
  const auto [name, value] = SplitAssignment(text, what);
  std::vector<double> c;
  std::stringstream ss(value);
  std::string part;
  while (std::getline(ss, part, ',')) c.push_back(ParseNumber(part, text, what));
  TROCAR_THROW_UNLESS(c.size() == 3, "'" << text << "': expected " << what);
  const double top = *std::max_element(c.begin(), c.end());
  const double scale = top > 1.0 ? 255.0 : 1.0;
  for (double v : c) {
    TROCAR_THROW_UNLESS(v >= 0 && v <= scale, "'" << text << "': expected " << what);
  }
  const Eigen::Vector3d rgb = Eigen::Vector3d(c[0], c[1], c[2]) / scale;
  if (name == "background") {
    background = rgb;
  } else {
    colours[name] = rgb;
  }
}

void SceneStyle::ParseOpacity(const std::string& text) {
  const char* what = "name=opacity in 0..1";
  const auto [name, value] = SplitAssignment(text, what);
  const double v = ParseNumber(value, text, what);
  TROCAR_THROW_UNLESS(v >= 0 && v <= 1, "'" << text << "': expected " << what);
  opacities[name] = v;
}

namespace {
std::vector<double> Numbers(const std::string& text, const char* what) {
  std::string t = text;
  std::replace(t.begin(), t.end(), ',', ' ');
  std::istringstream in(t);
  std::vector<double> v;
  std::string word;
  while (in >> word) v.push_back(ParseNumber(word, text, what));
  return v;
}
}  // namespace

Eigen::Isometry3d ParseBasePose(const std::string& position, const std::string& rotation) {
  const std::vector<double> p = Numbers(position, "x, y, z in metres");
  TROCAR_THROW_UNLESS(p.size() == 3, "base position '" << position << "': expected x, y, z (m)");
  const char* what = "XYZ Euler angles (3 numbers, deg), a quaternion (w x y z) or a rotation "
                     "matrix (9 numbers, by rows)";
  const std::vector<double> r = Numbers(rotation, what);
  Eigen::Matrix3d R;
  if (r.size() == 3) {
    R = (Eigen::AngleAxisd(r[0] * M_PI / 180, Eigen::Vector3d::UnitX()) *
         Eigen::AngleAxisd(r[1] * M_PI / 180, Eigen::Vector3d::UnitY()) *
         Eigen::AngleAxisd(r[2] * M_PI / 180, Eigen::Vector3d::UnitZ()))
            .toRotationMatrix();
  } else if (r.size() == 4) {
    const Eigen::Quaterniond q(r[0], r[1], r[2], r[3]);
    TROCAR_THROW_UNLESS(q.norm() > 1e-9, "base rotation '" << rotation << "': a zero quaternion");
    R = q.normalized().toRotationMatrix();
  } else if (r.size() == 9) {
    R << r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8];
    TROCAR_THROW_UNLESS((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
                            R.determinant() > 0,
                        "base rotation '" << rotation
                                          << "': the matrix is not a rotation (orthonormal, determinant +1)");
  } else {
    TROCAR_THROW("base rotation '" << rotation << "': " << r.size() << " numbers; expected " << what);
  }
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = R;
  X.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
  return X;
}

}  // namespace trocar::viz
