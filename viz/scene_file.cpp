#include "scene_file.hpp"

#include <cmath>
#include <filesystem>

#include "common/error.hpp"
#include "common/json_util.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"

namespace trocar::viz {
namespace {

std::string Absolute(const std::string& path) {
  if (path.empty()) return path;
  std::error_code ec;
  const auto a = std::filesystem::absolute(path, ec);
  return ec ? path : a.lexically_normal().string();
}

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
