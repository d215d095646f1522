#include "plan/plan_file.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <initializer_list>
#include <iomanip>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/json_util.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/patient_model.hpp"

namespace trocar::planners {
namespace {

/// Physical ranges of a plan's numbers (issue #44 item 1): a room is metres across (m), and a
/// joint turns a few times at most or slides a few metres (rad or m).
constexpr double kMaxRoomCoordinate = 100.0;
constexpr double kMaxJointValue = 1000.0;
/// Sizes a plan can hold: an arm's joints, a motion's waypoints.
constexpr std::size_t kMaxArmJoints = 64, kMaxWaypoints = 100000;

using nlohmann::json;

/// A JSON value with its path in the document, for messages.
struct Field {
  const std::string& file;
  const json& j;
  std::string path;

  [[noreturn]] void Fail(const std::string& expected) const {
    TROCAR_THROW(file << ": " << (path.empty() ? "the document" : path) << ": expected " << expected
                      << (j.is_null() ? "" : ", found " + j.dump().substr(0, 60)));
  }
  bool Has(const std::string& key) const { return j.is_object() && j.contains(key); }
  Field operator[](const std::string& key) const {
    if (!j.is_object()) Fail("an object");
    if (!j.contains(key)) {
      TROCAR_THROW(file << ": " << (path.empty() ? "" : path + ".") << key << ": missing");
    }
    return {file, j.at(key), path.empty() ? key : path + "." + key};
  }
  Field operator[](std::size_t i) const {
    return {file, j.at(i), path + "[" + std::to_string(i) + "]"};
  }
  std::size_t Size() const {
    if (!j.is_array()) Fail("an array");
    return j.size();
  }
  double Number() const {
    if (!j.is_number()) Fail("a number");
    const double v = j.get<double>();
    if (!std::isfinite(v)) Fail("a finite number");
    return v;
  }
  /// A number, or null for one that was not finite when written (NaN: not measured, unbounded).
  double NumberOrNull() const {
    if (j.is_null()) return std::numeric_limits<double>::quiet_NaN();
    return Number();
  }
  std::int64_t Int64() const {
    if (!j.is_number_integer()) Fail("an integer");
    if (j.is_number_unsigned() && j.get<std::uint64_t>() > static_cast<std::uint64_t>(INT64_MAX))
      Fail("an integer below 2^63");
    return j.get<std::int64_t>();
  }
  unsigned Unsigned() const {
    if (!j.is_number_integer()) Fail("an integer");
    return static_cast<unsigned>(
        JsonInt(j, file, path.empty() ? "the document" : path, 0, UINT32_MAX));
  }
  int Integer() const {
    if (!j.is_number_integer()) Fail("an integer");
    return JsonInt(j, file, path.empty() ? "the document" : path);
  }
  bool Bool() const {
    if (!j.is_boolean()) Fail("true or false");
    return j.get<bool>();
  }
  std::string String() const {
    if (!j.is_string()) Fail("a string");
    return j.get<std::string>();
  }
  Eigen::Vector3d Vec3() const {
    if (Size() != 3) Fail("3 numbers");
    return {(*this)[0].Number(), (*this)[1].Number(), (*this)[2].Number()};
  }
  /// A point of the operating room (m): within kMaxRoomCoordinate of its origin.
  Eigen::Vector3d Position() const {
    const Eigen::Vector3d p = Vec3();
    if (p.cwiseAbs().maxCoeff() > kMaxRoomCoordinate)
      Fail("a point within 100 m of the room's origin");
    return p;
  }
  /// A unit direction (within 1e-6).
  Eigen::Vector3d Direction() const {
    const Eigen::Vector3d d = Vec3();
    if (std::abs(d.norm() - 1.0) > 1e-6) Fail("a unit vector");
    return d;
  }
  Eigen::Isometry3d Pose() const {
    if (Size() != 4) Fail("a 4x4 matrix");
    Eigen::Matrix4d m;
    for (int r = 0; r < 4; ++r) {
      const Field row = (*this)[r];
      if (row.Size() != 4) row.Fail("4 numbers");
      for (int c = 0; c < 4; ++c) m(r, c) = row[c].Number();
    }
    const Eigen::Matrix3d R = m.topLeftCorner<3, 3>();
    if ((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-6 || R.determinant() < 0 ||
        m.row(3).head<3>().norm() > 1e-9 || std::abs(m(3, 3) - 1) > 1e-9) {
      Fail("a rigid transform (rotation and translation)");
    }
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = R;
    X.translation() = m.topRightCorner<3, 1>();
    return X;
  }
  std::vector<std::string> Strings() const {
    std::vector<std::string> out;
    for (std::size_t i = 0; i < Size(); ++i) out.push_back((*this)[i].String());
    return out;
  }
  /// A joint value in rad or m (1e300 is no pose: a limit check downstream would still pass it to
  /// sin and cos first).
  double JointValue() const {
    const double v = Number();
    if (std::abs(v) > kMaxJointValue) Fail("a joint value within 1000 (rad or m)");
    return v;
  }
  std::vector<std::pair<std::string, double>> NamedNumbers() const {
    if (!j.is_object()) Fail("an object of joint names and values");
    std::vector<std::pair<std::string, double>> out;
    for (const auto& [name, value] : j.items()) {
      out.emplace_back(name, (*this)[name].JointValue());
    }
    return out;
  }
};

// The cart's pose: X_WB, checked against the x, y and yaw stored beside it (one pose, not two
// sources of truth: `check --plan` and `verify` once read the one, `view` and `report` the other).
Eigen::Isometry3d CartPose(const Field& cart) {
  const Eigen::Isometry3d X_WB = cart["X_WB"].Pose();
  const double x = cart["x"].Number(), y = cart["y"].Number();
  const double z = cart.Has("z") ? cart["z"].Number() : 0.0;
  const double yaw = cart["yaw_deg"].Number() * M_PI / 180.0;
  Eigen::Isometry3d expected = Eigen::Isometry3d::Identity();
  expected.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  expected.translation() = Eigen::Vector3d(x, y, z);
  const double moved = (X_WB.translation() - expected.translation()).norm();
  const double turned = Eigen::AngleAxisd(X_WB.linear().transpose() * expected.linear()).angle();
  if (moved > 1e-6 || turned > 1e-6) {
    std::ostringstream m;
    m << "X_WB to agree with x, y, z and yaw_deg (the cart on the floor at (" << x << ", " << y
      << ", " << z << ") m, turned " << yaw * 180.0 / M_PI << " deg); it is " << moved * 1e3
      << " mm and " << turned * 180.0 / M_PI << " deg from that";
    cart.Fail(m.str());
  }
  return X_WB;
}

// The fields of `j` (an object) not among `known`, as JSON text.
UnknownFields Unknown(const json& j, std::initializer_list<const char*> known) {
  UnknownFields out;
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string& key = it.key();
    bool is_known = false;
    for (const char* k : known) is_known = is_known || key == k;
    if (!is_known) out.emplace_back(key, it.value().dump());
  }
  return out;
}

void AddUnknown(const UnknownFields& unknown, json* j) {
  for (const auto& [key, text] : unknown) (*j)[key] = json::parse(text);
}

StoredVerdict ReadVerdict(const Field& v, bool with_summary) {
  StoredVerdict out;
  out.suitable = v["suitable"].Bool();
  if (with_summary) out.summary = v["summary"].String();
  out.reasons = v["reasons"].Strings();
  return out;
}

StoredMotion ReadMotion(const Field& m) {
  StoredMotion motion;
  motion.arm = m["arm"].String();
  motion.sample = m["sample"].Integer();
  motion.outcome = m["outcome"].String();
  if (m.Has("reason")) motion.reason = m["reason"].String();
  motion.solved = m["solved"].Bool();
  if (m.Has("status")) motion.status = m["status"].String();
  if (m.Has("planning_time_s")) motion.planning_time = m["planning_time_s"].NumberOrNull();
  if (m.Has("simplification_time_s"))
    motion.simplification_time = m["simplification_time_s"].NumberOrNull();
  if (m.Has("graph_states")) motion.graph_states = m["graph_states"].Int64();
  if (m.Has("min_clearance_m")) motion.min_clearance = m["min_clearance_m"].Number();
  if (m.Has("waypoints")) {
    motion.has_path = true;
    if (m.Has("path_length")) motion.path_length = m["path_length"].NumberOrNull();
    if (m.Has("raw_path_length")) motion.raw_path_length = m["raw_path_length"].NumberOrNull();
    if (m.Has("tip_path_length_m")) motion.tip_path_length = m["tip_path_length_m"].NumberOrNull();
    if (m.Has("rechecked_states")) motion.rechecked_states = m["rechecked_states"].Integer();
    motion.joints = m["joints"].Strings();
    if (motion.joints.size() > kMaxArmJoints) m["joints"].Fail("at most 64 joints of one arm");
    const Field w = m["waypoints"];
    // A simplified path has tens of waypoints; the re-check steps it at a fine step.
    if (w.Size() > kMaxWaypoints) w.Fail("at most 100000 waypoints");
    for (std::size_t k = 0; k < w.Size(); ++k) {
      if (w[k].Size() != motion.joints.size()) {
        w[k].Fail(std::to_string(motion.joints.size()) + " joint values");
      }
      Eigen::VectorXd q(motion.joints.size());
      for (std::size_t d = 0; d < motion.joints.size(); ++d) q[d] = w[k][d].Number();
      motion.waypoints.push_back(q);
    }
  }
  if (m.Has("failure_pose")) {
    if (motion.solved) m["failure_pose"].Fail("no failure pose on a solved motion");
    if (motion.joints.empty()) {
      motion.joints = m["joints"].Strings();
      if (motion.joints.size() > kMaxArmJoints) m["joints"].Fail("at most 64 joints of one arm");
    }
    const Field f = m["failure_pose"];
    if (f.Size() != motion.joints.size())
      f.Fail(std::to_string(motion.joints.size()) + " joint values");
    motion.failure_pose.resize(static_cast<Eigen::Index>(motion.joints.size()));
    for (std::size_t d = 0; d < motion.joints.size(); ++d)
      motion.failure_pose[static_cast<Eigen::Index>(d)] = f[d].JointValue();
  }
  return motion;
}

void ReadVerification(const Field& v, StoredPlan* plan) {
  plan->verified = true;
  StoredVerificationRun& run = plan->verification_run;
  if (v.Has("planner")) run.planner = v["planner"].String();
  if (v.Has("time_limit_s")) run.time_limit = v["time_limit_s"].NumberOrNull();
  if (v.Has("check_step")) run.check_step = v["check_step"].NumberOrNull();
  if (v.Has("recheck_step")) run.recheck_step = v["recheck_step"].NumberOrNull();
  if (v.Has("prismatic_weight_per_m"))
    run.prismatic_weight_per_m = v["prismatic_weight_per_m"].NumberOrNull();
  if (v.Has("seed")) run.seed = v["seed"].Unsigned();
  if (v.Has("rank_score")) run.rank_score = v["rank_score"].NumberOrNull();
  if (v.Has("states_checked")) run.states_checked = v["states_checked"].Int64();
  if (v.Has("seconds")) run.seconds = v["seconds"].NumberOrNull();
  if (v.Has("threads")) run.threads = v["threads"].Integer();
  plan->verified_coverage = v["verified_coverage"].Number();
  plan->claimed_coverage = v["claimed_coverage"].Number();
  plan->served_fraction = v["served_fraction"].Number();
  plan->verified_suitable = v["suitable"].Bool();
  plan->verification_reasons = v["reasons"].Strings();
  if (v.Has("served")) {
    const Field served = v["served"];
    for (std::size_t i = 0; i < served.Size(); ++i)
      plan->verified_served.push_back(served[i].Bool());
  }
  const Field motions = v["motions"];
  for (std::size_t i = 0; i < motions.Size(); ++i) plan->motions.push_back(ReadMotion(motions[i]));
}

StoredPlan ReadPlan(const Field& p, int rank_from = 1) {
  StoredPlan plan;
  plan.rank = p["rank"].Integer();
  if (plan.rank < rank_from) p["rank"].Fail("a rank from " + std::to_string(rank_from));
  if (p.Has("rank_before_verification"))
    plan.rank_before_verification = p["rank_before_verification"].Integer();
  plan.status = p["status"].String();
  plan.score = p["score"].Number();
  plan.rank_score = p["rank_score"].Number();
  if (p.Has("robust_score")) plan.robust_score = p["robust_score"].NumberOrNull();
  if (p.Has("degradation")) plan.degradation = p["degradation"].NumberOrNull();
  if (p.Has("collisions_at_nominal"))
    plan.collisions_at_nominal = p["collisions_at_nominal"].Integer();
  if (p.Has("message")) plan.message = p["message"].String();
  const Field cart = p["cart"];
  plan.X_WB = CartPose(cart);
  plan.cart_x = cart["x"].Number();
  plan.cart_y = cart["y"].Number();
  plan.cart_yaw_deg = cart["yaw_deg"].Number();
  if (cart.Has("z")) {
    plan.cart_z = cart["z"].Number();
    // The cart's floor below the table's world by how far the table was raised: a table's travel.
    if (std::abs(plan.cart_z) > 1.0) cart["z"].Fail("a floor height within 1 m of z = 0 (m)");
  }
  if (cart.Has("table_height")) {
    plan.table_height = cart["table_height"].NumberOrNull();
    if (!std::isnan(plan.table_height) && !(plan.table_height >= 0.3 && plan.table_height <= 1.5))
      cart["table_height"].Fail("a table height of 0.3 to 1.5 m");
  }
  plan.setup_joints = p["setup_joints"].NamedNumbers();
  plan.q_nominal = p["q_nominal"].NamedNumbers();
  const Field ports = p["ports"];
  for (std::size_t i = 0; i < ports.Size(); ++i) {
    const Field f = ports[i];
    StoredPort port;
    port.arm = f["arm"].String();
    port.candidate = f["candidate"].String();
    port.p_W = f["p_W"].Position();
    port.rcm_W = f["rcm_W"].Position();
    if (f.Has("s")) port.s = f["s"].Number();
    if (f.Has("curve_P")) port.curve_P = f["curve_P"].Vec3();
    if (f.Has("p_P")) port.p_P = f["p_P"].Vec3();
    if (f.Has("anatomy")) port.anatomy = f["anatomy"].String();
    if (f.Has("skin_allowance")) port.skin_allowance = f["skin_allowance"].Number();
    if (f.Has("pivot")) port.pivot = f["pivot"].String();
    plan.ports.push_back(port);
  }
  if (p.Has("views")) {
    const Field views = p["views"];
    for (std::size_t i = 0; i < views.Size(); ++i) {
      StoredView view;
      view.arm = views[i]["arm"].String();
      view.frame = views[i]["frame"].String();
      view.axis_F = views[i]["axis_F"].Vec3();
      if (std::abs(view.axis_F.norm() - 1) > 1e-3) views[i]["axis_F"].Fail("a unit vector");
      plan.views.push_back(view);
    }
  }
  const Field terms = p["terms"];
  for (std::size_t i = 0; i < terms.Size(); ++i) {
    StoredTerm t;
    t.name = terms[i]["name"].String();
    t.value = terms[i]["value"].Number();
    t.score = terms[i]["score"].Number();
    if (terms[i].Has("unit")) t.unit = terms[i]["unit"].String();
    if (terms[i].Has("weight")) t.weight = terms[i]["weight"].Number();
    if (terms[i].Has("note")) t.note = terms[i]["note"].String();
    plan.terms.push_back(t);
  }
  if (p.Has("served")) {
    const Field served = p["served"];
    for (std::size_t i = 0; i < served.Size(); ++i) plan.served.push_back(served[i].Bool());
  }
  if (p.Has("samples")) {
    const Field list = p["samples"];
    for (std::size_t i = 0; i < list.Size(); ++i) {
      const Field r = list[i];
      StoredReach reach;
      reach.sample = r["sample"].Integer();
      reach.arm = r["arm"].String();
      reach.reached = r["reached"].Bool();
      reach.q = r["q"].NamedNumbers();
      reach.endoscope = r.Has("seen");
      if (reach.endoscope) {
        reach.seen = r["seen"].Bool();
        reach.off_axis_deg = r["off_axis_deg"].NumberOrNull();
      } else {
        reach.tip_error_m = r["tip_error_m"].NumberOrNull();
        reach.dexterity = r["dexterity"].NumberOrNull();
        reach.approach_deg = r["approach_deg"].NumberOrNull();
      }
      if (r.Has("reason")) reach.reason = r["reason"].String();
      plan.reaches.push_back(std::move(reach));
    }
  }
  if (p.Has("robustness")) {
    const Field list = p["robustness"];
    for (std::size_t i = 0; i < list.Size(); ++i) {
      StoredShift s;
      s.shift_P = list[i]["shift_P"].Vec3();
      s.score = list[i]["score"].NumberOrNull();
      s.coverage = list[i]["coverage"].NumberOrNull();
      s.served = list[i]["served"].NumberOrNull();
      plan.robustness.push_back(s);
    }
  }
  if (p.Has("verification")) ReadVerification(p["verification"], &plan);
  plan.unknown = Unknown(p.j, {"rank",         "rank_before_verification",
                               "status",       "score",
                               "rank_score",   "robust_score",
                               "degradation",  "collisions_at_nominal",
                               "message",      "ports",
                               "views",        "cart",
                               "setup_joints", "q_nominal",
                               "terms",        "served",
                               "samples",      "robustness",
                               "verification", "signoffs"});
  if (p.Has("signoffs")) {
    const Field list = p["signoffs"];
    for (std::size_t i = 0; i < list.Size(); ++i) {
      SignOff s;
      s.decision = list[i]["decision"].String();
      s.surgeon = list[i]["surgeon"].String();
      s.note = list[i]["note"].String();
      s.time = list[i]["time"].String();
      if (list[i].Has("session")) {
        s.session = list[i]["session"].String();
        s.session_hash = list[i]["session_hash"].String();
      }
      if (list[i].Has("override")) {
        s.override_reason = list[i]["override"].String();
        const Field o = list[i]["overridden"];
        for (std::size_t k = 0; k < o.Size(); ++k) s.overridden.push_back(o[k].String());
      }
      plan.signoffs.push_back(s);
    }
  }
  return plan;
}

void ReadParts(const Field& root, PlanFile* file) {
  if (root.Has("operation")) {
    const Field o = root["operation"];
    StoredOperation op;
    op.state = o["state"].String();
    op.description = o["description"].String();
    op.co2_mmHg = o["co2_mmHg"].Number();
    op.left_lung_isolated = o["left_lung_isolated"].Bool();
    op.left_side_up_deg = o["left_side_up_deg"].Number();
    op.heart_shift_m = o["heart_shift_m"].Number();
    const Field range = o["heart_shift_range_m"];
    if (range.Size() != 2) range.Fail("[min, max]");
    op.heart_shift_min_m = range[0].Number();
    op.heart_shift_max_m = range[1].Number();
    op.direction_P = o["direction_P"].Vec3();
    op.d_P = o["d_P"].Vec3();
    op.moved_structures = o["moved_structures"].Strings();
    op.moved_targets = o["moved_targets"].Strings();
    file->operation = op;
  }
  {
    const Field a = root["algorithm"];
    StoredAlgorithm& out = file->algorithm;
    out.global = a["global"].String();
    out.local = a["local"].String();
    out.seed = a["seed"].Unsigned();
    out.starts = a["starts"].Integer();
    out.evaluations_budget = a["evaluations_budget"].Integer();
    out.polish_evaluations = a["polish_evaluations"].Integer();
    out.evaluations = a["evaluations"].Integer();
    out.global_evaluations = a["global_evaluations"].Integer();
    out.best_global_score = a["best_global_score"].NumberOrNull();
    out.time_limit_s = a["time_limit_s"].Number();
    out.time_limit_hit = a["time_limit_hit"].Bool();
    out.grid = a["grid"].String();
    out.top_k = a["top_k"].Integer();
    out.distinct_distance_m = a["distinct_distance_m"].Number();
    out.robustness_shift_m = a["robustness_shift_m"].Number();
    out.robustness_weight = a["robustness_weight"].Number();
  }
  {
    const Field s = root["scoring"];
    StoredScoring& out = file->scoring;
    out.weights = s["weights"].NamedNumbers();
    out.standoff_m = s["standoff_m"].Number();
    out.rcm_depth_m = s["rcm_depth_m"].Number();
    out.gap_search_depth_m = s["gap_search_depth_m"].Number();
    out.ik_tolerance_m = s["ik_tolerance_m"].Number();
    if (s.Has("reach_restarts")) out.reach_restarts = s["reach_restarts"].Integer();
    if (s.Has("sight_margin_m")) out.sight_margin_m = s["sight_margin_m"].Number();
    out.scope_half_fov_deg = s["scope_half_fov_deg"].Number();
    out.scope_min_distance_m = s["scope_min_distance_m"].Number();
    out.scope_max_distance_m = s["scope_max_distance_m"].Number();
    out.scope_working_distance_m = s["scope_working_distance_m"].Number();
    if (s.Has("scope_moves")) out.scope_moves = s["scope_moves"].Bool();
    out.samples_per_target = s["samples_per_target"].Integer();
    out.suitable_fraction = s["suitable_fraction"].Number();
  }
  if (root.Has("ports_given")) {
    const Field g = root["ports_given"];
    file->ports_given = std::make_pair(g["what"].String(), g["where"].Strings());
  }
  if (root.Has("selection_criteria")) {
    const Field sc = root["selection_criteria"];
    const Field list = sc["criteria"];
    for (std::size_t i = 0; i < list.Size(); ++i) {
      const Field c = list[i];
      StoredCriterion out;
      out.name = c["name"].String();
      out.title = c["title"].String();
      out.value = c["value"].NumberOrNull();
      out.unit = c["unit"].String();
      out.threshold = c["threshold"].Number();
      out.favourable_when = c["favourable_when"].String();
      out.favourable = c["favourable"].Bool();
      out.meaning = c["meaning"].String();
      out.how = c["how"].String();
      out.source = c["source"].String();
      file->criteria.push_back(out);
    }
    file->criteria_comparison = sc["comparison"].String();
  }
  if (root.Has("convergence")) {
    const Field list = root["convergence"];
    for (std::size_t i = 0; i < list.Size(); ++i) {
      if (list[i].Size() != 2) list[i].Fail("[evaluations, best score]");
      file->convergence.emplace_back(list[i][0].Integer(), list[i][1].NumberOrNull());
    }
  }
  if (root.Has("run")) {
    const Field run = root["run"];
    file->run_threads = run["threads"].Integer();
    const Field t = run["timings_s"];
    if (!t.j.is_object()) t.Fail("an object of stages and seconds");
    for (const auto& [stage, value] : t.j.items())
      file->timings_s.emplace_back(stage, t[stage].Number());
  }
}

// ---- the writer -------------------------------------------------------------------------------

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
// Rounding a rounded value gives it back, so a plan read and written again keeps its bytes.
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

json Named(const NamedValues& values) {
  json out = json::object();
  for (const auto& [name, v] : values) out[name] = v;
  return out;
}

json VerdictJson(const StoredVerdict& v, bool with_summary) {
  json out = {{"suitable", v.suitable}, {"reasons", v.reasons}};
  if (with_summary) out["summary"] = v.summary;
  return out;
}

// `plans[].verification`: written as computed (not rounded).
json VerificationJson(const StoredPlan& plan) {
  const StoredVerificationRun& run = plan.verification_run;
  json motions = json::array();
  for (const StoredMotion& m : plan.motions) {
    json entry = {{"arm", m.arm},
                  {"sample", m.sample},
                  {"outcome", m.outcome},
                  {"status", m.status},
                  {"solved", m.solved},
                  {"planning_time_s", m.planning_time},
                  {"simplification_time_s", m.simplification_time},
                  {"graph_states", m.graph_states}};
    if (!m.reason.empty()) entry["reason"] = m.reason;
    if (m.has_path) {
      entry["path_length"] = m.path_length;
      entry["raw_path_length"] = m.raw_path_length;
      entry["tip_path_length_m"] = m.tip_path_length;
      entry["rechecked_states"] = m.rechecked_states;
      if (std::isfinite(m.min_clearance)) entry["min_clearance_m"] = m.min_clearance;
      json waypoints = json::array();
      for (const auto& q : m.waypoints) {
        json row = json::array();
        for (int c = 0; c < q.size(); ++c) row.push_back(q[c]);
        waypoints.push_back(row);
      }
      entry["joints"] = m.joints;
      entry["waypoints"] = waypoints;
    }
    if (m.failure_pose.size() > 0) {
      entry["joints"] = m.joints;
      json pose = json::array();
      for (int c = 0; c < m.failure_pose.size(); ++c) pose.push_back(m.failure_pose[c]);
      entry["failure_pose"] = pose;
    }
    motions.push_back(entry);
  }
  return {{"planner", run.planner},
          {"time_limit_s", run.time_limit},
          {"check_step", run.check_step},
          {"recheck_step", run.recheck_step},
          {"prismatic_weight_per_m", run.prismatic_weight_per_m},
          {"seed", run.seed},
          {"claimed_coverage", plan.claimed_coverage},
          {"verified_coverage", plan.verified_coverage},
          {"served", plan.verified_served},
          {"served_fraction", plan.served_fraction},
          {"rank_score", run.rank_score},
          {"suitable", plan.verified_suitable},
          {"reasons", plan.verification_reasons},
          {"states_checked", run.states_checked},
          {"seconds", run.seconds},
          {"threads", run.threads},
          {"motions", motions}};
}

// One plan's entry (docs/plan-format.md, "plans"): rounded, then its verification and sign-offs.
json PlanJsonEntry(const StoredPlan& plan) {
  json ports = json::array();
  for (const StoredPort& p : plan.ports) {
    ports.push_back({{"arm", p.arm},
                     {"candidate", p.candidate},
                     {"s", p.s},
                     {"curve_P", Vec(p.curve_P)},
                     {"p_P", Vec(p.p_P)},
                     {"p_W", Vec(p.p_W)},
                     {"rcm_W", Vec(p.rcm_W)},
                     {"anatomy", p.anatomy},
                     {"skin_allowance", p.skin_allowance},
                     {"pivot", p.pivot}});
  }
  json terms = json::array();
  for (const StoredTerm& t : plan.terms) {
    terms.push_back({{"name", t.name},
                     {"unit", t.unit},
                     {"value", t.value},
                     {"score", t.score},
                     {"weight", t.weight},
                     {"note", t.note}});
  }
  json reaches = json::array();
  for (const StoredReach& r : plan.reaches) {
    json entry = {{"sample", r.sample}, {"arm", r.arm}, {"reached", r.reached}, {"q", Named(r.q)}};
    if (r.endoscope) {
      entry["seen"] = r.seen;
      entry["off_axis_deg"] = r.off_axis_deg;
    } else {
      entry["tip_error_m"] = r.tip_error_m;
      entry["dexterity"] = r.dexterity;
      entry["approach_deg"] = r.approach_deg;
    }
    if (!r.reached) entry["reason"] = r.reason;
    reaches.push_back(entry);
  }
  json shifts = json::array();
  for (const StoredShift& s : plan.robustness) {
    shifts.push_back({{"shift_P", Vec(s.shift_P)},
                      {"score", s.score},
                      {"coverage", s.coverage},
                      {"served", s.served}});
  }
  json views = json::array();
  for (const StoredView& v : plan.views)
    views.push_back({{"arm", v.arm}, {"frame", v.frame}, {"axis_F", Vec(v.axis_F)}});
  json entry = {{"rank", plan.rank},
                {"status", plan.status},
                {"score", plan.score},
                {"rank_score", plan.rank_score},
                {"robust_score", plan.robust_score},
                {"degradation", plan.degradation},
                {"collisions_at_nominal", plan.collisions_at_nominal},
                {"message", plan.message},
                {"ports", ports},
                {"views", views},
                {"cart",
                 {{"x", plan.cart_x},
                  {"y", plan.cart_y},
                  {"z", plan.cart_z},
                  {"yaw_deg", plan.cart_yaw_deg},
                  {"table_height", plan.table_height},
                  {"X_WB", Matrix(plan.X_WB)}}},
                {"setup_joints", Named(plan.setup_joints)},
                {"q_nominal", Named(plan.q_nominal)},
                {"terms", terms},
                {"served", plan.served},
                {"samples", reaches},
                {"robustness", shifts}};
  if (plan.rank_before_verification)
    entry["rank_before_verification"] = *plan.rank_before_verification;
  entry = Rounded(entry);
  if (plan.verified) entry["verification"] = VerificationJson(plan);
  if (!plan.signoffs.empty()) {
    json list = json::array();
    for (const SignOff& s : plan.signoffs) {
      json e = {
          {"decision", s.decision}, {"surgeon", s.surgeon}, {"note", s.note}, {"time", s.time}};
      if (!s.session.empty()) {
        e["session"] = s.session;
        e["session_hash"] = s.session_hash;
      }
      if (!s.override_reason.empty()) {
        e["override"] = s.override_reason;
        e["overridden"] = s.overridden;
      }
      list.push_back(e);
    }
    entry["signoffs"] = list;
  }
  AddUnknown(plan.unknown, &entry);
  return entry;
}

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

}  // namespace

double StoredScoring::Weight(const std::string& name, double otherwise) const {
  for (const auto& [n, w] : weights) {
    if (n == name) return w;
  }
  return otherwise;
}

PlanFile ReadPlanFile(const std::string& path) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": no such plan file");
  json doc;
  try {
    doc = ReadJsonFile(path, "a plan");
  } catch (const json::exception& e) {
    TROCAR_THROW(path << ": not a plan (JSON: " << e.what() << ")");
  }
  const Field root{path, doc, ""};
  TROCAR_THROW_UNLESS(doc.is_object() && doc.contains("format") && doc["format"].is_string() &&
                          doc["format"].get<std::string>() == "trocar-plan",
                      path << ": not a trocar plan (field 'format' is not \"trocar-plan\")");
  const int version = root["version"].Integer();
  TROCAR_THROW_UNLESS(version >= kOldestPlanFormatVersion && version <= kPlanFormatVersion,
                      path << ": plan format version " << doc.at("version")
                           << ", this trocar reads versions " << kOldestPlanFormatVersion << " to "
                           << kPlanFormatVersion);
  PlanFile file;
  file.path = path;
  const std::string plan_dir = ParentDirectory(path);
  // Plans name their inputs by absolute paths (since stop 61); a relative one (an older plan, or
  // one a user edited) from the working directory, else from the plan's folder.
  auto resolve = [&](const std::string& p) {
    return std::filesystem::exists(p) ? p : JoinPath(plan_dir, p);
  };
  const Field inputs = root["inputs"];
  file.case_written = inputs["case"].String();
  file.robot_written = inputs["robot"].String();
  file.case_dir = resolve(file.case_written);
  file.robot_file = resolve(file.robot_written);
  file.case_hash = inputs["case_hash"].String();
  file.robot_hash = inputs["robot_hash"].String();
  file.model_hash = inputs["patient_model_hash"].String();
  file.patient_name = root["patient"]["name"].String();
  file.X_WP = root["patient"]["X_WP"].Pose();
  if (root["robot"].Has("name")) file.robot_name = root["robot"]["name"].String();
  const Field arms = root["robot"]["arms"];
  for (std::size_t i = 0; i < arms.Size(); ++i) {
    const Field a = arms[i];
    StoredArm arm;
    arm.name = a["name"].String();
    arm.role = a["role"].String();
    arm.tool_frame = a["tool_frame"].String();
    arm.rcm_frame = a["rcm_frame"].String();
    arm.shaft_link = a["shaft_link"].String();
    arm.joints = a["joints"].Strings();
    if (a.Has("shaft_a_L")) arm.shaft_a_L = a["shaft_a_L"].Vec3();
    if (a.Has("shaft_b_L")) arm.shaft_b_L = a["shaft_b_L"].Vec3();
    if (a.Has("max_reach_m")) arm.max_reach = a["max_reach_m"].NumberOrNull();
    file.arms.push_back(arm);
  }
  const Field verdict = root["verdict"];
  file.suitable = verdict["suitable"].Bool();
  file.summary = verdict["summary"].String();
  file.reasons = verdict["reasons"].Strings();
  if (verdict.Has("verified")) {
    const StoredVerdict v = ReadVerdict(verdict["verified"], /*with_summary=*/true);
    file.has_verified_verdict = true;
    file.verified_suitable = v.suitable;
    file.verified_summary = v.summary;
    file.verified_reasons = v.reasons;
  }
  const Field samples = root["target_samples"];
  for (std::size_t i = 0; i < samples.Size(); ++i) {
    const Field f = samples[i];
    StoredSample s;
    s.index = f["index"].Integer();
    s.target = f["target"].String();
    s.p_W = f["p_W"].Position();
    s.n_W = f["n_W"].Direction();
    if (f.Has("point")) s.point = f["point"].Integer();
    if (f.Has("arc_length_m")) s.arc_length = f["arc_length_m"].Number();
    if (f.Has("aim_W")) s.aim_W = f["aim_W"].Vec3();
    file.samples.push_back(s);
  }
  ReadParts(root, &file);
  const Field plans = root["plans"];
  if (plans.Size() == 0) plans.Fail("at least one plan");
  for (std::size_t i = 0; i < plans.Size(); ++i) {
    file.plans.push_back(ReadPlan(plans[i]));
    const StoredPlan& plan = file.plans.back();
    // One motion per (arm, sample) at most.
    TROCAR_THROW_UNLESS(plan.motions.size() <= file.arms.size() * file.samples.size(),
                        path << ": plans[" << i << "].verification.motions: " << plan.motions.size()
                             << " motions, more than one per arm (" << file.arms.size()
                             << ") and target sample (" << file.samples.size() << ")");
    for (const StoredMotion& m : plan.motions) {
      TROCAR_THROW_UNLESS(m.sample >= 0 && m.sample < static_cast<int>(file.samples.size()),
                          path << ": plans[" << i << "].verification: a motion names sample "
                               << m.sample << ", the plan has " << file.samples.size());
    }
    TROCAR_THROW_UNLESS(plan.ports.size() == file.arms.size(),
                        path << ": plans[" << i << "].ports: " << plan.ports.size() << " ports for "
                             << file.arms.size() << " arms");
  }
  if (root.Has("baselines")) {
    const Field list = root["baselines"];
    for (std::size_t i = 0; i < list.Size(); ++i) {
      const Field b = list[i];
      StoredBaseline base;
      base.kind = b["kind"].String();
      base.name = b["name"].String();
      base.placed = b["placed"].Bool();
      if (!base.placed) {
        base.why_not = b["why_not"].String();
      } else {
        base.where = b["where"].Strings();
        if (b.Has("source")) base.source = b["source"].String();
        if (b.Has("notes")) base.notes = b["notes"].Strings();
        if (b.Has("search")) base.search = b["search"].String();
        if (b.Has("evaluations")) base.evaluations = b["evaluations"].Integer();
        base.plan = ReadPlan(b["plan"], /*rank_from=*/0);
        TROCAR_THROW_UNLESS(base.plan.ports.size() == file.arms.size(),
                            path << ": baselines[" << i
                                 << "].plan.ports: " << base.plan.ports.size() << " ports for "
                                 << file.arms.size() << " arms");
        const StoredVerdict v = ReadVerdict(b["verdict"], /*with_summary=*/true);
        base.suitable = v.suitable;
        base.summary = v.summary;
        base.reasons = v.reasons;
        if (b["verdict"].Has("verified"))
          base.verified = ReadVerdict(b["verdict"]["verified"], /*with_summary=*/false);
      }
      file.baselines.push_back(std::move(base));
    }
  }
  file.unknown =
      Unknown(doc, {"format", "version", "inputs", "patient", "operation", "robot", "algorithm",
                    "scoring", "verdict", "target_samples", "plans", "ports_given", "baselines",
                    "selection_criteria", "convergence", "run"});
  // Per-sample lists as long as the samples.
  for (std::size_t i = 0; i < file.plans.size(); ++i) {
    const auto& served = file.plans[i].verified_served;
    TROCAR_THROW_UNLESS(served.empty() || served.size() == file.samples.size(),
                        path << ": plans[" << i << "].verification.served: " << served.size()
                             << " entries for " << file.samples.size() << " target samples");
  }
  return file;
}

std::string PlanFileText(const PlanFile& file) {
  json doc;
  doc["format"] = "trocar-plan";
  doc["version"] = kPlanFormatVersion;
  doc["inputs"] = {{"case", file.case_written},
                   {"case_hash", file.case_hash},
                   {"robot", file.robot_written},
                   {"robot_hash", file.robot_hash},
                   {"patient_model_hash", file.model_hash}};
  doc["patient"] = {{"name", file.patient_name}, {"X_WP", Matrix(file.X_WP)}};
  if (file.operation) {
    const StoredOperation& op = *file.operation;
    doc["operation"] = {
        {"state", op.state},
        {"description", op.description},
        {"co2_mmHg", op.co2_mmHg},
        {"left_lung_isolated", op.left_lung_isolated},
        {"left_side_up_deg", op.left_side_up_deg},
        {"heart_shift_m", op.heart_shift_m},
        {"heart_shift_range_m", json::array({op.heart_shift_min_m, op.heart_shift_max_m})},
        {"direction_P", Vec(op.direction_P)},
        {"d_P", Vec(op.d_P)},
        {"moved_structures", op.moved_structures},
        {"moved_targets", op.moved_targets}};
  }
  json arms = json::array();
  for (const StoredArm& arm : file.arms) {
    arms.push_back(
        {{"name", arm.name},
         {"role", arm.role},
         {"rcm_frame", arm.rcm_frame},
         {"tool_frame", arm.tool_frame},
         {"shaft_link", arm.shaft_link},
         {"shaft_a_L", Vec(arm.shaft_a_L)},
         {"shaft_b_L", Vec(arm.shaft_b_L)},
         {"joints", arm.joints},
         {"max_reach_m", std::isfinite(arm.max_reach) ? json(arm.max_reach) : json(nullptr)}});
  }
  doc["robot"] = {{"name", file.robot_name}, {"arms", arms}};
  const StoredAlgorithm& a = file.algorithm;
  doc["algorithm"] = {{"global", a.global},
                      {"local", a.local},
                      {"seed", a.seed},
                      {"starts", a.starts},
                      {"evaluations_budget", a.evaluations_budget},
                      {"polish_evaluations", a.polish_evaluations},
                      {"evaluations", a.evaluations},
                      {"global_evaluations", a.global_evaluations},
                      {"best_global_score", a.best_global_score},
                      {"time_limit_s", a.time_limit_s},
                      {"time_limit_hit", a.time_limit_hit},
                      {"grid", a.grid},
                      {"top_k", a.top_k},
                      {"distinct_distance_m", a.distinct_distance_m},
                      {"robustness_shift_m", a.robustness_shift_m},
                      {"robustness_weight", a.robustness_weight}};
  const StoredScoring& s = file.scoring;
  doc["scoring"] = {{"weights", Named(s.weights)},
                    {"standoff_m", s.standoff_m},
                    {"rcm_depth_m", s.rcm_depth_m},
                    {"gap_search_depth_m", s.gap_search_depth_m},
                    {"ik_tolerance_m", s.ik_tolerance_m},
                    {"reach_restarts", s.reach_restarts},
                    {"sight_margin_m", s.sight_margin_m},
                    {"scope_half_fov_deg", s.scope_half_fov_deg},
                    {"scope_min_distance_m", s.scope_min_distance_m},
                    {"scope_max_distance_m", s.scope_max_distance_m},
                    {"scope_working_distance_m", s.scope_working_distance_m},
                    {"samples_per_target", s.samples_per_target},
                    {"suitable_fraction", s.suitable_fraction}};
  if (s.scope_moves) doc["scoring"]["scope_moves"] = *s.scope_moves;
  doc["verdict"] = {
      {"suitable", file.suitable}, {"summary", file.summary}, {"reasons", file.reasons}};
  json samples = json::array();
  for (const StoredSample& t : file.samples) {
    samples.push_back({{"index", t.index},
                       {"target", t.target},
                       {"point", t.point},
                       {"arc_length_m", t.arc_length},
                       {"p_W", Vec(t.p_W)},
                       {"n_W", Vec(t.n_W)},
                       {"aim_W", Vec(t.aim_W)}});
  }
  doc["target_samples"] = samples;
  if (file.ports_given)
    doc["ports_given"] = {{"what", file.ports_given->first}, {"where", file.ports_given->second}};
  json criteria = json::array();
  for (const StoredCriterion& c : file.criteria) {
    criteria.push_back({{"name", c.name},
                        {"title", c.title},
                        {"value", std::isfinite(c.value) ? json(c.value) : json(nullptr)},
                        {"unit", c.unit},
                        {"threshold", c.threshold},
                        {"favourable_when", c.favourable_when},
                        {"favourable", c.favourable},
                        {"meaning", c.meaning},
                        {"how", c.how},
                        {"source", c.source}});
  }
  doc["selection_criteria"] = {{"criteria", criteria}, {"comparison", file.criteria_comparison}};
  json convergence = json::array();
  for (const auto& [evaluations, best] : file.convergence)
    convergence.push_back(json::array({evaluations, best}));
  doc["convergence"] = convergence;
  doc["run"] = {{"threads", file.run_threads}, {"timings_s", Named(file.timings_s)}};
  doc = Rounded(doc);
  // The parts with their own rounding: the plans (their verification as computed) and the
  // verdict from verified motions.
  if (file.has_verified_verdict) {
    doc["verdict"]["verified"] = {{"suitable", file.verified_suitable},
                                  {"summary", file.verified_summary},
                                  {"reasons", file.verified_reasons}};
  }
  json plans = json::array();
  for (const StoredPlan& plan : file.plans) plans.push_back(PlanJsonEntry(plan));
  doc["plans"] = plans;
  json baselines = json::array();
  for (const StoredBaseline& b : file.baselines) {
    json entry = {{"kind", b.kind}, {"name", b.name}, {"placed", b.placed}};
    if (!b.placed) {
      entry["why_not"] = b.why_not;
    } else {
      entry["source"] = b.source;
      entry["where"] = b.where;
      entry["notes"] = b.notes;
      entry["search"] = b.search;
      entry["evaluations"] = b.evaluations;
      entry["verdict"] = {{"suitable", b.suitable}, {"summary", b.summary}, {"reasons", b.reasons}};
      if (b.verified)
        entry["verdict"]["verified"] = VerdictJson(*b.verified, /*with_summary=*/false);
      entry["plan"] = PlanJsonEntry(b.plan);
    }
    baselines.push_back(entry);
  }
  doc["baselines"] = baselines;
  AddUnknown(file.unknown, &doc);
  return doc.dump(1) + "\n";
}

void WritePlanFile(const std::string& path, const PlanFile& file) {
  WriteFileAtomically(path, PlanFileText(file));
}

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

std::string RobotFileMismatch(const PlanFile& file) {
  if (!IsRegularFile(file.robot_file)) return "its robot " + file.robot_file + " does not exist";
  if (HashFile(file.robot_file) != file.robot_hash)
    return "robot file " + file.robot_file + " changed since the plan was made (hash differs)";
  return "";
}

std::string PatientModelMismatch(const PlanFile& file, const patient::PatientModel& patient,
                                 const std::string& case_dir) {
  if (HashPatientModel(patient) == file.model_hash) return "";
  return "was made for another patient model than " + case_dir + "'s (hash differs)";
}

robot::RobotState NominalState(const robot::RobotModel& robot, const StoredPlan& plan,
                               const std::string& where) {
  robot::RobotState state(robot);
  state.X_WB = plan.X_WB;
  for (const auto& [name, value] : plan.setup_joints) {
    try {
      kinematics::SetHeldJoint(robot, name, value, &state);
    } catch (const Error& e) {
      TROCAR_THROW(where << ": setup joint '" << name << "': " << e.what());
    }
  }
  for (const auto& [name, value] : plan.q_nominal) {
    const int j = robot.FindJoint(name);
    TROCAR_THROW_UNLESS(
        j >= 0 && robot.joint(j).q_index >= 0,
        where << ": q_nominal names '" << name << "', not an active joint of " << robot.name());
    state.q[robot.joint(j).q_index] = value;
  }
  const auto fk = kinematics::ForwardKinematics(robot, state.q, &state);
  TROCAR_THROW_UNLESS(fk.ok(), where << ": nominal pose: " << fk.message);
  return state;
}

namespace {
// The motion's arm at `q_arm` (its `joints`), the rest of `state` kept.
void SetArmJoints(const robot::RobotModel& robot, const StoredMotion& motion,
                  const Eigen::VectorXd& q_arm, const std::string& what, robot::RobotState* state) {
  Eigen::VectorXd q = state->q;
  TROCAR_THROW_UNLESS(q_arm.size() == static_cast<Eigen::Index>(motion.joints.size()),
                      "motion of " << motion.arm << " to sample " << motion.sample << ", " << what
                                   << ": " << q_arm.size() << " joint values for "
                                   << motion.joints.size() << " joints");
  for (std::size_t d = 0; d < motion.joints.size(); ++d) {
    const int j = robot.FindJoint(motion.joints[d]);
    TROCAR_THROW_UNLESS(j >= 0 && robot.joint(j).q_index >= 0,
                        "motion of " << motion.arm << ": '" << motion.joints[d]
                                     << "' is not an active joint of " << robot.name());
    q[robot.joint(j).q_index] = q_arm[static_cast<Eigen::Index>(d)];
  }
  const auto fk = kinematics::ForwardKinematics(robot, q, state);
  TROCAR_THROW_UNLESS(fk.ok(), "motion of " << motion.arm << " to sample " << motion.sample << ", "
                                            << what << ": " << fk.message);
}
}  // namespace

void SetWaypoint(const robot::RobotModel& robot, const StoredMotion& motion, std::size_t k,
                 robot::RobotState* state) {
  TROCAR_THROW_UNLESS(k < motion.waypoints.size(),
                      "motion of " << motion.arm << " to sample " << motion.sample << " has "
                                   << motion.waypoints.size() << " waypoints, not " << k + 1);
  SetArmJoints(robot, motion, motion.waypoints[k], "waypoint " + std::to_string(k), state);
}

void SetFailurePose(const robot::RobotModel& robot, const StoredMotion& motion,
                    robot::RobotState* state) {
  TROCAR_THROW_UNLESS(motion.failure_pose.size() > 0,
                      "motion of " << motion.arm << " to sample " << motion.sample
                                   << " has no failure pose (solved, or written before stop 66)");
  SetArmJoints(robot, motion, motion.failure_pose, "its failure pose", state);
}

}  // namespace trocar::planners
