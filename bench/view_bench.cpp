// The workstation's figures (issue #15), a small harness; run it under an X server:
//   scripts/with-xvfb build/bench/view_bench
// 1. Render-time study (thesis §5.3): frame time of the bundled default scene against the bodies
//    and triangles drawn, in software rendering (Xvfb, Mesa), 1280x720, shaded.
// 2. The control loop's rate with the teleop window rendering, divided by its rate headless
//    (target: at least 0.95), the PSM at 1 kHz for 4 s each, same input.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <thread>

#include <vtkCamera.h>
#include <vtkNew.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>

#include "control/control_loop.hpp"
#include "control/controller.hpp"
#include "control/device_input.hpp"
#include "control/teleop_session.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/start_configuration.hpp"
#include "patient/patient_model.hpp"
#include "robot/load_robot.hpp"
#include "scene.hpp"
#include "teleop_view.hpp"

using namespace trocar;

namespace {

// The mean frame time (ms) of `scene` at 1280x720; with `adapt`, as the windows draw it
// (viz::AdaptToRenderer after the first frame: no multisampling under software rendering), else
// with VTK's default multisampling.
double MeanFrameMs(viz::Scene& scene, int frames, bool adapt = true, bool* adapted = nullptr) {
  vtkNew<vtkRenderWindow> window;
  window->SetOffScreenRendering(1);
  window->SetSize(1280, 720);
  vtkNew<vtkRenderer> renderer;
  scene.AddTo(renderer);
  window->AddRenderer(renderer);
  viz::Scene::Apply(scene.ExternalCamera(1280.0 / 720), renderer);
  window->Render();  // first frame: uploads
  const bool changed = adapt && viz::AdaptToRenderer(window);
  if (adapted) *adapted = changed;
  if (changed) window->Render();
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < frames; ++i) {
    renderer->GetActiveCamera()->Azimuth(2.0);
    window->Render();
  }
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / frames;
  window->Finalize();
  return ms;
}

long Session(const robot::RobotModel& model, bool view) {
  const auto start = kinematics::ChooseStart(model);
  control::ControlLoop loop(model, control::MakeController("dls", model, control::Vector6d::Constant(20)), start.q);
  control::ScriptedMotion motion;
  motion.kind = control::ScriptedMotion::Kind::kCircle;
  control::ScriptedInput input(motion);
  control::TeleopSessionOptions o;
  o.duration = 4.0;
  o.rate_hz = 1000.0;
  o.realtime = true;
  control::RunnerStats stats;
  o.runner_stats = &stats;
  if (!view) {
    control::RunTeleopSession(&loop, &input, o);
    return stats.steps;
  }
  control::TripleBuffer<control::SessionSnapshot> snapshots;
  o.snapshots = &snapshots;
  std::atomic<bool> done{false};
  std::thread control_thread([&] {
    control::RunTeleopSession(&loop, &input, o);
    done = true;
  });
  auto shared = std::make_shared<const robot::RobotModel>(model);
  viz::Scene scene(nullptr, shared);
  const viz::TeleopViewStats v = viz::RunTeleopView(&scene, &snapshots, [&] { return done.load(); }, {});
  control_thread.join();
  std::printf("    window: %ld frames in %.2f s (%.1f fps)\n", v.frames, v.seconds, v.frames / v.seconds);
  return stats.steps;
}

}  // namespace

int main() {
  const std::string root = TROCAR_SOURCE_DIR;
  auto patient = patient::ImportCase(root + "/patients/phantom-default").model;
  auto cart = std::make_shared<const robot::RobotModel>(robot::LoadRobot(root + "/robots/davinci-classic/cart.yaml"));
  viz::Scene scene(patient, cart);
  robot::RobotState state = *scene.robot_state();
  state.X_WB.linear() = Eigen::AngleAxisd(-1.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  state.X_WB.translation() = Eigen::Vector3d(-0.28, 0.91, 0);
  kinematics::ForwardKinematics(*cart, &state);
  scene.SetRobotState(state);
  std::printf("render-time study: bundled default scene, 1280x720, software rendering (Mesa under Xvfb)\n");
  {
    bool adapted = false;
    MeanFrameMs(scene, 1, true, &adapted);
    std::printf("  as the windows draw it: multisampling %s\n",
                adapted ? "off (a software rasteriser)" : "as VTK sets it (a GPU)");
  }
  std::printf("  %-34s %8s %10s %9s %6s\n", "drawn", "groups", "triangles", "frame ms", "fps");
  struct Config {
    const char* name;
    std::vector<std::string> hidden;
  };
  std::vector<std::string> patient_groups, all = scene.groups();
  for (const auto& g : all)
    if (g != "robot" && g != "table" && g != "floor") patient_groups.push_back(g);
  std::vector<std::string> bones_only_hidden = {"skin", "heart", "cones", "candidates", "robot"};
  const std::vector<Config> configs = {
      {"floor and table", [&] { auto h = patient_groups; h.push_back("robot"); return h; }()},
      {"robot, table, floor", patient_groups},
      {"patient, table, floor", {"robot"}},
      {"patient without skin, table, floor", {"skin", "robot"}},
      {"everything (the default scene)", {}},
  };
  for (const Config& c : configs) {
    for (const auto& g : all) scene.SetVisible(g, true);
    for (const auto& g : c.hidden) scene.SetVisible(g, false);
    int bodies = 0;
    (void)bodies;
    const double ms = MeanFrameMs(scene, 20);
    long actors = 0;
    for (const auto& g : all) {
      bool hidden = false;
      for (const auto& h : c.hidden) hidden = hidden || h == g;
      if (!hidden) ++actors;
    }
    std::printf("  %-34s %8ld %10ld %9.1f %6.1f\n", c.name, actors, scene.triangle_count(), ms, 1000 / ms);
  }
  {
    viz::SceneStyle whole = viz::SceneStyle::Default();
    whole.patient_triangles = 0;  // no display decimation
    viz::Scene undecimated(patient, cart, whole);
    undecimated.SetRobotState(state);
    const double ms = MeanFrameMs(undecimated, 20);
    std::printf("  %-34s %8zu %10ld %9.1f %6.1f\n", "everything, surfaces not decimated",
                undecimated.groups().size(), undecimated.triangle_count(), ms, 1000 / ms);
  }
  {
    for (const auto& g : all) scene.SetVisible(g, true);
    const double ms = MeanFrameMs(scene, 20, false);
    std::printf("  %-34s %8zu %10ld %9.1f %6.1f\n", "everything, VTK's multisampling", all.size(),
                scene.triangle_count(), ms, 1000 / ms);
  }
  std::printf("control loop with the teleop window rendering vs headless (PSM, 1 kHz, 4 s):\n");
  const robot::RobotModel psm = robot::LoadRobot(root + "/robots/davinci-classic/psm.yaml");
  const long headless = Session(psm, false);
  std::printf("  headless: %ld steps\n", headless);
  const long viewed = Session(psm, true);
  std::printf("  with the window: %ld steps\n", viewed);
  std::printf("  ratio: %.3f (target >= 0.95)\n", double(viewed) / headless);
  return 0;
}
