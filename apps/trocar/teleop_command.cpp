// trocar teleop: a headless teleoperation session on a simulated clock.
#include <filesystem>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <exception>
#include <iomanip>
#include <thread>
#include <iostream>
#include <memory>
#include <sstream>

#include "apps/trocar/commands.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/geometry.hpp"
#include "control/control_loop.hpp"
#include "control/device_input.hpp"
#include "control/gain_tuning.hpp"
#include "control/teleop_session.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/start_configuration.hpp"
#include "robot/load_robot.hpp"
#include "control/igtl_device.hpp"
#include "scene.hpp"
#include "view_inputs.hpp"
#include "port_placement/plan_file.hpp"
#include "teleop_view.hpp"

namespace trocar::apps {
namespace {

struct TeleopCommandOptions {
  std::string robot;
  std::string input = "sinusoid";
  double scale = 1.0;
  double duration = 10.0;
  double rate = 1000.0;
  std::string record;
  std::string controller = "dls";
  bool position_only = false;
  bool full_pose = false;
  std::string filter = "none";
  double amplitude = 0.04;
  std::vector<double> q0;
  std::vector<double> camera_rpy;
  double max_jump = 0.05;
  bool realtime = false;
  bool view = false;
  double fps = 60.0;
  std::string grab;
  std::string listen;   ///< [ADDRESS:]PORT: drive the robot from an OpenIGTLink device
  std::string device;   ///< its name ("": the first that connects)
  double wait = 30.0;   ///< s for the first device
  double units = 0.001; ///< metres per device unit
  std::string plan;     ///< teleoperate an arm of a plan, in its patient
  int plan_index = 1;
  std::string arm;      ///< which arm of the plan ("": its first instrument)
};

int RunTeleop(const TeleopCommandOptions& o) {
  robot::LoadOptions load;
  load.load_meshes = o.view;  // the window draws the robot's meshes
  // An arm of a plan: the plan's robot with its tool at that arm's tool, at the plan's cart
  // pose, setup joints and nominal pose, in the plan's patient.
  std::unique_ptr<viz::LoadedView> plan_view;
  std::vector<std::pair<std::string, double>> held;
  Eigen::Isometry3d X_WB = Eigen::Isometry3d::Identity();
  std::shared_ptr<const robot::RobotModel> shared_model;
  std::string plan_arm;
  if (!o.plan.empty()) {
    TROCAR_THROW_UNLESS(o.robot.empty(), "--plan names its robot: give no --robot");
    viz::ViewInputs in;
    in.plan = o.plan;
    in.plan_index = o.plan_index;
    in.case_dir = planners::ReadPlanFile(o.plan).case_dir;
    plan_view = std::make_unique<viz::LoadedView>(viz::LoadView(in));
    const planners::PlanFile& file = *plan_view->plan;
    const planners::StoredArm* arm = nullptr;
    for (const auto& a : file.arms)
      if ((o.arm.empty() && a.role == "instrument" && !arm) || a.name == o.arm) arm = &a;
    TROCAR_THROW_UNLESS(arm, o.plan << ": no arm '" << o.arm << "' (arms: " << [&] {
      std::string names;
      for (const auto& a : file.arms) names += (names.empty() ? "" : ", ") + a.name;
      return names;
    }() << ")");
    plan_arm = arm->name;
    robot::RobotModelBuilder builder = robot::LoadRobotDescription(file.robot_file, load);
    bool found = false;
    for (const auto& f : builder.frames()) {
      if (f.name == arm->tool_frame) {
        robot::RobotModelBuilder::FrameSpec tool = f;
        tool.name = arm->name + "_teleop_tool";  // the arm's tool frame stays a frame of its own
        builder.SetTool(tool);
        found = true;
      }
    }
    TROCAR_THROW_UNLESS(found, o.plan << ": arm " << arm->name << "'s tool frame '" << arm->tool_frame
                                      << "' is not a frame of " << file.robot_file);
    shared_model = std::make_shared<const robot::RobotModel>(builder.Build());
    const planners::StoredPlan& plan = file.plans[o.plan_index - 1];
    held = plan.setup_joints;
    X_WB = plan.X_WB;
  } else {
    TROCAR_THROW_UNLESS(!o.robot.empty(), "teleop: give --robot FILE, or --plan PLAN.json");
    shared_model = std::make_shared<const robot::RobotModel>(robot::LoadRobot(o.robot, load));
  }
  const robot::RobotModel& model = *shared_model;
  // The robot's home, or one chosen away from limits and singularities; --q0 overrides both.
  kinematics::StartConfiguration start = plan_view ? kinematics::StartConfiguration{} : kinematics::ChooseStart(model);
  Eigen::VectorXd q0 = start.q;
  if (plan_view) {
    q0 = plan_view->scene->robot_state()->q;  // the plan's nominal pose (same joints, same order)
    start.q = q0;
    start.basis = "the nominal pose of plan " + std::to_string(o.plan_index) + ", arm " + plan_arm;
  }
  if (!o.q0.empty()) {
    TROCAR_THROW_UNLESS(static_cast<int>(o.q0.size()) == model.num_positions(),
                        "--q0: " << o.q0.size() << " values, robot '" << model.name()
                                 << "' has " << model.num_positions() << " active joints");
    q0 = Eigen::Map<const Eigen::VectorXd>(o.q0.data(), model.num_positions());
    start.basis = "--q0";
    start.warnings = kinematics::StartWarnings(model, q0, start.length);
  }
  const auto violations = kinematics::LimitViolations(model, q0);
  TROCAR_THROW_UNLESS(violations.empty(), "start configuration outside the joint limits: "
                                              << violations.front());
  control::Vector6d fallback = (control::Vector6d() << 20, 20, 20, 40, 40, 40).finished();
  // Jacobian transpose needs gains fitted to the robot (thesis §6.3.2): a robot that gives none
  // gets them tuned on first use, saved in the overlay beside it for the next sessions.
  std::string tuned_note;
  if (o.controller == "jt" && model.controller().gains.count("jt") == 0 &&
      model.controller().task_gains.size() == 0) {
    control::GainTuningOptions tuning;
    tuning.controller = "jt";
    const auto tuned = control::TuneGains(model, q0, tuning);
    fallback = tuned.gains;
    std::string saved;
    try {
      saved = "saved to " + control::SaveControllerGains(o.robot, "jt", tuned.gains);
    } catch (const Error& e) {
      saved = std::string("not saved: ") + e.what();
    }
    std::ostringstream note;
    note << "  jt gains tuned on first use (the robot gives none): " << FormatVector(tuned.gains, 5)
         << ", " << saved << "\n";
    tuned_note = note.str();
  }
  control::ControlLoop loop(model, control::MakeController(o.controller, model, fallback), q0, X_WB, held);

  std::unique_ptr<control::DeviceInput> input;
  std::optional<double> step_time;
  const bool is_file = o.input.size() > 4 && o.input.substr(o.input.size() - 4) == ".csv";
  viz::KeyboardInput* keyboard = nullptr;
  std::unique_ptr<control::IgtlDeviceServer> server;
  control::NetworkDeviceInput* network = nullptr;
  if (!o.listen.empty()) {
    control::IgtlServerOptions so;
    control::ParseListenAddress(o.listen, &so);
    TROCAR_THROW_UNLESS(std::isfinite(o.units) && o.units > 0, "--units " << o.units << ": expected metres per device unit, > 0");
    so.default_units = o.units;
    server = std::make_unique<control::IgtlDeviceServer>(so);
    std::cout << "listening on " << server->address() << ":" << server->port() << " (OpenIGTLink) for "
              << (o.device.empty() ? "the first device" : "device " + o.device) << std::endl;
    // The session starts with the first pose, so that its clock is the device's.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(o.wait);
    control::DeviceSample s;
    std::uint64_t sequence = 0;
    std::chrono::steady_clock::time_point arrival;
    while (!server->Latest(o.device, &s, &sequence, &arrival)) {
      TROCAR_THROW_UNLESS(std::chrono::steady_clock::now() < deadline,
                          "no device sent a pose to " << server->address() << ":" << server->port()
                                                      << " within " << o.wait << " s");
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    auto n = std::make_unique<control::NetworkDeviceInput>(server.get(), o.device);
    network = n.get();
    input = std::move(n);
  } else if (o.input == "keyboard") {
    TROCAR_THROW_UNLESS(o.view, "--input keyboard needs --view (the window takes the keys)");
    auto k = std::make_unique<viz::KeyboardInput>();
    keyboard = k.get();
    input = std::move(k);
  } else if (is_file) {
    input = std::make_unique<control::CsvReplayInput>(o.input);
  } else {
    control::ScriptedMotion motion;
    motion.kind = control::ParseScriptedMotion(o.input);
    TROCAR_THROW_UNLESS(std::isfinite(o.amplitude) && o.amplitude > 0,
                        "--amplitude " << o.amplitude << " must be positive");
    motion.amplitude = o.amplitude;
    if (motion.kind == control::ScriptedMotion::Kind::kStep) step_time = motion.step_time;
    input = std::make_unique<control::ScriptedInput>(motion);
  }
  control::TeleopSessionOptions session;
  session.duration = o.duration;
  session.rate_hz = o.rate;
  session.mapping.scale = o.scale;
  // A robot with fewer than six joints cannot follow a full pose: it follows the position.
  const bool position_only =
      o.position_only || (!o.full_pose && model.num_positions() < 6);
  TROCAR_THROW_UNLESS(!(o.position_only && o.full_pose), "--position-only and --full-pose exclude each other");
  session.mapping.position_only = position_only;
  session.mapping.filter = control::ParseTremorFilter(o.filter);
  session.mapping.max_jump = o.max_jump;
  if (!o.camera_rpy.empty()) {
    session.mapping.R_WC = RotationFromRpy(Eigen::Vector3d(o.camera_rpy[0], o.camera_rpy[1], o.camera_rpy[2]));
  }
  if (!o.record.empty()) {  // fail before the run, not after it
    std::error_code ec;
    std::filesystem::create_directories(o.record, ec);
    TROCAR_THROW_UNLESS(!ec && std::filesystem::is_directory(o.record),
                        "--record " << o.record << ": cannot create the folder: "
                                    << (ec ? ec.message() : "a file of that name is in the way"));
    for (const char* name : {"record.csv", "tracking.png", "errors.png"}) {
      const std::filesystem::path out = std::filesystem::path(o.record) / name;
      TROCAR_THROW_UNLESS(!std::filesystem::exists(out, ec) || std::filesystem::is_regular_file(out, ec),
                          "--record " << o.record << ": " << out.string()
                                      << " exists and is not a file (it cannot be replaced)");
    }
    // Writable: a file written and removed now, not after the run.
    const std::string probe = (std::filesystem::path(o.record) / ".trocar-write-test").string();
    WriteFileAtomically(probe, "");
    std::filesystem::remove(probe, ec);
  }
  control::RunnerStats timing;
  session.realtime = o.realtime || o.view || server;  // a person or a device: the wall's clock
  session.runner_stats = &timing;
  control::Recorder recorder;
  viz::TeleopViewStats view_stats;
  if (o.view) {
    // The control thread runs the session; this thread renders what it publishes, never
    // waiting on it.
    std::unique_ptr<viz::Scene> alone;
    viz::Scene* scene = nullptr;
    if (plan_view) {
      scene = plan_view->scene.get();
    } else {
      alone = std::make_unique<viz::Scene>(nullptr, shared_model);
      scene = alone.get();
    }
    control::TripleBuffer<control::SessionSnapshot> snapshots;
    session.snapshots = &snapshots;
    std::atomic<bool> done{false};
    std::exception_ptr failure;
    std::thread control_thread([&] {
      try {
        recorder = control::RunTeleopSession(&loop, input.get(), session);
      } catch (...) {
        failure = std::current_exception();
      }
      done = true;
    });
    viz::TeleopViewOptions vo;
    vo.fps = o.fps;
    vo.grab_path = o.grab;
    long frames_in_collision = 0;
    if (plan_view && plan_view->collisions) {
      // Each frame's collisions by the plan's rules, highlighted and said.
      vo.on_frame = [&](const robot::RobotState& state) {
        const planners::PoseCollisions pose = plan_view->collisions->Check(state);
        scene->HighlightLinks(pose.colliding_links, pose.near_links);
        frames_in_collision += pose.collision;
        return viz::Describe(pose);
      };
    }
    try {
      view_stats = viz::RunTeleopView(scene, &snapshots, [&] { return done.load(); }, vo, keyboard);
      view_stats.frames_in_collision = frames_in_collision;
    } catch (...) {
      control_thread.join();
      throw;
    }
    control_thread.join();
    if (failure) std::rethrow_exception(failure);
  } else {
    recorder = control::RunTeleopSession(&loop, input.get(), session);
  }
  const control::TrackingSummary s = recorder.Summarize(step_time);

  std::cout << std::setprecision(4);
  for (const std::string& w : start.warnings) std::cerr << "warning: " << w << "\n";
  std::cout << "teleop: robot '" << model.name() << "', controller " << o.controller
            << ", input " << input->name() << ", scale " << o.scale << ":1"
            << (position_only ? (o.position_only ? ", position only"
                                                 : ", position only (fewer than 6 joints)")
                              : "")
            << ", filter " << o.filter << ", "
            << o.duration << " s at " << o.rate << " Hz" << (o.realtime || o.view || server ? " (real time)" : "")
            << "\n";
  std::cout << "  start: " << FormatVector(q0, 4) << ", " << start.basis << "\n" << tuned_note;
  std::cout << "  position error:    RMS " << s.rms_position_error * 1e3 << " mm, max "
            << s.max_position_error * 1e3 << " mm\n";
  if (!position_only) {
    std::cout << "  orientation error: RMS " << s.rms_orientation_error * 180 / M_PI << " deg, max "
              << s.max_orientation_error * 180 / M_PI << " deg\n";
  }
  if (step_time) {
    if (s.settling_time) {
      std::cout << "  settling time after the step (0.1 mm, 0.1 deg): " << *s.settling_time << " s\n";
    } else {
      std::cout << "  not settled within 0.1 mm and 0.1 deg by the end of the run\n";
    }
  }
  int limited_steps = 0;
  for (const auto& row : recorder.rows()) limited_steps += row.limited_joints > 0;
  std::cout << "  samples: " << s.steps << " (" << s.dropped << " dropped, " << s.held
            << " held); a joint limit acted at " << limited_steps
            << (recorder.stride() > 1 ? " recorded" : "") << " steps\n";
  if (recorder.stride() > 1) {
    std::cout << "  record thinned to every " << recorder.stride() << "th step ("
              << recorder.rows().size() << " rows; TROCAR_MAX_RECORDED_SAMPLES bounds it)\n";
  }
  if (o.view) {
    std::cout << "  view: " << view_stats.frames << " frames in " << view_stats.seconds << " s ("
              << view_stats.frames / std::max(view_stats.seconds, 1e-9) << " fps), "
              << view_stats.snapshots << " new control steps shown"
              << (plan_view ? ", " + std::to_string(view_stats.frames_in_collision) + " frames in collision" : std::string())
              << "\n";
  }
  if (server) {
    for (const auto& [name, c] : server->Counters()) {
      std::cout << "  device '" << name << "': " << c.messages << " poses, " << c.drops() << " dropped (crc "
                << c.crc << ", malformed " << c.malformed << ", oversized " << c.oversized << ", unknown type "
                << c.unknown_type << ", non-finite " << c.non_finite << ", truncated " << c.truncated << "), "
                << c.connections << " connection" << (c.connections == 1 ? "" : "s") << "\n";
    }
    std::vector<double> latency = network->latencies();
    if (!latency.empty()) {
      std::sort(latency.begin(), latency.end());
      auto at = [&](double f) { return latency[std::min(latency.size() - 1, static_cast<std::size_t>(f * latency.size()))] * 1e3; };
      std::cout << "  latency, arrival to command: median " << at(0.5) << " ms, p99 " << at(0.99) << " ms, max "
                << latency.back() * 1e3 << " ms over " << latency.size() << " poses; silences "
                << network->silences() << "\n";
    }
  }
  if (o.realtime || o.view || server) {
    std::cout << "  real time: " << timing.steps << " steps, mean period "
              << timing.mean_period * 1e3 << " ms, period error p99 "
              << timing.p99_period_error * 1e6 << " us, max " << timing.max_period_error * 1e6
              << " us, " << timing.overruns << " overruns\n";
  }
  if (!o.record.empty()) {
    std::vector<std::string> names;
    for (int j : model.active_joints()) names.push_back(model.joint(j).name);
    const std::string path = (std::filesystem::path(o.record) / "record.csv").string();
    recorder.WriteCsv(path, names);
    std::cout << "  record: " << path << "\n";
    for (const std::string& plot : recorder.WritePlots(o.record, model.name() + " " + o.controller)) {
      std::cout << "  figure: " << plot << "\n";
    }
  }
  return 0;
}

struct TuneCommandOptions {
  std::string robot;
  std::string controller = "jt";
  std::string input = "sinusoid";
  double scale = 1.0;
  double duration = 6.0;
  int evaluations = 80;
  bool save = false;
};

int RunTune(const TuneCommandOptions& o) {
  robot::LoadOptions load;
  load.load_meshes = false;
  const robot::RobotModel model = robot::LoadRobot(o.robot, load);
  control::GainTuningOptions options;
  options.controller = o.controller;
  options.trajectory.kind = control::ParseScriptedMotion(o.input);
  options.scale = o.scale;
  options.duration = o.duration;
  options.max_evaluations = o.evaluations;
  const auto r = control::TuneGains(model, kinematics::ChooseStart(model).q, options);
  std::cout << std::setprecision(4) << "tune: robot '" << model.name() << "', controller "
            << o.controller << ", reference " << o.input << " (" << o.duration << " s, scale "
            << o.scale << ":1), " << r.evaluations << " evaluations\n";
  std::cout << "  gains [wx wy wz vx vy vz]: " << FormatVector(r.gains, 5) << "\n";
  std::cout << "  position error RMS " << r.rms_position_error * 1e3 << " mm (was "
            << r.initial_rms_position_error * 1e3 << " mm), max " << r.max_position_error * 1e3
            << " mm; orientation RMS " << r.rms_orientation_error * 180 / M_PI
            << " deg; step overshoot " << r.overshoot * 100 << " %\n";
  if (o.save) {
    std::cout << "  saved to " << control::SaveControllerGains(o.robot, o.controller, r.gains)
              << " (controller.gains." << o.controller << ")\n";
  }
  return 0;
}

}  // namespace

void AddTuneCommand(CLI::App* app) {
  auto o = std::make_shared<TuneCommandOptions>();
  CLI::App* cmd = app->add_subcommand(
      "tune", "Find controller gains that track a reference trajectory without oscillating");
  cmd->add_option("--robot", o->robot, "robot description (.urdf or .yaml)")->required();
  cmd->add_option("--controller", o->controller, "jt, dls or jla")->capture_default_str();
  cmd->add_option("--input", o->input, "reference: sinusoid, circle, step or roll")->capture_default_str();
  cmd->add_option("--scale", o->scale, "device:tool motion ratio")->capture_default_str();
  cmd->add_option("--duration", o->duration, "seconds of reference per evaluation")->capture_default_str();
  cmd->add_option("--evaluations", o->evaluations, "most evaluations")->capture_default_str();
  cmd->add_flag("--save", o->save, "write the gains into the robot's sidecar file");
  cmd->callback([o]() { RunTune(*o); });
}

void AddTeleopCommand(CLI::App* app) {
  auto o = std::make_shared<TeleopCommandOptions>();
  CLI::App* cmd = app->add_subcommand(
      "teleop", "Drive a simulated robot from a device input, headless, and report tracking");
  cmd->add_option("--robot", o->robot, "robot description (.urdf or .yaml); or --plan");
  cmd->add_option("--plan", o->plan,
                  "teleoperate an arm of a plan (trocar plan's plan.json) in its patient, from the plan's "
                  "nominal pose, setup joints and cart pose");
  cmd->add_option("--plan-index", o->plan_index, "which ranked plan (1: the best)")->capture_default_str();
  cmd->add_option("--arm", o->arm, "with --plan: the arm to drive (default: the plan's first instrument)");
  cmd->add_option("--input", o->input,
                  "sinusoid (thesis 5.4.2.1), circle, step, roll, or a recorded FILE.csv "
                  "(t,x,y,z,qw,qx,qy,qz[,clutch,present])")
      ->capture_default_str();
  cmd->add_option("--scale", o->scale, "device:tool motion ratio (5 means 5:1)")->capture_default_str();
  cmd->add_option("--duration", o->duration, "seconds of simulated time")->capture_default_str();
  cmd->add_option("--rate", o->rate, "control and device rate (Hz)")->capture_default_str();
  cmd->add_option("--record", o->record, "folder for record.csv, tracking.png and errors.png");
  cmd->add_option("--controller", o->controller, "jt (Jacobian transpose), dls, jla")
      ->capture_default_str();
  cmd->add_flag("--position-only", o->position_only,
                "control position only (the default for robots with fewer than 6 joints)");
  cmd->add_flag("--full-pose", o->full_pose, "control position and orientation even with fewer than 6 joints");
  cmd->add_option("--filter", o->filter, "tremor filter: none, lowpass, oneeuro")->capture_default_str();
  cmd->add_option("--amplitude", o->amplitude, "scripted input amplitude (m)")->capture_default_str();
  cmd->add_option("--q0", o->q0, "start configuration (default: the robot's home)");
  cmd->add_option("--camera-rpy", o->camera_rpy, "camera frame in the world, roll pitch yaw")
      ->expected(3);
  cmd->add_flag("--realtime", o->realtime,
                "run in real time in a fixed-rate control thread (measured step times)");
  cmd->add_flag("--view", o->view,
                "show the robot in a window while the control thread runs (real time; the window "
                "renders at --fps and never blocks the control loop); --input keyboard: arrows, "
                "Page Up/Down, Q/E, Space (clutch)");
  cmd->add_option("--fps", o->fps, "render rate of --view")->capture_default_str();
  cmd->add_option("--listen", o->listen,
                  "drive the robot from an OpenIGTLink device (TRANSFORM or POSITION): [ADDRESS:]PORT, "
                  "localhost unless an address is given (OpenIGTLink's usual port: 18944)");
  cmd->add_option("--device", o->device, "with --listen: the device's name (default: the first that sends)");
  cmd->add_option("--wait", o->wait, "with --listen: seconds to wait for the first pose")->capture_default_str();
  cmd->add_option("--units", o->units,
                  "with --listen: metres per device unit (OpenIGTLink: mm, 0.001; the dVRK bridge: m, 1)")
      ->capture_default_str();
  cmd->add_option("--grab", o->grab, "with --view: save an image of the window when the session ends");
  cmd->add_option("--max-jump", o->max_jump, "device jump (m) beyond which a sample is dropped")
      ->capture_default_str();
  cmd->callback([o]() {
    const int code = RunTeleop(*o);
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

void AddDeviceCommand(CLI::App* app) {
  struct DeviceOptions {
    std::string connect = "127.0.0.1:18944";
    std::string name = "device";
    std::string input = "circle";
    double duration = 5.0, rate = 1000.0, amplitude = 0.04, units = 0.001;
  };
  auto o = std::make_shared<DeviceOptions>();
  CLI::App* cmd = app->add_subcommand(
      "device", "A network device: streams a scripted hand motion (sinusoid, circle, step, roll) or a "
                "recorded CSV as OpenIGTLink TRANSFORM messages to a trocar (teleop --listen)");
  cmd->add_option("--connect", o->connect, "ADDRESS:PORT of the trocar")->capture_default_str();
  cmd->add_option("--name", o->name, "the device's name in its messages")->capture_default_str();
  cmd->add_option("--input", o->input, "sinusoid, circle, step, roll, or a CSV (t,x,y,z,qw,qx,qy,qz)")
      ->capture_default_str();
  cmd->add_option("--duration", o->duration, "seconds")->capture_default_str();
  cmd->add_option("--rate", o->rate, "messages per second")->capture_default_str();
  cmd->add_option("--amplitude", o->amplitude, "scripted motion amplitude (m)")->capture_default_str();
  cmd->add_option("--units", o->units, "metres per unit sent (0.001: millimetres, OpenIGTLink's)")->capture_default_str();
  cmd->callback([o]() {
    control::IgtlServerOptions target;
    control::ParseListenAddress(o->connect, &target);
    TROCAR_THROW_UNLESS(std::isfinite(o->rate) && o->rate > 0 && o->rate <= 100000, "--rate " << o->rate << ": expected 0..100000");
    TROCAR_THROW_UNLESS(std::isfinite(o->duration) && o->duration > 0, "--duration " << o->duration << ": expected > 0");
    TROCAR_THROW_UNLESS(o->name.size() <= 20, "--name '" << o->name << "': at most 20 characters (OpenIGTLink)");
    std::unique_ptr<control::DeviceInput> input;
    if (o->input.size() > 4 && o->input.substr(o->input.size() - 4) == ".csv") {
      input = std::make_unique<control::CsvReplayInput>(o->input);
    } else {
      control::ScriptedMotion motion;
      motion.kind = control::ParseScriptedMotion(o->input);
      motion.amplitude = o->amplitude;
      input = std::make_unique<control::ScriptedInput>(motion);
    }
    control::IgtlDeviceClient client(target.address, target.port);
    const auto start = std::chrono::steady_clock::now();
    const auto period = std::chrono::duration<double>(1.0 / o->rate);
    long sent = 0;
    for (long k = 0;; ++k) {
      const auto due = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(period * k);
      std::this_thread::sleep_until(due);
      const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      if (t > o->duration) break;
      const control::DeviceSample s = input->Sample(t);
      if (!client.SendPose(o->name, s.X_DH, o->units)) {
        std::cout << "device: the trocar closed the connection after " << sent << " messages\n";
        break;
      }
      ++sent;
    }
    std::cout << "device '" << o->name << "': sent " << sent << " TRANSFORM messages to " << o->connect << " in "
              << std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() << " s; received";
    const auto& got = client.Received();
    if (got.empty()) std::cout << " nothing";
    for (const auto& [type, n] : got) std::cout << " " << n << " " << type;
    std::cout << "\n";
  });
}

}  // namespace trocar::apps
