#include "port_placement/plan_io.hpp"

#include "port_placement/fixed_ports.hpp"
#include "port_placement/port_rules.hpp"

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <iomanip>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/markups.hpp"
#include "patient/patient_model.hpp"

namespace trocar::planners {

namespace {

using nlohmann::json;

struct Fnv {
  std::uint64_t h = 14695981039346656037ull;
  void Add(const void* data, std::size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < n; ++i) {
      h ^= p[i];
      h *= 1099511628211ull;
    }
  }
  void Add(double v) { Add(&v, sizeof v); }
  void Add(const std::string& s) { Add(s.data(), s.size()); }
  void Add(const Eigen::Vector3d& v) {
    for (int i = 0; i < 3; ++i) Add(v[i]);
  }
  std::string Text() const {
    std::ostringstream s;
    s << "fnv1a64:" << std::hex << std::setw(16) << std::setfill('0') << h;
    return s.str();
  }
};

json Vec(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

json Matrix(const Eigen::Isometry3d& X) {
  json rows = json::array();
  for (int r = 0; r < 4; ++r) {
    json row = json::array();
    for (int c = 0; c < 4; ++c) row.push_back(X.matrix()(r, c));
    rows.push_back(row);
  }
  return rows;
}

// Values rounded so that text output is stable (1e-12 relative is far below any tolerance).
double R(double v) {
  if (!std::isfinite(v)) return v;
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.12g", v);
  return std::strtod(buf, nullptr);
}

json Rounded(const json& j) {
  if (j.is_number_float()) return R(j.get<double>());
  if (j.is_array() || j.is_object()) {
    json out = j;
    for (auto it = out.begin(); it != out.end(); ++it) *it = Rounded(*it);
    return out;
  }
  return j;
}

}  // namespace

std::string HashFile(const std::string& path) {
  Fnv f;
  f.Add(ReadTextFile(path));
  return f.Text();
}

std::string HashPatientModel(const patient::PatientModel& model) {
  Fnv f;
  for (const auto& s : model.structures) {
    f.Add(s.name);
    for (const auto& v : s.mesh.vertices) f.Add(v);
    for (const auto& t : s.mesh.triangles) f.Add(t.data(), sizeof(int) * 3);
  }
  for (const auto& t : model.targets) {
    f.Add(t.name);
    for (const auto& p : t.points) f.Add(p);
    for (const auto& n : t.normals) f.Add(n);
  }
  for (const auto& c : model.port_candidates) {
    f.Add(c.name);
    for (const auto& p : c.skin) f.Add(p);
  }
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) f.Add(model.X_WP.matrix()(r, c));
  }
  return f.Text();
}

// One plan's entry in the plan file (docs/plan-format.md, "plans").
static json PlanEntry(const PortPlacementProblem& problem, const RankedPlan& plan, int rank) {
  const robot::RobotModel& robot = problem.robot();
  const patient::PatientModel& patient = problem.patient();
  const Evaluation& ev = plan.evaluation;
  json ports = json::array();
  for (std::size_t a = 0; a < plan.placement.sites.size(); ++a) {
    const PortSite& site = plan.placement.sites[a];
    ports.push_back({{"arm", problem.arms()[a].name},
                     {"candidate", patient.port_candidates[site.candidate].name},
                     {"s", site.s},
                     {"curve_P", Vec(site.p_curve_P)},
                     {"p_P", Vec(site.p_P)},
                     {"p_W", Vec(site.p_W)},
                     {"rcm_W", Vec(site.p_rcm_W)},
                     {"anatomy", DescribePort(patient, site)},
                     {"skin_allowance", site.skin_allowance},
                     {"pivot", site.in_gap ? "intercostal gap" : "rcm_depth toward the targets"}});
  }
  json setup = json::object();
  json nominal = json::object();
  for (int j = 0; j < robot.num_joints(); ++j) {
    const robot::Joint& joint = robot.joint(j);
    if (joint.movable() && joint.drive == robot::JointDrive::kHeld && ev.joint_values.size() > 0)
      setup[joint.name] = ev.joint_values[joint.dof_index];
    if (joint.movable() && joint.q_index >= 0 && ev.q_nominal.size() > 0)
      nominal[joint.name] = ev.q_nominal[joint.q_index];
  }
  json terms = json::array();
  for (const auto& t : ev.terms) {
    terms.push_back({{"name", t.name},
                     {"unit", t.unit},
                     {"value", t.value},
                     {"score", t.score},
                     {"weight", t.weight},
                     {"note", t.note}});
  }
  json reaches = json::array();
  for (const auto& r : ev.reaches) {
    const PlanArm& arm = problem.arms()[r.arm];
    json q = json::object();
    for (std::size_t c = 0;
         c < arm.q_indices.size() && c < static_cast<std::size_t>(r.q_arm.size()); ++c) {
      q[robot.joint(robot.active_joints()[arm.q_indices[c]]).name] = r.q_arm[c];
    }
    json entry = {{"sample", r.sample}, {"arm", arm.name}, {"reached", r.reached}, {"q", q}};
    if (arm.role == ArmRole::kEndoscope) {
      entry["seen"] = r.seen;
      entry["off_axis_deg"] = r.approach * 180 / M_PI;
    } else {
      entry["tip_error_m"] = r.tip_error;
      entry["dexterity"] = r.dexterity;
      entry["approach_deg"] = r.approach * 180 / M_PI;
    }
    if (!r.reached) entry["reason"] = r.reason;
    reaches.push_back(entry);
  }
  json shifts = json::array();
  for (const auto& s : plan.shifts) {
    shifts.push_back({{"shift_P", Vec(s.d_P)},
                      {"score", s.score},
                      {"coverage", s.coverage},
                      {"served", s.served}});
  }
  json served = json::array();
  for (bool b : ev.served) served.push_back(b);
  json views = json::array();
  for (const auto& v : ev.views) {
    views.push_back(
        {{"arm", problem.arms()[v.arm].name}, {"frame", v.frame}, {"axis_F", Vec(v.axis_F)}});
  }
  const Eigen::Isometry3d X_WB = plan.placement.X_WB();
  return json{{"rank", rank},
                   {"status", ToString(ev.status)},
                   {"score", ev.score},
                   {"rank_score", plan.rank_score},
                   {"robust_score", plan.robust_score},
                   {"degradation", plan.degradation},
                   {"collisions_at_nominal", ev.collisions},
                   {"message", ev.message},
                   {"ports", ports},
                   {"views", views},
                   {"cart",
                    {{"x", plan.placement.cart_x},
                     {"y", plan.placement.cart_y},
                     {"yaw_deg", plan.placement.cart_yaw * 180 / M_PI},
                     {"X_WB", Matrix(X_WB)}}},
                   {"setup_joints", setup},
                   {"q_nominal", nominal},
                   {"terms", terms},
                   {"served", served},
                   {"samples", reaches},
                   {"robustness", shifts}};
}

std::string PlanJson(const PortPlacementProblem& problem, const PortPlacementResult& result,
                     const PortPlacementOptions& options, const PlanInputs& inputs) {
  const robot::RobotModel& robot = problem.robot();
  const patient::PatientModel& patient = problem.patient();
  const ProblemOptions& po = problem.options();
  json doc;
  doc["format"] = "trocar-plan";
  doc["version"] = kPlanFormatVersion;
  doc["inputs"] = {{"case", inputs.case_dir},
                   {"case_hash", inputs.case_hash},
                   {"robot", inputs.robot_file},
                   {"robot_hash", inputs.robot_hash},
                   {"patient_model_hash", inputs.model_hash}};
  doc["patient"] = {{"name", patient.name}, {"X_WP", Matrix(patient.X_WP)}};
  {
    // The state the plans were made in (patient/operative_state.hpp; docs/operative-state.md).
    const patient::OperativeState& op = patient.operation;
    const patient::OperativeChange& change = patient.operative_change;
    doc["operation"] = {{"state", op.applied ? "operative" : "ct"},
                        {"description", op.Describe()},
                        {"co2_mmHg", op.applied ? op.co2_mmhg : 0.0},
                        {"left_lung_isolated", op.applied && op.left_lung_isolated},
                        {"left_side_up_deg", patient.left_side_up * 180 / M_PI},
                        {"heart_shift_m", op.moves() ? op.heart_shift : 0.0},
                        {"heart_shift_range_m",
                         op.moves() ? json::array({op.heart_shift_min, op.heart_shift_max})
                                    : json::array({0.0, 0.0})},
                        {"direction_P", Vec(change.direction_P)},
                        {"d_P", Vec(change.d_P)},
                        {"moved_structures", change.structures},
                        {"moved_targets", change.targets}};
  }
  json arms = json::array();
  for (const auto& arm : problem.arms()) {
    json joints = json::array();
    for (int i : arm.q_indices) joints.push_back(robot.joint(robot.active_joints()[i]).name);
    arms.push_back({{"name", arm.name},
                    {"role", ToString(arm.role)},
                    {"rcm_frame", arm.rcm_frame},
                    {"tool_frame", arm.tool_frame},
                    {"shaft_link", arm.shaft_link >= 0 ? robot.link(arm.shaft_link).name : ""},
                    {"shaft_a_L", Vec(arm.p_L_shaft_a)},
                    {"shaft_b_L", Vec(arm.p_L_shaft_b)},
                    {"joints", joints},
                    {"max_reach_m",
                     std::isfinite(problem.MaxReach(static_cast<int>(&arm - &problem.arms()[0])))
                         ? json(problem.MaxReach(static_cast<int>(&arm - &problem.arms()[0])))
                         : json(nullptr)}});
  }
  doc["robot"] = {{"name", robot.name()}, {"arms", arms}};
  const ScoreWeights& w = po.weights;
  doc["algorithm"] = {{"global", result.algorithm},
                      {"local", result.local},
                      {"seed", options.seed},
                      {"starts", options.starts},
                      {"evaluations_budget", options.evaluations},
                      {"polish_evaluations", options.polish_evaluations},
                      {"evaluations", result.evaluations},
                      {"global_evaluations", result.global_evaluations},
                      {"best_global_score", result.best_global_score},
                      {"time_limit_s", options.time_limit},
                      {"time_limit_hit", result.time_limit_hit},
                      {"grid", result.grid},
                      {"top_k", options.top_k},
                      {"distinct_distance_m", options.distinct_distance},
                      {"robustness_shift_m", options.robustness_shift},
                      {"robustness_weight", options.robustness_weight}};
  doc["scoring"] = {{"weights",
                     {{"coverage", w.coverage},
                      {"served", w.served},
                      {"dexterity", w.dexterity},
                      {"approach", w.approach},
                      {"triangulation", w.triangulation},
                      {"endoscope", w.endoscope},
                      {"spacing", w.spacing},
                      {"clearance_arm_arm", w.clearance_arm_arm},
                      {"clearance_arm_patient", w.clearance_arm_patient},
                      {"clearance_instrument_rib", w.clearance_instrument_rib}}},
                    {"standoff_m", po.standoff},
                    {"rcm_depth_m", po.rcm_depth},
                    {"gap_search_depth_m", po.gap_search_depth},
                    {"ik_tolerance_m", po.ik_tolerance},
                    {"reach_restarts", po.reach_restarts},
                    {"sight_margin_m", kSightMargin},
                    {"scope_half_fov_deg", po.scope_half_fov * 180 / M_PI},
                    {"scope_min_distance_m", po.scope_min_distance},
                    {"scope_max_distance_m", po.scope_max_distance},
                    {"scope_working_distance_m", po.scope_working_distance},
                    {"scope_moves", po.scope_moves},
                    {"samples_per_target", po.samples_per_target},
                    {"suitable_fraction", options.suitable_fraction}};
  doc["verdict"] = {{"suitable", result.verdict.suitable},
                    {"summary", result.verdict.summary},
                    {"reasons", result.verdict.reasons}};
  json samples = json::array();
  for (std::size_t i = 0; i < problem.samples().size(); ++i) {
    const auto& s = problem.samples()[i];
    samples.push_back({{"index", i},
                       {"target", patient.targets[s.target].name},
                       {"point", s.point},
                       {"arc_length_m", s.arc_length},
                       {"p_W", Vec(s.p_W)},
                       {"n_W", Vec(s.n_W)},
                       {"aim_W", Vec(s.p_W + po.standoff * s.n_W)}});
  }
  doc["target_samples"] = samples;
  json plans = json::array();
  for (std::size_t k = 0; k < result.plans.size(); ++k)
    plans.push_back(PlanEntry(problem, result.plans[k], static_cast<int>(k) + 1));
  doc["plans"] = plans;
  if (!result.ports_given.empty())
    doc["ports_given"] = {{"what", result.ports_given}, {"where", result.ports_where}};
  // The baselines beside the optimised plans (the template, a surgeon's ports).
  json baselines = json::array();
  for (const Baseline& b : result.baselines) {
    json entry = {{"kind", b.kind}, {"name", b.name}, {"placed", b.placed}};
    if (!b.placed) {
      entry["why_not"] = b.why_not;
    } else {
      const FixedPortsPlan& f = b.fixed;
      entry["source"] = f.ports.source;
      entry["where"] = f.ports.where;
      entry["notes"] = f.ports.notes;
      entry["search"] = f.search;
      entry["evaluations"] = f.evaluations;
      entry["verdict"] = {{"suitable", f.verdict.suitable},
                          {"summary", f.verdict.summary},
                          {"reasons", f.verdict.reasons}};
      entry["plan"] = PlanEntry(problem, f.plan, 0);
    }
    baselines.push_back(entry);
  }
  doc["baselines"] = baselines;
  // The anatomical selection criteria beside the verdict (docs/selection-criteria.md).
  json criteria = json::array();
  for (const Criterion& c : result.criteria.criteria) {
    criteria.push_back({{"name", c.name},
                        {"title", c.title},
                        {"value", c.measured() ? json(c.value) : json(nullptr)},
                        {"unit", c.unit},
                        {"threshold", c.threshold},
                        {"favourable_when", c.at_least ? "at least the threshold" : "at most the threshold"},
                        {"favourable", c.favourable()},
                        {"meaning", c.meaning},
                        {"how", c.how},
                        {"source", c.source}});
  }
  doc["selection_criteria"] = {{"criteria", criteria},
                               {"comparison", result.criteria_comparison}};
  json convergence = json::array();
  for (const auto& p : result.trace) convergence.push_back(json::array({p.evaluations, p.best}));
  doc["convergence"] = convergence;
  json timings = json::object();
  for (const auto& [stage, s] : result.timings) timings[stage] = s;
  doc["run"] = {{"threads", result.threads}, {"timings_s", timings}};
  return Rounded(doc).dump(1) + "\n";
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
                     const PlanInputs& inputs,
                     const std::function<std::string(const std::string&)>& finish) {
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
  const std::string text = PlanJson(problem, result, options, stored);
  WriteFileAtomically(JoinPath(dir, "plan.json"), finish ? finish(text) : text);
}

}  // namespace trocar::planners
