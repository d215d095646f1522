#pragma once
/// @file
/// Placing a cart at a patient: the cart's pose on the floor, and the held setup joints of each
/// arm solved so that its RCM sits at its port with the instrument aimed into the workspace.
/// The port-placement optimiser calls this for every candidate; `trocar check` uses it for a
/// plain placement. (Moved here from lib/collision: choosing a placement is planning.)

#include <Eigen/Geometry>
#include <string>
#include <unordered_map>
#include <vector>

#include "kinematics/setup_joints.hpp"
#include "port_placement/arms.hpp"
#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::patient {
struct PatientModel;
}
namespace trocar::collision {
class CollisionChecker;
}

namespace trocar::planners {

/// An arm at a port.
struct ArmAtPort {
  PlanArm arm;
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();  ///< the port, in the world (m)
};

struct CartPlacementRequest {
  Eigen::Isometry3d X_WB = Eigen::Isometry3d::Identity();  ///< the cart (robot base) on the floor
  std::vector<ArmAtPort> ports;
  /// Where the instruments point through their ports (a target's centroid), in the world.
  Eigen::Vector3d aim_W = Eigen::Vector3d::Zero();
  /// Insert each instrument toward the aim, stopping `insertion_margin` short; false keeps the
  /// state's insertion values.
  bool insert_toward_aim = true;
  double insertion_margin = 0.01;  ///< m
};

/// Remembered setup-joint solutions. One arm's solve in PlaceCart is a pure function of the
/// cart's pose, the arm's port and aim, the solver's options and the values of the joints that
/// move the arm's RCM frame (its path, and what drives the passive joints on it); an optimiser
/// that moves one coordinate at a time (DIRECT) asks the arms it did not move for the same solve
/// again. A memo answers those from memory: the same answers, bit for bit, as solving again (the
/// key is the inputs' exact bits), so a plan does not depend on what a memo holds. Not thread
/// safe: one per thread (the problem's Workspace).
class SetupJointMemo {
 public:
  /// The solution remembered under `key` (the inputs' bytes), or null.
  const kinematics::SetupJointResult* Find(const std::string& key);
  /// Remembers a solution; past kCapacity entries the memo starts afresh.
  void Remember(std::string key, const kinematics::SetupJointResult& solved);
  long hits() const { return hits_; }
  long misses() const { return misses_; }
  static constexpr std::size_t kCapacity = 4096;

 private:
  std::unordered_map<std::string, kinematics::SetupJointResult> entries_;
  long hits_ = 0, misses_ = 0;
};

struct CartPlacementOptions {
  unsigned seed = 1;
  /// Starts of the setup-joint solver per arm (kinematics::SetupJointOptions::starts).
  int starts = 32;
  int max_iterations = 300;  ///< per start
  /// When set, a placement whose arms collide (every moving pair class) is kInCollision.
  collision::CollisionChecker* checker = nullptr;
  /// When set, setup-joint solutions are looked up here first and remembered (SetupJointMemo).
  SetupJointMemo* memo = nullptr;
};

enum class PlacementStatus { kPlaced, kUnreachable, kInCollision };
const char* ToString(PlacementStatus status);

struct CartPlacementResult {
  PlacementStatus status = PlacementStatus::kUnreachable;
  /// Per arm: solved, or how many mm and degrees short; and the colliding pairs.
  std::string message;
  double worst_position_error = 0.0;  ///< m, over the arms' RCMs
  double worst_angle_error = 0.0;     ///< rad, over the instruments' axes
  int collisions = 0;                 ///< colliding pairs (when a checker was given)
  bool ok() const { return status == PlacementStatus::kPlaced; }
};

/// Default ports: for each arm in order, the middle point of a candidate curve spread over the
/// patient's candidate curves from superior to inferior (instruments outside, the endoscope
/// between them), aimed at the first target's centroid.
/// @throws trocar::Error when the patient has no port candidates or no targets.
CartPlacementRequest DefaultPorts(const patient::PatientModel& patient,
                                  const std::vector<PlanArm>& arms);

/// Solves each arm's setup joints for `request` into `state` (base pose set from the request)
/// and, when request.insert_toward_aim, sets each instrument's insertion toward the aim. Other
/// active joints keep their values. Arms without a mechanical RCM have nothing to solve.
CartPlacementResult PlaceCart(const robot::RobotModel& cart, const CartPlacementRequest& request,
                              const CartPlacementOptions& options, robot::RobotState* state);

/// Searches cart poses on the floor around the ports (headings every 45°, distances 0.5 to 1.3 m)
/// for the first where every arm reaches its port (and, with a checker, nothing collides); fills
/// request->X_WB and `state` with it, or with the nearest attempt.
CartPlacementResult PlaceCartAutomatically(const robot::RobotModel& cart,
                                           CartPlacementRequest* request,
                                           const CartPlacementOptions& options,
                                           robot::RobotState* state);

}  // namespace trocar::planners
