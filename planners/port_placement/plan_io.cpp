#include "port_placement/plan_io.hpp"

#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/markups.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/fixed_ports.hpp"
#include "port_placement/plan_config.hpp"
#include "port_placement/port_rules.hpp"
#include "port_placement/score_terms.hpp"

namespace trocar::planners {

namespace {

// One plan as the plan file stores it (docs/plan-format.md, "plans").
StoredPlan StorePlan(const PortPlacementProblem& problem, const RankedPlan& plan, int rank) {
  const robot::RobotModel& robot = problem.robot();
  const patient::PatientModel& patient = problem.patient();
  const Evaluation& ev = plan.evaluation;
  StoredPlan out;
  out.rank = rank;
  out.status = ToString(ev.status);
  out.score = ev.score;
  out.rank_score = plan.rank_score;
  out.robust_score = plan.robust_score;
  out.degradation = plan.degradation;
  out.collisions_at_nominal = ev.collisions;
  out.message = ev.message;
  for (std::size_t a = 0; a < plan.placement.sites.size(); ++a) {
    const PortSite& site = plan.placement.sites[a];
    StoredPort port;
    port.arm = problem.arms()[a].name;
    port.candidate = patient.port_candidates[site.candidate].name;
    port.s = site.s;
    port.curve_P = site.p_curve_P;
    port.p_P = site.p_P;
    port.p_W = site.p_W;
    port.rcm_W = site.p_rcm_W;
    port.anatomy = DescribePort(patient, site);
    port.skin_allowance = site.skin_allowance;
    port.pivot = site.in_gap ? "intercostal gap" : "rcm_depth toward the targets";
    out.ports.push_back(port);
  }
  // By name, as the file orders them.
  std::map<std::string, double> setup, nominal;
  for (int j = 0; j < robot.num_joints(); ++j) {
    const robot::Joint& joint = robot.joint(j);
    if (joint.movable() && joint.drive == robot::JointDrive::kHeld && ev.joint_values.size() > 0)
      setup[joint.name] = ev.joint_values[joint.dof_index];
    if (joint.movable() && joint.q_index >= 0 && ev.q_nominal.size() > 0)
      nominal[joint.name] = ev.q_nominal[joint.q_index];
  }
  out.setup_joints.assign(setup.begin(), setup.end());
  out.q_nominal.assign(nominal.begin(), nominal.end());
  for (const auto& t : ev.terms)
    out.terms.push_back({t.name, t.value, t.score, t.unit, t.weight, t.note});
  for (const auto& r : ev.reaches) {
    const PlanArm& arm = problem.arms()[r.arm];
    StoredReach reach;
    reach.sample = r.sample;
    reach.arm = arm.name;
    reach.reached = r.reached;
    std::map<std::string, double> q;
    for (std::size_t c = 0;
         c < arm.q_indices.size() && c < static_cast<std::size_t>(r.q_arm.size()); ++c) {
      q[robot.joint(robot.active_joints()[arm.q_indices[c]]).name] = r.q_arm[c];
    }
    reach.q.assign(q.begin(), q.end());
    reach.endoscope = arm.role == ArmRole::kEndoscope;
    if (reach.endoscope) {
      reach.seen = r.seen;
      reach.off_axis_deg = r.approach * 180 / M_PI;
    } else {
      reach.tip_error_m = r.tip_error;
      reach.dexterity = r.dexterity;
      reach.approach_deg = r.approach * 180 / M_PI;
    }
    if (!r.reached) reach.reason = r.reason;
    out.reaches.push_back(std::move(reach));
  }
  for (const auto& s : plan.shifts)
    out.robustness.push_back({s.d_P, s.score, s.coverage, s.served});
  out.served = ev.served;
  for (const auto& v : ev.views)
    out.views.push_back({problem.arms()[v.arm].name, v.frame, v.axis_F});
  out.cart_x = plan.placement.cart_x;
  out.cart_y = plan.placement.cart_y;
  out.cart_yaw_deg = plan.placement.cart_yaw * 180 / M_PI;
  out.cart_z = 0.0 - plan.placement.table_raise;  // +0 when not raised
  out.table_height = problem.patient().table.height + plan.placement.table_raise;
  out.X_WB = plan.placement.X_WB();
  return out;
}

StoredVerdict StoreVerdict(const Verdict& v) { return {v.suitable, v.summary, v.reasons}; }

}  // namespace

PlanFile MakePlanFile(const PortPlacementProblem& problem, const PortPlacementResult& result,
                      const PortPlacementOptions& options, const PlanInputs& inputs) {
  const robot::RobotModel& robot = problem.robot();
  const patient::PatientModel& patient = problem.patient();
  const ProblemOptions& po = problem.options();
  PlanFile file;
  file.case_written = file.case_dir = inputs.case_dir;
  file.robot_written = file.robot_file = inputs.robot_file;
  file.case_hash = inputs.case_hash;
  file.robot_hash = inputs.robot_hash;
  file.model_hash = inputs.model_hash;
  file.patient_name = patient.name;
  file.X_WP = patient.X_WP;
  {
    // The state the plans were made in (patient/operative_state.hpp; docs/operative-state.md).
    const patient::OperativeState& op = patient.operation;
    const patient::OperativeChange& change = patient.operative_change;
    StoredOperation s;
    s.state = op.applied ? "operative" : "ct";
    s.description = op.Describe();
    s.co2_mmHg = op.applied ? op.co2_mmhg : 0.0;
    s.left_lung_isolated = op.applied && op.left_lung_isolated;
    s.left_side_up_deg = patient.left_side_up * 180 / M_PI;
    s.heart_shift_m = op.moves() ? op.heart_shift : 0.0;
    s.heart_shift_min_m = op.moves() ? op.heart_shift_min : 0.0;
    s.heart_shift_max_m = op.moves() ? op.heart_shift_max : 0.0;
    s.direction_P = change.direction_P;
    s.d_P = change.d_P;
    s.moved_structures = change.structures;
    s.moved_targets = change.targets;
    file.operation = s;
  }
  file.robot_name = robot.name();
  for (std::size_t a = 0; a < problem.arms().size(); ++a) {
    const PlanArm& arm = problem.arms()[a];
    StoredArm s;
    s.name = arm.name;
    s.role = ToString(arm.role);
    s.rcm_frame = arm.rcm_frame;
    s.tool_frame = arm.tool_frame;
    s.shaft_link = arm.shaft_link >= 0 ? robot.link(arm.shaft_link).name : "";
    s.shaft_a_L = arm.p_L_shaft_a;
    s.shaft_b_L = arm.p_L_shaft_b;
    for (int i : arm.q_indices) s.joints.push_back(robot.joint(robot.active_joints()[i]).name);
    s.max_reach = problem.MaxReach(static_cast<int>(a));
    file.arms.push_back(s);
  }
  StoredAlgorithm& alg = file.algorithm;
  alg.global = result.algorithm;
  alg.local = result.local;
  alg.seed = options.seed;
  alg.starts = options.starts;
  alg.evaluations_budget = options.evaluations;
  alg.polish_evaluations = options.polish_evaluations;
  alg.evaluations = result.evaluations;
  alg.global_evaluations = result.global_evaluations;
  alg.best_global_score = result.best_global_score;
  alg.time_limit_s = options.time_limit;
  alg.time_limit_hit = result.time_limit_hit;
  alg.grid = result.grid;
  alg.top_k = options.top_k;
  alg.distinct_distance_m = options.distinct_distance;
  alg.robustness_shift_m = options.robustness_shift;
  alg.robustness_weight = options.robustness_weight;
  const ScoreWeights& w = po.weights;
  StoredScoring& sc = file.scoring;
  for (const ScoreTermDefinition& term : ScoreTermDefinitions())
    sc.weights.emplace_back(term.name, w.*term.weight);
  sc.standoff_m = po.standoff;
  sc.rcm_depth_m = po.rcm_depth;
  sc.gap_search_depth_m = po.gap_search_depth;
  sc.ik_tolerance_m = po.ik_tolerance;
  sc.reach_restarts = po.reach_restarts;
  sc.sight_margin_m = kSightMargin;
  sc.scope_half_fov_deg = po.scope_half_fov * 180 / M_PI;
  sc.scope_min_distance_m = po.scope_min_distance;
  sc.scope_max_distance_m = po.scope_max_distance;
  sc.scope_working_distance_m = po.scope_working_distance;
  sc.scope_moves = po.scope_moves;
  sc.samples_per_target = po.samples_per_target;
  sc.suitable_fraction = options.suitable_fraction;
  file.suitable = result.verdict.suitable;
  file.summary = result.verdict.summary;
  file.reasons = result.verdict.reasons;
  for (std::size_t i = 0; i < problem.samples().size(); ++i) {
    const auto& s = problem.samples()[i];
    StoredSample t;
    t.index = static_cast<int>(i);
    t.target = patient.targets[s.target].name;
    t.point = s.point;
    t.arc_length = s.arc_length;
    t.p_W = s.p_W;
    t.n_W = s.n_W;
    t.aim_W = s.p_W + po.standoff * s.n_W;
    file.samples.push_back(t);
  }
  for (std::size_t k = 0; k < result.plans.size(); ++k)
    file.plans.push_back(StorePlan(problem, result.plans[k], static_cast<int>(k) + 1));
  if (!result.ports_given.empty())
    file.ports_given = std::make_pair(result.ports_given, result.ports_where);
  // The baselines beside the optimised plans (the template, a surgeon's ports).
  for (const Baseline& b : result.baselines) {
    StoredBaseline s;
    s.kind = b.kind;
    s.name = b.name;
    s.placed = b.placed;
    if (!b.placed) {
      s.why_not = b.why_not;
    } else {
      const FixedPortsPlan& f = b.fixed;
      s.source = f.ports.source;
      s.where = f.ports.where;
      s.notes = f.ports.notes;
      s.search = f.search;
      s.evaluations = f.evaluations;
      const StoredVerdict v = StoreVerdict(f.verdict);
      s.suitable = v.suitable;
      s.summary = v.summary;
      s.reasons = v.reasons;
      s.plan = StorePlan(problem, f.plan, 0);
    }
    file.baselines.push_back(std::move(s));
  }
  // The anatomical selection criteria beside the verdict (docs/selection-criteria.md).
  for (const Criterion& c : result.criteria.criteria) {
    StoredCriterion s;
    s.name = c.name;
    s.title = c.title;
    s.value = c.measured() ? c.value : std::numeric_limits<double>::quiet_NaN();
    s.unit = c.unit;
    s.threshold = c.threshold;
    s.favourable_when = c.at_least ? "at least the threshold" : "at most the threshold";
    s.favourable = c.favourable();
    s.meaning = c.meaning;
    s.how = c.how;
    s.source = c.source;
    file.criteria.push_back(s);
  }
  file.criteria_comparison = result.criteria_comparison;
  for (const auto& p : result.trace) file.convergence.emplace_back(p.evaluations, p.best);
  file.run_threads = result.threads;
  std::map<std::string, double> timings(result.timings.begin(), result.timings.end());
  file.timings_s.assign(timings.begin(), timings.end());
  return file;
}

ProblemOptions PlanProblemOptions(const PlanFile& file) {
  ProblemOptions po;
  ReadPlanConfig(file.case_dir, &po);
  po.arms.clear();
  po.roles.clear();
  for (const StoredArm& arm : file.arms) {
    po.arms.push_back(arm.name);
    po.roles.push_back(arm.name + "=" + arm.role);
  }
  const StoredScoring& s = file.scoring;
  // A weight per term, by its name (score_terms.hpp). Plans written before stop 51 have no served
  // term: scored without it.
  for (const ScoreTermDefinition& term : ScoreTermDefinitions()) {
    const double w = s.Weight(term.name, std::string(term.name) == "served"
                                             ? 0.0
                                             : std::numeric_limits<double>::quiet_NaN());
    TROCAR_THROW_UNLESS(!std::isnan(w),
                        file.path << ": scoring.weights." << term.name << ": missing");
    po.weights.*term.weight = w;
  }
  po.standoff = s.standoff_m;
  po.rcm_depth = s.rcm_depth_m;
  po.gap_search_depth = s.gap_search_depth_m;
  po.ik_tolerance = s.ik_tolerance_m;
  po.scope_half_fov = s.scope_half_fov_deg * M_PI / 180;
  po.scope_min_distance = s.scope_min_distance_m;
  po.scope_max_distance = s.scope_max_distance_m;
  po.scope_working_distance = s.scope_working_distance_m;
  // Plans written before stop 54 judged the scope from its docking pose only.
  po.scope_moves = s.scope_moves.value_or(false);
  TROCAR_THROW_UNLESS(s.samples_per_target >= 1 && s.samples_per_target <= 100000,
                      file.path << ": scoring.samples_per_target: " << s.samples_per_target
                                << ", expected 1 to 100000");
  po.samples_per_target = s.samples_per_target;
  po.seed = file.algorithm.seed;
  return po;
}

RankedPlan RestorePlan(const PortPlacementProblem& problem, const PlanFile& file,
                       std::size_t index) {
  TROCAR_CHECK(index < file.plans.size(),
               "RestorePlan: plan " << index + 1 << " of " << file.plans.size());
  const StoredPlan& p = file.plans[index];
  const patient::PatientModel& patient = problem.patient();
  const robot::RobotModel& robot = problem.robot();
  const std::string where = file.path + ": plan " + std::to_string(index + 1);
  TROCAR_THROW_UNLESS(
      p.ports.size() == problem.arms().size(),
      where << " has " << p.ports.size() << " ports for " << problem.arms().size() << " arms");
  RankedPlan plan;
  for (const StoredPort& port : p.ports) {
    int candidate = -1;
    for (int c = 0; c < static_cast<int>(patient.port_candidates.size()); ++c) {
      if (patient.port_candidates[c].name == port.candidate) candidate = c;
    }
    TROCAR_THROW_UNLESS(candidate >= 0, where << ": port candidate '" << port.candidate
                                              << "' is not one of the patient's");
    plan.placement.sites.push_back(problem.Site(candidate, port.s));
    TROCAR_THROW_UNLESS(
        (plan.placement.sites.back().p_W - port.p_W).norm() < 1e-4,
        where << ": the port of \"" << port.arm << "\" is not where its candidate curve puts it");
  }
  plan.placement.cart_x = p.cart_x;
  plan.placement.cart_y = p.cart_y;
  plan.placement.cart_yaw = p.cart_yaw_deg * M_PI / 180;
  plan.placement.table_raise = 0.0 - p.cart_z;
  plan.rank_score = p.rank_score;
  // The plan as written: its status, its nominal pose (setup joints and active joints by name),
  // its coverage term and what its endoscope sees. A nominal pose that is not valid makes every
  // motion an "invalid start", named.
  Evaluation& ev = plan.evaluation;
  ev.status = p.status == ToString(PlacementStatus::kPlaced)        ? PlacementStatus::kPlaced
              : p.status == ToString(PlacementStatus::kInCollision) ? PlacementStatus::kInCollision
                                                                    : PlacementStatus::kUnreachable;
  ev.score = p.score;
  const robot::RobotState state = NominalState(robot, p, where);
  ev.q_nominal = state.q;
  ev.joint_values = state.joint_values;
  for (const StoredTerm& t : p.terms) {
    ScoreTerm term;
    term.name = t.name;
    term.value = t.value;
    term.score = t.score;
    ev.terms.push_back(term);
  }
  for (const StoredReach& r : p.reaches) {
    if (!r.endoscope) continue;
    SampleReach reach;
    reach.sample = r.sample;
    for (std::size_t a = 0; a < problem.arms().size(); ++a) {
      if (problem.arms()[a].name == r.arm) reach.arm = static_cast<int>(a);
    }
    TROCAR_THROW_UNLESS(reach.arm >= 0 && reach.sample >= 0 &&
                            reach.sample < static_cast<int>(problem.samples().size()),
                        where << ": a sample names arm '" << r.arm << "' or index " << reach.sample
                              << " that the plan has not");
    reach.seen = reach.reached = r.seen;
    ev.reaches.push_back(reach);
  }
  return plan;
}

void WritePortMarkups(const PortPlacementProblem& problem, const PortPlacementResult& result,
                      const std::string& path) {
  std::vector<patient::Markup> markups;
  for (std::size_t k = 0; k < result.plans.size(); ++k) {
    patient::Markup m;
    m.name = "plan " + std::to_string(k + 1) + " ports";
    m.type = "Fiducial";
    for (std::size_t a = 0; a < result.plans[k].placement.sites.size(); ++a) {
      m.points.push_back(result.plans[k].placement.sites[a].p_P);
      m.labels.push_back(problem.arms()[a].name);
    }
    markups.push_back(m);
  }
  patient::WriteMarkups(markups, path);
}

void WritePlanFolder(const std::string& dir, const PortPlacementProblem& problem,
                     const PortPlacementResult& result, const PortPlacementOptions& options,
                     const PlanInputs& inputs, const std::function<void(PlanFile*)>& finish) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  TROCAR_THROW_UNLESS(!ec && std::filesystem::is_directory(dir),
                      dir << ": cannot make the output folder (" << ec.message() << ")");
  WritePortMarkups(problem, result, JoinPath(dir, "ports.mrk.json"));
  // The inputs are named by absolute paths, so that the plan opens from any working directory
  // and a copy of it in another folder still finds them (a path relative to the folder trocar
  // plan ran in did neither).
  PlanInputs stored = inputs;
  auto absolute = [](const std::string& p) {
    std::error_code e;
    const std::filesystem::path abs = std::filesystem::absolute(p, e);
    return e ? p : abs.lexically_normal().string();
  };
  stored.case_dir = absolute(inputs.case_dir);
  stored.robot_file = absolute(inputs.robot_file);
  PlanFile file = MakePlanFile(problem, result, options, stored);
  if (finish) finish(&file);
  WritePlanFile(JoinPath(dir, "plan.json"), file);
}

}  // namespace trocar::planners
