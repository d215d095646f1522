#include "scene_file.hpp"

// The scene file's JSON: its writer and its bounded, checked reader (no renderer: the fuzz
// target builds this file alone).

#include <cmath>
#include <filesystem>

#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/json_util.hpp"
#include "common/file_util.hpp"

namespace trocar::viz {
namespace {

using nlohmann::json;

json Vec(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

/// Coordinates of a scene (m): a room, not a planet.
constexpr double kMaxSceneCoordinate = 100.0;

/// Reads with the field's path named on any error.
struct Reader {
  const std::string& file;
  [[noreturn]] void Fail(const std::string& field, const std::string& expected) const {
    TROCAR_THROW(file << ": " << field << ": expected " << expected);
  }
  const json& At(const json& j, const std::string& key, const std::string& field) const {
    if (!j.is_object() || !j.contains(key)) Fail(field, "a field '" + key + "'");
    return j.at(key);
  }
  double Number(const json& j, const std::string& field) const {
    if (!j.is_number() || !std::isfinite(j.get<double>())) Fail(field, "a finite number");
    return j.get<double>();
  }
  std::string String(const json& j, const std::string& field) const {
    if (!j.is_string()) Fail(field, "a string");
    return j.get<std::string>();
  }
  Eigen::Vector3d Vec3(const json& j, const std::string& field) const {
    if (!j.is_array() || j.size() != 3) Fail(field, "3 numbers");
    return {Number(j[0], field), Number(j[1], field), Number(j[2], field)};
  }
};

}  // namespace

void WriteSceneFile(const std::string& path, const SceneFile& f) {
  json doc = {{"format", "trocar-scene"}, {"version", kSceneFormatVersion}};
  doc["case"] = f.inputs.case_dir;
  doc["plan"] = f.inputs.plan;
  doc["plan_index"] = f.inputs.plan_index;
  doc["robot"] = f.inputs.robot;
  if (f.has_robot_state) {
    json pose = json::array();
    for (int r = 0; r < 4; ++r) {
      json row = json::array();
      for (int c = 0; c < 4; ++c) row.push_back(f.X_WB.matrix()(r, c));
      pose.push_back(row);
    }
    doc["X_WB"] = pose;
    json q = json::object();
    for (const auto& [name, value] : f.q) q[name] = value;
    doc["q"] = q;
  }
  if (f.has_camera) {
    doc["camera"] = {{"position", Vec(f.camera.position)},
                     {"focal_point", Vec(f.camera.focal_point)},
                     {"view_up", Vec(f.camera.view_up)},
                     {"view_angle_deg", f.camera.view_angle_deg}};
  }
  json style = {{"background", Vec(f.style.background)},
                {"flat", f.style.flat},
                {"patient_triangles", f.style.patient_triangles}};
  for (const auto& [g, c] : f.style.colours) style["colours"][g] = Vec(c);
  for (const auto& [g, o] : f.style.opacities) style["opacities"][g] = o;
  for (const auto& [g, v] : f.style.visible) style["visible"][g] = v;
  doc["style"] = style;
  WriteFileAtomically(path, doc.dump(1) + "\n");
}

SceneFile ReadSceneFile(const std::string& path) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": no such scene file");
  json doc;
  try {
    doc = ReadJsonFile(path, "a scene file");
  } catch (const json::exception& e) {
    TROCAR_THROW(path << ": not a scene file (JSON: " << e.what() << ")");
  }
  TROCAR_THROW_UNLESS(doc.is_object() && doc.contains("format") && doc["format"].is_string() &&
                          doc["format"].get<std::string>() == "trocar-scene",
                      path << ": not a trocar scene (field 'format' is not \"trocar-scene\")");
  const Reader r{path};
  TROCAR_THROW_UNLESS(r.Number(r.At(doc, "version", "version"), "version") == kSceneFormatVersion,
                      path << ": scene format version " << doc.at("version") << ", this trocar reads "
                           << kSceneFormatVersion);
  SceneFile f;
  f.inputs.case_dir = r.String(r.At(doc, "case", "case"), "case");
  f.inputs.plan = r.String(r.At(doc, "plan", "plan"), "plan");
  f.inputs.robot = r.String(r.At(doc, "robot", "robot"), "robot");
  const double index = r.Number(r.At(doc, "plan_index", "plan_index"), "plan_index");
  if (index < 1 || index > 1e6 || index != std::floor(index)) r.Fail("plan_index", "a whole number from 1");
  f.inputs.plan_index = static_cast<int>(index);
  if (doc.contains("X_WB")) {
    f.has_robot_state = true;
    const json& m = doc.at("X_WB");
    if (!m.is_array() || m.size() != 4) r.Fail("X_WB", "a 4x4 matrix");
    Eigen::Matrix4d X;
    for (int i = 0; i < 4; ++i) {
      if (!m[i].is_array() || m[i].size() != 4) r.Fail("X_WB", "a 4x4 matrix");
      for (int c = 0; c < 4; ++c) X(i, c) = r.Number(m[i][c], "X_WB");
    }
    const Eigen::Matrix3d R = X.topLeftCorner<3, 3>();
    if ((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-6 || R.determinant() < 0)
      r.Fail("X_WB", "a rigid transform");
    f.X_WB.linear() = R;
    f.X_WB.translation() = X.topRightCorner<3, 1>();
    if (f.X_WB.translation().cwiseAbs().maxCoeff() > kMaxSceneCoordinate)
      r.Fail("X_WB", "a base within 100 m of the room's origin");
    const json& q = r.At(doc, "q", "q");
    if (!q.is_object()) r.Fail("q", "an object of joint names and values");
    for (const auto& [name, value] : q.items()) {
      // Joint values in rad or m: a turn or a few metres; 1e300 is no pose.
      const double v = r.Number(value, "q." + name);
      if (std::abs(v) > 1e3) r.Fail("q." + name, "a joint value within 1000 (rad or m)");
      f.q.emplace_back(name, v);
    }
  }
  if (doc.contains("camera")) {
    const json& c = doc.at("camera");
    f.has_camera = true;
    f.camera.position = r.Vec3(r.At(c, "position", "camera.position"), "camera.position");
    f.camera.focal_point = r.Vec3(r.At(c, "focal_point", "camera.focal_point"), "camera.focal_point");
    f.camera.view_up = r.Vec3(r.At(c, "view_up", "camera.view_up"), "camera.view_up");
    f.camera.view_angle_deg = r.Number(r.At(c, "view_angle_deg", "camera.view_angle_deg"), "camera.view_angle_deg");
    if ((f.camera.position - f.camera.focal_point).norm() < 1e-9 || f.camera.view_up.norm() < 1e-9 ||
        f.camera.view_angle_deg <= 0 || f.camera.view_angle_deg >= 180)
      r.Fail("camera", "a camera off its focal point, an up direction and a view angle in 0..180");
    // Physical ranges (issue #44 item 1): the room is metres across, and an up direction along
    // the view direction leaves the picture's roll undefined (VTK draws nothing useful).
    if (f.camera.position.cwiseAbs().maxCoeff() > kMaxSceneCoordinate ||
        f.camera.focal_point.cwiseAbs().maxCoeff() > kMaxSceneCoordinate)
      r.Fail("camera", "a position and a focal point within 100 m of the room's origin");
    const Eigen::Vector3d view = (f.camera.focal_point - f.camera.position).normalized();
    if (view.cross(f.camera.view_up.normalized()).norm() < 1e-3)
      r.Fail("camera.view_up", "an up direction across the view direction (it is along it)");
  }
  f.style = SceneStyle::Default();
  if (doc.contains("style")) {
    const json& s = doc.at("style");
    if (s.contains("background")) f.style.background = r.Vec3(s.at("background"), "style.background");
    if (s.contains("flat")) {
      if (!s.at("flat").is_boolean()) r.Fail("style.flat", "true or false");
      f.style.flat = s.at("flat").get<bool>();
    }
    if (s.contains("patient_triangles")) {
      // A whole number of triangles (0: every triangle), within what a picture can hold.
      const double n = r.Number(s.at("patient_triangles"), "style.patient_triangles");
      if (n < 0 || n > 1e8 || n != std::floor(n))
        r.Fail("style.patient_triangles", "a whole number of triangles from 0 (all) to 100000000");
      f.style.patient_triangles = static_cast<long>(n);
    }
    if (s.contains("colours"))
      for (const auto& [g, c] : s.at("colours").items()) {
        const Eigen::Vector3d rgb = r.Vec3(c, "style.colours." + g);
        if ((rgb.array() < 0).any() || (rgb.array() > 1).any()) r.Fail("style.colours." + g, "r, g, b in 0..1");
        f.style.colours[g] = rgb;
      }
    if (s.contains("opacities"))
      for (const auto& [g, o] : s.at("opacities").items()) {
        const double v = r.Number(o, "style.opacities." + g);
        if (v < 0 || v > 1) r.Fail("style.opacities." + g, "an opacity in 0..1");
        f.style.opacities[g] = v;
      }
    if (s.contains("visible"))
      for (const auto& [g, v] : s.at("visible").items()) {
        if (!v.is_boolean()) r.Fail("style.visible." + g, "true or false");
        f.style.visible[g] = v.get<bool>();
      }
  }
  return f;
}

}  // namespace trocar::viz
