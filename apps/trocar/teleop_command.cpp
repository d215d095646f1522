// trocar teleop: a headless teleoperation session on a simulated clock.
#include <filesystem>
#include <atomic>
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
#include "scene.hpp"
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
};

int RunTeleop(const TeleopCommandOptions& o) {
  robot::LoadOptions load;
  load.load_meshes = o.view;  // the window draws the robot's meshes
  const auto shared_model = std::make_shared<const robot::RobotModel>(robot::LoadRobot(o.robot, load));
  const robot::RobotModel& model = *shared_model;
  // The robot's home, or one chosen away from limits and singularities; --q0 overrides both.
  kinematics::StartConfiguration start = kinematics::ChooseStart(model);
  Eigen::VectorXd q0 = start.q;
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
  control::ControlLoop loop(model, control::MakeController(o.controller, model, fallback), q0);

  std::unique_ptr<control::DeviceInput> input;
  std::optional<double> step_time;
  const bool is_file = o.input.size() > 4 && o.input.substr(o.input.size() - 4) == ".csv";
  viz::KeyboardInput* keyboard = nullptr;
  if (o.input == "keyboard") {
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
  session.realtime = o.realtime || o.view;  // a person watches: the clock is the wall's
  session.runner_stats = &timing;
  control::Recorder recorder;
  viz::TeleopViewStats view_stats;
  if (o.view) {
    // The control thread runs the session; this thread renders what it publishes, never
    // waiting on it.
    viz::Scene scene(nullptr, shared_model);
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
    try {
      view_stats = viz::RunTeleopView(&scene, &snapshots, [&] { return done.load(); }, vo, keyboard);
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
            << o.duration << " s at " << o.rate << " Hz" << (o.realtime || o.view ? " (real time)" : "")
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
              << view_stats.snapshots << " new control steps shown\n";
  }
  if (o.realtime || o.view) {
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
  cmd->add_option("--robot", o->robot, "robot description (.urdf or .yaml)")->required();
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
  cmd->add_option("--grab", o->grab, "with --view: save an image of the window when the session ends");
  cmd->add_option("--max-jump", o->max_jump, "device jump (m) beyond which a sample is dropped")
      ->capture_default_str();
  cmd->callback([o]() {
    const int code = RunTeleop(*o);
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace trocar::apps
