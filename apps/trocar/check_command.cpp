// trocar check: a robot configuration at a patient — collisions and clearances.
#include <chrono>
#include <cmath>
#include <iomanip>
#include <iostream>
#include <memory>

#include "apps/trocar/commands.hpp"
#include "collision/collision_world.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/geometry.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/cart_placement.hpp"
#include "robot/load_robot.hpp"

namespace trocar::apps {
namespace {

struct CheckOptions {
  std::string robot;  // default: the bundled da Vinci cart
  std::string patient;
  std::vector<std::string> ports;  // FRAME=x,y,z (patient frame, m)
  std::vector<double> base;        // x y heading_deg
  std::vector<std::string> q;      // active joints (SI, or expressions)
  double port_radius = 0.015;
  std::string bvh = "obbrss";
  unsigned seed = 1;
  std::string plan;  // a plan file to re-check
};

Eigen::Vector3d ParsePoint(const std::string& text, const std::string& what) {
  std::vector<double> v;
  std::stringstream in(text);
  std::string part;
  while (std::getline(in, part, ',')) {
    double x = 0;
    TROCAR_THROW_UNLESS(ParseScalarExpression(part, &x) && std::isfinite(x),
                        what << ": '" << part << "' is not a number");
    v.push_back(x);
  }
  TROCAR_THROW_UNLESS(v.size() == 3, what << ": expected x,y,z, got '" << text << "'");
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

std::string Point(const Eigen::Vector3d& p) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(3) << "[" << p.x() << ", " << p.y() << ", " << p.z() << "]";
  return s.str();
}

int RunCheck(const CheckOptions& o) {
  using Clock = std::chrono::steady_clock;
  if (!o.plan.empty()) return CheckPlanFile(o.plan, std::cout);
  // The bundled cart: from the working folder, else from the source tree this binary was built
  // from.
  std::string robot_file = o.robot;
  if (robot_file.empty()) {
    robot_file = "robots/davinci-classic/cart.yaml";
    if (!IsRegularFile(robot_file)) robot_file = std::string(TROCAR_SOURCE_DIR) + "/" + robot_file;
  }
  auto cart = std::make_shared<const robot::RobotModel>(robot::LoadRobot(robot_file));
  std::unique_ptr<patient::PatientModel> patient;
  if (!o.patient.empty())
    patient = std::make_unique<patient::PatientModel>(patient::ImportPatient(o.patient));
  collision::WorldOptions options;
  options.port_radius = o.port_radius;
  TROCAR_THROW_UNLESS(o.bvh == "obbrss" || o.bvh == "obb",
                      "--bvh: '" << o.bvh << "', expected obbrss or obb");
  options.bvh = o.bvh == "obb" ? collision::BvhKind::kObb : collision::BvhKind::kObbRss;
  const auto t0 = Clock::now();
  const auto world = collision::CollisionWorld::Build(patient.get(), cart, options);
  const double build_s = std::chrono::duration<double>(Clock::now() - t0).count();

  robot::RobotState state(*cart);
  if (!o.q.empty()) {
    TROCAR_THROW_UNLESS(static_cast<int>(o.q.size()) == cart->num_positions(),
                        "--q: robot '" << cart->name() << "' has " << cart->num_positions()
                                       << " active joints, got " << o.q.size() << " values");
    for (int i = 0; i < cart->num_positions(); ++i) {
      TROCAR_THROW_UNLESS(ParseScalarExpression(o.q[i], &state.q[i]) && std::isfinite(state.q[i]),
                          "--q: value " << i + 1 << " ('" << o.q[i] << "') is not a finite number");
    }
    const auto violations = kinematics::LimitViolations(*cart, state.q);
    TROCAR_THROW_UNLESS(violations.empty(), "--q: " << violations.front());
  }
  std::cout << "robot " << cart->name() << ": " << world->bodies().size() << " collision bodies";
  if (patient)
    std::cout << ", patient " << patient->name << " (" << world->triangle_count()
              << " triangles) on the table";
  std::cout << "\nworld: " << collision::ToString(options.bvh) << ", " << world->arms().size()
            << " arms, " << world->ports().size() << " ports (radius " << o.port_radius * 1e3
            << " mm), " << world->auto_allowed_pairs() << " link pairs allowed to touch, built in "
            << std::fixed << std::setprecision(2) << build_s << " s\n";

  if (patient) {
    const std::vector<planners::PlanArm> arms = planners::FindArms(*cart);
    planners::CartPlacementRequest setup = planners::DefaultPorts(*patient, arms);
    for (const auto& spec : o.ports) {
      const auto eq = spec.find('=');
      TROCAR_THROW_UNLESS(eq != std::string::npos,
                          "--port: '" << spec << "', expected FRAME=x,y,z");
      const std::string frame = spec.substr(0, eq);
      const Eigen::Vector3d p_W =
          patient->X_WP * ParsePoint(spec.substr(eq + 1), "--port " + frame);
      bool found = false;
      for (auto& p : setup.ports) {
        if (p.arm.rcm_frame == frame || p.arm.name == frame) p.p_W = p_W, found = true;
      }
      if (!found) setup.ports.push_back({planners::SelectArms(arms, {frame}).front(), p_W});
    }
    setup.insert_toward_aim = o.q.empty();  // joint values given: keep them as given
    planners::CartPlacementResult placed;
    planners::CartPlacementOptions placement_options;
    placement_options.seed = o.seed;
    if (o.base.empty()) {
      placed = planners::PlaceCartAutomatically(*cart, &setup, placement_options, &state);
    } else {
      TROCAR_THROW_UNLESS(o.base.size() == 3, "--base: expected x y heading_deg");
      for (double v : o.base)
        TROCAR_THROW_UNLESS(std::isfinite(v), "--base: " << v << " is not a finite number");
      setup.X_WB = Eigen::Isometry3d::Identity();
      setup.X_WB.linear() =
          Eigen::AngleAxisd(o.base[2] * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      setup.X_WB.translation() = Eigen::Vector3d(o.base[0], o.base[1], 0);
      placed = planners::PlaceCart(*cart, setup, placement_options, &state);
    }
    const double heading =
        std::atan2(setup.X_WB.linear()(1, 0), setup.X_WB.linear()(0, 0)) * 180 / M_PI;
    std::cout << "cart at " << Point(setup.X_WB.translation()) << " m, heading "
              << std::setprecision(0) << heading << " deg; instruments aimed at "
              << patient->targets[0].name << " " << std::setprecision(3) << Point(setup.aim_W)
              << "\n";
    for (const auto& p : setup.ports)
      std::cout << "  port " << p.arm.rcm_frame << " at " << Point(p.p_W) << " (world, m)\n";
    std::cout << placed.message;
    if (placed.status == planners::PlacementStatus::kUnreachable)
      std::cout
          << "warning: the setup joints do not reach every port; checking the nearest placement\n";
  } else {
    const auto fk = kinematics::ForwardKinematics(*cart, state.q, &state);
    TROCAR_THROW_UNLESS(fk.ok(), fk.message);
  }

  collision::CollisionChecker checker(world);
  checker.SetRobotState(state);
  const auto t1 = Clock::now();
  const collision::CollisionReport report = checker.Check();
  const double check_us = std::chrono::duration<double, std::micro>(Clock::now() - t1).count();
  const auto& bodies = world->bodies();
  std::cout << std::setprecision(1);
  if (report.collision) {
    std::cout << "IN COLLISION: " << report.contacts.size() << " pairs (checked in " << check_us
              << " us)\n";
    for (const auto& c : report.contacts) {
      std::cout << "  " << std::left << std::setw(18) << collision::ToString(c.cls) << std::right
                << " " << bodies[c.a].name << " - " << bodies[c.b].name << " at " << Point(c.p_W)
                << "\n";
    }
  } else {
    std::cout << "collision-free (checked in " << check_us << " us)\n";
  }
  if (report.port_contacts_allowed > 0) {
    std::cout << "  " << report.port_contacts_allowed
              << " instrument(s) pass the skin at their port\n";
  }
  std::cout << "clearances (m):\n";
  for (const auto& c : checker.ClearanceByClass()) {
    if (!c.valid()) continue;
    std::cout << "  " << std::left << std::setw(18) << collision::ToString(c.cls) << std::right
              << " " << std::setprecision(4) << c.distance << "  " << bodies[c.a].name << " - "
              << bodies[c.b].name << "  at " << Point(c.p_W_a) << " / " << Point(c.p_W_b) << "\n";
  }
  return report.collision ? 3 : 0;
}

}  // namespace

void AddCheckCommand(CLI::App* app) {
  auto o = std::make_shared<CheckOptions>();
  CLI::App* cmd = app->add_subcommand(
      "check",
      "Check a robot configuration at a patient: collisions (pairs, points) and clearances");
  cmd->add_option(
      "--robot", o->robot,
      "robot description (default: robots/davinci-classic/cart.yaml, the da Vinci Classic cart)");
  cmd->add_option("--patient", o->patient,
                  "patient case folder (patients/<case>); the cart is placed at its ports");
  cmd->add_option(
      "--port", o->ports,
      "FRAME=x,y,z: put an arm's RCM frame at a point of the patient frame (LPS, m); default: "
      "spread over the port candidates");
  cmd->add_option("--base", o->base,
                  "cart pose on the floor: x y (m) heading (deg); default: searched")
      ->expected(3);
  cmd->add_option(
      "--q", o->q,
      "active joint values (m, rad; expressions like pi/6), kept as given; default: neutral "
      "with each instrument inserted toward the target");
  cmd->add_option("--port-radius", o->port_radius, "skin contact allowed around each port (m)")
      ->capture_default_str();
  cmd->add_option("--bvh", o->bvh, "bounding volumes of the meshes: obbrss or obb")
      ->capture_default_str();
  cmd->add_option("--seed", o->seed, "seed of the setup-joint solver")->capture_default_str();
  cmd->add_option(
      "--plan", o->plan,
      "re-check every claim of a plan file (cart pose, setup joints, every reached target sample) "
      "through the robot model, joint limits and collision checker");
  cmd->footer(
      "Exit status: 0 collision-free (with --plan: every claim holds), 3 in collision (a claim "
      "fails), 1 bad input.");
  cmd->callback([o]() {
    const int code = RunCheck(*o);
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace trocar::apps
