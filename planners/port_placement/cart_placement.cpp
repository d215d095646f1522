#include "port_placement/cart_placement.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "collision/collision_world.hpp"
#include "common/error.hpp"
#include "common/geometry.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/setup_joints.hpp"
#include "patient/patient_model.hpp"

namespace trocar::planners {

const char* ToString(PlacementStatus status) {
  switch (status) {
    case PlacementStatus::kPlaced:
      return "placed";
    case PlacementStatus::kUnreachable:
      return "unreachable";
    case PlacementStatus::kInCollision:
      return "in collision";
  }
  return "?";
}

CartPlacementRequest DefaultPorts(const patient::PatientModel& patient,
                                  const std::vector<PlanArm>& arms) {
  TROCAR_THROW_UNLESS(!patient.port_candidates.empty(),
                      "patient '" << patient.name
                                  << "' has no port candidates (annotate them or let "
                                     "the intercostal spaces be found)");
  TROCAR_THROW_UNLESS(!patient.targets.empty() && !patient.targets[0].points.empty(),
                      "patient '" << patient.name << "' has no target to aim the instruments at");
  TROCAR_THROW_UNLESS(!arms.empty(), "no arms to place");
  CartPlacementRequest request;
  Eigen::Vector3d target_P = Eigen::Vector3d::Zero();
  for (const auto& p : patient.targets[0].points) target_P += p;
  target_P /= static_cast<double>(patient.targets[0].points.size());
  request.aim_W = patient.X_WP * target_P;
  std::vector<Eigen::Vector3d> middles;
  for (const auto& c : patient.port_candidates) {
    if (!c.skin.empty()) middles.push_back(c.skin[c.skin.size() / 2]);
  }
  TROCAR_THROW_UNLESS(!middles.empty(),
                      "patient '" << patient.name << "': every port candidate curve is empty");
  // Superior to inferior along the body axis (P's z is superior).
  std::sort(middles.begin(), middles.end(),
            [](const Eigen::Vector3d& a, const Eigen::Vector3d& b) { return a.z() > b.z(); });
  // Instruments spread outside, endoscopes between them.
  std::vector<const PlanArm*> order;
  std::vector<const PlanArm*> instruments, scopes;
  for (const auto& a : arms) (a.role == ArmRole::kEndoscope ? scopes : instruments).push_back(&a);
  for (std::size_t i = 0; i < instruments.size(); ++i) {
    order.push_back(instruments[i]);
    if (i == 0) order.insert(order.end(), scopes.begin(), scopes.end());
  }
  if (instruments.empty()) order = scopes;
  const int n = static_cast<int>(middles.size());
  const int m = static_cast<int>(order.size());
  for (int i = 0; i < m; ++i) {
    const double at = m == 1 ? 0.5 : 0.15 + 0.7 * i / (m - 1);
    const int index = std::clamp(static_cast<int>(std::lround(at * (n - 1))), 0, n - 1);
    request.ports.push_back({*order[i], patient.X_WP * middles[index]});
  }
  return request;
}

CartPlacementResult PlaceCart(const robot::RobotModel& cart, const CartPlacementRequest& request,
                              const CartPlacementOptions& options, robot::RobotState* state) {
  state->X_WB = request.X_WB;
  CartPlacementResult result;
  bool reached = true;
  std::ostringstream message;
  for (const auto& port : request.ports) {
    const PlanArm& arm = port.arm;
    const Eigen::Vector3d axis = request.aim_W - port.p_W;
    if (!arm.has_rcm())
      continue;  // a software RCM: the arm's own joints keep the shaft at the port
    kinematics::SetupJointRequest suj;
    suj.frame = arm.rcm_frame;
    suj.p_WF = port.p_W;
    if (axis.norm() > 1e-6) suj.axis_W = axis.normalized();
    kinematics::SetupJointOptions suj_options;
    suj_options.seed = options.seed;
    suj_options.starts = options.starts;
    suj_options.max_iterations = options.max_iterations;
    auto solved = kinematics::SolveSetupJoints(cart, *state, suj, suj_options);
    // The setup joints put the RCM at the port; pointing the instrument at the aim as well is
    // best effort: an arm whose setup joints cannot turn its RCM that far (the ECM's SUJ has four
    // joints, all but one vertical) keeps the nearest direction, and its own joints aim the rest.
    const bool at_port = solved.position_error <= suj_options.position_tolerance;
    if (!at_port && suj.axis_W) {
      // At the port first, aimed as near as the setup joints allow (not the position alone:
      // an RCM turned anywhere leaves the arm's own joints at their limits).
      auto port_first = suj_options;
      port_first.axis_secondary = true;
      const auto retry = kinematics::SolveSetupJoints(cart, *state, suj, port_first);
      if (retry.position_error < solved.position_error) solved = retry;
    }
    const bool placed = solved.position_error <= suj_options.position_tolerance;
    for (std::size_t i = 0; i < solved.joints.size(); ++i) {
      kinematics::SetHeldJoint(cart, solved.joints[i], solved.values[i], state);
    }
    result.worst_position_error = std::max(result.worst_position_error, solved.position_error);
    result.worst_angle_error = std::max(result.worst_angle_error, solved.angle_error);
    reached = reached && placed;
    if (placed && !solved.ok()) {
      std::ostringstream m;
      m << "frame '" << arm.rcm_frame << "' placed (error "
        << FormatError(solved.position_error * 1e3, "mm") << "); its axis "
        << FormatError(solved.angle_error * 180.0 / M_PI, "deg", 0.1)
        << " off the aim (the arm's joints aim the rest)";
      solved.message = m.str();
    }
    message << "  " << arm.rcm_frame << ": " << solved.message << "\n";
  }
  // Instruments inserted toward the aim; the arm's other joints point the shaft there (for an
  // arm with a mechanical RCM the setup joints already did).
  kinematics::ForwardKinematics(cart, state->q, state);
  if (request.insert_toward_aim) {
    for (const auto& port : request.ports) {
      const PlanArm& arm = port.arm;
      if (!arm.has_rcm() || arm.insertion_q < 0) continue;
      const Eigen::Vector3d axis = request.aim_W - port.p_W;
      if (axis.norm() < 1e-6) continue;
      const Eigen::Vector3d p_rcm =
          kinematics::FramePose(*state, cart.GetFrame(arm.rcm_frame)).translation();
      const double depth =
          (kinematics::FramePose(*state, cart.GetFrame(arm.tool_frame)).translation() - p_rcm)
              .dot(axis.normalized());
      const robot::Joint& joint = cart.joint(cart.active_joints()[arm.insertion_q]);
      double& q = state->q[arm.insertion_q];
      q = std::clamp(q + (axis.norm() - request.insertion_margin - depth), joint.limits.lower,
                     joint.limits.upper);
    }
  }
  const auto fk = kinematics::ForwardKinematics(cart, state->q, state);
  if (!fk.ok()) {
    reached = false;
    message << "  " << fk.message << "\n";
  }
  result.status = reached ? PlacementStatus::kPlaced : PlacementStatus::kUnreachable;
  if (reached && options.checker) {
    options.checker->SetRobotState(*state);
    const collision::CollisionReport report = options.checker->Check();
    result.collisions = static_cast<int>(report.contacts.size());
    if (report.collision) {
      result.status = PlacementStatus::kInCollision;
      message << "  in collision: " << report.contacts.size() << " pairs, e.g. "
              << options.checker->world().DescribePair(report.contacts[0].a, report.contacts[0].b)
              << "\n";
    }
  }
  result.message = message.str();
  return result;
}

CartPlacementResult PlaceCartAutomatically(const robot::RobotModel& cart,
                                           CartPlacementRequest* request,
                                           const CartPlacementOptions& options,
                                           robot::RobotState* state) {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const auto& p : request->ports) centre += p.p_W;
  centre /= static_cast<double>(std::max<std::size_t>(1, request->ports.size()));
  CartPlacementResult best;
  best.worst_position_error = std::numeric_limits<double>::infinity();
  int best_collisions = std::numeric_limits<int>::max();
  robot::RobotState best_state = *state;
  Eigen::Isometry3d best_pose = request->X_WB;
  // From the patient's right (the cart faces +y_W) first, then around.
  for (int d = 0; d < 8; ++d) {
    const double heading = M_PI / 2 + d * M_PI / 4;  // direction the cart faces
    for (double distance = 0.5; distance <= 1.3 + 1e-9; distance += 0.1) {
      CartPlacementRequest trial = *request;
      trial.X_WB = Eigen::Isometry3d::Identity();
      trial.X_WB.linear() = Eigen::AngleAxisd(heading, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      trial.X_WB.translation() =
          Eigen::Vector3d(centre.x(), centre.y(), 0) -
          distance * Eigen::Vector3d(std::cos(heading), std::sin(heading), 0);
      robot::RobotState s = *state;
      const CartPlacementResult r = PlaceCart(cart, trial, options, &s);
      const bool better =
          r.status != PlacementStatus::kUnreachable
              ? (best.status == PlacementStatus::kUnreachable || r.collisions < best_collisions)
              : (best.status == PlacementStatus::kUnreachable &&
                 r.worst_position_error < best.worst_position_error);
      if (better) {
        best = r;
        best_collisions = r.collisions;
        best_state = s;
        best_pose = trial.X_WB;
      }
      if (r.ok()) {
        request->X_WB = trial.X_WB;
        *state = s;
        return r;
      }
    }
  }
  request->X_WB = best_pose;
  *state = best_state;
  best.message = "no cart pose places every arm collision-free; the nearest:\n" + best.message;
  return best;
}

}  // namespace trocar::planners
