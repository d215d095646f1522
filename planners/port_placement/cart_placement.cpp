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

const kinematics::SetupJointResult* SetupJointMemo::Find(const std::string& key) {
  const auto it = entries_.find(key);
  if (it == entries_.end()) {
    ++misses_;
    return nullptr;
  }
  ++hits_;
  return &it->second;
}

void SetupJointMemo::Remember(std::string key, const kinematics::SetupJointResult& solved) {
  if (entries_.size() >= kCapacity) entries_.clear();
  entries_.emplace(std::move(key), solved);
}

namespace {

// The joints whose values move `link`: those on its path, and, transitively, the masters of mimic
// joints and the drivers of closures among them (SetConfiguration resolves those from their
// drivers, wherever the drivers are).
std::vector<int> JointsMoving(const robot::RobotModel& model, int link) {
  std::vector<bool> in(model.joints().size(), false);
  for (int j : model.movable_path(link)) in[j] = true;
  for (bool grew = true; grew;) {
    grew = false;
    for (int step : model.resolve_order()) {
      if (step >= 0) {
        const int master = model.joint(step).mimic.master;
        if (in[step] && master >= 0 && !in[master]) in[master] = grew = true;
      } else {
        const robot::FourBarClosure& c = model.closures()[-1 - step];
        if ((in[c.coupler] || in[c.rocker]) && !in[c.driver]) in[c.driver] = grew = true;
      }
    }
  }
  std::vector<int> out;
  for (std::size_t j = 0; j < in.size(); ++j)
    if (in[j]) out.push_back(static_cast<int>(j));
  return out;
}

// The exact bits of everything one arm's setup-joint solve in PlaceCart reads: the frame, the
// cart's pose, the port, the axis, the options, the active joints and the values of the joints
// that move the frame (their current values are the first start's).
std::string SolveKey(const robot::RobotModel& cart, const robot::RobotState& state,
                     const kinematics::SetupJointRequest& request,
                     const kinematics::SetupJointOptions& options) {
  std::string key;
  auto put = [&key](const void* p, std::size_t n) { key.append(static_cast<const char*>(p), n); };
  auto put_double = [&put](double v) { put(&v, sizeof v); };
  const int link = cart.GetFrame(request.frame).link;
  key.append(request.frame);
  key.push_back('\0');
  put(state.X_WB.matrix().data(), 16 * sizeof(double));
  put(request.p_WF.data(), 3 * sizeof(double));
  const bool axis = request.axis_W.has_value();
  put(&axis, sizeof axis);
  if (axis) put(request.axis_W->data(), 3 * sizeof(double));
  put(request.axis_F.data(), 3 * sizeof(double));
  put(&options.seed, sizeof options.seed);
  put(&options.starts, sizeof options.starts);
  put(&options.max_iterations, sizeof options.max_iterations);
  put_double(options.position_tolerance);
  put_double(options.angle_tolerance);
  put_double(options.length_scale);
  for (const std::string& name : request.joints) key.append(name + '\0');
  put(state.q.data(), static_cast<std::size_t>(state.q.size()) * sizeof(double));
  // Whether the whole robot's passive joints resolve (the solver's first check) reads the values
  // of every joint that drives one.
  for (int step : cart.resolve_order()) {
    const int driver =
        step >= 0 ? cart.joint(step).mimic.master : cart.closures()[-1 - step].driver;
    const int dof = driver >= 0 ? cart.joint(driver).dof_index : -1;
    if (dof >= 0 && dof < state.joint_values.size()) put_double(state.joint_values[dof]);
  }
  for (int j : JointsMoving(cart, link)) {
    const int dof = cart.joint(j).dof_index;
    if (dof >= 0 && dof < state.joint_values.size()) put_double(state.joint_values[dof]);
  }
  return key;
}

}  // namespace

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
    std::string key;
    const kinematics::SetupJointResult* known = nullptr;
    if (options.memo) {
      key = SolveKey(cart, *state, suj, suj_options);
      known = options.memo->Find(key);
    }
    kinematics::SetupJointResult solved;
    if (known) {
      solved = *known;
    } else {
      solved = kinematics::SolveSetupJoints(cart, *state, suj, suj_options);
      // The setup joints put the RCM at the port; pointing the instrument at the aim as well is
      // best effort: an arm whose setup joints cannot turn its RCM that far (the ECM's SUJ has
      // four joints, all but one vertical) keeps the nearest direction, and its own joints aim
      // the rest.
      const bool at_port = solved.position_error <= suj_options.position_tolerance;
      if (!at_port && suj.axis_W) {
        // At the port first, aimed as near as the setup joints allow (not the position alone:
        // an RCM turned anywhere leaves the arm's own joints at their limits).
        auto port_first = suj_options;
        port_first.axis_secondary = true;
        const auto retry = kinematics::SolveSetupJoints(cart, *state, suj, port_first);
        if (retry.position_error < solved.position_error) solved = retry;
      }
      if (options.memo) options.memo->Remember(std::move(key), solved);
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
