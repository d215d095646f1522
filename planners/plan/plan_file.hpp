#pragma once
/// @file
/// The plan file (`plan.json`, docs/plan-format.md) as one typed document, with its one reader
/// and its one writer. `trocar plan` fills it from the optimiser's result
/// (port_placement/plan_io.hpp), `trocar verify` adds the verification to it
/// (motion/verify.hpp), `trocar signoff` and the workstation add a decision
/// (plan/signoff.hpp); `check --plan`, `view`, `report`, `teleop` and `verify` read it. Every field
/// is checked for type and size as it is read; a bad one is named with its path in the document
/// ("plans[2].cart.X_WB"). Writing what was read gives the same bytes (the plan's numbers are
/// rounded to 12 significant digits when written, the verification's are not).

#include <cstdint>
#include <limits>
#include <optional>
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

/// Version of the plan format this trocar writes; it reads this one and the versions back to
/// kOldestPlanFormatVersion. 3 (stop 64): the cart's `z` and `table_height` (a plan whose table
/// was raised has its cart off z = 0, which a version-2 reader would refuse as a broken pose).
constexpr int kPlanFormatVersion = 3;
constexpr int kOldestPlanFormatVersion = 2;

/// Joint values by joint name, in the order written (the file orders them by name).
using NamedValues = std::vector<std::pair<std::string, double>>;
/// Fields this trocar does not know, by key, each as its JSON text: kept as they are when the file
/// is rewritten (a newer trocar's additions, or a tool's, survive this one's sign-off).
using UnknownFields = std::vector<std::pair<std::string, std::string>>;

struct StoredPort {
  std::string arm, candidate;
  double s = 0.0;                                     ///< along the candidate curve, 0..1
  Eigen::Vector3d curve_P = Eigen::Vector3d::Zero();  ///< the site on the candidate curve
  Eigen::Vector3d p_P = Eigen::Vector3d::Zero();      ///< the incision, in the patient's frame
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();      ///< the incision on the skin
  Eigen::Vector3d rcm_W = Eigen::Vector3d::Zero();    ///< the pivot
  /// Where it is in a surgeon's terms: "ICS-L4, on the anterior axillary line (153 mm from the
  /// midline)" (empty in files written before it).
  std::string anatomy;
  double skin_allowance = 0.0;  ///< m (port_rules.hpp)
  std::string pivot;            ///< how the pivot was found
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
  std::string note;     ///< how the value was measured
};

/// An arm at a target sample in the plan's own reach check (the claim `check --plan` re-checks).
struct StoredReach {
  int sample = 0;
  std::string arm;
  bool reached = false;
  NamedValues q;  ///< the arm's joints there
  /// An endoscope's entry has `seen` and `off_axis_deg`; an instrument's `tip_error_m`,
  /// `dexterity` and `approach_deg`.
  bool endoscope = false;
  bool seen = false;
  double off_axis_deg = 0.0;
  double tip_error_m = 0.0, dexterity = 0.0, approach_deg = 0.0;
  std::string reason;  ///< when not reached
};

/// The targets moved by one robustness shift, and how the plan fares there.
struct StoredShift {
  Eigen::Vector3d shift_P = Eigen::Vector3d::Zero();
  double score = 0.0, coverage = 0.0, served = 0.0;
};

/// One verified motion (an instrument arm to a target sample).
struct StoredMotion {
  std::string arm;
  int sample = -1;
  std::string outcome, reason;
  std::string status;  ///< OMPL's
  bool solved = false;
  double planning_time = 0.0, simplification_time = 0.0;  ///< s
  std::int64_t graph_states = 0;
  /// A motion with a path has these, its joints and waypoints.
  bool has_path = false;
  double path_length = 0.0, raw_path_length = 0.0, tip_path_length = 0.0;
  int rechecked_states = 0;
  double min_clearance = std::numeric_limits<double>::quiet_NaN();  ///< m, solved paths
  std::vector<std::string> joints;         ///< the arm's active joints, by name
  std::vector<Eigen::VectorXd> waypoints;  ///< joint values; the first is the nominal pose
  /// A motion not solved: the pose that fails, in `joints` (the colliding inverse-kinematics
  /// solution, where it stopped at a joint's limit, or the goal no path reached); empty when
  /// the file has none.
  Eigen::VectorXd failure_pose;
};

/// How a plan was verified (`plans[].verification`, beside the figures StoredPlan holds).
struct StoredVerificationRun {
  std::string planner;
  double time_limit = 0.0, check_step = 0.0, recheck_step = 0.0;
  double prismatic_weight_per_m = 0.0;
  unsigned seed = 0;
  double rank_score = 0.0;  ///< with the verified coverage and served share
  std::int64_t states_checked = 0;
  double seconds = 0.0;
  int threads = 1;
};

/// A surgeon's decision on a plan (trocar signoff, or the workstation's Approve / Reject).
struct SignOff {
  std::string decision;  ///< "approved" or "rejected"
  std::string surgeon;
  std::string note;
  std::string time;  ///< UTC, ISO 8601 (set when written)
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
  std::optional<int> rank_before_verification;  ///< set by trocar verify's re-ranking
  std::string status;                           ///< "placed", "in collision", "unreachable"
  double score = 0.0, rank_score = 0.0, robust_score = 0.0, degradation = 0.0;
  int collisions_at_nominal = 0;
  std::string message;
  double cart_x = 0.0, cart_y = 0.0, cart_yaw_deg = 0.0;   ///< the cart on the floor
  /// The floor's height under the cart in the world (m): minus how far the team raised the table
  /// above the case's (Placement::table_raise); 0 in plan files before stop 64.
  double cart_z = 0.0;
  /// The table top's height the plan was made for (m; NaN when the file does not say).
  double table_height = std::numeric_limits<double>::quiet_NaN();
  Eigen::Isometry3d X_WB = Eigen::Isometry3d::Identity();  ///< the same pose (checked)
  NamedValues setup_joints;                                ///< held joints, by name
  NamedValues q_nominal;                                   ///< active joints, by name
  std::vector<StoredPort> ports;
  std::vector<StoredView> views;
  std::vector<StoredTerm> terms;
  std::vector<bool> served;          ///< per sample, by the plan's own reach check
  std::vector<StoredReach> reaches;  ///< `samples`: per arm and sample
  std::vector<StoredShift> robustness;
  bool verified = false;  ///< has a "verification" part
  StoredVerificationRun verification_run;
  double verified_coverage = 0.0, served_fraction = 0.0;
  double claimed_coverage = 0.0;  ///< the plan's own reach figure, beside the verified one
  bool verified_suitable = false;
  std::vector<std::string> verification_reasons;
  /// Per target sample: every instrument's motion there verified and an endoscope sees it.
  std::vector<bool> verified_served;
  std::vector<StoredMotion> motions;
  std::vector<SignOff> signoffs;  ///< oldest first; the last is the plan's current decision
  UnknownFields unknown;
};

struct StoredSample {
  int index = 0;
  std::string target;
  int point = 0;            ///< the point of the target's curve
  double arc_length = 0.0;  ///< m from the curve's first point
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero(), n_W = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d aim_W = Eigen::Vector3d::Zero();  ///< where the tool tip goes
};

struct StoredArm {
  std::string name, role, tool_frame, rcm_frame, shaft_link;
  Eigen::Vector3d shaft_a_L = Eigen::Vector3d::Zero(), shaft_b_L = Eigen::Vector3d::Zero();
  std::vector<std::string> joints;
  double max_reach = std::numeric_limits<double>::quiet_NaN();  ///< m; NaN: unbounded (null)
};

/// A verdict: suitable or not, one line, one reason per failing target stretch.
struct StoredVerdict {
  bool suitable = false;
  std::string summary;
  std::vector<std::string> reasons;
};

/// A plan to compare the optimised ones with: the surgeons' template placed on this patient, or
/// a surgeon's own ports (`baselines` in docs/plan-format.md).
struct StoredBaseline {
  std::string kind;  ///< "template", "surgeon"
  std::string name;
  bool placed = false;
  std::string why_not;             ///< when not placed
  std::string source;              ///< the citation, or the ports file
  std::vector<std::string> where;  ///< per arm, the port as the template or file names it
  std::vector<std::string> notes;  ///< what was approximated placing it
  std::string search;              ///< how the cart was searched
  int evaluations = 0;
  StoredPlan plan;        ///< when placed (rank 0)
  bool suitable = false;  ///< its own verdict, as if it were the only plan
  std::string summary;
  std::vector<std::string> reasons;
  /// By its verified motions, when verified (no summary line).
  std::optional<StoredVerdict> verified;
};

/// The state the plans were made in (patient/operative_state.hpp; docs/operative-state.md).
struct StoredOperation {
  std::string state;  ///< "operative" or "ct"
  std::string description;
  double co2_mmHg = 0.0;
  bool left_lung_isolated = false;
  double left_side_up_deg = 0.0;
  double heart_shift_m = 0.0;
  double heart_shift_min_m = 0.0, heart_shift_max_m = 0.0;
  Eigen::Vector3d direction_P = Eigen::Vector3d::Zero(), d_P = Eigen::Vector3d::Zero();
  std::vector<std::string> moved_structures, moved_targets;
};

/// The optimiser's settings and effort (`algorithm`).
struct StoredAlgorithm {
  std::string global, local;
  unsigned seed = 1;
  int starts = 0, evaluations_budget = 0, polish_evaluations = 0;
  int evaluations = 0, global_evaluations = 0;
  double best_global_score = 0.0;
  double time_limit_s = 0.0;
  bool time_limit_hit = false;
  std::string grid;
  int top_k = 0;
  double distinct_distance_m = 0.0, robustness_shift_m = 0.0, robustness_weight = 0.0;
};

/// What the plans were scored with (`scoring`): enough to rebuild the problem they were scored
/// in (`trocar verify`) and to re-check their claims (`check --plan`).
struct StoredScoring {
  /// Term weights by name ("coverage", "served", ...): plans written before stop 51 have no
  /// "served".
  NamedValues weights;
  double standoff_m = 0.0, rcm_depth_m = 0.0, gap_search_depth_m = 0.0, ik_tolerance_m = 0.0;
  int reach_restarts = 0;
  double sight_margin_m = 0.0;
  double scope_half_fov_deg = 0.0, scope_min_distance_m = 0.0, scope_max_distance_m = 0.0,
         scope_working_distance_m = 0.0;
  /// Absent in plans written before stop 54 (the scope judged from its docking pose only).
  std::optional<bool> scope_moves;
  int samples_per_target = 0;
  double suitable_fraction = 0.0;
  /// The weight named `name`, or `otherwise` when the file has none.
  double Weight(const std::string& name, double otherwise) const;
};

/// An anatomical selection criterion measured on the CT (selection_criteria.hpp).
struct StoredCriterion {
  std::string name, title;
  double value = std::numeric_limits<double>::quiet_NaN();  ///< NaN: not measured (null)
  std::string unit;
  double threshold = 0.0;
  std::string favourable_when;
  bool favourable = false;
  std::string meaning, how, source;
};

struct PlanFile {
  std::string path;  ///< where it was read from (not written)
  /// The inputs as written (absolute paths since stop 61) ...
  std::string case_written, robot_written;
  /// ... and resolved: as given when that path exists (relative to the working directory), else
  /// relative to the plan's folder.
  std::string case_dir, robot_file;
  std::string case_hash, robot_hash, model_hash;
  std::string patient_name;
  Eigen::Isometry3d X_WP = Eigen::Isometry3d::Identity();
  std::optional<StoredOperation> operation;  ///< absent in plans before the operative state
  std::string robot_name;
  std::vector<StoredArm> arms;
  StoredAlgorithm algorithm;
  StoredScoring scoring;
  bool suitable = false;  ///< the claimed verdict: by the plans' own reach checks
  std::string summary;
  std::vector<std::string> reasons;
  /// The verdict that counts when the plans were verified: by plan 1's verified motions.
  bool has_verified_verdict = false, verified_suitable = false;
  std::string verified_summary;
  std::vector<std::string> verified_reasons;
  std::vector<StoredSample> samples;
  std::vector<StoredPlan> plans;  ///< best first
  /// Where the plans' ports came from when given, not optimised ("template: ...").
  std::optional<std::pair<std::string, std::vector<std::string>>> ports_given;
  std::vector<StoredBaseline> baselines;
  std::vector<StoredCriterion> criteria;
  std::string criteria_comparison;
  std::vector<std::pair<int, double>> convergence;  ///< evaluations, best score
  int run_threads = 1;
  NamedValues timings_s;  ///< by stage: the only part that differs between runs
  UnknownFields unknown;  ///< at the top level
};

/// Reads and checks a plan file. @throws trocar::Error naming the file and the field (its path
/// in the document) and what was expected: missing, not JSON, another format or version, a field
/// of the wrong type or size, a non-finite number.
PlanFile ReadPlanFile(const std::string& path);

/// The document as the file's text. PlanFileText(ReadPlanFile(p)) is p's bytes for a file this
/// trocar wrote.
std::string PlanFileText(const PlanFile& file);
/// Writes PlanFileText(file) to `path` atomically (temporary name, then rename).
/// @throws trocar::Error naming the path when it cannot be written.
void WritePlanFile(const std::string& path, const PlanFile& file);

/// "fnv1a64:<16 hex digits>" of a file's bytes. @throws trocar::Error when it cannot be read.
std::string HashFile(const std::string& path);
/// The same hash over the model's surfaces, targets, port candidates and X_WP.
std::string HashPatientModel(const patient::PatientModel& model);

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

/// The robot at a stored plan's nominal pose: cart at X_WB, setup joints held, active joints at
/// q_nominal (others at the model's neutral values), forward kinematics done.
/// @throws trocar::Error naming `where` and the joint when the plan does not fit the robot.
robot::RobotState NominalState(const robot::RobotModel& robot, const StoredPlan& plan,
                               const std::string& where);

/// `state` with one motion's waypoint `k` set on its arm's joints (then forward kinematics).
/// @throws trocar::Error when the motion names a joint the robot has not.
void SetWaypoint(const robot::RobotModel& robot, const StoredMotion& motion, std::size_t k,
                 robot::RobotState* state);
/// `state` with a failed motion's failure pose set on its arm's joints (then forward kinematics).
/// @throws trocar::Error when the motion has no failure pose or names a joint the robot has not.
void SetFailurePose(const robot::RobotModel& robot, const StoredMotion& motion,
                    robot::RobotState* state);

}  // namespace trocar::planners
