#pragma once
/// @file
/// Kinematic controllers behind one interface: given the robot's state and the desired tool pose,
/// each returns joint velocities q̇ (before joint limits, which ControlLoop applies). The thesis'
/// Jacobian-transpose law q̇ = Jᵀ K e (eq. 4.13), and those its future work asks for (§6.3):
/// damped least squares, joint-limit avoidance that does not stick at a limit, and a software
/// remote-centre-of-motion constraint for robots without a mechanical one.

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "control/task_error.hpp"
#include "kinematics/jacobian.hpp"
#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::control {

/// What the controller is asked to do at one step.
struct TaskTarget {
  Eigen::Isometry3d X_WD = Eigen::Isometry3d::Identity();  ///< desired tool pose in the world
  /// Desired tool spatial velocity [ω; v] (feed-forward), zero when unknown.
  Vector6d V_WD = Vector6d::Zero();
  /// Position-only control: orientation error and velocity are ignored.
  bool position_only = false;
};

/// Reusable buffers so that a control step does not allocate: sized on the first step of a
/// robot (Resize), then only written.
struct ControllerWorkspace {
  kinematics::Matrix6Xd J;        ///< the tool's Jacobian
  kinematics::Matrix6Xd J_task;   ///< the rows the task uses (top rows), frozen columns zeroed
  kinematics::Matrix6Xd J_a, J_b; ///< Jacobians of two points (the RCM controller's shaft)
  Eigen::Matrix<double, Eigen::Dynamic, 2> pinv2;  ///< n × 2 (the RCM constraint's inverse)
  Eigen::MatrixXd N;              ///< n × n null-space projector
  Eigen::VectorXd a, b, c;        ///< n-vectors
  std::vector<char> frozen;       ///< per active joint (joint-limit avoidance)
  /// The last direction of least singular value of the task's J Jᵀ (a warm start; zero at first).
  Vector6d sigma_direction = Vector6d::Zero();
  /// Sizes every buffer for `n` joints; nothing happens when they already are.
  void Resize(int n);
};

class Controller {
 public:
  virtual ~Controller() = default;
  /// Short name used on the command line and in records: "jt", "dls", "jla", "rcm".
  virtual std::string name() const = 0;
  /// Joint velocity command for the state (after ForwardKinematics) and target.
  /// @param qdot resized to num_positions().
  virtual void ComputeVelocity(const robot::RobotModel& model, const robot::RobotState& state,
                               const TaskTarget& target, ControllerWorkspace* workspace,
                               Eigen::VectorXd* qdot) const = 0;
};

/// Gains per task axis [ωx ωy ωz vx vy vz] (1/s) for controller `name`: the robot's sidecar
/// `controller.gains.<name>`, else its `controller.task_gains`, else `fallback`.
Vector6d TaskGains(const robot::RobotModel& model, const std::string& name,
                   const Vector6d& fallback);

/// q̇ = Jᵀ K e (thesis eq. 4.13) with K = diag(gains): no matrix inversion, so no singularity;
/// zero steady-state error for a step, bounded lag for a ramp.
class JacobianTransposeController final : public Controller {
 public:
  explicit JacobianTransposeController(const Vector6d& gains) : gains_(gains) {}
  std::string name() const override { return "jt"; }
  void ComputeVelocity(const robot::RobotModel& model, const robot::RobotState& state,
                       const TaskTarget& target, ControllerWorkspace* workspace,
                       Eigen::VectorXd* qdot) const override;
  const Vector6d& gains() const { return gains_; }

 private:
  Vector6d gains_;
};

/// q̇ = Jᵀ (J Jᵀ + λ² I)⁻¹ (V_d + K e): resolved-rate control with feed-forward, damped so that it
/// stays bounded near singularities (λ grows as the smallest singular value falls below
/// `singular_threshold`).
class DampedLeastSquaresController : public Controller {
 public:
  DampedLeastSquaresController(const Vector6d& gains, double max_damping = 0.05,
                               double singular_threshold = 0.05)
      : gains_(gains), max_damping_(max_damping), singular_threshold_(singular_threshold) {}
  std::string name() const override { return "dls"; }
  void ComputeVelocity(const robot::RobotModel& model, const robot::RobotState& state,
                       const TaskTarget& target, ControllerWorkspace* workspace,
                       Eigen::VectorXd* qdot) const override;

 protected:
  /// DLS solve of J q̇ = v for the rows selected by the target, the joints marked in
  /// `ws->frozen` held still (when `use_frozen`); q̇ into `qdot` (sized n). Allocates nothing.
  void Solve(const kinematics::Matrix6Xd& J, const Vector6d& v, bool position_only,
             bool use_frozen, ControllerWorkspace* ws, Eigen::VectorXd* qdot) const;
  Vector6d gains_;
  double max_damping_;
  double singular_threshold_;
};

/// Damped least squares plus a null-space motion away from the joint limits; a joint that sits at
/// a limit while the task pushes it outward is frozen and the task is re-solved with the others,
/// so the arm slides along the limit instead of sticking to it.
class JointLimitAvoidanceController final : public DampedLeastSquaresController {
 public:
  explicit JointLimitAvoidanceController(const Vector6d& gains, double avoidance_gain = 1.0)
      : DampedLeastSquaresController(gains), avoidance_gain_(avoidance_gain) {}
  std::string name() const override { return "jla"; }
  void ComputeVelocity(const robot::RobotModel& model, const robot::RobotState& state,
                       const TaskTarget& target, ControllerWorkspace* workspace,
                       Eigen::VectorXd* qdot) const override;

 private:
  double avoidance_gain_;
};

/// For an arm without a mechanical RCM (e.g. the PA10 with an instrument): the instrument shaft,
/// the line from `shaft_start` to the tool along the tool's z, must keep passing through a fixed
/// point p_WR (the port) while the tool follows the target. The RCM constraint (two directions
/// across the shaft) is solved first and the tool task in its null space (task priority, DLS).
class SoftwareRcmController final : public DampedLeastSquaresController {
 public:
  /// @param shaft_link, p_LS: a point on the shaft above the port (fixed to a link).
  /// @param p_WR: the port in the world.
  SoftwareRcmController(const Vector6d& gains, int shaft_link, const Eigen::Vector3d& p_LS,
                        const Eigen::Vector3d& p_WR, double rcm_gain = 50.0)
      : DampedLeastSquaresController(gains), shaft_link_(shaft_link), p_LS_(p_LS), p_WR_(p_WR),
        rcm_gain_(rcm_gain) {}
  std::string name() const override { return "rcm"; }
  void ComputeVelocity(const robot::RobotModel& model, const robot::RobotState& state,
                       const TaskTarget& target, ControllerWorkspace* workspace,
                       Eigen::VectorXd* qdot) const override;
  /// Distance (m) from the port to the shaft line in `state`.
  double RcmError(const robot::RobotModel& model, const robot::RobotState& state) const;

 private:
  int shaft_link_;
  Eigen::Vector3d p_LS_;
  Eigen::Vector3d p_WR_;
  double rcm_gain_;
};

/// Makes a controller by name ("jt", "dls", "jla") with exactly these gains.
/// @throws trocar::Error for an unknown name.
std::unique_ptr<Controller> MakeControllerWithGains(const std::string& name, const Vector6d& gains);

/// Makes a controller by name ("jt", "dls", "jla") with the robot's gains (or `fallback`).
/// @throws trocar::Error for an unknown name (the RCM controller needs a port: construct it).
std::unique_ptr<Controller> MakeController(const std::string& name,
                                           const robot::RobotModel& model,
                                           const Vector6d& fallback_gains);

}  // namespace trocar::control
