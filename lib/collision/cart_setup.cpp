#include "collision/cart_setup.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/setup_joints.hpp"
#include "patient/patient_model.hpp"

namespace trocar::collision {
namespace {

const robot::Frame* FindFrame(const robot::RobotModel& model, const std::string& name) {
  for (const auto& f : model.frames()) {
    if (f.name == name) return &f;
  }
  return nullptr;
}

// The first active prismatic joint below a frame's link: the arm's insertion.
int InsertionJoint(const robot::RobotModel& model, int link) {
  std::vector<int> links{link};
  for (std::size_t i = 0; i < links.size(); ++i) {
    for (int j : model.link(links[i]).child_joints) {
      const robot::Joint& joint = model.joint(j);
      if (joint.type == robot::JointType::kPrismatic && joint.drive == robot::JointDrive::kActive) return j;
      links.push_back(joint.child_link);
    }
  }
  return -1;
}

}  // namespace

CartSetup DefaultPorts(const patient::PatientModel& patient, const robot::RobotModel& cart) {
  TROCAR_THROW_UNLESS(!patient.port_candidates.empty(),
                      "patient '" << patient.name << "' has no port candidates (annotate them or let "
                                                     "the intercostal spaces be found)");
  TROCAR_THROW_UNLESS(!patient.targets.empty() && !patient.targets[0].points.empty(),
                      "patient '" << patient.name << "' has no target to aim the instruments at");
  CartSetup setup;
  Eigen::Vector3d target_P = Eigen::Vector3d::Zero();
  for (const auto& p : patient.targets[0].points) target_P += p;
  target_P /= static_cast<double>(patient.targets[0].points.size());
  setup.aim_W = patient.X_WP * target_P;
  // Candidate curves from superior to inferior, by their middle points.
  std::vector<Eigen::Vector3d> middles;
  for (const auto& c : patient.port_candidates) {
    if (!c.skin.empty()) middles.push_back(c.skin[c.skin.size() / 2]);
  }
  std::sort(middles.begin(), middles.end(),
            [](const Eigen::Vector3d& a, const Eigen::Vector3d& b) { return a.z() > b.z(); });
  const int n = static_cast<int>(middles.size());
  const std::vector<std::pair<std::string, double>> arms = {{"psm1_rcm", 0.15}, {"ecm_rcm", 0.5}, {"psm2_rcm", 0.85}};
  for (const auto& [frame, at] : arms) {
    if (!FindFrame(cart, frame)) continue;
    const int index = std::clamp(static_cast<int>(std::lround(at * (n - 1))), 0, n - 1);
    setup.ports.push_back({frame, patient.X_WP * middles[index]});
  }
  TROCAR_THROW_UNLESS(!setup.ports.empty(), "robot '" << cart.name() << "' has none of the frames psm1_rcm, "
                                                                         "ecm_rcm, psm2_rcm");
  return setup;
}

PlacementResult PlaceCart(const robot::RobotModel& cart, const CartSetup& setup, robot::RobotState* state,
                          unsigned seed) {
  state->X_WB = setup.X_WB;
  PlacementResult result;
  result.ok = true;
  std::ostringstream message;
  for (const auto& port : setup.ports) {
    const robot::Frame* frame = FindFrame(cart, port.frame);
    TROCAR_THROW_UNLESS(frame, "robot '" << cart.name() << "' has no frame '" << port.frame << "'");
    kinematics::SetupJointRequest request;
    request.frame = port.frame;
    request.p_WF = port.p_W;
    const Eigen::Vector3d axis = setup.aim_W - port.p_W;
    if (axis.norm() > 1e-6) request.axis_W = axis.normalized();
    kinematics::SetupJointOptions options;
    options.seed = seed;
    auto solved = kinematics::SolveSetupJoints(cart, *state, request, options);
    if (!solved.solved() && request.axis_W && solved.position_error < options.position_tolerance) {
      // The RCM reaches the port but the setup joints cannot also set the instrument's direction
      // (the ECM has four): the port alone is what the setup joints must give.
      auto position_only = request;
      position_only.axis_W.reset();
      const auto retry = kinematics::SolveSetupJoints(cart, *state, position_only, options);
      if (retry.solved()) solved = retry;
    }
    for (std::size_t i = 0; i < solved.joints.size(); ++i) {
      kinematics::SetHeldJoint(cart, solved.joints[i], solved.values[i], state);
    }
    result.worst_position_error = std::max(result.worst_position_error, solved.position_error);
    result.ok = result.ok && solved.solved();
    message << "  " << port.frame << ": " << solved.message << "\n";
    // Insertion toward the aim, 1 cm short.
    const int insertion = InsertionJoint(cart, frame->link);
    const std::string prefix = port.frame.substr(0, port.frame.size() - 3);
    const robot::Frame* tool = FindFrame(cart, prefix + "tool");
    if (setup.insert_toward_aim && insertion >= 0 && tool && request.axis_W) {
      kinematics::ForwardKinematics(cart, state->q, state);
      const Eigen::Vector3d p_rcm = kinematics::FramePose(*state, *frame).translation();
      const double depth = (kinematics::FramePose(*state, *tool).translation() - p_rcm).dot(*request.axis_W);
      const robot::Joint& joint = cart.joint(insertion);
      double& q = state->q[joint.q_index];
      q = std::clamp(q + (axis.norm() - 0.01 - depth), joint.limits.lower, joint.limits.upper);
    }
  }
  const auto fk = kinematics::ForwardKinematics(cart, state->q, state);
  if (!fk.ok) {
    result.ok = false;
    message << "  " << fk.message << "\n";
  }
  result.message = message.str();
  return result;
}

PlacementResult PlaceCartAutomatically(const robot::RobotModel& cart, CartSetup* setup, robot::RobotState* state,
                                       unsigned seed) {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const auto& p : setup->ports) centre += p.p_W;
  centre /= std::max<std::size_t>(1, setup->ports.size());
  PlacementResult best;
  best.worst_position_error = std::numeric_limits<double>::infinity();
  robot::RobotState best_state = *state;
  Eigen::Isometry3d best_pose = setup->X_WB;
  // From the patient's right (−y_W side faces +y) first, then around.
  for (int d = 0; d < 8; ++d) {
    const double heading = M_PI / 2 + d * M_PI / 4;  // direction the cart faces
    for (double distance = 0.5; distance <= 1.3 + 1e-9; distance += 0.1) {
      CartSetup trial = *setup;
      trial.X_WB = Eigen::Isometry3d::Identity();
      trial.X_WB.linear() = Eigen::AngleAxisd(heading, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      trial.X_WB.translation() =
          Eigen::Vector3d(centre.x(), centre.y(), 0) - distance * Eigen::Vector3d(std::cos(heading), std::sin(heading), 0);
      robot::RobotState s = *state;
      const PlacementResult r = PlaceCart(cart, trial, &s, seed);
      if (r.worst_position_error < best.worst_position_error) {
        best = r;
        best_state = s;
        best_pose = trial.X_WB;
      }
      if (r.ok) {
        setup->X_WB = trial.X_WB;
        *state = s;
        return r;
      }
    }
  }
  setup->X_WB = best_pose;
  *state = best_state;
  best.message = "no cart pose reaches every port; the nearest:\n" + best.message;
  return best;
}

}  // namespace trocar::collision
