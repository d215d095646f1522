#pragma once
/// @file
/// Reading a plan file (`plan.json`, docs/plan-format.md) back: what a viewer, a report or a
/// sign-off needs of it — the inputs, the verdict, the target samples, and per ranked plan its
/// status, scores, ports, cart pose, setup joints, nominal pose, endoscope views and verified
/// motions with their waypoints. Every field is checked for type and size as it is read; a bad
/// one is named with its path in the document ("plans[2].cart.X_WB").

#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::patient {
struct PatientModel;
}

namespace trocar::planners {

struct StoredPort {
  std::string arm, candidate;
  /// Where it is in a surgeon's terms: "ICS-L4, on the anterior axillary line (153 mm from the
  /// midline)" (empty in files written before it).
  std::string anatomy;
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();    ///< the incision on the skin
  Eigen::Vector3d rcm_W = Eigen::Vector3d::Zero();  ///< the pivot
};

/// An endoscope's camera: it looks along `axis_F` of robot frame `frame`.
struct StoredView {
  std::string arm, frame;
  Eigen::Vector3d axis_F = Eigen::Vector3d::UnitZ();
};

struct StoredTerm {
  std::string name;
  double value = 0.0, score = 0.0;
  std::string unit;     ///< of `value` ("fraction", "deg", "m"; empty in older files)
  double weight = 0.0;  ///< in the plan's score (0 in older files)
};

/// One verified motion (an instrument arm to a target sample).
struct StoredMotion {
  std::string arm;
  int sample = -1;
  std::string outcome, reason;
  bool solved = false;
  double min_clearance = std::numeric_limits<double>::quiet_NaN();  ///< m, solved paths
  std::vector<std::string> joints;          ///< the arm's active joints, by name
  std::vector<Eigen::VectorXd> waypoints;   ///< joint values; the first is the nominal pose
};

/// A surgeon's decision on a plan (trocar signoff, or the workstation's Approve / Reject).
struct SignOff {
  std::string decision;  ///< "approved" or "rejected"
  std::string surgeon;
  std::string note;
  std::string time;      ///< UTC, ISO 8601 (set when written)
  /// The teleoperation session the surgeon verified the plan with (trocar teleop --record):
  /// its path and content hash; empty when none.
  std::string session, session_hash;
  /// An approval of a plan that fails (see ApprovalBlockers) carries the surgeon's reason for
  /// approving it anyway, and the failures it overrode, as they were when it was signed.
  std::string override_reason;
  std::vector<std::string> overridden;
};

struct StoredPlan {
  int rank = 0;
  std::string status;  ///< "placed", "in collision", "unreachable"
  double score = 0.0, rank_score = 0.0;
  std::string message;
  Eigen::Isometry3d X_WB = Eigen::Isometry3d::Identity();  ///< the cart
  std::vector<std::pair<std::string, double>> setup_joints;  ///< held joints, by name
  std::vector<std::pair<std::string, double>> q_nominal;     ///< active joints, by name
  std::vector<StoredPort> ports;
  std::vector<StoredView> views;
  std::vector<StoredTerm> terms;
  bool verified = false;  ///< has a "verification" part
  double verified_coverage = 0.0, served_fraction = 0.0;
  double claimed_coverage = 0.0;  ///< the plan's own reach figure, beside the verified one
  bool verified_suitable = false;
  std::vector<std::string> verification_reasons;
  /// Per target sample: every instrument's motion there verified and an endoscope sees it.
  std::vector<bool> verified_served;
  std::vector<StoredMotion> motions;
  std::vector<SignOff> signoffs;  ///< oldest first; the last is the plan's current decision
};

struct StoredSample {
  int index = 0;
  std::string target;
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero(), n_W = Eigen::Vector3d::UnitZ();
};

struct StoredArm {
  std::string name, role, tool_frame, rcm_frame, shaft_link;
  std::vector<std::string> joints;
};

/// A plan to compare the optimised ones with: the surgeons' template placed on this patient, or
/// a surgeon's own ports (`baselines` in docs/plan-format.md).
struct StoredBaseline {
  std::string kind;  ///< "template", "surgeon"
  std::string name;
  bool placed = false;
  std::string why_not;             ///< when not placed
  std::vector<std::string> where;  ///< per arm, the port as the template or file names it
  StoredPlan plan;                 ///< when placed (rank 0)
  bool suitable = false;           ///< its own verdict, as if it were the only plan
  std::string summary;
  std::vector<std::string> reasons;
};

struct PlanFile {
  std::string path;
  /// The inputs as written, and resolved: as given when that path exists (relative to the
  /// working directory), else relative to the plan's folder.
  std::string case_dir, robot_file;
  std::string case_hash, robot_hash, model_hash;
  std::string patient_name;
  Eigen::Isometry3d X_WP = Eigen::Isometry3d::Identity();
  std::vector<StoredArm> arms;
  bool suitable = false;  ///< the claimed verdict: by the plans' own reach checks
  std::string summary;
  std::vector<std::string> reasons;
  /// The verdict that counts when the plans were verified: by plan 1's verified motions.
  bool has_verified_verdict = false, verified_suitable = false;
  std::string verified_summary;
  std::vector<std::string> verified_reasons;
  std::vector<StoredSample> samples;
  std::vector<StoredPlan> plans;  ///< best first
  std::vector<StoredBaseline> baselines;
};

/// Reads and checks a plan file. @throws trocar::Error naming the file and the field (its path
/// in the document) and what was expected: missing, not JSON, another format or version, a field
/// of the wrong type or size, a non-finite number.
PlanFile ReadPlanFile(const std::string& path);

/// Whether the plan still fits its robot: "" when the robot file it names exists with the
/// content it was planned with, else why not ("its robot R does not exist", "robot file R changed
/// since the plan was made (hash differs)"). The one place this is decided (plan, verify, check,
/// view, the workstation and the report call it); callers prefix the plan's path and add advice.
std::string RobotFileMismatch(const PlanFile& file);
/// Whether `patient` is the model the plan was made for (its content hash, over the geometry in
/// the state it was planned in): "" or why not ("was made for another patient model than CASE's
/// (hash differs)", naming `case_dir`).
std::string PatientModelMismatch(const PlanFile& file, const patient::PatientModel& patient,
                                 const std::string& case_dir);

/// Why plan `index` (0-based) of `file` may not be approved without an override: at its nominal
/// pose in collision or not placed; not verified by motions; not suitable by its verified verdict
/// (its verified motions and served samples, with the first reasons). Empty: nothing blocks.
/// @throws trocar::Error when the index is out of range.
std::vector<std::string> ApprovalBlockers(const PlanFile& file, std::size_t index);

/// A plan's current status derived from its sign-off history: "proposed" (never signed),
/// "approved", "rejected" (its latest decision), or "superseded" (approved, but another plan of
/// the file was approved after it and stands).
/// @throws trocar::Error when the index is out of range.
std::string PlanDecisionStatus(const PlanFile& file, std::size_t index);

/// Adds `signoff` (its time set now) to plan `index` (0-based) of the plan file at `path`, which
/// is rewritten atomically (temporary name, then rename): a crash leaves the previous file whole.
/// Everything else in the file is kept. @return the sign-off as written.
/// @throws trocar::Error naming the file when it is not a readable plan, the index is out of
/// range, the decision is not "approved" or "rejected", the surgeon is empty, the note is over
/// 10,000 characters, or the session file cannot be read; when approving a plan that
/// ApprovalBlockers blocks without `override_reason` (the error lists the blockers), or giving an
/// override where nothing is blocked or on a rejection.
SignOff SignOffPlan(const std::string& path, std::size_t index, SignOff signoff);

/// The robot at a stored plan's nominal pose: cart at X_WB, setup joints held, active joints at
/// q_nominal (others at the model's neutral values), forward kinematics done.
/// @throws trocar::Error naming `where` and the joint when the plan does not fit the robot.
robot::RobotState NominalState(const robot::RobotModel& robot, const StoredPlan& plan,
                               const std::string& where);

/// `state` with one motion's waypoint `k` set on its arm's joints (then forward kinematics).
/// @throws trocar::Error when the motion names a joint the robot has not.
void SetWaypoint(const robot::RobotModel& robot, const StoredMotion& motion, std::size_t k,
                 robot::RobotState* state);

}  // namespace trocar::planners
