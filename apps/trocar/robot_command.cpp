#include <cmath>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>

#include "apps/trocar/commands.hpp"
#include "common/error.hpp"
#include "common/geometry.hpp"
#include "kinematics/appearance.hpp"
#include "kinematics/dh_extraction.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/setup_joints.hpp"
#include "kinematics/start_configuration.hpp"
#include "robot/load_robot.hpp"

namespace trocar::apps {
namespace {

using robot::Joint;
using robot::JointDrive;
using robot::RobotModel;

std::string Number(double v) {
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  std::ostringstream out;
  out << std::setprecision(6) << v;
  return out.str();
}

void PrintPose(std::ostream& out, const Eigen::Isometry3d& X, const std::string& indent) {
  const Eigen::Vector3d p = X.translation();
  const Eigen::Vector3d rpy = RpyFromRotation(X.linear());
  const Eigen::Quaterniond quat(X.linear());
  out << std::fixed << std::setprecision(6);
  out << indent << "position (m):    " << p.x() << " " << p.y() << " " << p.z() << "\n";
  out << indent << "rotation:\n";
  for (int r = 0; r < 3; ++r) {
    out << indent << "  " << std::setw(10) << X.linear()(r, 0) << " " << std::setw(10)
        << X.linear()(r, 1) << " " << std::setw(10) << X.linear()(r, 2) << "\n";
  }
  out << indent << "rpy (rad):       " << rpy.x() << " " << rpy.y() << " " << rpy.z() << "\n";
  out << indent << "quaternion wxyz: " << quat.w() << " " << quat.x() << " " << quat.y() << " "
      << quat.z() << "\n";
  out.unsetf(std::ios::floatfield);
  out << std::setprecision(6);
}

std::string JointRole(const RobotModel& model, const Joint& joint) {
  switch (joint.drive) {
    case JointDrive::kActive: return "active q[" + std::to_string(joint.q_index) + "]";
    case JointDrive::kHeld: return "held";
    case JointDrive::kMimic: {
      std::ostringstream out;
      out << "mimic " << Number(joint.mimic.multiplier) << "*" << model.joint(joint.mimic.master).name;
      if (joint.mimic.offset != 0.0) out << "+" << Number(joint.mimic.offset);
      return out.str();
    }
    case JointDrive::kClosure: return "closure " + model.closures()[joint.closure].name;
  }
  return "";
}

void PrintTree(std::ostream& out, const RobotModel& model, int link, const std::string& prefix) {
  const auto& children = model.link(link).child_joints;
  for (std::size_t i = 0; i < children.size(); ++i) {
    const Joint& joint = model.joint(children[i]);
    const bool last = i + 1 == children.size();
    out << prefix << (last ? "`- " : "|- ") << model.link(joint.child_link).name << "  <- "
        << joint.name << " (" << robot::ToString(joint.type);
    if (joint.movable()) out << ", " << JointRole(model, joint);
    out << ")\n";
    PrintTree(out, model, joint.child_link, prefix + (last ? "   " : "|  "));
  }
}

void PrintGeometrySummary(std::ostream& out, const RobotModel& model) {
  int visuals = 0, collisions = 0;
  long triangles = 0, degenerate = 0;
  std::map<std::string, int> shapes;
  for (const auto& link : model.links()) {
    for (const auto* list : {&link.visuals, &link.collisions}) {
      for (const auto& g : *list) {
        ++shapes[robot::ToString(g.shape)];
        if (g.mesh) {
          triangles += static_cast<long>(g.mesh->triangles.size());
          degenerate += g.mesh->degenerate_triangles_removed;
        }
      }
    }
    visuals += static_cast<int>(link.visuals.size());
    collisions += static_cast<int>(link.collisions.size());
  }
  out << "geometry: " << visuals << " visual, " << collisions << " collision shapes (";
  bool first = true;
  for (const auto& [shape, count] : shapes) {
    out << (first ? "" : ", ") << count << " " << shape;
    first = false;
  }
  out << ")";
  if (triangles > 0) out << "; " << triangles << " mesh triangles";
  if (degenerate > 0) out << " (" << degenerate << " zero-area triangles dropped)";
  out << "\n";
}

// The meshes the links wear where drawn (kinematics/appearance.hpp): per appearance its file and,
// per worn link, how far its mesh is drawn from where its own model puts it over the fitting
// poses, beside the link's tolerance: what a user writing an `appearance:` sets tolerances from.
void PrintAppearance(std::ostream& out, const RobotModel& model) {
  const auto& appearances = model.defaults().appearances;
  if (appearances.empty()) return;
  const kinematics::Dressing dressing = kinematics::DressRobot(model);
  for (const robot::Appearance& a : appearances) {
    out << "appearance: " << a.links.size() << " links wear the meshes of " << a.urdf << "\n";
    for (const auto& wear : a.links) {
      const int l = model.GetLink(wear.link);
      if (dressing.worn[l].empty()) continue;
      out << "  " << std::left << std::setw(28) << wear.link << std::right << " wears " << std::left
          << std::setw(28) << wear.wears << std::right << " drawn within " << std::fixed
          << std::setprecision(1) << dressing.drift[l] * 1e3 << " mm of its place (at most "
          << a.ToleranceOf(wear.link) * 1e3 << ")" << std::defaultfloat << std::setprecision(6)
          << "\n";
    }
  }
  for (const std::string& note : dressing.notes) out << "  note: " << note << "\n";
}

void PrintInfo(std::ostream& out, const RobotModel& model) {
  int counts[4] = {0, 0, 0, 0};
  for (int j : model.dof_joints()) ++counts[static_cast<int>(model.joint(j).drive)];
  out << "robot '" << model.name() << "' from " << model.source() << "\n";
  out << "  " << model.num_links() << " links, " << model.num_joints() << " joints: "
      << model.num_positions() << " active, " << counts[1] << " held, " << counts[2]
      << " mimic, " << counts[3] << " closure-driven; " << model.closures().size()
      << " four-bar closures\n\n";
  out << "tree:\n" << model.link(0).name << "  (base)\n";
  PrintTree(out, model, 0, "");

  out << "\njoints (SI units: rad or m, rad/s or m/s, rad/s^2 or m/s^2):\n";
  out << "  " << std::left << std::setw(28) << "name" << std::setw(10) << "type" << std::setw(34)
      << "drive" << std::setw(24) << "axis" << std::setw(11) << "lower" << std::setw(11)
      << "upper" << std::setw(11) << "velocity" << "accel\n";
  for (int j : model.dof_joints()) {
    const Joint& joint = model.joint(j);
    out << "  " << std::setw(28) << joint.name << std::setw(10) << robot::ToString(joint.type)
        << std::setw(34) << JointRole(model, joint) << std::setw(24)
        << FormatVector(joint.axis_J, 3) << std::setw(11) << Number(joint.limits.lower)
        << std::setw(11) << Number(joint.limits.upper) << std::setw(11)
        << Number(joint.limits.velocity) << Number(joint.limits.acceleration) << "\n";
  }
  out << std::right;
  for (const auto& c : model.closures()) {
    out << "closure '" << c.name << "': driver " << model.joint(c.driver).name << ", coupler "
        << model.joint(c.coupler).name << ", rocker " << model.joint(c.rocker).name
        << "; ground link " << model.link(c.ground_link).name << "; crank " << Number(c.c0.norm())
        << " m, coupler " << Number(c.L23) << " m, rocker " << Number(c.L34) << " m, ground "
        << Number((c.P4 - c.P1).norm()) << " m\n";
  }
  out << "\ntool: link '" << model.link(model.tool_frame().link).name << "', "
      << model.tool_basis() << "\n";
  {
    const kinematics::StartConfiguration start = kinematics::ChooseStart(model);
    out << "start: " << FormatVector(start.q, 4) << ", " << start.basis << "\n";
    for (const std::string& w : start.warnings) out << "  warning: " << w << "\n";
  }
  out << "\nframes (every link is a frame too, by its name):\n";
  for (const auto& frame : model.frames()) {
    out << "  " << frame.name << " on link '" << model.link(frame.link).name << "' at xyz "
        << FormatVector(frame.X_LF.translation()) << " rpy "
        << FormatVector(RpyFromRotation(frame.X_LF.linear())) << "\n";
  }
  PrintGeometrySummary(out, model);
  PrintAppearance(out, model);

  std::string why_not;
  const auto dh = kinematics::ExtractModifiedDh(model, &why_not);
  if (dh) {
    out << "\nequivalent DH table (modified / Craig: Rx(alpha) Tx(a) Rz(theta) Tz(d); offset adds "
           "to theta (R) or d (P)):\n";
    out << "  base X_B0: xyz " << FormatVector(dh->X_B0.translation()) << " rpy "
        << FormatVector(RpyFromRotation(dh->X_B0.linear())) << "\n";
    out << "  " << std::left << std::setw(4) << "#" << std::setw(24) << "joint" << std::setw(6)
        << "type" << std::setw(12) << "alpha" << std::setw(12) << "a" << std::setw(12) << "theta"
        << std::setw(12) << "d" << std::setw(12) << "offset" << "range\n";
    for (std::size_t i = 0; i < dh->rows.size(); ++i) {
      const auto& row = dh->rows[i];
      auto clean = [](double v) { return Number(std::abs(v) < 1e-12 ? 0.0 : v); };
      out << "  " << std::setw(4) << i + 1 << std::setw(24) << row.joint << std::setw(6)
          << (row.type == robot::JointType::kRevolute ? "R" : "P") << std::setw(12)
          << clean(row.alpha) << std::setw(12) << clean(row.a) << std::setw(12)
          << clean(row.theta) << std::setw(12) << clean(row.d) << std::setw(12)
          << clean(row.offset) << Number(row.limits.lower) << " .. " << Number(row.limits.upper)
          << "\n";
    }
    out << std::right;
    out << "  tool X_NT: xyz " << FormatVector(dh->X_NT.translation()) << " rpy "
        << FormatVector(RpyFromRotation(dh->X_NT.linear())) << "\n";
  } else {
    out << "\nno equivalent DH table: " << why_not << "\n";
  }

  robot::RobotState state(model);
  const auto result =
      kinematics::ForwardKinematics(model, Eigen::VectorXd::Zero(model.num_positions()), &state);
  out << "\ntool pose at q = 0, in the base frame:\n";
  if (result.ok()) {
    PrintPose(out, kinematics::ToolPoseInBase(model, state), "  ");
  } else {
    out << "  not reachable: " << result.message << "\n";
  }
}

struct FkOptions {
  std::string file;
  std::vector<std::string> values;
  bool degrees = false;
  bool ignore_limits = false;
  std::string frame;
};

int RunFk(const FkOptions& options) {
  const RobotModel model = robot::LoadRobot(options.file);
  TROCAR_THROW_UNLESS(static_cast<int>(options.values.size()) == model.num_positions(),
                      "robot '" << model.name() << "' has " << model.num_positions()
                                << " active joints, got " << options.values.size()
                                << " values");
  Eigen::VectorXd q(model.num_positions());
  for (int i = 0; i < q.size(); ++i) {
    double v = 0.0;
    TROCAR_THROW_UNLESS(ParseScalarExpression(options.values[i], &v) && std::isfinite(v),
                        "value " << i + 1 << " ('" << options.values[i]
                                 << "') is not a finite number");
    const Joint& joint = model.joint(model.active_joints()[i]);
    if (options.degrees && joint.type == robot::JointType::kRevolute) v *= M_PI / 180.0;
    q[i] = v;
  }
  const auto violations = kinematics::LimitViolations(model, q);
  if (!violations.empty() && !options.ignore_limits) {
    std::string all;
    for (const auto& v : violations) all += "\n  " + v;
    TROCAR_THROW("configuration outside the joint limits (use --ignore-limits to evaluate it "
                 "anyway):" << all);
  }
  robot::RobotState state(model);
  const auto result = kinematics::ForwardKinematics(model, q, &state);
  if (!result.ok()) {
    std::cerr << "not reachable: " << result.message << "\n";
    return 3;
  }
  const robot::Frame& frame =
      options.frame.empty() ? model.tool_frame() : model.GetFrame(options.frame);
  const Eigen::Isometry3d X_BF =
      state.X_WL[model.base_link()].inverse() * kinematics::FramePose(state, frame);
  std::cout << "frame '" << frame.name << "' in base '" << model.link(model.base_link()).name
            << "' of robot '" << model.name() << "' at q = " << FormatVector(q, 9) << ":\n";
  PrintPose(std::cout, X_BF, "  ");
  return 0;
}

struct SujOptions {
  std::string file;
  std::string frame;
  std::vector<double> position;
  std::vector<double> axis;
  unsigned seed = 1;
};

int RunSuj(const SujOptions& options) {
  robot::LoadOptions load;
  load.load_meshes = false;
  const RobotModel model = robot::LoadRobot(options.file, load);
  kinematics::SetupJointRequest request;
  request.frame = options.frame;
  request.p_WF = Eigen::Vector3d(options.position[0], options.position[1], options.position[2]);
  if (!options.axis.empty()) {
    request.axis_W = Eigen::Vector3d(options.axis[0], options.axis[1], options.axis[2]);
  }
  robot::RobotState state(model);
  const auto configured = kinematics::SetConfiguration(model, model.neutral_configuration(), &state);
  TROCAR_THROW_UNLESS(configured.ok(), "robot '" << model.name() << "': neutral configuration: "
                                               << configured.message);
  kinematics::SetupJointOptions solver;
  solver.seed = options.seed;
  const auto result = kinematics::SolveSetupJoints(model, state, request, solver);
  std::cout << result.message << "\n";
  std::cout << (result.ok() ? "setup joints:\n" : "best setup joints found:\n");
  for (std::size_t i = 0; i < result.joints.size() && i < std::size_t(result.values.size()); ++i) {
    std::cout << "  " << std::left << std::setw(28) << result.joints[i] << std::right
              << result.values[i] << "\n";
  }
  return result.ok() ? 0 : 3;
}

}  // namespace

void AddRobotCommand(CLI::App* app) {
  CLI::App* robot = app->add_subcommand("robot", "Inspect robot descriptions (URDF, DH YAML)");
  robot->require_subcommand(1);

  auto info_file = std::make_shared<std::string>();
  auto no_meshes = std::make_shared<bool>(false);
  CLI::App* info = robot->add_subcommand(
      "info", "Print the kinematic tree, joints, limits, DH table and the tool pose at zero");
  info->add_option("file", *info_file, "robot description (.urdf or .yaml)")->required();
  info->add_flag("--no-meshes", *no_meshes, "check that mesh files exist but do not read them");
  info->callback([info_file, no_meshes]() {
    robot::LoadOptions options;
    options.load_meshes = !*no_meshes;
    PrintInfo(std::cout, robot::LoadRobot(*info_file, options));
  });

  auto fk = std::make_shared<FkOptions>();
  CLI::App* fk_cmd = robot->add_subcommand(
      "fk", "Print the tool pose in the base frame for the given active joint values");
  fk_cmd->add_option("file", fk->file, "robot description (.urdf or .yaml)")->required();
  fk_cmd->add_option("q", fk->values,
                     "active joint values in q order (rad or m; expressions such as pi/2 and 30deg are accepted; put -- before the values when one starts with - and is not a plain number, e.g. -- 0 -pi/6)");
  fk_cmd->add_flag("--deg", fk->degrees, "revolute values are in degrees");
  fk_cmd->add_flag("--ignore-limits", fk->ignore_limits, "evaluate beyond the joint limits");
  fk_cmd->add_option("--frame", fk->frame, "named frame instead of the tool (e.g. rcm)");
  fk_cmd->callback([fk]() {
    const int code = RunFk(*fk);
    if (code != 0) throw CLI::RuntimeError(code);
  });

  auto suj = std::make_shared<SujOptions>();
  CLI::App* suj_cmd = robot->add_subcommand(
      "suj", "Solve the held setup joints that put a frame (an arm's RCM) at a port");
  suj_cmd->add_option("file", suj->file, "robot description, e.g. a da Vinci cart")->required();
  suj_cmd->add_option("--frame", suj->frame, "frame to place, e.g. psm1_rcm")->required();
  suj_cmd->add_option("--position", suj->position, "target position x y z in the world (m)")
      ->required()
      ->expected(3);
  suj_cmd->add_option("--axis", suj->axis,
                      "direction x y z the instrument axis (the frame's -z) must point along")
      ->expected(3);
  suj_cmd->add_option("--seed", suj->seed, "seed of the solver's random starts");
  suj_cmd->callback([suj]() {
    const int code = RunSuj(*suj);
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace trocar::apps
