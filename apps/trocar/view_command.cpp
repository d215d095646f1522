// trocar view: a case and its plans in the workstation's 3D scene — a window, or screenshots.
#include <iostream>
#include <sstream>
#include <memory>
#include <optional>

#include "apps/trocar/commands.hpp"
#include "common/error.hpp"
#include "scene.hpp"
#include "report.hpp"
#include "scene_file.hpp"
#include "view_inputs.hpp"
#include "workstation.hpp"

namespace trocar::apps {
namespace {

struct ViewOptions {
  viz::ViewInputs inputs;
  std::string screenshot;
  std::string grab;
  std::string scene, save_scene;
  std::vector<std::string> views;
  std::string size = "1280x720";
  double light = 1.0;
};

std::pair<int, int> ParseSize(const std::string& text) {
  int w = 0, h = 0;
  char x = 0, extra = 0;
  std::istringstream in(text);
  in >> w >> x >> h;
  TROCAR_THROW_UNLESS(in && !(in >> extra) && x == 'x' && w >= 16 && h >= 16 && w <= 8192 && h <= 8192,
                      "--size '" << text << "': expected WIDTHxHEIGHT, each 16..8192 pixels");
  return {w, h};
}

int RunView(const ViewOptions& o) {
  viz::ViewInputs inputs = o.inputs;
  std::optional<viz::CameraPose> saved_camera;
  viz::LoadedView loaded;
  if (!o.scene.empty()) {
    TROCAR_THROW_UNLESS(o.inputs.case_dir.empty() && o.inputs.plan.empty(),
                        "--scene " << o.scene << ": the scene file names its case and plan; give no CASE or PLAN");
    const viz::SceneFile file = viz::ReadSceneFile(o.scene);
    inputs = file.inputs;
    if (file.has_camera) saved_camera = file.camera;
    TROCAR_THROW_UNLESS(o.inputs.motion.empty() && o.inputs.robot.empty(),
                        "--scene " << o.scene
                                   << ": the scene file saves its robot and the robot's pose; give "
                                      "no --motion or --robot");
    try {
      loaded = viz::LoadScene(file);
    } catch (const Error& e) {
      TROCAR_THROW(o.scene << ": " << e.what());
    }
    // What the command line says over the saved scene: colours, opacities, hidden groups, flat
    // colours, the targets' reach.
    viz::SceneStyle over;
    over.background = file.style.background;
    for (const auto& c : o.inputs.colours) over.ParseColour(c);
    for (const auto& op : o.inputs.opacities) over.ParseOpacity(op);
    for (const auto& [g, c] : over.colours) loaded.scene->SetColour(g, c);
    for (const auto& [g, v] : over.opacities) loaded.scene->SetOpacity(g, v);
    for (const auto& h : o.inputs.hidden) loaded.scene->SetVisible(h, false);
    loaded.scene->SetBackground(over.background);
    if (o.inputs.flat) loaded.scene->SetFlat(true);
    if (o.inputs.reach) {
      TROCAR_THROW_UNLESS(loaded.plan, "--reach: the scene " << o.scene << " shows no plan");
      loaded.scene->ShowReachability(*loaded.plan, static_cast<std::size_t>(inputs.plan_index - 1));
    }
  } else {
    TROCAR_THROW_UNLESS(!o.inputs.case_dir.empty(), "view: give a CASE folder (or --scene FILE)");
    WithFlags({{"plan_index", "--plan"}}, [&] { loaded = viz::LoadView(o.inputs); });
  }
  if (o.screenshot.empty()) {
    viz::WorkstationOptions wo;
    wo.inputs = inputs;
    wo.plan_index = inputs.plan_index - 1;
    if (saved_camera) wo.camera = *saved_camera;
    wo.grab_path = o.grab;
    return viz::RunWorkstation(std::move(loaded.scene), loaded.robot, loaded.plan.get(), wo);
  }
  const auto [width, height] = ParseSize(o.size);
  std::vector<std::string> names = o.views;
  if (names.empty()) {
    names.push_back("external");
    if (loaded.plan && !loaded.plan->plans.empty() &&
        !loaded.plan->plans[inputs.plan_index - 1].views.empty()) {
      names.push_back("endoscope");
    }
  }
  const planners::StoredPlan* plan =
      loaded.plan ? &loaded.plan->plans[inputs.plan_index - 1] : nullptr;
  viz::Views views;
  const double aspect = static_cast<double>(width) / names.size() / height;
  for (const std::string& name : names) {
    viz::ViewSpec spec = viz::ViewSpec::Parse(name);
    spec.camera.light_intensity = o.light;
    viz::FrameCamera used;
    viz::CameraPose pose = viz::ViewCamera(*loaded.scene, spec, aspect, plan, &used);
    if (spec.kind == viz::ViewSpec::Kind::kExternal && saved_camera) pose = *saved_camera;
    spec.camera = used;
    spec.camera.light_intensity = o.light;
    views.emplace_back(spec, pose);
  }
  if (!o.save_scene.empty()) {
    const viz::CameraPose* external = nullptr;
    for (const auto& [spec, pose] : views)
      if (spec.kind == viz::ViewSpec::Kind::kExternal && !external) external = &pose;
    viz::WriteSceneFile(o.save_scene, viz::CaptureScene(inputs, *loaded.scene, external));
    std::cout << "wrote " << o.save_scene << "\n";
  }
  viz::Screenshot(*loaded.scene, views, width, height, o.screenshot);
  std::cout << "wrote " << o.screenshot << " (" << width << "x" << height << ", "
            << names.size() << " view" << (names.size() > 1 ? "s" : "") << ", "
            << loaded.scene->triangle_count() << " triangles)\n";
  if (!loaded.failure.empty())
    std::cout << "motion " << inputs.motion << " fails: " << loaded.failure
              << "; shown at the pose where it fails\n";
  if (loaded.collisions) std::cout << "robot pose: " << viz::Describe(loaded.pose) << "\n";
  for (const std::string& note : loaded.scene->robot_notes()) std::cout << "note: " << note << "\n";
  return 0;
}

}  // namespace

void AddViewInputOptions(CLI::App* cmd, viz::ViewInputs* in) {
  cmd->add_option("case", in->case_dir, "patient case folder (patient.yaml); not with --scene");
  cmd->add_option("plan_file", in->plan, "a plan.json of this case (trocar plan --out DIR)");
  cmd->add_option("--plan", in->plan_index, "which ranked plan to show (1: the best)")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  cmd->add_option("--robot", in->robot,
                  "robot description to show when no plan is given (default: none)");
  cmd->add_option("--motion", in->motion,
                  "pose the robot on a verified motion of the plan: ARM:SAMPLE[:WAYPOINT] "
                  "(default waypoint: the last, at the target)");
  cmd->add_option("--colour", in->colours,
                  "GROUP=r,g,b (0..1 or 0..255); groups: skin ribs sternum spine heart "
                  "target:<name> cones candidates ports pivots table floor robot collision, "
                  "or background");
  cmd->add_option("--opacity", in->opacities, "GROUP=opacity (0..1)");
  cmd->add_option("--hide", in->hidden, "a group not to draw");
  cmd->add_flag("--flat", in->flat, "unlit exact colours (a pixel's colour names its group)");
  cmd->add_flag("--reach", in->reach,
                "colour each target along its length by how the plan serves it: served (every "
                "instrument moves there, the endoscope sees it), reached by some arms, by none "
                "(its verified motions, else its own reach check)");
}

void AddReportCommand(CLI::App* app) {
  auto in = std::make_shared<viz::ViewInputs>();
  auto dir = std::make_shared<std::string>();
  auto options = std::make_shared<viz::ReportOptions>();
  CLI::App* cmd = app->add_subcommand(
      "report", "One self-contained HTML report of a plan file: per ranked plan its external and "
                "endoscope views, score breakdown, ports, verified motions, sign-offs and verdict "
                "(renders: needs an X display, e.g. scripts/with-xvfb)");
  cmd->add_option("plan_file", in->plan, "the plan.json")->required();
  cmd->add_option("--out", *dir, "folder for report.html")->required();
  cmd->add_option("--case", in->case_dir, "the patient case (default: the plan's)");
  cmd->add_option("--plans", options->max_plans, "how many of the best plans")->capture_default_str();
  cmd->add_option("--colour", in->colours, "GROUP=r,g,b, as trocar view");
  cmd->add_option("--hide", in->hidden, "a group not to draw");
  cmd->add_flag("--flat", in->flat, "unlit exact colours");
  cmd->callback([in, dir, options]() {
    std::string written;
    WithFlags({{"plan_index", "--plan"}, {"max_plans", "--plans"}},
              [&] { written = viz::WriteReport(*in, *dir, *options); });
    std::cout << "wrote " << written << "\n";
  });
}

void AddViewCommand(CLI::App* app) {
  auto o = std::make_shared<ViewOptions>();
  CLI::App* cmd = app->add_subcommand(
      "view",
      "The case (and a plan's ranked plans) in the workstation: a window, or --screenshot FILE.png "
      "(needs an X display; headless: xvfb-run -a trocar view ...)");
  AddViewInputOptions(cmd, &o->inputs);
  cmd->add_option("--screenshot", o->screenshot,
                  "render one frame of the views side by side into this PNG, no window");
  cmd->add_option("--grab", o->grab,
                  "open the window, render it, save an image of the whole window (sidebar and "
                  "views) to this PNG, and close");
  cmd->add_option("--scene", o->scene, "open a scene file (trocar-scene JSON: case, plan, robot pose, camera, colours)");
  cmd->add_option("--save-scene", o->save_scene,
                  "with --screenshot: also save what it shows as a scene file (the window saves from File)");
  cmd->add_option("--view", o->views,
                  "external (the chest and its ports), room (the patient, table and robot), "
                  "targets (the targets and ports from the front), ports (the ports on the chest, "
                  "close), endoscope (the plan's scope camera) or frame:<robot frame>; repeat "
                  "for side by side (default: external, and endoscope when the plan has one)");
  cmd->add_option("--size", o->size, "screenshot WIDTHxHEIGHT in pixels")->capture_default_str();
  cmd->add_option("--light", o->light, "intensity of the light at the scope tip (0..)")
      ->check(CLI::Range(0.0, 10.0))
      ->capture_default_str();
  cmd->callback([o]() {
    const int code = RunView(*o);
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace trocar::apps
