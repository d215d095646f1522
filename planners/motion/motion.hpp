#pragma once
/// @file
/// Verified motions (docs/architecture.md, "Data flow"): OMPL plans in one arm's active
/// joint space, from the arm's start pose (the plan's nominal pose: the instrument just inside its
/// port) to a target sample, with every state checked by the collision world — the other arms held
/// at their nominal configuration, the instrument allowed to touch the skin only at its own port
/// (collision_world.hpp, "Ports"), closures solved by forward kinematics inside the check. Goal
/// states come from the port-placement problem's damped-least-squares inverse kinematics with
/// seeded restarts. A returned path is simplified, then re-checked state by state at a finer step
/// than the planner's before it is reported: a path the re-check rejects is a failure, never a
/// solution.
///
/// Threads: a MotionContext is one thread's scratch (robot state, collision checker); the
/// problem, placement and world are shared and immutable.
///
/// Determinism: OMPL seeds every random generator from one process-wide sequence. Each query
/// restarts that sequence from its own seed (under a process-wide lock, while its planner,
/// samplers and simplifier are made, and again whenever a planner makes a sampler mid-solve:
/// that draw from the sequence, unlocked, could shift another query's) and samples states with
/// its own generator, so a query
/// gives the same path from the same seed, alone or among other threads — for planners that
/// run in the calling thread and finish before their time limit (PRM and LazyPRM grow their
/// roadmap in a second thread; any planner stopped by its time limit depends on the machine).

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "port_placement/problem.hpp"

namespace trocar::planners {

/// The OMPL geometric planners trocar can run, by lower-case name: "rrtconnect", "rrt",
/// "rrtstar", "prm", "lazyprm", "kpiece1", "bkpiece1", "est", "sbl", "bitstar", and the rest
/// OMPL 1.5.2 offers for geometric planning.
std::vector<std::string> MotionPlanners();
/// OMPL's own name for one of MotionPlanners() ("RRTConnect", "BITstar", ...).
/// @throws trocar::Error naming the planner and listing the valid names.
std::string OmplPlannerName(const std::string& planner);

struct MotionOptions {
  std::string planner = "rrtconnect";
  double time_limit = 2.0;  ///< s per query (planning; simplification comes after)
  /// The planner checks motions at this step: radians for revolute joints, with prismatic
  /// joints weighed 10 rad per metre (OMPL's state validity checking resolution, as a fraction
  /// of the space's extent).
  double check_step = 0.01;
  /// The re-check of a returned path: every state at most this far apart (same units), each
  /// checked for collisions, joint limits and closures.
  double recheck_step = 0.002;
  int ik_restarts = 8;     ///< inverse-kinematics starts for the goal (first: the nominal pose)
  int goal_states = 3;     ///< distinct valid goal states to collect, at most
  /// OMPL's PathSimplifier: vertices reduced and close ones collapsed, then shortcuts (at most
  /// five rounds), then vertices reduced again; each bounded by the path's states, not a clock.
  bool simplify = true;
  unsigned seed = 1;
};
/// @throws trocar::Error for an unknown planner (listing the valid ones) or a non-positive time
///         limit or step.
void ValidateMotionOptions(const MotionOptions& options);

/// OMPL's planner status values (ompl::base::PlannerStatus::StatusType), which the benchmark
/// database stores as its `status` enum.
enum class MotionStatus {
  kUnknown = 0,
  kInvalidStart = 1,
  kInvalidGoal = 2,
  kUnrecognizedGoalType = 3,
  kTimeout = 4,
  kApproximateSolution = 5,
  kExactSolution = 6,
  kCrash = 7,
  kAbort = 8,
};
/// OMPL's text for a status ("Exact solution", "Timeout", ...).
std::string ToString(MotionStatus status);
/// Every status text, in enum order (the database's `status` enum).
std::vector<std::string> MotionStatusNames();

/// One arm's motion to one target sample.
struct TargetMotion {
  int arm = -1;     ///< index into the problem's arms
  int sample = -1;  ///< index into the problem's samples
  /// Solved: an exact solution that passed the re-check. A path the re-check rejects keeps the
  /// planner's status and gets solved = false with the reason.
  bool solved = false;
  MotionStatus status = MotionStatus::kUnknown;
  std::string outcome;  ///< "solved", "timeout", "unreachable", "invalid start", "rejected"
  std::string reason;   ///< why not solved (the inverse kinematics' reason, the colliding pair...)
  double planning_time = 0.0;        ///< s
  double simplification_time = 0.0;  ///< s
  double path_length = 0.0;          ///< joint space (OMPL's distance), after simplification
  double raw_path_length = 0.0;      ///< the planner's path, before simplification
  double tip_path_length = 0.0;      ///< m travelled by the tool tip along the re-checked path
  double min_clearance = 0.0;        ///< m, smallest distance to anything along the path
  int segments = 0;                  ///< of the simplified path
  int rechecked_states = 0;          ///< states the re-check looked at
  long graph_states = 0;             ///< the planner's graph size (PlannerData vertices)
  long graph_motions = 0;            ///< and edges
  bool correct = false;              ///< the re-check passed
  std::vector<Eigen::VectorXd> path; ///< waypoints: the arm's joint values (its q_indices)
  /// Not solved: the pose that fails, for replay (issue #43 item 9), the arm's joint values:
  /// "unreachable", the inverse kinematics' answer whose failure `reason` gives (its solution in
  /// collision, or where it stopped short at a joint's limit); "timeout" and "failed", the goal
  /// no path was found to. Empty when there is none (an invalid start).
  Eigen::VectorXd failure_q;
};

/// What a motion query needs from a plan, shared by every thread.
class MotionProblem {
 public:
  /// @param q_start the whole robot's q at the start (the evaluation's q_nominal): the arm under
  ///        plan starts there, every other arm stays there.
  /// @param joint_values every movable joint's value at the start (the evaluation's
  ///        joint_values: the setup joints the cart placement solved).
  /// @throws trocar::Error when the placement does not fit the problem or q_start or
  ///         joint_values have the wrong size.
  MotionProblem(const PortPlacementProblem& problem, Placement placement,
                Eigen::VectorXd q_start, Eigen::VectorXd joint_values);
  /// From a detailed evaluation of the placement (its q_nominal and joint_values).
  MotionProblem(const PortPlacementProblem& problem, const Placement& placement,
                const Evaluation& evaluation);
  const PortPlacementProblem& problem() const { return problem_; }
  const Placement& placement() const { return placement_; }
  const Eigen::VectorXd& q_start() const { return q_start_; }
  const Eigen::VectorXd& joint_values() const { return joint_values_; }

 private:
  const PortPlacementProblem& problem_;
  Placement placement_;
  Eigen::VectorXd q_start_, joint_values_;
};

/// One thread's scratch for motion queries.
class MotionContext {
 public:
  explicit MotionContext(const MotionProblem& problem);
  ~MotionContext();
  MotionContext(const MotionContext&) = delete;
  MotionContext& operator=(const MotionContext&) = delete;

  /// Plans arm `arm` from the start to sample `sample` (of the problem's samples).
  TargetMotion Plan(int arm, int sample, const MotionOptions& options);

  /// Whether the whole robot at q is valid: closures solve, joints within limits, no collision
  /// (ports at the placement's pivots). `why` gets the reason when not.
  bool Valid(const Eigen::VectorXd& q, std::string* why = nullptr);
  /// Minimum distance between the robot and anything at q (m; 0 in contact).
  double Clearance(const Eigen::VectorXd& q);
  /// Re-checks a path of arm `arm` (waypoints of its joint values, the rest of q at the
  /// problem's start) state by state, at most `step` apart (weighted as MotionOptions'
  /// steps): closures, limits, collisions. Uses nothing of the planner's.
  /// @return empty when every state is valid, else the first failure ("state 12 of 300:
  ///         collision: psm1_tool_link - ribs").
  std::string Recheck(int arm, const std::vector<Eigen::VectorXd>& path, double step,
                      int* states_checked = nullptr, double* min_clearance = nullptr,
                      double* tip_path_length = nullptr);
  /// Counts states checked since construction.
  long checks() const { return checks_; }

 private:
  const MotionProblem& problem_;
  robot::RobotState state_;
  std::unique_ptr<collision::CollisionChecker> checker_;
  long checks_ = 0;
  /// The target sample the instruments work on during a Plan (their wrist and jaws may touch
  /// the organ there: port_rules.hpp, kWorkSiteRadius); none outside one.
  bool has_work_ = false;
  Eigen::Vector3d work_W_ = Eigen::Vector3d::Zero();
  /// During a Plan whose start was valid over every pair: the collision world's index of the
  /// query's arm, and which entries of q are its joints. A state that keeps every other joint
  /// at the start differs from the start only in that arm's bodies, so only the pairs with one
  /// of them can have changed (the rest were free at the start, under the same ports and work
  /// site): those alone are checked. -1: every pair.
  int only_arm_ = -1;
  std::vector<char> in_query_arm_;
  /// only_arm_ when q keeps every joint outside the query's arm at the start, else -1.
  int PairsToCheck(const Eigen::VectorXd& q) const;
  void SetPorts();
};

}  // namespace trocar::planners
