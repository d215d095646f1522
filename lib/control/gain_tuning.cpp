#include "control/gain_tuning.hpp"

#include <cmath>
#include <filesystem>
#include <map>
#include <vector>
#include <iomanip>
#include <sstream>

#include <nlopt.hpp>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/yaml_util.hpp"
#include "robot/load_robot.hpp"
#include "control/control_loop.hpp"
#include "control/teleop_session.hpp"

namespace trocar::control {
namespace {

Vector6d GainsOf(double rotation, double translation) {
  Vector6d g;
  g << rotation, rotation, rotation, translation, translation, translation;
  return g;
}

struct Evaluation {
  double rms_position = 0.0, max_position = 0.0, rms_orientation = 0.0, overshoot = 0.0;
  double cost = 0.0;
};

Evaluation Evaluate(const robot::RobotModel& model, const Eigen::VectorXd& q0,
                    const GainTuningOptions& o, const Vector6d& gains) {
  Evaluation e;
  // Tracking on the reference trajectory.
  {
    ControlLoop loop(model, MakeControllerWithGains(o.controller, gains), q0);
    ScriptedInput input(o.trajectory);
    TeleopSessionOptions session;
    session.duration = o.duration;
    session.rate_hz = o.rate_hz;
    session.mapping.scale = o.scale;
    const TrackingSummary s = RunTeleopSession(&loop, &input, session).Summarize();
    e.rms_position = s.rms_position_error;
    e.max_position = s.max_position_error;
    e.rms_orientation = s.rms_orientation_error;
  }
  // Oscillation: overshoot of a step response along the step.
  {
    ScriptedMotion step;
    step.kind = ScriptedMotion::Kind::kStep;
    step.step_time = 0.05;
    step.step_angle = 0.0;
    step.step = o.trajectory.amplitude * 0.25 * Eigen::Vector3d(1, -1, 1).normalized();
    ControlLoop loop(model, MakeControllerWithGains(o.controller, gains), q0);
    const Eigen::Vector3d start = loop.ToolPose().translation();
    ScriptedInput input(step);
    TeleopSessionOptions session;
    session.duration = 1.0;
    session.rate_hz = o.rate_hz;
    session.mapping.scale = o.scale;
    const Recorder recorder = RunTeleopSession(&loop, &input, session);
    const Eigen::Vector3d target = start + step.step / o.scale;
    const Eigen::Vector3d direction = (target - start).normalized();
    double worst = 0.0;
    for (const RecordRow& row : recorder.rows()) {
      if (row.t < step.step_time) continue;
      worst = std::max(worst, (row.X_WT.translation() - target).dot(direction));
    }
    e.overshoot = worst / (target - start).norm();
  }
  const double scale_m_per_rad = 0.05;
  e.cost = e.rms_position + scale_m_per_rad * e.rms_orientation;
  if (!std::isfinite(e.cost)) e.cost = 1e3;
  if (e.overshoot > o.max_overshoot) e.cost += 10.0 * (e.overshoot - o.max_overshoot) * 0.01 + 0.01;
  return e;
}

}  // namespace

GainTuningResult TuneGains(const robot::RobotModel& model, const Eigen::VectorXd& q0,
                           const GainTuningOptions& o) {
  MakeControllerWithGains(o.controller, Vector6d::Ones());  // throws for an unknown name
  TROCAR_THROW_UNLESS(o.min_gain > 0 && o.max_gain > o.min_gain && std::isfinite(o.max_gain),
                      "gain tuning: gain bounds [" << o.min_gain << ", " << o.max_gain
                                                   << "] must be positive and ordered");
  TROCAR_THROW_UNLESS(o.max_evaluations > 0, "gain tuning: max_evaluations must be positive");
  const Vector6d start = TaskGains(model, o.controller, GainsOf(20, 40));
  GainTuningResult result;
  result.initial_rms_position_error = Evaluate(model, q0, o, start).rms_position;

  // Search in log-gain space: [log rotation gain, log translation gain].
  nlopt::opt optimiser(nlopt::LN_BOBYQA, 2);
  optimiser.set_lower_bounds(std::vector<double>(2, std::log(o.min_gain)));
  optimiser.set_upper_bounds(std::vector<double>(2, std::log(o.max_gain)));
  optimiser.set_maxeval(o.max_evaluations);
  optimiser.set_xtol_rel(1e-3);
  struct Context {
    const robot::RobotModel* model;
    const Eigen::VectorXd* q0;
    const GainTuningOptions* options;
    int evaluations = 0;
  } context{&model, &q0, &o};
  optimiser.set_min_objective(
      [](const std::vector<double>& x, std::vector<double>&, void* data) {
        auto* c = static_cast<Context*>(data);
        ++c->evaluations;
        return Evaluate(*c->model, *c->q0, *c->options, GainsOf(std::exp(x[0]), std::exp(x[1]))).cost;
      },
      &context);
  std::vector<double> x = {std::log(std::clamp(start[0], o.min_gain, o.max_gain)),
                           std::log(std::clamp(start[3], o.min_gain, o.max_gain))};
  double cost = 0.0;
  try {
    optimiser.optimize(x, cost);
  } catch (const nlopt::roundoff_limited&) {
    // keep the best point found
  } catch (const std::exception& e) {
    TROCAR_THROW("gain tuning: the optimiser failed: " << e.what());
  }
  result.gains = GainsOf(std::exp(x[0]), std::exp(x[1]));
  const Evaluation best = Evaluate(model, q0, o, result.gains);
  result.rms_position_error = best.rms_position;
  result.max_position_error = best.max_position;
  result.rms_orientation_error = best.rms_orientation;
  result.overshoot = best.overshoot;
  result.evaluations = context.evaluations;
  return result;
}

std::string SaveControllerGains(const std::string& description, const std::string& controller,
                                const Vector6d& gains) {
  // The overlay beside the robot, never the user's own file: other controllers' gains in it are
  // kept; numbers are written at full precision (17 significant digits) with yaml-cpp.
  const std::string path = robot::GainsOverlayPath(description);
  std::map<std::string, std::vector<double>> all;
  if (IsRegularFile(path)) {
    const YamlReader r = YamlReader::Load(path);
    if (r.root()["gains"] && r.root()["gains"].IsMap()) {
      for (const auto& entry : r.root()["gains"]) {
        const std::string name = r.String(entry.first, "gains");
        all[name] = r.Numbers(entry.second, "gains." + name);
      }
    }
  }
  all[controller] = std::vector<double>(gains.data(), gains.data() + 6);
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::Comment("Controller gains tuned by trocar for " +
                       std::filesystem::path(description).filename().string() +
                       "; read after the robot's own file. Delete it to tune again.");
  out << YAML::BeginMap << YAML::Key << "robot" << YAML::Value
      << std::filesystem::path(description).filename().string() << YAML::Key << "gains"
      << YAML::Value << YAML::BeginMap;
  for (const auto& [name, values] : all) {
    out << YAML::Key << name << YAML::Value << YAML::Flow << values;
  }
  out << YAML::EndMap << YAML::EndMap;
  WriteFileAtomically(path, std::string(out.c_str()) + "\n");
  return path;
}

}  // namespace trocar::control
