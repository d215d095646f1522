#pragma once
/// @file
/// Placing a da Vinci style cart at a patient: ports on the skin, the cart's pose on the floor,
/// the setup joints solved so that each arm's RCM sits at its port with the instrument aimed at
/// the target. The port-placement planner chooses ports and cart pose by optimisation; this is
/// the plain placement it and `trocar check` start from.

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::patient {
struct PatientModel;
}

namespace trocar::collision {

struct PortAssignment {
  std::string frame;  ///< the arm's RCM frame, e.g. "psm1_rcm"
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();
};

struct CartSetup {
  Eigen::Isometry3d X_WB = Eigen::Isometry3d::Identity();  ///< cart on the floor
  std::vector<PortAssignment> ports;
  Eigen::Vector3d aim_W = Eigen::Vector3d::Zero();  ///< where the instruments point (the target)
  /// Insert each instrument toward the aim (1 cm short); false keeps the state's insertion.
  bool insert_toward_aim = true;
};

/// Default ports for a cart with frames psm1_rcm, ecm_rcm, psm2_rcm (those present): the middle
/// points of port candidates spread over the patient's candidate curves (upper, middle, lower),
/// aimed at the first target's centroid.
/// @throws trocar::Error when the patient has no port candidates or no targets.
CartSetup DefaultPorts(const patient::PatientModel& patient, const robot::RobotModel& cart);

struct PlacementResult {
  bool ok = false;
  std::string message;  ///< per arm: solved, or how far off
  double worst_position_error = 0.0;  ///< m
};

/// Solves the setup joints of each port's arm for `setup` (base pose, ports, aim) into `state`
/// and, when setup.insert_toward_aim, sets each instrument's insertion toward the aim (stopping
/// 1 cm short, within limits).
/// Other active joints keep their values in `state`.
PlacementResult PlaceCart(const robot::RobotModel& cart, const CartSetup& setup, robot::RobotState* state,
                          unsigned seed = 1);

/// Searches cart poses on the floor around the ports (directions every 45°, distances 0.5 to
/// 1.3 m) for one where every arm reaches its port; fills setup->X_WB and `state`.
PlacementResult PlaceCartAutomatically(const robot::RobotModel& cart, CartSetup* setup,
                                       robot::RobotState* state, unsigned seed = 1);

}  // namespace trocar::collision
