#include "scene_file.hpp"

#include <cmath>
#include <filesystem>

#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/json_util.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"

namespace trocar::viz {
namespace {

using nlohmann::json;

json Vec(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

std::string Absolute(const std::string& path) {
  if (path.empty()) return path;
  std::error_code ec;
  const auto a = std::filesystem::absolute(path, ec);
  return ec ? path : a.lexically_normal().string();
}

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

SceneFile CaptureScene(const ViewInputs& inputs, const Scene& scene, const CameraPose* camera) {
  SceneFile f;
  f.inputs = inputs;
  f.inputs.case_dir = Absolute(inputs.case_dir);
  f.inputs.plan = Absolute(inputs.plan);
  f.inputs.robot = Absolute(inputs.robot);
  f.inputs.motion.clear();  // the pose is saved itself
  f.inputs.colours.clear();
  f.inputs.opacities.clear();
  f.inputs.hidden.clear();
  f.style = scene.style();
  if (const robot::RobotState* state = scene.robot_state()) {
    f.has_robot_state = true;
    f.X_WB = state->X_WB;
    const robot::RobotModel& robot = *scene.robot();
    for (int j : robot.active_joints()) f.q.emplace_back(robot.joint(j).name, state->q[robot.joint(j).q_index]);
  }
  if (camera) {
    f.has_camera = true;
    f.camera = *camera;
  }
  return f;
}

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
    const json& q = r.At(doc, "q", "q");
    if (!q.is_object()) r.Fail("q", "an object of joint names and values");
    for (const auto& [name, value] : q.items()) f.q.emplace_back(name, r.Number(value, "q." + name));
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
  }
  f.style = SceneStyle::Default();
  if (doc.contains("style")) {
    const json& s = doc.at("style");
    if (s.contains("background")) f.style.background = r.Vec3(s.at("background"), "style.background");
    if (s.contains("flat")) {
      if (!s.at("flat").is_boolean()) r.Fail("style.flat", "true or false");
      f.style.flat = s.at("flat").get<bool>();
    }
    if (s.contains("patient_triangles"))
      f.style.patient_triangles = static_cast<long>(r.Number(s.at("patient_triangles"), "style.patient_triangles"));
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

void ApplyScene(const SceneFile& f, Scene* scene) {
  for (const auto& [g, c] : f.style.colours) scene->SetColour(g, c);
  for (const auto& [g, o] : f.style.opacities) scene->SetOpacity(g, o);
  for (const auto& [g, v] : f.style.visible) scene->SetVisible(g, v);
  scene->SetBackground(f.style.background);
  scene->SetFlat(f.style.flat);
  if (!f.has_robot_state) return;
  TROCAR_THROW_UNLESS(scene->robot(), "the scene file poses a robot, and the view has none");
  const robot::RobotModel& robot = *scene->robot();
  robot::RobotState state = *scene->robot_state();
  state.X_WB = f.X_WB;
  Eigen::VectorXd q = state.q;
  for (const auto& [name, value] : f.q) {
    const int j = robot.FindJoint(name);
    TROCAR_THROW_UNLESS(j >= 0 && robot.joint(j).q_index >= 0,
                        "scene file: q names '" << name << "', not an active joint of " << robot.name());
    q[robot.joint(j).q_index] = value;
  }
  const auto fk = kinematics::ForwardKinematics(robot, q, &state);
  TROCAR_THROW_UNLESS(fk.ok(), "scene file: the robot's pose: " << fk.message);
  scene->SetRobotState(state);
}

LoadedView LoadScene(const SceneFile& f) {
  ViewInputs in = f.inputs;
  in.flat = f.style.flat;
  LoadedView view = LoadView(in);
  // The style as saved (LoadView built the scene with the default style; the display decimation
  // must match the saved one: rebuild when it differs).
  if (f.style.patient_triangles != view.scene->style().patient_triangles) {
    view.scene = std::make_unique<Scene>(view.patient, view.robot, f.style);
    if (view.plan) view.scene->ShowPlan(*view.plan, static_cast<std::size_t>(in.plan_index - 1));
  }
  ApplyScene(f, view.scene.get());
  if (view.collisions) {
    view.pose = view.collisions->Check(*view.scene->robot_state());
    view.scene->HighlightLinks(view.pose.colliding_links, view.pose.near_links);
  }
  return view;
}

}  // namespace trocar::viz
