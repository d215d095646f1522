#pragma once
/// @file
/// The port-placement problem (docs/architecture.md, "Data flow"): a decision vector — for each
/// arm a port on one of the patient's candidate curves, plus the cart's pose on the floor — is
/// turned into a placement (setup joints solved, instruments aimed), and scored term by term:
/// target coverage, dexterity, approach angle, triangulation, the endoscope's view, port spacing
/// and clearances. Each term is reported with its raw value and unit and a score in [0, 1]; the
/// total is their weighted sum. Evaluation is a pure function of the decision (seeded solvers, no
/// state carried between calls), so a plan is reproducible and any thread may evaluate it.

#include <Eigen/Geometry>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "collision/collision_world.hpp"
#include "port_placement/arms.hpp"
#include "port_placement/cart_placement.hpp"
#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::patient {
struct PatientModel;
}
namespace trocar::collision {
class CollisionWorld;
class CollisionChecker;
class TriangleBvh;
}  // namespace trocar::collision

namespace trocar::planners {

/// Weights of the score terms (they need not sum to 1; the total is divided by their sum).
/// Defaults and their sources are in docs/plan-format.md ("Score terms").
struct ScoreWeights {
  /// Reachability first (Sun & Yeung 2007, Xu et al. 2021), 0.35 in all: each instrument's
  /// share of the samples it reaches (`coverage`), and the share of samples every instrument
  /// reaches and the endoscope sees (`served`: the anastomosis and the harvest are two-handed,
  /// under vision; the verdict's own measure). Until stop 51 coverage alone, 0.35: plans where
  /// one instrument reached the LAD and the other the LIMA ranked first and served nothing.
  double coverage = 0.15;
  double served = 0.20;
  double dexterity = 0.10;  ///< Trejos et al. 2007, Azimian et al. 2010
  double approach =
      0.10;  ///< approach cones at the targets: Azimian et al. 2010 (thesis fig. 2.10)
  double triangulation = 0.10;          ///< 60° ideal, 45–75° acceptable: Hanna et al. 1997
  double endoscope = 0.15;              ///< the scope's view of the sites: Cannon et al. 2003
  double spacing = 0.05;                ///< ports about 8 cm apart: da Vinci guidance
  double clearance_arm_arm = 0.05;      ///< external arm clashes: SAGES 2016 survey, Xu et al. 2021
  double clearance_arm_patient = 0.05;  ///< Xu et al. 2021
  double clearance_instrument_rib = 0.05;  ///< mid-intercostal incision (thoracoscopy practice)
  double sum() const;
};

struct ProblemOptions {
  /// Arms to place, by name or RCM frame, in order; empty: every arm of the robot.
  std::vector<std::string> arms;
  /// Role overrides "NAME=instrument|endoscope" (FindArms).
  std::vector<std::string> roles;
  /// Target samples per target curve (evenly spaced by arc length; all points when fewer).
  int samples_per_target = 8;
  /// The tool tip stops this far out along the target's approach normal (m).
  double standoff = 0.005;
  /// The remote centre of motion (the pivot) is set in the chest wall, where the shaft passes
  /// between the ribs (the cannula's remote-centre mark is set at the body wall), not on the
  /// skin: under each candidate point, the middle of the intercostal gap at the ribs' depth
  /// (found on the rib meshes, see PortSite). Where no rib lies within `gap_search_depth` under
  /// the skin (or the patient has no ribs), the pivot is `rcm_depth` inside the skin toward the
  /// targets (m).
  double rcm_depth = 0.025;
  double gap_search_depth = 0.06;  ///< m, at most kMaxPivotDepth (port_rules.hpp)
  /// Cart pose bounds, around the centre of the candidate curves: the direction the cart comes
  /// from (any), its distance on the floor (m), and its heading off facing the centre (rad).
  double cart_distance_min = 0.6, cart_distance_max = 1.5;
  double cart_heading_offset_max = 60.0 * M_PI / 180.0;
  /// The heights the team may set the table's top to before docking (m): the search chooses one
  /// (Placement::table_raise from the case's table height). An operating table's top travels
  /// about 0.79-1.04 m (31-41 in; docs/operative-state.md, "The table's height"). NaN for both:
  /// the case's table height (PatientModel::table), not searched.
  double table_height_min = 0.79, table_height_max = 1.04;
  /// The table's raise's bounds for a patient whose table is at `case_height` (m).
  double TableRaiseMin(double case_height) const {
    return std::isnan(table_height_min) ? 0.0 : table_height_min - case_height;
  }
  double TableRaiseMax(double case_height) const {
    return std::isnan(table_height_max) ? 0.0 : table_height_max - case_height;
  }
  /// Endoscope: half field of view (rad), working distances (m), the distance it is inserted to
  /// from the targets' centroid.
  double scope_half_fov = 35.0 * M_PI / 180.0;
  double scope_min_distance = 0.02, scope_max_distance = 0.15, scope_working_distance = 0.07;
  /// A sample the endoscope does not see from its docking (nominal) pose counts as seen when the
  /// scope can be moved through its port to look at it: the view axis on it from
  /// `scope_working_distance`, its joints within their limits, its line of sight clear and the
  /// arm free of collisions (PortPlacementProblem::LookAt). The surgeon moves the camera to each
  /// work site; Cannon et al. 2003 score the endoscope per surgical site. false: only what the
  /// docking pose shows (the model before stop 54).
  bool scope_moves = true;
  /// Spacing: no score at `spacing_min`, full score from `spacing_ideal` (m).
  double spacing_min = 0.04, spacing_ideal = 0.08;
  /// Clearances scoring full at these distances (m).
  double clearance_scale = 0.05, rib_clearance_scale = 0.004;
  /// Setup-joint solver effort while optimising (starts, iterations per start).
  int suj_starts = 4, suj_iterations = 100;
  /// Remember each thread's setup-joint solutions (Workspace::memo): the same plans, faster
  /// (bench/port_placement_bench compares); false solves every time.
  bool setup_joint_memo = true;
  /// Placements whose arms collide at the nominal pose are solved again from other setup-joint
  /// starts, up to this many attempts in all.
  int placement_attempts = 3;
  /// Reach: inverse-kinematics iterations and success tolerance (m).
  int ik_iterations = 80;
  /// An instrument whose solution from its nominal pose is in contact (or does not converge) is
  /// solved again from this many other wrist poses (ReachSeed): the wrist bent another way tilts
  /// the shaft about its pivot, off a rib or the heart it grazed. The same attempts in the
  /// problem's reach and in the verification's goals, so that what a plan claims is what its
  /// verification finds (issue #41, item 5). 12 (6 until stop 54): the Halton points spread over
  /// the wrist's three joints' box; on the bundled default the best plan's verified share went
  /// 66 -> 75 % from 6 to 12 and stayed at 75 % with 18 (docs/decisions.md, "More wrist poses").
  int reach_restarts = 12;
  double ik_tolerance = 0.001;
  ScoreWeights weights;
  unsigned seed = 1;
};

/// A target sample: a point of a target with its approach normal, in the world.
struct TargetSample {
  int target = -1;          ///< index into the patient's targets
  int point = -1;           ///< index of the point in the target's curve
  double arc_length = 0.0;  ///< m from the curve's first point
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero(), n_W = Eigen::Vector3d::UnitZ();
};

/// A port site on a candidate curve: the point on the curve, the pivot in the chest wall under
/// it (the middle of the intercostal gap at the ribs' depth), and the incision, where the line
/// from the targets' centroid through the pivot leaves the skin (the trocar is inserted aimed at
/// the targets; near the curve point, but not on it when the wall is thick and the aim oblique).
struct PortSite {
  int candidate = -1;  ///< index into the patient's port candidates
  double s = 0.0;      ///< position along it, 0..1 of its arc length
  Eigen::Vector3d p_curve_P = Eigen::Vector3d::Zero();  ///< on the candidate curve
  /// The incision on the skin (the port): patient frame and world.
  Eigen::Vector3d p_P = Eigen::Vector3d::Zero(), p_W = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_rcm_W = Eigen::Vector3d::Zero();  ///< the pivot
  bool in_gap = false;  ///< the pivot was found between ribs (else rcm_depth toward the targets)
  /// The shaft may touch the skin within this distance of the pivot (m): the pivot's depth under
  /// the skin plus the world's port radius (the soft wall above the ribs yields around the
  /// cannula; the ribs do not). docs/plan-format.md states the rule; `trocar check --plan`
  /// recomputes it.
  double skin_allowance = 0.0;
  /// The pivot's depth under the skin (m; 0 without a skin mesh): the soft wall's thickness the
  /// cannula's track may shear by (TrackAllowance, port_rules.hpp).
  double pivot_depth = 0.0;
};

/// A placement: one site per arm (in the problem's arm order) and the cart's pose.
struct Placement {
  std::vector<PortSite> sites;
  double cart_x = 0.0, cart_y = 0.0, cart_yaw = 0.0;  ///< world, m and rad
  /// How much higher than the case's table (PatientModel::table.height) the team sets the table
  /// before docking (m). The world is the table's: the patient stays where the case puts it and
  /// the floor the cart stands on is this much lower (X_WB's z = -table_raise). Only the cart's
  /// pose relative to the patient and the table matters to every check (the floor is no
  /// collision body); the plan file states the table's height (docs/plan-format.md).
  double table_raise = 0.0;
  Eigen::Isometry3d X_WB() const;
};

/// One arm at one target sample.
struct SampleReach {
  int sample = -1;
  int arm = -1;
  bool reached = false;
  std::string reason;      ///< why not: "insertion limit (240 mm) exceeded", a joint at its limit
                           ///< in words (JointLimitWords), "collision: psm1's shaft ... against
                           ///< the heart", ...
  Eigen::VectorXd q_arm;   ///< the arm's joint values (its q_indices) there
  double tip_error = 0.0;  ///< m, tool tip to the aim point
  double dexterity =
      0.0;  ///< inverse condition number of the tool Jacobian (characteristic length 0.1 m)
  double approach = 0.0;  ///< rad between the instrument axis and the approach normal
  bool seen = false;      ///< endoscope arms: the sample is in view
};

struct ScoreTerm {
  std::string name;    ///< "coverage", "dexterity", ...
  std::string unit;    ///< of `value`
  double value = 0.0;  ///< the raw measure (mean over samples, a distance, ...)
  double score = 0.0;  ///< 0..1
  double weight = 0.0;
  std::string note;  ///< how the value was measured
};

struct Evaluation {
  PlacementStatus status = PlacementStatus::kUnreachable;
  std::string message;  ///< the placement's message
  double score = -2.0;  ///< weighted term score in [0, 1]; < 0 when not placed (see .cpp)
  std::vector<ScoreTerm> terms;
  std::vector<SampleReach>
      reaches;  ///< per instrument and endoscope arm and sample (detailed evaluations)
  /// Per sample: every instrument reaches it and an endoscope sees it.
  std::vector<bool> served;
  Eigen::VectorXd joint_values;  ///< every movable joint of the robot at the nominal pose
  Eigen::VectorXd q_nominal;     ///< q at the nominal pose (instruments aimed, inserted)
  int collisions = 0;            ///< colliding pairs at the nominal pose
  /// Per endoscope arm: the camera it looks from (one of PlanArm::view_frames, the scope rolled
  /// to the best of its range at the nominal pose) and its view axis in that frame.
  struct View {
    int arm = -1;
    std::string frame;
    Eigen::Vector3d axis_F = Eigen::Vector3d::UnitZ();
  };
  std::vector<View> views;
  const ScoreTerm* Find(const std::string& name) const;
};

/// Per-evaluator scratch: robot state and collision checker. One per thread or per start.
struct Workspace {
  explicit Workspace(const class PortPlacementProblem& problem);
  /// With another collision world of the same robot and patient structures (robustness).
  Workspace(const class PortPlacementProblem& problem,
            std::shared_ptr<const collision::CollisionWorld> world);
  ~Workspace();
  robot::RobotState state;
  std::unique_ptr<collision::CollisionChecker> checker;
  /// Setup-joint solutions this thread has found (the same answers as solving again).
  SetupJointMemo memo;
};

class PortPlacementProblem {
 public:
  /// @throws trocar::Error before any work for a patient with no targets or no candidate curves,
  ///         a robot whose arms cannot be found, unknown arm names, bad options.
  PortPlacementProblem(std::shared_ptr<const patient::PatientModel> patient,
                       std::shared_ptr<const robot::RobotModel> robot,
                       const ProblemOptions& options);
  ~PortPlacementProblem();

  const patient::PatientModel& patient() const { return *patient_; }
  const robot::RobotModel& robot() const { return *robot_; }
  std::shared_ptr<const robot::RobotModel> robot_ptr() const { return robot_; }
  const std::shared_ptr<const collision::CollisionWorld>& world() const { return world_; }
  const ProblemOptions& options() const { return options_; }
  const std::vector<PlanArm>& arms() const { return arms_; }
  /// Arm `arm`'s index in the collision world's arms (CollisionChecker's `arm`), -1 for none.
  int world_arm(int arm) const { return world_arm_.at(static_cast<std::size_t>(arm)); }
  const std::vector<TargetSample>& samples() const { return samples_; }
  const Eigen::Vector3d& aim_W() const { return aim_W_; }

  /// Decision vector: per arm (candidate coordinate in [0, candidates), position in [0, 1]),
  /// then the cart's kCartCoordinates (direction it comes from in [-pi, pi], distance, heading
  /// offset, the table's raise).
  static constexpr int kCartCoordinates = 4;
  int dimension() const { return 2 * static_cast<int>(arms_.size()) + kCartCoordinates; }
  /// The first of the cart's coordinates in the decision vector.
  int cart_index() const { return 2 * static_cast<int>(arms_.size()); }
  std::vector<double> lower_bounds() const;
  std::vector<double> upper_bounds() const;
  Placement Decode(const std::vector<double>& x) const;
  /// The decision vector of a placement (inverse of Decode up to the curve's rounding).
  std::vector<double> Encode(const Placement& placement) const;
  PortSite Site(int candidate, double s) const;

  struct EvaluateOptions {
    /// Keep per-sample results and name collision pairs (final plans); the optimiser leaves it off.
    bool detailed = false;
    /// The setup-joint solver's full effort (32 starts, 300 iterations) instead of the options'.
    bool full_solver = false;
    /// Other target samples (the robustness check moves them); null: the problem's.
    const std::vector<TargetSample>* samples = nullptr;
    /// Pair classes checked at each target sample. The robustness check leaves out
    /// instrument–patient: the targets move, the meshes do not.
    unsigned sample_mask = 0xffffffffu;
  };
  /// Scores a placement: placed and collision-free at the nominal pose, a score in [0, 1] (the
  /// weighted mean of the terms); in collision, in [-1.5, -0.5]; not placed, below -2.
  Evaluation Evaluate(const Placement& placement, Workspace* workspace,
                      const EvaluateOptions& how) const;
  Evaluation Evaluate(const Placement& placement, Workspace* workspace) const {
    return Evaluate(placement, workspace, EvaluateOptions{});
  }

  /// The structures that move with the targets: the organs some target lies on (median distance
  /// of its points to the surface under 1 cm), but never the chest wall, skin or bones
  /// (patient::IsMobileStructure).
  /// On the bundled cases: the heart, under the LAD.
  std::vector<std::string> MovingStructures() const;
  /// Per patient target: whether it lies on one of the MovingStructures (the LAD on the heart;
  /// not the LIMA in the chest wall). Only those move in the robustness check.
  std::vector<bool> MovingTargets() const;
  /// The collision world with the MovingStructures translated by d_P (patient frame, m): the
  /// robustness check moves the organ with its targets.
  std::shared_ptr<const collision::CollisionWorld> WorldWithTargetsMoved(
      const Eigen::Vector3d& d_P) const;

  /// The longest reach of an arm's tool from its RCM (m), insertion at its upper limit, for the
  /// verdict ("insertion limit exceeded from every candidate port").
  double MaxReach(int arm) const;

  /// Inverse kinematics of one arm's tool to a target sample's aim point (its point `standoff`
  /// out along its normal), starting from state->q: damped least squares on the arm's joints,
  /// clamped to their limits, a software-RCM arm's shaft kept through its port (as Evaluate
  /// does). Leaves the solution's q and poses in `state`. Not a collision check.
  /// @return empty when it converged within the options' tolerance, else why not ("insertion
  ///         limit (240 mm) exceeded: ...", "psm1's instrument cannot swing further toward the
  ///         feet about its port (joint limit 'x' (upper)); the point lies 12 mm beyond", ...).
  std::string SolveReach(int arm, const Placement& placement, const TargetSample& sample,
                         robot::RobotState* state) const;

  /// The start of reach attempt `attempt` (0: the state as it is, the nominal pose; 1 to
  /// ProblemOptions::reach_restarts: the arm's joints below its insertion joint — an instrument's
  /// roll and wrist — set to the attempt's point of a Halton sequence over their limits, the
  /// others left as they are). Deterministic. False when the attempt does not exist (beyond the
  /// restarts, or an arm with no joint below an insertion joint).
  bool ReachSeed(int arm, int attempt, robot::RobotState* state) const;
  /// How many attempts ReachSeed gives beyond the first for an arm (0: the nominal pose only).
  int ReachRestarts(int arm) const;

  /// Puts the collision checker's ports (where instruments may touch the skin) at the sites'
  /// pivots with their skin allowances; call after every CollisionChecker::SetRobotState. With a
  /// `work_W` (the target point the instruments work on), each instrument's wrist and jaws may
  /// touch the organ there (kWorkSiteRadius, port_rules.hpp); without, nowhere.
  /// An instrument's skin allowance follows its cannula's track in `state` (the pose the
  /// checker was given; TrackAllowance, port_rules.hpp).
  void SetPorts(const Placement& placement, const robot::RobotState& state,
                collision::CollisionChecker* checker,
                const Eigen::Vector3d* work_W = nullptr) const;

  /// Moves endoscope arm `a` (from `state`, its docking pose) so that the view `view` looks at
  /// `p_W` from the working distance: the shaft through the port turned toward the point (for an
  /// angled scope, by the angle its camera makes with the shaft, then rolled), solved by the
  /// arm's inverse kinematics. True when the point then lies in the field of view and the working
  /// distances, the line of sight is clear and the arm is free of collisions (its pairs only:
  /// the others stay at their docking poses); else `why` says what stops it. `state` holds the
  /// pose tried; `checker` is left at it.
  bool LookAt(int a, const Placement& placement, const Evaluation::View& view,
              const Eigen::Vector3d& p_W, robot::RobotState* state,
              collision::CollisionChecker* checker, std::string* why) const;

 private:
  // Evaluate's stages (problem.cpp): the cart docked and the arms at their nominal pose, the
  // endoscopes' views, each arm's reach or view of the samples; the terms are score_terms.hpp's.
  struct Docking;
  Docking Dock(const Placement& placement, const std::vector<TargetSample>& samples,
               bool full_solver, Workspace* ws, Evaluation* ev) const;
  std::vector<bool> AimArms(const Placement& placement, const std::vector<TargetSample>& samples,
                            Workspace* ws, collision::CollisionReport* nominal) const;
  void ChooseViews(const Placement& placement, const std::vector<TargetSample>& samples,
                   const Docking& docked, bool skip_reach, Workspace* ws, Evaluation* ev) const;
  void ScopeReaches(int a, const Placement& placement, const std::vector<TargetSample>& samples,
                    const Docking& docked, const robot::RobotState& nominal_state,
                    const Evaluation& ev, Workspace* ws, std::vector<SampleReach>* reach) const;
  void InstrumentReaches(int a, const Placement& placement,
                         const std::vector<TargetSample>& samples, const Docking& docked,
                         bool skip_reach, const robot::RobotState& nominal_state,
                         const EvaluateOptions& how, Workspace* ws,
                         std::vector<SampleReach>* reach) const;
  /// m from the shafts' axes (4 cm either side of their pivots, aimed at the targets) to a rib;
  /// +inf without ribs.
  double ShaftRibClearance(const Placement& placement) const;

  std::vector<int> world_port_;  // per arm: index of its port in the collision world
  std::vector<int> world_arm_;   // per arm: its index in the collision world's arms (-1: none)
  std::shared_ptr<const patient::PatientModel> patient_;
  std::shared_ptr<const robot::RobotModel> robot_;
  ProblemOptions options_;
  std::vector<PlanArm> arms_;
  std::vector<TargetSample> samples_;
  std::shared_ptr<const collision::CollisionWorld> world_;
  collision::WorldOptions world_options_;
  std::unique_ptr<collision::TriangleBvh> ribs_;    // in P
  std::unique_ptr<collision::TriangleBvh> skin_;    // in P
  std::vector<std::vector<double>> candidate_arc_;  // cumulative arc length per candidate
  // Per candidate and curve point, in P: the pivot, whether it is in a gap.
  std::vector<std::vector<Eigen::Vector3d>> candidate_pivot_;
  std::vector<std::vector<char>> candidate_in_gap_;
  void FindPivots();
  Eigen::Vector3d aim_W_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d centre_W_ = Eigen::Vector3d::Zero();  // of the candidate curves
  std::vector<double> max_reach_;
};

/// Why a joint at its limit stops an arm short of `p_aim_W`, in words a surgeon reads: of the
/// arm's joints at a limit in `state` (where the inverse kinematics stopped), the one whose motion
/// past its limit would carry the tip most directly toward the point; what it does at the port
/// (the insertion, the swing of the instrument about its port, the wrist), and the way the tip
/// would have to go in the patient's axes (X_WP: the patient frame P, LPS, in the world). E.g.
/// "psm2's instrument cannot swing further toward the feet about its port (joint limit
/// 'psm2_outer_pitch' (lower)); the point lies 74 mm beyond". Empty when no joint is at a limit.
std::string JointLimitWords(const robot::RobotModel& robot, const PlanArm& arm,
                            const robot::RobotState& state, const Eigen::Vector3d& p_aim_W,
                            const Eigen::Isometry3d& X_WP, double error);

}  // namespace trocar::planners
